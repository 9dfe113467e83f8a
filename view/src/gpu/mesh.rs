//! The scene's geometry as GPU vertex data: triangles expanded to three vertices each
//! (position, shading normal, face normal, texture coordinates), sorted by material so that
//! each material is one draw. The analytic sphere is tessellated finely enough that its
//! rasterised positions stay within 2e-4 of its radius.

use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};
use mlt_scenes::{Geometry, Scene, Texture};

/// One vertex as the G-buffer pass reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    /// Unit shading normal, or zero where the mesh has none (the face normal is used).
    pub normal: [f32; 3],
    /// Unit geometric normal of the triangle.
    pub face_normal: [f32; 3],
    pub uv: [f32; 2],
}

/// A material's draw: a range of vertices, an albedo factor and an optional texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Draw {
    pub first_vertex: u32,
    pub vertex_count: u32,
    pub albedo: [f32; 3],
    /// Index into [`GpuMesh::textures`].
    pub texture: Option<u32>,
}

/// Vertex data of a whole scene.
#[derive(Clone, Debug)]
pub struct GpuMesh {
    pub vertices: Vec<Vertex>,
    pub draws: Vec<Draw>,
    pub textures: Vec<Texture>,
    pub bounds: (Vec3, Vec3),
}

/// Segments around the sphere's equator of the tessellated analytic sphere.
const SPHERE_SEGMENTS: u32 = 256;

impl GpuMesh {
    pub fn from_scene(scene: &Scene) -> GpuMesh {
        match &scene.geometry {
            Geometry::Mesh(m) => {
                let mut order: Vec<u32> = (0..m.triangles.len() as u32).collect();
                // Stable: triangles keep their order within a material.
                order.sort_by_key(|&t| m.triangle_material[t as usize]);
                let mut vertices = Vec::with_capacity(order.len() * 3);
                let mut draws: Vec<Draw> = Vec::new();
                let mut current = u32::MAX;
                for &t in &order {
                    let mat = m.triangle_material[t as usize];
                    if mat != current {
                        let material = &m.materials[mat as usize];
                        draws.push(Draw {
                            first_vertex: vertices.len() as u32,
                            vertex_count: 0,
                            albedo: material.albedo,
                            texture: material.texture,
                        });
                        current = mat;
                    }
                    let tri = m.triangles[t as usize];
                    let [a, b, c] = m.corners(t);
                    let face = (b - a).cross(c - a).normalize_or_zero();
                    let normals: [Vec3; 3] = if m.normals.is_empty() {
                        [Vec3::ZERO; 3]
                    } else {
                        tri.map(|i| m.normals[i as usize])
                    };
                    // A vertex without a normal makes the whole triangle use its face normal,
                    // as the ray caster's shading normal does.
                    let flat = normals.contains(&Vec3::ZERO);
                    for (k, &i) in tri.iter().enumerate() {
                        let uv = if m.uvs.is_empty() {
                            Vec2::ZERO
                        } else {
                            m.uvs[i as usize]
                        };
                        vertices.push(Vertex {
                            position: m.positions[i as usize].to_array(),
                            normal: if flat {
                                [0.0; 3]
                            } else {
                                normals[k].to_array()
                            },
                            face_normal: face.to_array(),
                            uv: uv.to_array(),
                        });
                    }
                    if let Some(d) = draws.last_mut() {
                        d.vertex_count += 3;
                    }
                }
                GpuMesh {
                    vertices,
                    draws,
                    textures: m.textures.clone(),
                    bounds: m.bounds(),
                }
            }
            Geometry::Sphere {
                center,
                radius,
                albedo,
            } => {
                let vertices = tessellate_sphere(*center, *radius, SPHERE_SEGMENTS);
                let count = vertices.len() as u32;
                GpuMesh {
                    vertices,
                    draws: vec![Draw {
                        first_vertex: 0,
                        vertex_count: count,
                        albedo: *albedo,
                        texture: None,
                    }],
                    textures: Vec::new(),
                    bounds: (
                        *center - Vec3::splat(*radius),
                        *center + Vec3::splat(*radius),
                    ),
                }
            }
        }
    }
}

/// A latitude-longitude sphere with `segments` around and `segments / 2` from pole to pole;
/// vertices lie on the sphere, normals are the exact radial ones.
fn tessellate_sphere(center: Vec3, radius: f32, segments: u32) -> Vec<Vertex> {
    let rings = (segments / 2).max(2);
    let point = |i: u32, k: u32| {
        let theta = std::f32::consts::PI * k as f32 / rings as f32;
        let phi = std::f32::consts::TAU * i as f32 / segments as f32;
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.cos(),
            theta.sin() * phi.sin(),
        )
    };
    let mut out = Vec::with_capacity((segments * rings * 6) as usize);
    for k in 0..rings {
        for i in 0..segments {
            let quad = [
                point(i, k),
                point(i + 1, k),
                point(i + 1, k + 1),
                point(i, k + 1),
            ];
            for tri in [[0, 1, 2], [0, 2, 3]] {
                let [a, b, c] = tri.map(|q| quad[q]);
                let face = (b - a).cross(c - a);
                if face.length_squared() < 1e-20 {
                    continue; // the degenerate triangles at the poles
                }
                let face = face.normalize();
                for n in [a, b, c] {
                    out.push(Vertex {
                        position: (center + n * radius).to_array(),
                        normal: n.to_array(),
                        face_normal: face.to_array(),
                        uv: [0.0; 2],
                    });
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cornell_draws_cover_every_triangle_once_by_material() {
        let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
        let Geometry::Mesh(m) = &scene.geometry else {
            panic!("cornell is a mesh")
        };
        let gm = GpuMesh::from_scene(&scene);
        assert_eq!(gm.vertices.len(), 3 * m.triangles.len());
        let total: u32 = gm.draws.iter().map(|d| d.vertex_count).sum();
        assert_eq!(total as usize, gm.vertices.len());
        let mut next = 0;
        for d in &gm.draws {
            assert_eq!(d.first_vertex, next);
            next += d.vertex_count;
        }
        for v in &gm.vertices {
            let f = Vec3::from(v.face_normal);
            assert!((f.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn sphere_tessellation_stays_on_the_sphere() {
        let c = Vec3::new(1.0, 2.0, 3.0);
        let v = tessellate_sphere(c, 2.0, SPHERE_SEGMENTS);
        for t in v.chunks(3) {
            let centroid = t
                .iter()
                .map(|x| Vec3::from(x.position))
                .fold(Vec3::ZERO, |a, b| a + b)
                / 3.0;
            // A triangle's interior is within 2e-4 of the radius.
            assert!(((centroid - c).length() / 2.0 - 1.0).abs() < 2e-4);
        }
    }
}
