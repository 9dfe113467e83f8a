//! Projection of point samples onto the hierarchical basis: the coarse-to-fine operator `P`
//! (Eq. 7) and the band-limiting pull-push operator `P-dagger` (section 2.1, "Pull-Push
//! Approximation"; used for the direct light at run time, section 3.3).
//!
//! Samples and coefficients are flat `f32` arrays with `dim` values per point, indexed by the
//! basis' global point index.

use crate::shepard::{IndexedBasis, MAX_DIM, MIN_WEIGHT_SUM};

/// How many evaluations of a coarser approximation found no support at a point.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProjectionReport {
    /// Points `p_j` (levels >= 1) where no coarser level had support, so that `alpha_j = f_j`.
    pub unsupported_points: u64,
    /// Points (levels < finest) that had no children to pull from and kept their own sample.
    pub childless_points: u64,
}

/// Eq. 7: `alpha_j = f_j` on level 0 and `alpha_j = f_j - F_{l-1}(p_j)` on level `l`, where
/// `F_{l-1}` is the expansion over the coarser levels.
pub fn project(ib: &IndexedBasis, samples: &[f32], dim: usize) -> (Vec<f32>, ProjectionReport) {
    assert!(dim <= MAX_DIM && samples.len() == ib.basis.len() * dim);
    let mut alpha = samples.to_vec();
    let mut report = ProjectionReport::default();
    push_levels(ib, &mut alpha, dim, ib.basis.levels(), &mut report);
    (alpha, report)
}

/// The pull-push operator `P-dagger`: pull each coarser coefficient to the weighted average of
/// its children's values, `f'_i = sum_c w_i(p_c) f'_c / sum_c w_i(p_c)` over the children `c`
/// of `i` (from the second-finest level up to the coarsest; points without children keep
/// their sample), then push down with Eq. 7 using the averages as `f_j`.
///
/// For a constant function every `f'` is that constant, so the coarsest level reproduces it
/// exactly and all finer coefficients vanish wherever a coarser level has support.
pub fn pull_push(ib: &IndexedBasis, samples: &[f32], dim: usize) -> (Vec<f32>, ProjectionReport) {
    pull_push_levels(ib, samples, dim, ib.basis.levels())
}

/// [`pull_push`] on the coarsest `levels` levels only (the senders): `samples` holds `dim`
/// values for each of their points, and so does the result.
pub fn pull_push_levels(
    ib: &IndexedBasis,
    samples: &[f32],
    dim: usize,
    levels: usize,
) -> (Vec<f32>, ProjectionReport) {
    let b = &ib.basis;
    let levels = levels.min(b.levels());
    assert!(dim <= MAX_DIM && samples.len() == b.level_offsets[levels] as usize * dim);
    let mut values = samples.to_vec();
    let mut report = ProjectionReport::default();
    let mut num = Vec::new();
    let mut den = Vec::new();
    for l in (0..levels.saturating_sub(1)).rev() {
        let parents = b.level_range(l);
        num.clear();
        num.resize(parents.len() * dim, 0.0f32);
        den.clear();
        den.resize(parents.len(), 0.0f32);
        // Scatter each child's value to the parents whose support contains it (children of i
        // are exactly the level-(l+1) points with w_i(p_c) > 0). Sequential: deterministic.
        for c in b.level_range(l + 1) {
            let (xc, nc) = (b.positions[c], b.normals[c]);
            ib.for_each_weight(l, xc, nc, |i, w| {
                let k = i - parents.start;
                den[k] += w;
                for d in 0..dim {
                    num[k * dim + d] += w * values[c * dim + d];
                }
            });
        }
        for (k, i) in parents.clone().enumerate() {
            if den[k] > 0.0 {
                for d in 0..dim {
                    values[i * dim + d] = num[k * dim + d] / den[k];
                }
            } else {
                report.childless_points += 1;
            }
        }
    }
    push_levels(ib, &mut values, dim, levels, &mut report);
    (values, report)
}

/// In place: turns values `f_j` into the coefficients of Eq. 7, coarse to fine, since
/// `F_{l-1}` needs the final coefficients of all levels `< l`. Level 0 stays as is.
fn push_levels(
    ib: &IndexedBasis,
    values: &mut [f32],
    dim: usize,
    levels: usize,
    report: &mut ProjectionReport,
) {
    let b = &ib.basis;
    let mut approx = [0.0f32; MAX_DIM];
    for l in 1..levels {
        for j in b.level_range(l) {
            let s = ib.reconstruct(values, dim, 0..l, b.positions[j], b.normals[j], &mut approx);
            if s.supported == 0 {
                report.unsupported_points += 1;
            }
            for d in 0..dim {
                values[j * dim + d] -= approx[d];
            }
        }
    }
}

/// [`pull_push_levels`] precomputed: the weights of the pull (children per parent) and of the
/// push (Eq. 7: per point and coarser level, the weights `w_k(p_j)` and `1 / sum_k w_k(p_j)`)
/// are found once by R-tree queries, so that a projection is a few sparse loops (section 3.3:
/// `e = P-dagger E` every frame). [`apply`](Self::apply) gives the same bits as
/// [`pull_push_levels`]: it sums the same products in the same order.
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

impl PullPushOp {
    /// Precomputes [`pull_push_levels`] on the coarsest `levels` levels of `ib`.
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

    /// The report [`pull_push_levels`] would give.
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

    /// [`pull_push_levels`]: the pull, then the push, on a copy of `samples`.
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
    use crate::shepard::tests::plane_basis;

    fn sample(ib: &IndexedBasis, f: impl Fn([f32; 3]) -> f32) -> Vec<f32> {
        ib.basis.positions.iter().map(|&p| f(p)).collect()
    }

    #[test]
    fn pull_push_reproduces_a_constant_exactly() {
        let ib = plane_basis(4, 3);
        let samples = vec![2.5f32; ib.basis.len()];
        let (alpha, report) = pull_push(&ib, &samples, 1);
        assert_eq!(report.unsupported_points, 0);
        for j in ib.basis.level_range(0) {
            assert!((alpha[j] - 2.5).abs() < 1e-5);
        }
        let finer = &alpha[ib.basis.level_range(1).start..];
        assert!(finer.iter().all(|a| a.abs() < 1e-5), "{finer:?}");
        let mut out = [0.0];
        for q in 0..50 {
            let x = [0.1 + 0.016 * q as f32, 0.2 + 0.012 * q as f32, 0.0];
            ib.reconstruct(&alpha, 1, 0..4, x, [0.0, 0.0, 1.0], &mut out);
            assert!((out[0] - 2.5).abs() < 1e-5, "{}", out[0]);
        }
    }

    #[test]
    fn project_of_a_constant_is_exact_too() {
        let ib = plane_basis(3, 3);
        let samples = vec![-1.0f32; ib.basis.len()];
        let (alpha, _) = project(&ib, &samples, 1);
        let mut out = [0.0];
        ib.reconstruct(&alpha, 1, 0..3, [0.4, 0.6, 0.0], [0.0, 0.0, 1.0], &mut out);
        assert!((out[0] + 1.0).abs() < 1e-5);
    }

    #[test]
    fn coarse_to_fine_error_falls_with_levels() {
        let f = |p: [f32; 3]| (3.0 * p[0]).sin() * (2.0 * p[1]).cos() + p[0] * p[1];
        let ib = plane_basis(5, 2);
        let (alpha, _) = project(&ib, &sample(&ib, f), 1);
        let mut errs = Vec::new();
        for levels in 1..=5 {
            let mut e2 = 0.0f64;
            let mut out = [0.0];
            let mut count = 0;
            for iy in 1..40 {
                for ix in 1..40 {
                    let x = [ix as f32 / 40.0, iy as f32 / 40.0, 0.0];
                    ib.reconstruct(&alpha, 1, 0..levels, x, [0.0, 0.0, 1.0], &mut out);
                    e2 += ((out[0] - f(x)) as f64).powi(2);
                    count += 1;
                }
            }
            errs.push((e2 / count as f64).sqrt());
        }
        for w in errs.windows(2) {
            assert!(w[1] < w[0], "error did not fall: {errs:?}");
        }
        assert!(errs[4] < 0.25 * errs[0], "{errs:?}");
    }

    #[test]
    fn vector_valued_samples_project_per_component() {
        let ib = plane_basis(3, 3);
        let n = ib.basis.len();
        let mut samples = vec![0.0f32; n * 3];
        for j in 0..n {
            let p = ib.basis.positions[j];
            samples[j * 3] = 1.0;
            samples[j * 3 + 1] = p[0];
            samples[j * 3 + 2] = -2.0;
        }
        let (alpha, _) = pull_push(&ib, &samples, 3);
        let mut out = [0.0; 3];
        ib.reconstruct(&alpha, 3, 0..3, [0.5, 0.5, 0.0], [0.0, 0.0, 1.0], &mut out);
        assert!((out[0] - 1.0).abs() < 1e-5 && (out[2] + 2.0).abs() < 1e-5);
        assert!((out[1] - 0.5).abs() < 0.05, "{out:?}");
    }

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
