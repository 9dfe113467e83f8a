//! Sharpening of the flat coefficients: one step of iterated Shepard correction.
//!
//! The flattening operator gives each flat point the exact value of the hierarchical
//! expansion there, `c_j = F_L(p_j)` (Eq. 6), but the flat basis does not interpolate: its
//! Shepard functions (Eq. 2 on the one flat level) give at a flat point the weighted mean of
//! its neighbours' coefficients, `(W c)_j = sum_i c_i B^flat_i(p_j)`, and so smooth the
//! solution. Where neighbouring points face different ways (columns, arches, mouldings) the
//! mean of their vector irradiances also projects to less than each one on its own normal, so
//! the smoothing darkens. One correction step, `c' = c + (c - W c) = (2I - W) c`, takes back
//! most of both: the flat expansion at the flat points then errs by `(I - W)^2 c` instead of
//! `(I - W) c`.
//!
//! `W` is stored as a [`FlattenOp`] from the flat basis to itself (rows of Shepard weights,
//! which sum to one like the flattening operator's per level), so it shares that operator's
//! packed layout, kernels and GPU pass; a product costs its entries, about the mean number of
//! flat functions covering a flat point per row.

use mlt_format::flat_basis::FlatBasis;

use super::{FlattenOp, FlattenScratch, Kernel};
use crate::error::RelightError;

/// The sharpening step `c' = (2I - W) c` of a flat basis.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SharpenOp {
    /// `W`: the flat basis' Shepard weights at its own points.
    smoothing: FlattenOp,
}

/// Buffers a [`SharpenOp::apply`] reuses from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct SharpenScratch {
    sharpened: Vec<f32>,
    flatten: FlattenScratch,
}

impl SharpenOp {
    /// Builds `W` for `flat` (in parallel; the same for any thread count).
    pub fn build(flat: &FlatBasis) -> Result<SharpenOp, RelightError> {
        Ok(SharpenOp {
            smoothing: FlattenOp::smoothing_of(flat)?,
        })
    }

    /// The smoothing operator `W` (rows and columns: flat points), for evaluating the step
    /// elsewhere (the viewer's GPU pass): `c' = 2 c - W c`.
    pub fn smoothing(&self) -> &FlattenOp {
        &self.smoothing
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

    /// Replaces the flat coefficients `flat` (`dim` floats per flat point) by `2 c - W c`
    /// (computed into `scratch`, whose buffer is then swapped with `flat`); each row's
    /// `2 c - W c` is formed as soon as its `W c` is, while it is in cache. Each value is
    /// computed in one fixed order, so the result is the same for any thread count. Panics
    /// when `flat` is not `points * dim` long.
    pub fn apply(&self, flat: &mut Vec<f32>, dim: usize, scratch: &mut SharpenScratch) {
        if dim == 0 {
            return;
        }
        let SharpenScratch { sharpened, flatten } = scratch;
        sharpened.resize(flat.len(), 0.0);
        let c: &[f32] = flat;
        self.smoothing.apply_then(
            Kernel::detect(),
            c,
            dim,
            sharpened,
            flatten,
            |first, rows| {
                for (o, &own) in rows.iter_mut().zip(&c[first * dim..]) {
                    *o = 2.0 * own - *o;
                }
            },
        );
        std::mem::swap(flat, sharpened);
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
    fn equals_two_c_minus_the_flat_reconstruction_at_the_flat_points() {
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        let op = SharpenOp::build(&fb).unwrap();
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
    fn the_flat_expansion_moves_towards_the_exact_values_at_the_flat_points() {
        // A peaked function: smoothing lowers the peaks; after the step, `W c'` is closer
        // to the exact values `c` than `W c` was.
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        let c: Vec<f32> = fb
            .ib
            .basis
            .positions
            .iter()
            .map(|p| (9.0 * p[0]).sin() * (7.0 * p[1]).cos() + 1.5)
            .collect();
        let op = SharpenOp::build(&fb).unwrap();
        let mut sharp = c.clone();
        op.apply(&mut sharp, 1, &mut SharpenScratch::default());
        let err = |f: &[f32]| {
            let w = smoothed(&fb, f, 1);
            (w.iter()
                .zip(&c)
                .map(|(a, b)| f64::from(a - b).powi(2))
                .sum::<f64>()
                / c.iter().map(|b| f64::from(*b).powi(2)).sum::<f64>())
            .sqrt()
        };
        let (before, after) = (err(&c), err(&sharp));
        assert!(before > 1e-3, "{before}");
        assert!(after < 0.7 * before, "{before} -> {after}");
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
