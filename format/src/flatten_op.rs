//! A precomputed sparse flattening operator (section 4.1): the matrix that maps hierarchical
//! coefficients `alpha` to flat coefficients `c_j = F_L(p_j) = sum_l sum_{k in X_l}
//! alpha_k B^l_k(p_j)` (Eq. 6, with the per-level Shepard basis of Eq. 2), so that the
//! per-frame flattening is one sparse product instead of `levels` R-tree queries per point
//! ([`crate::flatten::flatten`] is the reference).
//!
//! Storage is row-major (one row per flat point `j`, entries `(column, B^l_k(p_j))`) in flat
//! arrays. Columns that are zero by construction are dropped when building (receivers without
//! links, section 3.3: most fine receivers), so they cost nothing per frame. The product is
//! bound by fetching coefficients, so rows are stored in a spatially coherent order (Morton
//! order of the points) and columns are numbered in order of first use along it: neighbouring
//! rows then share the coefficients they read, which stay in cache. (A column-major scatter,
//! which could also skip columns that are dark in one frame, measured 2-3x slower on Sponza,
//! where 94 % of the linked receivers are lit in every frame.)
//!
//! Each row is summed in its stored order, whatever the thread that computes it, so the result
//! is the same for any rayon thread count.

use rayon::prelude::*;

use crate::error::FormatError;
use crate::shepard::{IndexedBasis, MIN_WEIGHT_SUM};

/// Rows per block of the parallel build and per task of a product.
const BLOCK: usize = 2048;

/// The flattening operator `c = F alpha`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlattenOp {
    /// Number of flat (and hierarchical) points.
    points: usize,
    /// Hierarchical point of each stored column, numbered in order of first use.
    cols: Vec<u32>,
    /// Flat points in storage order (a permutation of `0..points`).
    order: Vec<u32>,
    /// `points + 1` offsets into `slots`/`values`, by storage position.
    offsets: Vec<u32>,
    /// Column of each entry.
    slots: Vec<u32>,
    /// `B^l_k(p_j)` of each entry.
    values: Vec<f32>,
}

/// Borrowed arrays of a [`FlattenOp`] (see [`FlattenOp::parts`]).
#[derive(Clone, Copy, Debug)]
pub struct FlattenOpParts<'a> {
    pub cols: &'a [u32],
    pub order: &'a [u32],
    pub offsets: &'a [u32],
    pub slots: &'a [u32],
    pub values: &'a [f32],
}

/// Buffers a product reuses from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct FlattenScratch {
    coefficients: Vec<f32>,
    rows: Vec<f32>,
}

/// 63-bit Morton code of `p` quantised over the box `lo..hi` (21 bits per axis).
fn morton(p: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> u64 {
    let mut code = 0u64;
    for a in 0..3 {
        let extent = hi[a] - lo[a];
        let t = if extent > 0.0 {
            ((p[a] - lo[a]) / extent).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = (t * ((1u32 << 21) - 1) as f32) as u64;
        for bit in 0..21 {
            code |= ((q >> bit) & 1) << (3 * bit + a);
        }
    }
    code
}

impl FlattenOp {
    /// Builds the operator over all levels of `ib`, in parallel (same result for any thread
    /// count). With `keep`, only the columns `k` with `keep[k]` are stored; a product then
    /// treats the coefficients of the others as zero.
    pub fn build(ib: &IndexedBasis, keep: Option<&[bool]>) -> Result<FlattenOp, FormatError> {
        let b = &ib.basis;
        let n = b.len();
        if let Some(keep) = keep {
            if keep.len() != n {
                return Err(FormatError::InvalidBasis(format!(
                    "flattening operator: {} column flags for {n} points",
                    keep.len()
                )));
            }
        }
        let kept = |k: usize| keep.is_none_or(|m| m[k]);
        // Rows by point index, in fixed blocks: (entries per row, column ids, values).
        let blocks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|blk| {
                let range = blk * BLOCK..((blk + 1) * BLOCK).min(n);
                let mut counts = Vec::with_capacity(range.len());
                let (mut ks, mut vs) = (Vec::new(), Vec::new());
                let mut level: Vec<(u32, f32)> = Vec::new();
                for j in range {
                    let (x, nj) = (b.positions[j], b.normals[j]);
                    let before = ks.len();
                    for l in 0..ib.levels() {
                        level.clear();
                        let sum = ib.for_each_weight(l, x, nj, |k, w| level.push((k as u32, w)));
                        if sum > MIN_WEIGHT_SUM {
                            let inv = 1.0 / sum;
                            for &(k, w) in &level {
                                if kept(k as usize) {
                                    ks.push(k);
                                    vs.push(w * inv);
                                }
                            }
                        }
                    }
                    counts.push((ks.len() - before) as u32);
                }
                (counts, ks, vs)
            })
            .collect();
        let total: usize = blocks.iter().map(|(_, ks, _)| ks.len()).sum();
        if total >= u32::MAX as usize {
            return Err(FormatError::InvalidBasis(format!(
                "flattening operator: {total} entries do not fit 32-bit offsets"
            )));
        }
        // Where each point's row starts in its block.
        let mut row_at = Vec::with_capacity(n);
        for (blk, (counts, _, _)) in blocks.iter().enumerate() {
            let mut at = 0usize;
            for &c in counts {
                row_at.push((blk, at, c as usize));
                at += c as usize;
            }
        }
        // Storage order: Morton order of the points (ties by index).
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &b.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let mut keyed: Vec<(u64, u32)> = b
            .positions
            .iter()
            .enumerate()
            .map(|(j, &p)| (morton(p, lo, hi), j as u32))
            .collect();
        keyed.sort_unstable();
        let order: Vec<u32> = keyed.into_iter().map(|(_, j)| j).collect();
        // Columns numbered by first use; entries in storage order.
        let mut slot_of = vec![u32::MAX; n];
        let mut cols = Vec::new();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0u32);
        let mut slots = Vec::with_capacity(total);
        let mut values = Vec::with_capacity(total);
        for &j in &order {
            let (blk, at, count) = row_at[j as usize];
            let (_, ks, vs) = &blocks[blk];
            for e in at..at + count {
                let k = ks[e] as usize;
                if slot_of[k] == u32::MAX {
                    slot_of[k] = cols.len() as u32;
                    cols.push(k as u32);
                }
                slots.push(slot_of[k]);
                values.push(vs[e]);
            }
            offsets.push(slots.len() as u32);
        }
        Ok(FlattenOp {
            points: n,
            cols,
            order,
            offsets,
            slots,
            values,
        })
    }

    /// Number of points (flat and hierarchical).
    pub fn points(&self) -> usize {
        self.points
    }

    /// Number of stored columns.
    pub fn columns(&self) -> usize {
        self.cols.len()
    }

    /// Number of stored entries `B^l_k(p_j)`.
    pub fn entries(&self) -> usize {
        self.values.len()
    }

    /// The operator's arrays, for evaluating it elsewhere (the viewer's GPU compute pass):
    /// storage position `pos` computes flat point `order[pos]` as the sum over
    /// `e in offsets[pos]..offsets[pos + 1]` of `values[e] * alpha[cols[slots[e]]]`.
    pub fn parts(&self) -> FlattenOpParts<'_> {
        FlattenOpParts {
            cols: &self.cols,
            order: &self.order,
            offsets: &self.offsets,
            slots: &self.slots,
            values: &self.values,
        }
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.cols.len()
            + self.order.len()
            + self.offsets.len()
            + self.slots.len()
            + self.values.len())
    }

    /// `flat = F alpha` with `dim` floats per point: `alpha.len() == flat.len() == points *
    /// dim`; `scratch` keeps its buffers for the next call. Panics on other lengths.
    pub fn apply(&self, alpha: &[f32], dim: usize, flat: &mut [f32], scratch: &mut FlattenScratch) {
        assert!(alpha.len() == self.points * dim && flat.len() == self.points * dim);
        match dim {
            1 => self.apply_n::<1>(alpha, flat, scratch),
            3 => self.apply_n::<3>(alpha, flat, scratch),
            9 => self.apply_n::<9>(alpha, flat, scratch),
            _ => self.apply_dyn(alpha, dim, flat, scratch),
        }
    }

    /// Gathers the kept columns' coefficients in column order into `scratch.coefficients`
    /// and sizes `scratch.rows`.
    fn gather(&self, alpha: &[f32], dim: usize, scratch: &mut FlattenScratch) {
        let c = &mut scratch.coefficients;
        c.clear();
        for &k in &self.cols {
            let k = k as usize;
            c.extend_from_slice(&alpha[k * dim..k * dim + dim]);
        }
        scratch.rows.resize(self.points * dim, 0.0);
    }

    /// Writes the rows, computed in storage order, to their points.
    fn scatter(&self, dim: usize, flat: &mut [f32], scratch: &FlattenScratch) {
        for (pos, &j) in self.order.iter().enumerate() {
            let j = j as usize;
            flat[j * dim..j * dim + dim].copy_from_slice(&scratch.rows[pos * dim..pos * dim + dim]);
        }
    }

    fn apply_n<const D: usize>(
        &self,
        alpha: &[f32],
        flat: &mut [f32],
        scratch: &mut FlattenScratch,
    ) {
        self.gather(alpha, D, scratch);
        let (coefficients, rows) = (&scratch.coefficients, &mut scratch.rows);
        let (coefficients, _) = coefficients.as_chunks::<D>();
        rows.par_chunks_mut(BLOCK * D)
            .enumerate()
            .for_each(|(blk, out)| {
                let (out, _) = out.as_chunks_mut::<D>();
                for (q, o) in out.iter_mut().enumerate() {
                    let pos = blk * BLOCK + q;
                    let (a, b) = (self.offsets[pos] as usize, self.offsets[pos + 1] as usize);
                    let mut acc = [0.0f32; D];
                    for (&s, &v) in self.slots[a..b].iter().zip(&self.values[a..b]) {
                        let c = &coefficients[s as usize];
                        for d in 0..D {
                            acc[d] += v * c[d];
                        }
                    }
                    *o = acc;
                }
            });
        self.scatter(D, flat, scratch);
    }

    fn apply_dyn(&self, alpha: &[f32], dim: usize, flat: &mut [f32], scratch: &mut FlattenScratch) {
        if dim == 0 {
            return;
        }
        self.gather(alpha, dim, scratch);
        let (coefficients, rows) = (&scratch.coefficients, &mut scratch.rows);
        rows.par_chunks_mut(BLOCK * dim)
            .enumerate()
            .for_each(|(blk, out)| {
                for (q, o) in out.chunks_exact_mut(dim).enumerate() {
                    let pos = blk * BLOCK + q;
                    let (a, b) = (self.offsets[pos] as usize, self.offsets[pos + 1] as usize);
                    o.fill(0.0);
                    for (&s, &v) in self.slots[a..b].iter().zip(&self.values[a..b]) {
                        let c = &coefficients[s as usize * dim..s as usize * dim + dim];
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

    #[test]
    fn operator_equals_flatten() {
        let ib = plane_basis(4, 3);
        let op = FlattenOp::build(&ib, None).unwrap();
        assert_eq!(op.columns(), ib.basis.len());
        for dim in [1, 3, 9, 4] {
            let alpha = coefficients(&ib, dim);
            let reference = flatten(&ib, &alpha, dim);
            let mut flat = vec![f32::NAN; alpha.len()];
            op.apply(&alpha, dim, &mut flat, &mut FlattenScratch::default());
            let scale = reference.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.5, "{scale}");
            let d = max_diff(&flat, &reference);
            assert!(d < 1e-5 * scale, "dim {dim}: differs by {d}");
        }
    }

    #[test]
    fn dropped_columns_count_as_zero_coefficients() {
        let ib = plane_basis(4, 3);
        let n = ib.basis.len();
        let keep: Vec<bool> = (0..n).map(|k| k % 3 != 0).collect();
        let op = FlattenOp::build(&ib, Some(&keep)).unwrap();
        let full = FlattenOp::build(&ib, None).unwrap();
        assert!(op.entries() < full.entries() && op.bytes() < full.bytes());
        let mut alpha = coefficients(&ib, 9);
        let mut flat = vec![0.0; alpha.len()];
        op.apply(&alpha, 9, &mut flat, &mut FlattenScratch::default());
        for k in (0..n).filter(|k| !keep[*k]) {
            alpha[k * 9..k * 9 + 9].fill(0.0);
        }
        let reference = flatten(&ib, &alpha, 9);
        assert!(max_diff(&flat, &reference) < 1e-5);
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
    fn same_bits_for_any_thread_count() {
        // Enough points for several build blocks and product bands.
        let ib = plane_basis(6, 5);
        assert!(ib.basis.len() > 4 * BLOCK, "{}", ib.basis.len());
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
        let reference = flatten(&ib, &alpha, 9);
        assert!(max_diff(&f1, &reference) < 1e-4);
    }
}

#[cfg(test)]
mod bench {
    use super::*;
    use crate::file::BakedFile;
    use crate::links::{ReceiverLinks, LINK_DIM};
    use std::time::Instant;

    /// Times on a baked file: `MLT_BENCH_FILE=F cargo test --release -p mlt-format
    /// flatten_op::bench -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn flatten_operator_on_a_baked_file() {
        let Ok(path) = std::env::var("MLT_BENCH_FILE") else {
            eprintln!("MLT_BENCH_FILE is not set");
            return;
        };
        let file = BakedFile::open(std::path::Path::new(&path)).unwrap();
        let ib = file.basis().unwrap();
        let lb = file.links_bytes().unwrap().unwrap();
        let links = file.access_links(&lb).unwrap();
        let mut keep = vec![false; ib.basis.len()];
        for r in links.receiver_ids.iter() {
            keep[r.to_native() as usize] = true;
        }
        let t = Instant::now();
        let op = FlattenOp::build(&ib, Some(&keep)).unwrap();
        eprintln!(
            "build {:.0} ms: {} columns, {} entries, {:.1} MB",
            t.elapsed().as_secs_f64() * 1e3,
            op.columns(),
            op.entries(),
            op.bytes() as f64 / 1e6
        );
        let rl = ReceiverLinks::build(links);
        let senders = links.senders.to_native() as usize;
        let e: Vec<f32> = (0..senders * 3).map(|k| 1.0 + (k % 7) as f32).collect();
        let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
        let mut flat = vec![0.0f32; i.len()];
        let mut scratch = FlattenScratch::default();
        let scalar: Vec<f32> = i.iter().step_by(LINK_DIM).copied().collect();
        let mut flat1 = vec![0.0f32; scalar.len()];
        let mut scratch1 = FlattenScratch::default();
        for _ in 0..7 {
            let t = Instant::now();
            rl.apply(&e, 0.0, &mut i);
            let t1 = Instant::now();
            op.apply(&i, 9, &mut flat, &mut scratch);
            let t2 = Instant::now();
            op.apply(&scalar, 1, &mut flat1, &mut scratch1);
            let t3 = Instant::now();
            let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
            eprintln!(
                "S e {:.2} ms, flatten {:.2} ms (one float per point: {:.2} ms)",
                ms(t, t1),
                ms(t1, t2),
                ms(t2, t3)
            );
        }
    }
}
