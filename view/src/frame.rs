//! One frame of the viewer, shared by the window and headless rendering: relight on the CPU
//! (section 3.3), hand the coefficients to the renderer, render (section 4.1).

use mlt_format::IndexedBasis;

use crate::camera::Camera;
use crate::gpu::{Gpu, GpuError, RenderTimes, Renderer};
use mlt_relight::{Frame, Light, Relight};

/// What a frame hands to the renderer and redraws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Redraw {
    /// Upload the lighting and redraw the camera's passes too, as when a window resizes: every
    /// timed headless frame is a full frame.
    Full,
    /// Upload the lighting; the camera's passes are redrawn only where the renderer finds
    /// them stale.
    Lighting,
    /// Upload the lighting and redraw the camera's passes only when the relighter recomputed
    /// the lighting (the light moved): the window's frame.
    WhenRelit,
}

/// A drawn frame: the relighter's frame and the renderer's times.
pub struct Drawn<'f> {
    pub frame: &'f Frame,
    /// The GPU passes; `flatten_ms` is the GPU flattening pass (0 when it ran on the CPU).
    pub gpu: RenderTimes,
}

/// The pipeline of one frame: the relighter, and the renderer that draws what it computes.
pub struct FrameDriver<'a> {
    pub gpu: &'a Gpu,
    pub renderer: &'a mut Renderer,
    pub relighter: &'a mut dyn Relight,
    /// The relighter's flat basis (its one-level points and R-tree: what the renderer culls
    /// and splats).
    pub ib: &'a IndexedBasis,
}

impl FrameDriver<'_> {
    /// Moves flattening to the GPU when the relighter has the precomputed operator: returns
    /// the operator's bytes on the GPU, or `None` (flattening stays on the CPU).
    pub fn flatten_on_gpu(&mut self) -> Result<Option<u64>, GpuError> {
        let Some(op) = self.relighter.flatten_operator() else {
            return Ok(None);
        };
        let sharpen = self.relighter.sharpen_operator();
        let bytes = self.renderer.enable_gpu_flatten(self.gpu, op, sharpen)?;
        self.relighter.set_flatten_on_cpu(false);
        Ok(Some(bytes))
    }

    /// Relights for `light`, uploads the lighting as `redraw` says and renders the view of
    /// `camera`; `timed` waits after each GPU pass to time it.
    pub fn draw(
        &mut self,
        camera: &Camera,
        light: &Light,
        redraw: Redraw,
        timed: bool,
    ) -> Result<Drawn<'_>, GpuError> {
        // The relighter computes the flat coefficients of the functions this view splats.
        self.relighter
            .set_view(Some(&self.renderer.frustum(camera)));
        let frame = self.relighter.relight(light);
        let mut flatten_ms = 0.0;
        if redraw != Redraw::WhenRelit || !frame.reused {
            flatten_ms = upload(self.gpu, self.renderer, frame, timed)?;
            if redraw != Redraw::Lighting {
                self.renderer.invalidate();
            }
        }
        let mut gpu = self
            .renderer
            .render(self.gpu, self.ib, camera, light, timed)?;
        gpu.flatten_ms = flatten_ms;
        Ok(Drawn { frame, gpu })
    }
}

/// Hands a relit frame to the renderer: the hierarchical coefficients when it flattens on the
/// GPU, else the flat ones. Returns the GPU flattening time (0 on the CPU path).
pub fn upload(gpu: &Gpu, renderer: &Renderer, frame: &Frame, timed: bool) -> Result<f64, GpuError> {
    if renderer.flattens_on_gpu() && frame.flat.is_empty() {
        renderer.set_hierarchical_coefficients(gpu, &frame.i, timed)
    } else {
        renderer.set_coefficients(gpu, &frame.flat);
        Ok(0.0)
    }
}
