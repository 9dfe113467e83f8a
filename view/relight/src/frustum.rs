//! A view frustum as six planes, and the sphere and box tests that culling needs: the
//! renderer culls the flat basis functions it splats with it, and the relighter flattens only
//! the flat points whose rows the view needs ([`crate::view_cull`]).

use glam::{Mat4, Vec3, Vec4};

/// The six planes of a view-projection's frustum, `dot(p, x) + w >= 0` inside, normalised.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    planes: [Vec4; 6],
}

impl Frustum {
    /// Planes of wgpu's clip volume (`-w <= x, y <= w`, `0 <= z <= w`).
    pub fn from_view_proj(m: &Mat4) -> Frustum {
        let r = [m.row(0), m.row(1), m.row(2), m.row(3)];
        let planes = [
            r[3] + r[0],
            r[3] - r[0],
            r[3] + r[1],
            r[3] - r[1],
            r[2],
            r[3] - r[2],
        ]
        .map(|p| {
            let len = p.truncate().length();
            if len > 0.0 {
                p / len
            } else {
                p
            }
        });
        Frustum { planes }
    }

    /// True unless the sphere lies entirely outside one plane.
    pub fn meets_sphere(&self, c: Vec3, r: f32) -> bool {
        self.planes.iter().all(|p| p.truncate().dot(c) + p.w >= -r)
    }

    /// True unless the box lies entirely outside one plane.
    pub fn meets_box(&self, lo: Vec3, hi: Vec3) -> bool {
        self.corners_inside(lo, hi, true)
    }

    /// Whether the axis-aligned box `lo..hi` lies wholly inside the frustum (on the inner side
    /// of every plane), so that everything in it meets it.
    pub fn contains_box(&self, lo: Vec3, hi: Vec3) -> bool {
        self.corners_inside(lo, hi, false)
    }

    /// Whether, for every plane, the corner of the box `lo..hi` farthest along its normal
    /// (`farthest`) or nearest lies on its inner side.
    fn corners_inside(&self, lo: Vec3, hi: Vec3, farthest: bool) -> bool {
        let (ahead, behind) = if farthest { (hi, lo) } else { (lo, hi) };
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let v = Vec3::select(n.cmpge(Vec3::ZERO), ahead, behind);
            n.dot(v) + p.w >= 0.0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at the origin looking down -z, 90 degrees, square, planes at 0.1 and 10.
    fn frustum() -> Frustum {
        let view = glam::camera::rh::view::look_at_mat4(Vec3::ZERO, -Vec3::Z, Vec3::Y);
        let proj = glam::camera::rh::proj::directx::perspective(
            std::f32::consts::FRAC_PI_2,
            1.0,
            0.1,
            10.0,
        );
        Frustum::from_view_proj(&(proj * view))
    }

    #[test]
    fn boxes_inside_across_and_outside() {
        let f = frustum();
        let h = Vec3::splat(0.2);
        // Around a point 5 ahead: inside (the side planes are 5 away there).
        let c = Vec3::new(0.0, 0.0, -5.0);
        assert!(f.contains_box(c - h, c + h) && f.meets_box(c - h, c + h));
        // Across the right plane (x = -z at 45 degrees): meets, not inside.
        let c = Vec3::new(5.0, 0.0, -5.0);
        assert!(!f.contains_box(c - h, c + h) && f.meets_box(c - h, c + h));
        // Behind the camera: neither.
        let c = Vec3::new(0.0, 0.0, 5.0);
        assert!(!f.contains_box(c - h, c + h) && !f.meets_box(c - h, c + h));
        // Across the far plane: meets, not inside.
        let c = Vec3::new(0.0, 0.0, -10.0);
        assert!(!f.contains_box(c - h, c + h) && f.meets_box(c - h, c + h));
        // Every point of a box inside meets the frustum, as a sphere of any radius.
        let (lo, hi) = (Vec3::new(-1.0, -1.0, -4.0), Vec3::new(1.0, 1.5, -3.0));
        assert!(f.contains_box(lo, hi));
        for i in 0..=4 {
            for j in 0..=4 {
                for k in 0..=4 {
                    let t = Vec3::new(i as f32, j as f32, k as f32) / 4.0;
                    assert!(f.meets_sphere(lo + t * (hi - lo), 0.0));
                }
            }
        }
    }
}
