//! Candidate points by importance particles (Lehtinen et al. 2008, section 2.3): particles
//! leave the user's interior viewpoint in uniform directions and bounce diffusely through the
//! scene; every hit after the first few bounces deposits a candidate on a surface that light
//! can carry from the viewpoint to, so enclosed or unreachable surfaces get none. More
//! particles are traced lazily whenever the dart thrower runs out of candidates.

use glam::Vec3;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::rng::{Rng, Stream};
use mlt_scenes::sampling::{cosine_hemisphere, uniform_sphere};

/// Longest particle path accepted (the paper uses 30 bounces).
pub const MAX_BOUNCES: usize = 1000;

/// A surface point reached by a particle, with normals facing the side it arrived from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    pub position: Vec3,
    /// Shading normal: the basis point's normal.
    pub normal: Vec3,
    /// Geometric normal: the side rays leave from.
    pub geometric_normal: Vec3,
}

/// The lazily grown pool of candidates.
pub struct CandidatePool<'a> {
    caster: &'a dyn RayCaster,
    viewpoint: Vec3,
    seed: u64,
    bounces: usize,
    skipped: usize,
    pub candidates: Vec<Candidate>,
    /// Particles traced so far.
    pub particles: u64,
    /// Rays cast by those particles.
    pub rays: u64,
    /// Rays that hit a surface (deposited or not).
    pub hits: u64,
    /// Seconds spent tracing particles.
    pub seconds: f64,
    /// Particles per batch; doubles with each batch.
    batch: u64,
    /// Most candidates the pool may grow to (a guard for scenes where placement never ends).
    limit: usize,
}

impl<'a> CandidatePool<'a> {
    pub fn new(
        caster: &'a dyn RayCaster,
        viewpoint: Vec3,
        seed: u64,
        bounces: u32,
        skipped: u32,
    ) -> Self {
        CandidatePool {
            caster,
            viewpoint,
            seed,
            bounces: (bounces as usize).min(MAX_BOUNCES),
            skipped: skipped as usize,
            candidates: Vec::new(),
            particles: 0,
            rays: 0,
            hits: 0,
            seconds: 0.0,
            batch: 4096,
            limit: 200_000_000,
        }
    }

    /// Traces the next batch of particles; returns how many candidates it added (0 when the
    /// viewpoint sees nothing or the pool reached its limit).
    pub fn grow(&mut self) -> usize {
        if self.candidates.len() >= self.limit {
            return 0;
        }
        let start = std::time::Instant::now();
        let first = self.particles;
        let n = self.batch;
        self.batch = (self.batch * 2).min(1 << 18);
        let (caster, viewpoint, seed) = (self.caster, self.viewpoint, self.seed);
        let (bounces, skipped) = (self.bounces, self.skipped);
        // Each particle's path depends only on its index, and chunks are concatenated in
        // particle order: identical results for any thread count.
        const CHUNK: u64 = 1024;
        let chunks: Vec<(Vec<Candidate>, u64, u64)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut out = Vec::with_capacity(CHUNK as usize * bounces.saturating_sub(skipped));
                let (mut rays, mut hits) = (0u64, 0u64);
                for id in first + c * CHUNK..(first + (c + 1) * CHUNK).min(first + n) {
                    let (r, h) = trace(caster, viewpoint, seed, id, bounces, skipped, &mut out);
                    rays += r;
                    hits += h;
                }
                (out, rays, hits)
            })
            .collect();
        let before = self.candidates.len();
        for (c, rays, hits) in chunks {
            self.candidates.extend_from_slice(&c);
            self.rays += rays;
            self.hits += hits;
        }
        self.particles += n;
        self.seconds += start.elapsed().as_secs_f64();
        self.candidates.len() - before
    }
}

/// Traces particle `id`, appending its deposits to `out`; returns the rays cast and the rays
/// that hit a surface.
fn trace(
    caster: &dyn RayCaster,
    viewpoint: Vec3,
    seed: u64,
    id: u64,
    bounces: usize,
    skipped: usize,
    out: &mut Vec<Candidate>,
) -> (u64, u64) {
    let mut rng = Rng::new(seed, Stream::Particle, id);
    let eps = caster.ray_epsilon();
    let mut origin = viewpoint;
    let mut dir = uniform_sphere(rng.next_f32(), rng.next_f32());
    let (mut rays, mut hits) = (0, 0);
    for bounce in 0..bounces {
        rays += 1;
        let Some(hit) = caster.intersect(origin, dir, 0.0, f32::INFINITY) else {
            break;
        };
        hits += 1;
        if bounce >= skipped {
            out.push(Candidate {
                position: hit.position,
                normal: hit.shading_normal,
                geometric_normal: hit.geometric_normal,
            });
        }
        origin = hit.position + hit.geometric_normal * eps;
        dir = cosine_hemisphere(hit.geometric_normal, rng.next_f32(), rng.next_f32());
    }
    (rays, hits)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_scenes::SphereCaster;

    #[test]
    fn particles_in_a_closed_sphere_deposit_after_the_skipped_bounces() {
        let caster = SphereCaster::new(Vec3::ZERO, 2.0, [0.5; 3]);
        let mut pool = CandidatePool::new(&caster, Vec3::ZERO, 1, 30, 3);
        let added = pool.grow();
        // Closed sphere: every path runs all 30 bounces and deposits 27 candidates.
        assert_eq!(added as u64, pool.particles * 27);
        assert_eq!(pool.rays, pool.particles * 30);
        for c in &pool.candidates {
            assert!((c.position.length() - 2.0).abs() < 1e-4);
            // Normals face the inside, where the particles travel.
            assert!(c.normal.dot(c.position) < 0.0);
        }
    }

    #[test]
    fn growth_is_deterministic() {
        let caster = SphereCaster::new(Vec3::ZERO, 1.0, [0.5; 3]);
        let mut a = CandidatePool::new(&caster, Vec3::ZERO, 7, 30, 3);
        let mut b = CandidatePool::new(&caster, Vec3::ZERO, 7, 30, 3);
        a.grow();
        a.grow();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        pool.install(|| {
            b.grow();
            b.grow();
        });
        assert_eq!(a.candidates, b.candidates);
    }
}
