//! Hierarchical point placement (section 2.3): dart throwing level by level with the disk
//! radius halved each time, radii `r = C R` with `C` linear from `c_coarse` to `c_fine`, and
//! the search for `R_coarse` when a level-0 point count is asked for instead.

use mlt_format::kernel::support_factor;
use mlt_format::meta::LevelStats;
use mlt_format::morton::morton_order;
use mlt_format::Basis;
use mlt_scenes::RayCaster;

use crate::candidates::CandidatePool;
use crate::poisson::{throw_level, DartSettings, LevelResult};

/// How `R_coarse` is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Coarse {
    /// This disk radius, in scene units.
    Radius(f32),
    /// The radius whose level 0 gets about this many points.
    Count(u32),
}

/// Salt of the random order of level `l` (trial throws of the radius search use others).
fn level_salt(l: usize) -> u64 {
    l as u64
}

/// Finds `R_coarse` so that level 0 gets about `target` points: repeated level-0 throws,
/// each rescaling `R` by `sqrt(points / target)` (point counts go as area / R^2), keeping the
/// closest. Returns the radius and the number of points it gave.
pub fn find_coarse_radius(
    pool: &mut CandidatePool<'_>,
    caster: &dyn RayCaster,
    target: u32,
    settings: &DartSettings,
) -> (f32, usize) {
    let (lo, hi) = caster.bounds();
    let diag = (hi - lo).length().max(f32::MIN_POSITIVE);
    let mut r = diag / (target.max(1) as f32).sqrt();
    let mut best = (r, usize::MAX, u32::MAX);
    for trial in 0..12u64 {
        let res = throw_level(pool, caster, r, settings, 1000 + trial);
        let n = res.points.len();
        let miss = (n as i64 - target as i64).unsigned_abs() as u32;
        if miss < best.2 {
            best = (r, n, miss);
        }
        if (miss as f32) <= 0.03 * target as f32 || n == 0 && trial > 6 {
            break;
        }
        let ratio = if n == 0 {
            0.25
        } else {
            n as f32 / target as f32
        };
        r *= ratio.sqrt().clamp(0.5, 2.0);
    }
    (best.0, best.1)
}

/// The placed hierarchy and what it cost.
pub struct Placement {
    pub basis: Basis,
    pub levels: Vec<LevelStats>,
    pub hmd_rays: u64,
    /// Levels that stopped because no more candidates could be generated.
    pub dry_levels: Vec<usize>,
}

/// The shape of the hierarchy: level count, `R_coarse`, and the support factors `C` on the
/// coarsest and finest level.
#[derive(Clone, Copy, Debug)]
pub struct LevelPlan {
    pub levels: usize,
    pub r_coarse: f32,
    pub c_coarse: f32,
    pub c_fine: f32,
}

/// One line on a placed level, for progress reports.
pub fn level_line(l: usize, s: &LevelStats) -> String {
    format!(
        "poisson disk level {l}: {} points, R = {:.5}, {} darts",
        s.points, s.disk_radius, s.darts
    )
}

/// Places the levels of `plan`, calling `on_level(l, stats)` after each.
pub fn place(
    pool: &mut CandidatePool<'_>,
    caster: &dyn RayCaster,
    plan: LevelPlan,
    settings: &DartSettings,
    mut on_level: impl FnMut(usize, &LevelStats),
) -> Placement {
    let LevelPlan {
        levels,
        r_coarse,
        c_coarse,
        c_fine,
    } = plan;
    let mut basis = Basis {
        level_offsets: vec![0],
        ..Basis::default()
    };
    let mut stats = Vec::with_capacity(levels);
    let mut hmd_rays = 0;
    let mut dry_levels = Vec::new();
    let mut r = r_coarse;
    for l in 0..levels {
        let LevelResult {
            points,
            darts,
            disk_rejected,
            hmd_rejected,
            hmd_rays: rays,
            ran_dry,
        } = throw_level(pool, caster, r, settings, level_salt(l));
        if ran_dry {
            dry_levels.push(l);
        }
        hmd_rays += rays;
        let support = support_factor(l, levels, c_coarse, c_fine) * r;
        // Stored in Morton order, so that neighbouring indices are neighbouring points (what
        // the viewer's per-frame products read stays in cache; `mlt_format::morton`).
        let positions: Vec<[f32; 3]> = points.iter().map(|p| p.position.to_array()).collect();
        for p in morton_order(&positions)
            .into_iter()
            .map(|i| &points[i as usize])
        {
            basis.positions.push(p.position.to_array());
            basis.normals.push(p.normal.normalize().to_array());
            basis.radii.push(support);
        }
        basis.level_offsets.push(basis.positions.len() as u32);
        basis.disk_radii.push(r);
        let prev = stats.last().map(|s: &LevelStats| s.points).unwrap_or(0);
        stats.push(LevelStats {
            points: points.len() as u64,
            disk_radius: r,
            support_radius: support,
            darts,
            disk_rejected,
            hmd_rejected,
            growth: if prev > 0 {
                points.len() as f32 / prev as f32
            } else {
                0.0
            },
        });
        if let Some(s) = stats.last() {
            on_level(l, s);
        }
        r *= 0.5;
    }
    Placement {
        basis,
        levels: stats,
        hmd_rays,
        dry_levels,
    }
}
