//! Load-time and per-frame figures of the CPU relighter on a baked file: what building its
//! operators costs, the median time of each stage over frames with a moving light, and the
//! reference stages (R-tree queries per frame, sender-major half-float links) for comparison.
//!
//! `cargo bench -p mlt-relight --bench relight_figures`. The file is `MLT_RELIGHT_FILE` (else a
//! small Cornell box baked into a temporary directory), its scene `MLT_RELIGHT_SCENE` (default:
//! the one the file names); `MLT_RELIGHT_FRAMES` (default 20) frames for the medians printed
//! first. Then divan times whole frames.

mod common;

use std::sync::{Mutex, OnceLock};
use std::time::Instant;

use anyhow::Context;
use common::Baked;
use glam::Vec3;
use mlt_format::flatten::flatten;
use mlt_format::links::LINK_DIM;
use mlt_format::pull_push::pull_push_levels;
use mlt_relight::{CpuRelighter, Light, Relight};
use mlt_scenes::RayCaster;

/// The relighter and the lights of a circle of frames.
struct Setup {
    baked: &'static Baked,
    relighter: Mutex<CpuRelighter<'static>>,
    sender_levels: usize,
    /// The file's light moved around a circle, one position per frame.
    lights: Vec<Light>,
}

static SETUP: OnceLock<Setup> = OnceLock::new();

fn load(frames: usize) -> anyhow::Result<Setup> {
    let baked: &'static Baked = Box::leak(Box::new(Baked::open_or_bake("MLT_RELIGHT_FILE")?));
    let meta = baked.file.meta()?;
    let tm = baked
        .file
        .transport_meta()?
        .context("the file holds no transport")?;
    let spec = std::env::var("MLT_RELIGHT_SCENE").unwrap_or(meta.scene.source.clone());
    let scene = mlt_scenes::load_scene(&spec).with_context(|| format!("loading {spec}"))?;
    let caster: &'static dyn RayCaster = Box::leak(scene.build_caster());
    let light = Light::from_info(&meta.light)?;
    let sender_levels = tm.params.sender_levels as usize;
    let mut relighter = CpuRelighter::new(&baked.ib, baked.links, caster, sender_levels, 8)
        .expect("relighting operators");
    // As the viewer relights this file (its defaults).
    relighter.use_bounce_corrections(&tm, None, None);
    let (lo, hi) = (
        Vec3::from(meta.scene.bounds_min),
        Vec3::from(meta.scene.bounds_max),
    );
    let radius = 0.05 * (hi - lo).length();
    let lights = (0..frames.max(1))
        .map(|f| {
            let a = std::f32::consts::TAU * f as f32 / frames.max(1) as f32;
            let mut l = light;
            l.position = light.position + Vec3::new(radius * a.cos(), 0.0, radius * a.sin());
            l
        })
        .collect();
    Ok(Setup {
        baked,
        relighter: Mutex::new(relighter),
        sender_levels,
        lights,
    })
}

fn main() {
    eprintln!("machine: {}", common::machine());
    let frames: usize = std::env::var("MLT_RELIGHT_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let s = match load(frames) {
        Ok(s) => SETUP.get_or_init(|| s),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    };
    eprintln!("file: {}", s.baked.path.display());
    figures(s);
    divan::main();
    s.baked.clean_up();
}

/// Prints the load figures, the per-stage medians over the frames and two frames of the
/// reference stages.
fn figures(s: &Setup) {
    let ib = &s.baked.ib;
    let mut r = s.relighter.lock().unwrap_or_else(|e| e.into_inner());
    eprintln!("load: {:?}", r.load_stats());
    let mut t: [Vec<f64>; 5] = Default::default();
    let mut live = Vec::new();
    for light in &s.lights {
        let frame = r.relight(light);
        t[0].push(frame.times.direct_ms);
        t[1].push(frame.times.project_ms);
        t[2].push(frame.times.transport_ms);
        t[3].push(frame.times.feedback_ms);
        t[4].push(frame.times.flatten_ms);
        live.push(
            frame
                .i
                .chunks(LINK_DIM)
                .filter(|c| c.iter().any(|&v| v != 0.0))
                .count(),
        );
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    let m: Vec<f64> = t.iter_mut().map(med).collect();
    eprintln!(
        "median over {} frames: direct {:.2} ms, pull-push {:.3} ms, S e {:.2} ms, bounce \
         feedback {:.2} ms, flatten {:.2} ms, total {:.2} ms; lit receivers {:?}",
        s.lights.len(),
        m[0],
        m[1],
        m[2],
        m[3],
        m[4],
        m.iter().sum::<f64>(),
        live.iter().min()
    );
    let light = s.lights[s.lights.len() - 1];
    for _ in 0..2 {
        let samples = r.direct(&light);
        let t0 = Instant::now();
        let (e, _) = pull_push_levels(ib, &samples, 3, s.sender_levels);
        let t1 = Instant::now();
        let mut i = vec![0.0f32; ib.basis.len() * LINK_DIM];
        s.baked.links.apply(&e, 0.0, &mut i);
        let t2 = Instant::now();
        let flat = flatten(ib, &i, LINK_DIM);
        let t3 = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        eprintln!(
            "reference stages: pull-push {:.2} ms, S e (f16, sender-major) {:.2} ms, flatten \
             {:.1} ms ({} values)",
            ms(t0, t1),
            ms(t1, t2),
            ms(t2, t3),
            flat.len()
        );
    }
}

/// One relit frame, the light moving on its circle (so that no frame is reused).
#[divan::bench]
fn relight_frame(bencher: divan::Bencher) {
    let s = SETUP.get().expect("the set-up is loaded in main");
    let mut r = s.relighter.lock().unwrap_or_else(|e| e.into_inner());
    let mut f = 0;
    bencher.bench_local(|| {
        f = (f + 1) % s.lights.len();
        r.relight(&s.lights[f]).senders_used
    });
}
