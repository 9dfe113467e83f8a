//! Candidate points by importance particles (Lehtinen et al. 2008, section 2.3): particles
//! leave the user's interior viewpoint in uniform directions and bounce diffusely through the
//! scene; every hit after the first few bounces deposits a candidate on a surface that light
//! can carry from the viewpoint to, so enclosed or unreachable surfaces get none. More
//! particles are traced lazily whenever the dart thrower runs out of candidates.
//!
//! When particles deposit fewer than [`MIN_DEPOSITS_PER_PARTICLE`] candidates each (most of
//! them escape: an open scene), the pool also samples the triangle sides they reached by area
//! ([`crate::surface_samples`]), so that every growth adds about as many candidates as in a
//! closed scene. Scenes whose particles deposit more grow exactly as described above.

use glam::Vec3;
use mlt_scenes::{Hit, RayCaster};
use rayon::prelude::*;

use crate::rng::{Rng, Stream};
use crate::surface_samples::{side_key, SurfaceSampler};
use mlt_scenes::sampling::{cosine_hemisphere, uniform_sphere};

/// Candidates per particle below which the pool adds area samples. A closed scene gives
/// `bounces - skipped` (27 by default) per particle, and scenes with openings (a Cornell box
/// without its front wall, a courtyard open to the sky) a few; where most particles escape
/// after a bounce or two (two quads, a box missing two walls) they give well below one, too
/// few for the finer levels ever to saturate.
pub const MIN_DEPOSITS_PER_PARTICLE: f64 = 1.0;

/// Fraction of particles reaching a surface below which the viewpoint is reported as
/// probably outside the scene.
pub const LOW_REACH: f64 = 0.05;

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
    /// Particles whose first ray hit a surface.
    pub reaching: u64,
    /// Candidates deposited by particles (the others are area samples).
    pub deposits: u64,
    /// Seconds spent tracing particles and sampling surfaces.
    pub seconds: f64,
    /// Once particles deposit too few candidates: which triangle sides they reached (indexed
    /// by [`side_key`]); those sides are then sampled by area at every growth.
    reached: Option<Vec<bool>>,
    /// Growths that added area samples.
    surface_batches: u64,
    /// Triangle sides the area samples cover.
    pub surface_sides: usize,
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
            reaching: 0,
            deposits: 0,
            seconds: 0.0,
            reached: None,
            surface_batches: 0,
            surface_sides: 0,
            batch: 4096,
            limit: 200_000_000,
        }
    }

    /// Traces the next batch of particles (and, in an open scene, samples the surfaces they
    /// reached); returns how many candidates it added (0 when the viewpoint sees nothing or
    /// the pool reached its limit).
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
        let mesh = self.reached.as_ref().and(caster.triangle_mesh());
        // Each particle's path depends only on its index, and chunks are concatenated in
        // particle order: identical results for any thread count.
        const CHUNK: u64 = 1024;
        let chunks: Vec<Traced> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut t = Traced {
                    out: Vec::with_capacity(CHUNK as usize * bounces.saturating_sub(skipped)),
                    ..Traced::default()
                };
                let mut on_hit = |h: &Hit| {
                    if let Some(k) = mesh.and_then(|m| side_key(m, h)) {
                        t.sides.push(k);
                    }
                };
                for id in first + c * CHUNK..(first + (c + 1) * CHUNK).min(first + n) {
                    let (r, h) = trace(
                        caster,
                        viewpoint,
                        seed,
                        id,
                        bounces,
                        skipped,
                        &mut t.out,
                        &mut on_hit,
                    );
                    t.rays += r;
                    t.hits += h;
                    t.reaching += (h > 0) as u64;
                }
                t
            })
            .collect();
        let before = self.candidates.len();
        for t in chunks {
            self.candidates.extend_from_slice(&t.out);
            self.rays += t.rays;
            self.hits += t.hits;
            self.reaching += t.reaching;
            if let Some(reached) = self.reached.as_mut() {
                for k in t.sides {
                    if let Some(r) = reached.get_mut(k as usize) {
                        *r = true;
                    }
                }
            }
        }
        self.particles += n;
        self.deposits += (self.candidates.len() - before) as u64;
        self.add_surface_samples(n);
        self.seconds += start.elapsed().as_secs_f64();
        self.candidates.len() - before
    }

    /// In an open scene, adds area samples of the reached sides for a batch of `n` particles
    /// (as many as `n` particles deposit in a closed scene); otherwise checks whether the
    /// scene is open, which turns the sampling on from the next growth.
    fn add_surface_samples(&mut self, n: u64) {
        let Some(mesh) = self.caster.triangle_mesh() else {
            return;
        };
        match &self.reached {
            Some(reached) => {
                let sampler = SurfaceSampler::new(mesh, reached);
                self.surface_sides = sampler.side_count();
                let per_particle = self.bounces.saturating_sub(self.skipped).max(1) as u64;
                let samples = sampler.sample(self.seed, self.surface_batches, n * per_particle);
                self.surface_batches += 1;
                self.candidates.extend_from_slice(&samples);
            }
            None => {
                if (self.deposits as f64) < MIN_DEPOSITS_PER_PARTICLE * self.particles as f64 {
                    self.reached = Some(vec![false; 2 * mesh.triangles.len()]);
                }
            }
        }
    }

    /// Whether area samples are being added (the scene looked open).
    pub fn samples_surfaces(&self) -> bool {
        self.reached.is_some()
    }

    /// What the user should know about the candidates: when most particles missed every
    /// surface, or escaped so soon that surfaces are sampled by area.
    pub fn notes(&self) -> Vec<String> {
        let mut notes = Vec::new();
        let p = self.particles.max(1) as f64;
        let reach = self.reaching as f64 / p;
        if self.particles > 0 && reach < LOW_REACH {
            let v = self.viewpoint;
            notes.push(format!(
                "only {:.2} % of importance particles hit a surface from the viewpoint ({}, {}, {}); set [scene] viewpoint to a point inside the scene",
                100.0 * reach,
                v.x,
                v.y,
                v.z
            ));
        }
        if self.samples_surfaces() {
            notes.push(format!(
                "importance particles deposit {:.2} candidates each (a closed scene gives {}): most escape, so the scene looks open; candidates were also sampled by area on the {} triangle sides they reached",
                self.deposits as f64 / p,
                self.bounces.saturating_sub(self.skipped),
                self.surface_sides
            ));
        }
        notes
    }
}

/// What one chunk of particles produced.
#[derive(Default)]
struct Traced {
    out: Vec<Candidate>,
    rays: u64,
    hits: u64,
    reaching: u64,
    /// Side keys of the hits, when the reached sides are being recorded.
    sides: Vec<u32>,
}

/// Traces particle `id`, appending its deposits to `out` and calling `on_hit` for every hit;
/// returns the rays cast and the rays that hit a surface.
#[allow(clippy::too_many_arguments)]
fn trace(
    caster: &dyn RayCaster,
    viewpoint: Vec3,
    seed: u64,
    id: u64,
    bounces: usize,
    skipped: usize,
    out: &mut Vec<Candidate>,
    on_hit: &mut impl FnMut(&Hit),
) -> (u64, u64) {
    let mut rng = Rng::new(seed, Stream::Particle, id);
    let eps = caster.ray_epsilon();
    let mut origin = viewpoint;
    let mut dir = uniform_sphere(rng.next_f32(), rng.next_f32());
    let (mut rays, mut hits) = (0, 0);
    for bounce in 0..bounces {
        rays += 1;
        let Some(hit) = caster.intersect_geometry(origin, dir, 0.0, f32::INFINITY) else {
            break;
        };
        hits += 1;
        on_hit(&hit);
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
    fn only_a_pool_whose_particles_escape_adds_area_samples() {
        let closed = SphereCaster::new(Vec3::ZERO, 1.0, [0.5; 3]);
        let mut pool = CandidatePool::new(&closed, Vec3::ZERO, 1, 30, 3);
        pool.grow();
        pool.grow();
        assert!(!pool.samples_surfaces());
        assert_eq!(pool.deposits, pool.candidates.len() as u64);
        assert!(pool.notes().is_empty());

        // A quad facing +Y, seen from below: every path escapes after its first hit.
        let quad = mlt_scenes::MeshCaster::new(mlt_scenes::Mesh {
            positions: vec![
                Vec3::new(-1.0, 0.0, -1.0),
                Vec3::new(-1.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, -1.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            triangle_material: vec![0, 0],
            materials: vec![mlt_scenes::Material::plain("m", [0.5; 3])],
            ..Default::default()
        });
        let mut pool = CandidatePool::new(&quad, Vec3::new(0.0, -0.5, 0.0), 1, 30, 3);
        assert_eq!(pool.grow(), 0);
        assert!(pool.samples_surfaces());
        let added = pool.grow();
        assert_eq!(added, pool.candidates.len());
        assert_eq!(added as u64, pool.particles / 3 * 2 * 27);
        assert_eq!(pool.surface_sides, 2);
        for c in &pool.candidates {
            assert_eq!(c.geometric_normal, -Vec3::Y);
            assert!(c.position.y == 0.0 && c.position.x.abs() <= 1.0);
        }
        assert!(pool.notes().iter().any(|n| n.contains("looks open")));
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
