//! The renderer of one baked scene (section 4.1): it uploads the scene and the basis, keeps
//! the render targets at the image's size, culls the basis to the view frustum and runs the
//! passes of [`super::passes`] in the order of [`Renderer::render`]. The G-buffer is redrawn
//! only when the camera changed and the shadow maps only when the light did.
//!
//! The G-buffer uses reversed depth (1 at the near plane, [`Camera::reversed_view_proj`]) in a
//! 32-bit float buffer, so depth precision does not depend on the scene's scale.

use std::time::Instant;

use glam::{Mat4, Vec3};
use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::LINK_DIM;
use mlt_format::{Basis, IndexedBasis};
use mlt_relight::{FlattenOp, Light, SharpenOp};
use serde::Serialize;

use super::context::{Gpu, GpuError};
use super::cull::{visible_points, Frustum};
use super::flatten::GpuFlatten;
use super::mesh::GpuMesh;
use super::passes::display::{DisplayPass, Output};
use super::passes::gbuffer::GBufferPass;
use super::passes::points::PointsPass;
use super::passes::resolve::ResolvePass;
use super::passes::shadow::ShadowPass;
use super::passes::splat::SplatPass;
use super::readback::{read_rgb, read_rgba16f_rgb, read_rgba32f};
use super::scene_buffers::SceneBuffers;
use super::targets::Targets;
use super::uniforms::Globals;
use crate::camera::Camera;
use crate::images::{RgbImage, ToneMap};

pub use super::passes::display::ViewMode;

/// Wall-clock milliseconds of the GPU passes of one frame (each pass submitted and waited for
/// on its own when timing was asked for), and the culling on the CPU.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RenderTimes {
    /// The flattening compute pass, when the renderer flattens (set by the caller).
    pub flatten_ms: f64,
    pub cull_ms: f64,
    pub gbuffer_ms: f64,
    pub shadow_ms: f64,
    pub splat_ms: f64,
    pub resolve_ms: f64,
    /// Basis functions drawn (those meeting the view frustum).
    pub splatted_points: usize,
    /// R-tree nodes visited by the culling.
    pub culling_nodes: usize,
}

/// The linear radiance buffers of a frame.
#[derive(Clone, Debug)]
pub struct Buffers {
    pub direct: RgbImage,
    pub indirect: RgbImage,
    pub final_: RgbImage,
}

/// The G-buffer read back (for tests and probes): per pixel, rows from the top.
#[derive(Clone, Debug)]
pub struct GBuffer {
    pub width: u32,
    pub height: u32,
    /// World position, `w = 1` where a surface covers the pixel, 0 elsewhere.
    pub position: Vec<[f32; 4]>,
    pub normal: Vec<[f32; 3]>,
    pub albedo: Vec<[f32; 3]>,
}

/// The renderer of one baked scene.
pub struct Renderer {
    /// Basis points (each with `LINK_DIM` flat coefficients).
    point_count: usize,
    /// Levels of the points (of the hierarchy, for a flat basis given its points' levels).
    levels: usize,
    bounds: (Vec3, Vec3),
    scene: SceneBuffers,
    gbuffer: GBufferPass,
    shadow: ShadowPass,
    splat: SplatPass,
    resolve: ResolvePass,
    display: DisplayPass,
    points: PointsPass,
    gpu_flatten: Option<GpuFlatten>,
    acc_format: wgpu::TextureFormat,
    targets: Option<Targets>,
    visible: Vec<u32>,
    culling_nodes: usize,
    last_camera: Option<Camera>,
    last_light: Option<Light>,
    /// Whether direct light is shadowed (shadow maps); on by default.
    pub shadows: bool,
}

impl Renderer {
    /// Uploads the scene and the flat basis `flat` (its points and its weights' normal
    /// power). `shadow_res` is the shadow maps' resolution.
    pub fn new(
        gpu: &Gpu,
        mesh: &GpuMesh,
        flat: &FlatBasis,
        shadow_res: u32,
    ) -> Result<Renderer, GpuError> {
        Self::build(gpu, mesh, flat, None, shadow_res)
    }

    /// [`Renderer::new`] for a flat basis `flat`, whose points are shown in the level-used and
    /// points views at the levels of the hierarchical points they are (`hier`'s), not at
    /// their own basis' one level.
    pub fn for_flat(
        gpu: &Gpu,
        mesh: &GpuMesh,
        flat: &FlatBasis,
        hier: &Basis,
        shadow_res: u32,
    ) -> Result<Renderer, GpuError> {
        let levels = flat.source_levels(hier);
        Self::build(gpu, mesh, flat, Some(&levels), shadow_res)
    }

    fn build(
        gpu: &Gpu,
        mesh: &GpuMesh,
        flat: &FlatBasis,
        levels: Option<&[u32]>,
        shadow_res: u32,
    ) -> Result<Renderer, GpuError> {
        let basis = &flat.ib.basis;
        let device = &gpu.device;
        let acc_format = if gpu.report.float32_blend {
            wgpu::TextureFormat::Rgba32Float
        } else {
            wgpu::TextureFormat::Rgba16Float
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let scene = SceneBuffers::new(
            device,
            mesh,
            (basis, &flat.ib.clip),
            levels,
            flat.normal_power,
        );
        let renderer = Renderer {
            point_count: basis.len(),
            levels: levels.map_or(basis.levels(), |l| {
                l.iter().max().map_or(1, |&m| m as usize + 1)
            }),
            bounds: mesh.bounds,
            gbuffer: GBufferPass::new(gpu, mesh, &scene),
            shadow: ShadowPass::new(device, shadow_res),
            splat: SplatPass::new(device, acc_format),
            resolve: ResolvePass::new(device),
            display: DisplayPass::new(device),
            points: PointsPass::new(device, &scene),
            scene,
            gpu_flatten: None,
            acc_format,
            targets: None,
            visible: Vec::with_capacity(basis.len()),
            culling_nodes: 0,
            last_camera: None,
            last_light: None,
            shadows: true,
        };
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(renderer)
    }

    /// The number of levels of the basis.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Sums the splats in 16-bit floats (`half`, the format every adapter blends) or, where the
    /// adapter blends them, 32-bit ones (the default); the next frame redraws every pass.
    pub fn set_half_precision_splat(&mut self, gpu: &Gpu, half: bool) {
        let format = if half || !gpu.report.float32_blend {
            wgpu::TextureFormat::Rgba16Float
        } else {
            wgpu::TextureFormat::Rgba32Float
        };
        if format != self.acc_format {
            self.acc_format = format;
            self.splat = SplatPass::new(&gpu.device, format);
            self.targets = None;
            self.invalidate();
        }
    }

    /// The accumulation format of the splat sums (`Rgba32Float` where it can be blended).
    pub fn accumulation_format(&self) -> wgpu::TextureFormat {
        self.acc_format
    }

    /// Uploads new flat coefficients (`LINK_DIM` floats per basis point).
    pub fn set_coefficients(&self, gpu: &Gpu, flat: &[f32]) {
        let n = self.point_count * LINK_DIM;
        if n > 0 && flat.len() >= n {
            gpu.queue.write_buffer(
                &self.scene.coefficients,
                0,
                bytemuck::cast_slice(&flat[..n]),
            );
        }
    }

    /// Moves flattening to the GPU: uploads the precomputed operator (and the sharpening step
    /// after it, if any) once; afterwards
    /// [`Renderer::set_hierarchical_coefficients`] replaces [`Renderer::set_coefficients`].
    /// Returns the bytes uploaded.
    pub fn enable_gpu_flatten(
        &mut self,
        gpu: &Gpu,
        op: &FlattenOp,
        sharpen: Option<&SharpenOp>,
    ) -> Result<u64, GpuError> {
        if op.points() != self.point_count {
            return Err(GpuError::Validation(format!(
                "flattening operator for {} points, basis of {}",
                op.points(),
                self.point_count
            )));
        }
        let f = GpuFlatten::new(gpu, op, sharpen, &self.scene.coefficients)?;
        let bytes = f.bytes;
        self.gpu_flatten = Some(f);
        Ok(bytes)
    }

    /// True after [`Renderer::enable_gpu_flatten`].
    pub fn flattens_on_gpu(&self) -> bool {
        self.gpu_flatten.is_some()
    }

    /// Flattens the hierarchical coefficients `i` (`LINK_DIM` per point) on the GPU into the
    /// splatted coefficients. With `timed`, waits and returns the wall time in milliseconds.
    pub fn set_hierarchical_coefficients(
        &self,
        gpu: &Gpu,
        i: &[f32],
        timed: bool,
    ) -> Result<f64, GpuError> {
        let Some(f) = &self.gpu_flatten else {
            return Err(GpuError::Validation(
                "GPU flattening is not enabled (enable_gpu_flatten)".into(),
            ));
        };
        run_pass(gpu, "flatten", timed, &|enc| f.encode(gpu, i, enc))
    }

    /// The buffer of flat coefficients the splatting pass reads (`LINK_DIM` floats per basis
    /// point), for a relighter that writes them on the GPU ([`super::GpuRelighter::new`]).
    pub fn coefficient_buffer(&self) -> &wgpu::Buffer {
        &self.scene.coefficients
    }

    /// Reads back the flat coefficients the splatting pass uses (for tests).
    pub fn read_coefficients(&self, gpu: &Gpu) -> Result<Vec<f32>, GpuError> {
        let n = self.point_count * LINK_DIM;
        super::readback::read_buffer_f32(gpu, &self.scene.coefficients, n)
    }

    /// Renders one frame of `camera` and `light` into the linear buffers. The G-buffer is
    /// redrawn only when the camera changed and the shadow maps only when the light did.
    /// With `timed`, each pass is submitted and waited for alone and its wall time reported.
    pub fn render(
        &mut self,
        gpu: &Gpu,
        ib: &IndexedBasis,
        camera: &Camera,
        light: &Light,
        timed: bool,
    ) -> Result<RenderTimes, GpuError> {
        self.ensure_targets(gpu, camera.width, camera.height);
        let camera_changed = self.last_camera.as_ref() != Some(camera);
        let light_changed = self.last_light.as_ref() != Some(light);
        let view_proj = self.write_globals(gpu, camera, light, light_changed);
        let mut times = RenderTimes::default();
        if camera_changed {
            times.cull_ms = self.cull(gpu, ib, &view_proj);
        }
        times.splatted_points = self.visible.len();
        times.culling_nodes = self.culling_nodes;

        let Some(t) = &self.targets else {
            return Err(GpuError::Validation("render targets missing".into()));
        };
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let (scene, visible) = (&self.scene, self.visible.len());
        if camera_changed {
            let encode = |enc: &mut _| self.gbuffer.encode(enc, t, scene);
            times.gbuffer_ms = run_pass(gpu, "gbuffer", timed, &encode)?;
        }
        if light_changed && self.shadows {
            let encode = |enc: &mut _| self.shadow.encode(&gpu.queue, enc, light, scene);
            times.shadow_ms = run_pass(gpu, "shadow", timed, &encode)?;
        }
        let encode = |enc: &mut _| self.splat.encode(enc, t, visible);
        times.splat_ms = run_pass(gpu, "splat", timed, &encode)?;
        let encode = |enc: &mut _| self.resolve.encode(enc, t);
        times.resolve_ms = run_pass(gpu, "resolve", timed, &encode)?;
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        self.last_camera = Some(*camera);
        self.last_light = Some(*light);
        Ok(times)
    }

    /// Makes the targets (and binds them to the passes) unless they are `w x h` already.
    fn ensure_targets(&mut self, gpu: &Gpu, w: u32, h: u32) {
        if self.targets.as_ref().is_some_and(|t| t.fit(w, h)) {
            return;
        }
        let device = &gpu.device;
        let targets = Targets::new(device, w, h, self.acc_format);
        self.splat.attach(device, &targets, &self.scene);
        self.resolve
            .attach(device, &targets, &self.scene, &self.shadow);
        self.display.attach(device, &targets);
        self.targets = Some(targets);
        self.last_camera = None;
    }

    /// Places the shadow faces and writes the frame's [`Globals`]; returns the camera's
    /// reversed-depth view-projection.
    fn write_globals(
        &mut self,
        gpu: &Gpu,
        camera: &Camera,
        light: &Light,
        light_changed: bool,
    ) -> Mat4 {
        let planes = camera.planes_for_bounds(self.bounds.0, self.bounds.1);
        self.shadow.place(light, self.bounds, light_changed);
        let shadows = if self.shadows {
            self.shadow.faces()
        } else {
            None
        };
        let view_proj = camera.reversed_view_proj(planes);
        let globals = Globals::new(camera, &view_proj, planes.0, light, shadows, 0, 0);
        gpu.queue
            .write_buffer(&self.scene.globals, 0, bytemuck::bytes_of(&globals));
        view_proj
    }

    /// The frustum that [`Renderer::render`] culls the flat basis to for `camera` (the
    /// relighter's view, [`mlt_relight::Relight::set_view`]).
    pub fn frustum(&self, camera: &Camera) -> Frustum {
        camera.frustum_for_bounds(self.bounds.0, self.bounds.1)
    }

    /// Culls the basis to the frustum of `view_proj` and uploads the visible list; returns
    /// the wall time in milliseconds.
    fn cull(&mut self, gpu: &Gpu, ib: &IndexedBasis, view_proj: &Mat4) -> f64 {
        let start = Instant::now();
        let frustum = Frustum::from_view_proj(view_proj);
        self.culling_nodes = visible_points(ib, &frustum, f32::INFINITY, &mut self.visible);
        if !self.visible.is_empty() {
            gpu.queue
                .write_buffer(&self.scene.visible, 0, bytemuck::cast_slice(&self.visible));
        }
        start.elapsed().as_secs_f64() * 1e3
    }

    /// Forgets the last light, so that the next frame redraws the shadow maps (after new
    /// coefficients for the same light, nothing else needs it).
    pub fn invalidate(&mut self) {
        self.last_light = None;
        self.last_camera = None;
    }

    /// Reads back direct, indirect and final linear radiance.
    pub fn read_buffers(&self, gpu: &Gpu) -> Result<Buffers, GpuError> {
        let t = self.rendered()?;
        Ok(Buffers {
            direct: read_rgb(gpu, &t.direct.texture)?,
            indirect: read_rgb(gpu, &t.indirect.texture)?,
            final_: read_rgb(gpu, &t.final_.texture)?,
        })
    }

    /// Reads back the final linear radiance only (what tone mapping measures).
    pub fn read_final(&self, gpu: &Gpu) -> Result<RgbImage, GpuError> {
        read_rgb(gpu, &self.rendered()?.final_.texture)
    }

    fn rendered(&self) -> Result<&Targets, GpuError> {
        self.targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing rendered yet".into()))
    }

    /// Reads back the G-buffer.
    pub fn read_gbuffer(&self, gpu: &Gpu) -> Result<GBuffer, GpuError> {
        let t = self.rendered()?;
        let p = read_rgba32f(gpu, &t.position.texture)?;
        let n = read_rgba32f(gpu, &t.normal.texture)?;
        Ok(GBuffer {
            width: t.width,
            height: t.height,
            position: p
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            normal: n.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
            albedo: read_rgba16f_rgb(gpu, &t.albedo.texture)?,
        })
    }

    /// Draws `mode` into `target_view` (of the rendered size and `format`), tone mapped with
    /// `tone`; `level` picks the level of the points view, coloured up to
    /// `flat_max_luminance`. sRGB is encoded in the shader unless the format does it.
    #[allow(clippy::too_many_arguments)]
    pub fn display(
        &mut self,
        gpu: &Gpu,
        target_view: &wgpu::TextureView,
        format: wgpu::TextureFormat,
        tone: &ToneMap,
        mode: ViewMode,
        level: usize,
        flat_max_luminance: f32,
    ) -> Result<(), GpuError> {
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let levels = self.levels();
        self.display.set(&gpu.queue, mode, tone, levels, format);
        let level = level.min(levels.saturating_sub(1));
        self.points
            .set(&gpu.queue, level, flat_max_luminance, format);
        let Some(t) = &self.targets else {
            return Err(GpuError::Validation("render before display".into()));
        };
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("display"),
            });
        let out = Output {
            view: target_view,
            format,
        };
        self.display.encode(&gpu.device, &mut enc, out);
        if mode == ViewMode::Points && self.point_count > 0 {
            let points = self.point_count;
            self.points.encode(&gpu.device, &mut enc, out, t, points);
        }
        gpu.queue.submit([enc.finish()]);
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Validation(e.to_string())),
            None => Ok(()),
        }
    }
}

/// Records one pass with `encode` and submits it; with `timed`, waits for it. Returns the
/// wall time in milliseconds.
fn run_pass(
    gpu: &Gpu,
    label: &str,
    timed: bool,
    encode: &dyn Fn(&mut wgpu::CommandEncoder),
) -> Result<f64, GpuError> {
    let start = Instant::now();
    let mut enc = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
    encode(&mut enc);
    gpu.queue.submit([enc.finish()]);
    if timed {
        gpu.wait()?;
    }
    Ok(start.elapsed().as_secs_f64() * 1e3)
}
