//! `view render FILE --out DIR`: the window's rendering without a window, into files:
//! direct.exr, indirect.exr, final.exr (linear radiance), final.png (tone mapped) and
//! timings.json; `--frames N` moves the light along a fixed path and reports medians;
//! `--reference SPP` adds the path-traced reference.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use mlt_relight::{LoadStats, Relight};
use mlt_view::frame::FrameDriver;
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{Gpu, Renderer};
use mlt_view::headless::{self, Timings};
use mlt_view::reference::{render_reference, write_reference};

use crate::cmd::args::{BakedArgs, GpuArgs};
use crate::cmd::load::{with_viewing, Viewing};

/// Renders images without a window.
#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Relight and render N frames with the light moving on a circle and report per-stage
    /// medians (the images are of the requested light).
    #[arg(long)]
    pub frames: Option<u32>,
    /// Also render the brute-force path-traced reference with SPP paths per pixel (even; two
    /// independent halves state its noise) into DIR/reference_*.exr, reference.png and
    /// reference.json, for `view compare`.
    #[arg(long)]
    pub reference: Option<u32>,
    /// Seed of the reference's random streams.
    #[arg(long, default_value_t = 1)]
    pub reference_seed: u64,
}

pub fn run(args: &RenderArgs) -> Result<()> {
    with_viewing(&args.baked, |mut v| {
        let timings = images(args, &mut v)?;
        if let Some(spp) = args.reference {
            reference(args, &v, spp)?;
        }
        report(args, &timings, v.relighter.load_stats());
        Ok(())
    })
}

/// Renders and writes the relit images and timings.json.
fn images(args: &RenderArgs, v: &mut Viewing<'_>) -> Result<Timings> {
    let gpu = Gpu::headless().context("starting the GPU for headless rendering")?;
    let mesh = GpuMesh::from_scene(v.scene);
    let flat = v.relighter.flat_basis().ib.clone();
    let mut renderer = Renderer::new(&gpu, &mesh, &flat.basis, args.gpu.shadow_res)
        .context("setting up the renderer")?;
    let path_radius = v.path_radius();
    let mut driver = FrameDriver {
        gpu: &gpu,
        renderer: &mut renderer,
        relighter: &mut v.relighter,
        ib: &flat,
    };
    if args.gpu.flatten.on_gpu(&gpu) {
        driver
            .flatten_on_gpu()
            .context("uploading the flattening operator")?;
    }
    let frames = args.frames.unwrap_or(1);
    let (buffers, mut timings) =
        headless::render(&mut driver, &v.camera, &v.light, frames, path_radius)
            .with_context(|| format!("rendering {}", v.path.display()))?;
    timings.load = Some(*v.relighter.load_stats());
    headless::write_outputs(&args.out, &buffers, &timings)?;
    Ok(timings)
}

/// Renders and writes the path-traced reference of the same camera and light.
fn reference(args: &RenderArgs, v: &Viewing<'_>, spp: u32) -> Result<()> {
    let out = &args.out;
    let start = Instant::now();
    let r = render_reference(v.caster, &v.camera, &v.light, spp, args.reference_seed)
        .context("rendering the reference")?;
    write_reference(out, &r)
        .with_context(|| format!("writing the reference into {}", out.display()))?;
    eprintln!(
        "reference: {spp} paths per pixel in {:.1} s, written to {}/reference_*.exr (compare with: view compare {} {})",
        start.elapsed().as_secs_f64(),
        out.display(),
        out.display(),
        out.display()
    );
    Ok(())
}

/// The summary on stderr: what was written, the median stage times, the set-up.
fn report(args: &RenderArgs, timings: &Timings, load: &LoadStats) {
    let c = &timings.cpu_median_ms;
    let g = &timings.gpu_median_ms;
    eprintln!(
        "{}x{} on {} ({}): wrote {}/{{direct,indirect,final}}.exr, final.png, timings.json",
        timings.width,
        timings.height,
        timings.adapter.name,
        timings.adapter.backend,
        args.out.display()
    );
    eprintln!(
        "median over {} frame(s): CPU direct {:.1} + pull-push {:.1} + S e {:.1} + flatten {:.1} = {:.1} ms; GPU passes {:.1} ms, of which flattening {:.1} ms ({} of {} basis functions splatted)",
        timings.frames, c.direct, c.project, c.transport, c.flatten, c.total, g.total,
        g.flatten, timings.splatted_points, timings.basis_points
    );
    eprintln!(
        "set-up once per file: {:.0} ms building the relighting operators ({:.1} MB)",
        load.build_ms,
        (load.flatten_bytes + load.pull_push_bytes + load.links_bytes) as f64 / 1e6
    );
}
