//! Flattening (section 4.1): resampling a hierarchical expansion into a single-level meshless
//! basis on the same points, so that a renderer accumulates one layer instead of all levels.
//! The flat coefficient of a point is the hierarchical expansion evaluated there,
//! `c_j = F_L(p_j)` (Eq. 6).
//!
//! [`flatten`] evaluates the hierarchical expansion (Eq. 6) at every hierarchical point; the
//! flat basis itself, a subset of those points with radii from their density, is
//! [`crate::flat_basis::FlatBasis`].

use crate::shepard::IndexedBasis;

/// Flat coefficients `c_j = F_L(p_j)` for every point, `dim` floats each. Points are
/// independent, so they are computed in parallel (in the current rayon pool) with the same
/// result for any thread count.
pub fn flatten(ib: &IndexedBasis, alpha: &[f32], dim: usize) -> Vec<f32> {
    use rayon::prelude::*;
    let b = &ib.basis;
    let mut flat = vec![0.0f32; b.len() * dim];
    flat.par_chunks_mut(dim.max(1) * 256)
        .enumerate()
        .for_each(|(chunk, out)| {
            for (k, o) in out.chunks_mut(dim.max(1)).enumerate() {
                let j = chunk * 256 + k;
                ib.reconstruct(alpha, dim, 0..b.levels(), b.positions[j], b.normals[j], o);
            }
        });
    flat
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pull_push::project;
    use crate::test_support::plane_basis;

    #[test]
    fn flat_coefficients_are_the_hierarchical_values_at_the_points() {
        let ib = plane_basis(3, 3);
        let f = |p: [f32; 3]| (4.0 * p[0]).sin() + p[1];
        let samples: Vec<f32> = ib.basis.positions.iter().map(|&p| f(p)).collect();
        let (alpha, _) = project(&ib, &samples, 1);
        let flat = flatten(&ib, &alpha, 1);
        let mut out = [0.0];
        for j in (0..ib.basis.len()).step_by(7) {
            let (x, n) = (ib.basis.positions[j], ib.basis.normals[j]);
            ib.reconstruct(&alpha, 1, 0..3, x, n, &mut out);
            assert_eq!(flat[j], out[0], "point {j}");
        }
    }
}
