//! Flattening (section 4.1): resampling a hierarchical expansion into a single-level meshless
//! basis on the same points, so that a renderer accumulates one layer instead of all levels.
//!
//! The flat basis is a single-level meshless basis on every point of every level ("constructed
//! from the same points as the hierarchical basis"): each point gets the weight function of
//! Eq. 8 with one common support radius, the finest level's ([`flat_radius`]), normalised over
//! all of them: `B^flat_j = w_j / sum_k w_k`. The flat coefficient of point `j` is the
//! hierarchical expansion evaluated there, `c_j = F_L(p_j)` (Eq. 6).
//!
//! Keeping each point's own (level) radius instead would make the coarse functions, whose
//! supports overlap as many neighbours as the fine ones, carry about as much weight as the
//! fine functions everywhere: the displayed solution would be blurred towards the coarse
//! levels (on a closed sphere, the vector irradiance averaged over the coarse supports comes
//! out 4-5 % short), and the splatting would draw every coarse footprint, which is the
//! overdraw flattening exists to remove.

use crate::kernel::weight;
use crate::shepard::{IndexedBasis, Support, MAX_DIM, MIN_WEIGHT_SUM};
use crate::Basis;

/// The common support radius of the flat basis: the finest non-empty level's largest support
/// radius (0 for an empty basis). It is never larger than any point's own radius, so the
/// R-trees (built over the own radii) stay conservative for flat queries.
pub fn flat_radius(basis: &Basis) -> f32 {
    (0..basis.levels())
        .rev()
        .map(|l| basis.level_range(l))
        .find(|r| !r.is_empty())
        .map(|r| basis.radii[r].iter().fold(0.0f32, |m, &v| m.max(v)))
        .unwrap_or(0.0)
}

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

/// Evaluates the flat expansion `sum_j c_j B^flat_j(x, n)` into `out[..dim]` (every point with
/// the [`flat_radius`]), as the renderer's splatting does per pixel.
pub fn reconstruct_flat(
    ib: &IndexedBasis,
    flat: &[f32],
    dim: usize,
    x: [f32; 3],
    n: [f32; 3],
    out: &mut [f32],
) -> Support {
    assert!(dim <= MAX_DIM && out.len() >= dim);
    let b = &ib.basis;
    let r = flat_radius(b);
    let mut acc = [0.0f32; MAX_DIM];
    let mut sum = 0.0f32;
    for tree in &ib.trees {
        tree.for_each_candidate(x, |j| {
            let j = j as usize;
            let w = weight(x, n, b.positions[j], b.normals[j], r);
            if w > 0.0 {
                sum += w;
                for k in 0..dim {
                    acc[k] += w * flat[j * dim + k];
                }
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
    fn flat_radius_is_the_finest_levels_and_bounded_by_every_points_own() {
        let ib = plane_basis(3, 3);
        let r = flat_radius(&ib.basis);
        let finest = ib.basis.level_range(2);
        assert!(r > 0.0);
        assert_eq!(r, ib.basis.radii[finest.start]);
        assert!(ib.basis.radii.iter().all(|&own| own >= r));
        assert_eq!(flat_radius(&crate::Basis::default()), 0.0);
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
