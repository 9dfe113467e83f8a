//! Options that several subcommands share: what to look at (scene, camera, light) and how to
//! relight and render it.

use std::path::PathBuf;

use clap::builder::TypedValueParser;
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

/// The heading of [`SceneArgs`] in the help.
const SCENE: &str = "Scene, camera and light";

/// The scene, camera and light, each defaulting to the file's (or the scene's).
#[derive(Args, Clone, Debug, Default)]
pub struct SceneArgs {
    /// The scene to draw and ray-cast (default: the one recorded in the file).
    #[arg(long, help_heading = SCENE)]
    pub scene: Option<String>,
    /// Camera position (default: the file's camera).
    #[arg(long, help_heading = SCENE, value_name = "X,Y,Z", value_parser = parse_vec3,
          allow_hyphen_values = true)]
    pub camera_pos: Option<Vec3>,
    /// The point the camera looks at.
    #[arg(long, help_heading = SCENE, value_name = "X,Y,Z", value_parser = parse_vec3,
          allow_hyphen_values = true)]
    pub camera_target: Option<Vec3>,
    /// The camera's up direction.
    #[arg(long, help_heading = SCENE, value_name = "X,Y,Z", value_parser = parse_vec3,
          allow_hyphen_values = true)]
    pub camera_up: Option<Vec3>,
    /// Vertical field of view in degrees.
    #[arg(long, help_heading = SCENE, value_name = "DEG")]
    pub fovy: Option<f32>,
    /// Image width in pixels (default: the camera's); the field of view is kept.
    #[arg(long, help_heading = SCENE, value_name = "PX")]
    pub width: Option<u32>,
    /// Image height in pixels (default: the camera's).
    #[arg(long, help_heading = SCENE, value_name = "PX")]
    pub height: Option<u32>,
    /// Light position (default: the file's light).
    #[arg(long, help_heading = SCENE, value_name = "X,Y,Z", value_parser = parse_vec3,
          allow_hyphen_values = true)]
    pub light_pos: Option<Vec3>,
    /// Light intensity per colour channel, in W/sr.
    #[arg(long, help_heading = SCENE, value_name = "R,G,B", value_parser = parse_vec3,
          allow_hyphen_values = true)]
    pub light_intensity: Option<Vec3>,
    /// Make the light a spot pointing this way (with --cone-deg).
    #[arg(long, help_heading = SCENE, value_name = "X,Y,Z", value_parser = parse_vec3,
          allow_hyphen_values = true, requires = "cone_deg")]
    pub light_dir: Option<Vec3>,
    /// The spot's full cone angle in degrees.
    #[arg(long, help_heading = SCENE, value_name = "DEG", requires = "light_dir")]
    pub cone_deg: Option<f32>,
    /// Smooth (glTF) spot falloff instead of a hard cone.
    #[arg(long, help_heading = SCENE)]
    pub smooth: bool,
}

/// How the CPU relights a frame (section 3.3).
#[derive(Args, Clone, Debug)]
pub struct RelightArgs {
    /// Shadow rays per sender point for the direct light.
    #[arg(long, value_name = "N", default_value_t = 8, hide = true)]
    pub shadow_rays: u32,
    /// Cast every shadow ray, not half first and the rest only in the penumbra.
    #[arg(long, hide = true)]
    pub all_shadow_rays: bool,
    /// Sample the direct light at the sender points only, also close to the light.
    #[arg(long, hide = true)]
    pub point_samples: bool,
    /// Skip the sharpening that takes back the flat basis' blur.
    #[arg(long, hide = true)]
    pub no_sharpen: bool,
    /// Relight every flat point each frame, not only those in view (same image, slower).
    #[arg(long, hide = true)]
    pub no_view_culling: bool,
    /// Sharpening steps, 1 to 16: more take back more of the flat basis' blur.
    #[arg(long, value_name = "N", default_value_t = mlt_relight::flatten_op::SHARPEN_STEPS,
          hide = true)]
    pub sharpen_steps: usize,
    /// Give the finer levels the first bounce only, as the paper (also no --bounce-feedback).
    #[arg(long, hide = true)]
    pub no_fine_bounces: bool,
    /// Feed the finer levels' bounce light back N times a frame, 0 to 16 (default 1 for
    /// --preset paper files, else 0).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=16),
          hide = true)]
    pub bounce_feedback: Option<u32>,
    /// Reuse last frame's bounce light while the light moves, to save time: auto (in the
    /// window), on, off.
    #[arg(long, value_enum, value_name = "auto|on|off", hide_possible_values = true,
          default_value_t = FeedbackLag::Auto, display_order = 900, hide = true)]
    pub feedback_lag: FeedbackLag,
    /// Where the finer levels' later bounces are emitted from: every sender point, or level 0.
    #[arg(long, value_enum, value_name = "senders|level0", hide_possible_values = true,
          default_value_t = FineEmissionArg::Senders, hide = true)]
    pub fine_emission: FineEmissionArg,
    /// Build the flat basis by this rule instead of the file's (for experiments).
    #[arg(long, value_name = "K,F[,H,R[,C]]", value_parser = parse_flat_rule, hide = true)]
    pub flat_rule: Option<FlatRule>,
    /// The exponent of the flat weights' normal factor, at least 2 (for experiments).
    #[arg(long, value_name = "P", default_value_t = FLAT_NORMAL_POWER,
          value_parser = parse_normal_power, hide = true)]
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
    /// Where the relighting runs: gpu, cpu, or auto (the GPU unless it is a software one).
    #[arg(long, value_enum, value_name = "auto|cpu|gpu", hide_possible_values = true,
          default_value_t = FlattenOn::Auto)]
    pub relight: FlattenOn,
    /// Where flattening runs: gpu, cpu, or auto (the GPU unless it is a software one).
    #[arg(long, value_enum, value_name = "auto|cpu|gpu", hide_possible_values = true,
          default_value_t = FlattenOn::Auto, hide = true)]
    pub flatten: FlattenOn,
    /// Bits of the floats the splats are summed in: 32, or 16 (less traffic, small error).
    #[arg(long, value_name = "16|32", default_value_t = 32,
          value_parser = clap::builder::PossibleValuesParser::new(["16", "32"]).map(|s| s.parse::<u32>().unwrap_or(32)))]
    pub splat_bits: u32,
    /// Shadow-map resolution of the direct light, in pixels.
    #[arg(long, value_name = "PX", default_value_t = 1024, hide = true)]
    pub shadow_res: u32,
}

/// Where flattening (`--flatten`) or the relighting (`--relight`) runs.
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

    /// Whether it runs on `gpu`.
    pub fn on_gpu(self, gpu: &Gpu) -> bool {
        self.choice().unwrap_or(!gpu.is_software())
    }
}

/// Probe points in and irradiance out.
#[derive(Args, Clone, Debug)]
pub struct ProbeArgs {
    /// Probe points: a CSV of rows x,y,z,nx,ny,nz.
    #[arg(long, value_name = "CSV")]
    pub probe: PathBuf,
    /// Where to write the probes' irradiance (CSV).
    #[arg(long, value_name = "CSV")]
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
