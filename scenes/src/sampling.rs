//! Direction sampling shared by the bake (particles, gathers, dart-thrower rays) and the
//! viewer's path-traced reference: the same function for the same distribution.

use glam::Vec3;

/// An orthonormal basis `(t, b)` completing the unit vector `n` (Duff et al. 2017).
#[inline]
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Uniform direction on the unit sphere from two uniform numbers in `[0, 1)`.
#[inline]
pub fn uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Cosine-weighted direction about the unit normal `n` (pdf `cos / pi`).
#[inline]
pub fn cosine_hemisphere(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = tangent_frame(n);
    let z = (1.0 - u1).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

/// Direction in the cone of half-angle `acos(cos_max)` about the unit axis `a`, uniform in
/// solid angle, from two uniform numbers in `[0, 1)`. `cos_max` is clamped to `[-1, 1]`
/// (`-1`: the whole sphere).
#[inline]
pub fn uniform_cone(a: Vec3, cos_max: f32, u1: f32, u2: f32) -> Vec3 {
    let cos_max = cos_max.clamp(-1.0, 1.0);
    let z = 1.0 - u1 * (1.0 - cos_max);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = tangent_frame(a);
    (t * (r * phi.cos()) + b * (r * phi.sin()) + a * z).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic uniform pairs: the Halton sequence in bases 2 and 3, offset per test.
    struct Halton(u32);

    impl Halton {
        fn new(offset: u32) -> Halton {
            Halton(offset * 100_003)
        }

        fn next_pair(&mut self) -> (f32, f32) {
            let inverse = |mut k: u32, base: u32| {
                let (mut f, mut r) = (1.0f64, 0.0f64);
                while k > 0 {
                    f /= base as f64;
                    r += f * (k % base) as f64;
                    k /= base;
                }
                r.min(1.0 - f64::EPSILON) as f32
            };
            self.0 += 1;
            (inverse(self.0, 2), inverse(self.0, 3))
        }
    }

    #[test]
    fn frames_are_orthonormal_including_the_pole() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.4, 0.5).normalize(),
        ] {
            let (t, b) = tangent_frame(n);
            assert!(t.dot(n).abs() < 1e-6 && b.dot(n).abs() < 1e-6 && t.dot(b).abs() < 1e-6);
            assert!((t.length() - 1.0).abs() < 1e-6 && (b.length() - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn cosine_samples_have_mean_cosine_two_thirds() {
        // E[cos] under the cosine pdf is 2/3; fixed seed, 5 standard errors.
        let n = Vec3::new(0.2, 0.9, -0.1).normalize();
        let mut r = Halton::new(9);
        let m = 50_000;
        let mut sum = 0.0f64;
        for _ in 0..m {
            let (u1, u2) = r.next_pair();
            let d = cosine_hemisphere(n, u1, u2);
            assert!(d.dot(n) >= -1e-6);
            sum += d.dot(n) as f64;
        }
        let mean = sum / m as f64;
        let sd = (0.5 - (2.0f64 / 3.0).powi(2)).sqrt() / (m as f64).sqrt();
        assert!((mean - 2.0 / 3.0).abs() < 5.0 * sd, "{mean}");
    }

    #[test]
    fn frames_stay_orthonormal_next_to_the_pole_singularity() {
        // The branch at n.z = 0 and just below -1 (where 1 / (sign + n.z) is largest).
        for n in [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, -0.0),
            Vec3::new(1e-4, 0.0, -1.0).normalize(),
            Vec3::new(0.0, 1e-7, -1.0).normalize(),
            Vec3::new(-1e-7, 0.0, 1.0).normalize(),
        ] {
            let (t, b) = tangent_frame(n);
            assert!(t.is_finite() && b.is_finite(), "{n}");
            assert!(t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5 && t.dot(b).abs() < 1e-5);
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn samplers_at_the_ends_of_the_unit_interval() {
        let n = Vec3::new(0.0, 0.0, 1.0);
        for (u1, u2) in [(0.0, 0.0), (0.0, 0.9999999), (0.9999999, 0.5), (1.0, 1.0)] {
            let d = cosine_hemisphere(n, u1, u2);
            assert!(d.is_finite() && (d.length() - 1.0).abs() < 1e-5 && d.z >= -1e-6);
            let s = uniform_sphere(u1, u2);
            assert!(s.is_finite() && (s.length() - 1.0).abs() < 1e-5);
            // A zero-angle cone is its axis; a cone of cos -1 (and beyond) is the sphere.
            let c = uniform_cone(n, 1.0, u1, u2);
            assert!((c - n).length() < 1e-5, "{c}");
            let c = uniform_cone(n, -3.0, u1, u2);
            assert!(c.is_finite() && (c.length() - 1.0).abs() < 1e-5);
        }
        // Inside the cone: cos >= cos_max.
        let a = Vec3::new(0.3, -0.9, 0.1).normalize();
        let mut r = Halton::new(4);
        for _ in 0..1000 {
            let (u1, u2) = r.next_pair();
            let d = uniform_cone(a, 0.8, u1, u2);
            assert!(d.dot(a) >= 0.8 - 1e-5);
        }
    }

    #[test]
    fn sphere_samples_are_centred() {
        let mut r = Halton::new(10);
        let m = 50_000;
        let mut sum = Vec3::ZERO;
        for _ in 0..m {
            let (u1, u2) = r.next_pair();
            let d = uniform_sphere(u1, u2);
            assert!((d.length() - 1.0).abs() < 1e-5);
            sum += d;
        }
        // Each component has variance 1/3; 5 standard errors.
        let bound = 5.0 * (1.0f32 / 3.0 / m as f32).sqrt();
        assert!((sum / m as f32).abs().max_element() < bound, "{sum}");
    }
}
