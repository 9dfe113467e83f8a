//! Flattening (section 4.1): resampling a hierarchical expansion into a single-level meshless
//! basis on the same points, so that a renderer accumulates one layer instead of all levels.
//!
//! The flat basis is a single-level meshless basis on every point of every level ("constructed
//! from the same points as the hierarchical basis"): point `j` of level `l` gets the weight
//! function of Eq. 8 with its own support radius, scaled by a level priority
//! `FLAT_LEVEL_PRIORITY^(L-1-l)` ([`flat_level_factor`]), and the functions are normalised over
//! all of them: `B^flat_j = f_j w_j / sum_k f_k w_k`. The flat coefficient of point `j` is the
//! hierarchical expansion evaluated there, `c_j = F_L(p_j)` (Eq. 6).
//!
//! Why the priority: with equal weights the coarse functions, whose supports overlap as many
//! neighbours as the fine ones, carry about as much weight as the fine functions everywhere, so
//! the displayed solution blurs towards the coarse levels (on a closed sphere it shows the
//! irradiance averaged over the coarse supports, short of the exact value). With the factor
//! each coarser level weighs 1 % of the next finer one where that one has support, and takes
//! over only where the finer levels have none. (Giving every point the finest level's radius
//! instead would leave holes, black pixels, wherever the finest level has no points: point
//! placement runs out of candidates there.)

use crate::shepard::{IndexedBasis, Support, MAX_DIM, MIN_WEIGHT_SUM};

/// Weight of a level relative to the next finer one in the flat basis.
pub const FLAT_LEVEL_PRIORITY: f32 = 0.01;

/// The factor `FLAT_LEVEL_PRIORITY^(levels-1-level)` of a level's weight functions in the flat
/// basis (1 on the finest level). Whether a point has support is decided on the unscaled
/// weights (`MIN_WEIGHT_SUM`), so the factor only ranks the levels.
pub fn flat_level_factor(level: usize, levels: usize) -> f32 {
    FLAT_LEVEL_PRIORITY.powi(levels.saturating_sub(1 + level) as i32)
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
/// its own radius and its level's [`flat_level_factor`]), as the renderer's splatting does per
/// pixel.
pub fn reconstruct_flat(
    ib: &IndexedBasis,
    flat: &[f32],
    dim: usize,
    x: [f32; 3],
    n: [f32; 3],
    out: &mut [f32],
) -> Support {
    assert!(dim <= MAX_DIM && out.len() >= dim);
    let levels = ib.levels();
    let mut acc = [0.0f32; MAX_DIM];
    let (mut sum, mut raw) = (0.0f32, 0.0f32);
    for l in 0..levels {
        let f = flat_level_factor(l, levels);
        raw += ib.for_each_weight(l, x, n, |j, w| {
            let w = f * w;
            sum += w;
            for k in 0..dim {
                acc[k] += w * flat[j * dim + k];
            }
        });
    }
    if raw > MIN_WEIGHT_SUM && sum > 0.0 {
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
    fn finer_levels_dominate_the_flat_basis_where_they_have_support() {
        assert_eq!(flat_level_factor(2, 3), 1.0);
        assert_eq!(
            flat_level_factor(0, 3),
            FLAT_LEVEL_PRIORITY * FLAT_LEVEL_PRIORITY
        );
        assert!(flat_level_factor(0, 6) > 0.5e-10);
        // Flat coefficients 1 on the finest level and 0 on the coarser ones: where the finest
        // level has support, the flat expansion is within the priority of 1.
        let ib = plane_basis(3, 3);
        let fine = ib.basis.level_range(2);
        let flat: Vec<f32> = (0..ib.basis.len())
            .map(|j| if fine.contains(&j) { 1.0 } else { 0.0 })
            .collect();
        let mut out = [0.0];
        for q in 0..50 {
            let x = [0.2 + 0.012 * q as f32, 0.3 + 0.008 * q as f32, 0.0];
            reconstruct_flat(&ib, &flat, 1, x, [0.0, 0.0, 1.0], &mut out);
            assert!(
                out[0] > 1.0 - 3.0 * FLAT_LEVEL_PRIORITY,
                "{x:?}: {}",
                out[0]
            );
        }
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
