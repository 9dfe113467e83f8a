//! The multi-bounce operator `S = T + T^2 + T^3 + ...` (section 3.2) by sparse products.
//!
//! A link maps scalar irradiance at a sender to vector irradiance at a receiver. To chain two
//! bounces, the vector irradiance gathered at a coarsest receiver `j` becomes scalar irradiance
//! at the coarsest sender on the same point by `n_j . I_j` (level-0 coefficients are point
//! values, Eq. 7). With `K` the level-0-receiver x level-0-sender block of T and `X_1` the
//! level-0 rows of T, bounce `b >= 2` is
//!
//! `X_b[i][s] = sum_j K[i][j] (n_j . X_{b-1}[j][s])`  (per colour channel),
//!
//! truncated below epsilon, except the links from coarsest senders to coarsest receivers, which
//! are always kept (nothing coarser represents them; see `refine`). The paper computes bounces
//! 2 and later on the coarsest receivers only ([`BounceReceivers::Coarsest`]): `S` adds every
//! `X_b` to T's level-0 rows. Vector irradiance turns with the surface normal, so on curved
//! geometry the coarsest level alone reconstructs these bounces poorly (about 10 % low on a
//! closed sphere of 24 level-0 points); [`BounceReceivers::All`] applies every refined row of T
//! instead (`X_b = T Y_{b-1}`: finer rows of T are Eq. 17 differences, so their products are
//! the finer coefficients of bounce `b`), at the cost of more products. By default (`bake
//! --level0-paths N`, N > 0) the bake then replaces the level-0 rows of bounces 2 and later by
//! path-traced ones (`crate::path_bounces`), which reflect the bounce light off the true
//! geometry instead of the level-0 functions; the series still gives the spectral radius, the
//! bounce count and the per-bounce statistics, and is what the paper preset keeps. The series converges
//! when the spectral radius of `M[j][i] = n_j . K[j][i]` is below one; it is estimated by power
//! iteration first, and a scene at or above one is refused.

use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use rayon::prelude::*;

use crate::gather::link_norm;
use crate::refine::ReceiverLinks;

/// One row of links: `(sender, value)`, ascending by sender.
pub type Row = Vec<(u32, [f32; LINK_DIM])>;

/// One bounce's links: `rows[r]` for row `r` of T (rows of level 0 come first, and row `i`
/// is level-0 receiver `i`).
pub type Rows = Vec<Row>;

/// Which receivers bounces 2 and later are computed on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BounceReceivers {
    /// The coarsest level only (the paper).
    Coarsest,
    /// Every receiver T was refined on.
    All,
}

/// What the series did.
#[derive(Clone, Debug, Default)]
pub struct SeriesReport {
    /// Bounces computed, counting T as the first.
    pub bounces: u32,
    /// Per bounce (from the first): largest link norm and sum of link norms, before
    /// truncation.
    pub max_norm: Vec<f64>,
    pub sum_norm: Vec<f64>,
    /// Per bounce, the sum of the norms of the links above epsilon.
    pub kept_sum_norm: Vec<f64>,
    /// Per bounce and colour channel, the irradiance `sum_i sum_j n_i . X_b[i][j]` over
    /// level-0 receivers `i` and level-0 senders `j`: the bounce's light at the coarsest
    /// points under unit irradiance at every coarsest sender (for a closed scene of uniform
    /// albedo `rho`, `n_0 rho^b`). Computed (before truncation) and kept.
    pub energy: Vec<[f64; 3]>,
    pub kept_energy: Vec<[f64; 3]>,
    pub spectral_radius: f64,
    /// The series was stopped early because a bounce's links all fell below epsilon.
    pub converged_early: bool,
}

/// Power-iteration estimate of the spectral radius of the bounce operator, the largest over
/// the colour channels.
pub fn spectral_radius(ib: &IndexedBasis, t: &ReceiverLinks) -> f64 {
    let n0 = ib.basis.level_range(0).len();
    let mut rho = 0.0f64;
    for c in 0..3 {
        // M[j][i] = n_j . K[j][i]_c over level-0 receivers j and level-0 senders i.
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n0];
        for (j, row) in rows.iter_mut().enumerate() {
            let nj = ib.basis.normals[j];
            let (senders, values) = t.row(j);
            for (s, v) in senders.iter().zip(values) {
                if (*s as usize) < n0 {
                    let m = nj[0] * v[3 * c] + nj[1] * v[3 * c + 1] + nj[2] * v[3 * c + 2];
                    row.push((*s as usize, m as f64));
                }
            }
        }
        let mut x = vec![1.0f64; n0];
        let mut lambda = 0.0f64;
        for _ in 0..500 {
            let y: Vec<f64> = rows
                .iter()
                .map(|r| r.iter().map(|&(i, m)| m * x[i]).sum())
                .collect();
            let norm_x = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            let norm_y = y.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm_x == 0.0 || norm_y == 0.0 || !norm_y.is_finite() {
                lambda = 0.0;
                break;
            }
            let next = norm_y / norm_x;
            x = y.iter().map(|v| v / norm_y).collect();
            let settled = (next - lambda).abs() <= 1e-9 * next.max(1e-30);
            lambda = next;
            if settled {
                break;
            }
        }
        rho = rho.max(lambda);
    }
    rho
}

/// `sum_j n . v_j` per colour channel over the links `(j, v_j)` of `row` to senders `j < n0`.
fn row_energy<'a>(
    n: [f32; 3],
    n0: usize,
    row: impl IntoIterator<Item = (u32, &'a [f32; LINK_DIM])>,
) -> [f64; 3] {
    let mut e = [0.0f64; 3];
    for (s, v) in row {
        if (s as usize) < n0 {
            for (c, ec) in e.iter_mut().enumerate() {
                *ec += (n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2]) as f64;
            }
        }
    }
    e
}

fn add3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Computes bounces 2..=`bounces` and returns them summed per row of T, with a report.
pub fn series(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    senders: usize,
    bounces: u32,
    epsilon: f32,
    receivers: BounceReceivers,
    mut on_bounce: impl FnMut(u32, usize),
) -> (Rows, SeriesReport) {
    let n0 = ib.basis.level_range(0).len();
    let out_rows = match receivers {
        BounceReceivers::Coarsest => n0,
        BounceReceivers::All => t.rows.len(),
    };
    let mut report = SeriesReport {
        bounces: 1,
        ..Default::default()
    };
    let first = first_bounce(ib, t, n0, &mut report);
    let mut total: Rows = vec![Vec::new(); out_rows];
    // Level-0 rows of the previous bounce: the next bounce's sender input.
    let mut prev = first;
    for b in 2..=bounces {
        let y = sender_irradiance(ib, &prev);
        let products: Vec<Product> = (0..out_rows)
            .into_par_iter()
            .map_init(
                || ProductScratch::new(senders),
                |scratch, row_index| product_row(ib, t, &y, n0, epsilon, scratch, row_index),
            )
            .collect();
        let rows = record_bounce(ib, n0, b, products, &mut report);
        let kept: usize = rows.iter().map(|r| r.len()).sum();
        report.kept_sum_norm.push(norms(&rows).1);
        on_bounce(b, kept);
        if kept == 0 {
            report.converged_early = true;
            break;
        }
        for (acc_row, row) in total.iter_mut().zip(&rows) {
            *acc_row = merge(acc_row, row);
        }
        prev = rows;
        prev.truncate(n0);
    }
    (total, report)
}

/// Largest link norm and sum of link norms of `rows`.
fn norms(rows: &Rows) -> (f64, f64) {
    rows.iter()
        .flatten()
        .fold((0.0f64, 0.0f64), |(m, s), (_, v)| {
            let n = link_norm(v) as f64;
            (m.max(n), s + n)
        })
}

/// The first bounce, T itself: its level-0 rows, with its norms and energy in `report`. T's
/// links are already the kept ones: nothing of the first bounce is truncated here.
fn first_bounce(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    n0: usize,
    report: &mut SeriesReport,
) -> Rows {
    let first: Rows = (0..n0)
        .map(|j| {
            let (s, v) = t.row(j);
            s.iter().copied().zip(v.iter().copied()).collect()
        })
        .collect();
    let (m1, s1) = norms(&first);
    report.max_norm.push(m1);
    report.sum_norm.push(s1);
    report.kept_sum_norm.push(s1);
    let e1 = first.iter().enumerate().fold([0.0; 3], |acc, (j, row)| {
        add3(
            acc,
            row_energy(ib.basis.normals[j], n0, row.iter().map(|(s, v)| (*s, v))),
        )
    });
    report.energy.push(e1);
    report.kept_energy.push(e1);
    first
}

/// `Y[j][s] = n_j . X_{b-1}[j][s]`, per channel: the previous bounce's vector irradiance at
/// the coarsest receivers as scalar irradiance at the coarsest senders on the same points.
fn sender_irradiance(ib: &IndexedBasis, prev: &Rows) -> Vec<Vec<(u32, [f32; 3])>> {
    prev.iter()
        .enumerate()
        .map(|(j, row)| {
            let n = ib.basis.normals[j];
            row.iter()
                .map(|(s, v)| {
                    let d = |c: usize| n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2];
                    (*s, [d(0), d(1), d(2)])
                })
                .collect()
        })
        .collect()
}

/// One row of a bounce: its kept links, largest and summed link norm, and energy (level-0
/// rows only; see [`SeriesReport::energy`]).
type Product = (Row, f64, f64, [f64; 3]);

/// A worker's dense accumulator over the senders, the senders it touched, and their marks.
struct ProductScratch {
    acc: Vec<[f32; LINK_DIM]>,
    touched: Vec<u32>,
    mark: Vec<bool>,
}

impl ProductScratch {
    fn new(senders: usize) -> Self {
        ProductScratch {
            acc: vec![[0.0f32; LINK_DIM]; senders],
            touched: Vec::new(),
            mark: vec![false; senders],
        }
    }
}

/// Row `row_index` of the next bounce, `X_b[i][s] = sum_j K[i][j] Y[j][s]`, truncated below
/// `epsilon` (the scratch is left cleared).
fn product_row(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    y: &[Vec<(u32, [f32; 3])>],
    n0: usize,
    epsilon: f32,
    scratch: &mut ProductScratch,
    row_index: usize,
) -> Product {
    let ProductScratch { acc, touched, mark } = scratch;
    let i = t.rows[row_index] as usize;
    let (ks, kv) = t.row(i);
    for (j, k) in ks.iter().zip(kv) {
        let j = *j as usize;
        if j >= n0 {
            continue;
        }
        for (s, yv) in &y[j] {
            let su = *s as usize;
            if !mark[su] {
                mark[su] = true;
                touched.push(*s);
            }
            let a = &mut acc[su];
            for c in 0..3 {
                for d in 0..3 {
                    a[3 * c + d] += k[3 * c + d] * yv[c];
                }
            }
        }
    }
    touched.sort_unstable();
    let (mut mx, mut sm) = (0.0f64, 0.0f64);
    let mut row = Vec::new();
    let energy = if row_index < n0 {
        row_energy(
            ib.basis.normals[row_index],
            n0,
            touched.iter().map(|&s| (s, &acc[s as usize])),
        )
    } else {
        [0.0; 3]
    };
    for &s in touched.iter() {
        let v = acc[s as usize];
        let nrm = link_norm(&v);
        mx = mx.max(nrm as f64);
        sm += nrm as f64;
        // Links between coarsest receivers and coarsest senders are kept whatever their size:
        // no coarser level represents them (see `refine`'s module docs), so truncating them
        // loses light.
        let base = row_index < n0 && (s as usize) < n0 && nrm > 0.0;
        if nrm > epsilon || base {
            row.push((s, v));
        }
        acc[s as usize] = [0.0; LINK_DIM];
        mark[s as usize] = false;
    }
    touched.clear();
    (row, mx, sm, energy)
}

/// Adds bounce `b`'s norms and energies to `report` and returns its rows.
fn record_bounce(
    ib: &IndexedBasis,
    n0: usize,
    b: u32,
    products: Vec<Product>,
    report: &mut SeriesReport,
) -> Rows {
    let mx = products.iter().fold(0.0f64, |m, p| m.max(p.1));
    let sm: f64 = products.iter().map(|p| p.2).sum();
    report.max_norm.push(mx);
    report.sum_norm.push(sm);
    report
        .energy
        .push(products.iter().fold([0.0; 3], |a, p| add3(a, p.3)));
    report.bounces = b;
    let rows: Rows = products.into_iter().map(|p| p.0).collect();
    let kept_energy = rows
        .iter()
        .take(n0)
        .enumerate()
        .fold([0.0; 3], |a, (j, row)| {
            add3(
                a,
                row_energy(ib.basis.normals[j], n0, row.iter().map(|(s, v)| (*s, v))),
            )
        });
    report.kept_energy.push(kept_energy);
    rows
}

/// Sum of two rows sorted by sender.
pub fn merge(
    a: &[(u32, [f32; LINK_DIM])],
    b: &[(u32, [f32; LINK_DIM])],
) -> Vec<(u32, [f32; LINK_DIM])> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        if j == b.len() || (i < a.len() && a[i].0 < b[j].0) {
            out.push(a[i]);
            i += 1;
        } else if i == a.len() || b[j].0 < a[i].0 {
            out.push(b[j]);
            j += 1;
        } else {
            let v = std::array::from_fn(|k| a[i].1[k] + b[j].1[k]);
            out.push((a[i].0, v));
            i += 1;
            j += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merge_adds_matching_senders_and_keeps_order() {
        let a = vec![(1u32, [1.0f32; 9]), (4, [2.0; 9])];
        let b = vec![(0u32, [0.5f32; 9]), (4, [1.0; 9]), (7, [3.0; 9])];
        let m = merge(&a, &b);
        let ids: Vec<u32> = m.iter().map(|x| x.0).collect();
        assert_eq!(ids, vec![0, 1, 4, 7]);
        assert_eq!(m[2].1, [3.0; 9]);
    }
}
