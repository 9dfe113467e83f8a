//! Open scenes bake in bounded time: most importance particles escape them, and the placement
//! still fills the surfaces the viewpoint reaches (area samples of the reached triangles),
//! saying so. Each scene is a small OBJ written into a temporary directory.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// Longest a bake of these scenes may take (debug build, shared machine).
const LIMIT: Duration = Duration::from_secs(60);

/// A fresh directory, removed with its contents when dropped.
fn temp(name: &str) -> mlt_test_support::TempDir {
    mlt_test_support::TempDir::new(&format!("open-{name}"))
}

/// A floor (y = 0) and a back wall (z = 0) of the unit cube.
const TWO_QUADS: &str = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 0 1 0\nv 1 1 0\n\
f 1 4 3 2\nf 1 2 6 5\n";

/// The unit cube without its front (z = 1) and right (x = 1) walls.
const BOX_MISSING_TWO_WALLS: &str = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\n\
v 0 1 0\nv 1 1 0\nv 1 1 1\nv 0 1 1\nf 1 4 3 2\nf 1 2 6 5\nf 5 6 7 8\nf 1 5 8 4\n";

/// One quad in the y = 0 plane, facing up.
const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nf 1 4 3 2\n";

/// Bakes `scene` with `args`, checking it finishes in time; returns stderr and the output.
fn bake(dir: &Path, scene: &Path, args: &[&str]) -> (String, PathBuf) {
    let out = dir.join("out.mlt");
    let start = Instant::now();
    let r = Command::new(env!("CARGO_BIN_EXE_bake"))
        .arg(scene)
        .arg("-o")
        .arg(&out)
        .args(args)
        .output()
        .unwrap();
    let took = start.elapsed();
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    assert!(r.status.success(), "{err}");
    assert!(took < LIMIT, "took {took:?}\n{err}");
    (err, out)
}

/// Points per level of a baked file.
fn level_points(file: &Path) -> Vec<u64> {
    let f = mlt_format::BakedFile::open(file).unwrap();
    let meta = f.meta().unwrap();
    meta.stats.levels.iter().map(|l| l.points).collect()
}

/// Every level holds points, about four times as many as the coarser one (a saturated
/// Poisson-disk level on flat surfaces).
fn assert_filled(points: &[u64]) {
    assert!(points[0] > 0, "{points:?}");
    for w in points.windows(2) {
        let g = w[1] as f64 / w[0] as f64;
        assert!((3.0..5.0).contains(&g), "growth {g} in {points:?}");
    }
}

#[test]
fn two_quads_bake_with_their_surfaces_filled() {
    let d = temp("two");
    let obj = d.join("two.obj");
    std::fs::write(&obj, TWO_QUADS).unwrap();
    let (err, out) = bake(&d, &obj, &["--basis-only", "--receiver-levels", "5"]);
    assert!(err.contains("the scene looks open"), "{err}");
    // The Poisson-disk stage reports each level as it ends.
    for l in 0..5 {
        assert!(err.contains(&format!("poisson disk level {l}:")), "{err}");
    }
    assert_filled(&level_points(&out));
}

#[test]
fn a_box_missing_two_walls_bakes_with_transport() {
    let d = temp("box");
    let obj = d.join("box.obj");
    std::fs::write(&obj, BOX_MISSING_TWO_WALLS).unwrap();
    let args = [
        "--receiver-levels",
        "4",
        "--coarse-count",
        "60",
        "--gather-rays",
        "64",
    ];
    let (err, out) = bake(&d, &obj, &args);
    assert!(err.contains("the scene looks open"), "{err}");
    assert_filled(&level_points(&out));
}

#[test]
fn a_quad_seen_from_below_its_horizon_bakes_on_its_underside() {
    let d = temp("below");
    std::fs::write(d.join("quad.obj"), QUAD).unwrap();
    let manifest = d.join("below.toml");
    std::fs::write(
        &manifest,
        "[scene]\nsource = \"quad.obj\"\nviewpoint = [0.5, -0.5, 0.5]\n",
    )
    .unwrap();
    let (err, out) = bake(&d, &manifest, &["--basis-only", "--receiver-levels", "4"]);
    assert!(err.contains("the scene looks open"), "{err}");
    let points = level_points(&out);
    assert_filled(&points);
    let f = mlt_format::BakedFile::open(&out).unwrap();
    let basis = f.basis().unwrap().basis;
    // Every point faces the viewpoint's side.
    assert!(basis.normals.iter().all(|n| n[1] < -0.99), "normals");
    assert!(basis.positions.iter().all(|p| p[1].abs() < 1e-5));
}

#[test]
fn a_viewpoint_outside_the_scene_is_named_with_what_to_do() {
    let d = temp("far");
    std::fs::write(d.join("two.obj"), TWO_QUADS).unwrap();
    let manifest = d.join("far.toml");
    std::fs::write(
        &manifest,
        "[scene]\nsource = \"two.obj\"\nviewpoint = [30.0, 40.0, 50.0]\n",
    )
    .unwrap();
    let (err, _) = bake(&d, &manifest, &["--basis-only", "--receiver-levels", "3"]);
    assert!(
        err.contains("of importance particles hit a surface from the viewpoint (30, 40, 50); set [scene] viewpoint to a point inside the scene"),
        "{err}"
    );
}
