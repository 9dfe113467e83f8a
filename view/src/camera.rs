//! The pinhole camera: position, target, up, vertical field of view in degrees,
//! width x height pixels. Pixel `(px, py)` has its centre at `(px + 0.5, py + 0.5)`, row 0 at
//! the top of the image. The GPU rasteriser and the CPU reference integrator both use these
//! definitions, so their images line up pixel for pixel.
//!
//! A camera may be jittered ([`Camera::jittered`]): its projection then moves the image by a
//! sub-pixel offset, so that the rasteriser's sample at a pixel's centre sees the point
//! `(px + 0.5 + jx, py + 0.5 + jy)` of the unjittered image. Averaging the images of the
//! offsets of [`subpixel_offsets`] is a box filter over each pixel.

use glam::{Mat4, Vec2, Vec3};
use mlt_format::meta::CameraInfo;

/// A camera in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fovy_deg: f32,
    pub width: u32,
    pub height: u32,
    /// Sub-pixel offset `(jx, jy)` of the projection, in pixels, each in `[-0.5, 0.5]`; zero
    /// for the pixel centres.
    pub jitter: Vec2,
}

/// Why a camera is unusable.
#[derive(Debug, thiserror::Error)]
#[error("invalid camera: {0}")]
pub struct CameraError(pub String);

impl Camera {
    /// Checks the camera: finite vectors, a view direction, an up vector not along it, a field
    /// of view in (0, 180) degrees and a non-empty image no larger than 16384 on a side.
    pub fn new(
        position: Vec3,
        target: Vec3,
        up: Vec3,
        fovy_deg: f32,
        width: u32,
        height: u32,
    ) -> Result<Camera, CameraError> {
        if !(position.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(CameraError(format!(
                "position {position}, target {target} and up {up} must be finite"
            )));
        }
        let forward = target - position;
        if forward.length_squared() <= f32::MIN_POSITIVE {
            return Err(CameraError(format!(
                "target {target} equals the position {position}"
            )));
        }
        if forward.normalize().cross(up.normalize_or_zero()).length() < 1e-6 {
            return Err(CameraError(format!(
                "up {up} is zero or along the view direction {forward}"
            )));
        }
        if !(fovy_deg > 0.0 && fovy_deg < 180.0) {
            return Err(CameraError(format!(
                "vertical field of view {fovy_deg} degrees is not in (0, 180)"
            )));
        }
        if width == 0 || height == 0 || width > 16384 || height > 16384 {
            return Err(CameraError(format!(
                "image size {width}x{height} is not within 1..=16384 on each side"
            )));
        }
        Ok(Camera {
            position,
            target,
            up,
            fovy_deg,
            width,
            height,
            jitter: Vec2::ZERO,
        })
    }

    /// This camera with its projection moved so that pixel centres sample the image at
    /// `offset` pixels (x right, y down) from them.
    pub fn jittered(&self, offset: Vec2) -> Camera {
        Camera {
            jitter: offset,
            ..*self
        }
    }

    /// The camera stored in a baked file.
    pub fn from_info(info: &CameraInfo) -> Result<Camera, CameraError> {
        Camera::new(
            Vec3::from(info.position),
            Vec3::from(info.target),
            Vec3::from(info.up),
            info.fovy_deg,
            info.width,
            info.height,
        )
    }

    /// Unit vectors `(right, up, back)` of the camera frame (right-handed, looking down -back).
    pub fn frame(&self) -> (Vec3, Vec3, Vec3) {
        mlt_format::camera::frame(self.position, self.target, self.up)
    }

    pub fn aspect(&self) -> f32 {
        self.width as f32 / self.height as f32
    }

    /// The unit direction of the primary ray through the point `(px, py)` of the image, in
    /// pixels from the top-left corner (use `px + 0.5, py + 0.5` for a pixel's centre).
    pub fn ray_direction(&self, px: f32, py: f32) -> Vec3 {
        mlt_format::camera::ray_direction(
            self.frame(),
            self.fovy_deg,
            (self.width, self.height),
            (px, py),
        )
    }

    /// World to view transform (right-handed, camera looking down -z).
    pub fn view_matrix(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.position, self.target, self.up)
    }

    /// Perspective projection to wgpu's clip space (depth 0..1) with the given planes.
    pub fn projection_matrix(&self, near: f32, far: f32) -> Mat4 {
        glam::camera::rh::proj::directx::perspective(
            self.fovy_deg.to_radians(),
            self.aspect(),
            near,
            far,
        )
    }

    /// The view-projection with reversed depth (near plane `planes.0` at depth 1, far plane
    /// `planes.1` at 0), as the G-buffer draws with it: floats are densest near 0, so reversed
    /// depth spreads their precision evenly over distance, whatever the scene's scale.
    /// With a [`Camera::jitter`], clip space is translated by the offset (less the offset in
    /// normalised device coordinates), so that the sample at a pixel centre sees the jittered
    /// point.
    pub fn reversed_view_proj(&self, planes: (f32, f32)) -> Mat4 {
        let proj = glam::camera::rh::proj::directx::perspective(
            self.fovy_deg.to_radians(),
            self.aspect(),
            planes.1,
            planes.0,
        );
        if self.jitter == Vec2::ZERO {
            return proj * self.view_matrix();
        }
        // NDC x grows to the right and y upward; pixel y grows downward.
        let shift = Vec3::new(
            -2.0 * self.jitter.x / self.width as f32,
            2.0 * self.jitter.y / self.height as f32,
            0.0,
        );
        Mat4::from_translation(shift) * proj * self.view_matrix()
    }

    /// The frustum of [`Camera::reversed_view_proj`] with [`Camera::planes_for_bounds`] for
    /// a scene with the given bounds: what the renderer culls the flat basis to, and the
    /// relighter's view ([`mlt_relight::Relight::set_view`]).
    pub fn frustum_for_bounds(&self, lo: Vec3, hi: Vec3) -> mlt_relight::Frustum {
        let view_proj = self.reversed_view_proj(self.planes_for_bounds(lo, hi));
        mlt_relight::Frustum::from_view_proj(&view_proj)
    }

    /// Near and far planes that enclose a scene with the given bounds: far beyond its farthest
    /// corner, near a fixed fraction (1e-4) of far, so that the planes scale with the scene.
    pub fn planes_for_bounds(&self, lo: Vec3, hi: Vec3) -> (f32, f32) {
        let centre = 0.5 * (lo + hi);
        let far = ((self.position - centre).length() + 0.5 * (hi - lo).length()) * 1.01;
        let far = far.max(f32::MIN_POSITIVE * 1e8);
        (far * 1e-4, far)
    }
}

/// The `n` sub-pixel offsets of a box-filtered image (pixels, each coordinate in
/// `[-0.5, 0.5)`): one point in each cell of a `rows x cols` grid over the pixel (`rows` the
/// largest divisor of `n` not above its square root), placed in its cell by a fixed hash of its
/// index, so that the offsets are stratified and the same on every run. One sample is the
/// pixel centre (no offset).
pub fn subpixel_offsets(n: u32) -> Vec<Vec2> {
    if n <= 1 {
        return vec![Vec2::ZERO];
    }
    let rows = (1..=n)
        .filter(|&r| n.is_multiple_of(r) && r * r <= n)
        .max()
        .unwrap_or(1);
    let cols = n / rows;
    (0..n)
        .map(|k| {
            let (col, row) = (k % cols, k / cols);
            let (u, v) = unit_pair(k);
            Vec2::new(
                (col as f32 + u) / cols as f32 - 0.5,
                (row as f32 + v) / rows as f32 - 0.5,
            )
        })
        .collect()
}

/// Two numbers in `[0, 1)` from a fixed hash (splitmix64) of `k`.
fn unit_pair(k: u32) -> (f32, f32) {
    let mut z = (k as u64)
        .wrapping_add(1)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    // The top 24 bits of each 32-bit half: exact in f32, below 1.
    let unit = |bits: u64| ((bits & 0xFFFF_FFFF) >> 8) as f32 / (1u64 << 24) as f32;
    (unit(z), unit(z >> 32))
}

/// Parses `x,y,z` (three finite numbers) from the command line.
pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<f32>()
                .map_err(|_| format!("'{c}' is not a number"))
        })
        .collect::<Result<_, _>>()?;
    if v.len() != 3 || v.iter().any(|c| !c.is_finite()) {
        return Err(format!("'{s}' is not three finite numbers x,y,z"));
    }
    Ok(Vec3::new(v[0], v[1], v[2]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::new(
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::ZERO,
            Vec3::Y,
            90.0,
            200,
            100,
        )
        .unwrap()
    }

    #[test]
    fn centre_ray_looks_at_the_target_and_corners_span_the_field_of_view() {
        let c = cam();
        let d = c.ray_direction(100.0, 50.0);
        assert!((d - Vec3::NEG_Z).length() < 1e-6);
        // Top edge at 45 degrees up (fovy 90), left edge at atan(2) (aspect 2).
        let top = c.ray_direction(100.0, 0.0);
        assert!((top.y.atan2(-top.z).to_degrees() - 45.0).abs() < 1e-4);
        let left = c.ray_direction(0.0, 50.0);
        assert!((left.x.atan2(-left.z) + 2f32.atan()).abs() < 1e-5);
    }

    #[test]
    fn rays_agree_with_the_projection_matrix() {
        let c = cam();
        let vp = c.projection_matrix(0.1, 100.0) * c.view_matrix();
        for (px, py) in [(10.5, 20.5), (150.25, 90.75), (199.5, 0.5)] {
            let p = c.position + c.ray_direction(px, py) * 3.0;
            let clip = vp * p.extend(1.0);
            let ndc = clip.truncate() / clip.w;
            let sx = (ndc.x + 1.0) * 0.5 * c.width as f32;
            let sy = (1.0 - ndc.y) * 0.5 * c.height as f32;
            assert!(
                (sx - px).abs() < 1e-3 && (sy - py).abs() < 1e-3,
                "{sx},{sy} vs {px},{py}"
            );
        }
    }

    #[test]
    fn reversed_depth_puts_the_near_plane_at_one_and_the_far_plane_at_zero() {
        let c = cam();
        let (near, far) = (0.1, 100.0);
        let reversed = c.reversed_view_proj((near, far));
        let forward = c.projection_matrix(near, far) * c.view_matrix();
        let ndc = |m: Mat4, p: Vec3| {
            let clip = m * p.extend(1.0);
            clip.truncate() / clip.w
        };
        let dir = c.ray_direction(30.5, 70.5);
        let depth_along = |d: f32| ndc(reversed, c.position + dir * d);
        // Distances along the ray that land on the planes (the ray is not along the axis).
        let axial = dir.dot((c.target - c.position).normalize());
        assert!((depth_along(near / axial).z - 1.0).abs() < 1e-4);
        assert!(depth_along(far / axial).z.abs() < 1e-4);
        let p = c.position + dir * 7.0;
        let (r, f) = (ndc(reversed, p), ndc(forward, p));
        assert!((r.x - f.x).abs() < 1e-5 && (r.y - f.y).abs() < 1e-5);
        assert!(r.z > depth_along(8.0).z, "depth decreases with distance");
    }

    #[test]
    fn a_jittered_projection_moves_the_image_by_the_offset() {
        let c = cam();
        let j = c.jittered(Vec2::new(0.25, -0.375));
        let (m, mj) = (
            c.reversed_view_proj((0.1, 100.0)),
            j.reversed_view_proj((0.1, 100.0)),
        );
        let screen = |m: Mat4, p: Vec3| {
            let clip = m * p.extend(1.0);
            let ndc = clip.truncate() / clip.w;
            Vec2::new(
                (ndc.x + 1.0) * 0.5 * c.width as f32,
                (1.0 - ndc.y) * 0.5 * c.height as f32,
            )
        };
        // The point seen at (px + 0.5 + jx, py + 0.5 + jy) without jitter lands on the
        // centre of pixel (px, py) with it.
        let p = c.position + c.ray_direction(40.5 + 0.25, 60.5 - 0.375) * 4.0;
        assert!((screen(m, p) - Vec2::new(40.75, 60.125)).length() < 1e-3);
        assert!((screen(mj, p) - Vec2::new(40.5, 60.5)).length() < 1e-3);
        assert_eq!(c.jittered(Vec2::ZERO).reversed_view_proj((0.1, 100.0)), m);
    }

    #[test]
    fn subpixel_offsets_are_stratified_and_fixed() {
        assert_eq!(subpixel_offsets(1), vec![Vec2::ZERO]);
        for (n, rows, cols) in [(4u32, 2u32, 2u32), (16, 4, 4), (6, 2, 3), (7, 1, 7)] {
            let o = subpixel_offsets(n);
            assert_eq!(o, subpixel_offsets(n));
            // Offset k lies in cell (k % cols, k / cols) (up to rounding at the cell's sides).
            for (k, p) in o.iter().enumerate() {
                assert!(
                    p.x >= -0.5 && p.x <= 0.5 && p.y >= -0.5 && p.y <= 0.5,
                    "{p}"
                );
                let (col, row) = ((k as u32 % cols) as f32, (k as u32 / cols) as f32);
                let cx = (p.x + 0.5) * cols as f32 - col;
                let cy = (p.y + 0.5) * rows as f32 - row;
                assert!(
                    (-1e-5..=1.0 + 1e-5).contains(&cx) && (-1e-5..=1.0 + 1e-5).contains(&cy),
                    "n = {n}, offset {k} at {p} is not in its cell ({col}, {row})"
                );
            }
        }
        // The mean offset of a stratified pattern is near the pixel centre.
        let mean = subpixel_offsets(16).iter().copied().sum::<Vec2>() / 16.0;
        assert!(mean.length() < 0.1, "{mean}");
    }

    #[test]
    fn bad_cameras_are_refused() {
        let p = Vec3::new(0.0, 0.0, 5.0);
        assert!(Camera::new(p, p, Vec3::Y, 60.0, 8, 8).is_err());
        assert!(Camera::new(p, Vec3::ZERO, Vec3::Z, 60.0, 8, 8).is_err());
        assert!(Camera::new(p, Vec3::ZERO, Vec3::Y, 0.0, 8, 8).is_err());
        assert!(Camera::new(p, Vec3::ZERO, Vec3::Y, 60.0, 0, 8).is_err());
        assert!(Camera::new(Vec3::NAN, Vec3::ZERO, Vec3::Y, 60.0, 8, 8).is_err());
    }
}
