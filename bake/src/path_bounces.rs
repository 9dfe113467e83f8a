//! Bounces 2 and later of the coarsest receivers by path tracing, linear in the emission.
//!
//! The series of `neumann` chains bounces through the coarsest level: bounce `b` re-emits bounce
//! `b - 1` from the level-0 sender functions alone (`X_b = K (n . X_{b-1})`). A level-0 function
//! spans pillars, arcades and both sides of thin walls, so the re-emitted light is smeared over
//! surfaces that do not see it, and the coarsest receivers' later bounces come out too smooth.
//!
//! Here each coarsest receiver `i` traces paths instead, off the true geometry: the first
//! segment is the gather's (uniform hemisphere, weight `2/N`, direction `w_1`), later segments
//! are cosine-sampled from each hit with the albedos' product `beta_m = rho(h_1) ... rho(h_m)`
//! as throughput and Russian roulette once it is small. The last segment is not traced: at
//! every vertex `h_m` (shading normal `n_m`) the single-bounce irradiance there is read from T
//! itself, its hierarchical expansion over every receiver level (Eq. 6 with T's rows as
//! coefficients), so vertex `m` adds bounce `m + 1`:
//!
//! `X_ij += 2/N * beta_m * w_1 * (n_m . sum_k B_k(h_m) T_kj)`
//!
//! per colour channel (`T_kj` holds a vector irradiance per channel). T gathered the direct
//! light of every sender with many rays per receiver and kept its detail by refinement, so the
//! paths carry only the geometry's variance: a path vertex that would have met a light's hot spot
//! through one sender function (the estimator's noise when it deposits `B_j(h_{m+1})` at a traced
//! last vertex) reads the hot spot's light as T's receivers there integrated it. A thousand
//! paths per receiver leave the images' noise under the references'.
//!
//! The sum runs in two steps, so that no vertex touches T's rows: the paths accumulate, per
//! receiver `k` that has a row, the weights `P_ik = sum 2/N beta_m (x) w_1 (x) n_m B_k(h_m)`
//! (3 channels x 3 directions x 3 normal components); then `X_i = sum_k P_ik T_k`.

use glam::Vec3;
use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use mlt_scenes::raycast::geometric_normal_under;
use mlt_scenes::sampling::{cosine_hemisphere, tangent_frame};
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::gather::{hemisphere_direction, Scratch};
use crate::neumann::Rows;
use crate::refine::{ReceiverLinks, NONE};
use crate::rng::{Rng, Stream};
use crate::sender_cells::SenderCells;

/// Roulette decides the step to this vertex and later ones (counting the first hit as 1)...
const ROULETTE_FROM: u32 = 3;

/// ... once the path's throughput (largest channel) is under this: a path continues with
/// probability `beta / ROULETTE_BELOW` and carries `ROULETTE_BELOW` on. Above it every path
/// goes on, so that the bounces that carry most of the light (at albedo `rho` the first
/// `ln 0.05 / ln rho`: 4 at 0.5, 29 at 0.9, 298 at 0.99) have no roulette noise, and the noise
/// of the rest is that of the few percent of the light they carry. In a stiff scene a path is
/// long, as the series is.
const ROULETTE_BELOW: f32 = 0.05;

/// A path's weights per receiver: channel `c`, first direction's component `d`, vertex
/// normal's component `e` at `9 c + 3 d + e`.
const WEIGHT_DIM: usize = 27;

/// How the paths of [`level0_bounces`] are traced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSettings {
    /// Senders: the points of levels `0..sender_levels` (T's columns).
    pub sender_levels: usize,
    /// Paths per receiver (the first segments follow the gather's pattern).
    pub paths: u32,
    /// The deepest bounce: bounce `b` of the series ends at vertex `b - 1`, so a bake of `B`
    /// bounces passes `B`, and `--bounces auto` its cap.
    pub max_vertex: u32,
    pub seed: u64,
}

/// Rows of bounces 2 to `max_vertex` for the receivers of level 0 (row `i` for receiver `i`),
/// over every sender that T's rows at the paths' vertices reach, nothing truncated (as level
/// 0's rows of T: the coarsest level has nothing coarser to represent a dropped link). `t`
/// must hold the rows of every receiver (a whole bake's T, not a shard's). Each row depends
/// only on the receiver's index, the seed and T, so the result is the same for any thread
/// count. Each thread holds 108 bytes per point of the basis for the paths' weights.
pub fn level0_bounces(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    settings: PathSettings,
    t: &ReceiverLinks,
) -> Rows {
    let n0 = ib.basis.level_range(0).len();
    if settings.max_vertex < 2 {
        return vec![Vec::new(); n0];
    }
    // Every receiver level: the vertices evaluate T's expansion with the gather's grid.
    let cells = SenderCells::new(ib, ib.levels());
    let senders = ib.basis.level_offsets[settings.sender_levels] as usize;
    let eps = caster.ray_epsilon();
    (0..n0)
        .into_par_iter()
        .map_init(
            || (Scratch::new(senders), PathWeights::new(ib.basis.len())),
            |(scratch, pw), i| {
                pw.clear();
                trace_receiver(ib, &cells, t, caster, i, settings, eps, pw);
                scratch.clear();
                apply(t, pw, scratch);
                scratch.sort_touched();
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

/// One receiver's path weights `P_ik` (module docs), dense over the receivers, with the list
/// of those touched (in first-touch order, which depends only on the paths).
struct PathWeights {
    acc: Vec<[f32; WEIGHT_DIM]>,
    mark: Vec<bool>,
    touched: Vec<u32>,
    /// `(receiver, weight)` of one level at one vertex.
    weights: Vec<(u32, f32)>,
}

impl PathWeights {
    fn new(receivers: usize) -> PathWeights {
        PathWeights {
            acc: vec![[0.0; WEIGHT_DIM]; receivers],
            mark: vec![false; receivers],
            touched: Vec::new(),
            weights: Vec::new(),
        }
    }

    fn clear(&mut self) {
        for &k in &self.touched {
            self.acc[k as usize] = [0.0; WEIGHT_DIM];
            self.mark[k as usize] = false;
        }
        self.touched.clear();
    }

    /// Adds `coef B_k(y, n)` for every receiver `k` with a row of T, over every level (Eq. 2's
    /// normalised weights, as T's expansion at `y` evaluates them).
    fn add_at_vertex(
        &mut self,
        cells: &SenderCells,
        levels: usize,
        t: &ReceiverLinks,
        y: [f32; 3],
        n: [f32; 3],
        coef: &[f32; WEIGHT_DIM],
    ) {
        let mut weights = std::mem::take(&mut self.weights);
        cells.for_each_basis_value(levels, y, n, 1.0, &mut weights, |k, b| {
            let ku = k as usize;
            if t.row_of[ku] == NONE {
                return;
            }
            if !self.mark[ku] {
                self.mark[ku] = true;
                self.touched.push(k);
            }
            for (a, c) in self.acc[ku].iter_mut().zip(coef) {
                *a += c * b;
            }
        });
        self.weights = weights;
    }
}

/// Adds receiver `receiver`'s paths' weights to `pw` (module docs).
#[allow(clippy::too_many_arguments)]
fn trace_receiver(
    ib: &IndexedBasis,
    cells: &SenderCells,
    t: &ReceiverLinks,
    caster: &dyn RayCaster,
    receiver: usize,
    settings: PathSettings,
    eps: f32,
    pw: &mut PathWeights,
) {
    let PathSettings {
        paths,
        max_vertex,
        seed,
        ..
    } = settings;
    let b = &ib.basis;
    let levels = ib.levels();
    let x = Vec3::from(b.positions[receiver]);
    let n = Vec3::from(b.normals[receiver]);
    // No light from below the surface, as in the gathers (`gather::gather`).
    let g = geometric_normal_under(caster, x, n, eps);
    let (tx, ty) = tangent_frame(n);
    let mut rng = Rng::new(seed, Stream::Paths, receiver as u64);
    let rotation = rng.next_f32();
    let w_ray = 2.0 / paths as f32;
    let origin = x + n * eps;
    for k in 0..paths {
        let dir1 = hemisphere_direction(k, paths, rotation, tx, ty, n);
        if dir1.dot(g) <= 0.0 {
            continue;
        }
        let Some(mut hit) = caster.intersect(origin, dir1, 0.0, f32::INFINITY) else {
            continue;
        };
        let mut beta = hit.albedo;
        let mut vertex = 1;
        loop {
            // Bounce `vertex + 1` from T's expansion here.
            let (y, ny) = (hit.position.to_array(), hit.shading_normal.to_array());
            let coef: [f32; WEIGHT_DIM] = std::array::from_fn(|q| {
                let (c, d, e) = (q / 9, (q / 3) % 3, q % 3);
                w_ray * beta[c] * dir1[d] * ny[e]
            });
            pw.add_at_vertex(cells, levels, t, y, ny, &coef);
            if vertex + 1 >= max_vertex {
                break;
            }
            let b = beta[0].max(beta[1]).max(beta[2]);
            if b.is_nan() || b <= 0.0 {
                break;
            }
            if vertex + 1 >= ROULETTE_FROM && b < ROULETTE_BELOW {
                let q = b / ROULETTE_BELOW;
                if rng.next_f32() >= q {
                    break;
                }
                for bc in &mut beta {
                    *bc /= q;
                }
            }
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
            hit = next;
            vertex += 1;
        }
    }
}

/// `X_i = sum_k P_ik T_k` into `scratch` (module docs): per link `T_kj` and channel `c`,
/// direction component `d`: `sum_e P_ik[c][d][e] T_kj[c][e]`.
fn apply(t: &ReceiverLinks, pw: &PathWeights, scratch: &mut Scratch) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: this CPU has AVX2 (checked just above), the only requirement for calling a
        // function compiled with it.
        unsafe { apply_avx2(t, pw, scratch) };
        return;
    }
    apply_portable(t, pw, scratch);
}

/// [`apply`] one value at a time, on any CPU.
fn apply_portable(t: &ReceiverLinks, pw: &PathWeights, scratch: &mut Scratch) {
    for &k in &pw.touched {
        let p = &pw.acc[k as usize];
        let (senders, values) = t.row(k as usize);
        for (&j, v) in senders.iter().zip(values) {
            let out: [f32; LINK_DIM] = std::array::from_fn(|q| {
                let (c, d) = (q / 3, q % 3);
                let w = &p[9 * c + 3 * d..9 * c + 3 * d + 3];
                w[0] * v[3 * c] + w[1] * v[3 * c + 1] + w[2] * v[3 * c + 2]
            });
            scratch.add(j, &out, 1.0);
        }
    }
}

/// [`apply`] with AVX2: the first eight of a link's nine outputs in one register. Output
/// `q = 3 c + d` is `(w_0 v_{3c} + w_1 v_{3c+1}) + w_2 v_{3c+2}` with `w_e = P[3 q + e]`, the
/// portable loop's products and sums in its order (no fused operations), so the result is the
/// same, bit for bit: the lanes take `P`'s values in three registers (`P[3 q + e]` for each
/// `e`) and the link's values permuted to match (`v_{3c+e}` in lane `q`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn apply_avx2(t: &ReceiverLinks, pw: &PathWeights, scratch: &mut Scratch) {
    use std::arch::x86_64::{
        _mm256_add_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_permutevar8x32_ps, _mm256_setr_epi32,
        _mm256_storeu_ps,
    };
    // Lane `q` reads `v[3 (q / 3) + e]`: for e = 0, 1 from `v[0..8]`, for e = 2 from `v[1..9]`.
    let at0 = _mm256_setr_epi32(0, 0, 0, 3, 3, 3, 6, 6);
    let at1 = _mm256_setr_epi32(1, 1, 1, 4, 4, 4, 7, 7);
    let at2 = at1;
    for &k in &pw.touched {
        let p = &pw.acc[k as usize];
        let w: [[f32; LINK_DIM]; 3] =
            std::array::from_fn(|e| std::array::from_fn(|q| p[3 * q + e]));
        // SAFETY (all loads and stores here): each reads or writes 8 floats inside a
        // `[f32; 9]`, at offset 0 or 1; none needs alignment.
        let (w0, w1, w2) = unsafe {
            (
                _mm256_loadu_ps(w[0].as_ptr()),
                _mm256_loadu_ps(w[1].as_ptr()),
                _mm256_loadu_ps(w[2].as_ptr()),
            )
        };
        let (senders, values) = t.row(k as usize);
        for (&j, v) in senders.iter().zip(values) {
            let (lo, hi) = unsafe {
                (
                    _mm256_loadu_ps(v.as_ptr()),
                    _mm256_loadu_ps(v.as_ptr().add(1)),
                )
            };
            let v0 = _mm256_permutevar8x32_ps(lo, at0);
            let v1 = _mm256_permutevar8x32_ps(lo, at1);
            let v2 = _mm256_permutevar8x32_ps(hi, at2);
            let out = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(w0, v0), _mm256_mul_ps(w1, v1)),
                _mm256_mul_ps(w2, v2),
            );
            let last = w[0][8] * v[6] + w[1][8] * v[7] + w[2][8] * v[8];
            let a = scratch.touch(j);
            unsafe {
                _mm256_storeu_ps(
                    a.as_mut_ptr(),
                    _mm256_add_ps(_mm256_loadu_ps(a.as_ptr()), out),
                );
            }
            a[8] += last;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gather::tests::sphere_basis;
    use mlt_scenes::SphereCaster;

    #[test]
    fn the_avx2_sum_gives_the_bits_of_the_portable_one() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // Forty receivers with rows of up to 30 links over 50 senders (values of every
            // sign and scale, zeros of both signs), weights on 25 of them, in touch order.
            let mut state = 0x9e37_79b9_7f4a_7c15u64;
            let mut rnd = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let u = (state >> 40) as f32 / (1u64 << 24) as f32;
                match state % 11 {
                    0 => 0.0,
                    1 => -0.0,
                    _ => (u - 0.4) * 10f32.powi((state % 7) as i32 - 3),
                }
            };
            let mut t = ReceiverLinks::new(40);
            for k in 0..40u32 {
                let len = (k as usize * 7) % 31;
                let links: Vec<(u32, [f32; LINK_DIM])> = (0..len)
                    .map(|m| {
                        (
                            ((k as usize * 3 + m * 5) % 50) as u32,
                            std::array::from_fn(|_| rnd()),
                        )
                    })
                    .collect::<std::collections::BTreeMap<_, _>>()
                    .into_iter()
                    .collect();
                t.push_row(k, &links, (0, 0), [0.0; LINK_DIM]);
            }
            let mut pw = PathWeights::new(40);
            for k in (0..40u32).rev().filter(|k| k % 8 != 3).take(25) {
                pw.mark[k as usize] = true;
                pw.touched.push(k);
                pw.acc[k as usize] = std::array::from_fn(|_| rnd());
            }
            let run = |avx2: bool| {
                let mut scratch = Scratch::new(50);
                if avx2 {
                    // SAFETY: the CPU has AVX2 (checked above).
                    unsafe { apply_avx2(&t, &pw, &mut scratch) };
                } else {
                    apply_portable(&t, &pw, &mut scratch);
                }
                let bits: Vec<(u32, [u32; LINK_DIM])> = scratch
                    .touched
                    .iter()
                    .map(|&j| (j, scratch.get(j).map(f32::to_bits)))
                    .collect();
                bits
            };
            let portable = run(false);
            assert!(portable.len() > 40, "{}", portable.len());
            assert_eq!(run(true), portable);
        }
    }

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

    /// T of the closed sphere: every receiver's gather (Eq. 16) with many rays, so that its
    /// vector irradiance under unit emission is `rho n_k` (the gather's test).
    fn sphere_t(ib: &IndexedBasis, caster: &SphereCaster) -> ReceiverLinks {
        let cells = SenderCells::new(ib, 1);
        let mut t = ReceiverLinks::new(ib.basis.len());
        for k in 0..ib.basis.len() {
            let mut s = Scratch::new(ib.basis.len());
            crate::gather::gather(
                ib,
                &cells,
                caster,
                k,
                1,
                4096,
                5,
                caster.ray_epsilon(),
                &mut s,
            );
            s.touched.sort_unstable();
            let links: Vec<_> = s.touched.iter().map(|&j| (j, *s.get(j))).collect();
            t.push_row(k as u32, &links, (0, 0), [0.0; LINK_DIM]);
        }
        t
    }

    #[test]
    fn a_closed_sphere_gets_the_geometric_series_of_its_albedo() {
        // In a closed sphere every path continues, and T's expansion at a vertex `h` under unit
        // emission is `rho c(h)` along the normal, where `c(h) = sum_k B_k(h) n_h . n_k` (at
        // most 1; the expansion of the receivers' normals) is the same for every channel and
        // every bounce. So bounce 2 is `rho^2 c` per channel (the first segments' cosines sum
        // to exactly one), and with every later bounce `rho^2 c / (1 - rho)`: the ratio of the
        // two is the geometric series' whatever `c` is, up to the roulette's noise.
        let ib = sphere_basis();
        let rho = [0.2f32, 0.5, 0.8];
        let caster = SphereCaster::new(Vec3::ZERO, 2.0, rho);
        let t = sphere_t(&ib, &caster);
        let settings = |max_vertex| PathSettings {
            sender_levels: 1,
            paths: 4096,
            max_vertex,
            seed: 3,
        };
        let second = level0_bounces(&ib, &caster, settings(2), &t);
        let all = level0_bounces(&ib, &caster, settings(1000), &t);
        assert_eq!(second.len(), 12);
        let mut ratio_sum = [0.0f32; 3];
        for i in 0..12 {
            let (s, a) = (
                along_normal(&ib, i, &second[i]),
                along_normal(&ib, i, &all[i]),
            );
            let c = s[0] / (rho[0] * rho[0]);
            assert!(c > 0.7 && c <= 1.0 + 1e-4, "{i}: c = {c}");
            for ch in 0..3 {
                let r = rho[ch];
                assert!(
                    (s[ch] - c * r * r).abs() < 1e-4 * r * r,
                    "{i} {ch}: {} vs {}",
                    s[ch],
                    c * r * r
                );
                // One receiver's 4,096 paths: the roulette's noise, a few percent at 0.8.
                let series = 1.0 / (1.0 - r);
                assert!(
                    (a[ch] / s[ch] - series).abs() < 0.06 * series,
                    "{i} {ch}: {} vs {series}",
                    a[ch] / s[ch]
                );
                ratio_sum[ch] += a[ch] / s[ch];
            }
        }
        for (ch, r) in rho.iter().enumerate() {
            let series = 1.0 / (1.0 - r);
            let mean = ratio_sum[ch] / 12.0;
            assert!(
                (mean - series).abs() < 0.015 * series,
                "{ch}: {mean} vs {series}"
            );
        }
        // One bounce adds nothing (that is T itself); the rows do not depend on the thread
        // count.
        assert!(level0_bounces(&ib, &caster, settings(1), &t)
            .iter()
            .all(|r| r.is_empty()));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let one = pool.install(|| level0_bounces(&ib, &caster, settings(1000), &t));
        assert_eq!(one, all);
    }
}
