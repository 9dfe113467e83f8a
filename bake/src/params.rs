//! Bake parameters: one struct, [`BakeOptions`], that is at once the `bake` command line's
//! flags (clap), a scene manifest's `[bake]` table and a batch job's table (serde, unknown keys
//! refused), and what the bake resolves into its basis and transport parameters.
//!
//! The layers, highest first: the command line, the batch job, the manifest, the preset's
//! defaults. [`BakeOptions::or`] puts one layer over another; [`resolve`],
//! [`resolve_transport`] and [`bounce_policy`] fill in the defaults and check the values.
//!
//! A preset ([`Preset`]: `--preset NAME`, `preset = "NAME"`) is a set of defaults, not a
//! layer: the preset named by the highest layer that names one supplies the value of every
//! parameter that no layer sets, and an explicit value overrides it whichever layer it comes
//! from (a manifest's `bounces = 6` holds under `--preset paper`). The default preset,
//! [`Preset::Converged`], runs the Neumann series until it converges (`--bounces auto`, 1 %);
//! [`Preset::Paper`] is Table 1's 4 bounces. The two presets share every other default.
//!
//! A new parameter is one field of [`BakeOptions`] (its doc comment is the flag's help, its
//! name the flag `--name-with-dashes` and the table key `name_with_underscores`), one line of
//! [`BakeOptions::or`], and its use in the resolution below. The help is one short sentence in
//! a user's words (the longer story goes to docs/design.md, "Options explained"); a tuning or
//! diagnostic parameter is `hide = true`, listed by `bake --help-advanced` only.

use std::path::Path;

use mlt_format::meta::{BasisParams, TransportParams};
use serde::Deserialize;

use crate::error::BakeError;
use crate::placement::Coarse;
use crate::refine::{RefinePolicy, RefineRule};
use crate::transport::{BouncePolicy, DEFAULT_BOUNCE_TOLERANCE};

/// The paper's values (section 2.3): `R_fine = R_coarse / 2^l`, the disk radius factors
/// `C_coarse` and `C_fine` (Eq. 11), the dart thrower's miss limit and the harmonic mean
/// distance test (rays, range in radii, rejection threshold), the importance particles'
/// path length and the first bounces that deposit no candidate.
pub const DEFAULT_LEVELS: u32 = 6;
pub const DEFAULT_COARSE_COUNT: u32 = 339;
pub const C_COARSE: f32 = 1.5;
pub const C_FINE: f32 = 2.5;
pub const MAX_MISSES: u32 = 2000;
pub const HMD_RAYS: u32 = 16;
pub const HMD_RANGE: f32 = 3.0;
pub const HMD_REJECT: f32 = 1.0 / 6.0;
pub const PARTICLE_BOUNCES: u32 = 30;
pub const SKIPPED_BOUNCES: u32 = 3;
pub const DEFAULT_EPSILON: f32 = 0.025;
pub const DEFAULT_SENDER_LEVELS: u32 = 3;
/// The paper's bounce count (Table 1: four bounces), the fixed count of [`Preset::Paper`].
pub const PAPER_BOUNCES: u32 = 4;
/// The cap of `--bounces auto` when none is given: enough for a spectral radius of 0.995 at
/// the default 1 % tolerance (0.995^919 < 0.01).
pub const DEFAULT_AUTO_BOUNCE_CAP: u32 = 1000;
/// Rays per receiver gather (the paper does not say; the tech report's radiosity used 512).
pub const DEFAULT_GATHER_RAYS: u32 = 256;
/// More levels than this would need more than 2^(2*16) points per coarse point.
pub const MAX_LEVELS: u32 = 16;

/// A named set of defaults for the parameters no layer sets (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// The series runs until the bounces left out carry under 1 % of the indirect light
    /// (`--bounces auto`, capped at [`DEFAULT_AUTO_BOUNCE_CAP`]), and the coarsest
    /// receivers' later bounces are traced as paths ([`DEFAULT_LEVEL0_PATHS`]); the paper's
    /// other values.
    #[default]
    Converged,
    /// The paper's Table 1: 4 bounces, 6 levels, epsilon 0.025, 3 sender levels; level 0 of
    /// about 339 points (the paper's Sponza) and 256 gather rays (ours: the paper gives
    /// neither a count for other scenes nor a ray count).
    Paper,
}

/// Paths per level-0 receiver that trace its later bounces under [`Preset::Converged`]
/// (`path_bounces`): the paths' noise is under the references' at a thousand.
pub const DEFAULT_LEVEL0_PATHS: u32 = 1024;

impl Preset {
    /// Paths per level-0 receiver for its later bounces when no layer sets `level0_paths`:
    /// traced by default, chained through the coarsest senders (0) as the paper does.
    pub fn level0_paths(self) -> u32 {
        match self {
            Preset::Converged => DEFAULT_LEVEL0_PATHS,
            Preset::Paper => 0,
        }
    }

    /// The bounce choice of this preset when no layer makes one.
    pub fn bounce_choice(self) -> BounceChoice {
        match self {
            Preset::Converged => BounceChoice {
                auto: true,
                count: None,
            },
            Preset::Paper => BounceChoice {
                auto: false,
                count: Some(PAPER_BOUNCES),
            },
        }
    }
}

/// The bake's parameters as asked for; `None` (or `false`) means "the next layer's value, else
/// the preset's". The doc comments are the command line's help.
#[derive(Clone, Debug, Default, PartialEq, clap::Args, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BakeOptions {
    /// Defaults to start from: converged (bounce the light until it converges; the default) or
    /// paper (the paper's Table 1).
    #[arg(long, value_enum, value_name = "NAME", hide_possible_values = true)]
    pub preset: Option<Preset>,
    /// Levels of the hierarchy, coarse to fine (default 6, the paper's).
    #[arg(long, value_name = "N")]
    pub receiver_levels: Option<u32>,
    /// About this many points on the coarsest level (default 339, the paper's Sponza).
    #[arg(long, value_name = "K", conflicts_with = "coarse_radius")]
    pub coarse_count: Option<u32>,
    /// The coarsest level's point spacing in scene units, instead of --coarse-count.
    #[arg(long, value_name = "R", hide = true)]
    pub coarse_radius: Option<f32>,
    /// Random seed: the same seed and inputs give a byte-identical file.
    #[arg(long, value_name = "S")]
    pub seed: Option<u64>,
    /// Link threshold (default 0.025): smaller keeps more links, for a more accurate image, a
    /// bigger file and slower frames.
    #[arg(long, value_name = "E")]
    pub epsilon: Option<f32>,
    /// Link threshold of bounces 2 and later (default: --epsilon).
    #[arg(long, value_name = "E", hide = true)]
    pub bounce_epsilon: Option<f32>,
    /// Levels that send light: the coarsest N of the receiver levels (default 3, the paper's).
    #[arg(long, value_name = "N", hide = true)]
    pub sender_levels: Option<u32>,
    /// Bounces of the Neumann series (paper: 4); with `auto_bounces`, the cap. On the
    /// command line it is `--bounces N` or `--bounces auto:N` ([`BakeOptions::bounce_flag`]).
    #[arg(skip)]
    pub bounces: Option<u32>,
    /// Choose the number of bounces from the spectral-radius estimate so that the series
    /// leaves out at most `bounce_tolerance` of the indirect light (capped by `bounces`,
    /// default [`DEFAULT_AUTO_BOUNCE_CAP`]; a lower layer's count is then ignored).
    #[arg(skip)]
    #[serde(default)]
    pub auto_bounces: bool,
    /// Light bounces: a count, or auto (the default) to bounce until the light converges,
    /// auto:N at most N times.
    #[arg(long = "bounces", value_name = "N|auto|auto:N", value_parser = parse_bounces)]
    #[serde(skip)]
    pub bounce_flag: Option<BounceChoice>,
    /// Share of the indirect light that --bounces auto may leave out (default 0.01).
    #[arg(long, value_name = "F", hide = true)]
    pub bounce_tolerance: Option<f64>,
    /// Rays per receiver point when gathering its links (default 256).
    #[arg(long, value_name = "N", hide = true)]
    pub gather_rays: Option<u32>,
    /// Compute bounces 2 and later on every receiver, not only the coarsest (slower).
    #[arg(long, hide = true)]
    #[serde(default)]
    pub bounces_on_all_receivers: bool,
    /// Paths per coarsest receiver that trace its later bounces (default 1024; 0 chains them, as
    /// the paper).
    #[arg(long, value_name = "N", hide = true)]
    pub level0_paths: Option<u32>,
    /// Place the basis points only; compute no light transport.
    #[arg(long, hide = true)]
    #[serde(default)]
    pub basis_only: bool,
    /// Misses in a row after which a level's point placement stops (default 2000, the paper's).
    #[arg(long, value_name = "N", hide = true)]
    pub max_misses: Option<u32>,
    /// Bake share I of N (I from 0) of the light transport into a shard file for `bake merge`.
    #[arg(long, value_name = "I/N", value_parser = parse_shard)]
    #[serde(skip)]
    pub shard: Option<(u32, u32)>,
    /// Store wall-clock timings in the file (it then differs from run to run).
    #[arg(long, hide = true)]
    #[serde(skip)]
    pub record_timings: bool,
    /// Compress the file with zstd: smaller, but read into memory instead of mapped.
    #[arg(long)]
    #[serde(skip)]
    pub compress: bool,
    /// Diagnostic: turn refinement rules off, for ablations (rules: docs/design.md)
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        value_name = "RULE,...",
        hide = true,
        hide_possible_values = true
    )]
    #[serde(default)]
    pub refine_off: Vec<RefineRule>,
    /// Diagnostic: leave the supports unclipped at occluders (light then leaks
    /// under thin walls; docs/design.md)
    #[arg(long, hide = true)]
    #[serde(default)]
    pub no_support_clip: bool,
}

/// The rules either layer turns off, sorted and once each (like flags, on when either sets them).
fn refine_off_union(a: &[RefineRule], b: &[RefineRule]) -> Vec<RefineRule> {
    let mut rules: Vec<RefineRule> = a.iter().chain(b).copied().collect();
    rules.sort_unstable();
    rules.dedup();
    rules
}

/// A choice of bounce count: `N` (`auto: false, count: Some(N)`), `auto` or `auto:N`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BounceChoice {
    pub auto: bool,
    pub count: Option<u32>,
}

impl BakeOptions {
    /// These options over `lower`: each value set here wins, the others come from `lower`.
    /// Flags are on when either layer sets them. The bounce choice (count and `auto`) and the
    /// coarse level's size (count or radius) each come whole from one layer, so that
    /// `--bounces auto` does not take a manifest's fixed count as its cap, nor a coarse radius
    /// meet a lower layer's coarse count.
    pub fn or(&self, lower: &BakeOptions) -> BakeOptions {
        let bounce = self.bounce_choice().or(lower.bounce_choice());
        let coarse_set = self.coarse_count.is_some() || self.coarse_radius.is_some();
        let coarse = if coarse_set { self } else { lower };
        BakeOptions {
            preset: self.preset.or(lower.preset),
            receiver_levels: self.receiver_levels.or(lower.receiver_levels),
            coarse_count: coarse.coarse_count,
            coarse_radius: coarse.coarse_radius,
            seed: self.seed.or(lower.seed),
            epsilon: self.epsilon.or(lower.epsilon),
            bounce_epsilon: self.bounce_epsilon.or(lower.bounce_epsilon),
            sender_levels: self.sender_levels.or(lower.sender_levels),
            bounces: bounce.and_then(|b| b.count),
            auto_bounces: bounce.is_some_and(|b| b.auto),
            bounce_flag: None,
            bounce_tolerance: self.bounce_tolerance.or(lower.bounce_tolerance),
            gather_rays: self.gather_rays.or(lower.gather_rays),
            bounces_on_all_receivers: self.bounces_on_all_receivers
                || lower.bounces_on_all_receivers,
            level0_paths: self.level0_paths.or(lower.level0_paths),
            basis_only: self.basis_only || lower.basis_only,
            max_misses: self.max_misses.or(lower.max_misses),
            shard: self.shard.or(lower.shard),
            record_timings: self.record_timings || lower.record_timings,
            compress: self.compress || lower.compress,
            refine_off: refine_off_union(&self.refine_off, &lower.refine_off),
            no_support_clip: self.no_support_clip || lower.no_support_clip,
        }
    }

    /// The refinement policy these options ask for: the default with `refine_off`'s rules off.
    pub fn refine_policy(&self) -> RefinePolicy {
        RefinePolicy::without(&self.refine_off)
    }

    /// The bounce choice of this layer, if it makes one: the command line's `--bounces`, else
    /// the `auto_bounces` and `bounces` fields. [`BakeOptions::resolved_bounces`] falls back
    /// on the preset's.
    pub fn bounce_choice(&self) -> Option<BounceChoice> {
        if self.bounce_flag.is_some() {
            return self.bounce_flag;
        }
        (self.auto_bounces || self.bounces.is_some()).then_some(BounceChoice {
            auto: self.auto_bounces,
            count: self.bounces,
        })
    }

    /// The bounce choice in effect: this layer's, else its preset's.
    pub fn resolved_bounces(&self) -> BounceChoice {
        self.bounce_choice()
            .unwrap_or_else(|| self.preset.unwrap_or_default().bounce_choice())
    }

    /// Parses a manifest's `[bake]` table or a batch job's table (`what` names it in errors,
    /// `path` is its file). Unknown keys and ill-typed values are errors naming both.
    pub fn from_table(table: toml::Table, path: &Path, what: &str) -> Result<Self, BakeError> {
        let bad = |message: String| BakeError::Options {
            path: path.to_path_buf(),
            message: format!("{what}: {message}"),
        };
        let opts: BakeOptions = table
            .try_into()
            .map_err(|e: toml::de::Error| bad(e.to_string().trim_end().to_string()))?;
        if opts.coarse_count.is_some() && opts.coarse_radius.is_some() {
            return Err(bad("sets both coarse_count and coarse_radius".into()));
        }
        Ok(opts)
    }
}

/// The options of a scene's manifest (its `[bake]` table; none for other scenes).
pub fn manifest_options(scene: &mlt_scenes::Scene) -> Result<BakeOptions, BakeError> {
    if scene.bake.is_empty() {
        return Ok(BakeOptions::default());
    }
    BakeOptions::from_table(scene.bake.clone(), Path::new(&scene.source), "[bake]")
}

/// `--bounces`: a count or `auto[:cap]`.
pub fn parse_bounces(s: &str) -> Result<BounceChoice, String> {
    let s = s.trim();
    let count = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{t}' is not a bounce count (a whole number >= 1)"))
    };
    match s.strip_prefix("auto") {
        Some("") => Ok(BounceChoice {
            auto: true,
            count: None,
        }),
        Some(rest) => match rest.strip_prefix(':') {
            Some(cap) => Ok(BounceChoice {
                auto: true,
                count: Some(count(cap)?),
            }),
            None => Err(format!("'{s}' is not N, auto or auto:N")),
        },
        None => Ok(BounceChoice {
            auto: false,
            count: Some(count(s)?),
        }),
    }
}

/// `--shard I/N` with `0 <= I < N`.
pub fn parse_shard(s: &str) -> Result<(u32, u32), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("'{s}' is not I/N"))?;
    let i: u32 = i
        .trim()
        .parse()
        .map_err(|_| format!("'{i}' is not a shard index"))?;
    let n: u32 = n
        .trim()
        .parse()
        .map_err(|_| format!("'{n}' is not a shard count"))?;
    if n == 0 || i >= n {
        return Err(format!("shard {i}/{n}: need 0 <= I < N"));
    }
    Ok((i, n))
}

/// Resolves the basis parameters (the options over the defaults), checking each.
pub fn resolve(opts: &BakeOptions) -> Result<(BasisParams, Coarse), BakeError> {
    let bad = |m: String| Err(BakeError::InvalidParameter(m));
    let levels = opts.receiver_levels.unwrap_or(DEFAULT_LEVELS);
    if !(1..=MAX_LEVELS).contains(&levels) {
        return bad(format!(
            "receiver levels must be 1..={MAX_LEVELS}, got {levels}"
        ));
    }
    let coarse = match (opts.coarse_count, opts.coarse_radius) {
        (Some(_), Some(_)) => return bad("give a coarse count or a coarse radius, not both".into()),
        (Some(k), None) => Coarse::Count(k),
        (None, Some(r)) => Coarse::Radius(r),
        (None, None) => Coarse::Count(DEFAULT_COARSE_COUNT),
    };
    match coarse {
        Coarse::Count(0) => return bad("the coarse count must be at least 1".into()),
        Coarse::Radius(r) if !(r.is_finite() && r > 0.0) => {
            return bad(format!(
                "the coarse radius must be positive and finite, got {r}"
            ))
        }
        _ => {}
    }
    let max_misses = opts.max_misses.unwrap_or(MAX_MISSES);
    if max_misses == 0 {
        return bad("the miss limit must be at least 1".into());
    }
    Ok((
        BasisParams {
            levels,
            coarse_radius: match coarse {
                Coarse::Radius(r) => r,
                Coarse::Count(_) => 0.0,
            },
            coarse_count_target: match coarse {
                Coarse::Count(k) => Some(k),
                Coarse::Radius(_) => None,
            },
            f_squash: mlt_format::kernel::F_SQUASH,
            c_coarse: C_COARSE,
            c_fine: C_FINE,
            max_misses,
            hmd_rays: HMD_RAYS,
            hmd_range: HMD_RANGE,
            hmd_reject: HMD_REJECT,
            particle_bounces: PARTICLE_BOUNCES,
            skipped_bounces: SKIPPED_BOUNCES,
            seed: opts.seed.unwrap_or(1),
        },
        coarse,
    ))
}

/// Resolves the transport parameters (the options over the paper's defaults).
pub fn resolve_transport(opts: &BakeOptions, basis: &BasisParams) -> TransportParams {
    let epsilon = opts.epsilon.unwrap_or(DEFAULT_EPSILON);
    let bounce = opts.resolved_bounces();
    TransportParams {
        epsilon,
        bounce_epsilon: opts.bounce_epsilon.unwrap_or(epsilon),
        sender_levels: opts
            .sender_levels
            .unwrap_or(DEFAULT_SENDER_LEVELS.min(basis.levels)),
        receiver_levels: basis.levels,
        bounces: match bounce {
            BounceChoice { auto: true, count } => count.unwrap_or(DEFAULT_AUTO_BOUNCE_CAP),
            BounceChoice { auto: false, count } => count.unwrap_or(PAPER_BOUNCES),
        },
        gather_rays: opts.gather_rays.unwrap_or(DEFAULT_GATHER_RAYS),
        bounces_on_all_receivers: opts.bounces_on_all_receivers,
        seed: basis.seed,
    }
}

/// The bounce policy asked for, checked.
pub fn bounce_policy(opts: &BakeOptions) -> Result<BouncePolicy, BakeError> {
    let tolerance = opts.bounce_tolerance.unwrap_or(DEFAULT_BOUNCE_TOLERANCE);
    if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 1.0) {
        return Err(BakeError::InvalidParameter(format!(
            "the bounce tolerance must be a fraction in (0, 1), got {tolerance}"
        )));
    }
    // `--bounces-on-all-receivers` chains every receiver's bounces, so it takes the place of
    // the preset's traced ones; an explicit count with it is a contradiction.
    let level0_paths = match opts.level0_paths {
        Some(n) => n,
        None if opts.bounces_on_all_receivers => 0,
        None => opts.preset.unwrap_or_default().level0_paths(),
    };
    if level0_paths > 0 && opts.bounces_on_all_receivers {
        return Err(BakeError::InvalidParameter(format!(
            "--level0-paths {level0_paths} traces the coarsest receivers' bounces, which \
             --bounces-on-all-receivers chains through every receiver instead; give one"
        )));
    }
    Ok(BouncePolicy {
        auto: opts.resolved_bounces().auto,
        tolerance,
        level0_paths,
    })
}

/// How a bake's resolved parameters differ from [`Preset::Paper`]'s, one `name ours (paper:
/// value)` per parameter; empty for a bake made at the paper's settings. `bounce_mode` is the
/// transport report's (`fixed` or `auto`; `None` where the file has no report),
/// `level0_paths` the paths per level-0 receiver of its later bounces (0 where chained).
pub fn paper_preset_differences(
    basis: &BasisParams,
    transport: Option<&TransportParams>,
    bounce_mode: Option<&str>,
    level0_paths: u32,
) -> Vec<String> {
    let mut out = Vec::new();
    let mut check = |name: &str, ours: String, paper: String| {
        if ours != paper {
            out.push(format!("{name} {ours} (paper: {paper})"));
        }
    };
    check(
        "levels",
        basis.levels.to_string(),
        DEFAULT_LEVELS.to_string(),
    );
    check(
        "coarse count",
        format!("{:?}", basis.coarse_count_target),
        format!("{:?}", Some(DEFAULT_COARSE_COUNT)),
    );
    check(
        "max misses",
        basis.max_misses.to_string(),
        MAX_MISSES.to_string(),
    );
    let Some(t) = transport else {
        out.push("no transport operator (basis only)".into());
        return out;
    };
    if let Some(mode) = bounce_mode {
        check("bounce mode", mode.to_string(), "fixed".into());
    }
    check("bounces", t.bounces.to_string(), PAPER_BOUNCES.to_string());
    check(
        "epsilon",
        t.epsilon.to_string(),
        DEFAULT_EPSILON.to_string(),
    );
    check(
        "bounce epsilon",
        t.bounce_epsilon.to_string(),
        DEFAULT_EPSILON.to_string(),
    );
    check(
        "sender levels",
        t.sender_levels.to_string(),
        DEFAULT_SENDER_LEVELS.to_string(),
    );
    check(
        "gather rays",
        t.gather_rays.to_string(),
        DEFAULT_GATHER_RAYS.to_string(),
    );
    check(
        "bounces on all receivers",
        t.bounces_on_all_receivers.to_string(),
        "false".into(),
    );
    let chained = |n: u32| match n {
        0 => "0 (chained)".to_string(),
        n => n.to_string(),
    };
    check("level-0 paths", chained(level0_paths), chained(0));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    /// The options as the `bake` command flattens them.
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        opts: BakeOptions,
    }

    fn cli(args: &[&str]) -> BakeOptions {
        let mut all = vec!["bake"];
        all.extend_from_slice(args);
        Cli::try_parse_from(all).unwrap().opts
    }

    fn table(text: &str) -> Result<BakeOptions, BakeError> {
        BakeOptions::from_table(toml::from_str(text).unwrap(), Path::new("m.toml"), "[bake]")
    }

    #[test]
    fn command_line_overrides_job_overrides_manifest_overrides_defaults() {
        let manifest = table(
            "receiver_levels = 4\ncoarse_radius = 0.5\nseed = 7\nepsilon = 0.1\nbounces = 6\n",
        )
        .unwrap();
        let job = table("receiver_levels = 3\nseed = 8\nauto_bounces = true\n").unwrap();
        let command = cli(&["--receiver-levels", "2", "--coarse-count", "10"]);
        let opts = command.or(&job).or(&manifest);
        let (p, c) = resolve(&opts).unwrap();
        let t = resolve_transport(&opts, &p);
        // Command line: levels and the coarse count (which displaces the manifest's radius).
        assert_eq!((p.levels, c), (2, Coarse::Count(10)));
        // Job: the seed, and `auto` without a cap (the manifest's count is not the cap).
        assert_eq!(p.seed, 8);
        assert_eq!(t.bounces, DEFAULT_AUTO_BOUNCE_CAP);
        assert!(bounce_policy(&opts).unwrap().auto);
        // Manifest: epsilon; defaults for the rest.
        assert_eq!(t.epsilon, 0.1);
        assert_eq!(t.gather_rays, DEFAULT_GATHER_RAYS);
        assert_eq!(t.sender_levels, 2);

        let (p, c) = resolve(&BakeOptions::default().or(&manifest)).unwrap();
        assert_eq!((p.levels, c, p.seed), (4, Coarse::Radius(0.5), 7));
        let (p, c) = resolve(&BakeOptions::default()).unwrap();
        assert_eq!((p.levels, c, p.seed), (6, Coarse::Count(339), 1));
        // A fixed count on the command line turns a lower layer's `auto` off.
        let fixed = cli(&["--bounces", "5"]).or(&job);
        assert_eq!(resolve_transport(&fixed, &p).bounces, 5);
        assert!(!bounce_policy(&fixed).unwrap().auto);
    }

    #[test]
    fn the_preset_fills_only_what_no_layer_sets() {
        let (p, _) = resolve(&BakeOptions::default()).unwrap();
        // No preset: the series runs to convergence.
        let none = BakeOptions::default();
        assert!(bounce_policy(&none).unwrap().auto);
        assert_eq!(
            resolve_transport(&none, &p).bounces,
            DEFAULT_AUTO_BOUNCE_CAP
        );
        // The paper's preset, from any layer: the fixed 4.
        let paper_manifest = table("preset = \"paper\"").unwrap();
        let paper_cli = cli(&["--preset", "paper"]);
        for opts in [
            paper_cli.or(&none),
            none.or(&paper_manifest),
            none.or(&paper_manifest).or(&none),
        ] {
            assert!(!bounce_policy(&opts).unwrap().auto);
            let t = resolve_transport(&opts, &p);
            assert_eq!((t.bounces, t.epsilon), (PAPER_BOUNCES, DEFAULT_EPSILON));
        }
        // An explicit value of a lower layer overrides a higher layer's preset...
        let manifest = table("bounces = 6\nepsilon = 0.1").unwrap();
        let opts = paper_cli.or(&manifest);
        let t = resolve_transport(&opts, &p);
        assert_eq!((t.bounces, t.epsilon), (6, 0.1));
        assert!(!bounce_policy(&opts).unwrap().auto);
        let opts = paper_cli.or(&table("auto_bounces = true").unwrap());
        assert!(bounce_policy(&opts).unwrap().auto);
        // ... and the highest layer's preset wins over a lower one's.
        let opts = cli(&["--preset", "converged"]).or(&paper_manifest);
        assert!(bounce_policy(&opts).unwrap().auto);
        let job = table("preset = \"paper\"\nbounces = 3").unwrap();
        let opts = BakeOptions::default()
            .or(&job)
            .or(&table("preset = \"converged\"").unwrap());
        assert_eq!(opts.preset, Some(Preset::Paper));
        assert_eq!(resolve_transport(&opts, &p).bounces, 3);
        assert!(table("preset = \"fast\"").is_err());
    }

    #[test]
    fn paper_differences_name_each_parameter_off_the_paper() {
        let paper = cli(&["--preset", "paper"]);
        let (p, _) = resolve(&paper).unwrap();
        let t = resolve_transport(&paper, &p);
        let paths = |o: &BakeOptions| bounce_policy(o).unwrap().level0_paths;
        assert_eq!(paths(&paper), 0);
        assert!(paper_preset_differences(&p, Some(&t), Some("fixed"), 0).is_empty());
        let default = BakeOptions::default();
        let (pd, _) = resolve(&default).unwrap();
        let td = resolve_transport(&default, &pd);
        assert_eq!(paths(&default), DEFAULT_LEVEL0_PATHS);
        let d = paper_preset_differences(&pd, Some(&td), Some("auto"), paths(&default));
        assert_eq!(d.len(), 3, "{d:?}");
        assert!(d[0].starts_with("bounce mode auto") && d[1].starts_with("bounces 1000"));
        assert_eq!(d[2], "level-0 paths 1024 (paper: 0 (chained))");
        // An explicit count wins over the preset; the bounces of every receiver replace the
        // preset's paths and contradict an explicit count.
        assert_eq!(
            paths(&cli(&["--preset", "paper", "--level0-paths", "64"])),
            64
        );
        assert_eq!(paths(&cli(&["--bounces-on-all-receivers"])), 0);
        assert!(
            bounce_policy(&cli(&["--bounces-on-all-receivers", "--level0-paths", "8"])).is_err()
        );
        let small = cli(&[
            "--preset",
            "paper",
            "--receiver-levels",
            "4",
            "--gather-rays",
            "8",
        ]);
        let (ps, _) = resolve(&small).unwrap();
        let ts = resolve_transport(&small, &ps);
        let d = paper_preset_differences(&ps, Some(&ts), None, 0);
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d[0].starts_with("levels 4") && d[1].starts_with("gather rays 8"));
        assert_eq!(paper_preset_differences(&p, None, None, 0).len(), 1);
    }

    #[test]
    fn every_flag_parses() {
        let o = cli(&[
            "--preset=paper",
            "--receiver-levels=3",
            "--coarse-radius=0.25",
            "--seed=9",
            "--epsilon=0.01",
            "--bounce-epsilon=0.001",
            "--sender-levels=2",
            "--bounces=auto:12",
            "--bounce-tolerance=0.05",
            "--gather-rays=64",
            "--bounces-on-all-receivers",
            "--basis-only",
            "--max-misses=100",
            "--shard=1/3",
            "--record-timings",
            "--compress",
        ])
        .or(&BakeOptions::default());
        let expected = BakeOptions {
            preset: Some(Preset::Paper),
            receiver_levels: Some(3),
            coarse_radius: Some(0.25),
            seed: Some(9),
            epsilon: Some(0.01),
            bounce_epsilon: Some(0.001),
            sender_levels: Some(2),
            bounces: Some(12),
            auto_bounces: true,
            bounce_tolerance: Some(0.05),
            gather_rays: Some(64),
            bounces_on_all_receivers: true,
            basis_only: true,
            max_misses: Some(100),
            shard: Some((1, 3)),
            record_timings: true,
            compress: true,
            ..Default::default()
        };
        assert_eq!(o, expected);
        assert_eq!(cli(&["--coarse-count", "5"]).coarse_count, Some(5));
        for (arg, auto, count) in [("7", false, Some(7)), ("auto", true, None)] {
            let o = cli(&["--bounces", arg]).or(&BakeOptions::default());
            assert_eq!((o.auto_bounces, o.bounces), (auto, count), "{arg}");
        }
        for bad in [
            &["--bounces", "auto:x"][..],
            &["--shard", "3/3"],
            &["--coarse-count", "5", "--coarse-radius", "1"],
            &["--output", "x"],
        ] {
            assert!(
                Cli::try_parse_from(["bake"].iter().chain(bad)).is_err(),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn tables_take_every_key_and_refuse_unknown_ones_naming_the_file() {
        let o = table(
            "preset = \"converged\"\nreceiver_levels = 3\nsender_levels = 2\ncoarse_count = 30\nseed = 4\nepsilon = 0.001\n\
             bounce_epsilon = 0.0001\nbounces = 24\nauto_bounces = true\nbounce_tolerance = 0.02\n\
             gather_rays = 128\nmax_misses = 50\nbounces_on_all_receivers = true\nbasis_only = true\n",
        )
        .unwrap();
        assert_eq!(
            (o.bounces, o.auto_bounces, o.coarse_count, o.basis_only),
            (Some(24), true, Some(30), true)
        );
        for (text, needle) in [
            ("receiver_level = 3", "receiver_level"),
            ("shard = [0, 2]", "shard"),
            ("compress = true", "compress"),
            ("bounces = \"many\"", "bounces"),
            ("coarse_count = 3\ncoarse_radius = 1.0", "coarse_radius"),
        ] {
            let e = table(text).unwrap_err().to_string();
            assert!(e.contains("m.toml") && e.contains(needle), "{text}: {e}");
        }
    }

    #[test]
    fn bad_values_are_refused_with_a_reason() {
        for opts in [
            BakeOptions {
                receiver_levels: Some(0),
                ..Default::default()
            },
            BakeOptions {
                receiver_levels: Some(40),
                ..Default::default()
            },
            BakeOptions {
                coarse_count: Some(0),
                ..Default::default()
            },
            BakeOptions {
                coarse_radius: Some(f32::NAN),
                ..Default::default()
            },
            BakeOptions {
                coarse_radius: Some(-1.0),
                ..Default::default()
            },
            BakeOptions {
                coarse_radius: Some(1.0),
                coarse_count: Some(3),
                ..Default::default()
            },
        ] {
            let e = resolve(&opts).unwrap_err();
            assert!(!e.to_string().is_empty());
        }
    }
}
