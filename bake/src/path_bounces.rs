//! Bounces 2 and later of the coarsest receivers by path tracing, linear in the emission.
//!
//! The series of `neumann` chains bounces through the coarsest level: bounce `b` re-emits bounce
//! `b - 1` from the level-0 sender functions alone (`X_b = K (n . X_{b-1})`). A level-0 function
//! spans pillars, arcades and both sides of thin walls, so the re-emitted light is smeared over
//! surfaces that do not see it, and the coarsest receivers' later bounces come out too smooth.
//!
//! Here each coarsest receiver `i` traces paths instead: the first segment is the gather's
//! (uniform hemisphere, weight `2/N`, direction `w_1`), later segments are cosine-sampled from
//! each hit with the albedos' product as throughput and Russian roulette, and at every vertex
//! `h_k` with `k >= 2` the direct light there, expanded in the sender functions of every sender
//! level, adds
//!
//! `X_ij += 2/N * rho(h_1) ... rho(h_k) * w_1 * B_j(h_k)`
//!
//! (per colour channel), the estimator of the vector irradiance at `i` that the direct light
//! of sender `j` delivers after two or more diffuse reflections. The bounce light is then
//! reflected by the true geometry, and its source is the sender hierarchy's detail, not the
//! level-0 functions' averages.

use glam::Vec3;
use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use mlt_scenes::sampling::{cosine_hemisphere, tangent_frame};
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::gather::{hemisphere_direction, Scratch};
use crate::neumann::Rows;
use crate::rng::{Rng, Stream};
use crate::sender_cells::SenderCells;

/// The deepest vertex of a path when the bake's bounce count does not limit it (`--bounces
/// auto`): with roulette a path's mean length is about `1 / (1 - rho)`, and at albedo 0.95 a
/// path reaches vertex 64 with probability under 4 %.
pub const MAX_VERTEX: u32 = 64;

/// Roulette starts at this vertex (counting the first hit as 1).
const ROULETTE_FROM: u32 = 3;

/// How the paths of [`level0_bounces`] are traced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSettings {
    /// Senders: the points of levels `0..sender_levels`.
    pub sender_levels: usize,
    /// Paths per receiver (the first segments follow the gather's pattern).
    pub paths: u32,
    /// The deepest vertex that deposits: bounce `b` of the series is vertex `b`, so a bake of
    /// `B` bounces passes `B`, and `--bounces auto` passes [`MAX_VERTEX`].
    pub max_vertex: u32,
    pub seed: u64,
}

/// Rows of bounces 2 to `max_vertex` for the receivers of level 0 (row `i` for receiver `i`;
/// empty where `wanted` says no), over every sender that a path's vertex reaches, nothing
/// truncated (as level 0's rows of T: the coarsest level has nothing coarser to represent a
/// dropped link). Each row depends only on the receiver's index and the seed, so the result is
/// the same for any thread count.
pub fn level0_bounces(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    settings: PathSettings,
    wanted: Option<&(dyn Fn(usize) -> bool + Sync)>,
) -> Rows {
    let n0 = ib.basis.level_range(0).len();
    if settings.max_vertex < 2 {
        return vec![Vec::new(); n0];
    }
    let cells = SenderCells::new(ib, settings.sender_levels);
    let senders = ib.basis.level_offsets[settings.sender_levels] as usize;
    let eps = caster.ray_epsilon();
    (0..n0)
        .into_par_iter()
        .map_init(
            || Scratch::new(senders),
            |scratch, i| {
                if wanted.is_some_and(|w| !w(i)) {
                    return Vec::new();
                }
                scratch.clear();
                trace_receiver(ib, &cells, caster, i, settings, eps, scratch);
                scratch.touched.sort_unstable();
                scratch
                    .touched
                    .iter()
                    .map(|&j| (j, *scratch.get(j)))
                    .filter(|(_, v)| v.iter().any(|x| *x != 0.0))
                    .collect()
            },
        )
        .collect()
}

/// Adds receiver `receiver`'s paths' deposits to `scratch` (module docs).
fn trace_receiver(
    ib: &IndexedBasis,
    cells: &SenderCells,
    caster: &dyn RayCaster,
    receiver: usize,
    settings: PathSettings,
    eps: f32,
    scratch: &mut Scratch,
) {
    let PathSettings {
        sender_levels,
        paths,
        max_vertex,
        seed,
    } = settings;
    let b = &ib.basis;
    let x = Vec3::from(b.positions[receiver]);
    let n = Vec3::from(b.normals[receiver]);
    let (t, bt) = tangent_frame(n);
    let mut rng = Rng::new(seed, Stream::Paths, receiver as u64);
    let rotation = rng.next_f32();
    let w_ray = 2.0 / paths as f32;
    let origin = x + n * eps;
    for k in 0..paths {
        let dir1 = hemisphere_direction(k, paths, rotation, t, bt, n);
        let Some(mut hit) = caster.intersect(origin, dir1, 0.0, f32::INFINITY) else {
            continue;
        };
        let mut beta = hit.albedo;
        for vertex in 2..=max_vertex {
            let (ns, ng) = (hit.shading_normal, hit.geometric_normal);
            let dir = cosine_hemisphere(ns, rng.next_f32(), rng.next_f32());
            if dir.dot(ng) <= 0.0 {
                break;
            }
            let Some(next) = caster.intersect(hit.position + ng * eps, dir, 0.0, f32::INFINITY)
            else {
                break;
            };
            for (bc, r) in beta.iter_mut().zip(next.albedo) {
                *bc *= r;
            }
            let v: [f32; LINK_DIM] = std::array::from_fn(|d| beta[d / 3] * dir1[d % 3]);
            let (y, ny) = (next.position.to_array(), next.shading_normal.to_array());
            scratch.add_at_hit(cells, sender_levels, y, ny, &v, w_ray);
            if vertex >= ROULETTE_FROM {
                let q = beta[0].max(beta[1]).max(beta[2]).min(1.0);
                if q.is_nan() || q <= 0.0 || rng.next_f32() >= q {
                    break;
                }
                for bc in &mut beta {
                    *bc /= q;
                }
            }
            hit = next;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gather::tests::sphere_basis;
    use mlt_scenes::SphereCaster;

    /// `n_i . sum_j X_ij` per channel: receiver `i`'s bounce light under unit irradiance at
    /// every sender.
    fn along_normal(ib: &IndexedBasis, i: usize, row: &[(u32, [f32; LINK_DIM])]) -> [f32; 3] {
        let n = ib.basis.normals[i];
        let mut out = [0.0f32; 3];
        for (_, v) in row {
            for (c, o) in out.iter_mut().enumerate() {
                *o += n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2];
            }
        }
        out
    }

    #[test]
    fn a_closed_sphere_gets_the_geometric_series_of_its_albedo() {
        // In a closed sphere every path continues and the sender weights at a vertex sum to
        // one, so under unit emission vertex k deposits rho^k along the normal, the first
        // segments' cosines summing to exactly one (the gather's midpoint rule). Vertex 2 has
        // no roulette: rho^2 to rounding; the whole series rho^2 / (1 - rho) up to the
        // roulette's noise.
        let ib = sphere_basis();
        let rho = [0.2f32, 0.5, 0.8];
        let caster = SphereCaster::new(Vec3::ZERO, 2.0, rho);
        let settings = |max_vertex| PathSettings {
            sender_levels: 1,
            paths: 16384,
            max_vertex,
            seed: 3,
        };
        let second = level0_bounces(&ib, &caster, settings(2), None);
        let all = level0_bounces(&ib, &caster, settings(MAX_VERTEX), None);
        assert_eq!(second.len(), 12);
        for i in 0..12 {
            let (s, a) = (
                along_normal(&ib, i, &second[i]),
                along_normal(&ib, i, &all[i]),
            );
            for c in 0..3 {
                let r = rho[c];
                assert!(
                    (s[c] - r * r).abs() < 1e-3 * r * r,
                    "{i} {c}: {} vs {}",
                    s[c],
                    r * r
                );
                let series = r * r / (1.0 - r);
                assert!(
                    (a[c] - series).abs() < 0.03 * series,
                    "{i} {c}: {} vs {series}",
                    a[c]
                );
            }
        }
        // One vertex deposits nothing (that is T's first bounce); a mask leaves rows empty;
        // the rows do not depend on the thread count.
        assert!(level0_bounces(&ib, &caster, settings(1), None)
            .iter()
            .all(|r| r.is_empty()));
        let even = level0_bounces(&ib, &caster, settings(2), Some(&|i| i % 2 == 0));
        assert!((0..12).all(|i| even[i].is_empty() == (i % 2 == 1)));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let one = pool.install(|| level0_bounces(&ib, &caster, settings(MAX_VERTEX), None));
        assert_eq!(one, all);
    }
}
