//! The products `c = F alpha` of a [`FlattenOp`]: blocks of rows summed from a table of their
//! local columns' coefficients, portable or compiled for AVX2 and FMA ([`Kernel`]), with one
//! copy per common number of floats per point (1, 3, 9) and a general one.

use rayon::prelude::*;

use super::{FlattenOp, FlattenScratch, RowMask, BLOCK_ROWS, QUANTUM};

/// Blocks per task of a parallel product.
pub(super) const TASK_BLOCKS: usize = 8;

/// Partial sums per row in a product (see [`FlattenOp::blocks`]).
const ACCUMULATORS: usize = 4;

/// How rows are summed (see [`FlattenOp::apply_with`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Separate multiplies and adds, any CPU.
    Portable,
    /// Fused multiply-adds compiled for AVX2 and FMA; only where the CPU has both.
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn detect() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Kernel::Avx2Fma;
        }
        Kernel::Portable
    }

    /// Whether this CPU runs `self`.
    pub fn supported(self) -> bool {
        match self {
            Kernel::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2Fma => Kernel::detect() == Kernel::Avx2Fma,
        }
    }
}

/// `out` as rows of 9 floats, when `D` is 9.
#[cfg(target_arch = "x86_64")]
fn as_rows9<const D: usize>(out: &mut [[f32; D]]) -> Option<&mut [[f32; 9]]> {
    if D != 9 {
        return None;
    }
    let (rows, _) = out.as_flattened_mut().as_chunks_mut::<9>();
    Some(rows)
}

impl FlattenOp {
    /// `flat = F alpha` with `D` floats per point and `kernel`: tasks of [`TASK_BLOCKS`]
    /// blocks in parallel, writing the rows in place when the storage order is the point
    /// order, else into `scratch` and then to their points; then `post` (see
    /// [`FlattenOp::apply_then`]). With a `mask`, only the rows it holds are computed.
    pub(super) fn apply_n<const D: usize>(
        &self,
        kernel: Kernel,
        alpha: &[f32],
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
        mask: Option<&RowMask>,
        post: impl Fn(usize, &mut [f32]) + Sync,
    ) {
        let rows: &mut [f32] = if self.identity {
            flat
        } else {
            scratch.rows.resize(self.points * D, 0.0);
            &mut scratch.rows
        };
        rows.par_chunks_mut(TASK_BLOCKS * BLOCK_ROWS * D)
            .enumerate()
            .for_each_init(Vec::new, |table, (task, out)| {
                let (out, _) = out.as_chunks_mut::<D>();
                let first = task * TASK_BLOCKS;
                let wanted = |b: usize| mask.is_none_or(|m| m.block(b));
                let blocks = out.len().div_ceil(BLOCK_ROWS);
                if !(first..first + blocks).any(wanted) {
                    return;
                }
                match kernel {
                    Kernel::Portable => self.blocks::<D, false>(alpha, first, out, table, mask),
                    #[cfg(target_arch = "x86_64")]
                    Kernel::Avx2Fma => {
                        if let Some(out9) = as_rows9(out) {
                            // SAFETY: `apply_with` asserted that this CPU runs `kernel` (has
                            // AVX2 and FMA), the only requirement for calling a function
                            // compiled with them.
                            unsafe { self.blocks_avx2_9(alpha, first, out9, table, mask) }
                        } else {
                            // SAFETY: as above.
                            unsafe { self.blocks_avx2::<D>(alpha, first, out, table, mask) }
                        }
                    }
                }
                if self.identity {
                    match mask {
                        None => post(first * BLOCK_ROWS, out.as_flattened_mut()),
                        Some(m) => {
                            let at = first * BLOCK_ROWS;
                            m.runs(at, out.len(), |a, b| {
                                post(a, out[a - at..b - at].as_flattened_mut())
                            });
                        }
                    }
                }
            });
        if !self.identity {
            self.scatter(D, flat, scratch);
            post(0, flat);
        }
    }

    /// [`FlattenOp::blocks`] compiled with AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn blocks_avx2<const D: usize>(
        &self,
        alpha: &[f32],
        first: usize,
        out: &mut [[f32; D]],
        table: &mut Vec<f32>,
        mask: Option<&RowMask>,
    ) {
        self.blocks::<D, true>(alpha, first, out, table, mask);
    }

    /// [`FlattenOp::blocks`] for 9 floats per point (vector irradiance, the viewer's case)
    /// with AVX2 and FMA: the first 8 floats of a row in one 256-bit register per partial sum.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn blocks_avx2_9(
        &self,
        alpha: &[f32],
        first: usize,
        out: &mut [[f32; 9]],
        table: &mut Vec<f32>,
        mask: Option<&RowMask>,
    ) {
        use std::arch::x86_64::{
            __m256, _mm256_add_ps, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_set1_ps,
            _mm256_setzero_ps, _mm256_storeu_ps,
        };
        let scale = 1.0 / QUANTUM as f32;
        let (alpha9, _) = alpha.as_chunks::<9>();
        // One row's sum, `$col(e)` the coefficients of entry `e`'s column: a macro, so that
        // the intrinsics expand inside this function, which is compiled with their features.
        macro_rules! sum_row {
            ($row:expr, $o:expr, $col:expr) => {{
                let mut lo: [__m256; ACCUMULATORS] = [_mm256_setzero_ps(); ACCUMULATORS];
                let mut hi = [0.0f32; ACCUMULATORS];
                let (quads, rest) = $row.as_chunks::<ACCUMULATORS>();
                for quad in quads {
                    for a in 0..ACCUMULATORS {
                        let e = quad[a];
                        let v = (e >> 16) as f32;
                        let c: &[f32; 9] = $col(e);
                        // SAFETY: `c` is a `[f32; 9]`: its first 8 floats are readable.
                        let c8 = unsafe { _mm256_loadu_ps(c.as_ptr()) };
                        lo[a] = _mm256_fmadd_ps(_mm256_set1_ps(v), c8, lo[a]);
                        hi[a] = v.mul_add(c[8], hi[a]);
                    }
                }
                for (a, &e) in rest.iter().enumerate() {
                    let v = (e >> 16) as f32;
                    let c: &[f32; 9] = $col(e);
                    // SAFETY: as above.
                    let c8 = unsafe { _mm256_loadu_ps(c.as_ptr()) };
                    lo[a] = _mm256_fmadd_ps(_mm256_set1_ps(v), c8, lo[a]);
                    hi[a] = v.mul_add(c[8], hi[a]);
                }
                let sum = _mm256_add_ps(_mm256_add_ps(lo[0], lo[1]), _mm256_add_ps(lo[2], lo[3]));
                let sum = _mm256_mul_ps(sum, _mm256_set1_ps(scale));
                let o: &mut [f32; 9] = $o;
                // SAFETY: `o` is a `[f32; 9]`: its first 8 floats are writable.
                unsafe { _mm256_storeu_ps(o.as_mut_ptr(), sum) };
                o[8] = ((hi[0] + hi[1]) + (hi[2] + hi[3])) * scale;
            }};
        }
        for (q, rows) in out.chunks_mut(BLOCK_ROWS).enumerate() {
            let b = first + q;
            if mask.is_some_and(|m| !m.block(b)) {
                continue;
            }
            if let Some(m) = mask.filter(|m| self.few_rows(m, b)) {
                // Few rows wanted: their columns read where they are, without the table (the
                // same values, summed in the same order: the same bits).
                let cols = self.block_cols(b);
                for (r, o) in rows.iter_mut().enumerate() {
                    if m.row(b * BLOCK_ROWS + r) {
                        sum_row!(self.row(b * BLOCK_ROWS + r), o, |e: u32| &alpha9
                            [cols[(e & 0xffff) as usize] as usize]);
                    }
                }
                continue;
            }
            self.gather_table(alpha, 9, b, table);
            let (table, _) = table.as_chunks::<9>();
            for (r, o) in rows.iter_mut().enumerate() {
                if mask.is_some_and(|m| !m.row(b * BLOCK_ROWS + r)) {
                    continue;
                }
                // SAFETY: every local column of a block is below its number of columns
                // (`build` numbers them 0, 1, ... as it meets them), and the table holds one
                // row per column.
                sum_row!(self.row(b * BLOCK_ROWS + r), o, |e: u32| unsafe {
                    table.get_unchecked((e & 0xffff) as usize)
                });
            }
        }
    }

    /// Whether the rows `mask` holds in block `b` read fewer entries than the block has
    /// columns: then reading their columns in place costs less than gathering the block's
    /// table of columns first.
    #[inline]
    fn few_rows(&self, mask: &RowMask, b: usize) -> bool {
        let first = b * BLOCK_ROWS;
        let end = (first + BLOCK_ROWS).min(self.points);
        let entries: usize = (first..end)
            .filter(|&r| mask.row(r))
            .map(|r| (self.row_offsets[r + 1] - self.row_offsets[r]) as usize)
            .sum();
        entries < self.block_cols(b).len()
    }

    /// Copies the coefficients of block `b`'s local columns, `dim` per column, into `table`:
    /// the first step of a product for each block (public so that benchmarks can time it).
    /// (A row sums `q alpha` and is scaled by `1 / QUANTUM` once at the end.) Panics unless
    /// `b` is below the number of blocks and `alpha` holds `dim` floats per point.
    #[inline(always)]
    pub fn gather_table(&self, alpha: &[f32], dim: usize, b: usize, table: &mut Vec<f32>) {
        let cols = self.block_cols(b);
        table.resize(cols.len() * dim, 0.0);
        for (t, &k) in table.chunks_exact_mut(dim.max(1)).zip(cols) {
            let k = k as usize;
            t.copy_from_slice(&alpha[k * dim..k * dim + dim]);
        }
    }

    /// Rows of the blocks from `first` on into `out` (whole blocks but perhaps the last),
    /// those `mask` holds when there is one (the others are left as they are).
    /// `FMA` sums with `mul_add`, which is a single instruction only where compiled for it.
    #[inline(always)]
    fn blocks<const D: usize, const FMA: bool>(
        &self,
        alpha: &[f32],
        first: usize,
        out: &mut [[f32; D]],
        table: &mut Vec<f32>,
        mask: Option<&RowMask>,
    ) {
        let (alpha_d, _) = alpha.as_chunks::<D>();
        for (q, rows) in out.chunks_mut(BLOCK_ROWS).enumerate() {
            let b = first + q;
            if mask.is_some_and(|m| !m.block(b)) {
                continue;
            }
            let cols = self.block_cols(b);
            if mask.is_some_and(|m| self.few_rows(m, b)) {
                // Few rows wanted: their columns read where they are, without the table (the
                // same values, summed in the same order: the same bits).
                self.block_rows::<D, FMA>(b, rows, mask, |l| &alpha_d[cols[l] as usize]);
            } else {
                self.gather_table(alpha, D, b, table);
                let (table, _) = table.as_chunks::<D>();
                self.block_rows::<D, FMA>(b, rows, mask, |l| &table[l]);
            }
        }
    }

    /// The rows of block `b` that `mask` holds (all without one) into `rows`, `col(l)` the
    /// coefficients of the block's local column `l`.
    #[inline(always)]
    fn block_rows<'c, const D: usize, const FMA: bool>(
        &self,
        b: usize,
        rows: &mut [[f32; D]],
        mask: Option<&RowMask>,
        col: impl Fn(usize) -> &'c [f32; D],
    ) {
        let scale = 1.0 / QUANTUM as f32;
        let add = |acc: &mut [f32; D], e: u32| {
            let v = (e >> 16) as f32;
            let c = col((e & 0xffff) as usize);
            for d in 0..D {
                acc[d] = if FMA {
                    v.mul_add(c[d], acc[d])
                } else {
                    acc[d] + v * c[d]
                };
            }
        };
        for (r, o) in rows.iter_mut().enumerate() {
            if mask.is_some_and(|m| !m.row(b * BLOCK_ROWS + r)) {
                continue;
            }
            // Four partial sums (entries 4i, 4i+1, ...), so that consecutive entries do not
            // wait on each other's additions; combined in a fixed order.
            let mut acc = [[0.0f32; D]; ACCUMULATORS];
            let (quads, rest) = self.row(b * BLOCK_ROWS + r).as_chunks::<ACCUMULATORS>();
            for quad in quads {
                for (a, &e) in acc.iter_mut().zip(quad) {
                    add(a, e);
                }
            }
            for (a, &e) in acc.iter_mut().zip(rest) {
                add(a, e);
            }
            for d in 0..D {
                o[d] = ((acc[0][d] + acc[1][d]) + (acc[2][d] + acc[3][d])) * scale;
            }
        }
    }

    /// `flat = F alpha` with any number `dim` of floats per point (the portable kernel,
    /// without partial sums), through `scratch`; with a `mask`, only its rows.
    pub(super) fn apply_dyn(
        &self,
        alpha: &[f32],
        dim: usize,
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
        mask: Option<&RowMask>,
    ) {
        let scale = 1.0 / QUANTUM as f32;
        scratch.rows.resize(self.points * dim, 0.0);
        scratch
            .rows
            .par_chunks_mut(BLOCK_ROWS * dim)
            .enumerate()
            .for_each(|(b, out)| {
                if mask.is_some_and(|m| !m.block(b)) {
                    return;
                }
                let cols = self.block_cols(b);
                for (r, o) in out.chunks_exact_mut(dim).enumerate() {
                    if mask.is_some_and(|m| !m.row(b * BLOCK_ROWS + r)) {
                        continue;
                    }
                    o.fill(0.0);
                    for &e in self.row(b * BLOCK_ROWS + r) {
                        let v = (e >> 16) as f32 * scale;
                        let k = cols[(e & 0xffff) as usize] as usize;
                        let c = &alpha[k * dim..k * dim + dim];
                        for d in 0..dim {
                            o[d] += v * c[d];
                        }
                    }
                }
            });
        self.scatter(dim, flat, scratch);
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{all, coefficients, max_diff};
    use super::*;
    use mlt_format::test_support::plane_basis;

    #[test]
    fn kernels_agree() {
        let ib = plane_basis(5, 3);
        let op = FlattenOp::build(&ib, &all(&ib), None).unwrap();
        #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
        let mut kernels = vec![Kernel::Portable];
        #[cfg(target_arch = "x86_64")]
        kernels.extend([Kernel::Avx2Fma].into_iter().filter(|k| k.supported()));
        for dim in [1, 3, 9, 5] {
            let alpha = coefficients(&ib, dim);
            let runs: Vec<Vec<f32>> = kernels
                .iter()
                .map(|&k| {
                    let mut flat = vec![f32::NAN; alpha.len()];
                    op.apply_with(k, &alpha, dim, &mut flat, &mut FlattenScratch::default());
                    flat
                })
                .collect();
            let scale = runs[0].iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (k, run) in kernels.iter().zip(&runs) {
                assert!(max_diff(&runs[0], run) <= 1e-6 * scale, "dim {dim}, {k:?}");
            }
        }
    }

    /// Masked products give the whole product's bits on the rows they hold, with each kernel,
    /// whether a block's rows are many (summed from the block's table of columns) or few
    /// (read where they are), and leave the other rows alone.
    #[test]
    fn masked_rows_have_the_whole_products_bits_few_or_many() {
        let ib = plane_basis(6, 3);
        let op = FlattenOp::build(&ib, &all(&ib), None).unwrap();
        assert!(op.in_point_order() && op.block_count() >= 4);
        let n = op.points();
        #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
        let mut kernels = vec![Kernel::Portable];
        #[cfg(target_arch = "x86_64")]
        kernels.extend([Kernel::Avx2Fma].into_iter().filter(|k| k.supported()));
        // Block 0: every row; block 1: every third; the others: one row each.
        let rows: Vec<bool> = (0..n)
            .map(|r| match r / BLOCK_ROWS {
                0 => true,
                1 => r % 3 == 0,
                _ => r % BLOCK_ROWS == 7,
            })
            .collect();
        let mask = RowMask::from_rows(rows);
        let few = (0..op.block_count())
            .filter(|&b| op.few_rows(&mask, b))
            .count();
        assert!(!op.few_rows(&mask, 0) && few >= 2, "{few}");
        for dim in [3, 9] {
            let alpha = coefficients(&ib, dim);
            for &k in &kernels {
                let mut whole = vec![0.0; n * dim];
                op.apply_with(k, &alpha, dim, &mut whole, &mut FlattenScratch::default());
                let mut flat = vec![f32::NAN; n * dim];
                op.apply_then(
                    k,
                    &alpha,
                    dim,
                    &mut flat,
                    &mut FlattenScratch::default(),
                    Some(&mask),
                    |_, _| {},
                );
                for r in 0..n {
                    for d in 0..dim {
                        let (got, want) = (flat[r * dim + d], whole[r * dim + d]);
                        if mask.row(r) {
                            assert_eq!(got.to_bits(), want.to_bits(), "{k:?} {dim}: row {r}");
                        } else {
                            assert!(got.is_nan(), "{k:?} {dim}: row {r} written");
                        }
                    }
                }
            }
        }
    }
}
