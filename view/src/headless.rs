//! Headless rendering: frames of [`crate::frame`] drawn without a window, then the linear
//! buffers (OpenEXR), tone-mapped PNGs and per-stage timings written.

use std::path::Path;

use glam::Vec3;
use mlt_format::IndexedBasis;
use mlt_relight::{Light, StageTimes};
use serde::Serialize;

use crate::camera::{subpixel_offsets, Camera};
use crate::frame::{FrameDriver, Redraw};
use crate::gpu::context::AdapterReport;
use crate::gpu::{Buffers, Gpu, GpuError, RenderTimes, Renderer};
use crate::images::{ImageError, RgbImage};

/// Errors of a headless render.
#[derive(Debug, thiserror::Error)]
pub enum HeadlessError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("{path}: {msg}")]
    Output { path: String, msg: String },
}

/// Median stage times over the frames of a headless run.
#[derive(Clone, Debug, Serialize)]
pub struct Timings {
    pub frames: u32,
    pub moving_light: bool,
    pub width: u32,
    pub height: u32,
    /// Sub-pixel samples per pixel of the images ([`box_filtered`]; not of the timed frames).
    pub spp: u32,
    pub threads: usize,
    /// Where the relighting after the direct light ran: "cpu" or "gpu" (`--relight`).
    pub relight: &'static str,
    /// How the relighting's stages in `cpu_median_ms` were timed (with `relight` "gpu": by the
    /// clock named here, the direct light's CPU part included in `direct`; the GPU's
    /// flattening is then the relighting's `flatten`, not `gpu_median_ms.flatten`).
    pub relight_clock: &'static str,
    /// The relighting's stages, milliseconds (medians over frames): on the CPU, or with
    /// `relight` "gpu" the direct light on the CPU and the GPU's stages (`relight_clock`).
    pub cpu_median_ms: CpuMedians,
    /// GPU passes, wall-clock milliseconds with a wait after each pass (medians). On a
    /// software rasteriser these measure the CPU that emulates the GPU.
    pub gpu_median_ms: GpuMedians,
    pub splatted_points: usize,
    pub basis_points: usize,
    pub median_senders_used: f64,
    /// Shadow rays cast per relit frame for the direct light at the senders (median).
    pub median_shadow_rays_cast: f64,
    pub adapter: AdapterReport,
    pub accumulation_format: String,
    /// The relighter's one-time set-up (precomputed operators), when it reports one.
    pub load: Option<mlt_relight::LoadStats>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct CpuMedians {
    pub direct: f64,
    pub project: f64,
    pub transport: f64,
    /// The bounce-light feedback after `S e` (0 when off).
    pub feedback: f64,
    pub flatten: f64,
    pub total: f64,
}

/// Median milliseconds of the renderer's stages per frame (`gpu_median_ms` in
/// `timings.json`): the GPU passes, timed on their own, and the culling before them.
#[derive(Clone, Debug, Default, Serialize)]
pub struct GpuMedians {
    /// The flattening compute pass (0 when flattening runs on the CPU).
    pub flatten: f64,
    /// The renderer's frustum culling, which runs on the CPU (the flat R-tree's walk and the
    /// upload of the visible list) but belongs to the renderer's stages, so it is counted here
    /// and in this `total`.
    pub cull: f64,
    pub gbuffer: f64,
    pub shadow: f64,
    pub splat: f64,
    pub resolve: f64,
    pub total: f64,
}

/// Median of a list (0 when empty).
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// The light of frame `f` of `n` on the fixed path of `--frames`: a horizontal circle of
/// radius `radius` around the given light's position (frame 0 on the +X side).
pub fn light_on_path(light: &Light, radius: f32, f: u32, n: u32) -> Light {
    let a = std::f32::consts::TAU * f as f32 / n.max(1) as f32;
    let mut l = *light;
    l.position = light.position + Vec3::new(radius * a.cos(), 0.0, radius * a.sin());
    l
}

/// The buffers of `camera` and `light`, as the renderer holds the lighting now, averaged over
/// `spp` sub-pixel positions of each pixel ([`subpixel_offsets`]: a box filter over the
/// pixel). The lighting is the same for every position (it is per light, not per pixel): only
/// the G-buffer and the passes after it are redrawn with the jittered projection. With one
/// sample, the image at the pixel centres.
pub fn box_filtered(
    gpu: &Gpu,
    renderer: &mut Renderer,
    ib: &IndexedBasis,
    camera: &Camera,
    light: &Light,
    spp: u32,
) -> Result<Buffers, GpuError> {
    let offsets = subpixel_offsets(spp);
    let mut sum: Option<Buffers> = None;
    for &offset in &offsets {
        renderer.render(gpu, ib, &camera.jittered(offset), light, false)?;
        let b = renderer.read_buffers(gpu)?;
        sum = Some(match sum {
            None => b,
            Some(mut s) => {
                add(&mut s.direct, &b.direct);
                add(&mut s.indirect, &b.indirect);
                add(&mut s.final_, &b.final_);
                s
            }
        });
    }
    let mut s = sum.ok_or_else(|| GpuError::Readback("no sub-pixel sample".into()))?;
    if offsets.len() > 1 {
        let k = 1.0 / offsets.len() as f32;
        for img in [&mut s.direct, &mut s.indirect, &mut s.final_] {
            img.pixels.iter_mut().flatten().for_each(|v| *v *= k);
        }
    }
    Ok(s)
}

/// `sum += img`, pixel by pixel.
fn add(sum: &mut RgbImage, img: &RgbImage) {
    for (s, p) in sum.pixels.iter_mut().zip(&img.pixels) {
        s.iter_mut().zip(p).for_each(|(s, p)| *s += p);
    }
}

/// Renders `frames` frames (the light moving on [`light_on_path`] when more than one), then
/// the requested light, and returns the buffers of the latter, box-filtered over `spp`
/// sub-pixel positions ([`box_filtered`]), with median timings of the frames.
pub fn render(
    driver: &mut FrameDriver<'_>,
    camera: &Camera,
    light: &Light,
    frames: u32,
    spp: u32,
    path_radius: f32,
) -> Result<(Buffers, Timings), HeadlessError> {
    let frames = frames.max(1);
    let mut cpu: Vec<StageTimes> = Vec::new();
    let mut gpu_times: Vec<RenderTimes> = Vec::new();
    let mut senders = Vec::new();
    let mut rays = Vec::new();
    let moving = frames > 1;
    for f in 0..frames {
        let l = if moving {
            light_on_path(light, path_radius, f, frames)
        } else {
            *light
        };
        // Every frame is a full frame: the camera is redrawn too, as when a window resizes.
        let drawn = driver.draw(camera, &l, Redraw::Full, true)?;
        cpu.push(drawn.frame.times);
        senders.push(drawn.frame.senders_used as f64);
        rays.push(drawn.frame.shadow_rays as f64);
        gpu_times.push(drawn.gpu);
    }
    if moving {
        driver.draw(camera, light, Redraw::Lighting, false)?;
    }
    let (gpu, ib) = (driver.gpu, driver.ib);
    let buffers = if spp <= 1 {
        driver.renderer.read_buffers(gpu)?
    } else {
        box_filtered(gpu, driver.renderer, ib, camera, light, spp)?
    };
    let m = |f: &dyn Fn(&StageTimes) -> f64| median(cpu.iter().map(f).collect());
    let cpu_median_ms = CpuMedians {
        direct: m(&|t| t.direct_ms),
        project: m(&|t| t.project_ms),
        transport: m(&|t| t.transport_ms),
        feedback: m(&|t| t.feedback_ms),
        flatten: m(&|t| t.flatten_ms),
        total: m(&|t| t.total_ms()),
    };
    let g = |f: &dyn Fn(&RenderTimes) -> f64| median(gpu_times.iter().map(f).collect());
    let gpu_median_ms = GpuMedians {
        flatten: g(&|t| t.flatten_ms),
        cull: g(&|t| t.cull_ms),
        gbuffer: g(&|t| t.gbuffer_ms),
        shadow: g(&|t| t.shadow_ms),
        splat: g(&|t| t.splat_ms),
        resolve: g(&|t| t.resolve_ms),
        total: g(&|t| {
            t.flatten_ms + t.cull_ms + t.gbuffer_ms + t.shadow_ms + t.splat_ms + t.resolve_ms
        }),
    };
    let timings = Timings {
        frames,
        moving_light: moving,
        width: camera.width,
        height: camera.height,
        spp: spp.max(1),
        threads: rayon::current_num_threads(),
        relight: "cpu",
        relight_clock: "CPU wall clock per stage",
        cpu_median_ms,
        gpu_median_ms,
        splatted_points: gpu_times.last().map(|t| t.splatted_points).unwrap_or(0),
        basis_points: ib.basis.len(),
        median_senders_used: median(senders),
        median_shadow_rays_cast: median(rays),
        adapter: gpu.report.clone(),
        accumulation_format: format!("{:?}", driver.renderer.accumulation_format()),
        load: None,
    };
    Ok((buffers, timings))
}

/// Writes DIR/direct.exr, indirect.exr, final.exr, final.png (and direct.png, indirect.png,
/// each tone-mapped on its own) and timings.json (each file
/// atomically). Refuses buffers with NaN or infinite values, naming the buffer.
pub fn write_outputs(
    dir: &Path,
    buffers: &Buffers,
    timings: &Timings,
) -> Result<(), HeadlessError> {
    std::fs::create_dir_all(dir).map_err(|e| HeadlessError::Output {
        path: dir.display().to_string(),
        msg: e.to_string(),
    })?;
    for (name, img) in [
        ("direct", &buffers.direct),
        ("indirect", &buffers.indirect),
        ("final", &buffers.final_),
    ] {
        if !img.all_finite() {
            return Err(HeadlessError::Output {
                path: dir.join(format!("{name}.exr")).display().to_string(),
                msg: "the rendered buffer has NaN or infinite pixels; nothing written".into(),
            });
        }
    }
    buffers.direct.write_exr(&dir.join("direct.exr"))?;
    buffers.indirect.write_exr(&dir.join("indirect.exr"))?;
    buffers.final_.write_exr(&dir.join("final.exr"))?;
    buffers.final_.write_png(&dir.join("final.png"))?;
    // Each buffer tone-mapped on its own, for people looking at the parts.
    buffers.direct.write_png(&dir.join("direct.png"))?;
    buffers.indirect.write_png(&dir.join("indirect.png"))?;
    let json = serde_json::to_string_pretty(timings).map_err(|e| HeadlessError::Output {
        path: dir.join("timings.json").display().to_string(),
        msg: e.to_string(),
    })?;
    mlt_format::file::write_atomic(&dir.join("timings.json"), json.as_bytes())
        .map_err(ImageError::from)?;
    Ok(())
}
