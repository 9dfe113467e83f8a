//! Every OBJ of the third-party scenes (see `mlt-test-support`) loads with the expected
//! triangle counts, and the manifests in scenes/ load and place their viewpoints inside the
//! geometry.

mod common;

use std::path::PathBuf;

use glam::Vec3;
use mlt_scenes::obj::load_obj;
use mlt_scenes::{load_scene, Geometry, MeshCaster, RayCaster};

#[test]
fn cornell_obj_loads_with_materials() {
    let path = common::shared_scene("cornell_box/CornellBox-Original.obj");
    let (mesh, warnings, hash) = load_obj(&path, 1.0).expect("loads");
    // 18 quads = 36 triangles; the 4 duplicates (bottom faces) are valid triangles.
    assert_eq!(mesh.triangles.len(), 36);
    assert_eq!(mesh.degenerate_dropped, 0);
    assert!(mesh.normals.is_empty() && mesh.uvs.is_empty());
    let names: Vec<&str> = mesh.materials.iter().map(|m| m.name.as_str()).collect();
    for n in [
        "leftWall",
        "rightWall",
        "floor",
        "light",
        "shortBox",
        "tallBox",
    ] {
        assert!(names.contains(&n), "{names:?}");
    }
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("'light'") && w.contains("emission ignored")),
        "{warnings:?}"
    );
    let (lo, hi) = mesh.bounds();
    assert!(
        (lo - Vec3::new(-1.02, 0.0, -1.04)).abs().max_element() < 1e-5,
        "{lo}"
    );
    assert!(
        (hi - Vec3::new(1.0, 1.99, 0.99)).abs().max_element() < 1e-5,
        "{hi}"
    );
    // The left wall is red: look left (-X) from the interior viewpoint.
    let caster = MeshCaster::new(mesh);
    let h = caster
        .intersect(Vec3::new(0.0, 1.0, 0.5), -Vec3::X, 0.0, f32::INFINITY)
        .expect("left wall");
    assert_eq!(h.albedo, [0.63, 0.065, 0.05]);
    // Loading twice gives the same hash; scaling gives the same hash (same bytes read).
    let (_, _, again) = load_obj(&path, 2.0).expect("loads");
    assert_eq!(hash, again);
}

#[test]
fn sponza_loads_with_and_without_materials() {
    let with = common::shared_scene("sponza_dabrovic/sponza_with_materials.obj");
    let (mesh, warnings, _) = load_obj(&with, 1.0).expect("loads");
    assert_eq!(mesh.degenerate_dropped, 1);
    assert_eq!(mesh.triangles.len(), 66_454 - 1);
    assert_eq!(mesh.normals.len(), mesh.positions.len());
    assert_eq!(mesh.uvs.len(), mesh.positions.len());
    // Normals are renormalised (the file has lengths up to 6.25) or absent (one is zero).
    assert!(mesh
        .normals
        .iter()
        .all(|n| *n == Vec3::ZERO || (n.length() - 1.0).abs() < 1e-5));
    assert!(mesh.normals.contains(&Vec3::ZERO));
    assert!(mesh.materials.len() >= 19);
    // All diffuse maps are present (some only with different case).
    assert!(
        mesh.textures.len() >= 10,
        "{} textures",
        mesh.textures.len()
    );
    assert!(
        !warnings.iter().any(|w| w.contains("not found")),
        "{warnings:?}"
    );
    assert!(mesh
        .textures
        .iter()
        .all(|t| t.texels().flatten().all(|c| (0.0..=1.0).contains(&c))));

    let plain = with.with_file_name("sponza.obj");
    let (mesh2, warnings2, _) = load_obj(&plain, 1.0).expect("loads");
    assert_eq!(mesh2.triangles.len(), 66_454 - 1);
    assert_eq!(mesh2.materials.len(), 1);
    assert!(
        warnings2.iter().any(|w| w.contains("grey")),
        "{warnings2:?}"
    );
}

#[test]
fn sibenik_loads() {
    let path = common::shared_scene("sibenik/sibenik.obj");
    let (mesh, _, _) = load_obj(&path, 1.0).expect("loads");
    // The file has 10 zero-area triangles in f64, 9 after rounding to f32.
    assert!(
        (9..=10).contains(&mesh.degenerate_dropped),
        "{}",
        mesh.degenerate_dropped
    );
    assert_eq!(
        mesh.triangles.len() as u64 + mesh.degenerate_dropped,
        75_284
    );
    assert!(mesh.normals.is_empty());
}

#[test]
fn conference_loads_and_drops_zero_area_triangles() {
    let path = common::shared_scene("conference/conference.obj");
    let (mesh, _, _) = load_obj(&path, 0.003).expect("loads");
    assert_eq!(mesh.degenerate_dropped, 53_627);
    assert_eq!(mesh.triangles.len(), 331_179 - 53_627);
    let (lo, hi) = mesh.bounds();
    let size = hi - lo;
    assert!(
        (size.x - 8.1).abs() < 0.1 && (size.y - 1.96).abs() < 0.05,
        "{size}"
    );
}

fn manifest(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(name)
}

/// Probes rays from the viewpoint: most must hit, none closer than `min_clearance`.
fn assert_viewpoint_inside(caster: &dyn RayCaster, viewpoint: Vec3, min_clearance: f32) {
    let dirs = common::directions(256, 7);
    let mut hits = 0;
    for d in &dirs {
        if let Some(h) = caster.intersect(viewpoint, *d, 0.0, f32::INFINITY) {
            hits += 1;
            assert!(h.t > min_clearance, "surface {} from the viewpoint", h.t);
        }
    }
    assert!(hits > 200, "only {hits} of 256 probe rays hit");
}

#[test]
fn builtin_cornell_manifest() {
    let scene = load_scene(&manifest("cornell.toml").to_string_lossy()).expect("loads");
    assert!(scene.source.ends_with("cornell.toml"));
    assert_eq!(scene.triangle_count(), 30);
    let caster = scene.build_caster();
    // The front is open, so only the back hemisphere is guaranteed to hit.
    let vp = scene.viewpoint;
    for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z] {
        let h = caster.intersect(vp, d, 0.0, f32::INFINITY).expect("hits");
        assert!(h.t > 0.1, "{d}: {}", h.t);
    }
    assert!(!caster.occluded(Vec3::from(scene.light.position), vp));
}

#[test]
fn cornell_obj_manifest() {
    common::shared_scene("cornell_box/CornellBox-Original.obj");
    let scene =
        load_scene(&common::shared_manifest(&manifest("cornell_obj.toml")).spec()).expect("loads");
    assert_eq!(scene.viewpoint, Vec3::new(0.0, 1.0, 0.5));
    assert_eq!(scene.light.intensity, [3.6; 3]);
    assert!(
        !scene
            .warnings
            .iter()
            .any(|w| w.contains("viewpoint is a guess")),
        "{:?}",
        scene.warnings
    );
    let caster = scene.build_caster();
    let light = Vec3::from(scene.light.position);
    assert!(!caster.occluded(light, scene.viewpoint));
    // The camera looks in through the open side: nothing between it and the viewpoint.
    assert!(!caster.occluded(Vec3::from(scene.camera.position), scene.viewpoint));
}

#[test]
fn sponza_manifest() {
    common::shared_scene("sponza_dabrovic/sponza_with_materials.obj");
    let scene =
        load_scene(&common::shared_manifest(&manifest("sponza.toml")).spec()).expect("loads");
    assert_eq!(scene.bake["receiver_levels"].as_integer(), Some(6));
    assert_eq!(scene.bake["coarse_count"].as_integer(), Some(339));
    let Geometry::Mesh(mesh) = &scene.geometry else {
        panic!("mesh expected");
    };
    let caster = MeshCaster::new(mesh.clone());
    // The courtyard is open to the sky: some probe rays escape, so check a lower bound.
    let dirs = common::directions(256, 3);
    let hits: Vec<f32> = dirs
        .iter()
        .filter_map(|d| caster.intersect(scene.viewpoint, *d, 0.0, f32::INFINITY))
        .map(|h| h.t)
        .collect();
    assert!(hits.len() > 180, "{} hits", hits.len());
    assert!(
        hits.iter().all(|&t| t > 2.0),
        "min {:?}",
        hits.iter().copied().reduce(f32::min)
    );
    // Straight up escapes through the open roof; the light sees the viewpoint.
    assert!(caster
        .intersect(scene.viewpoint, Vec3::Y, 0.0, f32::INFINITY)
        .is_none());
    assert!(!caster.occluded(Vec3::from(scene.light.position), scene.viewpoint));
}

#[test]
fn sibenik_and_conference_manifests() {
    common::shared_scene("sibenik/sibenik.obj");
    let scene =
        load_scene(&common::shared_manifest(&manifest("sibenik.toml")).spec()).expect("loads");
    let caster = scene.build_caster();
    assert_viewpoint_inside(caster.as_ref(), scene.viewpoint, 3.0);
    assert!(!caster.occluded(Vec3::from(scene.light.position), scene.viewpoint));

    common::shared_scene("conference/conference.obj");
    let scene =
        load_scene(&common::shared_manifest(&manifest("conference.toml")).spec()).expect("loads");
    assert!((scene.scale - 0.003).abs() < 1e-9);
    assert!((scene.viewpoint - Vec3::new(3.6, 1.2, -0.45)).length() < 1e-4);
    assert_eq!(scene.light.intensity, [3.0; 3], "intensity is not scaled");
    let caster = scene.build_caster();
    assert_viewpoint_inside(caster.as_ref(), scene.viewpoint, 0.7);
}
