//! CPU relighting and probes against known answers.

use std::process::Command;

use glam::Vec3;
use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::{BakedFile, WriteOptions};
use mlt_view::probe::{evaluate, Probe};
use mlt_view::{CpuRelighter, Light, Relight};

fn bake_to(path: &std::path::Path, spec: &str, opts: BakeOptions) {
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let out = bake_scene(&scene, &opts, &Silent).unwrap();
    mlt_format::file::write(path, &out.contents, WriteOptions::default()).unwrap();
}

fn temp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("mlt-view-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn closed_sphere_probes_give_the_analytic_direct_and_indirect_light() {
    let d = temp("sphere");
    let f = d.join("sphere.mlt");
    let spec = "builtin:sphere?albedo=0.5&radius=2";
    bake_to(
        &f,
        spec,
        BakeOptions {
            receiver_levels: Some(4),
            coarse_count: Some(24),
            sender_levels: Some(2),
            epsilon: Some(1e-5),
            bounces: Some(8),
            gather_rays: Some(256),
            bounces_on_all_receivers: true,
            ..Default::default()
        },
    );
    let file = BakedFile::open(&f).unwrap();
    let ib = file.basis().unwrap();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let caster = scene.build_caster();
    let light = Light::point(Vec3::ZERO, [1.0, 1.0, 1.0]).unwrap();
    let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), 2, 4);
    let frame = r.relight(&light).clone();
    assert!(!frame.reused);
    // E0 = I / R^2; indirect = rho / (1 - rho) E0 (less 0.5^8 of the series).
    let e0 = 0.25f32;
    let expected = e0 * (1.0 - 0.5f32.powi(8));
    let probes: Vec<Probe> = mlt_tests_points(400)
        .into_iter()
        .map(|d| Probe {
            position: d * 2.0,
            normal: -d,
        })
        .collect();
    for p in &probes {
        let [direct, basis, indirect] = evaluate(&ib, caster.as_ref(), &light, &frame, 2, p);
        for c in 0..3 {
            assert!((direct[c] - e0).abs() < 1e-5, "{direct:?}");
            assert!((basis[c] / e0 - 1.0).abs() < 1e-3, "{basis:?}");
            assert!(
                (indirect[c] / expected - 1.0).abs() < 0.02,
                "{indirect:?} vs {expected}"
            );
        }
    }
    // The light did not move: nothing is recomputed.
    assert!(r.relight(&light).reused);
    let moved = Light::point(Vec3::new(0.1, 0.0, 0.0), [1.0; 3]).unwrap();
    assert!(!r.relight(&moved).reused);
    let _ = std::fs::remove_dir_all(&d);
}

/// Unit directions on a golden-angle spiral.
fn mlt_tests_points(n: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f32;
            Vec3::new(r * phi.cos(), z, r * phi.sin())
        })
        .collect()
}

#[test]
fn cornell_box_bleeds_red_and_green_onto_the_white_back_wall() {
    let d = temp("cornell");
    let f = d.join("cornell.mlt");
    bake_to(
        &f,
        "builtin:cornell",
        BakeOptions {
            receiver_levels: Some(4),
            coarse_count: Some(60),
            gather_rays: Some(128),
            ..Default::default()
        },
    );
    // The back wall (z = 0.5592, normal -z), near the red wall (x ~ 0.55) and near the green
    // wall (x ~ 0): rows for the view binary.
    let mut csv = String::from("x,y,z,nx,ny,nz\n");
    for y in [0.1f32, 0.2, 0.3, 0.4] {
        csv.push_str(&format!("0.53,{y},0.559,0,0,-1\n"));
        csv.push_str(&format!("0.03,{y},0.559,0,0,-1\n"));
    }
    let input = d.join("in.csv");
    std::fs::write(&input, csv).unwrap();
    let output = d.join("out.csv");
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg(&f)
        .arg("--probe")
        .arg(&input)
        .arg("--probe-out")
        .arg(&output)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let text = std::fs::read_to_string(&output).unwrap();
    let rows: Vec<Vec<f32>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 8);
    let (mut red_side, mut green_side) = (0.0f32, 0.0f32);
    for row in &rows {
        let (ir, ig) = (row[12], row[13]);
        assert!(ir > 0.0 && ig > 0.0, "{row:?}");
        if row[0] > 0.3 {
            red_side += ir / ig;
        } else {
            green_side += ir / ig;
        }
    }
    eprintln!(
        "indirect red/green on the back wall: {:.3} near the red wall, {:.3} near the green wall",
        red_side / 4.0,
        green_side / 4.0
    );
    assert!(
        red_side > 1.2 * green_side,
        "no colour bleeding: {red_side} vs {green_side}"
    );

    // Timings with a moving light, and the errors a user can make.
    let t = d.join("t.json");
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg(&f)
        .args(["--frames", "3", "--timings-out"])
        .arg(&t)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&t).unwrap()).unwrap();
    for stage in ["direct", "project", "transport", "flatten"] {
        assert!(json["median_ms"][stage].as_f64().unwrap() >= 0.0);
    }
    std::fs::write(&input, "1,2,3,0,0,1\n1,2,3\n").unwrap();
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg(&f)
        .arg("--probe")
        .arg(&input)
        .arg("--probe-out")
        .arg(&output)
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("in.csv:2"));
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg(&f)
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("not implemented"));
    let _ = std::fs::remove_dir_all(&d);
}
