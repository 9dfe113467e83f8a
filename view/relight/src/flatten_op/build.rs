//! Building a [`FlattenOp`]: each point's row from R-tree queries on every level, its values
//! normalised per level (Eq. 2) and quantised to 16 bits keeping their sum, then the rows in
//! storage order, in blocks sharing a table of local columns.

use mlt_format::flat_basis::FlatBasis;
use mlt_format::morton::morton_order;
use mlt_format::shepard::{IndexedBasis, MIN_WEIGHT_SUM};
use rayon::prelude::*;

use super::{FlattenOp, FlattenOptions, BLOCK_ROWS, BUILD_BLOCK, QUANTUM};
use crate::error::RelightError;

/// Largest number of distinct columns one block may read (16-bit local columns).
const MAX_LOCAL: usize = 1 << 16;

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

/// Rows by point index, for one block of [`BUILD_BLOCK`] points: entries per row, columns,
/// quantised values.
#[derive(Default)]
struct Rows {
    counts: Vec<u32>,
    ks: Vec<u32>,
    qs: Vec<u16>,
}

impl FlattenOp {
    /// Builds the default operator ([`FlattenOptions::default`]) from all levels of `ib` to
    /// the flat points of `flat` (one row each), in parallel (same result for any thread
    /// count). With `keep`, only the columns `k` with `keep[k]` are stored; a product then
    /// treats the coefficients of the others as zero.
    pub fn build(
        ib: &IndexedBasis,
        flat: &FlatBasis,
        keep: Option<&[bool]>,
    ) -> Result<FlattenOp, RelightError> {
        FlattenOp::build_with(ib, flat, keep, FlattenOptions::default())
    }

    /// [`FlattenOp::build`] with chosen options.
    pub fn build_with(
        ib: &IndexedBasis,
        flat: &FlatBasis,
        keep: Option<&[bool]>,
        options: FlattenOptions,
    ) -> Result<FlattenOp, RelightError> {
        FlattenOp::build_weighted(ib, flat, keep, options, false)
    }

    /// The flat basis `flat`'s own weights at its points, normalised (rows and columns: flat
    /// points), with its weights ([`FlatBasis::for_each_weight`]: Eq. 8 times the sharper
    /// normal factor) instead of Eq. 8's; values below the default threshold dropped.
    pub(super) fn smoothing_of(flat: &FlatBasis) -> Result<FlattenOp, RelightError> {
        let itself = FlatBasis {
            ib: flat.ib.clone(),
            source: (0..flat.len() as u32).collect(),
            normal_power: flat.normal_power,
        };
        FlattenOp::build_weighted(&flat.ib, &itself, None, FlattenOptions::default(), true)
    }

    /// [`FlattenOp::build_with`]; with `flat_weights`, the rows hold `flat`'s own weights
    /// ([`FlatBasis::for_each_weight`]) instead of Eq. 8's (`ib` is then `flat`'s one level).
    fn build_weighted(
        ib: &IndexedBasis,
        flat: &FlatBasis,
        keep: Option<&[bool]>,
        options: FlattenOptions,
        flat_weights: bool,
    ) -> Result<FlattenOp, RelightError> {
        let b = &ib.basis;
        let n = b.len();
        let m = flat.len();
        if flat.source.iter().any(|&j| j as usize >= n) {
            return Err(RelightError::FlattenOperator(
                "flat points outside the basis".into(),
            ));
        }
        if let Some(keep) = keep {
            if keep.len() != n {
                return Err(RelightError::FlattenOperator(format!(
                    "{} column flags for {n} points",
                    keep.len()
                )));
            }
        }
        let blocks = quantised_rows(ib, flat, keep, options.drop_below.max(0.0), flat_weights);
        let total: usize = blocks.iter().map(|rows| rows.ks.len()).sum();
        if total >= u32::MAX as usize {
            return Err(RelightError::FlattenOperator(format!(
                "{total} entries do not fit 32-bit offsets"
            )));
        }
        // Where each point's row starts in its build block.
        let mut row_at = Vec::with_capacity(m);
        for (blk, rows) in blocks.iter().enumerate() {
            let mut at = 0usize;
            for &c in &rows.counts {
                row_at.push((blk, at, c as usize));
                at += c as usize;
            }
        }
        let (order, identity) = storage_order(flat);
        let mut position = vec![0u32; m];
        for (pos, &j) in order.iter().enumerate() {
            position[j as usize] = pos as u32;
        }
        let row = |j: u32| {
            let (blk, at, count) = row_at[j as usize];
            let r = &blocks[blk];
            (&r.ks[at..at + count], &r.qs[at..at + count])
        };
        let packed = pack_blocks(n, &order, total, row)?;
        Ok(FlattenOp {
            points: m,
            hier_points: n,
            columns: packed.columns,
            position,
            identity,
            order,
            row_offsets: packed.row_offsets,
            block_offsets: packed.block_offsets,
            block_cols: packed.block_cols,
            entries: packed.entries,
        })
    }
}

/// Every flat point's row (Eq. 6: the normalised weights `B^l_k(p_j)` of each level with
/// support at `p_j`, Eq. 2), quantised per level, in blocks of [`BUILD_BLOCK`] points computed
/// in parallel. Only the columns `k` with `keep[k]` (all without `keep`) are stored. With
/// `flat_weights`, the weights are `flat`'s own ([`FlatBasis::for_each_weight`]; `ib` is then
/// its one level).
fn quantised_rows(
    ib: &IndexedBasis,
    flat: &FlatBasis,
    keep: Option<&[bool]>,
    drop_below: f64,
    flat_weights: bool,
) -> Vec<Rows> {
    let b = &ib.basis;
    let n = flat.len();
    let levels = ib.levels();
    let kept = |k: usize| keep.is_none_or(|m| m[k]);
    (0..n.div_ceil(BUILD_BLOCK))
        .into_par_iter()
        .map(|blk| {
            let range = blk * BUILD_BLOCK..((blk + 1) * BUILD_BLOCK).min(n);
            let mut rows = Rows::default();
            let mut level: Vec<(u32, f32)> = Vec::new();
            let mut group: Vec<(u32, f64)> = Vec::new();
            let mut order = Vec::new();
            for i in range {
                let j = flat.source[i] as usize;
                let (x, nj) = (b.positions[j], b.normals[j]);
                let before = rows.ks.len();
                for l in 0..levels {
                    level.clear();
                    let push = |k: usize, w: f32| level.push((k as u32, w));
                    let sum = if flat_weights {
                        flat.for_each_weight(x, nj, push)
                    } else {
                        ib.for_each_weight(l, x, nj, push)
                    };
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
        .collect()
}

/// Storage order: the flat points in Morton order ([`FlatBasis::build`] stores them so: then
/// this is the identity, the second value, and the rows need no reordering).
fn storage_order(flat: &FlatBasis) -> (Vec<u32>, bool) {
    let b = &flat.ib.basis;
    let mut order = Vec::with_capacity(b.len());
    for l in 0..b.levels() {
        let range = b.level_range(l);
        order.extend(
            morton_order(&b.positions[range.clone()])
                .into_iter()
                .map(|i| i + range.start as u32),
        );
    }
    let identity = order.iter().enumerate().all(|(i, &j)| i == j as usize);
    (order, identity)
}

/// The stored rows of a [`FlattenOp`], in blocks.
struct Packed {
    columns: usize,
    row_offsets: Vec<u32>,
    block_offsets: Vec<u32>,
    block_cols: Vec<u32>,
    entries: Vec<u32>,
}

/// Packs the rows (`row(j)`: columns and quantised values of point `j`) in storage `order`
/// into blocks of [`BLOCK_ROWS`] rows, each with its local columns in ascending point order,
/// so that gathering a block's table walks the coefficients forwards (with Morton-ordered
/// points, in a few runs per level). `total` is the number of entries.
fn pack_blocks<'r>(
    n: usize,
    order: &[u32],
    total: usize,
    row: impl Fn(u32) -> (&'r [u32], &'r [u16]),
) -> Result<Packed, RelightError> {
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
            return Err(RelightError::FlattenOperator(format!(
                "the {BLOCK_ROWS} points around point {} read more than {MAX_LOCAL} basis \
                 functions",
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
        return Err(RelightError::FlattenOperator(format!(
            "{} block columns do not fit 32-bit offsets",
            block_cols.len()
        )));
    }
    Ok(Packed {
        columns: used.iter().filter(|u| **u).count(),
        row_offsets,
        block_offsets,
        block_cols,
        entries,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
