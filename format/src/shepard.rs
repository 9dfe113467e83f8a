//! Shepard evaluation of the per-level basis (Eq. 1-2) and reconstruction of a hierarchical
//! expansion (Eq. 5-6).

use crate::basis::Basis;
use crate::error::FormatError;
use crate::kernel::weight;
use crate::rtree::RTree;
use crate::support_clip::SupportClip;

/// Weight sums at or below this are treated as "no support" rather than divided by. Weights
/// are products of a kernel and a squared cosine, both at most 1; a sum this small means the
/// query point sits on the very rim of every support, where the normalised value is not
/// meaningful.
pub const MIN_WEIGHT_SUM: f32 = 1e-12;

/// Largest coefficient dimension (scalar 1, RGB 3, RGB vector irradiance 9).
pub const MAX_DIM: usize = 16;

/// A basis with one R-tree per level: everything needed to evaluate basis functions.
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedBasis {
    pub basis: Basis,
    pub trees: Vec<RTree>,
    /// The functions' supports clipped at occluders ([`crate::support_clip`]); empty where
    /// nothing is clipped. Every weight evaluation of this type leaves out what it cuts.
    pub clip: SupportClip,
}

/// What a reconstruction found at the query point.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Support {
    /// Levels with a non-negligible weight sum at the query point.
    pub supported: u32,
    /// Levels asked for that had none (reported, never divided by).
    pub unsupported: u32,
}

impl IndexedBasis {
    /// Builds the R-trees of every level.
    pub fn build(basis: Basis) -> Result<IndexedBasis, FormatError> {
        basis.validate()?;
        let trees = (0..basis.levels())
            .map(|l| RTree::build(&basis, basis.level_range(l)))
            .collect();
        Ok(IndexedBasis {
            basis,
            trees,
            clip: SupportClip::default(),
        })
    }

    /// Pairs a basis with trees read from a file, validating both.
    pub fn from_parts(basis: Basis, trees: Vec<RTree>) -> Result<IndexedBasis, FormatError> {
        basis.validate()?;
        if trees.len() != basis.levels() {
            return Err(FormatError::InvalidBasis(format!(
                "{} R-trees for {} levels",
                trees.len(),
                basis.levels()
            )));
        }
        for (l, t) in trees.iter().enumerate() {
            t.validate(&basis, basis.level_range(l))
                .map_err(|e| FormatError::InvalidBasis(format!("R-tree of level {l}: {e}")))?;
        }
        Ok(IndexedBasis {
            basis,
            trees,
            clip: SupportClip::default(),
        })
    }

    /// The basis with its supports clipped by `clip` (validated against the point count).
    pub fn with_clip(mut self, clip: SupportClip) -> Result<IndexedBasis, FormatError> {
        clip.validate(self.basis.len())?;
        self.clip = clip;
        Ok(self)
    }

    pub fn levels(&self) -> usize {
        self.basis.levels()
    }

    /// Calls `f(j, w_j(x, n))` for every basis function of level `l` with a positive weight
    /// (Eq. 8) at the surface point `(x, n)`, less those whose clipped support leaves `x` out
    /// (unless that leaves none: a clip never opens a hole in a level, which would lose the
    /// light there); returns the sum of those weights.
    #[inline]
    pub fn for_each_weight(
        &self,
        l: usize,
        x: [f32; 3],
        n: [f32; 3],
        mut f: impl FnMut(usize, f32),
    ) -> f32 {
        let (sum, cut) = self.weights(l, x, n, true, &mut f);
        if sum == 0.0 && cut {
            // The clip would leave the level without support at `x`: unclipped there.
            return self.weights(l, x, n, false, &mut f).0;
        }
        sum
    }

    /// Calls `f(j, w_j)` for the functions of level `l` with a positive weight at `(x, n)`,
    /// less those the clip cuts when `clipped`; returns their weights' sum and whether the
    /// clip cut any.
    #[inline]
    fn weights(
        &self,
        l: usize,
        x: [f32; 3],
        n: [f32; 3],
        clipped: bool,
        f: &mut impl FnMut(usize, f32),
    ) -> (f32, bool) {
        let b = &self.basis;
        let (mut sum, mut cut) = (0.0f32, false);
        self.trees[l].for_each_candidate(x, |j| {
            let j = j as usize;
            let w = weight(x, n, b.positions[j], b.normals[j], b.radii[j]);
            if w > 0.0 {
                if clipped && self.clip.cuts(j, x) {
                    cut = true;
                } else {
                    sum += w;
                    f(j, w);
                }
            }
        });
        (sum, cut)
    }

    /// [`IndexedBasis::for_each_weight`] without the fallback: where the clip cuts every
    /// function of the level, none is called and the sum is 0 (the flat basis, whose splat
    /// on the GPU sees one function at a time, evaluates this).
    #[inline]
    pub fn for_each_clipped_weight(
        &self,
        l: usize,
        x: [f32; 3],
        n: [f32; 3],
        mut f: impl FnMut(usize, f32),
    ) -> f32 {
        self.weights(l, x, n, true, &mut f).0
    }

    /// Sum of the weights of level `l` at `(x, n)`, the Shepard denominator of Eq. 2.
    pub fn weight_sum(&self, l: usize, x: [f32; 3], n: [f32; 3]) -> f32 {
        self.for_each_weight(l, x, n, |_, _| {})
    }

    /// Calls `f(j, B_j(x, n))` for the basis functions of level `l` (Eq. 2); returns false, and
    /// calls nothing, where the level has no support.
    pub fn for_each_basis_value(
        &self,
        l: usize,
        x: [f32; 3],
        n: [f32; 3],
        mut f: impl FnMut(usize, f32),
    ) -> bool {
        let sum = self.weight_sum(l, x, n);
        if sum <= MIN_WEIGHT_SUM {
            return false;
        }
        let inv = 1.0 / sum;
        self.for_each_weight(l, x, n, |j, w| f(j, w * inv));
        true
    }

    /// Evaluates `sum_j alpha_j B_j(x, n)` over the levels `levels` (Eq. 6; with `0..L` the
    /// full hierarchical expansion, with `0..l` the approximation `F_{l-1}` of Eq. 7).
    /// `alpha` holds `dim` floats per point (at least for the points of `levels`); the result
    /// is written to `out[..dim]`.
    pub fn reconstruct(
        &self,
        alpha: &[f32],
        dim: usize,
        levels: std::ops::Range<usize>,
        x: [f32; 3],
        n: [f32; 3],
        out: &mut [f32],
    ) -> Support {
        // `alpha` must cover the points of the levels evaluated (the senders' coefficients,
        // say, cover only the coarsest levels).
        let covered = self.basis.level_offsets[levels.end.min(self.levels())] as usize;
        assert!(dim <= MAX_DIM && out.len() >= dim && alpha.len() >= covered * dim);
        out[..dim].fill(0.0);
        let mut support = Support::default();
        let mut acc = [0.0f32; MAX_DIM];
        for l in levels {
            acc[..dim].fill(0.0);
            let sum = self.for_each_weight(l, x, n, |j, w| {
                let a = &alpha[j * dim..j * dim + dim];
                for k in 0..dim {
                    acc[k] += w * a[k];
                }
            });
            if sum > MIN_WEIGHT_SUM {
                support.supported += 1;
                let inv = 1.0 / sum;
                for k in 0..dim {
                    out[k] += acc[k] * inv;
                }
            } else {
                support.unsupported += 1;
            }
        }
        support
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::plane_basis;

    #[test]
    fn partition_of_unity_on_every_level() {
        let ib = plane_basis(4, 3);
        let n = [0.0, 0.0, 1.0];
        for l in 0..4 {
            for q in 0..100 {
                let x = [0.05 + 0.009 * q as f32, 0.93 - 0.0087 * q as f32, 0.0];
                let mut total = 0.0f64;
                assert!(ib.for_each_basis_value(l, x, n, |_, b| total += b as f64));
                assert!((total - 1.0).abs() < 1e-5, "level {l} query {q}: {total}");
            }
        }
    }

    #[test]
    fn no_support_is_reported_not_divided() {
        let ib = plane_basis(2, 3);
        let far = [10.0, 10.0, 0.0];
        let alpha = vec![1.0f32; ib.basis.len()];
        let mut out = [f32::NAN];
        let s = ib.reconstruct(&alpha, 1, 0..2, far, [0.0, 0.0, 1.0], &mut out);
        assert_eq!(
            s,
            Support {
                supported: 0,
                unsupported: 2
            }
        );
        assert_eq!(out[0], 0.0);
        // Back-facing query normal: no support either.
        let s = ib.reconstruct(&alpha, 1, 0..2, [0.5, 0.5, 0.0], [0.0, 0.0, -1.0], &mut out);
        assert_eq!(s.unsupported, 2);
        assert!(out[0].is_finite());
        // Normal at exactly 90 degrees to every point normal: zero weight, no NaN.
        let s = ib.reconstruct(&alpha, 1, 0..2, [0.5, 0.5, 0.0], [1.0, 0.0, 0.0], &mut out);
        assert_eq!(s.unsupported, 2);
        assert_eq!(out[0], 0.0);
    }

    fn single_point(radius: f32) -> IndexedBasis {
        let mut b = Basis::default();
        b.positions.push([0.0; 3]);
        b.normals.push([0.0, 0.0, 1.0]);
        b.radii.push(radius);
        b.level_offsets = vec![0, 1];
        b.disk_radii = vec![radius];
        IndexedBasis::build(b).unwrap()
    }

    #[test]
    fn the_min_weight_sum_threshold_decides_support_and_nothing_else() {
        // Query normals tilted so that the weight is c^2 just below and just above
        // MIN_WEIGHT_SUM: below, the level has no support and nothing is divided; above, the
        // lone function normalises to exactly 1 (B_j = w_j / w_j), whatever the tiny weight.
        let ib = single_point(1.0);
        let tilt = |c: f32| [(1.0 - c * c).sqrt(), 0.0, c];
        let below = (0.5 * MIN_WEIGHT_SUM).sqrt();
        let above = (2.0 * MIN_WEIGHT_SUM).sqrt();
        let alpha = [3.0f32];
        let mut out = [f32::NAN];
        let s = ib.reconstruct(&alpha, 1, 0..1, [0.0; 3], tilt(below), &mut out);
        assert_eq!(s.unsupported, 1);
        assert_eq!(out[0], 0.0);
        let mut called = false;
        assert!(!ib.for_each_basis_value(0, [0.0; 3], tilt(below), |_, _| called = true));
        assert!(!called);
        let s = ib.reconstruct(&alpha, 1, 0..1, [0.0; 3], tilt(above), &mut out);
        assert_eq!(s.supported, 1);
        assert!((out[0] - 3.0).abs() < 1e-5, "{}", out[0]);
        let mut total = 0.0;
        assert!(ib.for_each_basis_value(0, [0.0; 3], tilt(above), |_, b| total += b));
        assert!((total - 1.0).abs() < 1e-6, "{total}");
    }

    #[test]
    fn r_zero_gives_the_coefficient_and_r_j_gives_no_support() {
        let ib = single_point(0.5);
        let n = [0.0, 0.0, 1.0];
        let alpha = [7.0f32];
        let mut out = [0.0];
        assert_eq!(ib.weight_sum(0, [0.0; 3], n), 1.0);
        ib.reconstruct(&alpha, 1, 0..1, [0.0; 3], n, &mut out);
        assert_eq!(out[0], 7.0);
        // Exactly at r_j in the tangent plane, and at r_j / (1 + F_squash) along the normal.
        for x in [[0.5, 0.0, 0.0], [0.0, 0.0, 0.5 / 3.0]] {
            assert_eq!(ib.weight_sum(0, x, n), 0.0);
            let s = ib.reconstruct(&alpha, 1, 0..1, x, n, &mut out);
            assert_eq!((s.unsupported, out[0]), (1, 0.0));
        }
    }

    #[test]
    fn non_finite_queries_find_no_support() {
        let ib = plane_basis(2, 3);
        let alpha = vec![1.0f32; ib.basis.len()];
        let mut out = [f32::NAN];
        for (x, n) in [
            ([f32::NAN, 0.5, 0.0], [0.0, 0.0, 1.0]),
            ([0.5, f32::INFINITY, 0.0], [0.0, 0.0, 1.0]),
            ([0.5, 0.5, 0.0], [f32::NAN, 0.0, 1.0]),
        ] {
            let s = ib.reconstruct(&alpha, 1, 0..2, x, n, &mut out);
            assert_eq!(s.unsupported, 2, "{x:?} {n:?}");
            assert_eq!(out[0], 0.0);
        }
    }

    #[test]
    fn weight_sums_near_zero_stay_finite() {
        // A single point; query at the rim of its support, where the weight is tiny.
        let mut b = Basis::default();
        b.positions.push([0.0; 3]);
        b.normals.push([0.0, 0.0, 1.0]);
        b.radii.push(1.0);
        b.level_offsets = vec![0, 1];
        b.disk_radii = vec![1.0];
        let ib = IndexedBasis::build(b).unwrap();
        let alpha = [3.0f32];
        let mut out = [0.0];
        for d in [0.999, 0.99999, 0.9999999, 1.0] {
            let s = ib.reconstruct(&alpha, 1, 0..1, [d, 0.0, 0.0], [0.0, 0.0, 1.0], &mut out);
            assert!(out[0].is_finite());
            if s.supported == 1 {
                assert!((out[0] - 3.0).abs() < 1e-4, "{d}: {}", out[0]);
            } else {
                assert_eq!(out[0], 0.0);
            }
        }
    }
}
