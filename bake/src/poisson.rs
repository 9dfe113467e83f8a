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

/// Darts per batch of [`throw_level`]: tested in parallel against the points accepted before
/// the batch, then decided in order.
const BATCH: usize = 2048;

/// Throws darts for a level with disk radius `radius`; `salt` distinguishes the random order
/// of separate throws (levels, or trial radii of the coarse-radius search).
///
/// The darts are decided one after the other in their random order, but the work is done in
/// batches of [`BATCH`] darts: first, in parallel, each dart of the batch is tested against the
/// points accepted before the batch (the accepted set only grows, so a dart in conflict with
/// one of them is rejected at its turn too), and the harmonic mean distance of each dart that
/// passes is computed (it depends only on the candidate). Then, in order, each remaining dart
/// is tested against the points accepted earlier in the same batch and accepted or rejected
/// as the one-at-a-time thrower would. The points, their order and every count are therefore
/// those of that thrower, whatever the number of threads; only the distances of darts that
/// a point of their own batch rejects are computed in vain.
pub fn throw_level(
    pool: &mut CandidatePool<'_>,
    caster: &dyn RayCaster,
    radius: f32,
    settings: &DartSettings,
    salt: u64,
) -> LevelResult {
    use rayon::prelude::*;
    let mut res = LevelResult::default();
    let mut grid = Grid::new(radius);
    let mut order: Vec<u32> = (0..pool.candidates.len() as u32).collect();
    let mut shuffler = Rng::new(settings.seed, Stream::Shuffle, salt);
    shuffler.shuffle(&mut order);
    let mut cursor = 0usize;
    let mut misses = 0u32;
    let (mut fruitless, mut accepted) = (0u32, false);
    let eps = caster.ray_epsilon();
    // D(p, q) >= |x_p - x_q|, so only points within R in space can conflict.
    let conflicts = |grid: &Grid, points: &[Candidate], c: &Candidate| {
        let (xp, np) = (c.position.to_array(), c.normal.to_array());
        grid.any_near(c.position, |id| {
            let q = &points[id as usize];
            poisson_distance(xp, np, q.position.to_array(), q.normal.to_array()) < radius
        })
    };
    let hmd_of = |ci: u32, c: &Candidate| {
        let mut rng = Rng::new(settings.seed, Stream::Hmd, ci as u64 ^ (salt << 40));
        harmonic_mean_distance(
            caster,
            c,
            radius * settings.hmd_range,
            settings.hmd_rays,
            eps,
            &mut rng,
        )
    };
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
        let batch = &order[cursor..(cursor + BATCH).min(order.len())];
        let candidates = &pool.candidates;
        // Per dart: `None` when a point accepted before the batch rejects it, else its
        // harmonic mean distance.
        let passed: Vec<Option<f32>> = batch
            .par_iter()
            .map(|&ci| {
                let c = &candidates[ci as usize];
                (!conflicts(&grid, &res.points, c)).then(|| hmd_of(ci, c))
            })
            .collect();
        // The points accepted in this batch, the only ones a passed dart has yet to meet.
        let mut recent = Grid::new(radius);
        let mut stop = false;
        for (&ci, hmd) in batch.iter().zip(passed) {
            cursor += 1;
            let c = candidates[ci as usize];
            res.darts += 1;
            let hmd = hmd.filter(|_| !conflicts(&recent, &res.points, &c));
            if let Some(hmd) = hmd {
                res.hmd_rays += settings.hmd_rays as u64;
                if hmd < settings.hmd_reject * radius {
                    res.hmd_rejected += 1;
                } else {
                    grid.insert(c.position, res.points.len() as u32);
                    recent.insert(c.position, res.points.len() as u32);
                    res.points.push(c);
                    misses = 0;
                    accepted = true;
                    continue;
                }
            } else {
                res.disk_rejected += 1;
            }
            misses += 1;
            if misses >= settings.max_misses {
                stop = true;
                break;
            }
        }
        if stop {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The thrower one dart at a time: each dart is tested against every point accepted so
    /// far, then, if it passes, by its harmonic mean distance.
    fn one_at_a_time(
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
        let (mut cursor, mut misses, mut fruitless, mut accepted) = (0, 0, 0, false);
        loop {
            if cursor == order.len() {
                fruitless = if accepted { 0 } else { fruitless + 1 };
                accepted = false;
                let before = pool.candidates.len();
                if fruitless > MAX_FRUITLESS_GROWTHS || pool.grow() == 0 {
                    res.ran_dry = fruitless <= MAX_FRUITLESS_GROWTHS;
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
            if grid.any_near(c.position, |id| {
                let q = &res.points[id as usize];
                poisson_distance(xp, np, q.position.to_array(), q.normal.to_array()) < radius
            }) {
                res.disk_rejected += 1;
            } else {
                let mut rng = Rng::new(settings.seed, Stream::Hmd, ci as u64 ^ (salt << 40));
                let range = radius * settings.hmd_range;
                let eps = caster.ray_epsilon();
                let hmd =
                    harmonic_mean_distance(caster, &c, range, settings.hmd_rays, eps, &mut rng);
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

    fn key(r: &LevelResult) -> (Vec<[u32; 3]>, [u64; 4], bool) {
        let points = r
            .points
            .iter()
            .map(|c| c.position.to_array().map(f32::to_bits));
        let counts = [r.darts, r.disk_rejected, r.hmd_rejected, r.hmd_rays];
        (points.collect(), counts, r.ran_dry)
    }

    #[test]
    fn batches_decide_every_dart_as_the_one_at_a_time_thrower() {
        // The Cornell box: corners and the blocks' contacts reject darts by their harmonic
        // mean distance, walls by the disk test; thousands of darts per level, so several
        // batches, and levels that end by misses and by the pool's growths.
        let scene = mlt_scenes::builtin::load_builtin("cornell").unwrap();
        let caster = scene.build_caster();
        let caster = caster.as_ref();
        let settings = DartSettings {
            max_misses: 300,
            hmd_rays: 16,
            hmd_range: 3.0,
            hmd_reject: 1.0 / 6.0,
            seed: 5,
        };
        let viewpoint = scene.viewpoint;
        let run = |threads: usize, radius: f32, batched: bool| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut cands = CandidatePool::new(caster, viewpoint, 5, 30, 3);
                cands.grow();
                if batched {
                    throw_level(&mut cands, caster, radius, &settings, 3)
                } else {
                    one_at_a_time(&mut cands, caster, radius, &settings, 3)
                }
            })
        };
        for radius in [0.05, 0.02, 0.01] {
            let want = run(1, radius, false);
            assert!(
                want.darts as usize > 2 * BATCH,
                "{radius}: {} darts",
                want.darts
            );
            assert!(want.hmd_rejected > 0 && want.disk_rejected > 0, "{radius}");
            for threads in [1, 2, 3] {
                assert_eq!(
                    key(&run(threads, radius, true)),
                    key(&want),
                    "{radius}, {threads}"
                );
            }
        }
    }
}
