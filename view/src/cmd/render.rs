//! `view render FILE --out DIR`: the window's rendering without a window, into files:
//! direct.exr, indirect.exr, final.exr (linear radiance), final.png (tone mapped) and
//! timings.json; `--frames N` moves the light along a fixed path and reports medians;
//! `--spp N` box-filters each pixel over N sub-pixel positions; `--reference SPP` adds the
//! path-traced reference (box-filtered over the pixel as well); `--oracle SPP` adds the basis
//! floor (`mlt_view::oracle`) into DIR/oracle.

use std::ops::Range;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use mlt_relight::{LoadStats, Relight};
use mlt_view::frame::FrameDriver;
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{BoundGpuRelighter, Gpu, GpuRelighter, Renderer};
use mlt_view::headless::{self, Timings};
use mlt_view::oracle::{oracle, OracleRelighter};
use mlt_view::reference::{render_reference, write_reference, ReferenceOptions};

use crate::cmd::args::{BakedArgs, GpuArgs};
use crate::cmd::load::{with_viewing, Viewing};

/// Renders images without a window.
#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    /// Output directory: direct.exr, indirect.exr, final.exr, final.png and timings.json.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Also time N frames with the light moving on a small circle (per-stage medians).
    #[arg(long, value_name = "N")]
    pub frames: Option<u32>,
    /// Positions per pixel, averaged: the reference's box filter (1: the pixel centres).
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub spp: u32,
    /// Also path-trace the reference with SPP paths per pixel (even), for `view compare`.
    #[arg(long, value_name = "SPP")]
    pub reference: Option<u32>,
    /// Seed of the reference's random numbers.
    #[arg(long, value_name = "S", default_value_t = 1, hide = true)]
    pub reference_seed: u64,
    /// Also render the basis floor, coefficients path-traced with SPP paths, into DIR/oracle.
    #[arg(long, value_name = "SPP", hide = true)]
    pub oracle: Option<u32>,
    /// With --oracle: the oracle's coefficients on levels A..B only, the bake's on the others.
    #[arg(long, value_name = "A..B", requires = "oracle", value_parser = parse_levels,
          hide = true)]
    pub oracle_levels: Option<Range<usize>>,
    /// With --oracle: the oracle's longest path, in bounces (1: the first bounce only).
    #[arg(long, value_name = "N", requires = "oracle",
          value_parser = clap::value_parser!(u32).range(1..), hide = true)]
    pub oracle_max_bounces: Option<u32>,
}

/// `A..B` with `A < B` for [`RenderArgs::oracle_levels`].
fn parse_levels(s: &str) -> Result<Range<usize>, String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("expected A..B (e.g. 0..1), got {s}"))?;
    let a: usize = a.trim().parse().map_err(|e| format!("{a}: {e}"))?;
    let b: usize = b.trim().parse().map_err(|e| format!("{b}: {e}"))?;
    if a >= b {
        return Err(format!("the range {s} holds no level (A must be below B)"));
    }
    Ok(a..b)
}

pub fn run(args: &RenderArgs) -> Result<()> {
    with_viewing(&args.baked, |mut v| {
        let timings = images(args, &mut v)?;
        if let Some(spp) = args.reference {
            reference(args, &v, spp)?;
        }
        if let Some(spp) = args.oracle {
            oracle_images(args, &mut v, spp)?;
        }
        report(args, &timings, v.relighter.load_stats());
        Ok(())
    })
}

/// Renders and writes the relit images and timings.json.
fn images(args: &RenderArgs, v: &mut Viewing<'_>) -> Result<Timings> {
    let gpu = Gpu::headless().context("starting the GPU for headless rendering")?;
    let mesh = GpuMesh::from_scene(v.scene);
    let fb = v.relighter.flat_basis();
    let mut renderer = Renderer::for_flat(&gpu, &mesh, fb, &v.ib.basis, args.gpu.shadow_res)
        .context("setting up the renderer")?;
    renderer.set_half_precision_splat(&gpu, args.gpu.splat_bits == 16);
    let flat = fb.ib.clone();
    let path_radius = v.path_radius();
    let frames = args.frames.unwrap_or(1);
    let relight_on_gpu = GpuRelighter::chosen(args.gpu.relight.choice(), &gpu, &v.relighter);
    let mut clock = "";
    let (camera, light, spp) = (v.camera, v.light, args.spp);
    let draw = |driver: &mut FrameDriver<'_>| {
        headless::render(driver, &camera, &light, frames, spp, path_radius)
    };
    let (buffers, mut timings) = if relight_on_gpu {
        // The relighting's compute passes write the flat coefficients the splatting reads.
        let mut relighter =
            GpuRelighter::new(&gpu, &v.relighter, Some(renderer.coefficient_buffer()))
                .context("uploading the relighting to the GPU")?;
        relighter.timed = true;
        clock = relighter.clock();
        let mut bound = BoundGpuRelighter {
            gpu: &gpu,
            relighter: &mut relighter,
            error: None,
        };
        let mut driver = FrameDriver {
            gpu: &gpu,
            renderer: &mut renderer,
            relighter: &mut bound,
            ib: &flat,
        };
        let out = draw(&mut driver);
        if let Some(e) = bound.error {
            return Err(e).context("relighting on the GPU");
        }
        out
    } else {
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
        draw(&mut driver)
    }
    .with_context(|| format!("rendering {}", v.path.display()))?;
    timings.load = Some(*v.relighter.load_stats());
    if relight_on_gpu {
        timings.relight = "gpu";
        timings.relight_clock = clock;
    }
    headless::write_outputs(&args.out, &buffers, &timings)?;
    Ok(timings)
}

/// Renders the basis floor into DIR/oracle (images as [`images`], and oracle.json).
fn oracle_images(args: &RenderArgs, v: &mut Viewing<'_>, spp: u32) -> Result<()> {
    if let Some(levels) = args
        .oracle_levels
        .as_ref()
        .filter(|l| l.start >= v.ib.levels())
    {
        anyhow::bail!(
            "--oracle-levels {}..{}: {} has levels 0..{}",
            levels.start,
            levels.end,
            v.path.display(),
            v.ib.levels()
        );
    }
    let mut opts = ReferenceOptions::new(spp, args.reference_seed ^ 0x6f72_6163_6c65);
    if let Some(b) = args.oracle_max_bounces {
        opts.max_bounces = b;
    }
    let o = oracle(v.ib, v.caster, &v.light, &opts).context("path tracing the basis floor")?;
    let gpu = Gpu::headless().context("starting the GPU for headless rendering")?;
    let mesh = GpuMesh::from_scene(v.scene);
    let mut relighter = OracleRelighter::new(v.ib, &mut v.relighter, o.alpha)
        .context("building the flattening operator over every point")?;
    if let Some(levels) = &args.oracle_levels {
        relighter = relighter.with_levels(levels.clone());
    }
    let fb = relighter.flat_basis();
    let mut renderer = Renderer::for_flat(&gpu, &mesh, fb, &v.ib.basis, args.gpu.shadow_res)
        .context("setting up the renderer")?;
    let flat = fb.ib.clone();
    let mut driver = FrameDriver {
        gpu: &gpu,
        renderer: &mut renderer,
        relighter: &mut relighter,
        ib: &flat,
    };
    // The same pixel footprint as the bake's images (--spp), so the two compare pixel by pixel.
    let (buffers, timings) = headless::render(&mut driver, &v.camera, &v.light, 1, args.spp, 0.0)
        .context("rendering the basis floor")?;
    let dir = args.out.join("oracle");
    headless::write_outputs(&dir, &buffers, &timings)?;
    let json = serde_json::json!({
        "spp_per_point": o.spp,
        "points": v.ib.basis.len(),
        "relative_noise_per_point": o.relative_noise,
        "unsupported_points": o.projection.unsupported_points,
        "oracle_levels": args.oracle_levels.as_ref().map(|l| [l.start, l.end]),
        "max_bounces": opts.max_bounces,
        "seconds": o.seconds,
    });
    std::fs::write(
        dir.join("oracle.json"),
        serde_json::to_string_pretty(&json)?,
    )
    .with_context(|| format!("writing {}/oracle.json", dir.display()))?;
    eprintln!(
        "basis floor: {spp} paths at each of {} points in {:.1} s (relative noise per point {:.3}), written to {} (compare with: view compare {} {})",
        v.ib.basis.len(),
        o.seconds,
        o.relative_noise,
        dir.display(),
        args.out.display(),
        dir.display()
    );
    Ok(())
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
        "{}x{} ({} sub-pixel sample(s) per pixel) on {} ({}): wrote {}/{{direct,indirect,final}}.exr, final.png, timings.json",
        timings.width,
        timings.height,
        timings.spp,
        timings.adapter.name,
        timings.adapter.backend,
        args.out.display()
    );
    eprintln!(
        "median over {} frame(s): relighting ({}) direct {:.1} + pull-push {:.1} + S e {:.1} + flatten {:.1} = {:.1} ms; GPU passes {:.1} ms, of which flattening {:.1} ms ({} of {} basis functions splatted)",
        timings.frames, timings.relight, c.direct, c.project, c.transport, c.flatten, c.total, g.total,
        g.flatten, timings.splatted_points, timings.basis_points
    );
    eprintln!(
        "set-up once per file: {:.0} ms building the relighting operators ({:.1} MB)",
        load.build_ms,
        (load.flatten_bytes + load.pull_push_bytes + load.links_bytes) as f64 / 1e6
    );
}

#[cfg(test)]
mod tests {
    use super::parse_levels;

    #[test]
    fn levels_parse_as_half_open_ranges() {
        assert_eq!(parse_levels("0..1"), Ok(0..1));
        assert_eq!(parse_levels(" 2 .. 6 "), Ok(2..6));
        for bad in ["1", "1..1", "3..2", "a..2", "0..", "-1..2"] {
            assert!(parse_levels(bad).is_err(), "{bad} accepted");
        }
    }
}
