//! The bounce light of the finer receivers fed back into the transport, per frame
//! ([`BounceFeedbackOp`]).
//!
//! The bake chains bounces 2 and later through the coarsest receivers (section 3.2, as the
//! paper does): the light a surface re-emits for bounce `b` is taken to be `y_j = n_j .
//! X_{b-1}[j]`, the level-0 coefficient of the previous bounce at level-0 point `j`, used as
//! the emission of the level-0 sender on that point. The light the surface actually re-emits
//! is the whole hierarchical expansion of the previous bounce (Eq. 6), and its projection onto
//! the senders differs from `y` twice over. The level-0 senders' coefficients of that
//! projection are not the level-0 receivers' coefficients: the level-0 reconstruction at a
//! point, `sum_k B_k n_j . i_k`, falls short of `n_j . i_j` where the neighbours' vector
//! irradiance turns away from the normal, and the finer receivers (their first bounce, and
//! the later bounces [`FineBounceOp`] adds) hold the light that makes up for it and more.
//! And the finer senders' coefficients, the detail itself, are never emitted at all. In a
//! closed or bright room every later bounce then starts a little short, and the shortfall
//! compounds (2 to 8 % of the indirect light in our references).
//!
//! Per frame the indirect light `i` is the fixed point of
//!
//! `i = S (e + P-dagger (n . R i) - y(i))`
//!
//! where `R i` reconstructs `i` at the sender points over every level (Eq. 6), `n . R i` is the
//! irradiance there, `P-dagger` the pull-push projection onto the sender levels (section 2.1,
//! as for the direct light), and `y(i)` the level-0 emission the bake's chain already carries
//! (on level-0 senders only). `S` holds every bounce of what it is given, so the correction
//! `d = P-dagger (n . R i) - y(i)` is itself transported through all bounces. Starting from
//! `i_0 = S e` each step adds `S d(i_k - i_{k-1})`, a geometric series whose terms shrink
//! with the albedo and the (small) size of `d`; one step takes the indirect light's mean to
//! within about 1 % in our cases, a second moves it by under 1 point.
//!
//! Only the level-0 rows of `S` are applied to `d` (`S_0`, the first rows of the
//! receiver-major [`ReceiverLinks`]): those rows carry every bounce; the finer receivers then
//! get the added light's later bounces from the level-0 change through their links to level-0
//! senders, as [`FineBounceOp`] gives them for `S e`. Their first bounce of `d` (the rows of
//! T) is left out: it is the smallest part of the correction and would cost a full product of
//! `S`.
//!
//! `R` is precomputed once per file: one row per sender point, the normalised weights
//! `B_k(x_s, n_s)` of every level's basis functions there (Eq. 2) that belong to receivers
//! with links (the others' coefficients are always zero).

use mlt_format::links::{ArchivedLinks, LINK_DIM};
use mlt_format::IndexedBasis;
use rayon::prelude::*;

use crate::fine_bounce::{along_normal, level0_emission, FineBounceOp};
use crate::pull_push_op::PullPushOp;
#[cfg(target_arch = "x86_64")]
use crate::receiver_links::unpack;
use crate::receiver_links::ReceiverLinks;

/// Sender points per parallel task of the reconstruction.
const POINT_CHUNK: usize = 256;

/// `R`, the hierarchical reconstruction at the sender points, for the fixed point
/// `i = S (e + P-dagger (n . R i) - y(i))`; `S` is the caller's [`ReceiverLinks`], of which
/// the level-0 rows are applied.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BounceFeedbackOp {
    /// Level-0 points.
    coarsest: usize,
    /// Normals of the sender points (their count is the number of sender points).
    normals: Vec<[f32; 3]>,
    /// Per sender point, offsets into `columns`/`weights` (one more than points).
    offsets: Vec<u32>,
    /// Receiver points and their basis values `B_k(x_s, n_s)`, level by level.
    columns: Vec<u32>,
    weights: Vec<f32>,
}

/// The arrays of `R` ([`BounceFeedbackOp::parts`]): the sender points' normals, and per sender
/// point `s` the entries `offsets[s]..offsets[s + 1]` of `columns` (receiver points) and
/// `weights`; [`BounceFeedbackOp::emission`] is `n_s . sum_e weights[e] v[columns[e]]` per
/// channel, then pull-pushed.
#[derive(Clone, Copy, Debug)]
pub struct ReconstructionParts<'a> {
    pub normals: &'a [[f32; 3]],
    pub offsets: &'a [u32],
    pub columns: &'a [u32],
    pub weights: &'a [f32],
}

impl BounceFeedbackOp {
    /// Precomputes `R` at the points of the coarsest `sender_levels` levels of `ib`, over the
    /// receivers with links in validated `links` (whose receivers are `ib`'s points). In
    /// parallel; the same for any thread count.
    pub fn build(ib: &IndexedBasis, links: &ArchivedLinks, sender_levels: usize) -> Self {
        let b = &ib.basis;
        let senders = b.level_offsets[sender_levels.min(ib.levels())] as usize;
        let coarsest = b.level_range(0).len();
        let linked = links.linked_flags(b.len());
        let rows: Vec<Vec<(u32, f32)>> = (0..senders)
            .into_par_iter()
            .map(|s| {
                let (x, n) = (b.positions[s], b.normals[s]);
                let mut row = Vec::new();
                for l in 0..ib.levels() {
                    ib.for_each_basis_value(l, x, n, |k, w| {
                        if linked[k] {
                            row.push((k as u32, w));
                        }
                    });
                }
                row
            })
            .collect();
        let mut offsets = Vec::with_capacity(senders + 1);
        offsets.push(0u32);
        let total: usize = rows.iter().map(Vec::len).sum();
        let mut columns = Vec::with_capacity(total);
        let mut weights = Vec::with_capacity(total);
        for row in rows {
            for (k, w) in row {
                columns.push(k);
                weights.push(w);
            }
            offsets.push(columns.len() as u32);
        }
        BounceFeedbackOp {
            coarsest,
            normals: b.normals[..senders].to_vec(),
            offsets,
            columns,
            weights,
        }
    }

    /// `R`'s arrays, for applying it elsewhere (the viewer's GPU compute passes).
    pub fn parts(&self) -> ReconstructionParts<'_> {
        ReconstructionParts {
            normals: &self.normals,
            offsets: &self.offsets,
            columns: &self.columns,
            weights: &self.weights,
        }
    }

    /// Entries of `R`.
    pub fn entries(&self) -> usize {
        self.weights.len()
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        12 * self.normals.len() + 4 * (self.offsets.len() + self.columns.len() + self.weights.len())
    }

    /// The emission `P-dagger (n . R v)` of indirect light `v` (9 floats per point): its
    /// irradiance at every sender point, reconstructed over every level (Eq. 6) and
    /// pull-pushed onto the sender levels as the direct light is; RGB per sender point.
    pub fn emission(&self, pull_push: &PullPushOp, v: &[f32]) -> Vec<f32> {
        let senders = self.normals.len();
        let mut d = vec![0.0f32; 3 * senders];
        #[cfg(target_arch = "x86_64")]
        let avx2 = std::arch::is_x86_feature_detected!("avx2");
        d.par_chunks_mut(3 * POINT_CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (k, o) in out.chunks_exact_mut(3).enumerate() {
                    let s = c * POINT_CHUNK + k;
                    let (a, b) = (self.offsets[s] as usize, self.offsets[s + 1] as usize);
                    let (columns, weights) = (&self.columns[a..b], &self.weights[a..b]);
                    #[cfg(target_arch = "x86_64")]
                    let acc = if avx2 {
                        // SAFETY: this CPU has AVX2 (checked above), the only requirement for
                        // calling a function compiled with it.
                        unsafe { reconstruct_avx2(columns, weights, v) }
                    } else {
                        reconstruct(columns, weights, v)
                    };
                    #[cfg(not(target_arch = "x86_64"))]
                    let acc = reconstruct(columns, weights, v);
                    o.copy_from_slice(&along_normal(self.normals[s], &acc));
                }
            });
        pull_push.pull(&mut d, 3);
        pull_push.push(&mut d, 3);
        d
    }

    /// The correction `d = P-dagger (n . R v) - y(v)` of the senders' emission for indirect
    /// light `v` (9 floats per point): RGB per sender point.
    pub fn correction(&self, pull_push: &PullPushOp, v: &[f32]) -> Vec<f32> {
        let mut d = self.emission(pull_push, v);
        let y = level0_emission(&self.normals[..self.coarsest], v);
        for (a, y) in d.iter_mut().zip(y) {
            *a -= y;
        }
        d
    }

    /// Runs `steps` steps of the fixed point on `i = S e`, `S` being `links` (with the finer
    /// receivers' later bounces already added when `fine` is given): each adds `S_0 d` of the
    /// previous step's change at the level-0 receivers and, through `fine`, that change's
    /// later bounces at the finer ones. Senders whose correction is at most `threshold` in
    /// every channel are skipped. The same bits for any thread count. Panics unless `i` holds
    /// 9 floats per point of the basis this was built on.
    pub fn apply(
        &self,
        links: &ReceiverLinks,
        pull_push: &PullPushOp,
        fine: Option<&FineBounceOp>,
        steps: u32,
        threshold: f32,
        i: &mut [f32],
    ) {
        let n0 = self.coarsest * LINK_DIM;
        // The previous step's change of `i`; `None` before the first step (the change is
        // then `i = S e` itself).
        let mut change: Option<Vec<f32>> = None;
        let mut delta = vec![0.0f32; n0];
        for step in 0..steps {
            let d = self.correction(pull_push, change.as_deref().unwrap_or(i));
            links.apply_first(&d, threshold, self.coarsest, &mut delta);
            for (a, b) in i[..n0].iter_mut().zip(&delta) {
                *a += b;
            }
            if step + 1 == steps {
                // The last step's change is not needed again: its later bounces at the finer
                // receivers go straight into `i` (whose level-0 part they do not read).
                if let Some(fine) = fine {
                    fine.apply_from(&delta, i);
                }
                break;
            }
            // The change of this step, for the next: `delta` at level 0, the finer receivers'
            // later bounces of it above.
            let mut c = vec![0.0f32; i.len()];
            c[..n0].copy_from_slice(&delta);
            if let Some(fine) = fine {
                fine.apply_from(&delta, &mut c);
                for (a, b) in i[n0..].iter_mut().zip(&c[n0..]) {
                    *a += b;
                }
            }
            change = Some(c);
        }
    }
}

/// One row of `R` applied to `v` (9 floats per point): `sum_k w_k v[r_k]`, each element a
/// product then a sum in `f32`, in entry order.
#[inline(always)]
fn reconstruct(columns: &[u32], weights: &[f32], v: &[f32]) -> [f32; LINK_DIM] {
    let mut acc = [0.0f32; LINK_DIM];
    for (&r, &w) in columns.iter().zip(weights) {
        let vr = &v[r as usize * LINK_DIM..(r as usize + 1) * LINK_DIM];
        for q in 0..LINK_DIM {
            acc[q] += w * vr[q];
        }
    }
    acc
}

/// [`reconstruct`] with AVX2: elements 0-7 and 5-8 of each point's nine floats multiplied and
/// added at once (separate products and sums, so each element's bits are the scalar loop's),
/// then unpacked as the links' products are ([`unpack`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn reconstruct_avx2(columns: &[u32], weights: &[f32], v: &[f32]) -> [f32; LINK_DIM] {
    use std::arch::x86_64::*;
    let (mut acc8, mut acc4) = (_mm256_setzero_ps(), _mm_setzero_ps());
    for (&r, &w) in columns.iter().zip(weights) {
        let vr = &v[r as usize * LINK_DIM..(r as usize + 1) * LINK_DIM];
        // SAFETY: `vr` holds 9 `f32`: the 32 bytes from its start and the 16 from its sixth
        // element are in bounds (unaligned loads).
        let (v8, v4) = unsafe {
            (
                _mm256_loadu_ps(vr.as_ptr()),
                _mm_loadu_ps(vr.as_ptr().add(5)),
            )
        };
        acc8 = _mm256_add_ps(acc8, _mm256_mul_ps(_mm256_set1_ps(w), v8));
        acc4 = _mm_add_ps(acc4, _mm_mul_ps(_mm_set1_ps(w), v4));
    }
    unpack(acc8, acc4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_format::links::{Links, SenderLinks};
    use mlt_format::pull_push::pull_push_levels;
    use mlt_format::test_support::plane_basis;
    use rkyv::rancor;

    /// Links from every one of `senders` senders to every receiver but each fifth, with
    /// values that vary smoothly.
    fn links_on(points: u32, senders: u32) -> Links {
        let cols: Vec<Vec<(u32, [f32; 9])>> = (0..senders)
            .map(|s| {
                (0..points)
                    .filter(|r| r % 5 != 4)
                    .map(|r| {
                        let v = std::array::from_fn(|d| {
                            0.01 * (1.0 + ((s * 13 + r * 3 + d as u32) as f32 * 0.1).sin())
                        });
                        (r, v)
                    })
                    .collect()
            })
            .collect();
        Links::pack(
            points,
            senders,
            cols.iter().enumerate().map(|(s, c)| SenderLinks {
                sender: s as u32,
                links: c,
            }),
        )
        .0
    }

    #[test]
    fn the_correction_is_the_projection_of_the_reconstruction_less_the_level0_emission() {
        let ib = plane_basis(4, 3);
        let sender_levels = 2;
        let senders = ib.basis.level_offsets[sender_levels] as u32;
        let points = ib.basis.len() as u32;
        let bytes = rkyv::to_bytes::<rancor::Error>(&links_on(points, senders)).unwrap();
        let links = rkyv::access::<ArchivedLinks, rancor::Error>(&bytes).unwrap();
        links.validate().unwrap();
        let op = BounceFeedbackOp::build(&ib, links, sender_levels);
        let pp = PullPushOp::build(&ib, sender_levels);
        // Indirect light that varies over the plane, zero at the unlinked receivers.
        let v: Vec<f32> = (0..points as usize * LINK_DIM)
            .map(|k| {
                if (k / LINK_DIM) % 5 == 4 {
                    0.0
                } else {
                    1.0 + 0.5 * (k as f32 * 0.37).sin()
                }
            })
            .collect();
        let got = op.correction(&pp, &v);
        // Per query: Eq. 6 at each sender point, the pull-push onto the sender levels, less
        // `n . v` at level 0.
        let b = &ib.basis;
        let mut z = vec![0.0f32; 3 * senders as usize];
        for s in 0..senders as usize {
            let mut r = [0.0f32; LINK_DIM];
            ib.reconstruct(
                &v,
                LINK_DIM,
                0..ib.levels(),
                b.positions[s],
                b.normals[s],
                &mut r,
            );
            let n = b.normals[s];
            for c in 0..3 {
                z[3 * s + c] = n[0] * r[3 * c] + n[1] * r[3 * c + 1] + n[2] * r[3 * c + 2];
            }
        }
        let (mut want, _) = pull_push_levels(&ib, &z, 3, sender_levels);
        for j in b.level_range(0) {
            for c in 0..3 {
                want[3 * j + c] -= v[j * LINK_DIM + 3 * c + 2];
            }
        }
        assert_eq!(got.len(), want.len());
        let scale = want.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(scale > 0.1, "{scale}");
        for (k, (a, w)) in got.iter().zip(&want).enumerate() {
            assert!((a - w).abs() <= 1e-5 * scale, "entry {k}: {a} vs {w}");
        }
        // A step adds `S_0 d` at level 0 (no finer rows without the fine step) and nothing
        // above it.
        let mut i = v.clone();
        op.apply(&ReceiverLinks::build(links), &pp, None, 1, 0.0, &mut i);
        let mut full = vec![0.0f32; v.len()];
        ReceiverLinks::build(links).apply(&got, 0.0, &mut full);
        let n0 = b.level_range(0).len() * LINK_DIM;
        for k in 0..v.len() {
            let want = if k < n0 { v[k] + full[k] } else { v[k] };
            assert!((i[k] - want).abs() <= 1e-5 * want.abs().max(1.0), "{k}");
        }
    }

    #[test]
    fn the_avx2_reconstruction_gives_the_bits_of_the_scalar_one() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // Values over many magnitudes and both signs, rows of 0 to 40 entries.
            let v: Vec<f32> = (0..50 * LINK_DIM)
                .map(|k| ((k as f32 * 0.73).sin() * 1e3).powi(3) * 1e-6)
                .collect();
            for len in 0..40usize {
                let columns: Vec<u32> = (0..len).map(|k| ((k * 17 + len) % 50) as u32).collect();
                let weights: Vec<f32> = (0..len).map(|k| (k as f32 * 0.31).cos()).collect();
                let slow = reconstruct(&columns, &weights, &v);
                // SAFETY: this CPU has AVX2 (checked above).
                let fast = unsafe { reconstruct_avx2(&columns, &weights, &v) };
                assert_eq!(
                    fast.map(f32::to_bits),
                    slow.map(f32::to_bits),
                    "{len} entries"
                );
            }
        }
    }
}
