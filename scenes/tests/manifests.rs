//! Manifest parsing, scaling and validation against hand-written files.

mod common;

use std::path::{Path, PathBuf};

use common::TempDir;

use glam::Vec3;
use mlt_scenes::{load_manifest, load_scene, LightKind, SceneError};

const TRIANGLE_OBJ: &str = "v 0 0 0\nv 4 0 0\nv 0 0 4\nf 1 3 2\n";

fn setup(name: &str, manifest: &str) -> (TempDir, PathBuf) {
    let dir = TempDir::new(&format!("scenes-{name}"));
    std::fs::create_dir_all(dir.join("meshes")).expect("mkdir");
    std::fs::write(dir.join("meshes/tri.obj"), TRIANGLE_OBJ).expect("write obj");
    let path = dir.join("scene.toml");
    std::fs::write(&path, manifest).expect("write manifest");
    (dir, path)
}

fn err_of(name: &str, manifest: &str) -> SceneError {
    let (_dir, path) = setup(name, manifest);
    let e = load_manifest(&path).expect_err(name);
    let msg = e.to_string();
    assert!(
        msg.contains("scene.toml"),
        "{name}: message does not name the file: {msg}"
    );
    e
}

#[test]
fn positions_are_scaled_intensity_is_not() {
    let (_dir, path) = setup(
        "scaled",
        r#"
[scene]
source = "meshes/tri.obj"
scale = 0.5
viewpoint = [1, 2, 1]

[camera]
position = [1, 2, 10]
target = [1, 0, 1]

[light]
kind = "spot"
position = [1, 3, 1]
intensity = [2, 2, 2]
direction = [0, -1, 0]
cone_deg = 60
falloff = "smooth"

[bake]
coarse_count = 50
seed = 9
"#,
    );
    let scene = load_scene(&path.to_string_lossy()).expect("loads");
    assert_eq!(scene.viewpoint, Vec3::new(0.5, 1.0, 0.5));
    assert_eq!(scene.camera.position, [0.5, 1.0, 5.0]);
    assert_eq!(scene.camera.target, [0.5, 0.0, 0.5]);
    assert_eq!(scene.light.position, [0.5, 1.5, 0.5]);
    assert_eq!(scene.light.intensity, [2.0; 3]);
    assert_eq!(scene.light.kind, LightKind::Spot);
    assert_eq!(scene.bake["coarse_count"].as_integer(), Some(50));
    assert_eq!(scene.bake["seed"].as_integer(), Some(9));
    assert_eq!(scene.scale, 0.5);
    let caster = scene.build_caster();
    let (lo, hi) = caster.bounds();
    assert_eq!((lo, hi), (Vec3::ZERO, Vec3::new(2.0, 0.0, 2.0)));
    assert!(!scene
        .warnings
        .iter()
        .any(|w| w.contains("viewpoint is a guess")));

    // The hash covers the manifest: change a comment, the hash changes.
    let text = std::fs::read_to_string(&path).expect("read");
    std::fs::write(&path, format!("# edited\n{text}")).expect("write");
    let again = load_manifest(&path).expect("loads");
    assert_ne!(again.content_hash, scene.content_hash);
}

#[test]
fn builtin_source_with_scale_and_defaults() {
    let (_dir, path) = setup(
        "builtin",
        "[scene]\nsource = \"builtin:sphere?radius=2\"\nscale = 3\n",
    );
    let scene = load_manifest(&path).expect("loads");
    match scene.geometry {
        mlt_scenes::Geometry::Sphere { radius, .. } => assert_eq!(radius, 6.0),
        mlt_scenes::Geometry::Mesh(_) => panic!("sphere expected"),
    }
    assert_eq!(scene.light.intensity, [1.0; 3]);
}

#[test]
fn bad_manifests_are_errors_naming_the_file() {
    let base = "[scene]\nsource = \"meshes/tri.obj\"\n";
    let e = err_of("typo", "[scene]\nsource = \"meshes/tri.obj\"\nscael = 2\n");
    assert!(matches!(e, SceneError::Manifest { .. }), "{e}");
    assert!(e.to_string().contains("scael"), "{e}");
    let e = err_of("section", &format!("{base}[lights]\nkind = \"point\"\n"));
    assert!(matches!(e, SceneError::Manifest { .. }), "{e}");
    let e = err_of(
        "camtypo",
        &format!("{base}[camera]\nposition = [0,0,1]\ntarget = [0,0,0]\nfov = 3\n"),
    );
    assert!(e.to_string().contains("fov"), "{e}");
    let e = err_of(
        "nan",
        "[scene]\nsource = \"meshes/tri.obj\"\nviewpoint = [0, nan, 0]\n",
    );
    assert!(matches!(e, SceneError::NonFinite { .. }), "{e}");
    let e = err_of(
        "inflight",
        &format!("{base}[light]\nkind = \"point\"\nposition = [0, inf, 0]\nintensity = [1,1,1]\n"),
    );
    assert!(matches!(e, SceneError::NonFinite { .. }), "{e}");
    let e = err_of(
        "spotdir",
        &format!("{base}[light]\nkind = \"spot\"\nposition = [0,1,0]\nintensity = [1,1,1]\ncone_deg = 30\n"),
    );
    assert!(matches!(e, SceneError::InvalidLight { .. }), "{e}");
    let e = err_of(
        "spotcone",
        &format!("{base}[light]\nkind = \"spot\"\nposition = [0,1,0]\nintensity = [1,1,1]\ndirection = [0,-1,0]\ncone_deg = 180\n"),
    );
    assert!(matches!(e, SceneError::InvalidLight { .. }), "{e}");
    let e = err_of(
        "camera",
        &format!("{base}[camera]\nposition = [0,0,0]\ntarget = [0,0,0]\n"),
    );
    assert!(matches!(e, SceneError::Manifest { .. }), "{e}");
    let e = err_of(
        "scale",
        "[scene]\nsource = \"meshes/tri.obj\"\nscale = -1\n",
    );
    assert!(matches!(e, SceneError::Manifest { .. }), "{e}");
    let e = err_of(
        "kind",
        &format!("{base}[light]\nkind = \"area\"\nposition = [0,1,0]\nintensity = [1,1,1]\n"),
    );
    assert!(matches!(e, SceneError::Manifest { .. }), "{e}");
}

#[test]
fn missing_source_names_the_mesh_file() {
    let (_dir, path) = setup("missing", "[scene]\nsource = \"meshes/nothere.obj\"\n");
    let e = load_manifest(&path).expect_err("missing mesh");
    assert!(matches!(e, SceneError::Io { .. }), "{e}");
    assert!(e.to_string().contains("nothere.obj"), "{e}");
    // The message carries the operating system's reason itself and exposes no source, so
    // that a binary printing the chain of causes does not print the reason twice.
    let SceneError::Io { error, .. } = &e else {
        unreachable!()
    };
    assert_eq!(error.kind(), std::io::ErrorKind::NotFound);
    assert!(
        e.to_string().ends_with(&format!("nothere.obj: {error}")),
        "{e}"
    );
    assert!(std::error::Error::source(&e).is_none(), "{e}");
}

#[test]
fn bare_mesh_gets_guessed_defaults() {
    let (_dir, path) = setup("bare", "[scene]\nsource = \"meshes/tri.obj\"\n");
    let obj = path.with_file_name("meshes").join("tri.obj");
    let scene = load_scene(&obj.to_string_lossy()).expect("loads");
    assert_eq!(scene.viewpoint, Vec3::new(2.0, 0.0, 2.0));
    assert!(scene
        .warnings
        .iter()
        .any(|w| w.contains("viewpoint is a guess")));
    let cam = Vec3::from(scene.camera.position);
    assert!(cam.z > 2.0 && cam.x == 2.0, "{cam}");
    // I = h², h the half-diagonal (sqrt(32) / 2 = 2.83).
    assert!((scene.light.intensity[0] - 8.0).abs() < 1e-4);
    // A manifest naming only the source keeps the guessed defaults.
    let via_manifest = load_manifest(&path).expect("loads");
    assert_eq!(via_manifest.viewpoint, scene.viewpoint);
}

#[test]
fn unknown_extension_and_missing_files() {
    let e = load_scene("scene.ply").expect_err("ply");
    assert!(matches!(e, SceneError::UnknownFormat { .. }));
    assert!(e.to_string().contains("scene.ply"));
    let e = load_scene("/nonexistent/dir/x.toml").expect_err("missing");
    assert!(e
        .to_string()
        .contains(&*Path::new("/nonexistent/dir/x.toml").to_string_lossy()));
    let e = load_scene("builtin:nope").expect_err("builtin");
    assert!(matches!(e, SceneError::Builtin { .. }));
}

/// NaN or infinity in any number of a manifest is an error naming the file and the field
/// (TOML writes them `nan`, `inf`, `-inf`).
#[test]
fn every_non_finite_manifest_number_is_named() {
    let scene = "[scene]\nsource = \"meshes/tri.obj\"\n";
    let camera = |field: &str, v: &str| {
        let mut c = vec![
            ("position", "[0, 0, 1]".to_string()),
            ("target", "[0, 0, 0]".to_string()),
            ("up", "[0, 1, 0]".to_string()),
            ("fovy_deg", "45".to_string()),
        ];
        for (k, x) in &mut c {
            if *k == field {
                *x = v.to_string();
            }
        }
        let body: Vec<String> = c.iter().map(|(k, x)| format!("{k} = {x}")).collect();
        format!("{scene}[camera]\n{}\n", body.join("\n"))
    };
    let spot = |field: &str, v: &str| {
        let mut c = vec![
            ("position", "[0, 1, 0]".to_string()),
            ("intensity", "[1, 1, 1]".to_string()),
            ("direction", "[0, -1, 0]".to_string()),
            ("cone_deg", "30".to_string()),
        ];
        for (k, x) in &mut c {
            if *k == field {
                *x = v.to_string();
            }
        }
        let body: Vec<String> = c.iter().map(|(k, x)| format!("{k} = {x}")).collect();
        format!("{scene}[light]\nkind = \"spot\"\n{}\n", body.join("\n"))
    };
    let cases: Vec<(String, &str)> = vec![
        (
            "[scene]\nsource = \"meshes/tri.obj\"\nscale = inf\n".into(),
            "scale",
        ),
        (
            "[scene]\nsource = \"meshes/tri.obj\"\nviewpoint = [0, 0, -inf]\n".into(),
            "[scene] viewpoint",
        ),
        (camera("position", "[nan, 0, 1]"), "[camera] position"),
        (camera("target", "[0, inf, 0]"), "[camera] target"),
        (camera("up", "[0, nan, 0]"), "[camera] up"),
        (camera("fovy_deg", "nan"), "[camera] fovy_deg"),
        (spot("position", "[0, nan, 0]"), "[light] position"),
        (spot("intensity", "[1, inf, 1]"), "[light] intensity"),
        (spot("direction", "[0, -inf, 0]"), "[light] direction"),
        (spot("cone_deg", "nan"), "[light] cone_deg"),
        (format!("{scene}[bake]\nepsilon = nan\n"), "[bake] epsilon"),
        (
            format!("{scene}[bake]\ncoarse_radius = inf\n"),
            "[bake] coarse_radius",
        ),
    ];
    for (k, (text, field)) in cases.iter().enumerate() {
        let e = err_of(&format!("nonfinite{k}"), text);
        let msg = e.to_string();
        assert!(msg.contains(field), "{field}: {msg}");
        assert!(
            msg.contains("finite"),
            "{field}: the message does not say what is wrong: {msg}"
        );
    }
}

/// `[scene] textures = false` and `normals = "face"` on a textured quad with tilted vertex
/// normals written here: the hit albedo becomes the MTL `Kd`, the shading normal the face's,
/// and each option changes the content hash.
#[test]
fn textures_and_vertex_normals_can_be_turned_off() {
    let dir = TempDir::new("scenes-options");
    let mut png = Vec::new();
    image::RgbImage::from_raw(1, 1, vec![0, 255, 0])
        .expect("size")
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("png");
    std::fs::write(dir.join("tex.png"), &png).expect("write png");
    std::fs::write(
        dir.join("m.mtl"),
        "newmtl a\nKd 0.5 0.5 0.5\nmap_Kd tex.png\n",
    )
    .expect("mtl");
    // The quad faces +Z; its vertex normals lean 45 degrees toward +X.
    std::fs::write(
        dir.join("q.obj"),
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         vn 1 0 1\nusemtl a\nf 1/1/1 2/2/1 3/3/1 4/4/1\n",
    )
    .expect("obj");
    let load = |name: &str, extra: &str| {
        let path = dir.join(name);
        std::fs::write(&path, format!("[scene]\nsource = \"q.obj\"\n{extra}")).expect("toml");
        let scene = load_manifest(&path).expect(name);
        let hit = scene
            .build_caster()
            .intersect(Vec3::new(0.5, 0.5, 1.0), Vec3::NEG_Z, 0.0, 10.0)
            .expect("hits the quad");
        (scene.content_hash, hit)
    };
    let (h_default, hit) = load("default.toml", "");
    assert!(
        (hit.albedo[1] - 0.5).abs() < 1e-3 && hit.albedo[0] < 1e-3,
        "{:?}",
        hit.albedo
    );
    assert!(
        (hit.shading_normal.x - 0.5f32.sqrt()).abs() < 1e-4,
        "{}",
        hit.shading_normal
    );
    let (h_plain, hit) = load("plain.toml", "textures = false\n");
    assert_eq!(hit.albedo, [0.5, 0.5, 0.5]);
    assert!((hit.shading_normal.x - 0.5f32.sqrt()).abs() < 1e-4);
    let (h_face, hit) = load("face.toml", "normals = \"face\"\n");
    assert!((hit.albedo[1] - 0.5).abs() < 1e-3 && hit.albedo[0] < 1e-3);
    assert!(
        (hit.shading_normal - Vec3::Z).length() < 1e-6,
        "{}",
        hit.shading_normal
    );
    let (h_both, hit) = load("both.toml", "textures = false\nnormals = \"face\"\n");
    assert_eq!(hit.albedo, [0.5, 0.5, 0.5]);
    assert_eq!(hit.shading_normal, hit.geometric_normal);
    let hashes = [h_default, h_plain, h_face, h_both];
    for (i, a) in hashes.iter().enumerate() {
        for b in &hashes[i + 1..] {
            assert_ne!(a, b, "{hashes:?}");
        }
    }
    // The defaults spelled out are today's scene (the bytes differ, so the hash does too).
    let (_, hit) = load("explicit.toml", "textures = true\nnormals = \"vertex\"\n");
    assert!((hit.shading_normal.x - 0.5f32.sqrt()).abs() < 1e-4);
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[scene]\nsource = \"q.obj\"\nnormals = \"smooth\"\n").expect("toml");
    let e = load_manifest(&bad)
        .expect_err("unknown normal source")
        .to_string();
    assert!(e.contains("bad.toml") && e.contains("smooth"), "{e}");
}

/// `[scene] subdivide = N` gives `4^N` times the triangles over the same bounds and area, the
/// same hit (albedo from the texture, shading normal) at a point, and its own content hash;
/// more levels than the limit are an error naming the file.
#[test]
fn subdivide_keeps_the_surface() {
    let dir = TempDir::new("scenes-subdivide");
    let mut png = Vec::new();
    image::RgbImage::from_raw(2, 1, vec![255, 0, 0, 0, 0, 255])
        .expect("size")
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("png");
    std::fs::write(dir.join("tex.png"), &png).expect("write png");
    std::fs::write(dir.join("m.mtl"), "newmtl a\nKd 1 1 1\nmap_Kd tex.png\n").expect("mtl");
    std::fs::write(
        dir.join("q.obj"),
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         vn 1 0 1\nvn 0 0 1\nusemtl a\nf 1/1/1 2/2/2 3/3/2 4/4/1\n",
    )
    .expect("obj");
    let load = |name: &str, extra: &str| {
        let path = dir.join(name);
        std::fs::write(&path, format!("[scene]\nsource = \"q.obj\"\n{extra}")).expect("toml");
        load_manifest(&path)
    };
    let area = |scene: &mlt_scenes::Scene| -> (usize, f64) {
        let mlt_scenes::Geometry::Mesh(m) = &scene.geometry else {
            panic!("a mesh")
        };
        let a = (0..m.triangles.len() as u32)
            .map(|t| {
                let [a, b, c] = m.corners(t);
                0.5 * (b - a).cross(c - a).length() as f64
            })
            .sum();
        (m.triangles.len(), a)
    };
    let probe = |scene: &mlt_scenes::Scene, x: f32| {
        scene
            .build_caster()
            .intersect(Vec3::new(x, 0.3, 1.0), Vec3::NEG_Z, 0.0, 10.0)
            .expect("hits the quad")
    };
    let source = load("source.toml", "").expect("source");
    let (tris, a0) = area(&source);
    assert_eq!(tris, 2);
    let mut hashes = vec![source.content_hash];
    for levels in 1..=2u32 {
        let scene = load(
            &format!("s{levels}.toml"),
            &format!("subdivide = {levels}\n"),
        )
        .expect("subdivided");
        let (n, a) = area(&scene);
        assert_eq!(n, 2 * 4usize.pow(levels));
        assert!((a - a0).abs() < 1e-6, "area {a} vs {a0}");
        for x in [0.2f32, 0.8] {
            let (want, got) = (probe(&source, x), probe(&scene, x));
            let albedo_gap = (0..3).map(|k| (got.albedo[k] - want.albedo[k]).abs());
            assert!(
                albedo_gap.fold(0.0f32, f32::max) < 1e-4,
                "x = {x}: {:?} vs {:?}",
                got.albedo,
                want.albedo
            );
            assert!(
                (got.shading_normal - want.shading_normal).length() < 1e-5,
                "{} vs {}",
                got.shading_normal,
                want.shading_normal
            );
            assert!((got.position - want.position).length() < 1e-6);
        }
        hashes.push(scene.content_hash);
    }
    assert!(
        hashes[0] != hashes[1] && hashes[1] != hashes[2],
        "{hashes:?}"
    );
    let e = load("too_many.toml", "subdivide = 9\n")
        .expect_err("too many levels")
        .to_string();
    assert!(
        e.contains("too_many.toml") && e.contains("subdivide"),
        "{e}"
    );
}

/// `albedo_max` scales the built-in Cornell box so that its brightest channel is the target,
/// changes the scene's identity, and a value that would not lose energy is refused with the
/// file named.
#[test]
fn albedo_max_brightens_the_whole_scene_and_is_checked() {
    let largest = |scene: &mlt_scenes::Scene| {
        let mlt_scenes::Geometry::Mesh(m) = &scene.geometry else {
            panic!("a mesh")
        };
        mlt_scenes::scene_options::largest_albedo(m)
    };
    let (_d, plain) = setup("albedo-plain", "[scene]\nsource = \"builtin:cornell\"\n");
    let (_e, bright) = setup(
        "albedo-bright",
        "[scene]\nsource = \"builtin:cornell\"\nalbedo_max = 0.95\n",
    );
    let (plain, bright) = (
        load_manifest(&plain).unwrap(),
        load_manifest(&bright).unwrap(),
    );
    assert!(largest(&plain) < 0.9, "{}", largest(&plain));
    assert!((largest(&bright) - 0.95).abs() < 1e-6);
    assert_ne!(plain.content_hash, bright.content_hash);
    for bad in ["1.0", "0.0", "-0.5", "nan"] {
        let (_f, path) = setup(
            "albedo-bad",
            &format!("[scene]\nsource = \"builtin:cornell\"\nalbedo_max = {bad}\n"),
        );
        let e = load_manifest(&path).expect_err(bad).to_string();
        assert!(e.contains("albedo_max") && e.contains(".toml"), "{e}");
    }
}
