//! CPU relighting and probes against known answers.

mod common;

use std::process::Command;

use common::bake_to;
use glam::Vec3;
use mlt_bake::BakeOptions;
use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::LINK_DIM;
use mlt_format::pull_push::pull_push_levels;
use mlt_format::BakedFile;
use mlt_relight::flatten_op::{step_weight, SHARPEN_STEPS};
use mlt_relight::{FineEmission, ReceiverLinks};
use mlt_view::probe::{evaluate, Probe};
use mlt_view::{CpuRelighter, Light, Relight};

fn temp(name: &str) -> common::TempDir {
    common::temp_dir("view", name)
}

/// A small Cornell box bake (4 receiver levels, 40 coarse points) in a fresh directory `name`:
/// the directory, the opened file, its basis and sender level count, and the scene's caster.
fn small_cornell(
    name: &str,
    gather_rays: u32,
) -> (
    common::TempDir,
    BakedFile,
    mlt_format::IndexedBasis,
    usize,
    Box<dyn mlt_scenes::RayCaster>,
) {
    let d = temp(name);
    let f = d.join("cornell.mlt");
    let spec = "builtin:cornell";
    bake_to(&f, spec, common::small_cornell(4, gather_rays, None));
    let file = BakedFile::open(&f).unwrap();
    let ib = file.basis().unwrap();
    let tm = file.transport_meta().unwrap().unwrap();
    let sender_levels = tm.params.sender_levels as usize;
    let caster = mlt_scenes::load_scene(spec).unwrap().build_caster();
    (d, file, ib, sender_levels, caster)
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
    let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), 2, 4).expect("relighting operators");
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
        .arg("probe")
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
        .arg("timings")
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
    // The camera turn reflattens at most once per step, never more rows than the file has.
    let turn = &json["camera_turn"];
    let steps = turn["steps"].as_u64().unwrap();
    assert!(
        turn["steps_reflattened"].as_u64().unwrap() <= steps,
        "{turn}"
    );
    assert!(turn["median_ms"].as_f64().unwrap() >= 0.0, "{turn}");
    assert!(
        turn["median_flat_rows"].as_f64().unwrap() <= json["load"]["flat_points"].as_f64().unwrap(),
        "{turn} {}",
        json["load"]
    );
    std::fs::write(&input, "1,2,3,0,0,1\n1,2,3\n").unwrap();
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg("probe")
        .arg(&f)
        .arg("--probe")
        .arg(&input)
        .arg("--probe-out")
        .arg(&output)
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("in.csv:2"));
    // No window without a display: the viewer says so and points to `view render`.
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg(&f)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("view render"));
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// The precomputed operators give what the reference stages give: `e` the same bits as
/// `pull_push_levels` of the ray-cast samples, `i` the same bits as the receiver-major links'
/// `apply` (the stored links' product over sender weights rounded to half-float precision),
/// `flat` close to `FlatBasis::flatten(i)` sharpened by the default steps with `W` the flat
/// basis' own reconstruction at its points (the operators' 16-bit values and dropped values
/// below 1e-3 cost about 1e-3, relative, per product); and the same bits for 1 and 2 threads.
///
/// [`SHARPEN_STEPS`] steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` from `c_0 = c`, `w_k` the
/// step's relaxation weight: `(W c_k)_j` the flat expansion of `c_k` at flat point `j`.
fn sharpened(fb: &FlatBasis, c: &[f32]) -> Vec<f32> {
    let b = &fb.ib.basis;
    let mut ck = c.to_vec();
    for step in 0..SHARPEN_STEPS {
        let w = step_weight(step);
        let mut next = vec![0.0f32; c.len()];
        for (j, o) in next.chunks_mut(LINK_DIM).enumerate() {
            fb.reconstruct(&ck, LINK_DIM, b.positions[j], b.normals[j], o);
            for (d, v) in o.iter_mut().enumerate() {
                let k = j * LINK_DIM + d;
                *v = ck[k] + w * (c[k] - *v);
            }
        }
        ck = next;
    }
    ck
}

/// `f` run on a rayon pool of `threads` threads.
fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn precomputed_stages_match_the_reference_stages() {
    let (_d, file, ib, sender_levels, caster) = small_cornell("stages", 64);
    assert!(sender_levels >= 2, "{sender_levels}");
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let light = Light::point(Vec3::new(0.278, 0.5, 0.28), [0.3, 0.25, 0.2]).unwrap();

    let run = |threads: usize| {
        with_threads(threads, || {
            let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4)
                .expect("relighting operators");
            let samples = r.direct(&light);
            let stats = *r.load_stats();
            (
                r.relight(&light).clone(),
                samples,
                stats,
                r.flat_basis().clone(),
            )
        })
    };
    let (frame, samples, stats, fb) = run(2);
    assert!(stats.flatten_entries > 0 && stats.flatten_bytes >= 4 * stats.flatten_entries);
    // The flat basis stores its points in Morton order, so the product needs no reordering;
    // the bake stores each level's points so too.
    assert!(stats.points_in_morton_order);
    for l in 0..ib.levels() {
        let order = mlt_format::morton::morton_order(&ib.basis.positions[ib.basis.level_range(l)]);
        assert!(order.iter().enumerate().all(|(i, &j)| i == j as usize));
    }
    let senders = ib.basis.level_offsets[sender_levels] as usize;
    assert!(stats.direct_points < senders, "{stats:?}");

    let (e, _) = pull_push_levels(&ib, &samples, 3, sender_levels);
    assert_eq!(bits(&frame.e), bits(&e));
    assert!(frame.e.iter().any(|&v| v != 0.0));
    let max_e = e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
    let used = ReceiverLinks::build(links).apply(&e, 1e-4 * max_e, &mut i);
    assert_eq!(frame.senders_used, used);
    assert_eq!(bits(&frame.i), bits(&i));
    // That is the stored links' product but for the sender weights' rounding to half-float
    // precision (at most 2^-11 of each term).
    let mut exact = vec![0.0f32; i.len()];
    assert_eq!(links.apply(&e, 1e-4 * max_e, &mut exact), used);
    let (num, den) = i
        .iter()
        .zip(&exact)
        .fold((0.0f64, 0.0f64), |(n, d), (a, b)| {
            (n + f64::from(a - b).powi(2), d + f64::from(*b).powi(2))
        });
    assert!(den > 0.0 && num > 0.0, "{num} {den}");
    assert!(
        (num / den).sqrt() <= 2f64.powi(-11),
        "{}",
        (num / den).sqrt()
    );

    let unsharpened = fb.flatten(&ib, &i, LINK_DIM);
    let reference = sharpened(&fb, &unsharpened);
    let scale = reference.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(scale > 0.0);
    assert_eq!(frame.flat.len(), reference.len());
    let diff = frame
        .flat
        .iter()
        .zip(&reference)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        diff <= 1e-2 * scale,
        "flat differs by {diff} (scale {scale})"
    );
    let (num, den) = frame
        .flat
        .iter()
        .zip(&reference)
        .fold((0.0f64, 0.0f64), |(n, d), (a, b)| {
            (n + f64::from(a - b).powi(2), d + f64::from(*b).powi(2))
        });
    let rms = (num / den).sqrt();
    assert!(rms < 2e-3, "flat differs by {rms} (relative rms)");

    let (one, _, _, fb1) = run(1);
    assert!(fb1 == fb);
    assert_eq!(bits(&one.direct), bits(&frame.direct));
    assert_eq!(bits(&one.flat), bits(&frame.flat));
}

/// Adaptive shadow rays (half first, the rest only where they disagree) cast fewer rays and
/// change the direct light only in the penumbra, where they still give fractions.
#[test]
fn adaptive_shadow_rays_only_refine_the_penumbra() {
    let (_d, file, ib, sender_levels, caster) = small_cornell("adaptive", 16);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    // Low and to the side: the blocks cast long shadows with wide penumbrae on the floor.
    let light = Light::point(Vec3::new(0.1, 0.2, 0.3), [0.3, 0.25, 0.2]).unwrap();
    let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 8)
        .expect("relighting operators");
    let (adaptive, adaptive_rays) = r.direct_counted(&light);
    r.adaptive_shadows = false;
    let (full, full_rays) = r.direct_counted(&light);
    assert!(
        adaptive_rays < full_rays * 9 / 10,
        "{adaptive_rays} of {full_rays} rays"
    );
    let (mut fractional, mut changed, mut total, mut moved) = (0, 0, 0.0f64, 0.0f64);
    for (j, (a, b)) in adaptive.chunks(3).zip(full.chunks(3)).enumerate() {
        let (x, n) = (ib.basis.positions[j], ib.basis.normals[j]);
        let unshadowed = light.irradiance(Vec3::from(x), Vec3::from(n))[0];
        if unshadowed <= 0.0 || (a[0] == 0.0 && b[0] == 0.0) {
            continue;
        }
        let (va, vb) = (a[0] / unshadowed, b[0] / unshadowed);
        if va > 0.01 && va < 0.99 {
            fractional += 1;
            // Where the odd rays were cast the result is the full estimate.
            assert!((va - vb).abs() < 1e-5, "{va} {vb}");
        }
        if (va - vb).abs() > 1e-5 {
            changed += 1;
            // Only where the full estimate is itself in the penumbra.
            assert!(vb > 0.0 && vb < 1.0, "{va} {vb}");
        }
        total += f64::from(b[0]);
        moved += f64::from((a[0] - b[0]).abs());
    }
    assert!(fractional > 0, "no penumbra");
    assert!(
        moved < 0.05 * total,
        "{changed} points moved {moved} of {total}"
    );
}

/// With the fine bounces and the bounce-light feedback on (as the viewer relights a file whose
/// bounces ran on the coarsest receivers), the frame's `i` is `S e`, then the fine bounces, then
/// one feedback step, bit for bit as the operators give them one by one; the same bits for 1
/// and 2 threads; the step changes only what it should: the level-0 receivers, and the finer
/// ones only by the fine bounces of that change.
#[test]
fn the_bounce_feedback_step_is_its_operators_in_order_and_thread_independent() {
    use mlt_relight::{BounceFeedbackOp, FineBounceOp, PullPushOp};
    let (_d, file, ib, sender_levels, caster) = small_cornell("feedback", 64);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let tm = file.transport_meta().unwrap().unwrap();
    assert!(FineBounceOp::applies_to(&tm), "{:?}", tm.params);
    let light = Light::point(Vec3::new(0.278, 0.5, 0.28), [0.3, 0.25, 0.2]).unwrap();
    let run = |threads: usize, steps: u32| {
        with_threads(threads, || {
            let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4)
                .expect("relighting operators");
            r.fine_bounces = true;
            // The feedback is built on the level-0 emission (with no step the default would
            // emit from every sender point instead: the next test).
            r.fine_emission = FineEmission::Level0;
            r.bounce_feedback = steps;
            r.relight(&light).clone()
        })
    };
    let frame = run(2, 1);
    assert_eq!(bits(&frame.i), bits(&run(1, 1).i));
    assert_eq!(bits(&frame.flat), bits(&run(1, 1).flat));

    let max_e = frame.e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let threshold = 1e-4 * max_e;
    let s = ReceiverLinks::build(links);
    let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
    s.apply(&frame.e, threshold, &mut i);
    let fine = FineBounceOp::build(&ib, links);
    fine.apply(&mut i);
    let without = i.clone();
    let pp = PullPushOp::build(&ib, sender_levels);
    BounceFeedbackOp::build(&ib, links, sender_levels).apply(
        &s,
        &pp,
        Some(&fine),
        1,
        threshold,
        &mut i,
    );
    assert_eq!(bits(&frame.i), bits(&i));
    assert_eq!(bits(&run(2, 0).i), bits(&without));

    // Level 0 gets the step's light directly; the finer receivers through their links to
    // level-0 senders only.
    let n0 = ib.basis.level_range(0).len() * LINK_DIM;
    let sum = |v: &[f32]| v.iter().map(|&x| f64::from(x)).sum::<f64>();
    assert!(frame.i[..n0] != without[..n0]);
    let added = sum(&frame.i) - sum(&without);
    assert!(added.abs() > 1e-6 * sum(&without).abs(), "{added}");
    let mut finer_only = without.clone();
    finer_only[..n0].copy_from_slice(&frame.i[..n0]);
    let level0: Vec<f32> = (0..n0).map(|k| frame.i[k] - without[k]).collect();
    fine.apply_from(&level0, &mut finer_only);
    let scale = frame.i.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (k, (a, b)) in frame.i.iter().zip(&finer_only).enumerate().skip(n0) {
        assert!((a - b).abs() <= 1e-5 * scale, "{k}: {a} vs {b}");
    }
}

/// With the fine bounces emitted from every sender point (the default without the feedback),
/// the frame's `i` is `S e`, then the finer receivers' rows of `S` applied to the pull-pushed
/// indirect light at the sender points (`BounceFeedbackOp::emission`), bit for bit as the
/// operators give it and the same for 1 and 2 threads: level 0's rows are `S e`'s, the finer
/// receivers change, and the added light is the rows' product of that emission
/// and nothing else (the level-0 emission through level-0 links differs).
#[test]
fn fine_bounces_from_every_sender_point_are_the_finer_rows_of_s_on_the_bounce_emission() {
    use mlt_relight::{BounceFeedbackOp, FineBounceOp, PullPushOp};
    let (_d, file, ib, sender_levels, caster) = small_cornell("senders", 64);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let light = Light::point(Vec3::new(0.278, 0.5, 0.28), [0.3, 0.25, 0.2]).unwrap();
    let run = |threads: usize, emission: FineEmission| {
        with_threads(threads, || {
            let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4)
                .expect("relighting operators");
            r.fine_bounces = true;
            assert_eq!(r.fine_emission, FineEmission::Senders);
            r.fine_emission = emission;
            r.relight(&light).clone()
        })
    };
    let frame = run(2, FineEmission::Senders);
    assert_eq!(bits(&frame.i), bits(&run(1, FineEmission::Senders).i));

    let max_e = frame.e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let s = ReceiverLinks::build(links);
    let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
    s.apply(&frame.e, 1e-4 * max_e, &mut i);
    let plain = i.clone();
    let pp = PullPushOp::build(&ib, sender_levels);
    let y = BounceFeedbackOp::build(&ib, links, sender_levels).emission(&pp, &i);
    let max_y = y.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let n0 = ib.basis.level_range(0).len();
    s.apply_add_from(&y, 1e-4 * max_y, n0, &mut i);
    assert_eq!(bits(&frame.i), bits(&i));

    // Level 0 keeps `S e`; the finer receivers' coefficients change (their rows are Eq. 17
    // differences, so a receiver may gain or lose), and the level-0 way gives other values.
    let m0 = n0 * LINK_DIM;
    assert_eq!(bits(&frame.i[..m0]), bits(&plain[..m0]));
    let changed = (n0..ib.basis.len())
        .filter(|&r| {
            frame.i[r * LINK_DIM..(r + 1) * LINK_DIM] != plain[r * LINK_DIM..(r + 1) * LINK_DIM]
        })
        .count();
    assert!(changed > 0);
    let mut level0 = plain.clone();
    FineBounceOp::build(&ib, links).apply(&mut level0);
    assert_ne!(bits(&level0), bits(&frame.i));
    assert_eq!(bits(&run(1, FineEmission::Level0).i), bits(&level0));
}

/// Relative RMS difference of `a` from `b`.
fn rel_rms(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| f64::from(*y).powi(2)).sum();
    (num / den).sqrt()
}

/// Frame `k` of a light moving 5 mm per frame under the small Cornell box's ceiling.
fn moving_light(k: usize) -> Light {
    let p = Vec3::new(0.25 + 0.005 * k as f32, 0.5, 0.28);
    Light::point(p, [0.3, 0.25, 0.2]).unwrap()
}

/// The largest relative RMS difference of `lagged`'s indirect coefficients from `exact`'s over
/// the moving light's `frames`.
fn worst_lag(
    lagged: &mut CpuRelighter,
    exact: &mut CpuRelighter,
    frames: std::ops::Range<usize>,
) -> f64 {
    frames
        .map(|k| {
            let a = lagged.relight(&moving_light(k)).i.clone();
            rel_rms(&a, &exact.relight(&moving_light(k)).i)
        })
        .fold(0.0, f64::max)
}

#[test]
fn lagged_bounce_feedback_is_one_pass_with_last_frames_correction_and_tracks_the_exact_step() {
    use mlt_relight::{BounceFeedbackOp, FineBounceOp, PullPushOp};
    let (_d, file, ib, sender_levels, caster) = small_cornell("lagged", 64);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let relighter = |lagged: bool| {
        let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4)
            .expect("relighting operators");
        r.fine_bounces = true;
        r.bounce_feedback = 1;
        r.lagged_feedback = lagged;
        r
    };
    let (mut lagged, mut exact) = (relighter(true), relighter(false));
    // The first frame has no previous correction: it is the exact step.
    let first = lagged.relight(&moving_light(0)).clone();
    assert_eq!(bits(&first.i), bits(&exact.relight(&moving_light(0)).i));

    // A later frame is one pass of S with the level-0 rows on e + d(previous i), then the
    // fine bounces: no step of its own.
    let s = ReceiverLinks::build(links);
    let fine = FineBounceOp::build(&ib, links);
    let pp = PullPushOp::build(&ib, sender_levels);
    let d = BounceFeedbackOp::build(&ib, links, sender_levels).correction(&pp, &first.i);
    let second = lagged.relight(&moving_light(1)).clone();
    let max_e = second.e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let e_first: Vec<f32> = second.e.iter().zip(&d).map(|(a, b)| a + b).collect();
    let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
    let m = ib.basis.level_range(0).len();
    s.apply_split(&second.e, &e_first, m, 1e-4 * max_e, &mut i);
    fine.apply(&mut i);
    assert_eq!(bits(&second.i), bits(&i));

    // Over frames of a slowly moving light the lagged frames stay close to the exact step;
    // after a reset the next frame is the exact step again.
    let worst = worst_lag(&mut lagged, &mut exact, 2..8);
    assert!(worst < 0.01, "lagged frames {worst} from the exact step");
    // And the lag matters at all: the last frame differs from the exact one.
    assert!(worst > 0.0);
    // When the light stops, its next frame takes its own correction: a further step of the
    // fixed point, so it is nearer the fixed point (16 exact steps) than the single exact
    // step is, and it is then reused.
    let settled = lagged.relight(&moving_light(7)).i.clone();
    let exact7 = exact.relight(&moving_light(7)).i.clone();
    let fixed = {
        let mut r = relighter(false);
        r.bounce_feedback = 16;
        r.relight(&moving_light(7)).i.clone()
    };
    let (near, one_step) = (rel_rms(&settled, &fixed), rel_rms(&exact7, &fixed));
    assert!(near < 0.5 * one_step, "{near} vs {one_step}");
    assert!(rel_rms(&settled, &exact7) < 5e-3);
    assert!(lagged.relight(&moving_light(7)).reused);
    lagged.reset_lag();
    let a = lagged.relight(&moving_light(20)).i.clone();
    assert_eq!(bits(&a), bits(&exact.relight(&moving_light(20)).i));
}

/// The lag saves a product wherever a part is lagged: with the fine bounces from every sender
/// point (the finer rows' second product) and with the feedback (its own product).
#[test]
fn the_lag_pays_wherever_a_part_is_lagged() {
    let (_d, file, ib, sender_levels, caster) = small_cornell("lag_pays", 16);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4).unwrap();
    r.fine_bounces = true;
    // The fine bounces from every sender point, which the finer rows (some of the links)
    // take.
    let m = ib.basis.level_range(0).len();
    let finer = links
        .receiver_ids
        .iter()
        .filter(|r| r.to_native() as usize >= m)
        .count();
    assert!(finer > 0 && finer < links.link_count());
    assert!(r.lag_pays());
    // Nothing lagged: the level-0 emission, or no fine bounces.
    r.fine_emission = FineEmission::Level0;
    assert!(!r.lag_pays());
    r.fine_emission = FineEmission::Senders;
    r.fine_bounces = false;
    assert!(!r.lag_pays());
    // The feedback's lag saves its own product.
    r.bounce_feedback = 1;
    assert!(r.lag_pays());
}

/// With the lag, a file whose fine bounces re-emit from every sender point and take no
/// feedback step (traced level-0 rows) computes one product per frame: the level-0 rows on
/// `e`, the finer rows on `e + y`, `y` the bounce emission of the previous frame's whole `i`.
/// Frame after frame that iterates toward the fixed point `i_fine = T_fine (e + y(i))`: a
/// moving light's frames stay near their lights' fixed points, a light that stops gets a
/// further step (nearer its fixed point than the exact frame is) and is then reused, and a
/// reset gives the exact frame.
#[test]
fn lagged_fine_bounces_share_the_pass_of_s_e_and_iterate_to_the_fixed_point() {
    use mlt_relight::{BounceFeedbackOp, PullPushOp};
    let (_d, file, ib, sender_levels, caster) = small_cornell("lagged_fine", 64);
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let relighter = |lagged: bool| {
        let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4)
            .expect("relighting operators");
        r.fine_bounces = true;
        assert_eq!(r.fine_emission, FineEmission::Senders);
        assert_eq!(r.bounce_feedback, 0);
        r.lagged_feedback = lagged;
        r
    };
    let (mut lagged, mut exact) = (relighter(true), relighter(false));
    let first = lagged.relight(&moving_light(0)).clone();
    assert_eq!(bits(&first.i), bits(&exact.relight(&moving_light(0)).i));

    // The next frame: one pass, the level-0 rows on `e`, the finer rows on `e + y`, `y` the
    // bounce emission of the first frame's `i`; the same bits for 1 and 2 threads.
    let s = ReceiverLinks::build(links);
    let pp = PullPushOp::build(&ib, sender_levels);
    let feedback = BounceFeedbackOp::build(&ib, links, sender_levels);
    let n = ib.basis.len() * LINK_DIM;
    let n0 = ib.basis.level_range(0).len();
    // One step from `i` under emission `e`.
    let step = |e: &[f32], i: &[f32]| {
        let y = feedback.emission(&pp, i);
        let e_sum: Vec<f32> = e.iter().zip(&y).map(|(a, b)| a + b).collect();
        let max_e = e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let mut next = vec![0.0f32; n];
        s.apply_split(&e_sum, e, n0, 1e-4 * max_e, &mut next);
        next
    };
    let second = lagged.relight(&moving_light(1)).clone();
    assert_eq!(bits(&second.i), bits(&step(&second.e, &first.i)));
    let one_thread = with_threads(1, || {
        let mut r = relighter(true);
        r.relight(&moving_light(0));
        r.relight(&moving_light(1)).i.clone()
    });
    assert_eq!(bits(&one_thread), bits(&second.i));

    // The fixed point of light `k` (from its exact frame, 16 steps).
    let fixed_of = |exact: &mut CpuRelighter, k: usize| {
        let f = exact.relight(&moving_light(k)).clone();
        (0..16).fold(f.i.clone(), |i, _| step(&f.e, &i))
    };
    // The steps converge: the fixed point is one of the step.
    let (e7, fixed7) = (
        exact.relight(&moving_light(7)).e.clone(),
        fixed_of(&mut exact, 7),
    );
    assert!(rel_rms(&step(&e7, &fixed7), &fixed7) < 1e-4);
    // A moving light's frames stay near their fixed points, nearer than the exact frames.
    for k in 2..8 {
        let a = lagged.relight(&moving_light(k)).i.clone();
        let fixed = fixed_of(&mut exact, k);
        let ex = exact.relight(&moving_light(k)).i.clone();
        let (near, one_pass) = (rel_rms(&a, &fixed), rel_rms(&ex, &fixed));
        assert!(
            near < 0.01 && near < 0.5 * one_pass,
            "frame {k}: {near} vs {one_pass}"
        );
    }
    // The light stops: its next frame is a further step, nearer its fixed point than the
    // exact frame, and is then reused.
    let settled = lagged.relight(&moving_light(7)).i.clone();
    let exact7 = exact.relight(&moving_light(7)).i.clone();
    let (near, one_pass) = (rel_rms(&settled, &fixed7), rel_rms(&exact7, &fixed7));
    assert!(near < 0.2 * one_pass, "{near} vs {one_pass}");
    assert!(lagged.relight(&moving_light(7)).reused);
    // Turning the flattening off forces the next frame to be computed; its lagged part is
    // this light's own, so it is settled (a further step): the one after is reused.
    lagged.set_flatten_on_cpu(false);
    let again = lagged.relight(&moving_light(7));
    assert!(!again.reused);
    assert!(rel_rms(&again.i, &fixed7) <= near);
    assert!(again.flat.is_empty());
    assert!(lagged.relight(&moving_light(7)).reused);
    lagged.set_flatten_on_cpu(true);
    lagged.relight(&moving_light(9));
    lagged.reset_lag();
    let a = lagged.relight(&moving_light(20)).i.clone();
    assert_eq!(bits(&a), bits(&exact.relight(&moving_light(20)).i));
}

/// With a view, the flat coefficients of every flat point whose function may meet it are the
/// same bits as without one, for fewer rows computed; a view that needs rows the light's
/// frame lacks has them computed without relighting, and a view it holds reuses the frame.
#[test]
fn a_view_flattens_only_what_it_needs_and_the_same_bits() {
    // Enough flat points for a narrow view to leave most blocks out.
    let d = temp("view");
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", common::small_cornell(6, 16, None));
    let file = BakedFile::open(&f).unwrap();
    let ib = file.basis().unwrap();
    let sender_levels = file.transport_meta().unwrap().unwrap().params.sender_levels as usize;
    let caster = mlt_scenes::load_scene("builtin:cornell")
        .unwrap()
        .build_caster();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let meta = file.meta().unwrap();
    let light = Light::point(Vec3::new(0.278, 0.5, 0.28), [0.3, 0.25, 0.2]).unwrap();
    let mut whole = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4).unwrap();
    let all = whole.relight(&light).clone();
    let points = whole.flat_basis().len();
    assert_eq!(all.flat_rows, points);
    let (lo, hi) = (
        Vec3::from(meta.scene.bounds_min),
        Vec3::from(meta.scene.bounds_max),
    );
    let file_camera = mlt_view::Camera::from_info(&meta.camera).unwrap();
    // The file's camera narrowed to a fifth of its field of view, turned toward two corners.
    let view_of = |target: Vec3| {
        let mut c = file_camera;
        c.fovy_deg /= 5.0;
        c.target = target;
        mlt_view::Frustum::from_view_proj(&c.reversed_view_proj(c.planes_for_bounds(lo, hi)))
    };
    let left = view_of(Vec3::new(lo.x, hi.y, hi.z));
    let right = view_of(Vec3::new(hi.x, lo.y, hi.z));
    let fb = whole.flat_basis().clone();
    let b = &fb.ib.basis;
    let seen = |f: &mlt_view::Frustum| -> Vec<usize> {
        (0..points)
            .filter(|&j| f.meets_sphere(Vec3::from(b.positions[j]), b.radii[j]))
            .collect()
    };
    let same_where_seen = |frame: &mlt_view::Frame, f: &mlt_view::Frustum| {
        let seen = seen(f);
        assert!(
            !seen.is_empty() && seen.len() < points / 2,
            "{}",
            seen.len()
        );
        for j in seen {
            let (got, want) = (
                &frame.flat[j * LINK_DIM..(j + 1) * LINK_DIM],
                &all.flat[j * LINK_DIM..(j + 1) * LINK_DIM],
            );
            assert_eq!(bits(got), bits(want), "flat point {j}");
        }
    };

    let mut culled = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4).unwrap();
    culled.set_view(Some(&left));
    let frame = culled.relight(&light).clone();
    assert!(!frame.reused);
    // The view's own rows, dilated twice through `W`'s rows for the two sharpening steps.
    assert!(frame.flat_rows < points, "{} of {points}", frame.flat_rows);
    assert!(frame.flat_rows >= seen(&left).len());
    assert_eq!(bits(&frame.i), bits(&all.i));
    same_where_seen(&frame, &left);
    // The same view again: nothing recomputed.
    assert!(culled.relight(&light).reused);
    // Another view, same light: only step 4 runs.
    culled.set_view(Some(&right));
    let frame = culled.relight(&light).clone();
    assert!(!frame.reused && frame.flat_rows > 0);
    assert_eq!(frame.times.direct_ms, 0.0);
    assert_eq!(frame.times.transport_ms, 0.0);
    same_where_seen(&frame, &right);
    // A view overlapping the right one: only the rows it adds are computed.
    let near_right = view_of(Vec3::new(hi.x - 0.15 * (hi.x - lo.x), lo.y, hi.z));
    let alone = {
        let mut r = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4).unwrap();
        r.set_view(Some(&near_right));
        r.relight(&light).flat_rows
    };
    culled.set_view(Some(&near_right));
    let frame = culled.relight(&light).clone();
    assert!(!frame.reused);
    assert!(
        frame.flat_rows > 0 && frame.flat_rows < alone,
        "{} of {alone}",
        frame.flat_rows
    );
    same_where_seen(&frame, &near_right);
    // Back to the left view: what was computed covers it, nothing is recomputed, and its rows
    // are still right.
    culled.set_view(Some(&left));
    let frame = culled.relight(&light).clone();
    assert!(frame.reused);
    same_where_seen(&frame, &left);
    same_where_seen(&frame, &right);
    // No view: every row, as without culling.
    culled.set_view(None);
    let frame = culled.relight(&light).clone();
    assert!(!frame.reused);
    assert_eq!(frame.flat_rows, points);
    assert_eq!(bits(&frame.flat), bits(&all.flat));
    // Culling off: a view changes nothing.
    let mut off = CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, 4).unwrap();
    off.view_culling = false;
    off.set_view(Some(&left));
    let frame = off.relight(&light);
    assert_eq!(frame.flat_rows, points);
    assert_eq!(bits(&frame.flat), bits(&all.flat));
}
