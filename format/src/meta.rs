//! The `META` section: the scene's identity, every parameter, the tool version, the scene's
//! default camera and light, and the bake's statistics.

use serde::{Deserialize, Serialize};

/// Derives both rkyv (for the file) and serde (for JSON output) on a plain data type.
macro_rules! data {
    ($(#[$m:meta])* pub struct $name:ident { $($(#[$fm:meta])* pub $f:ident : $t:ty),* $(,)? }) => {
        $(#[$m])*
        #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize,
                 rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
        pub struct $name { $($(#[$fm])* pub $f: $t),* }
    };
}

data! {
    /// Everything a baked file records about how it was made.
    pub struct Meta {
        /// The tool and its version, e.g. `mlt-bake 0.1.0`.
        pub tool: String,
        pub scene: SceneInfo,
        pub camera: CameraInfo,
        pub light: LightInfo,
        pub params: BasisParams,
        pub stats: BasisStats,
        /// Wall-clock timings; absent unless the bake was asked to record them, so that the
        /// same inputs give a byte-identical file.
        pub timings: Option<Timings>,
    }
}

data! {
    /// Where the scene came from.
    pub struct SceneInfo {
        /// The scene specification as given (manifest, mesh path or `builtin:` name).
        pub source: String,
        /// xxh3-64 of every input byte (mesh, materials, textures, manifest).
        pub content_hash: u64,
        pub triangles: u64,
        /// Degenerate (zero-area) triangles dropped while loading.
        pub degenerate_dropped: u64,
        pub scale: f32,
        /// The interior viewpoint point placement started from.
        pub viewpoint: [f32; 3],
        pub bounds_min: [f32; 3],
        pub bounds_max: [f32; 3],
    }
}

data! {
    /// The scene's default camera: right-handed world space with +Y up, `fovy_deg` the vertical
    /// field of view in degrees, `width` x `height` pixels.
    pub struct CameraInfo {
        pub position: [f32; 3],
        pub target: [f32; 3],
        pub up: [f32; 3],
        pub fovy_deg: f32,
        pub width: u32,
        pub height: u32,
    }
}

data! {
    /// The scene's default light.
    pub struct LightInfo {
        /// `point` or `spot`.
        pub kind: String,
        pub position: [f32; 3],
        /// RGB radiant intensity, W/sr.
        pub intensity: [f32; 3],
        /// Spot axis (unit), zero for a point light.
        pub direction: [f32; 3],
        /// Spot full cone angle in degrees, 0 for a point light.
        pub cone_deg: f32,
        /// `hard` or `smooth` (glTF KHR_lights_punctual) spot falloff.
        pub falloff: String,
    }
}

data! {
    /// Point placement and basis parameters (section 2.3).
    pub struct BasisParams {
        /// Number of hierarchy levels placed (receiver levels).
        pub levels: u32,
        /// The Poisson-disk radius `R_coarse` of level 0 (halved per level).
        pub coarse_radius: f32,
        /// The level-0 point count `R_coarse` was searched for, if one was asked.
        pub coarse_count_target: Option<u32>,
        pub f_squash: f32,
        /// Support factor `C` on the coarsest and finest level (`r = C R`).
        pub c_coarse: f32,
        pub c_fine: f32,
        /// A level ends after this many consecutive failed darts.
        pub max_misses: u32,
        /// Rays of the harmonic-mean-distance test, their length in units of `R`, and the
        /// rejection threshold in units of `R`.
        pub hmd_rays: u32,
        pub hmd_range: f32,
        pub hmd_reject: f32,
        /// Importance particle path length and the bounces not deposited.
        pub particle_bounces: u32,
        pub skipped_bounces: u32,
        pub seed: u64,
    }
}

data! {
    /// Statistics of one level.
    pub struct LevelStats {
        pub points: u64,
        pub disk_radius: f32,
        pub support_radius: f32,
        /// Candidates tried (darts thrown) on this level.
        pub darts: u64,
        /// Darts rejected by the Poisson-disk test (Eq. 11).
        pub disk_rejected: u64,
        /// Darts that passed it but were rejected by the harmonic-mean-distance test.
        pub hmd_rejected: u64,
        /// Points of this level divided by points of the previous level.
        pub growth: f32,
    }
}

data! {
    /// Counts from the bake (deterministic: they go in the file).
    pub struct BasisStats {
        pub particles: u64,
        pub candidates: u64,
        /// Rays cast: importance particles plus harmonic-mean-distance tests.
        pub rays: u64,
        pub points: u64,
        pub levels: Vec<LevelStats>,
        pub rtree_nodes: u64,
        /// Points of a level `l >= 1` where no coarser level had support (Eq. 7 falls back to
        /// the sample itself there).
        pub points_without_coarser_support: u64,
    }
}

data! {
    /// Wall-clock seconds per stage.
    pub struct Timings {
        pub load_s: f64,
        pub bvh_s: f64,
        pub candidates_s: f64,
        pub poisson_s: f64,
        pub rtrees_s: f64,
        pub write_s: f64,
        pub total_s: f64,
        pub threads: u32,
    }
}

data! {
    /// The `TRNS` section: how the transport operator S was computed, and what it cost.
    pub struct TransportMeta {
        pub params: TransportParams,
        pub stats: TransportStats,
        /// Wall-clock timings and peak memory; absent unless recorded (see [`Meta::timings`]).
        pub timings: Option<TransportTimings>,
    }
}

data! {
    /// Parameters of the transport precomputation (section 3.2).
    pub struct TransportParams {
        /// Link threshold epsilon (paper: 0.025).
        pub epsilon: f32,
        /// Truncation threshold of bounces 2 and later (the paper: epsilon).
        pub bounce_epsilon: f32,
        /// Sender levels (paper: 3) and receiver levels (paper: 6).
        pub sender_levels: u32,
        pub receiver_levels: u32,
        /// Most bounces in the Neumann series S = T + T^2 + ... (paper: 4).
        pub bounces: u32,
        /// Rays per receiver gather (Eq. 16).
        pub gather_rays: u32,
        /// Bounces 2 and later on every refined receiver instead of the coarsest only (the
        /// paper's choice).
        pub bounces_on_all_receivers: bool,
        pub seed: u64,
    }
}

data! {
    /// The paper's Table 1 columns and more (all deterministic counts).
    pub struct TransportStats {
        /// Links in S.
        pub links: u64,
        /// Senders x receivers.
        pub potential_links: u64,
        /// Links of the single-bounce operator T.
        pub t_links: u64,
        pub senders: u64,
        pub receivers: u64,
        /// Gather rays cast (the paper's "visibility rays").
        pub visibility_rays: u64,
        /// Gather hits where no sender level had support.
        pub unsupported_hits: u64,
        /// Per receiver level: receivers whose links were computed.
        pub receivers_refined: Vec<u64>,
        /// Per receiver level: links of T kept, and links of S.
        pub t_links_per_level: Vec<u64>,
        pub s_links_per_level: Vec<u64>,
        /// Bounces computed (1 = T only), and per bounce the largest link norm and the sum of
        /// link norms of its increment (before truncation).
        pub bounces: u32,
        pub bounce_max_norm: Vec<f64>,
        pub bounce_sum_norm: Vec<f64>,
        /// Per bounce, the sum of the norms of the links kept (above epsilon): with
        /// `bounce_sum_norm`, how much each bounce lost to truncation.
        pub bounce_kept_sum_norm: Vec<f64>,
        /// Power-iteration estimate of the spectral radius of the bounce operator.
        pub spectral_radius: f64,
        /// Largest absolute error of the half-float storage of S.
        pub quantisation_error: f32,
        /// Bytes of the basis (points and R-trees) and of the links as stored.
        pub basis_bytes: u64,
        pub links_bytes: u64,
    }
}

data! {
    /// Wall-clock cost of the transport precomputation.
    pub struct TransportTimings {
        pub refine_s: f64,
        pub bounces_s: f64,
        pub total_s: f64,
        pub peak_rss_bytes: u64,
        pub threads: u32,
    }
}

data! {
    /// The `TRPT` section (since format 1.3; absent from older files and from basis-only and
    /// shard files): how the bake chose the length of the Neumann series, the error it
    /// estimates it committed to, and what it left out of the file. A new section rather than
    /// new fields of `TRNS`, whose layout is fixed within the major version.
    pub struct TransportReport {
        /// `fixed` (a count, the paper's 4 by default) or `auto` (the count chosen from the
        /// spectral-radius estimate so that the series tail falls under `bounce_tolerance`).
        pub bounce_mode: String,
        /// Largest fraction of the indirect light the series may leave out: the target of
        /// `auto`, the warning threshold of `fixed`.
        pub bounce_tolerance: f64,
        /// The count the series was allowed (fixed: the count asked; auto: the chosen count,
        /// at most `bounce_cap`), and the cap of `auto` (0 for `fixed`).
        pub bounces_planned: u32,
        pub bounce_cap: u32,
        pub error: ErrorEstimate,
        pub left_out: LeftOut,
    }
}

data! {
    /// The bake's own estimate of the relative error it committed to, as fractions of the
    /// indirect light at the coarsest points under uniform unit emission at the coarsest
    /// senders (the worst colour channel). Not a per-pixel RMSE: the basis' reconstruction
    /// error and the links of T the refinement dropped at epsilon (Fig. 5) are not in it.
    pub struct ErrorEstimate {
        /// Indirect light beyond the last bounce computed: the last kept bounce times
        /// `rho / (1 - rho)`, over the estimated total (`rho^B` for a closed scene of
        /// uniform albedo).
        pub series_tail: f64,
        /// Light dropped by truncating bounces >= 2 below the bounce epsilon, with the later
        /// bounces it would have caused (`/ (1 - rho)`), over the estimated total.
        pub bounce_truncation: f64,
        /// Largest half-float storage error over the largest link norm of S.
        pub quantisation: f64,
        /// The sum of the three.
        pub total: f64,
        /// Whether `series_tail` is within the tolerance.
        pub series_converged: bool,
    }
}

data! {
    /// What the bake did not store, and what that saved.
    pub struct LeftOut {
        /// Levels placed, and levels stored: finer levels into which refinement added no
        /// receiver with a link (and that are not sender levels) are dropped with their
        /// points and R-trees; the hierarchical expansion of `S e` is unchanged by it.
        pub levels_placed: u32,
        pub levels_stored: u32,
        pub points_placed: u64,
        pub points_stored: u64,
        /// Bytes of the dropped levels' points and R-trees.
        pub level_bytes_saved: u64,
        /// Per placed level: receivers refined (T rows computed) and receivers with a link
        /// of S.
        pub receivers_refined_per_level: Vec<u64>,
        pub receivers_linked_per_level: Vec<u64>,
        /// Senders with at least one link (the others have no column in `SLNK`), of all.
        pub senders_linked: u64,
        pub senders: u64,
        /// Bytes of the links as stored, and what a dense S in the same half floats would take.
        pub links_bytes: u64,
        pub dense_links_bytes: u64,
    }
}

data! {
    /// The `TBNC` section (since format 1.7; absent when the series chained the bounces, in
    /// older files and in shard files): how the bake computed the level-0 receivers' bounces 2
    /// and later when it traced them as paths (`bake --level0-paths`) instead of chaining them
    /// through the level-0 senders. Those rows of `S` then hold every bounce off the true
    /// geometry, so a viewer must not re-emit bounce light through them again.
    pub struct BounceMethod {
        /// Paths per level-0 receiver.
        pub level0_paths: u32,
        /// The deepest bounce the paths compute (bounce `b` reads T at a path's vertex
        /// `b - 1`).
        pub max_vertex: u32,
    }
}

data! {
    /// The `TDRP` section (since format 1.5; absent from older files, basis-only files and
    /// shard files): the bake's estimate of the single-bounce light that the refinement of T
    /// (Fig. 5 and its budget rule) dropped, under a representative emission: the file's own
    /// light, its direct irradiance sampled at the sender points (one shadow ray each) and
    /// pull-pushed onto the sender levels as the viewer does. At every processed receiver `i`
    /// of level `l`, the irradiance along its normal that its gather found against what the
    /// kept links reconstruct there (Eq. 6 over all levels), per colour channel, times
    /// `R_l^2` (the area its basis function stands for), summed over the receivers in index
    /// order. A new section rather than new fields of `TRPT`, whose layout is fixed within the
    /// major version.
    pub struct RefinementDrop {
        /// The emission the sums weight the links by (`file light`).
        pub emission: String,
        /// Per colour channel, the light the kept links reconstruct, and the light the gathers
        /// found minus that (what was dropped).
        pub kept: [f64; 3],
        pub dropped: [f64; 3],
        /// `dropped / (kept + dropped)` in the colour channel where it is largest in
        /// magnitude: positive when the dropped links would have added light (the file's
        /// image is that much too dark), negative when they would have taken it away.
        pub share: f64,
    }
}

impl RefinementDrop {
    /// The estimate from the summed light of the kept and dropped links.
    pub fn new(emission: &str, kept: [f64; 3], dropped: [f64; 3]) -> RefinementDrop {
        let share = (0..3)
            .map(|c| {
                let all = kept[c] + dropped[c];
                if all > 0.0 {
                    dropped[c] / all
                } else {
                    0.0
                }
            })
            .fold(0.0f64, |m, d| if d.abs() > m.abs() { d } else { m });
        RefinementDrop {
            emission: emission.to_string(),
            kept,
            dropped,
            share,
        }
    }
}

data! {
    /// The `TCAM` section (since format 1.8; absent from older files, basis-only and shard
    /// files, and from merges without the scene): the bake's check of its own indirect light
    /// where the scene's camera looks. Through a grid of `width x height` cells over the
    /// camera's image, one primary ray through a random point of each cell to its first hit
    /// `x` (shading normal `n`, albedo `ρ`); there `rays` paths traced as `view reference`
    /// traces them (at each vertex a cosine-weighted and a light sample by multiple importance
    /// sampling), whose first vertex's term is the first bounce, against the file's: `n`
    /// dotted with T's coefficients under the file's light (its direct irradiance at the
    /// sender points, sampled and pull-pushed as the viewer does) expanded over all levels
    /// (Eq. 6), and the same of every bounce (below). Each times `ρ`, averaged over the grid's
    /// cells (a miss adds zero): the image's radiance times `π`, so the comparison weighs the
    /// surfaces as an image does.
    pub struct CameraCheck {
        /// The grid of primary rays, and the paths per cell.
        pub width: u32,
        pub height: u32,
        pub rays: u32,
        /// Cells whose primary ray hit the scene.
        pub cells_hit: u64,
        /// Per colour channel, the mean traced and baked first bounce (times the albedo).
        pub traced: [f64; 3],
        pub baked: [f64; 3],
        /// `1 - Y(baked) / Y(traced)` with `Y` the Rec. 709 luminance: the share of the first
        /// bounce the image lacks (negative: the image is that much too bright), and the
        /// standard error of that share from the cells' differences.
        pub share: f64,
        pub std_error: f64,
        /// The same for every bounce: the traced paths' whole indirect irradiance (next-event
        /// estimation at every vertex, roulette) against what a frame of the viewer gives
        /// there under the same emission (`S e`, with the finer receivers' bounces chained
        /// through level 0 where the file leaves them to the viewer), expanded with Eq. 6.
        pub traced_all: [f64; 3],
        pub baked_all: [f64; 3],
        pub share_all: f64,
        pub std_error_all: f64,
    }
}

data! {
    /// The `TCBK` section (since format 1.9, beside `TCAM`): the camera check's cells taken
    /// by blocks of `block` x `block` cells, every bounce, so that a seam or a leak a few
    /// pixels wide shows where the image's mean hides it. A block is *lit* when its traced
    /// mean exceeds a tenth of the image's; the worst is the lit block whose baked mean is
    /// farthest from the traced one in ratio.
    pub struct CameraBlocks {
        pub block: u32,
        /// Blocks across and down the grid.
        pub columns: u32,
        pub rows: u32,
        pub lit: u32,
        /// The worst lit block (column, row from the top-left), its `Y(baked) / Y(traced)`,
        /// and the standard error of that ratio from the block's cells.
        pub worst_column: u32,
        pub worst_row: u32,
        pub worst_ratio: f64,
        pub worst_std_error: f64,
        /// The smallest and largest ratio over the lit blocks.
        pub ratio_min: f64,
        pub ratio_max: f64,
    }
}
