//! The brute-force reference against the closed sphere's analytic answer, its noise estimate,
//! determinism, and the compare measures.

mod common;

use std::path::Path;
use std::process::Command;

use glam::Vec3;
use mlt_view::compare::{compare_dirs, compare_probe_csv, CompareError};
use mlt_view::probe::Probe;
use mlt_view::reference::{
    probes_to_csv, reference_probes, render_reference, write_reference, ReferenceImages,
    ReferenceOptions,
};
use mlt_view::{Camera, Light, RgbImage};

fn temp(name: &str) -> common::TempDir {
    common::temp_dir("reference", name)
}

/// A camera inside the sphere of radius 2 at the origin, looking at its wall.
fn inside_camera(w: u32, h: u32) -> Camera {
    Camera::new(
        Vec3::new(0.0, 0.3, 1.0),
        Vec3::new(0.2, -0.1, -2.0),
        Vec3::Y,
        70.0,
        w,
        h,
    )
    .unwrap()
}

/// The scene's own camera at `w` x `h` pixels.
fn scene_camera(scene: &mlt_scenes::Scene, w: u32, h: u32) -> Camera {
    let c = &scene.camera;
    Camera::new(
        c.position.into(),
        c.target.into(),
        c.up.into(),
        c.fovy_deg,
        w,
        h,
    )
    .unwrap()
}

fn sphere(albedo: f32) -> Box<dyn mlt_scenes::RayCaster> {
    mlt_scenes::load_scene(&format!("builtin:sphere?albedo={albedo}&radius=2"))
        .unwrap()
        .build_caster()
}

fn render_sphere(albedo: f32, spp: u32, seed: u64) -> ReferenceImages {
    let caster = sphere(albedo);
    let light = Light::point(Vec3::ZERO, [1.0, 1.0, 1.0]).unwrap();
    render_reference(caster.as_ref(), &inside_camera(24, 16), &light, spp, seed).unwrap()
}

/// Analytic indirect radiance in the closed sphere of radius `R` with the light `I` at its
/// centre: every point receives `E0 = I/R²` directly, each bounce scales the irradiance by `ρ`,
/// so the indirect irradiance is `ρ/(1-ρ) · E0` and the radiance `ρ/π · ρ/(1-ρ) · I/R²`.
fn analytic_indirect_radiance(albedo: f32) -> f64 {
    let e0 = 1.0 / 4.0;
    let rho = albedo as f64;
    rho / std::f64::consts::PI * rho / (1.0 - rho) * e0
}

#[test]
fn closed_sphere_matches_the_analytic_value_within_the_stated_noise() {
    for albedo in [0.5f32, 0.8] {
        let r = render_sphere(albedo, 64, 1);
        let n = r.indirect.pixels.len() as f64;
        let expected = analytic_indirect_radiance(albedo);
        // Direct: exact, rho/pi * I/R^2 everywhere.
        let d = albedo as f64 / std::f64::consts::PI * 0.25;
        for p in &r.direct.pixels {
            assert!((p[0] as f64 / d - 1.0).abs() < 1e-4, "{p:?} vs {d}");
        }
        // No edge in the image: the box filter adds no noise to the direct light.
        assert!(r.direct_noise.relative < 1e-5, "{:?}", r.direct_noise);
        // Every pixel hits the wall; the image mean is within 4 standard errors (the noise
        // of one pixel over sqrt(N)) of the analytic value.
        let lum: Vec<f64> = r
            .indirect
            .pixels
            .iter()
            .map(|p| mlt_view::images::luminance(*p) as f64)
            .collect();
        let mean = lum.iter().sum::<f64>() / n;
        let sigma = r.indirect_noise.rms;
        assert!(sigma > 0.0);
        assert!(
            (mean - expected).abs() < 4.0 * sigma / n.sqrt(),
            "albedo {albedo}: mean {mean} vs analytic {expected}, noise {sigma}"
        );
        // The actual per-pixel error against the analytic value has the RMS that the two
        // halves' difference predicts (384 pixels: the ratio is within ~4 % of 1 by chance).
        let rms = (lum.iter().map(|l| (l - expected).powi(2)).sum::<f64>() / n).sqrt();
        let ratio = rms / sigma;
        assert!(
            (0.8..1.25).contains(&ratio),
            "albedo {albedo}: true error RMS {rms} vs half-difference noise {sigma}"
        );
        // Final = direct + indirect, same noise (the direct is uniform: no edge in the image).
        assert!(
            (r.final_noise.rms - sigma).abs() < 1e-4 * sigma,
            "{:?}",
            r.final_noise
        );
        assert!((r.indirect_noise.relative - sigma / mean).abs() < 1e-6);
    }
}

#[test]
fn noise_falls_as_one_over_root_spp_and_seeds_give_independent_images() {
    let a = render_sphere(0.5, 16, 1);
    let b = render_sphere(0.5, 64, 1);
    let ratio = a.indirect_noise.rms / b.indirect_noise.rms;
    // 4x the paths: half the noise.
    assert!((1.7..2.35).contains(&ratio), "{ratio}");
    let c = render_sphere(0.5, 16, 2);
    assert_ne!(a.indirect, c.indirect);
    // Two seeds' images differ by about sqrt(2) times the noise of one.
    let n = a.indirect.pixels.len() as f64;
    let d = (a
        .indirect
        .pixels
        .iter()
        .zip(&c.indirect.pixels)
        .map(|(p, q)| {
            let x = mlt_view::images::luminance(*p) as f64 - mlt_view::images::luminance(*q) as f64;
            x * x
        })
        .sum::<f64>()
        / n)
        .sqrt();
    let expected = (a.indirect_noise.rms.powi(2) + c.indirect_noise.rms.powi(2)).sqrt();
    assert!((0.8..1.25).contains(&(d / expected)), "{d} vs {expected}");
}

#[test]
fn images_are_bit_identical_for_any_thread_count() {
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render_sphere(0.7, 8, 5))
    };
    let (one, three) = (run(1), run(3));
    assert_eq!(one.indirect, three.indirect);
    assert_eq!(one.noise_image, three.noise_image);
    assert_eq!(one.final_image, three.final_image);
}

#[test]
fn probes_match_the_analytic_value_within_their_standard_error() {
    let caster = sphere(0.8);
    let light = Light::point(Vec3::ZERO, [1.0, 1.0, 1.0]).unwrap();
    let probes: Vec<Probe> = [Vec3::X, -Vec3::Y, Vec3::new(0.3, 0.5, -0.8).normalize()]
        .into_iter()
        .map(|d| Probe {
            position: d * 2.0,
            normal: -d,
        })
        .collect();
    let opts = ReferenceOptions::new(4000, 3);
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| reference_probes(caster.as_ref(), &light, &probes, &opts).unwrap())
    };
    let v = run(2);
    assert_eq!(v, run(1));
    let expected = 0.8 / 0.2 * 0.25;
    for p in &v {
        assert!((p.direct[0] - 0.25).abs() < 1e-5);
        let se = p.std_error[0] as f64;
        assert!(se > 0.0 && se < 0.05 * expected, "{se}");
        assert!(
            (p.indirect[0] as f64 - expected).abs() < 4.0 * se,
            "{:?} vs {expected} (se {se})",
            p.indirect
        );
        // The two halves average to the whole.
        let avg = 0.5 * (p.halves[0][0] + p.halves[1][0]);
        assert!((avg - p.indirect[0]).abs() < 1e-5 * expected as f32);
    }
    // An odd sample count is refused.
    assert!(reference_probes(
        caster.as_ref(),
        &light,
        &probes,
        &ReferenceOptions::new(5, 0)
    )
    .is_err());
}

#[test]
fn a_light_near_the_wall_gives_the_same_uniform_indirect_light() {
    // In a sphere every surface element sees every other with the same form factor
    // dA / (4 pi R^2), so E_i = rho/(1-rho) Phi/(4 pi R^2) wherever the light is inside it.
    // With the light 0.1 from the wall (a bright spot of 100x the centre's irradiance), this
    // checks the light-sampled half of the estimator.
    let caster = sphere(0.5);
    let light = Light::point(Vec3::new(0.0, 1.9, 0.0), [1.0, 1.0, 1.0]).unwrap();
    let expected = 0.5 / 0.5 * 0.25;
    let probes: Vec<Probe> = [
        Vec3::X,
        -Vec3::Y,
        Vec3::new(0.3, 0.9, -0.3).normalize(),
        Vec3::new(-0.6, -0.2, 0.77).normalize(),
    ]
    .into_iter()
    .map(|d| Probe {
        position: d * 2.0,
        normal: -d,
    })
    .collect();
    let v = reference_probes(
        caster.as_ref(),
        &light,
        &probes,
        &ReferenceOptions::new(4000, 9),
    )
    .unwrap();
    for p in &v {
        let se = p.std_error[1] as f64;
        assert!(se > 0.0 && se < 0.05 * expected, "{se}");
        assert!(
            (p.indirect[1] as f64 - expected).abs() < 4.0 * se,
            "{:?} vs {expected} (se {se})",
            p.indirect
        );
    }
}

fn scaled(img: &RgbImage, k: f32) -> RgbImage {
    RgbImage {
        width: img.width,
        height: img.height,
        pixels: img.pixels.iter().map(|p| p.map(|v| v * k)).collect(),
    }
}

#[test]
fn compare_reports_zero_for_identical_dirs_and_the_scale_of_a_scaled_image() {
    // The Cornell box: a real mesh, shadows and colour (also checks the tracer on a BVH).
    let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
    let caster = scene.build_caster();
    let camera = scene_camera(&scene, 20, 20);
    let light = Light::point(scene.light.position.into(), scene.light.intensity).unwrap();
    let r = render_reference(caster.as_ref(), &camera, &light, 8, 1).unwrap();
    assert!(r.indirect.all_finite() && r.final_image.all_finite());
    assert!(r.indirect_noise.mean > 0.0 && r.indirect_noise.relative > 0.0);
    let dir = temp("cmp");
    let (ref_dir, test_dir) = (dir.join("ref"), dir.join("test"));
    write_reference(&ref_dir, &r).unwrap();
    for f in mlt_view::reference::REFERENCE_FILES {
        assert!(ref_dir.join(f).is_file(), "{f}");
    }
    let same = compare_dirs(&ref_dir, &ref_dir).unwrap();
    for m in [same.indirect, same.final_image] {
        assert_eq!(m.relative_rmse, 0.0);
        assert_eq!(m.mean_relative_error_lit, 0.0);
        assert_eq!(m.ratio_of_means, 1.0);
        assert!(m.lit > 0 && m.noise_relative_rmse.unwrap() > 0.0);
    }
    assert!(same.reference_noise.is_some());

    std::fs::create_dir_all(&test_dir).unwrap();
    scaled(&r.indirect, 1.25)
        .write_exr(&test_dir.join("indirect.exr"))
        .unwrap();
    scaled(&r.final_image, 0.5)
        .write_exr(&test_dir.join("final.exr"))
        .unwrap();
    let s = compare_dirs(&ref_dir, &test_dir).unwrap();
    assert!((s.indirect.ratio_of_means - 1.25).abs() < 1e-5);
    assert!((s.indirect.mean_relative_error_lit - 0.25).abs() < 1e-5);
    assert!((s.final_image.ratio_of_means - 0.5).abs() < 1e-5);
    assert!((s.final_image.mean_relative_error_lit - 0.5).abs() < 1e-5);
    // rel. RMSE of a scaled image: |k - 1| RMS(L) / mean(L) >= |k - 1|.
    assert!(s.final_image.relative_rmse >= 0.5 - 1e-6);

    // The binary: text and JSON, and errors that name the file.
    let exe = env!("CARGO_BIN_EXE_view");
    let compare = |options: &[&str]| {
        Command::new(exe)
            .arg("compare")
            .args([&ref_dir, &test_dir])
            .args(options)
            .output()
            .unwrap()
    };
    let out = compare(&["--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!((v["indirect"]["ratio_of_means"].as_f64().unwrap() - 1.25).abs() < 1e-5);
    assert!(v.get("indirect_breakdown").is_none());
    // The breakdown of a uniformly scaled image: every lit part 1.25, the parts' excesses
    // adding up to the whole image's.
    let out = compare(&["--json", "--breakdown", "2x2"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let b = &v["indirect_breakdown"];
    for (key, count) in [("tiles", 4), ("brightness", 5)] {
        let parts = b[key].as_array().unwrap();
        assert_eq!(parts.len(), count, "{key}");
        let pixels: u64 = parts.iter().map(|p| p["pixels"].as_u64().unwrap()).sum();
        assert_eq!(pixels, 400, "{key}");
        let excess: f64 = parts
            .iter()
            .map(|p| p["excess_of_total"].as_f64().unwrap())
            .sum();
        assert!((excess - 0.25).abs() < 1e-5, "{key}: {excess}");
        for p in parts
            .iter()
            .filter(|p| p["share_of_reference"].as_f64().unwrap() > 0.0)
        {
            assert!(
                (p["ratio_of_means"].as_f64().unwrap() - 1.25).abs() < 1e-5,
                "{p}"
            );
        }
    }
    let out = compare(&["--breakdown", "3x0"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("3x0"));
    std::fs::remove_file(test_dir.join("final.exr")).unwrap();
    let out = compare(&[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    // The final image falls back to reference_final.exr, which is not there either.
    assert!(
        err.contains("final.exr") && err.contains("missing"),
        "{err}"
    );

    // Size mismatch and NaN are named.
    RgbImage::new(3, 2)
        .write_exr(&test_dir.join("final.exr"))
        .unwrap();
    let e = compare_dirs(&ref_dir, &test_dir).unwrap_err();
    assert!(matches!(e, CompareError::Size { .. }), "{e}");
    assert!(
        e.to_string().contains("3x2") && e.to_string().contains("final.exr"),
        "{e}"
    );
    let mut nan = r.final_image.clone();
    nan.pixels[7] = [f32::NAN, 0.0, 0.0];
    nan.write_exr(&test_dir.join("final.exr")).unwrap();
    let e = compare_dirs(&ref_dir, &test_dir).unwrap_err().to_string();
    assert!(
        e.contains("final.exr") && e.contains("(7, 0)") && e.contains("not finite"),
        "{e}"
    );
}

/// `view reference SCENE`: the scene's camera and light with the command line's overrides, the
/// same images as the library renders for them; no output asked for is an error.
#[test]
fn reference_cli_renders_the_scene_with_its_overrides() {
    let dir = temp("cli");
    let out = dir.join("out");
    let exe = env!("CARGO_BIN_EXE_view");
    let r = Command::new(exe)
        .args([
            "reference",
            "builtin:cornell",
            "--spp",
            "4",
            "--width",
            "12",
        ])
        .args(["--height", "10", "--light-pos", "0.3,0.45,0.3", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
    let camera = scene_camera(&scene, 12, 10);
    let light = Light::point(Vec3::new(0.3, 0.45, 0.3), scene.light.intensity).unwrap();
    let lib = render_reference(scene.build_caster().as_ref(), &camera, &light, 4, 1).unwrap();
    let cli = RgbImage::read_exr(&out.join("reference_final.exr")).unwrap();
    assert_eq!((cli.width, cli.height), (12, 10));
    assert_eq!(cli.pixels, lib.final_image.pixels);

    let r = Command::new(exe)
        .args(["reference", "builtin:cornell"])
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("nothing to do"));
}

fn write(path: &Path, s: &str) {
    std::fs::write(path, s).unwrap();
}

#[test]
fn probe_csvs_compare_row_by_row() {
    let caster = sphere(0.5);
    let light = Light::point(Vec3::ZERO, [1.0, 1.0, 1.0]).unwrap();
    let probes: Vec<Probe> = [Vec3::X, Vec3::Y, Vec3::Z]
        .into_iter()
        .map(|d| Probe {
            position: d * 2.0,
            normal: -d,
        })
        .collect();
    let v = reference_probes(
        caster.as_ref(),
        &light,
        &probes,
        &ReferenceOptions::new(64, 1),
    )
    .unwrap();
    let dir = temp("probes");
    let rp = dir.join("ref.csv");
    write(&rp, &probes_to_csv(&probes, &v));
    // A test CSV in `view probe --probe-out`'s layout, indirect 1.1x the reference's; `shift` moves
    // the second probe.
    let test_csv = |shift: f32| {
        let mut t = String::from("x,y,z,nx,ny,nz,direct_r,direct_g,direct_b,direct_basis_r,direct_basis_g,direct_basis_b,indirect_r,indirect_g,indirect_b\n");
        for (k, (p, r)) in probes.iter().zip(&v).enumerate() {
            let i = r.indirect.map(|c| c * 1.1);
            let x = p.position + Vec3::X * if k == 1 { shift } else { 0.0 };
            t.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},0,0,0,{},{},{}\n",
                x.x,
                x.y,
                x.z,
                p.normal.x,
                p.normal.y,
                p.normal.z,
                r.direct[0],
                r.direct[1],
                r.direct[2],
                i[0],
                i[1],
                i[2]
            ));
        }
        t
    };
    let t = test_csv(0.0);
    let tp = dir.join("test.csv");
    write(&tp, &t);
    let c = compare_probe_csv(&rp, &tp).unwrap();
    assert!((c.indirect.ratio_of_means - 1.1).abs() < 1e-5);
    assert!((c.indirect.mean_relative_error_lit - 0.1).abs() < 1e-5);
    assert!(c.final_image.ratio_of_means > 1.0 && c.final_image.ratio_of_means < 1.1);
    assert!(c.indirect.noise_relative_rmse.unwrap() > 0.0);
    let same = compare_probe_csv(&rp, &rp).unwrap();
    assert_eq!(same.indirect.relative_rmse, 0.0);
    // Probes at other points are refused, naming the probe.
    write(&tp, &test_csv(0.5));
    let e = compare_probe_csv(&rp, &tp).unwrap_err().to_string();
    assert!(e.contains("test.csv") && e.contains("probe 2"), "{e}");
}
