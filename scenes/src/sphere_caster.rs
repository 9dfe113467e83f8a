//! Analytic ray casting against one closed sphere (the test scene with a known answer:
//! uniform indirect irradiance `ρ/(1-ρ) · Φ/(4πR²)` for a point light at the centre).

use glam::Vec3;

use crate::raycast::{Hit, RayCaster};

/// A closed sphere with a uniform albedo, usually seen from inside.
#[derive(Clone, Debug)]
pub struct SphereCaster {
    center: Vec3,
    radius: f32,
    albedo: [f32; 3],
}

impl SphereCaster {
    /// A sphere of `radius` around `center`. A non-positive or non-finite radius gives a
    /// sphere nothing hits.
    pub fn new(center: Vec3, radius: f32, albedo: [f32; 3]) -> SphereCaster {
        SphereCaster {
            center,
            radius,
            albedo,
        }
    }

    pub fn center(&self) -> Vec3 {
        self.center
    }

    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Both roots (ascending) of `|origin + t dir - center| = radius`, `dir` unit length.
    ///
    /// Numerically robust form: the discriminant is computed from the component of
    /// `origin - center` perpendicular to the ray (no cancellation for far origins), and the
    /// roots as `q` and `c / q` (no cancellation between `-b` and the square root).
    fn roots(&self, origin: Vec3, dir: Vec3) -> Option<(f32, f32)> {
        let r = self.radius;
        if !(r > 0.0 && r.is_finite()) {
            return None;
        }
        let oc = origin - self.center;
        let b = oc.dot(dir);
        let perp = oc - b * dir;
        let disc = r * r - perp.length_squared();
        if disc < 0.0 {
            return None;
        }
        let c = oc.length_squared() - r * r;
        let sq = disc.sqrt();
        let q = -b - sq.copysign(b);
        if q == 0.0 {
            // b = 0 and tangent: a double root at t = 0.
            return Some((0.0, 0.0));
        }
        let (t0, t1) = (c / q, q);
        Some(if t0 <= t1 { (t0, t1) } else { (t1, t0) })
    }
}

impl RayCaster for SphereCaster {
    fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        if !origin.is_finite() || !dir.is_finite() {
            return None;
        }
        let (t0, t1) = self.roots(origin, dir)?;
        let t = [t0, t1].into_iter().find(|&t| t > tmin && t < tmax)?;
        // Project onto the surface so that offsets from the hit are measured from the sphere.
        let radial = (origin + t * dir - self.center).normalize_or_zero();
        if radial == Vec3::ZERO {
            return None;
        }
        let position = self.center + radial * self.radius;
        let normal = if radial.dot(dir) > 0.0 {
            -radial
        } else {
            radial
        };
        Some(Hit {
            t,
            position,
            geometric_normal: normal,
            shading_normal: normal,
            albedo: self.albedo,
            prim_id: 0,
        })
    }

    fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        if !a.is_finite() || !b.is_finite() {
            return false;
        }
        let eps = self.ray_epsilon();
        // The sphere is convex: a segment between two points inside or on it never crosses
        // its surface.
        let inside = |p: Vec3| (p - self.center).length() <= self.radius + eps;
        if inside(a) && inside(b) {
            return false;
        }
        let d = b - a;
        let len = d.length();
        if len <= 2.0 * eps {
            return false;
        }
        let dir = d / len;
        match self.roots(a, dir) {
            Some((t0, t1)) => [t0, t1].iter().any(|&t| t > eps && t < len - eps),
            None => false,
        }
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        let r = Vec3::splat(self.radius.max(0.0));
        (self.center - r, self.center + r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inside_hits_face_the_centre() {
        let s = SphereCaster::new(Vec3::new(1.0, 2.0, 3.0), 2.0, [0.5; 3]);
        let dir = Vec3::new(1.0, 1.0, 0.0).normalize();
        let h = s
            .intersect(s.center(), dir, 0.0, f32::INFINITY)
            .expect("hits from inside");
        assert!((h.t - 2.0).abs() < 1e-5);
        assert!((h.geometric_normal + dir).length() < 1e-5, "points inward");
        assert!(h.geometric_normal.dot(dir) <= 0.0);
        assert_eq!(h.prim_id, 0);
    }

    #[test]
    fn outside_hits_face_outwards_and_far_rays_are_accurate() {
        let s = SphereCaster::new(Vec3::ZERO, 1.0, [0.5; 3]);
        let h = s
            .intersect(Vec3::new(0.0, 0.0, 1e5), -Vec3::Z, 0.0, f32::INFINITY)
            .expect("hits");
        assert!((h.t - (1e5 - 1.0)).abs() <= 1e5 * 1e-6, "{}", h.t);
        assert!((h.geometric_normal - Vec3::Z).length() < 1e-5);
        // Tangent-ish miss and a ray pointing away.
        assert!(s
            .intersect(Vec3::new(0.0, 1.001, 5.0), -Vec3::Z, 0.0, f32::INFINITY)
            .is_none());
        assert!(s
            .intersect(Vec3::new(0.0, 0.0, 5.0), Vec3::Z, 0.0, f32::INFINITY)
            .is_none());
        // tmax before the sphere.
        assert!(s
            .intersect(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z, 0.0, 3.9)
            .is_none());
    }

    #[test]
    fn occlusion() {
        let s = SphereCaster::new(Vec3::ZERO, 1.0, [0.5; 3]);
        // Two points on the surface: never occluded.
        assert!(!s.occluded(Vec3::X, -Vec3::X));
        assert!(!s.occluded(Vec3::ZERO, Vec3::Y));
        // Inside to outside crosses the surface.
        assert!(s.occluded(Vec3::ZERO, Vec3::new(3.0, 0.0, 0.0)));
        // Outside, through the sphere.
        assert!(s.occluded(Vec3::new(-3.0, 0.0, 0.0), Vec3::new(3.0, 0.0, 0.0)));
        // Outside, passing by.
        assert!(!s.occluded(Vec3::new(-3.0, 2.0, 0.0), Vec3::new(3.0, 2.0, 0.0)));
    }
}
