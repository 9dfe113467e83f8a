//! Bake parameters: the paper's defaults, overridden by a manifest's `[bake]` table, overridden
//! by the command line.

use mlt_format::meta::{BasisParams, TransportParams};
use mlt_scenes::BakeSettings;

use crate::error::BakeError;
use crate::placement::Coarse;
use crate::transport::{BouncePolicy, DEFAULT_BOUNCE_TOLERANCE};

/// The paper's values (section 2.3, DESIGN.md).
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
pub const DEFAULT_BOUNCES: u32 = 4;
/// The cap of `--bounces auto` when none is given: enough for a spectral radius of 0.995 at
/// the default 1 % tolerance (0.995^919 < 0.01).
pub const DEFAULT_AUTO_BOUNCE_CAP: u32 = 1000;
/// Rays per receiver gather (the paper does not say; the tech report's radiosity used 512).
pub const DEFAULT_GATHER_RAYS: u32 = 256;
/// More levels than this would need more than 2^(2*16) points per coarse point.
pub const MAX_LEVELS: u32 = 16;

/// What the user asked for; `None` means "the manifest's value, else the default".
#[derive(Clone, Debug, Default)]
pub struct BakeOptions {
    pub receiver_levels: Option<u32>,
    pub coarse_count: Option<u32>,
    pub coarse_radius: Option<f32>,
    pub seed: Option<u64>,
    /// Override the dart thrower's consecutive-miss limit (paper: 2000).
    pub max_misses: Option<u32>,
    /// Link threshold epsilon (paper: 0.025).
    pub epsilon: Option<f32>,
    /// Truncation threshold of bounces 2 and later (default: epsilon, as the paper).
    pub bounce_epsilon: Option<f32>,
    /// Sender levels (paper: 3; at most the receiver levels).
    pub sender_levels: Option<u32>,
    /// Most bounces of the Neumann series (paper: 4); with `auto_bounces`, the cap.
    pub bounces: Option<u32>,
    /// Choose the number of bounces from the spectral-radius estimate so that the series
    /// leaves out at most `bounce_tolerance` of the indirect light (capped by `bounces`,
    /// default [`DEFAULT_AUTO_BOUNCE_CAP`]; the manifest's count is then ignored).
    pub auto_bounces: bool,
    /// Fraction of the indirect light the series may leave out (default 1 %): the target of
    /// `auto_bounces`, the warning threshold of a fixed count.
    pub bounce_tolerance: Option<f64>,
    /// Rays per receiver gather.
    pub gather_rays: Option<u32>,
    /// Bounces 2 and later on every refined receiver, not only the coarsest.
    pub bounces_on_all_receivers: bool,
    /// Place the basis only; compute no transport operator.
    pub basis_only: bool,
    /// Compute only shard `(index, count)` of T (a shard file for `bake merge`).
    pub shard: Option<(u32, u32)>,
    /// Store wall-clock timings in the file (makes it differ from run to run).
    pub record_timings: bool,
    /// zstd-compress the file's sections.
    pub compress: bool,
}

/// Resolves the parameters, checking each.
pub fn resolve(
    opts: &BakeOptions,
    scene: &BakeSettings,
) -> Result<(BasisParams, Coarse), BakeError> {
    let bad = |m: String| Err(BakeError::InvalidParameter(m));
    let levels = opts
        .receiver_levels
        .or(scene.receiver_levels)
        .unwrap_or(DEFAULT_LEVELS);
    if !(1..=MAX_LEVELS).contains(&levels) {
        return bad(format!(
            "receiver levels must be 1..={MAX_LEVELS}, got {levels}"
        ));
    }
    // The command line's choice of count or radius wins over the manifest's.
    let coarse = match (opts.coarse_count, opts.coarse_radius) {
        (Some(_), Some(_)) => return bad("give a coarse count or a coarse radius, not both".into()),
        (Some(k), None) => Coarse::Count(k),
        (None, Some(r)) => Coarse::Radius(r),
        (None, None) => match (scene.coarse_count, scene.coarse_radius) {
            (Some(_), Some(_)) => {
                return bad("the manifest sets both coarse_count and coarse_radius".into())
            }
            (Some(k), None) => Coarse::Count(k),
            (None, Some(r)) => Coarse::Radius(r),
            (None, None) => Coarse::Count(DEFAULT_COARSE_COUNT),
        },
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
            seed: opts.seed.or(scene.seed).unwrap_or(1),
        },
        coarse,
    ))
}

/// Resolves the transport parameters (command line, else manifest, else the paper's).
pub fn resolve_transport(
    opts: &BakeOptions,
    scene: &BakeSettings,
    basis: &BasisParams,
) -> TransportParams {
    let epsilon = opts.epsilon.or(scene.epsilon).unwrap_or(DEFAULT_EPSILON);
    TransportParams {
        epsilon,
        bounce_epsilon: opts.bounce_epsilon.unwrap_or(epsilon),
        sender_levels: opts
            .sender_levels
            .or(scene.sender_levels)
            .unwrap_or(DEFAULT_SENDER_LEVELS.min(basis.levels)),
        receiver_levels: basis.levels,
        bounces: if opts.auto_bounces {
            opts.bounces.unwrap_or(DEFAULT_AUTO_BOUNCE_CAP)
        } else {
            opts.bounces.or(scene.bounces).unwrap_or(DEFAULT_BOUNCES)
        },
        gather_rays: opts
            .gather_rays
            .or(scene.gather_rays)
            .unwrap_or(DEFAULT_GATHER_RAYS),
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
    Ok(BouncePolicy {
        auto: opts.auto_bounces,
        tolerance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_line_overrides_manifest_overrides_defaults() {
        let scene = BakeSettings {
            receiver_levels: Some(4),
            coarse_radius: Some(0.5),
            ..Default::default()
        };
        let (p, c) = resolve(&BakeOptions::default(), &scene).unwrap();
        assert_eq!((p.levels, c), (4, Coarse::Radius(0.5)));
        let opts = BakeOptions {
            receiver_levels: Some(2),
            coarse_count: Some(10),
            ..Default::default()
        };
        let (p, c) = resolve(&opts, &scene).unwrap();
        assert_eq!((p.levels, c), (2, Coarse::Count(10)));
        let (p, c) = resolve(&BakeOptions::default(), &BakeSettings::default()).unwrap();
        assert_eq!((p.levels, c), (6, Coarse::Count(339)));
    }

    #[test]
    fn bad_values_are_refused_with_a_reason() {
        let s = BakeSettings::default();
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
            let e = resolve(&opts, &s).unwrap_err();
            assert!(!e.to_string().is_empty());
        }
    }
}
