//! The mesh caster against the analytic sphere, and determinism of BVH results.

mod common;

use glam::Vec3;
use mlt_scenes::builtin::icosphere;
use mlt_scenes::{MeshCaster, RayCaster, SphereCaster};

#[test]
fn sphere_mesh_agrees_with_the_analytic_sphere() {
    let radius = 2.0;
    let centre = Vec3::ZERO;
    let mesh = MeshCaster::new(icosphere(radius, 4, [0.5; 3]));
    let sphere = SphereCaster::new(centre, radius, [0.5; 3]);
    // The chord sag of a level-4 icosphere is below 1.5e-3 of the radius (about 1.1e-3);
    // along oblique rays the distance error is the sag over the cosine of incidence.
    let sag = 1.5e-3 * radius;
    let tol = 3.0 * sag;
    for d in common::directions(2000, 11) {
        // From inside (the centre and off-centre).
        for origin in [centre, Vec3::new(0.3, -0.5, 0.2)] {
            let a = sphere
                .intersect(origin, d, 0.0, f32::INFINITY)
                .expect("analytic hit");
            let m = mesh
                .intersect(origin, d, 0.0, f32::INFINITY)
                .expect("mesh hit");
            assert!((a.t - m.t).abs() < tol, "t {} vs {}", a.t, m.t);
            assert!(m.t <= a.t + 1e-5, "the inscribed mesh is hit first");
            let r = (m.position - centre).length();
            assert!(r > radius - sag && r < radius + 1e-5, "hit at radius {r}");
            assert!(m.geometric_normal.dot(d) <= 0.0);
            assert!(m.shading_normal.dot(a.shading_normal) > 0.9999);
        }
        // From outside, aimed at the centre.
        let origin = -d * 10.0;
        let a = sphere
            .intersect(origin, d, 0.0, f32::INFINITY)
            .expect("analytic hit");
        let m = mesh
            .intersect(origin, d, 0.0, f32::INFINITY)
            .expect("mesh hit");
        assert!((a.t - m.t).abs() < tol);
        assert!(
            m.shading_normal.dot(-d) > 0.999,
            "outside hits face outward"
        );
    }
    // Points on the inside never occlude each other, for both casters.
    for d in common::directions(200, 5) {
        let p = d * radius * 0.99;
        let q = -d * radius * 0.5 + Vec3::new(0.1, 0.0, 0.0);
        assert!(!mesh.occluded(p, q));
        assert!(!sphere.occluded(p, q));
        assert!(mesh.occluded(p, d * radius * 3.0));
        assert!(sphere.occluded(p, d * radius * 3.0));
    }
}

#[test]
fn hits_are_deterministic_across_builds_and_threads() {
    let mesh = icosphere(1.0, 3, [0.5; 3]);
    let a = MeshCaster::new(mesh.clone());
    let b = MeshCaster::new(mesh);
    let dirs = common::directions(500, 1);
    let origin = Vec3::new(0.1, 0.2, -0.3);
    let serial: Vec<_> = dirs
        .iter()
        .map(|d| a.intersect(origin, *d, 0.0, f32::INFINITY))
        .collect();
    use rayon::prelude::*;
    let parallel: Vec<_> = dirs
        .par_iter()
        .map(|d| b.intersect(origin, *d, 0.0, f32::INFINITY))
        .collect();
    assert_eq!(serial, parallel);
}

#[test]
fn hits_from_the_surface_do_not_self_intersect() {
    let caster = MeshCaster::new(icosphere(100.0, 3, [0.5; 3]));
    let eps = caster.ray_epsilon();
    for d in common::directions(300, 9) {
        let h = caster
            .intersect(Vec3::ZERO, d, 0.0, f32::INFINITY)
            .expect("hit");
        // Leave the surface along a direction into the sphere's interior hemisphere.
        let out = (h.shading_normal + 0.5 * d.any_orthonormal_vector()).normalize();
        let next = caster
            .intersect(h.position, out, eps, f32::INFINITY)
            .expect("hits the far side");
        assert!(next.t > 1.0, "self-intersection at t = {}", next.t);
    }
}
