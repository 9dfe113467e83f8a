//! Projection of point samples onto the hierarchical basis: the coarse-to-fine operator `P`
//! (Eq. 7) and the band-limiting pull-push operator `P-dagger` (section 2.1, "Pull-Push
//! Approximation"; used for the direct light at run time, section 3.3).
//!
//! Samples and coefficients are flat `f32` arrays with `dim` values per point, indexed by the
//! basis' global point index.

use crate::shepard::{IndexedBasis, MAX_DIM};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::plane_basis;

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
}
