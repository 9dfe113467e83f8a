//! A precomputed sparse flattening operator (section 4.1): the matrix that maps hierarchical
//! coefficients `alpha` to the coefficients of the flat basis
//! ([`mlt_format::flat_basis::FlatBasis`]), `c_j = F_L(p_j) = sum_l sum_{k in X_l}
//! alpha_k B^l_k(p_j)` (Eq. 6, with the per-level Shepard basis of Eq. 2) at each flat point
//! `p_j`, one row per flat point, so that the per-frame flattening is one sparse product
//! instead of `levels` R-tree queries per point ([`FlatBasis::flatten`] is the reference).
//!
//! The product streams millions of entries per frame (tens per point), so the layout is chosen
//! for memory traffic and cache use:
//!
//! - Rows (flat points) are stored in Morton order ([`mlt_format::morton`]). The flat basis
//!   stores its points in that order, so the storage order is the point order and rows are
//!   written in place; flat bases in another order cost one reordering pass per product. Rows are cut into blocks of [`BLOCK_ROWS`] rows.
//!   Each block lists the hierarchical points its rows read (its local columns, a few hundred,
//!   in ascending order); a product first copies their coefficients into a small table that
//!   stays in L1 cache, then every entry reads from that table.
//! - An entry is one 32-bit word: the local column in the low 16 bits and the value
//!   `B^l_k(p_j)` in the high 16 bits, as a fixed-point fraction of 65535. The values of one
//!   row and level are rounded together (largest remainders), so that they keep their exact
//!   sum: where a level's functions all have a coefficient, the row still reproduces a constant
//!   exactly (the partition of unity of Eq. 2). Each value is within `1/65535` of the exact
//!   one.
//! - By default values below [`DEFAULT_DROP_BELOW`] are dropped and their weight given to the
//!   rest of their row and level ([`FlattenOptions`]): fewer entries for a small change in the
//!   flat coefficients. [`FlattenOptions::EXACT`] keeps them.
//! - Columns that are zero by construction are dropped when building (receivers without links,
//!   section 3.3: most fine receivers), so they cost nothing per frame.
//!
//! Each row is summed in its stored order, whatever the thread that computes it, so the result
//! is the same for any rayon thread count. On x86-64 CPUs with AVX2 and FMA (detected at run
//! time, [`Kernel`]) the rows are summed with fused multiply-adds, 8 of a point's 9 floats in
//! one register; the result then differs from other CPUs in the last bits, never between runs
//! on one machine.
//!
//! The module is in four parts: `build` (rows from the basis, quantised, in blocks),
//! `kernels` (the products), `sharpen` (the correction steps applied to the flat coefficients
//! after the product, [`SharpenOp`]) and, here, the operator and its public interface.

mod build;
mod kernels;
mod row_mask;
mod sharpen;

#[cfg(doc)]
use mlt_format::flat_basis::FlatBasis;
use rayon::prelude::*;

pub use kernels::Kernel;
pub use row_mask::RowMask;
pub use sharpen::{
    step_weight, SharpenOp, SharpenScratch, MAX_SHARPEN_STEPS, OVER_RELAXATION, SHARPEN_STEPS,
};

/// Points per block of the parallel build and of the reordering pass.
const BUILD_BLOCK: usize = 2048;

/// Rows per block of stored rows, sharing one table of local columns.
pub const BLOCK_ROWS: usize = 128;

/// Fixed-point scale of a stored value: `B = q / QUANTUM`.
pub const QUANTUM: u32 = 65535;

/// How a [`FlattenOp`] is built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlattenOptions {
    /// Normalised values `B^l_k(p_j)` below this are dropped from a row, their weight given to
    /// the other values of the same row and level (which keep their sum).
    pub drop_below: f64,
}

impl FlattenOptions {
    /// Nothing dropped but what rounds to zero: the operator equals
    /// [`mlt_format::flatten::flatten`] within `1/65535` per value.
    pub const EXACT: FlattenOptions = FlattenOptions { drop_below: 0.0 };
}

impl Default for FlattenOptions {
    /// The viewer's operator: values below [`DEFAULT_DROP_BELOW`] dropped.
    fn default() -> FlattenOptions {
        FlattenOptions {
            drop_below: DEFAULT_DROP_BELOW,
        }
    }
}

/// Values below this are dropped by default: small values are many of the entries but little
/// of the weight, so the flat coefficients move little from the exact operator's (relative RMS
/// below 1e-3, the bound the tests check).
pub const DEFAULT_DROP_BELOW: f64 = 1e-3;

/// The flattening operator `c = F alpha`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlattenOp {
    /// Number of flat points (rows).
    points: usize,
    /// Number of hierarchical points (the length of `alpha`, in points).
    hier_points: usize,
    /// Number of distinct hierarchical points read.
    columns: usize,
    /// Flat points in storage order (a permutation of `0..points`).
    order: Vec<u32>,
    /// Storage position of each point (the inverse of `order`).
    position: Vec<u32>,
    /// True when `order` is the identity: rows are then computed in place.
    identity: bool,
    /// `points + 1` offsets into `entries`, by storage position.
    row_offsets: Vec<u32>,
    /// `blocks + 1` offsets into `block_cols`.
    block_offsets: Vec<u32>,
    /// The hierarchical points each block reads, block after block.
    block_cols: Vec<u32>,
    /// Entries: local column in the low 16 bits, `q` of `B = q / QUANTUM` in the high 16.
    entries: Vec<u32>,
}

/// Borrowed arrays of a [`FlattenOp`] (see [`FlattenOp::parts`]).
#[derive(Clone, Copy, Debug)]
pub struct FlattenOpParts<'a> {
    pub order: &'a [u32],
    pub row_offsets: &'a [u32],
    pub block_offsets: &'a [u32],
    pub block_cols: &'a [u32],
    pub entries: &'a [u32],
}

/// Buffers a product reuses from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct FlattenScratch {
    rows: Vec<f32>,
}

impl FlattenOp {
    /// Number of flat points (rows).
    pub fn points(&self) -> usize {
        self.points
    }

    /// Number of hierarchical points the product reads coefficients of.
    pub fn hier_points(&self) -> usize {
        self.hier_points
    }

    /// Number of distinct hierarchical points read.
    pub fn columns(&self) -> usize {
        self.columns
    }

    /// Number of stored entries `B^l_k(p_j)`.
    pub fn entries(&self) -> usize {
        self.entries.len()
    }

    /// True when the storage order is the flat point order (Morton order, as
    /// [`FlatBasis::build`] stores them): products then need no reordering pass.
    pub fn in_point_order(&self) -> bool {
        self.identity
    }

    /// The operator's arrays, for evaluating it elsewhere (the viewer's GPU compute pass):
    /// storage position `pos` computes flat point `order[pos]` as the sum over
    /// `e in row_offsets[pos]..row_offsets[pos + 1]` of
    /// `(entries[e] >> 16) / QUANTUM * alpha[block_cols[block_offsets[pos / BLOCK_ROWS] +
    /// (entries[e] & 0xffff)]]`.
    pub fn parts(&self) -> FlattenOpParts<'_> {
        FlattenOpParts {
            order: &self.order,
            row_offsets: &self.row_offsets,
            block_offsets: &self.block_offsets,
            block_cols: &self.block_cols,
            entries: &self.entries,
        }
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.order.len()
            + self.position.len()
            + self.row_offsets.len()
            + self.block_offsets.len()
            + self.block_cols.len()
            + self.entries.len())
    }

    /// `flat = F alpha` with `dim` floats per point: `alpha.len() == hier_points * dim`,
    /// `flat.len() == points * dim`; `scratch` keeps its buffers for the next call. Panics on
    /// other lengths.
    pub fn apply(&self, alpha: &[f32], dim: usize, flat: &mut [f32], scratch: &mut FlattenScratch) {
        self.apply_with(Kernel::detect(), alpha, dim, flat, scratch);
    }

    /// [`FlattenOp::apply`] with a chosen kernel. Panics if `kernel` needs CPU features this
    /// CPU lacks.
    pub fn apply_with(
        &self,
        kernel: Kernel,
        alpha: &[f32],
        dim: usize,
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
    ) {
        self.apply_then(kernel, alpha, dim, flat, scratch, None, |_, _| {});
    }

    /// Number of blocks of [`BLOCK_ROWS`] rows (the last perhaps shorter), in storage order.
    pub fn block_count(&self) -> usize {
        self.block_offsets.len().saturating_sub(1)
    }

    /// [`FlattenOp::apply`] on the rows `mask` holds (in storage order): their values are
    /// those of the whole product, bit for bit, and the other rows are left as they were in
    /// `flat` (or, when the storage order is not the point order, take what the last product
    /// through `scratch` left there). Panics when `mask` is not one flag per row.
    pub fn apply_masked(
        &self,
        alpha: &[f32],
        dim: usize,
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
        mask: &RowMask,
    ) {
        assert_eq!(mask.rows().len(), self.points, "one flag per row");
        let kernel = Kernel::detect();
        self.apply_then(kernel, alpha, dim, flat, scratch, Some(mask), |_, _| {});
    }

    /// [`FlattenOp::apply_with`] (on the rows of `mask` only, when there is one), then
    /// `post(first, rows)` on the computed rows of the points `first..` (`dim` floats each),
    /// a task's rows (with a mask, each run of consecutive computed rows) at a time while they
    /// are still in cache when the storage order is the point order, else once on all of
    /// `flat`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn apply_then(
        &self,
        kernel: Kernel,
        alpha: &[f32],
        dim: usize,
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
        mask: Option<&RowMask>,
        post: impl Fn(usize, &mut [f32]) + Sync,
    ) {
        assert!(alpha.len() == self.hier_points * dim && flat.len() == self.points * dim);
        assert!(kernel.supported(), "this CPU cannot run {kernel:?}");
        if dim == 0 {
            return;
        }
        match dim {
            1 => self.apply_n::<1>(kernel, alpha, flat, scratch, mask, post),
            3 => self.apply_n::<3>(kernel, alpha, flat, scratch, mask, post),
            9 => self.apply_n::<9>(kernel, alpha, flat, scratch, mask, post),
            _ => {
                self.apply_dyn(alpha, dim, flat, scratch, mask);
                post(0, flat);
            }
        }
    }

    /// Writes the rows, computed in storage order, to their points: a parallel gather by
    /// point (random reads cost less than random writes, which must first fetch their line).
    fn scatter(&self, dim: usize, flat: &mut [f32], scratch: &FlattenScratch) {
        let rows = &scratch.rows;
        flat.par_chunks_mut(BUILD_BLOCK * dim)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (q, o) in out.chunks_exact_mut(dim).enumerate() {
                    let pos = self.position[chunk * BUILD_BLOCK + q] as usize;
                    o.copy_from_slice(&rows[pos * dim..pos * dim + dim]);
                }
            });
    }

    /// The local columns of block `b`.
    fn block_cols(&self, b: usize) -> &[u32] {
        &self.block_cols[self.block_offsets[b] as usize..self.block_offsets[b + 1] as usize]
    }

    /// The entries of the row at storage position `pos`.
    fn row(&self, pos: usize) -> &[u32] {
        &self.entries[self.row_offsets[pos] as usize..self.row_offsets[pos + 1] as usize]
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::kernels::TASK_BLOCKS;
    use super::*;
    use mlt_format::flat_basis::FlatBasis;
    use mlt_format::pull_push::project;
    use mlt_format::shepard::{IndexedBasis, MIN_WEIGHT_SUM};
    use mlt_format::test_support::plane_basis;

    /// The flat basis on every point of `ib`.
    pub(crate) fn all(ib: &IndexedBasis) -> FlatBasis {
        FlatBasis::build(ib, None).unwrap()
    }

    /// Coefficients of a smooth function, 9 per point, with some points zeroed.
    pub(crate) fn coefficients(ib: &IndexedBasis, dim: usize) -> Vec<f32> {
        let mut samples = Vec::with_capacity(ib.basis.len() * dim);
        for (j, p) in ib.basis.positions.iter().enumerate() {
            for d in 0..dim {
                let v = (3.0 * p[0] + d as f32).sin() * (2.0 * p[1]).cos() + 0.1 * d as f32;
                samples.push(if j % 5 == 3 { 0.0 } else { v });
            }
        }
        project(ib, &samples, dim).0
    }

    pub(super) fn max_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    /// `|a - reference| / |reference|` (2-norms).
    fn rel_rms(a: &[f32], reference: &[f32]) -> f64 {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (x, y) in a.iter().zip(reference) {
            num += f64::from(x - y).powi(2);
            den += f64::from(*y).powi(2);
        }
        (num / den).sqrt()
    }

    /// Asserts `|flat - reference|` within the quantisation bound at every point: each stored
    /// value is within `1/QUANTUM` of the exact one, so a row errs by at most its entry count
    /// times the largest coefficient over `QUANTUM`, plus float rounding.
    fn assert_within_quantisation(op: &FlattenOp, alpha: &[f32], flat: &[f32], reference: &[f32]) {
        let dim = alpha.len() / op.hier_points();
        let largest = alpha.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        for (pos, &j) in op.order.iter().enumerate() {
            let bound = op.row(pos).len() as f32 * largest / QUANTUM as f32 + 1e-5 * largest;
            for d in 0..dim {
                let (x, y) = (flat[j as usize * dim + d], reference[j as usize * dim + d]);
                assert!(
                    (x - y).abs() <= bound,
                    "point {j}, {d}: {x} vs {y} (bound {bound})"
                );
            }
        }
    }

    #[test]
    fn operator_equals_flatten_within_quantisation() {
        let ib = plane_basis(4, 3);
        let fb = all(&ib);
        let op = FlattenOp::build_with(&ib, &fb, None, FlattenOptions::EXACT).unwrap();
        assert_eq!(op.columns(), ib.basis.len());
        assert!(op.in_point_order());
        for dim in [1, 3, 9, 4] {
            let alpha = coefficients(&ib, dim);
            let reference = fb.flatten(&ib, &alpha, dim);
            let mut flat = vec![f32::NAN; alpha.len()];
            op.apply(&alpha, dim, &mut flat, &mut FlattenScratch::default());
            let scale = reference.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.5, "{scale}");
            assert_within_quantisation(&op, &alpha, &flat, &reference);
            // And in practice far inside the bound.
            let d = max_diff(&flat, &reference);
            assert!(d < 1e-4 * scale, "dim {dim}: differs by {d}");
        }
    }

    #[test]
    fn rows_reproduce_a_constant_per_level_exactly() {
        // The values of one row and level are rounded keeping their sum, so a level whose
        // coefficients are all `c` flattens to `c` wherever it has support (Eq. 2's partition
        // of unity), despite 16-bit values.
        let ib = plane_basis(5, 3);
        let fb = all(&ib);
        for options in [FlattenOptions::EXACT, FlattenOptions::default()] {
            let op = FlattenOp::build_with(&ib, &fb, None, options).unwrap();
            let n = ib.basis.len();
            for l in 0..ib.levels() {
                let mut alpha = vec![0.0f32; n];
                for k in ib.basis.level_range(l) {
                    alpha[k] = 0.7;
                }
                let mut flat_out = vec![f32::NAN; fb.len()];
                op.apply(&alpha, 1, &mut flat_out, &mut FlattenScratch::default());
                for (i, &v) in flat_out.iter().enumerate() {
                    let j = fb.source[i] as usize;
                    let (x, nj) = (ib.basis.positions[j], ib.basis.normals[j]);
                    if ib.weight_sum(l, x, nj) > MIN_WEIGHT_SUM {
                        assert!(
                            (v - 0.7).abs() < 1e-6,
                            "{options:?} level {l}, point {j}: {v}"
                        );
                    } else {
                        assert_eq!(v, 0.0);
                    }
                }
            }
        }
    }

    #[test]
    fn dropping_small_values_costs_little() {
        let ib = plane_basis(6, 3);
        let fb = all(&ib);
        let exact = FlattenOp::build_with(&ib, &fb, None, FlattenOptions::EXACT).unwrap();
        let dropped = FlattenOp::build(&ib, &fb, None).unwrap();
        // Fewer entries, and the kept ones still sum to one per row and level (tested above).
        assert!(dropped.entries() < exact.entries() * 97 / 100);
        let alpha = coefficients(&ib, 9);
        let run = |op: &FlattenOp| {
            let mut flat = vec![f32::NAN; fb.len() * 9];
            op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
            flat
        };
        let rms = rel_rms(&run(&dropped), &run(&exact));
        assert!(rms < 1e-3, "relative rms {rms}");
    }

    #[test]
    fn dropped_columns_count_as_zero_coefficients() {
        let ib = plane_basis(4, 3);
        let n = ib.basis.len();
        let keep: Vec<bool> = (0..n).map(|k| k % 3 != 0).collect();
        let fb = all(&ib);
        let op = FlattenOp::build_with(&ib, &fb, Some(&keep), FlattenOptions::EXACT).unwrap();
        let full = FlattenOp::build_with(&ib, &fb, None, FlattenOptions::EXACT).unwrap();
        assert!(op.entries() < full.entries() && op.bytes() < full.bytes());
        let mut alpha = coefficients(&ib, 9);
        let mut flat = vec![0.0; fb.len() * 9];
        op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
        for k in (0..n).filter(|k| !keep[*k]) {
            alpha[k * 9..k * 9 + 9].fill(0.0);
        }
        let reference = fb.flatten(&ib, &alpha, 9);
        assert_within_quantisation(&op, &alpha, &flat, &reference);
        // The dropped coefficients did matter.
        let mut all = vec![0.0; fb.len() * 9];
        full.apply(
            &coefficients(&ib, 9),
            9,
            &mut all,
            &mut FlattenScratch::default(),
        );
        assert!(max_diff(&flat, &all) > 1e-2);
        assert!(FlattenOp::build(&ib, &fb, Some(&keep[1..])).is_err());
    }

    #[test]
    fn same_bits_for_any_thread_count() {
        // Enough points for several build blocks and product tasks.
        let ib = plane_basis(6, 5);
        assert!(ib.basis.len() > 4 * BUILD_BLOCK, "{}", ib.basis.len());
        assert!(ib.basis.len() > 4 * TASK_BLOCKS * BLOCK_ROWS);
        let alpha = coefficients(&ib, 9);
        let fb = all(&ib);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let op = FlattenOp::build(&ib, &fb, None).unwrap();
                let mut flat = vec![0.0; fb.len() * 9];
                op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
                (op, flat)
            })
        };
        let (op1, f1) = run(1);
        let (op2, f2) = run(2);
        let (op3, f3) = run(3);
        assert!(op1 == op2 && op1 == op3);
        let bits = |f: &[f32]| f.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&f1), bits(&f2));
        assert_eq!(bits(&f1), bits(&f3));
        // The default operator drops small values: close to the reference, not within the
        // quantisation bound.
        assert!(rel_rms(&f1, &fb.flatten(&ib, &alpha, 9)) < 1e-3);
    }
}
