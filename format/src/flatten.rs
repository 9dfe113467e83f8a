//! Flattening (section 4.1): resampling a hierarchical expansion into a single-level meshless
//! basis on the same points, so that a renderer accumulates one layer instead of all levels.
//!
//! The flat basis uses every point of every level with its own weight function, normalised
//! over all of them: `B^flat_j = w_j / sum_k w_k`. The flat coefficient of point `j` is the
//! hierarchical expansion evaluated there, `c_j = F_L(p_j)` (Eq. 6).

use crate::shepard::{IndexedBasis, Support, MAX_DIM, MIN_WEIGHT_SUM};

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

/// Evaluates the flat expansion `sum_j c_j B^flat_j(x, n)` into `out[..dim]`.
pub fn reconstruct_flat(
    ib: &IndexedBasis,
    flat: &[f32],
    dim: usize,
    x: [f32; 3],
    n: [f32; 3],
    out: &mut [f32],
) -> Support {
    assert!(dim <= MAX_DIM && out.len() >= dim);
    let mut acc = [0.0f32; MAX_DIM];
    let mut sum = 0.0f32;
    for l in 0..ib.levels() {
        sum += ib.for_each_weight(l, x, n, |j, w| {
            for k in 0..dim {
                acc[k] += w * flat[j * dim + k];
            }
        });
    }
    if sum > MIN_WEIGHT_SUM {
        for k in 0..dim {
            out[k] = acc[k] / sum;
        }
        Support {
            supported: 1,
            unsupported: 0,
        }
    } else {
        out[..dim].fill(0.0);
        Support {
            supported: 0,
            unsupported: 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pull_push::project;
    use crate::shepard::tests::plane_basis;

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

    #[test]
    fn flat_reconstruction_tracks_the_hierarchical_one() {
        let ib = plane_basis(4, 3);
        let f = |p: [f32; 3]| (3.0 * p[0]).sin() * (2.0 * p[1]).cos();
        let samples: Vec<f32> = ib.basis.positions.iter().map(|&p| f(p)).collect();
        let (alpha, _) = project(&ib, &samples, 1);
        let flat = flatten(&ib, &alpha, 1);
        let (mut h, mut fl) = ([0.0], [0.0]);
        let mut max_diff = 0.0f32;
        for q in 0..200 {
            let x = [0.1 + 0.004 * q as f32, 0.85 - 0.0035 * q as f32, 0.0];
            let n = [0.0, 0.0, 1.0];
            ib.reconstruct(&alpha, 1, 0..4, x, n, &mut h);
            reconstruct_flat(&ib, &flat, 1, x, n, &mut fl);
            max_diff = max_diff.max((h[0] - fl[0]).abs());
        }
        assert!(
            max_diff < 0.05,
            "flat and hierarchical differ by {max_diff}"
        );
    }

    #[test]
    fn flat_constant_is_exact() {
        let ib = plane_basis(3, 3);
        let flat = vec![0.75f32; ib.basis.len()];
        let mut out = [0.0];
        let s = reconstruct_flat(&ib, &flat, 1, [0.3, 0.3, 0.0], [0.0, 0.0, 1.0], &mut out);
        assert_eq!(s.supported, 1);
        assert!((out[0] - 0.75).abs() < 1e-6);
    }
}
