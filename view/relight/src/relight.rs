//! The interface of per-frame relighting (Lehtinen et al. 2008, section 3.3): a [`Relight`]
//! turns a light into a [`Frame`] (direct light, sender coefficients `e`, receiver
//! coefficients `i = S e` and, unless a renderer flattens on the GPU, the flat coefficients),
//! timed per stage ([`StageTimes`]). [`crate::CpuRelighter`] implements it on the CPU.

use serde::Serialize;

use crate::flatten_op::{FlattenOp, SharpenOp};
use crate::frustum::Frustum;
use crate::light::Light;
use mlt_format::flat_basis::FlatBasis;

/// Milliseconds per stage of one relit frame.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimes {
    pub direct_ms: f64,
    pub project_ms: f64,
    pub transport_ms: f64,
    /// The bounce-light feedback after `S e` (zero when off).
    pub feedback_ms: f64,
    pub flatten_ms: f64,
}

impl StageTimes {
    /// The CPU stages together.
    pub fn total_ms(&self) -> f64 {
        self.direct_ms + self.project_ms + self.transport_ms + self.feedback_ms + self.flatten_ms
    }
}

/// The lighting of one frame.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// Direct irradiance samples at the sender points, RGB. At the points whose sample the
    /// pull-push replaces (those with children, on all but the finest sender level) this is
    /// that replacement, the weighted average of the children's values, not a ray-cast sample.
    pub direct: Vec<f32>,
    /// Sender coefficients `e` (RGB per sender point).
    pub e: Vec<f32>,
    /// Receiver coefficients `i` of indirect vector irradiance (9 per point).
    pub i: Vec<f32>,
    /// Flat coefficients (9 per flat point), as
    /// [`mlt_format::flat_basis::FlatBasis::flatten`] of `i` computes them up to rounding (one
    /// `LINK_DIM` group per flat point); empty when
    /// flattening is left to the GPU ([`crate::CpuRelighter::flatten_on_cpu`]).
    pub flat: Vec<f32>,
    pub times: StageTimes,
    /// Senders whose links were applied.
    pub senders_used: usize,
    /// Shadow rays cast for the direct light.
    pub shadow_rays: u64,
    /// Sender points whose direct sample was averaged over their basis function (the light
    /// was within a few support radii).
    pub averaged_points: u64,
    /// Flat points whose rows the flattening product computed: all of them, or with a view
    /// ([`Relight::set_view`]) those it needs; 0 when the renderer flattens.
    pub flat_rows: usize,
    /// True when the light had not moved and the previous frame was reused (with a view
    /// whose rows it holds).
    pub reused: bool,
}

/// Per-frame relighting.
pub trait Relight {
    /// The lighting for `light`; recomputed only when the light changed.
    fn relight(&mut self, light: &Light) -> &Frame;

    /// The flat basis whose coefficients `Frame::flat` holds (what a renderer splats).
    fn flat_basis(&self) -> &FlatBasis;

    /// The precomputed flattening operator, for a renderer that flattens on the GPU.
    fn flatten_operator(&self) -> Option<&FlattenOp> {
        None
    }

    /// The sharpening applied after the flattening operator (`SharpenOp::steps` steps of
    /// `c_{k+1} = c_k + w_k (c_0 - W c_k)`), for a renderer that flattens on the GPU; `None` when
    /// the flat coefficients are not sharpened.
    fn sharpen_operator(&self) -> Option<&SharpenOp> {
        None
    }

    /// The view the next frames are drawn for: with one, an implementation may compute
    /// `Frame::flat` only for the flat points whose functions may meet its frustum (the
    /// others then hold stale values), and a frame for the same light but a view that needs
    /// more is recomputed (`Frame::reused` false). `None`: every flat point. Implementations
    /// that always compute every point ignore it.
    fn set_view(&mut self, _view: Option<&Frustum>) {}

    /// Whether step 4 (flattening) runs here; off when the renderer does it on the GPU from
    /// `Frame::i`. Implementations without an operator ignore it.
    fn set_flatten_on_cpu(&mut self, _on: bool) {}
}
