//! Scale invariance and extreme inputs, through bake and probes.

use glam::Vec3;
use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::{BakeContents, BakedFile, WriteOptions};
use mlt_view::probe::{evaluate, Probe};
use mlt_view::{CpuRelighter, Light, Relight};

fn bake(spec: &str, opts: &BakeOptions) -> BakeContents {
    let scene = mlt_scenes::load_scene(spec).unwrap();
    bake_scene(&scene, opts, &Silent)
        .unwrap_or_else(|e| panic!("{spec}: {e}"))
        .contents
}

/// Direct and indirect irradiance at `probes` for a point light at `light`.
fn probe_values(
    spec: &str,
    contents: &BakeContents,
    light: Light,
    probes: &[Probe],
) -> Vec<[[f32; 3]; 3]> {
    let bytes = mlt_format::file::encode(contents, WriteOptions::default()).unwrap();
    let file = BakedFile::from_bytes(std::path::Path::new("x.mlt"), &bytes).unwrap();
    let ib = file.basis().unwrap();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let caster = scene.build_caster();
    let m = file.transport_meta().unwrap().unwrap().params.sender_levels as usize;
    let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), m, 4).expect("relighting operators");
    let frame = r.relight(&light).clone();
    probes
        .iter()
        .map(|p| evaluate(&ib, caster.as_ref(), &light, &frame, m, p))
        .collect()
}

fn small() -> BakeOptions {
    BakeOptions {
        receiver_levels: Some(3),
        coarse_count: Some(40),
        gather_rays: Some(64),
        sender_levels: Some(2),
        ..Default::default()
    }
}

/// Bakes the Cornell box at each scale and returns, per scale, the points per level and the
/// probe values (direct, direct from the basis, indirect) at the same relative places.
/// Per probe: direct, direct from the basis, indirect (RGB each).
type ProbeValues = Vec<[[f32; 3]; 3]>;

fn cornell_at_scales(scales: &[f32], opts: &BakeOptions) -> Vec<(f32, Vec<u64>, ProbeValues)> {
    // Probes on the floor and back wall of the Cornell box (coordinates at scale 1, metres).
    let unit: Vec<(Vec3, Vec3)> = (0..12)
        .map(|k| {
            let t = 0.08 + 0.035 * k as f32;
            if k % 2 == 0 {
                (Vec3::new(t, 0.0, 0.3), Vec3::Y)
            } else {
                (Vec3::new(t, 0.25, 0.559), -Vec3::Z)
            }
        })
        .collect();
    let light_at = Vec3::new(0.278, 0.45, 0.28);
    let mut results = Vec::new();
    for &s in scales {
        let spec = format!("builtin:cornell?scale={s}");
        let contents = bake(&spec, opts);
        let probes: Vec<Probe> = unit
            .iter()
            .map(|(x, n)| Probe {
                position: *x * s,
                normal: *n,
            })
            .collect();
        // Intensity times s^2 keeps irradiance (I / d^2) the same at every scale.
        let light = Light::point(light_at * s, [s * s; 3]).unwrap();
        let v = probe_values(&spec, &contents, light, &probes);
        let counts: Vec<u64> = contents
            .meta
            .stats
            .levels
            .iter()
            .map(|l| l.points)
            .collect();
        results.push((s, counts, v));
    }
    results
}

#[test]
fn scaling_by_powers_of_two_changes_nothing() {
    // 2^-13 ~ 1.2e-4 and 2^13 ~ 8.2e3 scale every coordinate exactly, so a bake with no
    // absolute distance anywhere gives the same basis and the same light.
    let results = cornell_at_scales(&[2f32.powi(-13), 1.0, 2f32.powi(13)], &small());
    let (_, ref_counts, ref_v) = &results[1];
    for (s, counts, v) in &results {
        assert_eq!(counts, ref_counts, "scale {s}");
        for (a, b) in v.iter().zip(ref_v) {
            for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
                assert!(
                    (x - y).abs() <= 1e-4 * y.abs().max(1e-3),
                    "scale {s}: {x} vs {y}"
                );
            }
        }
    }
}

#[test]
fn the_same_scene_at_scale_1e_minus_4_and_1e4_gives_the_same_light() {
    // Decimal scales round differently, so darts may fall differently: the exact direct
    // light agrees closely, the basis' reconstructions within their approximation error.
    // The level-0 bounces chained: traced ones vary more with where the darts fell at these
    // coarse settings (indirect means 4.05-4.54 over the three scales, against 4.10-4.31
    // chained); their exact scale invariance is the power-of-two test's, which traces them.
    let chained = BakeOptions {
        level0_paths: Some(0),
        ..small()
    };
    let results = cornell_at_scales(&[1e-4, 1.0, 1e4], &chained);
    let (_, ref_counts, ref_v) = &results[1];
    let mean = |v: &[[[f32; 3]; 3]], kind: usize| {
        v.iter()
            .map(|p| p[kind].iter().sum::<f32>() as f64)
            .sum::<f64>()
            / (3 * v.len()) as f64
    };
    for (s, counts, v) in &results {
        eprintln!(
            "scale {s}: points per level {counts:?}; mean direct {:.4}, from the basis {:.4}, indirect {:.4}",
            mean(v, 0),
            mean(v, 1),
            mean(v, 2)
        );
        for (a, b) in v.iter().zip(ref_v) {
            for (x, y) in a[0].iter().zip(&b[0]) {
                assert!(
                    (x - y).abs() <= 1e-3 * y.abs().max(0.05),
                    "scale {s}: direct {x} vs {y}"
                );
            }
            assert!(a.iter().flatten().all(|x| x.is_finite()));
        }
        // A basis placed a little differently (a dart rounds the other way) reconstructs
        // single probes differently, by up to about 15 % at these coarse settings, and their
        // mean by up to about 6 %. The exact invariance is the power-of-two test's.
        for kind in 1..3 {
            let (x, y) = (mean(v, kind), mean(ref_v, kind));
            assert!(
                (x - y).abs() <= 0.1 * y.abs(),
                "scale {s}: mean of kind {kind}: {x} vs {y}"
            );
        }
        // Dart throwing that stops after 2000 misses varies by this much between random
        // orders, as between seeds.
        for (a, b) in counts.iter().zip(ref_counts) {
            assert!(
                (*a as f64 - *b as f64).abs() <= 0.2 * *b as f64,
                "scale {s}: {counts:?} vs {ref_counts:?}"
            );
        }
    }
}

#[test]
fn one_triangle_bakes_to_no_transport_and_no_nan() {
    let spec = "builtin:triangle";
    let contents = bake(spec, &small());
    let t = contents.transport.as_ref().unwrap();
    // A single flat triangle cannot light itself.
    assert_eq!(t.links.link_count(), 0);
    let probes = [Probe {
        position: Vec3::new(0.1, 0.0, 0.1),
        normal: Vec3::Y,
    }];
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let (lo, hi) = scene.build_caster().bounds();
    let light = Light::point((lo + hi) * 0.5 + Vec3::Y, [1.0; 3]).unwrap();
    for v in probe_values(spec, &contents, light, &probes) {
        assert_eq!(v[2], [0.0; 3]);
        assert!(v.iter().flatten().all(|x| x.is_finite()));
    }
}

#[test]
fn lights_on_a_surface_or_aimed_at_nothing_give_finite_light() {
    let spec = "builtin:box?albedo=0.5";
    let contents = bake(spec, &small());
    let probes: Vec<Probe> = (0..8)
        .map(|k| Probe {
            position: Vec3::new(-0.4 + 0.1 * k as f32, -0.5, 0.1),
            normal: Vec3::Y,
        })
        .collect();
    // On the floor, exactly at a probe; outside the box; a spot aimed out of the box's wall.
    let lights = [
        Light::point(Vec3::new(-0.4, -0.5, 0.1), [1.0; 3]).unwrap(),
        Light::point(Vec3::new(3.0, 0.0, 0.0), [1.0; 3]).unwrap(),
        Light::spot(Vec3::ZERO, [1.0; 3], Vec3::new(0.0, 0.0, 1.0), 1.0, false).unwrap(),
    ];
    for light in lights {
        for v in probe_values(spec, &contents, light, &probes) {
            assert!(
                v.iter().flatten().all(|x| x.is_finite() && *x >= -1e-3),
                "{v:?}"
            );
        }
    }
    // The light outside the closed box reaches nothing inside.
    let outside = probe_values(spec, &contents, lights[1], &probes);
    assert!(outside
        .iter()
        .all(|v| v[0] == [0.0; 3] && v[2].iter().all(|x| x.abs() < 1e-6)));
}

#[test]
fn an_empty_scene_is_refused_with_the_file_named() {
    let d = mlt_test_support::TempDir::new("empty");
    let f = d.join("empty.obj");
    std::fs::write(&f, "# nothing\nv 0 0 0\n").unwrap();
    let e = mlt_scenes::load_scene(&f.display().to_string())
        .unwrap_err()
        .to_string();
    assert!(e.contains("empty.obj"), "{e}");
}
