//! Weight functions of the meshless basis (Lehtinen et al. 2008, section 2.2) and the
//! Poisson-disk metric of point placement (section 2.3).
//!
//! All functions take plain `[f32; 3]` so that both the bake and the viewer (and, later, a
//! GPU port) share one definition.

/// The paper's `F_squash`: the support ellipsoid is `1 / (1 + F_squash)` thinner along the
/// normal than in the tangent plane.
pub const F_SQUASH: f32 = 2.0;

/// `2 F_squash + F_squash^2`, the factor of Eq. 10's squashed distance:
/// `|v + F_squash <v, n_j> n_j|^2 = |v|^2 + SQUASH <v, n_j>^2` for a unit `n_j`.
pub const SQUASH: f32 = 2.0 * F_SQUASH + F_SQUASH * F_SQUASH;

#[inline(always)]
pub(crate) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The radial polynomial kernel of Eq. 9: `K(r) = 2r^3 - 3r^2 + 1` for `0 <= r <= 1`, 0 beyond.
///
/// `K(0) = 1`, `K(1) = 0`, `K'(0) = K'(1) = 0`. Negative arguments (which distances never
/// produce) are clamped to 0.
/// NaN gives 0 (no support), never NaN.
#[inline(always)]
pub fn kernel(r: f32) -> f32 {
    if r >= 1.0 || r.is_nan() {
        0.0
    } else if r <= 0.0 {
        1.0
    } else {
        (2.0 * r - 3.0) * r * r + 1.0
    }
}

/// Squared anisotropic distance of Eq. 10 from the point `(x_j, n_j)` to `x`:
/// `|v + F_squash <v, n_j> n_j|^2` with `v = x - x_j`, i.e. `|v|^2 + (2F + F^2) <v, n_j>^2`.
///
/// `n_j` must be unit length. The result is never smaller than `|x - x_j|^2`, so a sphere of
/// radius `r_j` bounds the support.
#[inline(always)]
pub fn squashed_distance_sq(x: [f32; 3], xj: [f32; 3], nj: [f32; 3]) -> f32 {
    let v = sub(x, xj);
    let vn = dot(v, nj);
    dot(v, v) + SQUASH * vn * vn
}

/// The anisotropic distance `dist_j(x)` of Eq. 10.
#[inline(always)]
pub fn squashed_distance(x: [f32; 3], xj: [f32; 3], nj: [f32; 3]) -> f32 {
    squashed_distance_sq(x, xj, nj).sqrt()
}

/// The weight function of Eq. 8: `w_j(x, n) = K(dist_j(x) / r_j) * max(0, n . n_j)^2`.
///
/// Returns exactly 0 outside the support (`dist_j(x) >= r_j`), for back-facing normals
/// (`n . n_j <= 0`), for a non-positive or non-finite radius and for non-finite inputs.
/// The offset is divided by `r_j` before it is squared, so the result does not depend on the
/// scene's scale (no underflow of `r_j^2` for radii below 1e-19, no overflow above 1e19).
#[inline(always)]
pub fn weight(x: [f32; 3], n: [f32; 3], xj: [f32; 3], nj: [f32; 3], rj: f32) -> f32 {
    if !(rj > 0.0 && rj.is_finite()) {
        return 0.0;
    }
    weight_inv_radius(x, n, xj, nj, 1.0 / rj)
}

/// [`weight`] given the reciprocal of the radius, `inv_rj = 1 / r_j`, for callers that keep
/// it (the same bits as [`weight`] for that radius); `inv_rj` must be positive and finite.
#[inline(always)]
pub fn weight_inv_radius(x: [f32; 3], n: [f32; 3], xj: [f32; 3], nj: [f32; 3], inv_rj: f32) -> f32 {
    let c = dot(n, nj);
    if c.is_nan() || c <= 0.0 {
        return 0.0;
    }
    let d = sub(x, xj);
    let v = [d[0] * inv_rj, d[1] * inv_rj, d[2] * inv_rj];
    let vn = dot(v, nj);
    let q = dot(v, v) + SQUASH * vn * vn;
    if q >= 1.0 || q.is_nan() {
        return 0.0;
    }
    kernel(q.sqrt()) * c * c
}

/// The symmetric Poisson-disk distance of Eq. 11:
/// `D(p, q) = min(dist_p(x_q), dist_q(x_p)) / max(0, n_p . n_q)^2`.
///
/// Points whose normals are at 90 degrees or more are infinitely far apart (`f32::INFINITY`),
/// so they may be placed arbitrarily close in space. `D(p, q) >= |x_p - x_q|` always.
#[inline]
pub fn poisson_distance(xp: [f32; 3], np: [f32; 3], xq: [f32; 3], nq: [f32; 3]) -> f32 {
    let c = dot(np, nq);
    if c <= 0.0 {
        return f32::INFINITY;
    }
    let d = squashed_distance_sq(xq, xp, np)
        .min(squashed_distance_sq(xp, xq, nq))
        .sqrt();
    d / (c * c)
}

/// Support radius `r = C R` of a level's basis functions (section 2.3): `C` varies linearly
/// from `c_coarse` on level 0 to `c_fine` on the finest of `levels` levels.
pub fn support_factor(level: usize, levels: usize, c_coarse: f32, c_fine: f32) -> f32 {
    if levels <= 1 {
        c_coarse
    } else {
        c_coarse + (c_fine - c_coarse) * level as f32 / (levels - 1) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: [f32; 3] = [0.0, 0.0, 1.0];

    #[test]
    fn kernel_end_points_and_smoothness() {
        assert_eq!(kernel(0.0), 1.0);
        assert_eq!(kernel(1.0), 0.0);
        assert_eq!(kernel(1.5), 0.0);
        assert_eq!(kernel(-0.1), 1.0);
        assert!((kernel(0.5) - 0.5).abs() < 1e-7);
        // Monotone decreasing on [0, 1].
        let mut prev = 1.0;
        for i in 1..=1000 {
            let k = kernel(i as f32 / 1000.0);
            assert!(k <= prev, "kernel not monotone at {i}");
            prev = k;
        }
        // Near the edge the kernel vanishes quadratically (K'(1) = 0): K(1 - h) ~ 3 h^2.
        let h = 1e-3f32;
        assert!((kernel(1.0 - h) / (3.0 * h * h) - 1.0).abs() < 1e-2);
    }

    #[test]
    fn weight_at_centre_and_support_edge() {
        let x = [1.0, 2.0, 3.0];
        assert_eq!(weight(x, N, x, N, 0.5), 1.0);
        // Exactly at r = r_j in the tangent plane: zero.
        assert_eq!(weight([1.5, 2.0, 3.0], N, x, N, 0.5), 0.0);
        // Just inside: tiny but positive.
        let w = weight([1.4999, 2.0, 3.0], N, x, N, 0.5);
        assert!(w > 0.0 && w < 1e-6, "{w}");
        // Zero radius and NaN radius give zero, never NaN.
        assert_eq!(weight(x, N, x, N, 0.0), 0.0);
        assert_eq!(weight(x, N, x, N, f32::NAN), 0.0);
    }

    #[test]
    fn weight_normal_term_at_and_beyond_90_degrees() {
        let x = [0.0; 3];
        assert_eq!(weight(x, [1.0, 0.0, 0.0], x, N, 1.0), 0.0);
        assert_eq!(weight(x, [0.0, 0.0, -1.0], x, N, 1.0), 0.0);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        assert!((weight(x, [s, 0.0, s], x, N, 1.0) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn squash_shrinks_support_along_the_normal() {
        let x = [0.0; 3];
        // Along the normal the support ends at r / (1 + F_squash).
        let edge = 1.0 / (1.0 + F_SQUASH);
        assert!((squashed_distance([0.0, 0.0, edge], x, N) - 1.0).abs() < 1e-6);
        assert!(weight([0.0, 0.0, edge * 1.001], N, x, N, 1.0) == 0.0);
        assert!(weight([0.0, 0.0, edge * 0.999], N, x, N, 1.0) > 0.0);
        // In the tangent plane it is the Euclidean distance.
        assert_eq!(squashed_distance([0.3, 0.4, 0.0], x, N), 0.5);
    }

    #[test]
    fn poisson_distance_properties() {
        let a = [0.0; 3];
        let b = [0.1, 0.0, 0.0];
        // Same normal, tangent offset: Euclidean.
        assert!((poisson_distance(a, N, b, N) - 0.1).abs() < 1e-7);
        // Symmetric.
        let n2 = [0.0, 0.6, 0.8];
        assert_eq!(poisson_distance(a, N, b, n2), poisson_distance(b, n2, a, N));
        // Never below the Euclidean distance.
        assert!(poisson_distance(a, N, b, n2) >= 0.1);
        // Perpendicular or opposite normals: infinitely far.
        assert_eq!(poisson_distance(a, N, b, [1.0, 0.0, 0.0]), f32::INFINITY);
        assert_eq!(poisson_distance(a, N, a, [0.0, 0.0, -1.0]), f32::INFINITY);
    }

    #[test]
    fn kernel_near_both_ends_and_for_nan() {
        assert!((kernel(1e-7) - 1.0).abs() < 1e-6);
        assert!(kernel(1.0 - 1e-7) >= 0.0 && kernel(1.0 - 1e-7) < 1e-12);
        assert_eq!(kernel(f32::NAN), 0.0);
        assert_eq!(kernel(f32::INFINITY), 0.0);
        assert_eq!(kernel(f32::NEG_INFINITY), 1.0);
        // Never outside [0, 1].
        for i in 0..=10_000 {
            let k = kernel(i as f32 / 10_000.0);
            assert!((0.0..=1.0).contains(&k), "{i}: {k}");
        }
    }

    #[test]
    fn weight_at_r_zero_and_r_j_in_every_direction_and_at_every_scale() {
        // Directions in the tangent plane, along the normal and in between; the support's
        // edge in direction u is at r_j / |u + F <u, n> n|.
        let dirs = [
            [1.0f32, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.6, 0.0, 0.8],
        ];
        for scale in [1e-30f32, 1e-20, 1e-4, 1.0, 1e4, 1e20, 1e30] {
            let xj = [3.0 * scale, -2.0 * scale, 0.5 * scale];
            let rj = 0.25 * scale;
            // r = 0: the full weight, at every scale (r_j^2 would underflow at 1e-20).
            assert_eq!(weight(xj, N, xj, N, rj), 1.0, "scale {scale}");
            for u in dirs {
                let stretch = squashed_distance(u, [0.0; 3], N);
                let at = |f: f32| {
                    let t = f * rj / stretch;
                    [xj[0] + t * u[0], xj[1] + t * u[1], xj[2] + t * u[2]]
                };
                // Just outside and well outside: exactly 0.
                assert_eq!(weight(at(1.0001), N, xj, N, rj), 0.0, "{scale} {u:?}");
                assert_eq!(weight(at(2.0), N, xj, N, rj), 0.0);
                // Just inside: tiny, non-negative; halfway: K(1/2) = 1/2.
                let w = weight(at(0.999), N, xj, N, rj);
                assert!((0.0..1e-4).contains(&w), "{scale} {u:?}: {w}");
                let w = weight(at(0.5), N, xj, N, rj);
                assert!((w - 0.5).abs() < 1e-3, "{scale} {u:?}: {w}");
            }
        }
    }

    #[test]
    fn weight_at_and_around_90_degrees_and_for_bad_inputs() {
        let x = [0.0; 3];
        // cos = +-1e-6 about 90 degrees: the weight is c^2 (1e-12) or exactly 0.
        let tilt = |c: f32| [(1.0 - c * c).sqrt(), 0.0, c];
        let w = weight(x, tilt(1e-6), x, N, 1.0);
        assert!(w > 0.0 && w < 2e-12, "{w}");
        assert_eq!(weight(x, tilt(-1e-6), x, N, 1.0), 0.0);
        assert_eq!(weight(x, tilt(0.0), x, N, 1.0), 0.0);
        // Non-finite positions, normals and radii give 0, never NaN.
        let nan = f32::NAN;
        assert_eq!(weight([nan, 0.0, 0.0], N, x, N, 1.0), 0.0);
        assert_eq!(weight(x, [nan, 0.0, 1.0], x, N, 1.0), 0.0);
        assert_eq!(weight(x, N, [f32::INFINITY, 0.0, 0.0], N, 1.0), 0.0);
        assert_eq!(weight(x, N, x, N, f32::INFINITY), 0.0);
        assert_eq!(weight(x, N, x, N, -1.0), 0.0);
        // The Poisson-disk distance at 90 degrees and for coincident points.
        assert_eq!(poisson_distance(x, N, x, tilt(0.0)), f32::INFINITY);
        assert_eq!(poisson_distance(x, N, x, N), 0.0);
        let d = poisson_distance(x, N, [1.0, 0.0, 0.0], tilt(1e-3));
        assert!(d.is_finite() && d > 1e5, "{d}");
    }

    #[test]
    fn support_factor_is_linear_between_the_end_levels() {
        assert_eq!(support_factor(0, 6, 1.5, 2.5), 1.5);
        assert_eq!(support_factor(5, 6, 1.5, 2.5), 2.5);
        assert!((support_factor(1, 6, 1.5, 2.5) - 1.7).abs() < 1e-6);
        assert_eq!(support_factor(0, 1, 1.5, 2.5), 1.5);
    }
}
