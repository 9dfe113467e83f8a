//! The narrow ray-casting interface (Lehtinen et al. 2008, section 5.1).

use glam::Vec3;

/// What a ray hit. The geometric normal faces the side the ray came from
/// (`dot(geometric_normal, dir) <= 0`); the shading normal is turned to the same side of the
/// surface as the geometric one (for grazing rays it may lean slightly past the ray).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (distance, as ray directions are unit length).
    pub t: f32,
    pub position: Vec3,
    /// Geometric (face) normal, unit length, flipped to face the incoming ray.
    pub geometric_normal: Vec3,
    /// Interpolated shading normal, renormalised, on the same side as `geometric_normal`
    /// (falls back to the geometric normal where the mesh has none or it is degenerate).
    pub shading_normal: Vec3,
    /// Linear RGB diffuse albedo at the hit (material colour times texture, if any).
    pub albedo: [f32; 3],
    /// Index of the primitive (triangle index in [`crate::Mesh::triangles`], 0 for the sphere).
    pub prim_id: u32,
}

/// Ray casting against a scene. Implementations are immutable after construction and shared
/// between threads.
pub trait RayCaster: Sync + Send {
    /// Closest hit along `origin + t * dir` for `t` in `(tmin, tmax)`; `dir` must be unit length.
    fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit>;

    /// [`RayCaster::intersect`] for callers that need only the hit's geometry: the same hit,
    /// except that `albedo` may be left at zero (no material or texture lookup).
    fn intersect_geometry(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        self.intersect(origin, dir, tmin, tmax)
    }

    /// True when any surface lies strictly between `a` and `b` (end points excluded by a
    /// scale-relative offset).
    fn occluded(&self, a: Vec3, b: Vec3) -> bool;

    /// Axis-aligned bounds of the geometry: (min, max).
    fn bounds(&self) -> (Vec3, Vec3);

    /// The triangle mesh cast against (its triangle indices are [`Hit::prim_id`]); `None` for
    /// analytic geometry.
    fn triangle_mesh(&self) -> Option<&crate::Mesh> {
        None
    }

    /// A distance, relative to the scene's size and coordinate magnitude, by which secondary
    /// rays are offset from the surface they leave. Never an absolute constant in scene units.
    fn ray_epsilon(&self) -> f32 {
        let (lo, hi) = self.bounds();
        let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE);
        let magnitude = lo.abs().max(hi.abs()).max_element();
        1e-5 * extent + 4.0 * f32::EPSILON * magnitude
    }
}

/// The geometric (face) normal of the surface a point `x` with shading normal `n` lies on (a
/// basis point, which carries only its shading normal): that of the first hit of a probe from
/// `x + 4 eps n` toward `-n` within `8 eps` (a hit's geometric normal faces the probe, so `n`'s
/// side), or `n` where the probe finds no surface (a point at a surface's edge).
///
/// Where a mesh's vertex normals are smoothed across edges the shading normal leans away from
/// the face, and part of its hemisphere lies below the surface: light from there does not reach
/// `x` (the surface is in the way), which is how every estimator here treats it (a direction
/// `d` with `d . n_g <= 0` carries nothing), the reference path tracer's included.
pub fn geometric_normal_under(caster: &dyn RayCaster, x: Vec3, n: Vec3, eps: f32) -> Vec3 {
    caster
        .intersect_geometry(x + n * (4.0 * eps), -n, 0.0, 8.0 * eps)
        .map_or(n, |h| h.geometric_normal)
}
