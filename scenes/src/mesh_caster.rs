//! Ray casting over triangle meshes with an obvhs compressed-wide BVH (CWBVH).
//!
//! The BVH is built single-threaded (obvhs without its `parallel` feature), so the tree and
//! every result are the same whatever the thread count.
//!
//! The BVH sees the mesh scaled by a power of two that brings its extent near 1024
//! ([`BVH_EXTENT_LOG2`]; exact in floating point: only exponents change), and rays are scaled
//! alike, so results do not depend on the scene's units. obvhs' node test clamps every entry
//! distance to at least an absolute `1e-4` (`cwbvh/node.rs`, `EPSILON`): a surface closer than
//! that to a ray's origin is invisible where its node's box is thin along the ray (a wall, a
//! floor). At 1e-4 of the
//! Cornell box's size every ray missed; at an extent near 1 the blind zone was 1e-4 of the
//! scene (ten ray epsilons: rays from a floor passed through the foot of a wall, rays leaving
//! below a leaning shading normal passed through their own surface). At an extent near 1024
//! it is 1e-7 of the scene, a hundredth of the ray epsilon, while f32 keeps the same relative
//! precision (a power of two changes only exponents).

use std::time::{Duration, Instant};

use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::mesh::Mesh;
use crate::raycast::{Hit, RayCaster};

/// The power of two the scene's extent is scaled to in the BVH's coordinates (module docs).
pub const BVH_EXTENT_LOG2: i32 = 10;

/// A [`RayCaster`] over a [`Mesh`].
pub struct MeshCaster {
    mesh: Mesh,
    bvh: CwBvh,
    /// Triangles in BVH primitive order (so traversal indexes them directly).
    tris: Vec<Triangle>,
    /// BVH primitive order → triangle index in the mesh.
    tri_ids: Vec<u32>,
    bounds: (Vec3, Vec3),
    /// The power of two the BVH's coordinates are scaled by.
    scale: f32,
    build_time: Duration,
}

impl MeshCaster {
    /// Builds the BVH over `mesh` (expected to satisfy [`Mesh::validate`]; triangles with
    /// out-of-range indices are left out rather than panicking).
    pub fn new(mesh: Mesh) -> MeshCaster {
        let start = Instant::now();
        let bounds = mesh.bounds();
        let extent = (bounds.1 - bounds.0).max_element();
        // An empty or non-finite extent, or one beyond f32's exponents (under about 1e-35),
        // keeps the scene's own units.
        let scale = Some(extent)
            .filter(|e| e.is_finite() && *e > 0.0)
            .map(|e| 2f32.powi(BVH_EXTENT_LOG2 - e.log2().round() as i32))
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(1.0);
        let mut ids = Vec::with_capacity(mesh.triangles.len());
        let mut tris = Vec::with_capacity(mesh.triangles.len());
        for (i, t) in mesh.triangles.iter().enumerate() {
            let p = |k: u32| mesh.positions.get(k as usize).copied();
            if let (Some(a), Some(b), Some(c)) = (p(t[0]), p(t[1]), p(t[2])) {
                ids.push(i as u32);
                tris.push(Triangle {
                    v0: (a * scale).into(),
                    v1: (b * scale).into(),
                    v2: (c * scale).into(),
                });
            }
        }
        let bvh = if tris.is_empty() {
            CwBvh::default()
        } else {
            obvhs::cwbvh::builder::build_cwbvh_from_tris(
                &tris,
                BvhBuildParams::medium_build(),
                &mut Duration::default(),
            )
        };
        let order: Vec<usize> = bvh.primitive_indices.iter().map(|&i| i as usize).collect();
        let bvh_tris = order.iter().map(|&i| tris[i]).collect();
        let tri_ids = order.iter().map(|&i| ids[i]).collect();
        MeshCaster {
            mesh,
            bvh,
            tris: bvh_tris,
            tri_ids,
            bounds,
            scale,
            build_time: start.elapsed(),
        }
    }

    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// Wall-clock time of the BVH build (including preparing its input).
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    fn ray(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Ray> {
        let ok = origin.is_finite() && dir.is_finite() && dir != Vec3::ZERO && tmin < tmax;
        // obvhs picks the slab order by `dir < 0` but inverts with the sign of the zero, so
        // a -0.0 component (e.g. from `-Vec3::Y`) makes every node test miss. Use +0.0.
        let dir = Vec3::from_array(dir.to_array().map(|c| if c == 0.0 { 0.0 } else { c }));
        ok.then(|| Ray::new(Vec3A::from(origin), Vec3A::from(dir), tmin, tmax))
    }
}

/// Barycentric weights `(u, v)` of the second and third corner where the ray crosses the
/// plane of triangle `[a, b, c]` (Möller–Trumbore), clamped into the triangle.
fn barycentrics(a: Vec3, b: Vec3, c: Vec3, origin: Vec3, dir: Vec3) -> (f32, f32) {
    let e1 = b - a;
    let e2 = c - a;
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return (1.0 / 3.0, 1.0 / 3.0);
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(p) * inv;
    let v = dir.dot(s.cross(e1)) * inv;
    if !(u.is_finite() && v.is_finite()) {
        return (1.0 / 3.0, 1.0 / 3.0);
    }
    let u = u.clamp(0.0, 1.0);
    let v = v.clamp(0.0, 1.0 - u);
    (u, v)
}

impl MeshCaster {
    /// The closest hit, with the albedo looked up only when `albedo` is set.
    fn closest_hit(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
        albedo: bool,
    ) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let k = self.scale;
        let ray = Self::ray(origin * k, dir, tmin * k, tmax * k)?;
        let mut hit = RayHit::none();
        let tris = &self.tris;
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| tris[id].intersect(r))
        {
            return None;
        }
        let prim_id = *self.tri_ids.get(hit.primitive_id as usize)?;
        let [a, b, c] = self.mesh.corners(prim_id);
        let (u, v) = barycentrics(a, b, c, origin, dir);
        let position = a * (1.0 - u - v) + b * u + c * v;
        let mut geometric_normal = (b - a).cross(c - a).normalize_or_zero();
        if geometric_normal == Vec3::ZERO || !geometric_normal.is_finite() {
            geometric_normal = -dir;
        }
        if geometric_normal.dot(dir) > 0.0 {
            geometric_normal = -geometric_normal;
        }
        let shading_normal = match self.mesh.shading_normal(prim_id, (u, v)) {
            Some(s) if s.dot(geometric_normal) < 0.0 => -s,
            Some(s) => s,
            None => geometric_normal,
        };
        Some(Hit {
            t: hit.t / k,
            position,
            geometric_normal,
            shading_normal,
            albedo: if albedo {
                self.mesh.albedo_at(prim_id, (u, v))
            } else {
                [0.0; 3]
            },
            prim_id,
        })
    }
}

impl RayCaster for MeshCaster {
    fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        self.closest_hit(origin, dir, tmin, tmax, true)
    }

    fn intersect_geometry(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        self.closest_hit(origin, dir, tmin, tmax, false)
    }

    fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let d = b - a;
        let len = d.length();
        let eps = self.ray_epsilon();
        if !len.is_finite() || len <= 2.0 * eps {
            return false;
        }
        let k = self.scale;
        let Some(ray) = Self::ray(a * k, d / len, eps * k, (len - eps) * k) else {
            return false;
        };
        let tris = &self.tris;
        !self
            .bvh
            .ray_traverse_miss(ray, |r, id| tris[id].intersect(r))
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    fn triangle_mesh(&self) -> Option<&Mesh> {
        Some(&self.mesh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Material;

    /// A unit quad in the y = 0 plane, wound to face +Y, with optional vertex normals.
    fn quad(normals: Vec<Vec3>) -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(-1.0, 0.0, -1.0),
                Vec3::new(-1.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, -1.0),
            ],
            normals,
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            triangle_material: vec![0, 0],
            materials: vec![Material::plain("m", [0.3, 0.6, 0.9])],
            ..Default::default()
        }
    }

    #[test]
    fn closest_hit_and_normals_face_the_ray() {
        let caster = MeshCaster::new(quad(Vec::new()));
        for (y, dir) in [(2.0, -Vec3::Y), (-2.0, Vec3::Y)] {
            let h = caster
                .intersect(Vec3::new(0.2, y, 0.3), dir, 0.0, f32::INFINITY)
                .expect("hits the quad");
            assert!((h.t - 2.0).abs() < 1e-6);
            assert!((h.position - Vec3::new(0.2, 0.0, 0.3)).length() < 1e-6);
            assert!(h.geometric_normal.dot(dir) < 0.0);
            assert_eq!(h.shading_normal, h.geometric_normal);
            assert_eq!(h.albedo, [0.3, 0.6, 0.9]);
            // The geometry-only query: the same hit without the albedo lookup.
            let g = caster
                .intersect_geometry(Vec3::new(0.2, y, 0.3), dir, 0.0, f32::INFINITY)
                .expect("hits the quad");
            assert_eq!(
                Hit {
                    albedo: h.albedo,
                    ..g
                },
                h
            );
            assert_eq!(g.albedo, [0.0; 3]);
        }
        assert!(caster
            .intersect(Vec3::new(0.2, 2.0, 0.3), -Vec3::Y, 0.0, 1.5)
            .is_none());
        assert!(caster
            .intersect(Vec3::new(3.0, 2.0, 0.3), -Vec3::Y, 0.0, f32::INFINITY)
            .is_none());
    }

    #[test]
    fn flipped_vertex_normals_are_turned_to_the_geometric_side() {
        // Sponza-like: vertex normals point against the winding, and are tilted.
        let n = Vec3::new(0.3, -1.0, 0.0).normalize();
        let caster = MeshCaster::new(quad(vec![n; 4]));
        for (y, dir) in [(2.0, -Vec3::Y), (-2.0, Vec3::Y)] {
            let h = caster
                .intersect(Vec3::new(0.2, y, 0.3), dir, 0.0, f32::INFINITY)
                .expect("hits");
            assert!(h.geometric_normal.dot(dir) < 0.0);
            assert!(
                h.shading_normal.dot(h.geometric_normal) > 0.0,
                "from y={y}: shading {} geometric {}",
                h.shading_normal,
                h.geometric_normal
            );
            assert!((h.shading_normal.length() - 1.0).abs() < 1e-5);
            // Still the (possibly flipped) tilted normal, not the geometric fallback.
            assert!((h.shading_normal.x.abs() - n.x.abs()).abs() < 1e-5);
        }
    }

    #[test]
    fn surfaces_a_few_ray_epsilons_from_the_origin_are_hit() {
        // A floor and a wall meeting at x = 1 (a contact). obvhs' node test sees nothing
        // within 1e-4 of a ray's origin in the BVH's coordinates; scaled to an extent near
        // 1024 that is far below the ray epsilon, so rays from just above the floor find it
        // below them and rays from next to the wall's foot find the wall.
        let mut mesh = quad(Vec::new());
        let base = mesh.positions.len() as u32;
        for (y, z) in [(0.0, -1.0), (0.0, 1.0), (2.0, 1.0), (2.0, -1.0)] {
            mesh.positions.push(Vec3::new(1.0, y, z));
        }
        mesh.triangles.push([base, base + 1, base + 2]);
        mesh.triangles.push([base, base + 2, base + 3]);
        mesh.triangle_material.extend([0, 0]);
        let caster = MeshCaster::new(mesh);
        let eps = caster.ray_epsilon();
        for k in [1.5f32, 2.0, 4.0, 10.0, 32.0] {
            let d = k * eps;
            let down = caster.intersect(Vec3::new(0.3, d, 0.2), -Vec3::Y, 0.0, 1.0);
            let t = down.map(|h| h.t);
            assert!(t.is_some_and(|t| (t - d).abs() < 0.1 * d), "{k}: {t:?}");
            let side = caster.intersect(Vec3::new(1.0 - d, eps, 0.2), Vec3::X, 0.0, 1.0);
            let t = side.map(|h| h.t);
            assert!(t.is_some_and(|t| (t - d).abs() < 0.1 * d), "{k}: {t:?}");
            assert!(caster.occluded(Vec3::new(1.0 - d, eps, 0.2), Vec3::new(1.5, eps, 0.2)));
        }
    }

    #[test]
    fn occlusion_across_a_quad() {
        let caster = MeshCaster::new(quad(Vec::new()));
        let above = Vec3::new(0.1, 1.0, 0.1);
        let below = Vec3::new(-0.2, -1.0, 0.3);
        assert!(caster.occluded(above, below));
        assert!(caster.occluded(below, above));
        assert!(!caster.occluded(above, Vec3::new(0.5, 2.0, -0.5)));
        // A point on the quad sees a point above it (end point excluded).
        assert!(!caster.occluded(Vec3::new(0.1, 0.0, 0.1), above));
        // Passing beside the quad.
        assert!(!caster.occluded(Vec3::new(2.0, 1.0, 0.0), Vec3::new(2.0, -1.0, 0.0)));
    }

    #[test]
    fn barycentrics_interpolate_the_hit() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Z);
        let (u, v) = barycentrics(a, b, c, Vec3::new(0.25, 1.0, 0.5), -Vec3::Y);
        assert!((u - 0.25).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
    }
}
