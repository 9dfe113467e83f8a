//! The pinhole camera's primary rays, shared by the viewer (its rasteriser and reference
//! integrator) and the bake's check of its first bounce at the scene's camera, so that both
//! look through the same pixels.
//!
//! The camera sits at `position`, looks at `target` with `up` as the image's upward direction
//! and a vertical field of view of `fovy_deg` degrees, over `width x height` pixels. Image
//! coordinates `(px, py)` are in pixels from the top-left corner, so pixel `(i, j)` spans
//! `[i, i + 1) x [j, j + 1)` and has its centre at `(i + 0.5, j + 0.5)`.

use glam::Vec3;

use crate::meta::CameraInfo;

/// Unit vectors `(right, up, back)` of the camera frame (right-handed, looking down `-back`).
/// Not finite when `target` equals `position` or `up` is along the view direction.
pub fn frame(position: Vec3, target: Vec3, up: Vec3) -> (Vec3, Vec3, Vec3) {
    let back = (position - target).normalize();
    let right = up.cross(back).normalize();
    let up = back.cross(right);
    (right, up, back)
}

/// The unit direction of the primary ray through the image point `(px, py)` of a camera with
/// the given `frame` ([`frame`]), vertical field of view and image size.
pub fn ray_direction(
    (right, up, back): (Vec3, Vec3, Vec3),
    fovy_deg: f32,
    (width, height): (u32, u32),
    (px, py): (f32, f32),
) -> Vec3 {
    let t = (0.5 * fovy_deg.to_radians()).tan();
    let aspect = width as f32 / height as f32;
    let sx = (2.0 * px / width as f32 - 1.0) * t * aspect;
    let sy = (1.0 - 2.0 * py / height as f32) * t;
    (right * sx + up * sy - back).normalize()
}

/// A camera's primary rays with its frame computed once, for many rays.
#[derive(Clone, Copy, Debug)]
pub struct PrimaryRays {
    frame: (Vec3, Vec3, Vec3),
    fovy_deg: f32,
    size: (u32, u32),
}

impl PrimaryRays {
    /// The unit direction of the primary ray through the image point `(px, py)`.
    pub fn direction(&self, px: f32, py: f32) -> Vec3 {
        ray_direction(self.frame, self.fovy_deg, self.size, (px, py))
    }
}

impl CameraInfo {
    /// This camera's primary rays; `None` when the camera is degenerate (see [`frame`]) or
    /// has an empty image.
    pub fn primary_rays(&self) -> Option<PrimaryRays> {
        if self.width == 0 || self.height == 0 {
            return None;
        }
        let rays = PrimaryRays {
            frame: frame(
                Vec3::from(self.position),
                Vec3::from(self.target),
                Vec3::from(self.up),
            ),
            fovy_deg: self.fovy_deg,
            size: (self.width, self.height),
        };
        let centre = rays.direction(0.5 * self.width as f32, 0.5 * self.height as f32);
        centre.is_finite().then_some(rays)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centre_ray_looks_at_the_target_and_the_corners_span_the_field_of_view() {
        let cam = CameraInfo {
            position: [0.0, 0.0, 5.0],
            target: [0.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
            fovy_deg: 90.0,
            width: 200,
            height: 100,
        };
        let rays = cam.primary_rays().unwrap();
        let c = rays.direction(100.0, 50.0);
        assert!((c - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        // Top edge at 45 degrees up; the left edge at atan(2) (aspect 2).
        let top = rays.direction(100.0, 0.0);
        assert!((top.y / -top.z - 1.0).abs() < 1e-5);
        let left = rays.direction(0.0, 50.0);
        assert!((left.x / left.z - 2.0).abs() < 1e-5);
        let bad = CameraInfo {
            up: [0.0, 0.0, 1.0],
            ..cam.clone()
        };
        assert!(bad.primary_rays().is_none());
    }
}
