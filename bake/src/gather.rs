//! The hemispherical gather of Eq. 16: one receiver's links from all senders at once,
//!
//! `T'_ij = 1/pi * integral over the hemisphere of B_j(r(x_i, w)) rho(r(x_i, w)) w dw`,
//!
//! i.e. the vector irradiance at receiver `i` when sender `j` carries unit scalar irradiance
//! (the outgoing radiance of a Lambertian surface with irradiance `E` is `rho E / pi`; the
//! paper's Eq. 16 leaves the `1/pi` to its normalisation of `B_j`). Directions are uniform
//! over the hemisphere (a cosine-weighted pattern would put `1/cos` into the tangential
//! components) in a fixed Hammersley pattern, `cos theta_k = (k + 1/2) / N` and
//! `phi_k = 2 pi radical_inverse(k)`, rotated about the normal by a random angle per receiver
//! (as the tech report's gathers). The midpoint rule in `cos theta` integrates the normal
//! component exactly for uniform radiance. The angle comes from a stream keyed by the
//! receiver's index, so the result does not depend on the thread that computes it.
//!
//! The hemisphere is the receiver's shading normal's, less the directions below the surface it
//! lies on (found by [`geometric_normal_under`]): where vertex normals are smoothed across
//! edges the shading normal leans from the face, and light cannot arrive through the surface.
//! Those directions count as rays that found nothing (their weight stays in `2/N`), which is how
//! the reference path tracer treats them. With face normals none is skipped.

use glam::Vec3;
use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use mlt_scenes::raycast::geometric_normal_under;
use mlt_scenes::RayCaster;

use crate::rng::{Rng, Stream};
use crate::sender_cells::SenderCells;
use mlt_scenes::sampling::tangent_frame;

/// [`Scratch::sort_touched`] scans the marks instead of sorting once at least one sender in
/// this many is touched (a sort costs a few comparisons per element and `log2` of the count
/// passes, a scan one test per sender).
const DENSE_TOUCHED: usize = 16;

/// A dense accumulator over senders with a list of the ones touched, reused between
/// receivers (no allocation per ray or per link).
pub struct Scratch {
    pub acc: Vec<[f32; LINK_DIM]>,
    touched_mark: Vec<bool>,
    pub touched: Vec<u32>,
    /// Per sender: the gather's hits at which its function had weight (saturating), the
    /// samples a link rests on. Only [`Scratch::add_at_hit`] counts them.
    hits: Vec<u16>,
    /// `(sender, weight)` of one level at one hit.
    weights: Vec<(u32, f32)>,
}

impl Scratch {
    pub fn new(senders: usize) -> Scratch {
        Scratch {
            acc: vec![[0.0; LINK_DIM]; senders],
            touched_mark: vec![false; senders],
            touched: Vec::new(),
            hits: vec![0; senders],
            weights: Vec::new(),
        }
    }

    #[inline]
    pub fn add(&mut self, j: u32, v: &[f32; LINK_DIM], scale: f32) {
        let ju = j as usize;
        if !self.touched_mark[ju] {
            self.touched_mark[ju] = true;
            self.touched.push(j);
        }
        let a = &mut self.acc[ju];
        for d in 0..LINK_DIM {
            a[d] += scale * v[d];
        }
    }

    /// Marks sender `j` touched and returns its value, to be added to.
    #[inline]
    pub fn touch(&mut self, j: u32) -> &mut [f32; LINK_DIM] {
        let ju = j as usize;
        if !self.touched_mark[ju] {
            self.touched_mark[ju] = true;
            self.touched.push(j);
        }
        &mut self.acc[ju]
    }

    /// Puts the touched senders in ascending order. When they are a large share of all senders
    /// (a finer receiver's Eq. 17 subtraction touches every sender of its parents' rows,
    /// thousands) a scan of the marks gives that order in time linear in the senders, cheaper
    /// than sorting; otherwise they are sorted. The same list either way.
    pub fn sort_touched(&mut self) {
        let Scratch {
            touched,
            touched_mark,
            ..
        } = self;
        if touched.len().saturating_mul(DENSE_TOUCHED) >= touched_mark.len() {
            touched.clear();
            touched.extend(
                touched_mark
                    .iter()
                    .enumerate()
                    .filter(|(_, &m)| m)
                    .map(|(j, _)| j as u32),
            );
        } else {
            touched.sort_unstable();
        }
    }

    /// The value for sender `j` (zero when untouched).
    #[inline]
    pub fn get(&self, j: u32) -> &[f32; LINK_DIM] {
        &self.acc[j as usize]
    }

    /// The gather's hits at which sender `j`'s function had weight (0 when only `add`
    /// touched it, e.g. Eq. 17's subtraction of the parents' links).
    #[inline]
    pub fn hits(&self, j: u32) -> u16 {
        self.hits[j as usize]
    }

    /// Adds `scale * v * B_j(y, n)` for every sender `j` of levels `0..levels` with weight at
    /// the surface point `(y, n)` ([`SenderCells::for_each_basis_value`]): `v` spread over the
    /// sender hierarchy's expansion at `y`. Returns the number of levels with no support there.
    #[inline]
    pub fn add_at_hit(
        &mut self,
        cells: &SenderCells,
        levels: usize,
        y: [f32; 3],
        n: [f32; 3],
        v: &[f32; LINK_DIM],
        scale: f32,
    ) -> u64 {
        let mut weights = std::mem::take(&mut self.weights);
        let unsupported = cells.for_each_basis_value(levels, y, n, scale, &mut weights, |j, b| {
            self.add(j, v, b);
            self.hits[j as usize] = self.hits[j as usize].saturating_add(1);
        });
        self.weights = weights;
        unsupported
    }

    pub fn clear(&mut self) {
        for &j in &self.touched {
            self.acc[j as usize] = [0.0; LINK_DIM];
            self.touched_mark[j as usize] = false;
            self.hits[j as usize] = 0;
        }
        self.touched.clear();
    }
}

/// Counts from one gather.
#[derive(Clone, Copy, Debug, Default)]
pub struct GatherCounts {
    pub rays: u64,
    /// Hits at which some sender level had no support.
    pub unsupported: u64,
    /// Hits nearer to the receiver than its level's disk radius: surfaces in contact with the
    /// receiver's basis function (`refine` uses their share).
    pub near: u64,
}

/// Adds `T'_ij` for every sender `j` (points of levels `0..sender_levels`) seen from receiver
/// `i` to `scratch` (Eq. 16). `cells` evaluates the senders' weights at the hits; it must be
/// built over `ib` with at least `sender_levels` levels.
#[allow(clippy::too_many_arguments)]
pub fn gather(
    ib: &IndexedBasis,
    cells: &SenderCells,
    caster: &dyn RayCaster,
    receiver: usize,
    sender_levels: usize,
    rays: u32,
    seed: u64,
    eps: f32,
    scratch: &mut Scratch,
) -> GatherCounts {
    let b = &ib.basis;
    let x = Vec3::from(b.positions[receiver]);
    let n = Vec3::from(b.normals[receiver]);
    let g = geometric_normal_under(caster, x, n, eps);
    let (t, bt) = tangent_frame(n);
    let mut rng = Rng::new(seed, Stream::Gather, receiver as u64);
    let rotation = rng.next_f32();
    // Uniform hemisphere: pdf 1/(2 pi); with the 1/pi of Eq. 16 each ray weighs 2/N.
    let w_ray = 2.0 / rays as f32;
    let origin = x + n * eps;
    let mut counts = GatherCounts::default();
    let near = b.disk_radii[b.level_of(receiver)];
    for k in 0..rays {
        let dir = hemisphere_direction(k, rays, rotation, t, bt, n);
        if dir.dot(g) <= 0.0 {
            // Below the surface (a shading normal leaning from its face): no light.
            continue;
        }
        counts.rays += 1;
        let Some(hit) = caster.intersect(origin, dir, 0.0, f32::INFINITY) else {
            continue;
        };
        if (hit.position - origin).length() < near {
            counts.near += 1;
        }
        let (y, ny) = (hit.position.to_array(), hit.shading_normal.to_array());
        let rho = hit.albedo;
        let v: [f32; LINK_DIM] = [
            rho[0] * dir.x,
            rho[0] * dir.y,
            rho[0] * dir.z,
            rho[1] * dir.x,
            rho[1] * dir.y,
            rho[1] * dir.z,
            rho[2] * dir.x,
            rho[2] * dir.y,
            rho[2] * dir.z,
        ];
        counts.unsupported += scratch.add_at_hit(cells, sender_levels, y, ny, &v, w_ray);
    }
    counts
}

/// Direction `k` of the gather's pattern of `rays` (module docs): `cos theta = (k + 1/2) / N`,
/// `phi = 2 pi (radical_inverse(k) + rotation)`, in the frame `(t, bt, n)` about the normal `n`.
#[inline]
pub fn hemisphere_direction(k: u32, rays: u32, rotation: f32, t: Vec3, bt: Vec3, n: Vec3) -> Vec3 {
    let cos_t = (k as f32 + 0.5) / rays as f32;
    let phi = std::f32::consts::TAU * (radical_inverse(k) + rotation).fract();
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    (t * (sin_t * phi.cos()) + bt * (sin_t * phi.sin()) + n * cos_t).normalize()
}

/// Van der Corput radical inverse in base 2, in `[0, 1)`: the 24 leading bits of the
/// reversed index, exact in f32 (rounding all 32 bits to f32 would give 1.0 for the
/// largest indices).
#[inline]
pub fn radical_inverse(k: u32) -> f32 {
    (k.reverse_bits() >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// The magnitude of a link: the largest length of its three per-channel vectors.
#[inline]
pub fn link_norm(v: &[f32; LINK_DIM]) -> f32 {
    let mut m = 0.0f32;
    for c in 0..3 {
        let l = (v[3 * c] * v[3 * c] + v[3 * c + 1] * v[3 * c + 1] + v[3 * c + 2] * v[3 * c + 2])
            .sqrt();
        m = m.max(l);
    }
    m
}

/// `link_norm(a - b)`.
#[inline]
pub fn link_distance(a: &[f32; LINK_DIM], b: &[f32; LINK_DIM]) -> f32 {
    let d: [f32; LINK_DIM] = std::array::from_fn(|k| a[k] - b[k]);
    link_norm(&d)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::refine::RefinePolicy;
    use mlt_format::Basis;
    use mlt_scenes::SphereCaster;

    /// A one-level basis on the 12 vertices of an icosahedron inscribed in the closed sphere
    /// of radius 2, normals pointing inwards, supports wide enough to overlap.
    pub(crate) fn sphere_basis() -> IndexedBasis {
        let mesh = mlt_scenes::builtin::icosphere(2.0, 0, [0.5; 3]);
        let mut b = Basis::default();
        for p in &mesh.positions {
            b.positions.push(p.to_array());
            b.normals.push((-p.normalize()).to_array());
            b.radii.push(3.2);
        }
        b.level_offsets = vec![0, b.positions.len() as u32];
        b.disk_radii = vec![2.0];
        IndexedBasis::build(b).unwrap()
    }

    #[test]
    fn touched_senders_sort_alike_whether_few_or_many() {
        let senders = 1000u32;
        let mut s = Scratch::new(senders as usize);
        // Few (a sort) and many (a scan of the marks), in a scrambled first-touch order with
        // repeats; each must come out ascending, once each.
        for count in [5u32, 40, 600, 1000] {
            s.clear();
            let mut want = Vec::new();
            for k in 0..count {
                let j = (k * 7919 + 13) % senders;
                s.add(j, &[1.0; LINK_DIM], 1.0);
                s.add(j, &[1.0; LINK_DIM], 1.0);
                want.push(j);
            }
            want.sort_unstable();
            want.dedup();
            s.sort_touched();
            assert_eq!(s.touched, want, "{count} touched");
        }
    }

    #[test]
    fn hits_count_the_gather_samples_a_link_rests_on() {
        let ib = sphere_basis();
        let caster = SphereCaster::new(Vec3::ZERO, 2.0, [0.5; 3]);
        let eps = caster.ray_epsilon();
        let cells = SenderCells::new(&ib, 1);
        let mut s = Scratch::new(ib.basis.len());
        // One ray, one hit: every sender with weight there rests on that one sample, which
        // the finer-sender budget does not keep.
        gather(&ib, &cells, &caster, 0, 1, 1, 7, eps, &mut s);
        assert!(!s.touched.is_empty());
        assert!(s.touched.iter().all(|&j| s.hits(j) == 1));
        assert!(s
            .touched
            .iter()
            .all(|&j| !RefinePolicy::default().budget_sampled(s.hits(j))));
        s.clear();
        // Every ray hits the closed sphere and has weight on at least one sender.
        let rays = 256u32;
        gather(&ib, &cells, &caster, 0, 1, rays, 7, eps, &mut s);
        let touched = s.touched.clone();
        let hits: Vec<u16> = touched.iter().map(|&j| s.hits(j)).collect();
        assert!(hits.iter().map(|&h| h as u32).sum::<u32>() >= rays);
        assert!(
            hits.iter().all(|&h| (1..=rays as u16).contains(&h)),
            "{hits:?}"
        );
        assert!(hits
            .iter()
            .any(|&h| h >= RefinePolicy::default().min_budget_hits));
        // Eq. 17's subtraction of the parents' links adds values, not samples: a sender it
        // alone touches has no hits (and stays a budget candidate).
        for &j in &touched {
            s.add(j, &[1.0; LINK_DIM], -0.5);
        }
        assert_eq!(touched.iter().map(|&j| s.hits(j)).collect::<Vec<_>>(), hits);
        s.clear();
        assert!((0..ib.basis.len() as u32).all(|j| s.hits(j) == 0));
        s.add(3, &[1.0; LINK_DIM], -0.5);
        assert_eq!((s.touched.as_slice(), s.hits(3)), (&[3u32][..], 0));
        assert!(RefinePolicy::default().budget_sampled(0));
    }

    #[test]
    fn a_closed_sphere_gathers_rho_along_the_normal_with_any_ray_count() {
        // Eq. 16 with the midpoint rule in cos(theta): every ray hits, the sender weights at
        // the hit sum to one (Eq. 2), so n . sum_j T'_ij = rho exactly, even for one ray
        // (cos 1/2, weight 2); the tangential part cancels only with many rays.
        let ib = sphere_basis();
        let rho = [0.2f32, 0.5, 0.9];
        let caster = SphereCaster::new(Vec3::ZERO, 2.0, rho);
        let eps = caster.ray_epsilon();
        let cells = SenderCells::new(&ib, 1);
        for rays in [1u32, 2, 3, 256] {
            for i in 0..ib.basis.len() {
                let mut s = Scratch::new(ib.basis.len());
                let counts = gather(&ib, &cells, &caster, i, 1, rays, 7, eps, &mut s);
                assert_eq!((counts.rays, counts.unsupported), (rays as u64, 0));
                let n = Vec3::from(ib.basis.normals[i]);
                let mut sum = [Vec3::ZERO; 3];
                for &j in &s.touched {
                    let v = s.get(j);
                    for (c, sc) in sum.iter_mut().enumerate() {
                        *sc += Vec3::new(v[3 * c], v[3 * c + 1], v[3 * c + 2]);
                    }
                }
                for c in 0..3 {
                    assert!(sum[c].is_finite());
                    let along = sum[c].dot(n);
                    assert!(
                        (along - rho[c]).abs() < 1e-4 * rho[c].max(1.0),
                        "{rays}: {along}"
                    );
                    if rays == 256 {
                        let tangential = (sum[c] - along * n).length();
                        assert!(tangential < 0.01 * rho[c], "{tangential}");
                    }
                }
            }
        }
    }

    /// A horizontal quad at height `y`, two metres wide.
    fn plate(y: f32, m: &mut mlt_scenes::Mesh, material: u32) {
        let base = m.positions.len() as u32;
        for (x, z) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0), (1.0, -1.0)] {
            m.positions.push(Vec3::new(x, y, z));
        }
        m.triangles.push([base, base + 1, base + 2]);
        m.triangles.push([base, base + 2, base + 3]);
        m.triangle_material.extend([material; 2]);
    }

    #[test]
    fn no_light_arrives_from_below_a_leaning_shading_normal() {
        // A floor between a ceiling and a plate below it. A receiver on the floor whose shading
        // normal leans 30 degrees from the face sees the ceiling only: the sixth of its
        // hemisphere below the floor holds neither the plate (light from behind the surface)
        // nor the floor itself (its own surface, hit from a few eps away).
        let mut mesh = mlt_scenes::Mesh {
            materials: vec![mlt_scenes::Material::plain("m", [0.5; 3])],
            ..Default::default()
        };
        for y in [-0.5, 0.0, 1.0] {
            plate(y, &mut mesh, 0);
        }
        let caster = mlt_scenes::MeshCaster::new(mesh);
        let eps = caster.ray_epsilon();
        let lean = Vec3::new(0.5, 0.75f32.sqrt(), 0.0);
        let mut b = Basis::default();
        // (position, normal): the receiver, then one sender on each surface.
        let points = [
            (Vec3::ZERO, lean),
            (Vec3::new(0.3, -0.5, 0.0), Vec3::Y),
            (Vec3::new(-0.3, 0.0, 0.0), Vec3::Y),
            (Vec3::new(0.0, 1.0, 0.0), -Vec3::Y),
        ];
        for (p, n) in points {
            b.positions.push(p.to_array());
            b.normals.push(n.to_array());
            b.radii.push(4.0);
        }
        b.level_offsets = vec![0, b.positions.len() as u32];
        b.disk_radii = vec![0.5];
        let ib = IndexedBasis::build(b).unwrap();
        let cells = SenderCells::new(&ib, 1);
        let mut s = Scratch::new(ib.basis.len());
        let rays = 64;
        let counts = gather(&ib, &cells, &caster, 0, 1, rays, 3, eps, &mut s);
        let linked = |j: u32| s.touched.contains(&j) && link_norm(s.get(j)) > 0.0;
        assert!(linked(3), "the ceiling is seen");
        assert!(!linked(1), "light from behind the floor");
        assert!(!linked(2), "the receiver's own floor");
        // The part of the hemisphere below the face is a lune of angle 30 degrees, solid
        // angle 2 (pi / 6) of the hemisphere's 2 pi: 5/6 of the (uniform) directions stay.
        let kept = counts.rays as f32 / rays as f32;
        assert!((kept - 5.0 / 6.0).abs() < 0.05, "{kept}");
    }

    #[test]
    fn norms_and_the_radical_inverse_at_their_edges() {
        assert_eq!(link_norm(&[0.0; LINK_DIM]), 0.0);
        let mut v = [0.0f32; LINK_DIM];
        v[7] = -3.0;
        assert_eq!(link_norm(&v), 3.0);
        assert_eq!(link_distance(&v, &v), 0.0);
        assert_eq!(radical_inverse(0), 0.0);
        assert_eq!(radical_inverse(1), 0.5);
        assert_eq!(radical_inverse(2), 0.25);
        let top = radical_inverse(u32::MAX);
        assert!(top < 1.0 && top > 0.99, "{top}");
    }
}
