//! Camera, light and shadow-face parameters in the layout of `shaders/common.wgsl`.

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};
use mlt_relight::light::{Cone, Light};

use crate::camera::Camera;

/// `Globals` of `common.wgsl` (std140-compatible: only vec4 and mat4 members).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct Globals {
    pub view_proj: [[f32; 4]; 4],
    pub cam_pos: [f32; 4],
    pub cam_forward: [f32; 4],
    pub cam_up: [f32; 4],
    pub viewport: [f32; 4],
    pub light_pos: [f32; 4],
    pub light_intensity: [f32; 4],
    pub light_axis: [f32; 4],
    pub light_params: [f32; 4],
    pub misc: [f32; 4],
    pub face_vp: [[[f32; 4]; 4]; 6],
}

/// `Face` of `shadow.wgsl`, padded to the 256-byte uniform offset alignment.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FaceUniform {
    pub view_proj: [[f32; 4]; 4],
    pub light: [f32; 4],
    pub pad: [f32; 44],
}

/// The shadow maps a light needs: a cube (six 90-degree faces) for a point light or a wide
/// spot, one face for a spot of at most 120 degrees.
#[derive(Clone, Debug)]
pub struct ShadowFaces {
    pub view_proj: Vec<Mat4>,
    /// Distance to which depths are normalised (the farthest corner of the scene's bounds).
    pub far: f32,
    /// Texel size per unit distance: `2 tan(fov / 2) / resolution`.
    pub texel_per_distance: f32,
}

/// Directions and up vectors of the cube faces, in the order the resolve shader picks them:
/// +X, -X, +Y, -Y, +Z, -Z.
const CUBE: [(Vec3, Vec3); 6] = [
    (Vec3::X, Vec3::Y),
    (Vec3::NEG_X, Vec3::Y),
    (Vec3::Y, Vec3::Z),
    (Vec3::NEG_Y, Vec3::Z),
    (Vec3::Z, Vec3::Y),
    (Vec3::NEG_Z, Vec3::Y),
];

impl ShadowFaces {
    pub fn new(light: &Light, bounds: (Vec3, Vec3), resolution: u32) -> ShadowFaces {
        let (lo, hi) = bounds;
        let far = corners(lo, hi)
            .iter()
            .map(|c| (*c - light.position).length())
            .fold(0.0f32, f32::max)
            * 1.01;
        let far = far.max(f32::MIN_POSITIVE * 1e6);
        let near = far * 1e-5;
        let spot = match light.cone {
            Cone::None => None,
            Cone::Hard { axis, cos_half } => Some((axis, cos_half)),
            Cone::Smooth {
                axis, cos_outer, ..
            } => Some((axis, cos_outer)),
        };
        match spot {
            Some((axis, cos_half)) if cos_half >= 0.5 => {
                // Full angle at most 120 degrees: one map with a little margin.
                let half = cos_half.clamp(-1.0, 1.0).acos() * 1.05 + 0.01;
                let fov = (2.0 * half).min(2.2);
                let up = if axis.cross(Vec3::Y).length() > 1e-3 {
                    Vec3::Y
                } else {
                    Vec3::Z
                };
                let view =
                    glam::camera::rh::view::look_at_mat4(light.position, light.position + axis, up);
                let proj = glam::camera::rh::proj::directx::perspective(fov, 1.0, near, far);
                ShadowFaces {
                    view_proj: vec![proj * view],
                    far,
                    texel_per_distance: 2.0 * (0.5 * fov).tan() / resolution as f32,
                }
            }
            _ => {
                let proj = glam::camera::rh::proj::directx::perspective(
                    std::f32::consts::FRAC_PI_2,
                    1.0,
                    near,
                    far,
                );
                let view_proj = CUBE
                    .iter()
                    .map(|(dir, up)| {
                        proj * glam::camera::rh::view::look_at_mat4(
                            light.position,
                            light.position + *dir,
                            *up,
                        )
                    })
                    .collect();
                ShadowFaces {
                    view_proj,
                    far,
                    texel_per_distance: 2.0 / resolution as f32,
                }
            }
        }
    }
}

fn corners(lo: Vec3, hi: Vec3) -> [Vec3; 8] {
    std::array::from_fn(|k| {
        Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

impl Globals {
    /// Parameters for one frame: `view_proj` is the camera's reversed-depth view-projection
    /// ([`Camera::reversed_view_proj`]) with the near plane at `near`. `shadows` is `None` to
    /// render without shadows.
    pub fn new(
        camera: &Camera,
        view_proj: &Mat4,
        near: f32,
        light: &Light,
        shadows: Option<(&ShadowFaces, u32)>,
        mode: u32,
        debug_level: u32,
    ) -> Globals {
        let (_, up, back) = camera.frame();
        let (kind, axis, cos_a, cos_inner) = match light.cone {
            Cone::None => (0.0, Vec3::ZERO, -2.0, 0.0),
            Cone::Hard { axis, cos_half } => (1.0, axis, cos_half, 0.0),
            Cone::Smooth {
                axis,
                cos_inner,
                cos_outer,
            } => (2.0, axis, cos_outer, cos_inner),
        };
        let mut face_vp = [Mat4::IDENTITY.to_cols_array_2d(); 6];
        let (faces, texel, far_shadow, res) = match shadows {
            Some((s, res)) => {
                for (k, m) in s.view_proj.iter().enumerate().take(6) {
                    face_vp[k] = m.to_cols_array_2d();
                }
                (
                    s.view_proj.len() as f32,
                    s.texel_per_distance,
                    s.far,
                    res as f32,
                )
            }
            None => (0.0, 0.0, 1.0, 1.0),
        };
        let p = light.position;
        let i = light.intensity;
        Globals {
            view_proj: view_proj.to_cols_array_2d(),
            cam_pos: [
                camera.position.x,
                camera.position.y,
                camera.position.z,
                near,
            ],
            cam_forward: (-back).extend(0.0).to_array(),
            cam_up: up.extend(0.0).to_array(),
            viewport: [
                camera.width as f32,
                camera.height as f32,
                1.0 / camera.width as f32,
                1.0 / camera.height as f32,
            ],
            light_pos: [p.x, p.y, p.z, kind],
            light_intensity: [i[0], i[1], i[2], far_shadow],
            light_axis: [axis.x, axis.y, axis.z, cos_a],
            light_params: [cos_inner, texel, faces, res],
            misc: [mode as f32, debug_level as f32, 0.0, 0.0],
            face_vp,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_direction_projects_inside_the_face_the_shader_picks() {
        let light = Light::point(Vec3::new(0.1, 0.2, 0.3), [1.0; 3]).unwrap();
        let faces = ShadowFaces::new(&light, (Vec3::splat(-2.0), Vec3::splat(2.0)), 512);
        assert_eq!(faces.view_proj.len(), 6);
        let mut rng = 12345u32;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            rng as f32 / u32::MAX as f32 * 2.0 - 1.0
        };
        for _ in 0..1000 {
            let d = Vec3::new(next(), next(), next());
            if d.length() < 1e-3 {
                continue;
            }
            let a = d.abs();
            // The same rule as `shadow_face` in resolve.wgsl.
            let face = if a.x >= a.y && a.x >= a.z {
                if d.x >= 0.0 {
                    0
                } else {
                    1
                }
            } else if a.y >= a.z {
                if d.y >= 0.0 {
                    2
                } else {
                    3
                }
            } else if d.z >= 0.0 {
                4
            } else {
                5
            };
            let clip = faces.view_proj[face] * (light.position + d).extend(1.0);
            assert!(clip.w > 0.0);
            let ndc = clip.truncate() / clip.w;
            assert!(
                ndc.x.abs() <= 1.0 + 1e-4 && ndc.y.abs() <= 1.0 + 1e-4,
                "{d} {face} {ndc}"
            );
        }
    }

    #[test]
    fn a_narrow_spot_gets_one_face_covering_its_cone() {
        let light = Light::spot(Vec3::ZERO, [1.0; 3], Vec3::NEG_Y, 90.0, false).unwrap();
        let faces = ShadowFaces::new(&light, (Vec3::splat(-1.0), Vec3::splat(1.0)), 256);
        assert_eq!(faces.view_proj.len(), 1);
        // A direction 44 degrees off the axis is inside the map.
        let a = 44f32.to_radians();
        let d = Vec3::new(a.sin(), -a.cos(), 0.0);
        let clip = faces.view_proj[0] * d.extend(1.0);
        let ndc = clip.truncate() / clip.w;
        assert!(ndc.x.abs() < 1.0 && ndc.y.abs() < 1.0);
        let wide = Light::spot(Vec3::ZERO, [1.0; 3], Vec3::NEG_Y, 150.0, false).unwrap();
        let faces = ShadowFaces::new(&wide, (Vec3::splat(-1.0), Vec3::splat(1.0)), 256);
        assert_eq!(faces.view_proj.len(), 6);
    }
}
