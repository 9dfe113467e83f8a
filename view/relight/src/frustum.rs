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
        self.planes.iter().all(|p| {
            let n = p.truncate();
            // The box corner farthest along the plane's normal.
            let v = Vec3::select(n.cmpge(Vec3::ZERO), hi, lo);
            n.dot(v) + p.w >= 0.0
        })
    }
}
