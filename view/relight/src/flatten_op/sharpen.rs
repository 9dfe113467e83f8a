//! Sharpening of the flat coefficients: a few steps of iterated Shepard correction.
//!
//! The flattening operator gives each flat point the exact value of the hierarchical
//! expansion there, `c_j = F_L(p_j)` (Eq. 6), but the flat basis does not interpolate: its
//! Shepard functions (Eq. 2 on the one flat level) give at a flat point the weighted mean of
//! its neighbours' coefficients, `(W c)_j = sum_i c_i B^flat_i(p_j)`, and so smooth the
//! solution. Where neighbouring points face different ways (columns, arches, mouldings) the
//! mean of their vector irradiances also projects to less than each one on its own normal, so
//! the smoothing darkens. Iterated Shepard correction takes back most of both: starting from
//! `c_0 = c`, each step adds what the flat expansion still misses at the flat points, scaled by
//! the step's relaxation weight `w_k`,
//!
//! `c_{k+1} = c_k + w_k (c_0 - W c_k)`,
//!
//! so that after `s` steps the flat expansion at the flat points errs by
//! `prod_k (I - w_k W) (I - W) c` instead of `(I - W) c`. With every `w_k = 1` (plain
//! Richardson iteration) a component of `c` along an eigenvector of `W` with eigenvalue
//! `lambda` shrinks by `1 - lambda` per step: the smooth components (`lambda` near 1) at once,
//! the sharp ones (`lambda` small: detail on the scale of the point spacing, which `W`
//! flattens most) slowly. Every second step is therefore over-relaxed ([`step_weight`]: 1,
//! [`OVER_RELAXATION`], 1, ...): a pair of steps then multiplies a component by
//! `(1 - lambda)(1 - 2.5 lambda)`, at most 0.4 in magnitude for `lambda` in `[0.2, 1]`,
//! where two plain steps leave up to 0.64; a constant (`lambda = 1`) is kept exactly. The
//! iteration converges to the coefficients that interpolate `c` where `W`'s eigenvalues lie
//! in `(0, 1.4)` (plain steps: `(0, 2)`). `W`'s rows are non-negative and sum to one, and each
//! point's own function weighs most at the point, so its eigenvalues lie in `[2 d - 1, 1]`
//! (Gershgorin, `d` the smallest diagonal weight); components with `lambda <= 0`, if any, are
//! not corrected by any weights and grow a little faster than with plain steps (by 1.375 per
//! pair at `lambda = -0.1`, against 1.21). The rest of the flat image's error is the shape of
//! the flat functions between the points.
//! [`SHARPEN_STEPS`] steps by default.
//!
//! `W` is stored as a [`FlattenOp`] from the flat basis to itself (rows of Shepard weights,
//! which sum to one like the flattening operator's per level), so it shares that operator's
//! packed layout, kernels and GPU pass; a step costs its entries, about the mean number of
//! flat functions covering a flat point per row.

use mlt_format::flat_basis::FlatBasis;

use super::{FlattenOp, FlattenScratch, Kernel, RowMask};
use crate::error::RelightError;

/// Steps of the correction by default: one plain step and one over-relaxed, which leave the
/// flat image closer to the exact evaluation of Eq. 6 than three plain steps do, for two
/// products of `W` instead of three (docs/design.md, "The flat basis"; the figures in
/// BENCHMARKS.md, "Flattening, sharpening and view culling").
pub const SHARPEN_STEPS: usize = 2;

/// The relaxation weight of every second step ([`step_weight`]): the middle of the range (2.4
/// to 2.8) where the flat image's error on the paper's scenes is least; past 3 it grows again.
pub const OVER_RELAXATION: f32 = 2.5;

/// The relaxation weight `w_k` of step `k` (from 0) in `c_{k+1} = c_k + w_k (c_0 - W c_k)`: 1
/// for the first step and every second after it, [`OVER_RELAXATION`] for the others.
pub fn step_weight(step: usize) -> f32 {
    if step % 2 == 1 {
        OVER_RELAXATION
    } else {
        1.0
    }
}

/// The most steps [`SharpenOp::set_steps`] takes.
pub const MAX_SHARPEN_STEPS: usize = 16;

/// The sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` of a flat basis.
#[derive(Clone, Debug, PartialEq)]
pub struct SharpenOp {
    /// `W`: the flat basis' Shepard weights at its own points.
    smoothing: FlattenOp,
    /// Steps per [`SharpenOp::apply`], 1 to [`MAX_SHARPEN_STEPS`].
    steps: usize,
}

impl Default for SharpenOp {
    fn default() -> SharpenOp {
        SharpenOp {
            smoothing: FlattenOp::default(),
            steps: SHARPEN_STEPS,
        }
    }
}

/// Buffers a [`SharpenOp::apply`] reuses from frame to frame: every step's input `c_k`
/// (`c_0` to `c_{s-1}`), as the last run left them, so that a later run can add rows
/// ([`SharpenOp::extend_masked`]).
#[derive(Clone, Debug, Default)]
pub struct SharpenScratch {
    steps: Vec<Vec<f32>>,
    flatten: FlattenScratch,
}

impl SharpenScratch {
    /// `c_0` as the last run left it (empty before the first): the rows a
    /// [`SharpenOp::extend_masked`] adds are written here first, by the flattening product.
    pub fn original_mut(&mut self) -> &mut [f32] {
        self.steps.first_mut().map_or(&mut [], |c| c.as_mut_slice())
    }
}

impl SharpenOp {
    /// Builds `W` for `flat` (in parallel; the same for any thread count), with
    /// [`SHARPEN_STEPS`] steps.
    pub fn build(flat: &FlatBasis) -> Result<SharpenOp, RelightError> {
        Ok(SharpenOp {
            smoothing: FlattenOp::smoothing_of(flat)?,
            steps: SHARPEN_STEPS,
        })
    }

    /// The smoothing operator `W` (rows and columns: flat points), for evaluating the steps
    /// elsewhere (the viewer's GPU pass): `c_{k+1} = c_k + w_k (c_0 - W c_k)` with
    /// `w_k = step_weight(k)`.
    pub fn smoothing(&self) -> &FlattenOp {
        &self.smoothing
    }

    /// Steps per [`SharpenOp::apply`].
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Sets the steps per [`SharpenOp::apply`]; outside 1 to [`MAX_SHARPEN_STEPS`] an error
    /// that changes nothing.
    pub fn set_steps(&mut self, steps: usize) -> Result<(), RelightError> {
        if !(1..=MAX_SHARPEN_STEPS).contains(&steps) {
            return Err(RelightError::Invalid(format!(
                "{steps} sharpening steps (1 to {MAX_SHARPEN_STEPS})"
            )));
        }
        self.steps = steps;
        Ok(())
    }

    /// Number of flat points.
    pub fn points(&self) -> usize {
        self.smoothing.points()
    }

    /// Number of stored entries of `W`.
    pub fn entries(&self) -> usize {
        self.smoothing.entries()
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        self.smoothing.bytes()
    }

    /// Replaces the flat coefficients `flat` (`dim` floats per flat point), `c_0`, by
    /// `c_s` after [`SharpenOp::steps`] steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` (each computed
    /// into `scratch`, whose buffers then trade places with `flat`); each row's value is formed
    /// as soon as its `W c_k` is, while it is in cache. Each value is computed in one fixed
    /// order, so the result is the same for any thread count. Panics when `flat` is not
    /// `points * dim` long.
    pub fn apply(&self, flat: &mut Vec<f32>, dim: usize, scratch: &mut SharpenScratch) {
        self.apply_inner(flat, dim, scratch, None, false);
    }

    /// [`SharpenOp::apply`] where only some rows are wanted: step `k` computes the rows
    /// `masks[k]` holds (one flag per flat point). Where each step's rows hold every row that
    /// the next step's rows read through `W` and their own (and `flat`'s rows are right on the
    /// first step's rows and those it reads), the last step's rows equal
    /// [`SharpenOp::apply`]'s bit for bit; the other rows of `flat` are left with stale
    /// values. Panics unless there is one mask per step, each of one flag per flat point, or
    /// when `W`'s storage order is not the flat point order ([`FlattenOp::in_point_order`]).
    pub fn apply_masked(
        &self,
        flat: &mut Vec<f32>,
        dim: usize,
        scratch: &mut SharpenScratch,
        masks: &[RowMask],
    ) {
        self.check_masks(masks);
        self.apply_inner(flat, dim, scratch, Some(masks), false);
    }

    /// Panics unless `masks` is one mask per step, each of one flag per flat point, and `W`'s
    /// storage order is the flat point order.
    fn check_masks(&self, masks: &[RowMask]) {
        assert_eq!(masks.len(), self.steps, "one mask per step");
        assert!(masks
            .iter()
            .all(|m| m.rows().len() == self.smoothing.points()));
        assert!(self.smoothing.in_point_order());
    }

    /// Adds rows to the result of the last [`SharpenOp::apply_masked`] (or of the last
    /// extension) for the same `c_0`: step `k` computes the rows `added[k]` holds from the
    /// step inputs that run left in `scratch`, into them and, for the last step, into `flat`,
    /// which must hold that run's result. The rows `added[0]` reads must have been added to
    /// `c_0` first, through [`SharpenScratch::original_mut`]. Where each step's rows, those
    /// computed before and those added, hold every row the next step's added rows read, the
    /// added rows of the last step equal [`SharpenOp::apply`]'s bit for bit (a camera move
    /// under a held light computes only the rows the new view adds). Panics on the masks as
    /// [`SharpenOp::apply_masked`] does, or when no run for these steps preceded.
    pub fn extend_masked(
        &self,
        flat: &mut Vec<f32>,
        dim: usize,
        scratch: &mut SharpenScratch,
        added: &[RowMask],
    ) {
        self.check_masks(added);
        assert!(
            scratch.steps.len() == self.steps
                && scratch.steps.iter().all(|c| c.len() == flat.len()),
            "an extension follows a run for the same steps"
        );
        self.apply_inner(flat, dim, scratch, Some(added), true);
    }

    fn apply_inner(
        &self,
        flat: &mut Vec<f32>,
        dim: usize,
        scratch: &mut SharpenScratch,
        masks: Option<&[RowMask]>,
        extend: bool,
    ) {
        if dim == 0 {
            return;
        }
        let SharpenScratch { steps, flatten } = scratch;
        if !extend {
            // `c_0` comes in `flat` and stays in `steps[0]`; `flat` receives `c_s` (into the
            // buffer `c_0` of the last run held: every row the run wants is overwritten).
            steps.resize_with(self.steps, Vec::new);
            std::mem::swap(flat, &mut steps[0]);
            let n = steps[0].len();
            for c in steps[1..].iter_mut() {
                c.resize(n, 0.0);
            }
            flat.resize(n, 0.0);
        }
        let kernel = Kernel::detect();
        for step in 0..self.steps {
            let (done, next) = steps.split_at_mut(step + 1);
            let (c0, c): (&[f32], &[f32]) = (&done[0], &done[step]);
            let out: &mut [f32] = if step + 1 == self.steps {
                flat
            } else {
                &mut next[0]
            };
            let w = step_weight(step);
            let mask = masks.map(|m| &m[step]);
            self.smoothing
                .apply_then(kernel, c, dim, out, flatten, mask, |first, rows| {
                    let at = first * dim;
                    for ((o, &own), &orig) in rows.iter_mut().zip(&c[at..]).zip(&c0[at..]) {
                        *o = own + w * (orig - *o);
                    }
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flatten_op::tests::{all, coefficients};
    use mlt_format::test_support::plane_basis;

    /// `(W c)_j` by the flat basis' own reconstruction at its points.
    fn smoothed(fb: &FlatBasis, c: &[f32], dim: usize) -> Vec<f32> {
        let b = &fb.ib.basis;
        let mut out = vec![0.0f32; c.len()];
        for (j, o) in out.chunks_mut(dim).enumerate() {
            fb.reconstruct(c, dim, b.positions[j], b.normals[j], o);
        }
        out
    }

    /// `sin(kx x) cos(ky y) + 1.5` at the flat points of `fb`.
    fn wave(fb: &FlatBasis, kx: f32, ky: f32) -> Vec<f32> {
        let b = &fb.ib.basis;
        b.positions
            .iter()
            .map(|p| (kx * p[0]).sin() * (ky * p[1]).cos() + 1.5)
            .collect()
    }

    /// Relative RMS difference of the flat expansion of `f` at the flat points of `fb` from
    /// the exact values `c` there.
    fn residual(fb: &FlatBasis, f: &[f32], c: &[f32]) -> f64 {
        let w = smoothed(fb, f, 1);
        let num: f64 = w.iter().zip(c).map(|(a, b)| f64::from(a - b).powi(2)).sum();
        let den: f64 = c.iter().map(|b| f64::from(*b).powi(2)).sum();
        (num / den).sqrt()
    }

    #[test]
    fn a_constant_is_kept() {
        let ib = plane_basis(4, 3);
        let fb = all(&ib);
        let op = SharpenOp::build(&fb).unwrap();
        assert_eq!(op.points(), fb.len());
        let mut c = vec![0.6f32; fb.len() * 3];
        op.apply(&mut c, 3, &mut SharpenScratch::default());
        assert!(c.iter().all(|v| (v - 0.6).abs() < 1e-5), "{c:?}");
    }

    #[test]
    fn one_step_equals_two_c_minus_the_flat_reconstruction_at_the_flat_points() {
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        let mut op = SharpenOp::build(&fb).unwrap();
        op.set_steps(1).unwrap();
        let alpha = coefficients(&ib, 9);
        let c = fb.flatten(&ib, &alpha, 9);
        let w = smoothed(&fb, &c, 9);
        let mut sharp = c.clone();
        op.apply(&mut sharp, 9, &mut SharpenScratch::default());
        let scale = c.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        for k in 0..c.len() {
            let want = 2.0 * c[k] - w[k];
            // `W` drops values below 1e-3 and rounds to 16 bits.
            assert!(
                (sharp[k] - want).abs() < 4e-3 * scale,
                "{k}: {} vs {want}",
                sharp[k]
            );
        }
    }

    #[test]
    fn steps_equal_the_iterated_correction_by_the_flat_reconstruction() {
        // `c_{k+1} = c_k + w_k (c_0 - W c_k)`, with `W c` evaluated by the flat basis itself
        // and the weights 1, 2.5, 1, 2.5.
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        let alpha = coefficients(&ib, 9);
        let c0 = fb.flatten(&ib, &alpha, 9);
        let scale = c0.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let mut want = c0.clone();
        let mut op = SharpenOp::build(&fb).unwrap();
        assert_eq!(op.steps(), SHARPEN_STEPS);
        let mut weights = 0.0;
        for steps in 1..=4 {
            let w = smoothed(&fb, &want, 9);
            let weight = [1.0, 2.5, 1.0, 2.5][steps - 1];
            assert_eq!(step_weight(steps - 1), weight);
            weights += weight;
            for k in 0..want.len() {
                want[k] += weight * (c0[k] - w[k]);
            }
            op.set_steps(steps).unwrap();
            let mut got = c0.clone();
            op.apply(&mut got, 9, &mut SharpenScratch::default());
            for k in 0..c0.len() {
                // `W` drops values below 1e-3 and rounds to 16 bits, once per step, each
                // step's error scaled by its weight.
                assert!(
                    (got[k] - want[k]).abs() < 4e-3 * weights * scale,
                    "{steps} steps, {k}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
        }
    }

    #[test]
    fn steps_outside_their_range_are_refused() {
        let mut op = SharpenOp::build(&all(&plane_basis(3, 2))).unwrap();
        assert!(op.set_steps(0).is_err());
        assert!(op.set_steps(MAX_SHARPEN_STEPS + 1).is_err());
        assert_eq!(op.steps(), SHARPEN_STEPS);
        op.set_steps(MAX_SHARPEN_STEPS).unwrap();
        assert_eq!(op.steps(), MAX_SHARPEN_STEPS);
    }

    #[test]
    fn the_flat_expansion_moves_towards_the_exact_values_at_the_flat_points() {
        // A peaked function: smoothing lowers the peaks; after the step, `W c'` is closer
        // to the exact values `c` than `W c` was.
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        let c = wave(&fb, 9.0, 7.0);
        let mut op = SharpenOp::build(&fb).unwrap();
        op.set_steps(1).unwrap();
        let mut sharp = c.clone();
        op.apply(&mut sharp, 1, &mut SharpenScratch::default());
        let err = |f: &[f32]| residual(&fb, f, &c);
        let (before, after) = (err(&c), err(&sharp));
        assert!(before > 1e-3, "{before}");
        assert!(after < 0.7 * before, "{before} -> {after}");
        // Each further step takes back more: the error falls with the steps.
        let mut last = after;
        for steps in 2..=4 {
            op.set_steps(steps).unwrap();
            let mut f = c.clone();
            op.apply(&mut f, 1, &mut SharpenScratch::default());
            let e = err(&f);
            assert!(e < 0.9 * last, "{steps} steps: {last} -> {e}");
            last = e;
        }
    }

    #[test]
    fn the_over_relaxed_step_takes_back_more_than_a_plain_one() {
        // Detail on the scale of the point spacing, which `W` smooths most: after the default
        // steps (weights 1 and 2.5) the flat expansion at the flat points is closer to the
        // exact values than after two plain steps, and than after three.
        let ib = plane_basis(6, 3);
        let fb = all(&ib);
        let c = wave(&fb, 23.0, 19.0);
        let residual = |f: &[f32]| residual(&fb, f, &c);
        let plain = |steps: usize| {
            let mut ck = c.clone();
            for _ in 0..steps {
                let w = smoothed(&fb, &ck, 1);
                for k in 0..ck.len() {
                    ck[k] += c[k] - w[k];
                }
            }
            residual(&ck)
        };
        let op = SharpenOp::build(&fb).unwrap();
        assert_eq!(op.steps(), 2);
        let mut f = c.clone();
        op.apply(&mut f, 1, &mut SharpenScratch::default());
        let relaxed = residual(&f);
        let (two, three) = (plain(2), plain(3));
        assert!(
            relaxed < 0.9 * two,
            "relaxed {relaxed}, two plain steps {two}"
        );
        assert!(
            relaxed < three,
            "relaxed {relaxed}, three plain steps {three}"
        );
    }

    #[test]
    fn same_bits_for_any_thread_count() {
        let ib = plane_basis(6, 4);
        let fb = all(&ib);
        let alpha = coefficients(&ib, 9);
        let c = fb.flatten(&ib, &alpha, 9);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let op = SharpenOp::build(&fb).unwrap();
                let mut f = c.clone();
                op.apply(&mut f, 9, &mut SharpenScratch::default());
                (op, f.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            })
        };
        let (op1, f1) = run(1);
        let (op2, f2) = run(3);
        assert!(op1 == op2);
        assert_eq!(f1, f2);
    }
}
