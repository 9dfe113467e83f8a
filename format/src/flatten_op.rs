//! A precomputed sparse flattening operator (section 4.1): the matrix that maps hierarchical
//! coefficients `alpha` to flat coefficients `c_j = F_L(p_j) = sum_l sum_{k in X_l}
//! alpha_k B^l_k(p_j)` (Eq. 6, with the per-level Shepard basis of Eq. 2), so that the
//! per-frame flattening is one sparse product instead of `levels` R-tree queries per point
//! ([`crate::flatten::flatten`] is the reference).
//!
//! The product streams millions of entries per frame (46 per point on Sponza), so the layout is
//! chosen for memory traffic and cache use:
//!
//! - Rows (flat points) are stored level by level, each level's points in Morton order
//!   ([`crate::morton`]). The bake stores its points in that order, so for its files the
//!   storage order is the point order and rows are written in place; files with another order
//!   cost one reordering pass per product. Rows are cut into blocks of [`BLOCK_ROWS`] rows.
//!   Each block lists the hierarchical points its rows read (its local columns, about 600 on
//!   Sponza, in ascending order); a product first copies their coefficients into a small table
//!   that stays in L1 cache, then every entry reads from that table.
//! - An entry is one 32-bit word: the local column in the low 16 bits and the value
//!   `B^l_k(p_j)` in the high 16 bits, as a fixed-point fraction of 65535. The values of one
//!   row and level are rounded together (largest remainders), so that they keep their exact
//!   sum: where a level's functions all have a coefficient, the row still reproduces a constant
//!   exactly (the partition of unity of Eq. 2). Each value is within `1/65535` of the exact
//!   one.
//! - By default values below [`DEFAULT_DROP_BELOW`] are dropped and their weight given to the
//!   rest of their row and level ([`FlattenOptions`]): 14 % fewer entries on Sponza for a
//!   relative RMS change of 8e-4 in the flat coefficients. [`FlattenOptions::EXACT`] keeps them.
//! - Columns that are zero by construction are dropped when building (receivers without links,
//!   section 3.3: most fine receivers), so they cost nothing per frame.
//!
//! Each row is summed in its stored order, whatever the thread that computes it, so the result
//! is the same for any rayon thread count. On x86-64 CPUs with AVX2 and FMA (detected at run
//! time, [`Kernel`]) the rows are summed with fused multiply-adds, 8 of a point's 9 floats in
//! one register; the result then differs from other CPUs in the last bits, never between runs
//! on one machine. (A kernel with AVX-512, all 9 floats in one masked register, measured no
//! faster.)
//!
//! Measured on Sponza (BENCHMARKS.md): 6.0 M entries, 28 MB, 6-8 ms per product of 9 floats
//! per point on this project's 2-vCPU machine. (A two-stage variant that carried the coarse
//! levels to finer points through an intermediate level's Shepard basis halved the entries but
//! moved the result by 18 % on Sponza, and was dropped.)

use rayon::prelude::*;

use crate::error::FormatError;
use crate::morton::morton_order;
use crate::shepard::{IndexedBasis, MIN_WEIGHT_SUM};

/// Points per block of the parallel build.
const BUILD_BLOCK: usize = 2048;

/// Rows per block of stored rows, sharing one table of local columns.
pub const BLOCK_ROWS: usize = 128;

/// Blocks per task of a parallel product.
const TASK_BLOCKS: usize = 8;

/// Fixed-point scale of a stored value: `B = q / QUANTUM`.
pub const QUANTUM: u32 = 65535;

/// Partial sums per row in a product (see [`FlattenOp::blocks`]).
const ACCUMULATORS: usize = 4;

/// Largest number of distinct columns one block may read (16-bit local columns).
const MAX_LOCAL: usize = 1 << 16;

/// How a [`FlattenOp`] is built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlattenOptions {
    /// Normalised values `B^l_k(p_j)` below this are dropped from a row, their weight given to
    /// the other values of the same row and level (which keep their sum).
    pub drop_below: f64,
}

impl FlattenOptions {
    /// Nothing dropped but what rounds to zero: the operator equals
    /// [`crate::flatten::flatten`] within `1/65535` per value.
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

/// Values below this are dropped by default: on Sponza they are 14 % of the entries and
/// 0.05 % of the weight, and the flat coefficients move by 8e-4 (relative RMS) from the exact
/// operator's.
pub const DEFAULT_DROP_BELOW: f64 = 1e-3;

/// The flattening operator `c = F alpha`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlattenOp {
    /// Number of flat (and hierarchical) points.
    points: usize,
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

/// Rounds the normalised values `group[..].1` of one row and level to multiples of
/// `1/QUANTUM` that keep their rounded sum (largest remainders, ties by position), appending
/// the non-zero ones to `ks`/`qs`. Values below `drop_below` are left out first and the others
/// scaled up to the same sum. `order` is scratch.
fn quantise_group(
    group: &mut Vec<(u32, f64)>,
    drop_below: f64,
    ks: &mut Vec<u32>,
    qs: &mut Vec<u16>,
    order: &mut Vec<(f64, usize)>,
) {
    let scale = QUANTUM as f64;
    let total = group.iter().map(|g| g.1).sum::<f64>();
    let target = (total * scale).round() as i64;
    if drop_below > 0.0 {
        group.retain(|g| g.1 >= drop_below);
        let kept: f64 = group.iter().map(|g| g.1).sum();
        if kept > 0.0 {
            for g in group.iter_mut() {
                g.1 *= total / kept;
            }
        }
    }
    let floors: i64 = group.iter().map(|g| (g.1 * scale).floor() as i64).sum();
    // 0 <= deficit <= group.len(): the floors sum to an integer at most the scaled sum.
    let deficit = (target - floors).clamp(0, group.len() as i64) as usize;
    order.clear();
    order.extend(
        group
            .iter()
            .enumerate()
            .map(|(e, g)| (g.1 * scale - (g.1 * scale).floor(), e)),
    );
    // Largest remainder first; the sort is total (remainders are finite, positions distinct).
    order.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let start = qs.len();
    for &(k, w) in group.iter() {
        ks.push(k);
        qs.push((w * scale).floor().min(scale) as u16);
    }
    for &(_, e) in &order[..deficit] {
        let q = &mut qs[start + e];
        *q = q.saturating_add(1).min(QUANTUM as u16);
    }
    // Drop what rounded to zero.
    let mut w = start;
    for r in start..qs.len() {
        if qs[r] > 0 {
            ks[w] = ks[r];
            qs[w] = qs[r];
            w += 1;
        }
    }
    ks.truncate(w);
    qs.truncate(w);
}

impl FlattenOp {
    /// Builds the default operator ([`FlattenOptions::default`]) over all levels of `ib`, in
    /// parallel (same result for any thread count). With `keep`, only the columns `k` with
    /// `keep[k]` are stored; a product then treats the coefficients of the others as zero.
    pub fn build(ib: &IndexedBasis, keep: Option<&[bool]>) -> Result<FlattenOp, FormatError> {
        FlattenOp::build_with(ib, keep, FlattenOptions::default())
    }

    /// [`FlattenOp::build`] with chosen options.
    pub fn build_with(
        ib: &IndexedBasis,
        keep: Option<&[bool]>,
        options: FlattenOptions,
    ) -> Result<FlattenOp, FormatError> {
        let b = &ib.basis;
        let n = b.len();
        let levels = ib.levels();
        if let Some(keep) = keep {
            if keep.len() != n {
                return Err(FormatError::InvalidBasis(format!(
                    "flattening operator: {} column flags for {n} points",
                    keep.len()
                )));
            }
        }
        let kept = |k: usize| keep.is_none_or(|m| m[k]);
        let drop_below = options.drop_below.max(0.0);
        // Rows by point index, in fixed blocks: entries per row, columns, quantised values.
        #[derive(Default)]
        struct Rows {
            counts: Vec<u32>,
            ks: Vec<u32>,
            qs: Vec<u16>,
        }
        let blocks: Vec<Rows> = (0..n.div_ceil(BUILD_BLOCK))
            .into_par_iter()
            .map(|blk| {
                let range = blk * BUILD_BLOCK..((blk + 1) * BUILD_BLOCK).min(n);
                let mut rows = Rows::default();
                let mut level: Vec<(u32, f32)> = Vec::new();
                let mut group: Vec<(u32, f64)> = Vec::new();
                let mut order = Vec::new();
                for j in range {
                    let (x, nj) = (b.positions[j], b.normals[j]);
                    let before = rows.ks.len();
                    for l in 0..levels {
                        level.clear();
                        let sum = ib.for_each_weight(l, x, nj, |k, w| level.push((k as u32, w)));
                        if sum <= MIN_WEIGHT_SUM {
                            continue;
                        }
                        let inv = 1.0 / sum as f64;
                        group.clear();
                        group.extend(
                            level
                                .iter()
                                .filter(|(k, _)| kept(*k as usize))
                                .map(|&(k, w)| (k, w as f64 * inv)),
                        );
                        quantise_group(
                            &mut group,
                            drop_below,
                            &mut rows.ks,
                            &mut rows.qs,
                            &mut order,
                        );
                    }
                    rows.counts.push((rows.ks.len() - before) as u32);
                }
                rows
            })
            .collect();
        let total: usize = blocks.iter().map(|rows| rows.ks.len()).sum();
        if total >= u32::MAX as usize {
            return Err(FormatError::InvalidBasis(format!(
                "flattening operator: {total} entries do not fit 32-bit offsets"
            )));
        }
        // Where each point's row starts in its build block.
        let mut row_at = Vec::with_capacity(n);
        for (blk, rows) in blocks.iter().enumerate() {
            let mut at = 0usize;
            for &c in &rows.counts {
                row_at.push((blk, at, c as usize));
                at += c as usize;
            }
        }
        // Storage order: each level's points in Morton order (the bake stores them so: then
        // this is the identity and the rows need no reordering).
        let mut order = Vec::with_capacity(n);
        for l in 0..levels {
            let range = b.level_range(l);
            order.extend(
                morton_order(&b.positions[range.clone()])
                    .into_iter()
                    .map(|i| i + range.start as u32),
            );
        }
        let identity = order.iter().enumerate().all(|(i, &j)| i == j as usize);
        let mut position = vec![0u32; n];
        for (pos, &j) in order.iter().enumerate() {
            position[j as usize] = pos as u32;
        }
        // Blocks of stored rows, each with its local columns in ascending point order, so
        // that gathering a block's table walks the coefficients forwards (with Morton-ordered
        // points, in a few runs per level).
        let row = |j: u32| {
            let (blk, at, count) = row_at[j as usize];
            let r = &blocks[blk];
            (&r.ks[at..at + count], &r.qs[at..at + count])
        };
        let mut local_of = vec![u32::MAX; n];
        let mut used = vec![false; n];
        let mut row_offsets = Vec::with_capacity(n + 1);
        row_offsets.push(0u32);
        let mut block_offsets = vec![0u32];
        let mut block_cols: Vec<u32> = Vec::new();
        let mut entries = Vec::with_capacity(total);
        for rows in order.chunks(BLOCK_ROWS) {
            let first = block_cols.len();
            for &j in rows {
                for &k in row(j).0 {
                    used[k as usize] = true;
                    if local_of[k as usize] == u32::MAX {
                        // In this block; numbered once all are known.
                        local_of[k as usize] = 0;
                        block_cols.push(k);
                    }
                }
            }
            let cols = &mut block_cols[first..];
            if cols.len() > MAX_LOCAL {
                return Err(FormatError::InvalidBasis(format!(
                    "flattening operator: the {BLOCK_ROWS} points around point {} read more \
                     than {MAX_LOCAL} basis functions",
                    rows[0]
                )));
            }
            cols.sort_unstable();
            for (local, &k) in cols.iter().enumerate() {
                local_of[k as usize] = local as u32;
            }
            for &j in rows {
                let (ks, qs) = row(j);
                for (&k, &q) in ks.iter().zip(qs) {
                    entries.push(local_of[k as usize] | (u32::from(q) << 16));
                }
                row_offsets.push(entries.len() as u32);
            }
            for &k in cols.iter() {
                local_of[k as usize] = u32::MAX;
            }
            block_offsets.push(block_cols.len() as u32);
        }
        if block_cols.len() >= u32::MAX as usize {
            return Err(FormatError::InvalidBasis(format!(
                "flattening operator: {} block columns do not fit 32-bit offsets",
                block_cols.len()
            )));
        }
        Ok(FlattenOp {
            points: n,
            columns: used.iter().filter(|u| **u).count(),
            position,
            identity,
            order,
            row_offsets,
            block_offsets,
            block_cols,
            entries,
        })
    }

    /// Number of points (flat and hierarchical).
    pub fn points(&self) -> usize {
        self.points
    }

    /// Number of distinct hierarchical points read.
    pub fn columns(&self) -> usize {
        self.columns
    }

    /// Number of stored entries `B^l_k(p_j)`.
    pub fn entries(&self) -> usize {
        self.entries.len()
    }

    /// True when the storage order is the point order (the basis stores each level's points
    /// in Morton order, as the bake does): products then need no reordering pass.
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

    /// `flat = F alpha` with `dim` floats per point: `alpha.len() == flat.len() == points *
    /// dim`; `scratch` keeps its buffers for the next call. Panics on other lengths.
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
        assert!(alpha.len() == self.points * dim && flat.len() == self.points * dim);
        assert!(kernel.supported(), "this CPU cannot run {kernel:?}");
        if dim == 0 {
            return;
        }
        match dim {
            1 => self.apply_n::<1>(kernel, alpha, flat, scratch),
            3 => self.apply_n::<3>(kernel, alpha, flat, scratch),
            9 => self.apply_n::<9>(kernel, alpha, flat, scratch),
            _ => self.apply_dyn(alpha, dim, flat, scratch),
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

    fn apply_n<const D: usize>(
        &self,
        kernel: Kernel,
        alpha: &[f32],
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
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
                match kernel {
                    Kernel::Portable => self.blocks::<D, false>(alpha, first, out, table),
                    #[cfg(target_arch = "x86_64")]
                    Kernel::Avx2Fma => {
                        if let Some(out9) = as_rows9(out) {
                            // SAFETY: `apply_with` asserted that this CPU runs `kernel` (has
                            // AVX2 and FMA), the only requirement for calling a function
                            // compiled with them.
                            unsafe { self.blocks_avx2_9(alpha, first, out9, table) }
                        } else {
                            // SAFETY: as above.
                            unsafe { self.blocks_avx2::<D>(alpha, first, out, table) }
                        }
                    }
                }
            });
        if !self.identity {
            self.scatter(D, flat, scratch);
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
    ) {
        self.blocks::<D, true>(alpha, first, out, table);
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
    ) {
        use std::arch::x86_64::{
            __m256, _mm256_add_ps, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_set1_ps,
            _mm256_setzero_ps, _mm256_storeu_ps,
        };
        let scale = 1.0 / QUANTUM as f32;
        for (q, rows) in out.chunks_mut(BLOCK_ROWS).enumerate() {
            let b = first + q;
            self.gather_table(alpha, 9, b, table);
            let (table, _) = table.as_chunks::<9>();
            for (r, o) in rows.iter_mut().enumerate() {
                let mut lo: [__m256; ACCUMULATORS] = [_mm256_setzero_ps(); ACCUMULATORS];
                let mut hi = [0.0f32; ACCUMULATORS];
                let (quads, rest) = self.row(b * BLOCK_ROWS + r).as_chunks::<ACCUMULATORS>();
                for quad in quads {
                    for a in 0..ACCUMULATORS {
                        let e = quad[a];
                        let v = (e >> 16) as f32;
                        // SAFETY: every local column of a block is below its number of
                        // columns (`build` numbers them 0, 1, ... as it meets them), and the
                        // table holds one row per column.
                        let c = unsafe { table.get_unchecked((e & 0xffff) as usize) };
                        // SAFETY: `c` is a `[f32; 9]`: its first 8 floats are readable.
                        let c8 = unsafe { _mm256_loadu_ps(c.as_ptr()) };
                        lo[a] = _mm256_fmadd_ps(_mm256_set1_ps(v), c8, lo[a]);
                        hi[a] = v.mul_add(c[8], hi[a]);
                    }
                }
                for (a, &e) in rest.iter().enumerate() {
                    let v = (e >> 16) as f32;
                    // SAFETY: as above.
                    let c = unsafe { table.get_unchecked((e & 0xffff) as usize) };
                    // SAFETY: as above.
                    let c8 = unsafe { _mm256_loadu_ps(c.as_ptr()) };
                    lo[a] = _mm256_fmadd_ps(_mm256_set1_ps(v), c8, lo[a]);
                    hi[a] = v.mul_add(c[8], hi[a]);
                }
                let sum = _mm256_add_ps(_mm256_add_ps(lo[0], lo[1]), _mm256_add_ps(lo[2], lo[3]));
                let sum = _mm256_mul_ps(sum, _mm256_set1_ps(scale));
                // SAFETY: `o` is a `[f32; 9]`: its first 8 floats are writable.
                unsafe { _mm256_storeu_ps(o.as_mut_ptr(), sum) };
                o[8] = ((hi[0] + hi[1]) + (hi[2] + hi[3])) * scale;
            }
        }
    }

    /// Copies the coefficients of block `b`'s local columns, `dim` per column, into `table`.
    /// (A row sums `q alpha` and is scaled by `1 / QUANTUM` once at the end.)
    #[inline(always)]
    fn gather_table(&self, alpha: &[f32], dim: usize, b: usize, table: &mut Vec<f32>) {
        let cols = self.block_cols(b);
        table.resize(cols.len() * dim, 0.0);
        for (t, &k) in table.chunks_exact_mut(dim.max(1)).zip(cols) {
            let k = k as usize;
            t.copy_from_slice(&alpha[k * dim..k * dim + dim]);
        }
    }

    /// Rows of the blocks from `first` on into `out` (whole blocks but perhaps the last).
    /// `FMA` sums with `mul_add`, which is a single instruction only where compiled for it.
    #[inline(always)]
    fn blocks<const D: usize, const FMA: bool>(
        &self,
        alpha: &[f32],
        first: usize,
        out: &mut [[f32; D]],
        table: &mut Vec<f32>,
    ) {
        let scale = 1.0 / QUANTUM as f32;
        for (q, rows) in out.chunks_mut(BLOCK_ROWS).enumerate() {
            let b = first + q;
            self.gather_table(alpha, D, b, table);
            let (table, _) = table.as_chunks::<D>();
            let add = |acc: &mut [f32; D], e: u32| {
                let v = (e >> 16) as f32;
                let c = &table[(e & 0xffff) as usize];
                for d in 0..D {
                    acc[d] = if FMA {
                        v.mul_add(c[d], acc[d])
                    } else {
                        acc[d] + v * c[d]
                    };
                }
            };
            for (r, o) in rows.iter_mut().enumerate() {
                // Four partial sums (entries 4i, 4i+1, ...), so that consecutive entries do
                // not wait on each other's additions; combined in a fixed order.
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
    }

    fn apply_dyn(&self, alpha: &[f32], dim: usize, flat: &mut [f32], scratch: &mut FlattenScratch) {
        let scale = 1.0 / QUANTUM as f32;
        scratch.rows.resize(self.points * dim, 0.0);
        scratch
            .rows
            .par_chunks_mut(BLOCK_ROWS * dim)
            .enumerate()
            .for_each(|(b, out)| {
                let cols = self.block_cols(b);
                for (r, o) in out.chunks_exact_mut(dim).enumerate() {
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
    use super::*;
    use crate::flatten::flatten;
    use crate::pull_push::project;
    use crate::shepard::tests::plane_basis;

    /// Coefficients of a smooth function, 9 per point, with some points zeroed.
    fn coefficients(ib: &IndexedBasis, dim: usize) -> Vec<f32> {
        let mut samples = Vec::with_capacity(ib.basis.len() * dim);
        for (j, p) in ib.basis.positions.iter().enumerate() {
            for d in 0..dim {
                let v = (3.0 * p[0] + d as f32).sin() * (2.0 * p[1]).cos() + 0.1 * d as f32;
                samples.push(if j % 5 == 3 { 0.0 } else { v });
            }
        }
        project(ib, &samples, dim).0
    }

    fn max_diff(a: &[f32], b: &[f32]) -> f32 {
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
        let dim = alpha.len() / op.points();
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
        let op = FlattenOp::build_with(&ib, None, FlattenOptions::EXACT).unwrap();
        assert_eq!(op.columns(), ib.basis.len());
        for dim in [1, 3, 9, 4] {
            let alpha = coefficients(&ib, dim);
            let reference = flatten(&ib, &alpha, dim);
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
        for options in [FlattenOptions::EXACT, FlattenOptions::default()] {
            let op = FlattenOp::build_with(&ib, None, options).unwrap();
            let n = ib.basis.len();
            for l in 0..ib.levels() {
                let mut alpha = vec![0.0f32; n];
                for k in ib.basis.level_range(l) {
                    alpha[k] = 0.7;
                }
                let mut flat = vec![f32::NAN; n];
                op.apply(&alpha, 1, &mut flat, &mut FlattenScratch::default());
                for (j, &v) in flat.iter().enumerate() {
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
        let exact = FlattenOp::build_with(&ib, None, FlattenOptions::EXACT).unwrap();
        let dropped = FlattenOp::build(&ib, None).unwrap();
        // Fewer entries, and the kept ones still sum to one per row and level (tested above).
        assert!(dropped.entries() < exact.entries() * 97 / 100);
        let alpha = coefficients(&ib, 9);
        let run = |op: &FlattenOp| {
            let mut flat = vec![f32::NAN; alpha.len()];
            op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
            flat
        };
        let rms = rel_rms(&run(&dropped), &run(&exact));
        assert!(rms < 1e-3, "relative rms {rms}");
    }

    #[test]
    fn quantised_groups_keep_their_sum() {
        let group: Vec<(u32, f64)> = [0.5, 0.25, 0.125, 0.0625, 0.0625 - 1e-7, 1e-7]
            .iter()
            .enumerate()
            .map(|(k, &w)| (k as u32, w / 3.0))
            .collect();
        let (mut ks, mut qs, mut order) = (vec![99], vec![7], Vec::new());
        quantise_group(&mut group.clone(), 0.0, &mut ks, &mut qs, &mut order);
        // What was there is kept; the value that rounds to zero is dropped.
        assert_eq!((ks[0], qs[0]), (99, 7));
        assert_eq!(ks[1..], [0, 1, 2, 3, 4]);
        let sum: u32 = qs[1..].iter().map(|&q| u32::from(q)).sum();
        let exact: f64 = group.iter().map(|g| g.1).sum();
        assert_eq!(sum, (exact * QUANTUM as f64).round() as u32);
        for (q, g) in qs[1..].iter().zip(&group) {
            assert!(
                (f64::from(*q) - g.1 * QUANTUM as f64).abs() < 1.0,
                "{q} {}",
                g.1
            );
        }
    }

    #[test]
    fn dropped_columns_count_as_zero_coefficients() {
        let ib = plane_basis(4, 3);
        let n = ib.basis.len();
        let keep: Vec<bool> = (0..n).map(|k| k % 3 != 0).collect();
        let op = FlattenOp::build_with(&ib, Some(&keep), FlattenOptions::EXACT).unwrap();
        let full = FlattenOp::build_with(&ib, None, FlattenOptions::EXACT).unwrap();
        assert!(op.entries() < full.entries() && op.bytes() < full.bytes());
        let mut alpha = coefficients(&ib, 9);
        let mut flat = vec![0.0; alpha.len()];
        op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
        for k in (0..n).filter(|k| !keep[*k]) {
            alpha[k * 9..k * 9 + 9].fill(0.0);
        }
        let reference = flatten(&ib, &alpha, 9);
        assert_within_quantisation(&op, &alpha, &flat, &reference);
        // The dropped coefficients did matter.
        let mut all = vec![0.0; alpha.len()];
        full.apply(
            &coefficients(&ib, 9),
            9,
            &mut all,
            &mut FlattenScratch::default(),
        );
        assert!(max_diff(&flat, &all) > 1e-2);
        assert!(FlattenOp::build(&ib, Some(&keep[1..])).is_err());
    }

    #[test]
    fn kernels_agree() {
        let ib = plane_basis(5, 3);
        let op = FlattenOp::build(&ib, None).unwrap();
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

    #[test]
    fn same_bits_for_any_thread_count() {
        // Enough points for several build blocks and product tasks.
        let ib = plane_basis(6, 5);
        assert!(ib.basis.len() > 4 * BUILD_BLOCK, "{}", ib.basis.len());
        assert!(ib.basis.len() > 4 * TASK_BLOCKS * BLOCK_ROWS);
        let alpha = coefficients(&ib, 9);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let op = FlattenOp::build(&ib, None).unwrap();
                let mut flat = vec![0.0; alpha.len()];
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
        assert!(rel_rms(&f1, &flatten(&ib, &alpha, 9)) < 1e-3);
    }
}

#[cfg(test)]
mod bench {
    use super::*;
    use crate::file::BakedFile;
    use crate::links::{ReceiverLinks, LINK_DIM};
    use std::time::Instant;

    /// Times and errors on a baked file: `MLT_BENCH_FILE=F cargo test --release -p
    /// mlt-format flatten_op::bench -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn flatten_operator_on_a_baked_file() {
        let Ok(path) = std::env::var("MLT_BENCH_FILE") else {
            eprintln!("MLT_BENCH_FILE is not set");
            return;
        };
        let rounds: usize = std::env::var("MLT_BENCH_ROUNDS")
            .ok()
            .and_then(|r| r.parse().ok())
            .unwrap_or(9);
        let file = BakedFile::open(std::path::Path::new(&path)).unwrap();
        let ib = file.basis().unwrap();
        let lb = file.links_bytes().unwrap().unwrap();
        let links = file.access_links(&lb).unwrap();
        let mut keep = vec![false; ib.basis.len()];
        for r in links.receiver_ids.iter() {
            keep[r.to_native() as usize] = true;
        }
        let rl = ReceiverLinks::build(links);
        let senders = links.senders.to_native() as usize;
        // Two direct-light patterns: smooth in space, and rough (neighbouring senders differ).
        let smooth: Vec<f32> = (0..senders * 3)
            .map(|k| {
                let p = ib.basis.positions[k / 3];
                1.0 + 0.8 * (0.4 * p[0] + (k % 3) as f32).sin() * (0.3 * p[2]).cos()
            })
            .collect();
        let rough: Vec<f32> = (0..senders * 3).map(|k| 1.0 + (k % 7) as f32).collect();
        let n = ib.basis.len();
        let mut exact_flat = Vec::new();
        let mut variants = vec![
            ("exact", FlattenOptions::EXACT),
            ("default", FlattenOptions::default()),
        ];
        if let Ok(list) = std::env::var("MLT_BENCH_DROP") {
            for d in list.split(',').filter_map(|d| d.parse::<f64>().ok()) {
                variants.push(("drop", FlattenOptions { drop_below: d }));
            }
        }
        for (name, options) in variants {
            eprintln!("{name}: {options:?}");
            let t = Instant::now();
            let op = FlattenOp::build_with(&ib, Some(&keep), options).unwrap();
            eprintln!(
                "{name}: build {:.0} ms, {} columns ({:.0} per block of {BLOCK_ROWS} rows), {} \
                 entries ({:.1} per point), {:.1} MB, stored in point order: {}",
                t.elapsed().as_secs_f64() * 1e3,
                op.columns(),
                op.block_cols.len() as f64 / (op.block_offsets.len() - 1) as f64,
                op.entries(),
                op.entries() as f64 / n as f64,
                op.bytes() as f64 / 1e6,
                op.identity
            );
            let mut i = vec![0.0f32; n * LINK_DIM];
            let mut flat = vec![0.0f32; i.len()];
            let mut scratch = FlattenScratch::default();
            for (pattern, e) in [("smooth", &smooth), ("rough", &rough)] {
                rl.apply(e, 0.0, &mut i);
                op.apply(&i, LINK_DIM, &mut flat, &mut scratch);
                if name == "exact" {
                    exact_flat.push(flat.clone());
                    continue;
                }
                let reference = &exact_flat[if pattern == "smooth" { 0 } else { 1 }];
                let (mut num, mut den) = (0.0f64, 0.0f64);
                for (x, y) in flat.iter().zip(reference) {
                    num += f64::from(x - y).powi(2);
                    den += f64::from(*y).powi(2);
                }
                eprintln!(
                    "  {pattern} direct light: relative rms difference from exact {:.2e}",
                    (num / den).sqrt()
                );
            }
            let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
            let mut times = Vec::new();
            for round in 0..rounds {
                let t = Instant::now();
                rl.apply(if round % 2 == 0 { &smooth } else { &rough }, 0.0, &mut i);
                let t1 = Instant::now();
                op.apply(&i, LINK_DIM, &mut flat, &mut scratch);
                let t2 = Instant::now();
                op.apply_with(Kernel::Portable, &i, LINK_DIM, &mut flat, &mut scratch);
                let t3 = Instant::now();
                #[cfg(target_arch = "x86_64")]
                if Kernel::Avx2Fma.supported() {
                    op.apply_with(Kernel::Avx2Fma, &i, LINK_DIM, &mut flat, &mut scratch);
                }
                let t4 = Instant::now();
                times.push((ms(t, t1), ms(t1, t2), ms(t2, t3), ms(t3, t4)));
            }
            {
                let t = Instant::now();
                let mut table = Vec::new();
                let mut sum = 0.0f32;
                for b in 0..op.block_offsets.len() - 1 {
                    op.gather_table(&i, LINK_DIM, b, &mut table);
                    sum += table[0];
                }
                eprintln!(
                    "  gathering the tables alone, one thread: {:.2} ms ({sum})",
                    t.elapsed().as_secs_f64() * 1e3
                );
            }
            let median = |f: fn(&(f64, f64, f64, f64)) -> f64| {
                let mut v: Vec<f64> = times.iter().map(f).collect();
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            eprintln!(
                "  medians of {rounds}: S e {:.2} ms, flatten {:.2} ms ({:?}); portable kernel \
                 {:.2} ms, AVX2 kernel {:.2} ms",
                median(|t| t.0),
                median(|t| t.1),
                Kernel::detect(),
                median(|t| t.2),
                median(|t| t.3)
            );
        }
    }
}
