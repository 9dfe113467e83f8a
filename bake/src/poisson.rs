//! Dart throwing for one level of the hierarchical Poisson-disk distribution (section 2.3):
//! candidates are tried in a random order; one is accepted when no accepted point of the same
//! level lies within `R` in the metric of Eq. 11 and its harmonic mean distance to the
//! surrounding geometry (rays of length `hmd_range * R`) is at least `hmd_reject * R`. The
//! level ends after `max_misses` consecutive rejections, or after [`MAX_FRUITLESS_GROWTHS`]
//! growths of the candidate pool in a row with no dart accepted (a pool that grows by fewer
//! than `max_misses` candidates at a time). Levels are independent: points of other levels do
//! not take part in the test.

use glam::Vec3;
use mlt_format::kernel::poisson_distance;
use mlt_scenes::RayCaster;

use crate::candidates::{Candidate, CandidatePool};
use crate::grid::Grid;
use crate::rng::{Rng, Stream};
use mlt_scenes::sampling::cosine_hemisphere;

/// Pool growths in a row without an accepted dart after which a level counts as saturated.
pub const MAX_FRUITLESS_GROWTHS: u32 = 8;

/// Settings of the dart thrower.
#[derive(Clone, Copy, Debug)]
pub struct DartSettings {
    pub max_misses: u32,
    pub hmd_rays: u32,
    /// Ray length in units of `R`.
    pub hmd_range: f32,
    /// Rejection threshold in units of `R`.
    pub hmd_reject: f32,
    pub seed: u64,
}

/// The outcome of one level.
#[derive(Clone, Debug, Default)]
pub struct LevelResult {
    pub points: Vec<Candidate>,
    pub darts: u64,
    pub disk_rejected: u64,
    pub hmd_rejected: u64,
    pub hmd_rays: u64,
    /// True when the candidate pool could not grow any more before the level saturated.
    pub ran_dry: bool,
}

/// Throws darts for a level with disk radius `radius`; `salt` distinguishes the random order
/// of separate throws (levels, or trial radii of the coarse-radius search).
pub fn throw_level(
    pool: &mut CandidatePool<'_>,
    caster: &dyn RayCaster,
    radius: f32,
    settings: &DartSettings,
    salt: u64,
) -> LevelResult {
    let mut res = LevelResult::default();
    let mut grid = Grid::new(radius);
    let mut order: Vec<u32> = (0..pool.candidates.len() as u32).collect();
    let mut shuffler = Rng::new(settings.seed, Stream::Shuffle, salt);
    shuffler.shuffle(&mut order);
    let mut cursor = 0usize;
    let mut misses = 0u32;
    let (mut fruitless, mut accepted) = (0u32, false);
    let eps = caster.ray_epsilon();
    loop {
        if cursor == order.len() {
            fruitless = if accepted { 0 } else { fruitless + 1 };
            accepted = false;
            if fruitless > MAX_FRUITLESS_GROWTHS {
                break;
            }
            let before = pool.candidates.len();
            if pool.grow() == 0 {
                res.ran_dry = true;
                break;
            }
            let mut fresh: Vec<u32> = (before as u32..pool.candidates.len() as u32).collect();
            shuffler.shuffle(&mut fresh);
            order.extend_from_slice(&fresh);
        }
        let ci = order[cursor];
        cursor += 1;
        let c = pool.candidates[ci as usize];
        res.darts += 1;
        let (xp, np) = (c.position.to_array(), c.normal.to_array());
        // D(p, q) >= |x_p - x_q|, so only points within R in space can conflict.
        let conflict = grid.any_near(c.position, |id| {
            let q = &res.points[id as usize];
            poisson_distance(xp, np, q.position.to_array(), q.normal.to_array()) < radius
        });
        if conflict {
            res.disk_rejected += 1;
        } else {
            let mut rng = Rng::new(settings.seed, Stream::Hmd, ci as u64 ^ (salt << 40));
            let hmd = harmonic_mean_distance(
                caster,
                &c,
                radius * settings.hmd_range,
                settings.hmd_rays,
                eps,
                &mut rng,
            );
            res.hmd_rays += settings.hmd_rays as u64;
            if hmd < settings.hmd_reject * radius {
                res.hmd_rejected += 1;
            } else {
                grid.insert(c.position, res.points.len() as u32);
                res.points.push(c);
                misses = 0;
                accepted = true;
                continue;
            }
        }
        misses += 1;
        if misses >= settings.max_misses {
            break;
        }
    }
    res
}

/// Harmonic mean of the hit distances of `rays` stratified, cosine-distributed rays over the
/// candidate's hemisphere, each capped at `range` (a miss counts as `range`). Zero rays give
/// `range`.
pub fn harmonic_mean_distance(
    caster: &dyn RayCaster,
    c: &Candidate,
    range: f32,
    rays: u32,
    eps: f32,
    rng: &mut Rng,
) -> f32 {
    if rays == 0 {
        return range;
    }
    let n = c.geometric_normal;
    let origin = c.position + n * eps;
    // Stratify on a near-square grid, rotated by a random offset per candidate.
    let sx = (rays as f32).sqrt().ceil() as u32;
    let sy = rays.div_ceil(sx);
    let (ou, ov) = (rng.next_f32(), rng.next_f32());
    let mut inv_sum = 0.0f32;
    for k in 0..rays {
        let (i, j) = (k % sx, k / sx);
        let u = ((i as f32 + ou) / sx as f32).fract();
        let v = ((j as f32 + ov) / sy as f32).fract();
        let dir: Vec3 = cosine_hemisphere(n, u, v);
        let d = match caster.intersect_geometry(origin, dir, 0.0, range) {
            Some(h) => h.t.max(eps),
            None => range,
        };
        inv_sum += 1.0 / d;
    }
    rays as f32 / inv_sum
}
