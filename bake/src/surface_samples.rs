//! Candidates by area sampling of the triangle sides that importance particles reached.
//!
//! In an open scene (two quads, a box missing walls, an object on a ground plane) most
//! particles escape after a bounce or two, so the particle deposits of section 2.3 come far
//! too slowly for the dart thrower to saturate the finer levels. The surfaces the particles
//! did reach are still the ones seen from the viewpoint: sampling them uniformly by area gives
//! the dart thrower as many candidates as it needs, each on the side a particle arrived from.

use mlt_scenes::{Hit, Mesh};
use rayon::prelude::*;

use crate::candidates::Candidate;
use crate::rng::{Rng, Stream};

/// The key of one side of a triangle: `2 * triangle + side`, side 1 facing against the
/// winding's normal.
pub fn side_key(mesh: &Mesh, hit: &Hit) -> Option<u32> {
    let tri = hit.prim_id;
    mesh.triangles.get(tri as usize)?;
    let [a, b, c] = mesh.corners(tri);
    let back = (b - a).cross(c - a).dot(hit.geometric_normal) < 0.0;
    tri.checked_mul(2).map(|k| k + back as u32)
}

/// The reached triangle sides and the cumulative distribution of their areas.
pub struct SurfaceSampler<'a> {
    mesh: &'a Mesh,
    /// Reached side keys, ascending (so sampling does not depend on the order of discovery).
    sides: Vec<u32>,
    /// Cumulative areas of `sides`.
    cdf: Vec<f64>,
}

impl<'a> SurfaceSampler<'a> {
    /// A sampler over the reached sides `reached[key]` of `mesh`'s triangles.
    pub fn new(mesh: &'a Mesh, reached: &[bool]) -> SurfaceSampler<'a> {
        let mut sides = Vec::new();
        let mut cdf = Vec::new();
        let mut total = 0.0f64;
        for (key, _) in reached.iter().enumerate().filter(|(_, r)| **r) {
            let tri = (key / 2) as u32;
            if mesh.triangles.get(tri as usize).is_none() {
                continue;
            }
            let [a, b, c] = mesh.corners(tri);
            let area = 0.5 * (b - a).cross(c - a).length() as f64;
            if area.is_finite() && area > 0.0 {
                total += area;
                sides.push(key as u32);
                cdf.push(total);
            }
        }
        SurfaceSampler { mesh, sides, cdf }
    }

    /// Number of triangle sides sampled.
    pub fn side_count(&self) -> usize {
        self.sides.len()
    }

    /// `count` candidates, uniform in area over the reached sides. Each chunk of samples of
    /// growth `batch` draws from its own random stream, so the result does not depend on the
    /// thread count.
    pub fn sample(&self, seed: u64, batch: u64, count: u64) -> Vec<Candidate> {
        let Some(&total) = self.cdf.last() else {
            return Vec::new();
        };
        const CHUNK: u64 = 4096;
        let chunks: Vec<Vec<Candidate>> = (0..count.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut rng = Rng::new(seed, Stream::Surface, (batch << 32) | c);
                let n = CHUNK.min(count - c * CHUNK);
                (0..n).map(|_| self.one(&mut rng, total)).collect()
            })
            .collect();
        chunks.concat()
    }

    fn one(&self, rng: &mut Rng, total: f64) -> Candidate {
        let x = rng.next_f32() as f64 * total;
        let i = self
            .cdf
            .partition_point(|&c| c <= x)
            .min(self.sides.len() - 1);
        let key = self.sides[i];
        let tri = key / 2;
        let [a, b, c] = self.mesh.corners(tri);
        // Uniform in the triangle: fold the unit square's upper half back into it.
        let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let position = a * (1.0 - u - v) + b * u + c * v;
        let face = (b - a).cross(c - a).normalize_or_zero();
        let geometric_normal = if key % 2 == 1 { -face } else { face };
        // Turned to the geometric side, as the ray caster does for hits.
        let normal = match self.mesh.shading_normal(tri, (u, v)) {
            Some(s) if s.dot(geometric_normal) < 0.0 => -s,
            Some(s) => s,
            None => geometric_normal,
        };
        Candidate {
            position,
            normal,
            geometric_normal,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use mlt_scenes::Material;

    fn quad() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(2.0, 0.0, 1.0),
                Vec3::new(2.0, 0.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            triangle_material: vec![0, 0],
            materials: vec![Material::plain("m", [0.5; 3])],
            ..Default::default()
        }
    }

    #[test]
    fn samples_cover_the_reached_sides_uniformly() {
        let mesh = quad();
        // Winding normal is +Y; only the underside (side 1) of both triangles was reached.
        let reached = [false, true, false, true];
        let s = SurfaceSampler::new(&mesh, &reached);
        assert_eq!(s.side_count(), 2);
        let c = s.sample(3, 0, 20_000);
        assert_eq!(c.len(), 20_000);
        for p in &c {
            assert_eq!(p.geometric_normal, -Vec3::Y);
            assert_eq!(p.normal, -Vec3::Y);
            assert!(p.position.y == 0.0 && (0.0..=2.0).contains(&p.position.x));
        }
        // Uniform in area: half the samples on each half of the quad.
        let left = c.iter().filter(|p| p.position.x < 1.0).count() as f64;
        assert!((left / 20_000.0 - 0.5).abs() < 0.02, "{left}");
    }

    #[test]
    fn sampling_is_deterministic_and_nothing_reached_gives_nothing() {
        let mesh = quad();
        let s = SurfaceSampler::new(&mesh, &[true, false, true, false]);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let one = pool.install(|| s.sample(9, 8192, 10_000));
        assert_eq!(one, s.sample(9, 8192, 10_000));
        assert!(SurfaceSampler::new(&mesh, &[false; 4])
            .sample(9, 0, 100)
            .is_empty());
    }
}
