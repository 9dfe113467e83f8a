//! `view timings FILE --frames N`: CPU relighting only (no GPU), N frames with the light
//! moving on a circle, per-stage medians as JSON. The flat coefficients are computed for the
//! file's camera, as the renderer would cull them (`--no-view-culling`: for every flat point);
//! then, under the last light, the camera turns in small steps and the cost of each step
//! (flattening the rows the new view adds) is reported as `camera_turn`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use mlt_view::gpu::{Gpu, GpuRelighter};
use mlt_view::headless::{light_on_path, median};
use mlt_view::Relight;

use crate::cmd::args::{BakedArgs, FlattenOn};
use crate::cmd::load::{with_viewing, Viewing};

/// Times the CPU relighting stages. `--feedback-lag`, advanced elsewhere, is one of its
/// everyday options: `on` times the frame as the window runs it.
#[derive(Args, Debug)]
#[command(mut_arg("feedback_lag", |a| a.hide(false)))]
pub struct TimingsArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    /// Frames to relight, the light moving on a small circle.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub frames: u32,
    /// Write the timings (JSON) here instead of standard output.
    #[arg(long, value_name = "FILE")]
    pub timings_out: Option<PathBuf>,
    /// Where the relighting runs: cpu, or gpu (each stage submitted alone and waited for).
    #[arg(long, value_enum, value_name = "cpu|gpu", hide_possible_values = true,
          default_value_t = FlattenOn::Cpu)]
    pub relight: FlattenOn,
}

pub fn run(args: &TimingsArgs) -> Result<()> {
    if args.relight == FlattenOn::Auto {
        anyhow::bail!("--relight auto: view timings times one of cpu or gpu; name it");
    }
    with_viewing(&args.baked, |mut v| {
        let json = if args.relight == FlattenOn::Gpu {
            gpu_frames(args, &v)?
        } else {
            relight_frames(args, &mut v)
        };
        match &args.timings_out {
            Some(out) => {
                mlt_format::file::write_atomic(out, serde_json::to_string_pretty(&json)?.as_bytes())
                    .with_context(|| format!("writing {}", out.display()))
            }
            None => {
                println!("{}", serde_json::to_string_pretty(&json)?);
                Ok(())
            }
        }
    })
}

/// Degrees the camera turns per step in [`camera_turn`].
const TURN_DEG: f32 = 2.0;

/// What a camera move under a fixed light costs: the light is held until the relighter reuses
/// its frame, then the camera turns about its up vector by [`TURN_DEG`] per step for `steps`
/// steps; each step that needs rows the previous views did not is reflattened for them (with
/// view culling; without it every row was flattened with the light, and a turn costs nothing).
fn camera_turn(v: &mut Viewing<'_>, light: &mlt_view::Light, steps: u32) -> serde_json::Value {
    let (lo, hi) = v.bounds();
    let mut camera = v.camera;
    // Until the light's frame is final (the lagged feedback settles on a held light).
    for _ in 0..4 {
        if v.relighter.relight(light).reused {
            break;
        }
    }
    let (mut ms, mut rows) = (Vec::new(), Vec::new());
    let turn = glam::Quat::from_axis_angle(camera.up.normalize(), TURN_DEG.to_radians());
    for _ in 0..steps.max(1) {
        camera.target = camera.position + turn * (camera.target - camera.position);
        v.relighter
            .set_view(Some(&camera.frustum_for_bounds(lo, hi)));
        let frame = v.relighter.relight(light);
        if !frame.reused {
            ms.push(frame.times.flatten_ms);
            rows.push(frame.flat_rows as f64);
        }
    }
    let reflattened = ms.len();
    serde_json::json!({
        "degrees_per_step": TURN_DEG,
        "steps": steps.max(1),
        "steps_reflattened": reflattened,
        "median_ms": median(ms),
        "median_flat_rows": median(rows),
    })
}

/// [`relight_frames`] with the GPU relighter: the same moving light, each stage timed alone.
/// Every flat point's coefficients are computed (the GPU relighter does not cull to a view).
fn gpu_frames(args: &TimingsArgs, v: &Viewing<'_>) -> Result<serde_json::Value> {
    let gpu = Gpu::headless().context("starting the GPU")?;
    let mut relighter = GpuRelighter::new(&gpu, &v.relighter, None)
        .context("uploading the relighting to the GPU")?;
    relighter.timed = true;
    let n = args.frames.max(1);
    let path_radius = v.path_radius();
    let mut per_stage: [Vec<f64>; 4] = Default::default();
    let mut rays = Vec::new();
    for f in 0..n {
        let l = light_on_path(&v.light, path_radius, f, n);
        let frame = relighter
            .relight_on(&gpu, &l)
            .context("relighting on the GPU")?;
        let t = frame.times;
        for (k, ms) in [t.direct_ms, t.project_ms, t.transport_ms, t.flatten_ms]
            .into_iter()
            .enumerate()
        {
            per_stage[k].push(ms);
        }
        rays.push(frame.shadow_rays as f64);
    }
    let [d, p, s, fl] = per_stage.map(median);
    eprintln!(
        "median per frame over {n} frames with a moving light, relighting on {} ({}): direct {d:.1} ms, pull-push {p:.1} ms, S e with the fine bounces {s:.1} ms, flatten {fl:.1} ms",
        gpu.report.name, gpu.report.backend
    );
    Ok(serde_json::json!({
        "file": v.path.display().to_string(),
        "frames": n,
        "moving_light": true,
        "relight": "gpu",
        "clock": relighter.clock(),
        "direct_on_gpu": relighter.direct_on_gpu(),
        "threads": rayon::current_num_threads(),
        "median_ms": {"direct": d, "project": p, "transport": s, "feedback": 0.0, "flatten": fl, "total": d + p + s + fl},
        "median_shadow_rays_cast": median(rays),
        "fine_bounces": v.relighter.fine_bounces,
        "lagged_feedback": v.relighter.lagged_feedback,
        "flat_rows": relighter.frame_flat_rows(),
        "gpu_bytes": relighter.bytes,
        "adapter": gpu.report,
        "load": v.relighter.load_stats(),
    }))
}

/// Relights the frames and returns the medians as JSON (also summed up on stderr).
fn relight_frames(args: &TimingsArgs, v: &mut Viewing<'_>) -> serde_json::Value {
    let n = args.frames;
    let path_radius = v.path_radius();
    let (lo, hi) = v.bounds();
    let camera = v.camera;
    v.relighter
        .set_view(Some(&camera.frustum_for_bounds(lo, hi)));
    let mut flat_rows = Vec::new();
    let mut per_stage: [Vec<f64>; 5] = Default::default();
    let mut senders = Vec::new();
    let mut rays = Vec::new();
    let mut averaged = Vec::new();
    for f in 0..n.max(1) {
        let l = light_on_path(&v.light, path_radius, f, n.max(1));
        let frame = v.relighter.relight(&l);
        let t = frame.times;
        per_stage[0].push(t.direct_ms);
        per_stage[1].push(t.project_ms);
        per_stage[2].push(t.transport_ms);
        per_stage[3].push(t.feedback_ms);
        per_stage[4].push(t.flatten_ms);
        senders.push(frame.senders_used as f64);
        rays.push(frame.shadow_rays as f64);
        averaged.push(frame.averaged_points as f64);
        flat_rows.push(frame.flat_rows as f64);
    }
    let [d, p, s, fb, fl] = per_stage.map(median);
    let turn = camera_turn(
        v,
        &light_on_path(&v.light, path_radius, n.max(1) - 1, n.max(1)),
        n,
    );
    eprintln!(
        "median per frame over {n} frames with a moving light: direct {d:.1} ms, pull-push {p:.1} ms, S e {s:.1} ms, bounce feedback {fb:.1} ms, flatten {fl:.1} ms"
    );
    serde_json::json!({
        "file": v.path.display().to_string(),
        "frames": n,
        "moving_light": true,
        "shadow_rays": args.baked.relight.shadow_rays,
        "adaptive_shadow_rays": !args.baked.relight.all_shadow_rays,
        "threads": rayon::current_num_threads(),
        "median_ms": {"direct": d, "project": p, "transport": s, "feedback": fb, "flatten": fl, "total": d + p + s + fb + fl},
        "median_senders_used": median(senders),
        "median_shadow_rays_cast": median(rays),
        "support_average": !args.baked.relight.point_samples,
        "sharpen": !args.baked.relight.no_sharpen,
        "sharpen_steps": args.baked.relight.sharpen_steps,
        "fine_bounces": v.relighter.fine_bounces,
        "fine_emission": v.relighter.fine_emission,
        "bounce_feedback_steps": v.relighter.bounce_feedback,
        "lagged_feedback": v.relighter.lagged_feedback,
        "lag_pays": v.relighter.lag_pays(),
        "median_averaged_points": median(averaged),
        "view_culling": v.relighter.view_culling,
        "camera": {"width": camera.width, "height": camera.height},
        "median_flat_rows": median(flat_rows),
        "camera_turn": turn,
        "load": v.relighter.load_stats(),
        "relight": "cpu",
        "gpu": "not used: CPU relighting only (`--relight gpu` times the GPU's; `view render FILE --out DIR` renders)",
    })
}
