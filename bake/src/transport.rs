//! The transport precomputation (section 3): T by adaptive refinement, then S by the Neumann
//! series, stored sender-major with its statistics (the paper's Table 1 and more).

use std::time::Instant;

use mlt_format::adjacency::{children, neighbors};
use mlt_format::light::LightDesc;
use mlt_format::light_model::Light;
use mlt_format::links::{Links, SenderLinks, LINK_DIM};
use mlt_format::meta::{
    BounceMethod, CameraBlocks, CameraCheck, CameraInfo, ErrorEstimate, LeftOut, RefinementDrop,
    TransportMeta, TransportParams, TransportReport, TransportStats, TransportTimings,
};
use mlt_format::{IndexedBasis, Transport};
use mlt_scenes::RayCaster;

use crate::camera_check::{camera_check, frame_coefficients, CheckSettings};
use crate::drop_estimate::{estimate, representative_emission};
use crate::error::BakeError;
use crate::neumann::{series, spectral_radius, BounceReceivers, Row, Rows, SeriesReport};
use crate::observer::Observer;
use crate::path_bounces::{level0_bounces, PathSettings};
use crate::refine::{refine, ReceiverLinks, RefinePolicy, RefineSettings, RefineStats};
use crate::report::too_dark_or_bright;

/// The result, with what the user should be told.
pub struct TransportOutput {
    pub transport: Transport,
    /// Always taken; stored in the file only when timings are recorded.
    pub timings: TransportTimings,
    pub warnings: Vec<String>,
    /// Levels of the basis to store: finer levels without a link of S are left out (see
    /// [`trim_levels`]); the links already index only the stored points.
    pub levels_stored: usize,
}

/// How long the Neumann series `S = T + T^2 + ...` runs (section 3.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BouncePolicy {
    /// Choose the count from the spectral-radius estimate `rho` (the transport parameters'
    /// `bounces` is then the cap); otherwise run `bounces` (unless truncation empties a
    /// bounce first).
    pub auto: bool,
    /// Largest fraction of the indirect light the series may leave out (`auto`'s target, and
    /// the threshold above which a fixed count is warned about).
    pub tolerance: f64,
    /// Paths per level-0 receiver that trace its bounces 2 and later (`path_bounces`); 0 chains
    /// them through the level-0 senders as the paper does (`neumann`). Ignored with
    /// `bounces_on_all_receivers`, which chains every receiver's.
    pub level0_paths: u32,
}

/// The default tolerance of [`BouncePolicy`]: 1 % of the indirect light.
pub const DEFAULT_BOUNCE_TOLERANCE: f64 = 0.01;

impl Default for BouncePolicy {
    fn default() -> Self {
        BouncePolicy {
            auto: false,
            tolerance: DEFAULT_BOUNCE_TOLERANCE,
            level0_paths: 0,
        }
    }
}

/// What the check of the light at the scene's camera (`camera_check`) needs beyond T and S:
/// the scene, its camera and its light.
#[derive(Clone, Copy)]
pub struct CheckScene<'a> {
    pub caster: &'a dyn RayCaster,
    pub camera: &'a CameraInfo,
    pub light: &'a Light,
}

/// Bounces needed so that the tail of the series, `sum_{b > B} rho^(b-1)` over
/// `sum_b rho^(b-1)`, i.e. `rho^B`, is at most `tolerance`: `ceil(ln tol / ln rho)`, at least 1.
/// `None` for `rho >= 1` (the series diverges).
pub fn bounces_needed(rho: f64, tolerance: f64) -> Option<u64> {
    let usable = rho < 1.0 && tolerance > 0.0 && tolerance < 1.0;
    if !usable {
        return None;
    }
    if rho <= 0.0 {
        return Some(1);
    }
    let b = (tolerance.ln() / rho.ln()).ceil();
    Some((b.max(1.0) as u64).max(1))
}

/// The bake's estimate of the error it committed to (see [`ErrorEstimate`]), from each
/// bounce's light at the coarsest points under uniform unit emission (computed and kept,
/// [`SeriesReport::energy`]) and the spectral radius `rho < 1`, per colour channel (the
/// worst channel is reported).
///
/// With `k_b` the kept and `s_b` the computed light of bounce `b` and `g = 1 / (1 - rho)`:
/// the tail beyond the last bounce `B` is `k_B rho g`, the light truncation dropped, with the
/// later bounces it would have caused, `sum_b (s_b - k_b) g`, and the total `sum_b k_b` plus
/// both. For a closed scene of uniform albedo without truncation the tail is exactly `rho^B`
/// of the total (bounce `b` carries `rho^(b-1)` of the first, section 3.2).
/// `quantisation` is the largest absolute f16 error and `max_link` the largest link norm
/// of S.
///
/// `traced` is the deepest vertex of the level-0 receivers' paths when they trace bounces 2 and
/// later (`path_bounces`; 0 when the series chains them): those keep every link, so nothing is
/// truncated, and their tail starts after that vertex instead of after the series' last bounce.
pub fn error_estimate(
    report: &SeriesReport,
    rho: f64,
    tolerance: f64,
    quantisation: f32,
    max_link: f64,
    traced: u32,
) -> ErrorEstimate {
    let g = 1.0 / (1.0 - rho).max(1e-12);
    let computed = report.kept_energy.len() as i32;
    let beyond = if traced > 0 {
        rho.powi((traced as i32 - computed).max(0))
    } else {
        1.0
    };
    let (mut series_tail, mut bounce_truncation) = (0.0f64, 0.0f64);
    for c in 0..3 {
        let kept: f64 = report.kept_energy.iter().map(|e| e[c].max(0.0)).sum();
        let last = report.kept_energy.last().map_or(0.0, |e| e[c].max(0.0));
        let tail = last * rho * g * beyond;
        let dropped: f64 = if traced > 0 {
            0.0
        } else {
            report
                .energy
                .iter()
                .zip(&report.kept_energy)
                .map(|(s, k)| (s[c] - k[c]).abs() * g)
                .sum()
        };
        let total = kept + tail + dropped;
        if total > 0.0 && total.is_finite() {
            series_tail = series_tail.max(tail / total);
            bounce_truncation = bounce_truncation.max(dropped / total);
        }
    }
    let quantisation = if max_link > 0.0 {
        quantisation as f64 / max_link
    } else {
        0.0
    };
    ErrorEstimate {
        series_tail,
        bounce_truncation,
        quantisation,
        total: series_tail + bounce_truncation + quantisation,
        series_converged: series_tail <= tolerance,
    }
}

/// The basis of the first `levels` levels of `ib` (finer levels dropped with their R-trees;
/// the kept points keep their indices).
pub fn trim_levels(ib: &IndexedBasis, levels: usize) -> Result<IndexedBasis, BakeError> {
    if levels >= ib.levels() {
        return Ok(ib.clone());
    }
    let b = &ib.basis;
    let n = b.level_offsets[levels] as usize;
    let basis = mlt_format::Basis {
        positions: b.positions[..n].to_vec(),
        normals: b.normals[..n].to_vec(),
        radii: b.radii[..n].to_vec(),
        level_offsets: b.level_offsets[..=levels].to_vec(),
        disk_radii: b.disk_radii[..levels].to_vec(),
    };
    let clip = mlt_format::support_clip::SupportClip::from_rows(
        (0..n.min(ib.clip.points())).map(|j| ib.clip.planes_of(j)),
    );
    let clip = if clip.is_empty() {
        Default::default()
    } else {
        clip
    };
    Ok(IndexedBasis::from_parts(basis, ib.trees[..levels].to_vec())?.with_clip(clip)?)
}

/// Checks the transport parameters against the basis.
pub fn check_params(p: &TransportParams, levels: u32) -> Result<(), BakeError> {
    let bad = |m: String| Err(BakeError::InvalidParameter(m));
    if !(p.epsilon.is_finite() && p.epsilon >= 0.0) {
        return bad(format!(
            "epsilon must be finite and >= 0, got {}",
            p.epsilon
        ));
    }
    if !(p.bounce_epsilon.is_finite() && p.bounce_epsilon >= 0.0) {
        return bad(format!(
            "the bounce epsilon must be finite and >= 0, got {}",
            p.bounce_epsilon
        ));
    }
    if p.sender_levels == 0 || p.sender_levels > levels {
        return bad(format!(
            "sender levels must be 1..={levels} (the receiver levels), got {}",
            p.sender_levels
        ));
    }
    if p.bounces == 0 {
        return bad("bounces must be at least 1".into());
    }
    if p.gather_rays == 0 {
        return bad("gather rays must be at least 1".into());
    }
    Ok(())
}

/// Peak resident memory of this process, where the platform tells (Linux).
pub fn peak_rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map(|kb| kb * 1024)
        .unwrap_or(0)
}

/// Computes S for `ib` (in the current rayon pool; the result does not depend on its size).
/// `light` gives the representative emission of the estimate of what refinement drops
/// (`drop_estimate`) and, with `camera`, the check of the light at the camera
/// (`camera_check`); neither changes S.
#[allow(clippy::too_many_arguments)]
pub fn compute_transport(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    (params, refine): (TransportParams, &RefinePolicy),
    policy: BouncePolicy,
    light: &LightDesc,
    camera: &CameraInfo,
    obs: &dyn Observer,
) -> Result<TransportOutput, BakeError> {
    check_params(&params, ib.levels() as u32)?;
    let model = Light::from_desc(light).map_err(|e| BakeError::InvalidParameter(e.to_string()))?;
    let (mut t, rstats, refine_s) = refine_t(ib, caster, &params, refine, light, None, obs)?;
    trace_level0_bounces(ib, caster, &params, policy, &mut t, obs);
    let check = CheckScene {
        caster,
        camera,
        light: &model,
    };
    finish_transport(ib, t, rstats, params, policy, refine_s, Some(check), obs)
}

/// The warning when the links of T dropped at epsilon carry more than `tolerance` of the
/// single-bounce light under the file's light ([`RefinementDrop::share`], either sign).
pub fn refinement_warning(drop: &RefinementDrop, epsilon: f32, tolerance: f64) -> Option<String> {
    let d = drop.share;
    (d.abs() > tolerance).then(|| {
        format!(
            "links of T dropped at epsilon {epsilon} would have {} about {:.1} % of the single-bounce light under the file's light (the image is that much too {}); a smaller --epsilon keeps them",
            if d > 0.0 { "added" } else { "taken away" },
            100.0 * d.abs(),
            too_dark_or_bright(d)
        )
    })
}

/// The check of the light at the scene's camera (`camera_check`): T's first bounce and the
/// viewer's frame from S (`fine`: with the finer receivers' later bounces re-emitted from
/// every point of the `sender_levels` sender levels), as a stage of the bake's report; `None`
/// when the camera is degenerate or T carries no representative emission over those levels.
fn check_at_camera(
    ib: &IndexedBasis,
    (t, links, fine): (&ReceiverLinks, &Links, bool),
    sender_levels: usize,
    scene: CheckScene<'_>,
    seed: u64,
    obs: &dyn Observer,
) -> Option<(CameraCheck, CameraBlocks)> {
    let senders = ib.basis.level_offsets[sender_levels.min(ib.levels())] as usize;
    if t.emission.len() != 3 * senders {
        return None;
    }
    obs.stage("light checked at the camera");
    let t0 = Instant::now();
    let settings = CheckSettings::new(seed);
    let frame = frame_coefficients(ib, links, (&t.emission, sender_levels), fine);
    let (c, blocks) = camera_check(
        ib,
        scene.caster,
        scene.light,
        scene.camera,
        (t, &frame),
        settings,
    )?;
    obs.done(
        "light checked at the camera",
        t0.elapsed().as_secs_f64(),
        &format!(
            "{}x{} primary rays, {} paths each: the indirect light {:.2} % +- {:.2} % too {} against the traced one (the first bounce {:.2} % +- {:.2} % too {}); {}",
            c.width,
            c.height,
            c.rays,
            100.0 * c.share_all.abs(),
            100.0 * c.std_error_all,
            too_dark_or_bright(c.share_all),
            100.0 * c.share.abs(),
            100.0 * c.std_error,
            too_dark_or_bright(c.share),
            blocks_line(&blocks),
        ),
    );
    Some((c, blocks))
}

/// The camera check by blocks in words: the range of the lit blocks' ratios and the worst.
pub fn blocks_line(b: &CameraBlocks) -> String {
    format!(
        "by {}x{} blocks: baked / traced {:.2}-{:.2} over {} lit blocks, worst {:.2} +- {:.2} at block ({}, {}) of {}x{}",
        b.block,
        b.block,
        b.ratio_min,
        b.ratio_max,
        b.lit,
        b.worst_ratio,
        b.worst_std_error,
        b.worst_column,
        b.worst_row,
        b.columns,
        b.rows
    )
}

/// A block of the camera check whose baked light is off by more than this factor (either
/// way) by more than twice its standard error draws a warning.
pub const CAMERA_BLOCK_WARNING: f64 = 1.3;

/// The warning when the camera check's worst block is off by more than
/// [`CAMERA_BLOCK_WARNING`] (a local error: a seam, a leak, a hole).
pub fn camera_block_warning(b: &CameraBlocks) -> Option<String> {
    let r = b.worst_ratio;
    let off = !(1.0 / CAMERA_BLOCK_WARNING..=CAMERA_BLOCK_WARNING).contains(&r);
    let sure = (r - 1.0).abs() > 2.0 * b.worst_std_error;
    (b.lit > 0 && off && sure).then(|| {
        format!(
            "at the scene's camera one part of the image is {:.2}x (+- {:.2}) the traced indirect light, block ({}, {}) of {}x{} blocks of {} cells: a local error the mean hides",
            r, b.worst_std_error, b.worst_column, b.worst_row, b.columns, b.rows, b.block
        )
    })
}

/// The share of the indirect light at the scene's camera above which the bake warns: the 3 %
/// in the mean a user can expect against a path tracer on ordinary scenes (the built-in
/// Cornell box measures 1.5 %), so that a default bake of such a scene is quiet.
pub const CAMERA_WARNING: f64 = 0.03;

/// The warning when the indirect light at the camera lacks (or exceeds) more than
/// [`CAMERA_WARNING`] of the traced one by more than twice its standard error.
pub fn camera_warning(c: &CameraCheck) -> Option<String> {
    let d = c.share_all;
    (d.abs() > CAMERA_WARNING && d.abs() > 2.0 * c.std_error_all).then(|| {
        format!(
            "at the scene's camera the indirect light is about {:.1} % (+- {:.1} %) too {} against traced paths (the first bounce alone {:.1} % too {}: T's dropped links, the direct light's projection and the basis; the rest is the later bounces)",
            100.0 * d.abs(),
            100.0 * c.std_error_all,
            too_dark_or_bright(d),
            100.0 * c.share.abs(),
            too_dark_or_bright(c.share)
        )
    })
}

/// The deepest bounce of the level-0 receivers' paths (`path_bounces`) under `params` and
/// `policy`, or 0 when the series chains their bounces: the fixed bounce count, or with
/// `--bounces auto` its cap (the paths' roulette ends them long before it unless the scene is
/// stiff, where they need that depth as the series does).
pub fn traced_vertex(params: &TransportParams, policy: BouncePolicy) -> u32 {
    if policy.level0_paths == 0 || params.bounces_on_all_receivers {
        0
    } else {
        params.bounces
    }
}

/// Bounces 2 and later of the level-0 receivers by path tracing, into `t.bounce0` (`t` holds
/// every receiver's row of T: a whole bake's or a merge's); nothing when the policy leaves
/// them to the series.
pub fn trace_level0_bounces(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    params: &TransportParams,
    policy: BouncePolicy,
    t: &mut ReceiverLinks,
    obs: &dyn Observer,
) {
    let max_vertex = traced_vertex(params, policy);
    if max_vertex == 0 {
        return;
    }
    obs.stage("level-0 bounces by path tracing");
    let t0 = Instant::now();
    let settings = PathSettings {
        sender_levels: params.sender_levels as usize,
        paths: policy.level0_paths,
        max_vertex,
        seed: params.seed,
    };
    t.bounce0 = level0_bounces(ib, caster, settings, t);
    let links: usize = t.bounce0.iter().map(|r| r.len()).sum();
    obs.done(
        "level-0 bounces by path tracing",
        t0.elapsed().as_secs_f64(),
        &format!(
            "{} paths per receiver ending in T, bounces 2 to {max_vertex}, {links} links",
            policy.level0_paths
        ),
    );
}

/// The refinement of T (optionally only of the receivers marked in `needed`, for a shard);
/// returns T, its counts and the seconds it took. A light the light model refuses is an
/// error.
pub fn refine_t(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    params: &TransportParams,
    refine_policy: &RefinePolicy,
    light: &LightDesc,
    needed: Option<&[bool]>,
    obs: &dyn Observer,
) -> Result<(ReceiverLinks, RefineStats, f64), BakeError> {
    obs.stage("refinement of T");
    let t0 = Instant::now();
    let light = Light::from_desc(light).map_err(|e| BakeError::InvalidParameter(e.to_string()))?;
    let emission = representative_emission(ib, caster, &light, params.sender_levels as usize);
    let nb = neighbors(ib);
    let ch = children(ib);
    let settings = RefineSettings {
        epsilon: params.epsilon,
        sender_levels: params.sender_levels as usize,
        gather_rays: params.gather_rays,
        seed: params.seed,
        policy: *refine_policy,
    };
    let levels = ib.levels();
    let (t, rstats) = refine(
        ib,
        caster,
        &nb,
        &ch,
        &settings,
        needed,
        &emission,
        |l, n, kept| {
            obs.progress(l as u64 + 1, levels as u64);
            obs.done(
                &format!("receiver level {l}"),
                t0.elapsed().as_secs_f64(),
                &format!("{n} receivers refined, {kept} links kept"),
            );
        },
    );
    let refine_s = t0.elapsed().as_secs_f64();
    obs.done(
        "refinement of T",
        refine_s,
        &format!(
            "{} links, {} rays; links dropped at epsilon: {:+.2} % of the single-bounce light under the file's light ({:+.2} % under uniform emission)",
            t.link_count(),
            rstats.rays,
            100.0 * estimate(ib, &t).share,
            100.0 * rstats.dropped_share()
        ),
    );
    Ok((t, rstats, refine_s))
}

/// From T to the stored S: the spectral-radius check, the Neumann series, sender-major
/// packing and the statistics. Deterministic in `t` and `rstats` (a merge of shards calls it
/// with the shards' T and gets the single bake's S).
#[allow(clippy::too_many_arguments)]
pub fn finish_transport(
    ib: &IndexedBasis,
    mut t: ReceiverLinks,
    rstats: RefineStats,
    params: TransportParams,
    policy: BouncePolicy,
    refine_s: f64,
    check: Option<CheckScene<'_>>,
    obs: &dyn Observer,
) -> Result<TransportOutput, BakeError> {
    let t_start = Instant::now();
    let b = &ib.basis;
    let levels = ib.levels();
    let drop = estimate(ib, &t);
    let senders = b.level_offsets[params.sender_levels as usize] as usize;
    let receivers = b.len();
    let mut run = run_series(ib, &t, &params, policy, senders, obs)?;
    let traced = traced_vertex(&params, policy);
    if traced > 0 {
        // The level-0 rows of bounces 2 and later come from the paths, not the chain.
        let n0 = b.level_range(0).len();
        if t.bounce0.len() != n0 {
            return Err(BakeError::InvalidParameter(format!(
                "the path-traced bounces hold {} of the {n0} level-0 receivers' rows",
                t.bounce0.len()
            )));
        }
        if run.extra.len() < n0 {
            run.extra.resize(n0, Vec::new());
        }
        for (row, traced_row) in run.extra.iter_mut().zip(std::mem::take(&mut t.bounce0)) {
            *row = traced_row;
        }
    }
    let p = pack_s(ib, &t, &run.extra, &params, senders)?;
    // The viewer chains the finer receivers' later bounces for such a file
    // (`mlt_relight::FineBounceOp::applies_to`: bounces on the coarsest receivers only, more
    // than one), so its frame, which the check compares, has them.
    let fine = !params.bounces_on_all_receivers && run.report.bounces >= 2;
    let checked = check.and_then(|c| {
        check_at_camera(
            ib,
            (&t, &p.links, fine),
            params.sender_levels as usize,
            c,
            params.seed,
            obs,
        )
    });
    let SeriesRun {
        rho,
        needed,
        planned,
        report,
        bounces_s,
        ..
    } = run;
    let error = error_estimate(&report, rho, policy.tolerance, p.qerr, p.max_link, traced);
    let mut warnings = error_warnings(&error, &report, rho, needed, &params, policy, obs);
    if let Some(w) = refinement_warning(&drop, params.epsilon, policy.tolerance) {
        obs.warn(&w);
        warnings.push(w);
    }
    let (camera_check, camera_blocks) = match checked {
        Some((c, b)) => (Some(c), Some(b)),
        None => (None, None),
    };
    if let Some(w) = camera_check.as_ref().and_then(camera_warning) {
        obs.warn(&w);
        warnings.push(w);
    }
    if let Some(w) = camera_blocks.as_ref().and_then(camera_block_warning) {
        obs.warn(&w);
        warnings.push(w);
    }
    let dense_links_bytes = senders as u64 * receivers as u64 * (LINK_DIM as u64 * 2);
    let report_section = TransportReport {
        bounce_mode: if policy.auto { "auto" } else { "fixed" }.into(),
        bounce_tolerance: policy.tolerance,
        bounces_planned: planned,
        bounce_cap: if policy.auto { params.bounces } else { 0 },
        error,
        left_out: LeftOut {
            levels_placed: levels as u32,
            levels_stored: p.levels_stored as u32,
            points_placed: receivers as u64,
            points_stored: p.stored_receivers as u64,
            level_bytes_saved: p.basis_bytes.saturating_sub(p.stored_basis_bytes),
            receivers_refined_per_level: rstats.receivers_refined.clone(),
            receivers_linked_per_level: p.linked_per_level,
            senders_linked: p.links.sender_ids.len() as u64,
            senders: senders as u64,
            links_bytes: p.links_bytes,
            dense_links_bytes,
        },
    };

    let stats = TransportStats {
        links: p.links.link_count() as u64,
        potential_links: senders as u64 * receivers as u64,
        t_links: t.link_count() as u64,
        senders: senders as u64,
        receivers: receivers as u64,
        visibility_rays: rstats.rays,
        unsupported_hits: rstats.unsupported_hits,
        receivers_refined: rstats.receivers_refined,
        t_links_per_level: rstats.links_per_level,
        s_links_per_level: p.s_per_level,
        bounces: report.bounces,
        bounce_max_norm: report.max_norm,
        bounce_sum_norm: report.sum_norm,
        bounce_kept_sum_norm: report.kept_sum_norm,
        spectral_radius: rho,
        quantisation_error: p.qerr,
        basis_bytes: p.basis_bytes,
        links_bytes: p.links_bytes,
    };
    let timings = TransportTimings {
        refine_s,
        bounces_s,
        total_s: refine_s + t_start.elapsed().as_secs_f64(),
        peak_rss_bytes: peak_rss_bytes(),
        threads: rayon::current_num_threads() as u32,
    };
    Ok(TransportOutput {
        transport: Transport {
            meta: TransportMeta {
                params,
                stats,
                timings: None,
            },
            links: p.links,
            report: Some(report_section),
            drop: Some(drop),
            bounces: (traced > 0).then_some(BounceMethod {
                level0_paths: policy.level0_paths,
                max_vertex: traced,
            }),
            camera_check,
            camera_blocks,
        },
        timings,
        warnings,
        levels_stored: p.levels_stored,
    })
}

/// S packed for the file, with the counts and sizes its statistics report.
struct PackedS {
    links: Links,
    /// The largest absolute f16 error of the packed links.
    qerr: f32,
    s_per_level: Vec<u64>,
    linked_per_level: Vec<u64>,
    levels_stored: usize,
    stored_receivers: usize,
    links_bytes: u64,
    basis_bytes: u64,
    stored_basis_bytes: u64,
    /// The largest link norm of S.
    max_link: f64,
}

/// S = T + `extra`, sender-major, packed over the levels to store: every sender level, and
/// the receiver levels that hold a link of S (refinement queues a receiver's children only
/// when it kept a link, so these are contiguous from level 0).
fn pack_s(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    extra: &Rows,
    params: &TransportParams,
    senders: usize,
) -> Result<PackedS, BakeError> {
    let b = &ib.basis;
    let levels = ib.levels();
    let (columns, s_per_level) = sender_major(ib, t, extra);
    let linked_per_level = linked_per_level(ib, &columns);
    let last_linked = linked_per_level
        .iter()
        .rposition(|&n| n > 0)
        .map_or(0, |l| l + 1);
    let levels_stored = last_linked.max(params.sender_levels as usize).min(levels);
    let stored_receivers = b.level_offsets[levels_stored] as usize;
    let (links, qerr) = Links::pack(
        stored_receivers as u32,
        senders as u32,
        columns.iter().map(|(s, col)| SenderLinks {
            sender: *s,
            links: col,
        }),
    );
    let max_link = columns
        .iter()
        .flat_map(|(_, col)| col.iter())
        .fold(0.0f64, |m, (_, v)| {
            m.max(crate::gather::link_norm(v) as f64)
        });
    // The sender-major rows (40 bytes a link) are done with: freed before the sizes below
    // serialise the links and the basis once more, which would otherwise add to them at the
    // bake's peak of memory.
    drop(columns);
    let links_bytes = mlt_format::file::archived_len(&links)?;
    let basis_bytes = mlt_format::file::basis_archived_len(ib)?;
    let stored_basis_bytes = if levels_stored < levels {
        mlt_format::file::basis_archived_len(&trim_levels(ib, levels_stored)?)?
    } else {
        basis_bytes
    };
    Ok(PackedS {
        links,
        qerr,
        s_per_level,
        linked_per_level,
        levels_stored,
        stored_receivers,
        links_bytes,
        basis_bytes,
        stored_basis_bytes,
        max_link,
    })
}

/// What the Neumann series gave: the spectral radius, the bounces the tolerance needs, the
/// bounces planned, the bounces beyond T summed per row, the report and the seconds it took.
struct SeriesRun {
    rho: f64,
    needed: Option<u64>,
    planned: u32,
    extra: Rows,
    report: SeriesReport,
    bounces_s: f64,
}

/// The spectral-radius check and the series (section 3.2), with the count asked for or, with
/// `policy.auto`, the one that brings the tail `rho^B` under the tolerance, at most the cap.
fn run_series(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    params: &TransportParams,
    policy: BouncePolicy,
    senders: usize,
    obs: &dyn Observer,
) -> Result<SeriesRun, BakeError> {
    obs.stage("indirect bounces");
    let t1 = Instant::now();
    let rho = spectral_radius(ib, t);
    // At 1 - 1e-4 the series would need some 10^5 bounces; treat it as divergent.
    if rho.is_nan() || rho >= 1.0 - 1e-4 {
        return Err(BakeError::Divergent {
            spectral_radius: rho,
        });
    }
    let bounce_receivers = if params.bounces_on_all_receivers {
        BounceReceivers::All
    } else {
        BounceReceivers::Coarsest
    };
    let needed = bounces_needed(rho, policy.tolerance);
    let planned = if policy.auto {
        needed
            .unwrap_or(params.bounces as u64)
            .min(params.bounces as u64) as u32
    } else {
        params.bounces
    };
    let (extra, report) = series(
        ib,
        t,
        senders,
        planned,
        params.bounce_epsilon,
        bounce_receivers,
        |b, kept| {
            // Every bounce of a short series; of a long one the first few, powers of two
            // and the last.
            if b <= 8 || b.is_power_of_two() || b == planned || kept == 0 {
                obs.done(
                    &format!("bounce {b}"),
                    t1.elapsed().as_secs_f64(),
                    &format!("{kept} links above epsilon"),
                )
            }
        },
    );
    let bounces_s = t1.elapsed().as_secs_f64();
    obs.done(
        "indirect bounces",
        bounces_s,
        &format!("{} bounces, spectral radius {rho:.3}", report.bounces),
    );
    Ok(SeriesRun {
        rho,
        needed,
        planned,
        extra,
        report,
        bounces_s,
    })
}

/// One sender's links of S: `(receiver, value)` ascending by receiver.
type Column = (u32, Row);

/// S = T + the bounces, regrouped sender-major: every link as (sender, receiver, value),
/// sorted; a receiver holds at most one T link and one bounce link per sender, summed (float
/// addition of two terms is commutative, so the order does not matter). Returns the columns
/// and the links of S per receiver level.
fn sender_major(ib: &IndexedBasis, t: &ReceiverLinks, extra: &Rows) -> (Vec<Column>, Vec<u64>) {
    let b = &ib.basis;
    let extra_links: usize = extra.iter().map(|r| r.len()).sum();
    let mut triples: Vec<(u32, u32, [f32; LINK_DIM])> =
        Vec::with_capacity(t.link_count() + extra_links);
    for (row, &r) in t.rows.iter().enumerate() {
        let (a, e) = (t.offsets[row] as usize, t.offsets[row + 1] as usize);
        for (s, v) in t.senders[a..e].iter().zip(&t.values[a..e]) {
            triples.push((*s, r, *v));
        }
        for (s, v) in extra.get(row).map(|x| &x[..]).unwrap_or(&[]) {
            triples.push((*s, r, *v));
        }
    }
    triples.sort_unstable_by_key(|&(s, r, _)| (s, r));
    let mut s_per_level = vec![0u64; ib.levels()];
    let mut columns: Vec<Column> = Vec::new();
    for (s, r, v) in triples {
        match columns.last_mut() {
            Some((cs, col)) if *cs == s => match col.last_mut() {
                Some((cr, cv)) if *cr == r => {
                    for k in 0..LINK_DIM {
                        cv[k] += v[k];
                    }
                    continue;
                }
                _ => col.push((r, v)),
            },
            _ => columns.push((s, vec![(r, v)])),
        }
        s_per_level[b.level_of(r as usize)] += 1;
    }
    (columns, s_per_level)
}

/// Receivers that hold a link of S, per level.
fn linked_per_level(ib: &IndexedBasis, columns: &[Column]) -> Vec<u64> {
    let b = &ib.basis;
    let mut linked_per_level = vec![0u64; ib.levels()];
    let mut linked = vec![false; b.len()];
    for (_, col) in columns {
        for (r, _) in col {
            linked[*r as usize] = true;
        }
    }
    for (r, &l) in linked.iter().enumerate() {
        if l {
            linked_per_level[b.level_of(r)] += 1;
        }
    }
    linked_per_level
}

/// Warnings (sent to `obs` and returned) when the series left out more of the indirect light
/// than the tolerance: by stopping too early, or by truncating bounces 2 and later.
fn error_warnings(
    error: &ErrorEstimate,
    report: &SeriesReport,
    rho: f64,
    needed: Option<u64>,
    params: &TransportParams,
    policy: BouncePolicy,
    obs: &dyn Observer,
) -> Vec<String> {
    let mut warnings = Vec::new();
    let more = needed.map_or("many more".to_string(), |n| n.to_string());
    if !error.series_converged {
        let w = if policy.auto {
            format!(
                "the Neumann series is cut at the cap of {} bounces (spectral radius {rho:.4}): bounces left out carry about {:.1} % of the indirect light; {more} bounces would bring that under {:.1} % (raise the cap with --bounces auto:N)",
                report.bounces,
                100.0 * error.series_tail,
                100.0 * policy.tolerance
            )
        } else {
            format!(
                "the Neumann series has not converged after {} bounces (spectral radius {rho:.4}): bounces left out carry about {:.1} % of the indirect light; {more} bounces would bring that under {:.1} % (--bounces auto chooses the count)",
                report.bounces,
                100.0 * error.series_tail,
                100.0 * policy.tolerance
            )
        };
        obs.warn(&w);
        warnings.push(w);
    }
    if error.bounce_truncation > policy.tolerance {
        let w = format!(
            "truncating bounces 2 and later at the bounce epsilon {} drops about {:.1} % of the indirect light (estimate, above the tolerance {:.1} %); a smaller --bounce-epsilon (e.g. {}) keeps it",
            params.bounce_epsilon,
            100.0 * error.bounce_truncation,
            100.0 * policy.tolerance,
            params.bounce_epsilon / 25.0
        );
        obs.warn(&w);
        warnings.push(w);
    }
    warnings
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_camera_warning_says_which_way_each_part_is_off() {
        let check = |all: f64, first: f64| mlt_format::meta::CameraCheck {
            width: 160,
            height: 90,
            rays: 32,
            cells_hit: 100,
            traced: [1.0; 3],
            baked: [1.0; 3],
            share: first,
            std_error: 0.001,
            traced_all: [1.0; 3],
            baked_all: [1.0; 3],
            share_all: all,
            std_error_all: 0.001,
        };
        let w = camera_warning(&check(0.109, -0.148)).expect("a warning");
        assert!(w.contains("10.9 % (+- 0.1 %) too dark"), "{w}");
        assert!(
            w.contains("the first bounce alone 14.8 % too bright"),
            "{w}"
        );
        let w = camera_warning(&check(-0.2, 0.05)).expect("a warning");
        assert!(
            w.contains("too bright against") && w.contains("alone 5.0 % too dark"),
            "{w}"
        );
        assert!(
            camera_warning(&check(0.001, 0.2)).is_none(),
            "under the threshold"
        );
    }

    #[test]
    fn the_camera_warning_needs_a_share_above_three_percent_and_twice_its_error() {
        let check = |share_all: f64, std_error_all: f64| CameraCheck {
            share_all,
            std_error_all,
            share: 0.01,
            ..CameraCheck::default()
        };
        let w = camera_warning(&check(0.05, 0.001)).expect("5 % +- 0.1 % warns");
        assert!(w.contains("5.0 %") && w.contains("too dark"), "{w}");
        let w = camera_warning(&check(-0.04, 0.001)).expect("-4 % warns");
        assert!(w.contains("too bright"), "{w}");
        assert!(camera_warning(&check(0.02, 0.001)).is_none());
        assert!(camera_warning(&check(0.05, 0.03)).is_none());
    }
}
