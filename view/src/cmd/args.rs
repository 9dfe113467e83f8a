//! Options that several subcommands share: what to look at (scene, camera, light) and how to
//! relight and render it.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use glam::Vec3;
use mlt_format::flat_basis::{FlatRule, FLAT_NORMAL_POWER};
use mlt_view::camera::parse_vec3;
use mlt_view::gpu::Gpu;

/// A baked file to view, with the setting to view it in and how to relight it.
#[derive(Args, Clone, Debug)]
pub struct BakedArgs {
    /// A file written by `bake`.
    pub file: PathBuf,
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub relight: RelightArgs,
}

/// The scene, camera and light, each defaulting to the file's (or the scene's).
#[derive(Args, Clone, Debug, Default)]
pub struct SceneArgs {
    /// The scene to ray-cast for visibility and to rasterise (default: the source recorded
    /// in the file).
    #[arg(long)]
    pub scene: Option<String>,
    /// Camera position (default: the file's camera).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_pos: Option<Vec3>,
    /// Camera target.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_target: Option<Vec3>,
    /// Camera up vector.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_up: Option<Vec3>,
    /// Vertical field of view, degrees.
    #[arg(long)]
    pub fovy: Option<f32>,
    /// Image width in pixels (default: the camera's); the field of view is kept.
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Light position (default: the file's light).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light_pos: Option<Vec3>,
    /// Light RGB intensity in W/sr.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light_intensity: Option<Vec3>,
    /// Spot direction (with --cone-deg): makes the light a spot.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "cone_deg")]
    pub light_dir: Option<Vec3>,
    /// Spot full cone angle, degrees.
    #[arg(long, requires = "light_dir")]
    pub cone_deg: Option<f32>,
    /// Smooth (glTF) spot falloff instead of a hard cone.
    #[arg(long)]
    pub smooth: bool,
}

/// How the CPU relights a frame (section 3.3).
#[derive(Args, Clone, Debug)]
pub struct RelightArgs {
    /// Shadow rays per sender point for the direct light at the senders.
    #[arg(long, default_value_t = 8)]
    pub shadow_rays: u32,
    /// Cast every shadow ray at every point; by default half are cast first and the rest only
    /// where those disagree (the penumbra).
    #[arg(long)]
    pub all_shadow_rays: bool,
    /// Sample the direct light only at the sender points, also near the light; by default,
    /// within a few support radii of the light, it is averaged over each sender's basis
    /// function so that a hot spot keeps its flux (and the shadow rays end in front of the
    /// surfaces next to the light).
    #[arg(long)]
    pub point_samples: bool,
    /// Leave the flat coefficients as flattened (the exact values of Eq. 6 at the flat
    /// points), without the sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` that take
    /// back the flat basis' smoothing.
    #[arg(long)]
    pub no_sharpen: bool,
    /// Flatten (and sharpen) every flat point's coefficients each frame; by default only the
    /// rows of the flat points whose functions may meet the view frustum, and those their
    /// sharpening reads, are computed (the image is the same).
    #[arg(long)]
    pub no_view_culling: bool,
    /// Steps of the sharpening (iterated Shepard correction), 1 to 16: each takes back more of
    /// the flat basis' smoothing for one more product of its weights `W` (every second step
    /// over-relaxed, its correction weighted by 2.5).
    #[arg(long, default_value_t = mlt_relight::flatten_op::SHARPEN_STEPS)]
    pub sharpen_steps: usize,
    /// Leave the finer receivers with the first bounce only, as the bake's `S` has them (the
    /// paper's relighting; also turns the bounce-light feedback off): by default, for a file
    /// whose bounces 2 and later were computed on the coarsest receivers, they are added at
    /// the finer receivers each frame from the level-0 coefficients of `S e`, through the
    /// finer receivers' links to level-0 senders.
    #[arg(long)]
    pub no_fine_bounces: bool,
    /// Steps of the bounce-light feedback: the finer receivers' bounce light, which the
    /// bake's chain of bounces through the coarsest receivers leaves out, re-emitted each
    /// frame through the level-0 rows of `S` (the indirect light as the fixed point of
    /// `i = S (e + P-dagger (n . R i) - y(i))`). 0 turns it off; `--no-fine-bounces` turns
    /// it off too (the paper's relighting), and files whose bounces ran on every receiver, or
    /// with one bounce, never get it. Each step costs about one `S e`; a second moves the
    /// mean by under 1 %. At most 16. Default 0 for a file whose level-0 bounces were traced
    /// as paths (the default bake; `bake --level0-paths`): its level-0 rows hold every bounce
    /// already, and re-emitting through them would count the later bounces twice; 1 for a
    /// file that chains them (`bake --preset paper`, `--level0-paths 0`).
    #[arg(long, value_name = "STEPS", value_parser = clap::value_parser!(u32).range(0..=16))]
    pub bounce_feedback: Option<u32>,
    /// Lagged bounce light, for a moving light: each frame applies the bounce light
    /// computed from the previous frame's indirect light in the same pass as `S e`, instead
    /// of a pass of its own after it: the feedback's correction (files that chain their
    /// bounces; on Sponza 4-5 ms less per frame on 2 cores) or the fine bounces' emission
    /// from every sender point, which the finer rows take added to the direct light (files
    /// with traced level-0 rows, the default bake; on textured Sponza 6 ms less, the built-in
    /// Cornell box 0.7 ms). A moving light's lagged part is a frame late, and frame after
    /// frame it iterates toward a fixed point (with the fine bounces one that also re-emits
    /// the finer receivers' later bounces); a light that stops gets one more frame with its
    /// own, a further step. The first frame is exact. `auto`: on in the window (`view
    /// open`) wherever a part is lagged, off for images and timings.
    #[arg(long, value_enum, default_value_t = FeedbackLag::Auto)]
    pub feedback_lag: FeedbackLag,
    /// How the finer receivers' bounces 2 and later are emitted, for a file whose bounces 2
    /// and later were computed on the coarsest receivers: `senders` re-emits the indirect
    /// light at every sender point, pull-pushed onto the sender levels like the direct light,
    /// through the finer receivers' whole rows of `S` (about 0.011 better per pixel on Sponza,
    /// one more product of the finer rows per frame); `level0` takes the level-0 coefficients
    /// through their links to level-0 senders only. With the bounce-light feedback on (files
    /// that chain their bounces) `level0` is used.
    #[arg(long, value_enum, default_value_t = FineEmissionArg::Senders)]
    pub fine_emission: FineEmissionArg,
    /// For experiments: build the flat basis with this neighbour count and radius factor
    /// (`K,F`: each flat radius F times the distance to the K-th nearest flat point; `K,F,H,R`
    /// also sets the hole weight and reach, `K,F,H,R,C` the finer cover above which a coarser
    /// point is left out, 0 keeping every needed point) instead of reading the file's or
    /// building it by the default rule.
    #[arg(long, value_parser = parse_flat_rule)]
    pub flat_rule: Option<FlatRule>,
    /// For experiments: the exponent `p` of the flat weights' normal factor `(n . n_i)^p`, at
    /// least 2 (2: Eq. 8's own weights, as before this build), with which the flat basis is
    /// splatted and sharpened.
    #[arg(long, value_name = "P", default_value_t = FLAT_NORMAL_POWER,
          value_parser = parse_normal_power)]
    pub flat_normal_power: f32,
}

/// [`RelightArgs::fine_emission`].
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FineEmissionArg {
    /// The indirect light at every sender point, through the finer receivers' whole rows.
    Senders,
    /// The level-0 coefficients through the finer receivers' links to level-0 senders.
    Level0,
}

impl FineEmissionArg {
    /// The relighter's setting.
    pub fn emission(self) -> mlt_relight::FineEmission {
        match self {
            FineEmissionArg::Senders => mlt_relight::FineEmission::Senders,
            FineEmissionArg::Level0 => mlt_relight::FineEmission::Level0,
        }
    }
}

/// [`RelightArgs::feedback_lag`].
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FeedbackLag {
    /// On in the window where it saves work for the file, off elsewhere.
    Auto,
    /// Last frame's correction in every command.
    On,
    /// The exact step every frame, also in the window.
    Off,
}

impl FeedbackLag {
    /// Whether the feedback is lagged, in the window (`in_window`) or elsewhere, for a file
    /// and settings where lagging saves work (`pays`, [`mlt_relight::CpuRelighter::lag_pays`])
    /// or not.
    pub fn lagged(self, in_window: bool, pays: bool) -> bool {
        match self {
            FeedbackLag::Auto => in_window && pays,
            FeedbackLag::On => true,
            FeedbackLag::Off => false,
        }
    }
}

/// A finite power of at least 2 for [`RelightArgs::flat_normal_power`].
fn parse_normal_power(s: &str) -> Result<f32, String> {
    let p: f32 = s.trim().parse().map_err(|e| format!("{s}: {e}"))?;
    if !(p.is_finite() && p >= 2.0) {
        return Err(format!(
            "the power must be a finite number of at least 2, got {s}"
        ));
    }
    Ok(p)
}

/// `K,F[,H,R[,C]]` for [`RelightArgs::flat_rule`].
fn parse_flat_rule(s: &str) -> Result<FlatRule, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [k, f, rest @ ..] = parts.as_slice() else {
        return Err(format!("expected K,F (e.g. 4,1.35), got {s}"));
    };
    let k: u32 = k.parse().map_err(|e| format!("{k}: {e}"))?;
    let f: f32 = f.parse().map_err(|e| format!("{f}: {e}"))?;
    let max = mlt_format::flat_basis::MAX_NEIGHBOURS as u32;
    if !((1..=max).contains(&k) && f > 0.0 && f.is_finite()) {
        return Err(format!("K must be 1 to {max} and F positive, got {s}"));
    }
    let mut rule = FlatRule {
        neighbours: k,
        radius_factor: f,
        ..FlatRule::current()
    };
    let (holes, cover) = match rest {
        [] => (None, None),
        [h, r] => (Some((h, r)), None),
        [h, r, c] => (Some((h, r)), Some(c)),
        _ => return Err(format!("expected K,F or K,F,H,R or K,F,H,R,C, got {s}")),
    };
    if let Some((h, r)) = holes {
        rule.hole_weight = h.parse().map_err(|e| format!("{h}: {e}"))?;
        rule.hole_reach = r.parse().map_err(|e| format!("{r}: {e}"))?;
        if !(rule.hole_weight.is_finite() && rule.hole_reach > 0.0 && rule.hole_reach <= 1.0) {
            return Err(format!("H must be finite and R in (0, 1], got {s}"));
        }
    }
    if let Some(c) = cover {
        rule.finer_cover = c.parse().map_err(|e| format!("{c}: {e}"))?;
        if !(rule.finer_cover.is_finite() && rule.finer_cover >= 0.0) {
            return Err(format!("C must be finite and not negative, got {s}"));
        }
    }
    Ok(rule)
}

/// How the GPU renders.
#[derive(Args, Clone, Debug)]
pub struct GpuArgs {
    /// Where the fourth relighting stage, flattening, runs: `gpu` (a compute pass), `cpu`, or
    /// `auto`: the GPU unless the adapter is a software rasteriser (on llvmpipe the compute
    /// pass costs more of the same CPU than the CPU path).
    #[arg(long, value_enum, default_value_t = FlattenOn::Auto)]
    pub flatten: FlattenOn,
    /// Shadow-map resolution of the rendered direct light.
    #[arg(long, default_value_t = 1024)]
    pub shadow_res: u32,
}

/// Where flattening runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FlattenOn {
    Auto,
    Cpu,
    Gpu,
}

impl FlattenOn {
    /// `Some(true)` (GPU), `Some(false)` (CPU), or `None`: decided by the adapter.
    pub fn choice(self) -> Option<bool> {
        match self {
            FlattenOn::Gpu => Some(true),
            FlattenOn::Cpu => Some(false),
            FlattenOn::Auto => None,
        }
    }

    /// Whether flattening runs on `gpu`.
    pub fn on_gpu(self, gpu: &Gpu) -> bool {
        self.choice().unwrap_or(!gpu.is_software())
    }
}

/// Probe points in and irradiance out.
#[derive(Args, Clone, Debug)]
pub struct ProbeArgs {
    /// Probe points, rows x,y,z,nx,ny,nz.
    #[arg(long)]
    pub probe: PathBuf,
    /// Where to write the probes' irradiance.
    #[arg(long)]
    pub probe_out: PathBuf,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_automatic_lag_is_on_in_the_window_only_where_it_pays() {
        use FeedbackLag::*;
        let cases = [
            (Auto, [false, false, false, true]),
            (On, [true; 4]),
            (Off, [false; 4]),
        ];
        for (lag, want) in cases {
            let got = [(false, false), (false, true), (true, false), (true, true)]
                .map(|(window, pays)| lag.lagged(window, pays));
            assert_eq!(got, want, "{lag:?}");
        }
    }

    #[test]
    fn vectors_may_start_with_a_minus_sign() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            baked: BakedArgs,
        }
        let cli = Cli::try_parse_from([
            "view",
            "f.mlt",
            "--camera-pos",
            "-10,3,2",
            "--camera-target",
            "-1.5,-2,-0.25",
            "--light-pos",
            "-5,3,-2",
            "--light-dir",
            "-0,-1,0",
            "--cone-deg",
            "40",
        ])
        .unwrap();
        let s = &cli.baked.scene;
        assert_eq!(s.camera_pos, Some(Vec3::new(-10.0, 3.0, 2.0)));
        assert_eq!(s.camera_target, Some(Vec3::new(-1.5, -2.0, -0.25)));
        assert_eq!(s.light_pos, Some(Vec3::new(-5.0, 3.0, -2.0)));
        assert_eq!(s.light_dir, Some(Vec3::new(0.0, -1.0, 0.0)));
        // An option after a vector is still an option, and a malformed vector an error.
        assert!(Cli::try_parse_from(["view", "f.mlt", "--light-pos", "--json"]).is_err());
        assert!(Cli::try_parse_from(["view", "f.mlt", "--light-pos", "-5,3"]).is_err());
    }

    #[test]
    fn normal_powers_are_finite_and_at_least_two() {
        assert_eq!(parse_normal_power("12"), Ok(12.0));
        assert_eq!(parse_normal_power(" 2 "), Ok(2.0));
        for bad in ["1.5", "-3", "inf", "NaN", "twelve", ""] {
            assert!(parse_normal_power(bad).is_err(), "{bad} accepted");
        }
    }

    #[test]
    fn flat_rules_take_two_four_or_five_values() {
        let rule = parse_flat_rule("4,1.35").unwrap();
        assert_eq!((rule.neighbours, rule.radius_factor), (4, 1.35));
        assert_eq!(rule.finer_cover, FlatRule::current().finer_cover);
        let rule = parse_flat_rule("6, 1.2, 0.1, 0.5, 0").unwrap();
        assert_eq!(
            (rule.hole_weight, rule.hole_reach, rule.finer_cover),
            (0.1, 0.5, 0.0)
        );
        for bad in [
            "4",
            "0,1.35",
            "4,-1",
            "4,1.35,0.05",
            "4,1.35,0.05,1.5",
            "4,1.35,0.05,0.7,-1",
        ] {
            assert!(parse_flat_rule(bad).is_err(), "{bad} accepted");
        }
    }
}
