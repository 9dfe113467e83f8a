//! The pull-push projection `e = P-dagger E` (section 2.1, "Pull-Push Approximation") with
//! its weights precomputed, for the direct light of every frame (section 3.3).
//!
//! [`mlt_format::pull_push::pull_push_levels`] finds the weights by R-tree queries on each
//! call; [`PullPushOp`] finds them once per file, so that a projection is a few sparse loops
//! that sum the same products in the same order, hence the same bits.

use mlt_format::pull_push::ProjectionReport;
use mlt_format::shepard::{IndexedBasis, MAX_DIM, MIN_WEIGHT_SUM};

/// [`pull_push_levels`] precomputed: the weights of the pull (children per parent) and of the
/// push (Eq. 7: per point and coarser level, the weights `w_k(p_j)` and `1 / sum_k w_k(p_j)`)
/// are found once by R-tree queries, so that a projection is a few sparse loops (section 3.3:
/// `e = P-dagger E` every frame). [`apply`](Self::apply) gives the same bits as
/// [`pull_push_levels`]: it sums the same products in the same order.
///
/// [`pull_push_levels`]: mlt_format::pull_push::pull_push_levels
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PullPushOp {
    /// Points covered (those of the coarsest `levels` levels).
    points: usize,
    /// Per level `l < levels - 1`, from the second finest up, parents `i` with children.
    pull_parents: Vec<u32>,
    /// `pull_parents.len() + 1` offsets into `pull_children`/`pull_weights`.
    pull_offsets: Vec<u32>,
    /// Sum of the children's weights of each pulled parent.
    pull_den: Vec<f32>,
    pull_children: Vec<u32>,
    pull_weights: Vec<f32>,
    /// Segments of the push, in point order (levels 1 and up): one per point and supported
    /// coarser level, `(point, 1 / weight sum)`; `push_offsets` has one more entry.
    push_points: Vec<u32>,
    push_inv: Vec<f32>,
    push_offsets: Vec<u32>,
    push_ids: Vec<u32>,
    push_weights: Vec<f32>,
    report: ProjectionReport,
}

/// The arrays of a [`PullPushOp`], borrowed ([`PullPushOp::parts`]): on `dim` floats per point,
/// the pull sets each parent `pull_parents[p]` (level by level, from the second finest level
/// up: a level's parents read its children's pulled values) to
/// `sum_e pull_weights[e] values[pull_children[e]] / pull_den[p]` over `e in
/// pull_offsets[p]..pull_offsets[p + 1]`; then the push (Eq. 7), level by level from level 1
/// down to the finest, subtracts from each point `push_points[s]` the sum over its segments `s`
/// (consecutive, one per supported coarser level) of `push_inv[s] * sum_e push_weights[e]
/// values[push_ids[e]]` over `e in push_offsets[s]..push_offsets[s + 1]`, the coarser levels'
/// values being already pushed.
#[derive(Clone, Copy, Debug)]
pub struct PullPushParts<'a> {
    /// Points covered (those of the coarsest levels the operator was built on).
    pub points: usize,
    pub pull_parents: &'a [u32],
    pub pull_offsets: &'a [u32],
    pub pull_den: &'a [f32],
    pub pull_children: &'a [u32],
    pub pull_weights: &'a [f32],
    pub push_points: &'a [u32],
    pub push_inv: &'a [f32],
    pub push_offsets: &'a [u32],
    pub push_ids: &'a [u32],
    pub push_weights: &'a [f32],
}

impl PullPushOp {
    /// Precomputes `pull_push_levels` on the coarsest `levels` levels of `ib`.
    pub fn build(ib: &IndexedBasis, levels: usize) -> PullPushOp {
        let b = &ib.basis;
        let levels = levels.min(b.levels());
        let mut op = PullPushOp {
            points: b.level_offsets[levels] as usize,
            pull_offsets: vec![0],
            push_offsets: vec![0],
            ..PullPushOp::default()
        };
        // Pull: gather per parent, children ascending (the order the scatter of
        // `pull_push_levels` adds them in).
        let mut lists: Vec<Vec<(u32, f32)>> = Vec::new();
        for l in (0..levels.saturating_sub(1)).rev() {
            let parents = b.level_range(l);
            lists.clear();
            lists.resize(parents.len(), Vec::new());
            for c in b.level_range(l + 1) {
                ib.for_each_weight(l, b.positions[c], b.normals[c], |i, w| {
                    lists[i - parents.start].push((c as u32, w));
                });
            }
            for (k, list) in lists.iter().enumerate() {
                let den = list.iter().fold(0.0f32, |d, &(_, w)| d + w);
                if den > 0.0 {
                    op.pull_parents.push((parents.start + k) as u32);
                    op.pull_den.push(den);
                    for &(c, w) in list {
                        op.pull_children.push(c);
                        op.pull_weights.push(w);
                    }
                    op.pull_offsets.push(op.pull_children.len() as u32);
                } else {
                    op.report.childless_points += 1;
                }
            }
        }
        // Push: the weights `reconstruct` would use for F_{l-1}(p_j), in its order.
        for l in 1..levels {
            for j in b.level_range(l) {
                let (x, n) = (b.positions[j], b.normals[j]);
                let mut supported = false;
                for m in 0..l {
                    let start = op.push_ids.len();
                    let sum = ib.for_each_weight(m, x, n, |k, w| {
                        op.push_ids.push(k as u32);
                        op.push_weights.push(w);
                    });
                    if sum > MIN_WEIGHT_SUM {
                        supported = true;
                        op.push_points.push(j as u32);
                        op.push_inv.push(1.0 / sum);
                        op.push_offsets.push(op.push_ids.len() as u32);
                    } else {
                        op.push_ids.truncate(start);
                        op.push_weights.truncate(start);
                    }
                }
                if !supported {
                    op.report.unsupported_points += 1;
                }
            }
        }
        op
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.pull_parents.len()
            + self.pull_offsets.len()
            + self.pull_den.len()
            + self.pull_children.len()
            + self.pull_weights.len()
            + self.push_points.len()
            + self.push_inv.len()
            + self.push_offsets.len()
            + self.push_ids.len()
            + self.push_weights.len())
    }

    /// The precomputed arrays, for applying the projection elsewhere (the viewer's GPU compute
    /// passes): see [`PullPushParts`].
    pub fn parts(&self) -> PullPushParts<'_> {
        PullPushParts {
            points: self.points,
            pull_parents: &self.pull_parents,
            pull_offsets: &self.pull_offsets,
            pull_den: &self.pull_den,
            pull_children: &self.pull_children,
            pull_weights: &self.pull_weights,
            push_points: &self.push_points,
            push_inv: &self.push_inv,
            push_offsets: &self.push_offsets,
            push_ids: &self.push_ids,
            push_weights: &self.push_weights,
        }
    }

    /// The report `pull_push_levels` would give.
    pub fn report(&self) -> ProjectionReport {
        self.report
    }

    /// Whether the sample of point `j` is used: false for the points whose value the pull
    /// replaces by their children's average.
    pub fn sample_used(&self) -> Vec<bool> {
        let mut used = vec![true; self.points];
        for &i in &self.pull_parents {
            used[i as usize] = false;
        }
        used
    }

    /// The pull in place: each parent with children gets their weighted average, finest
    /// parents first. `values` holds `dim` floats per covered point.
    pub fn pull(&self, values: &mut [f32], dim: usize) {
        // Inlined per common dimension, so that each copy's inner loops have a constant length.
        match dim {
            1 => self.pull_dim(values, 1),
            3 => self.pull_dim(values, 3),
            _ => self.pull_dim(values, dim),
        }
    }

    #[inline(always)]
    fn pull_dim(&self, values: &mut [f32], dim: usize) {
        assert!(dim <= MAX_DIM && values.len() == self.points * dim);
        let mut num = [0.0f32; MAX_DIM];
        for (p, &i) in self.pull_parents.iter().enumerate() {
            let (a, e) = (
                self.pull_offsets[p] as usize,
                self.pull_offsets[p + 1] as usize,
            );
            num[..dim].fill(0.0);
            for (&c, &w) in self.pull_children[a..e]
                .iter()
                .zip(&self.pull_weights[a..e])
            {
                let c = c as usize;
                for d in 0..dim {
                    num[d] += w * values[c * dim + d];
                }
            }
            let den = self.pull_den[p];
            let i = i as usize;
            for d in 0..dim {
                values[i * dim + d] = num[d] / den;
            }
        }
    }

    /// The push in place (Eq. 7): values become coefficients, coarse to fine.
    pub fn push(&self, values: &mut [f32], dim: usize) {
        match dim {
            1 => self.push_dim(values, 1),
            3 => self.push_dim(values, 3),
            _ => self.push_dim(values, dim),
        }
    }

    #[inline(always)]
    fn push_dim(&self, values: &mut [f32], dim: usize) {
        assert!(dim <= MAX_DIM && values.len() == self.points * dim);
        let mut acc = [0.0f32; MAX_DIM];
        let mut approx = [0.0f32; MAX_DIM];
        let mut current = None;
        let segments = self.push_points.len();
        for s in 0..segments {
            let j = self.push_points[s] as usize;
            if current != Some(j) {
                approx[..dim].fill(0.0);
                current = Some(j);
            }
            let (a, e) = (
                self.push_offsets[s] as usize,
                self.push_offsets[s + 1] as usize,
            );
            acc[..dim].fill(0.0);
            for (&k, &w) in self.push_ids[a..e].iter().zip(&self.push_weights[a..e]) {
                let k = k as usize;
                for d in 0..dim {
                    acc[d] += w * values[k * dim + d];
                }
            }
            let inv = self.push_inv[s];
            for d in 0..dim {
                approx[d] += acc[d] * inv;
            }
            if s + 1 == segments || self.push_points[s + 1] as usize != j {
                for d in 0..dim {
                    values[j * dim + d] -= approx[d];
                }
            }
        }
    }

    /// `pull_push_levels`: the pull, then the push, on a copy of `samples`.
    pub fn apply(&self, samples: &[f32], dim: usize) -> (Vec<f32>, ProjectionReport) {
        let mut values = samples.to_vec();
        self.pull(&mut values, dim);
        self.push(&mut values, dim);
        (values, self.report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_format::pull_push::pull_push_levels;
    use mlt_format::test_support::plane_basis;

    #[test]
    fn precomputed_pull_push_gives_the_same_bits() {
        let ib = plane_basis(5, 2);
        let n = ib.basis.len();
        let mut samples = vec![0.0f32; n * 3];
        for j in 0..n {
            let p = ib.basis.positions[j];
            samples[j * 3] = (5.0 * p[0]).sin() + 2.0;
            samples[j * 3 + 1] = if p[1] > 0.5 { 1.0 } else { 0.0 };
            samples[j * 3 + 2] = p[0] * p[1];
        }
        for levels in [1, 2, 3, 5] {
            let m = ib.basis.level_offsets[levels] as usize;
            let (want, report) = pull_push_levels(&ib, &samples[..m * 3], 3, levels);
            let op = PullPushOp::build(&ib, levels);
            let (got, op_report) = op.apply(&samples[..m * 3], 3);
            assert_eq!(report, op_report);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "levels {levels}");
            // Samples the pull overwrites do not matter; the others do.
            let used = op.sample_used();
            assert_eq!(used.len(), m);
            assert_eq!(used.iter().filter(|u| !**u).count() > 0, levels > 1);
            let mut changed = samples[..m * 3].to_vec();
            for j in (0..m).filter(|&j| !used[j]) {
                changed[j * 3] = 1e6;
            }
            assert_eq!(bits(&op.apply(&changed, 3).0), bits(&want));
            let finest = ib.basis.level_range(levels - 1).start;
            changed[finest * 3] += 1.0;
            assert_ne!(bits(&op.apply(&changed, 3).0), bits(&want));
        }
    }
}
