//! The viewer's library: the light model, per-frame relighting and probes.
//!
//! Status: the CPU side of the viewer (relighting and probes) is here; GPU rendering (G-buffer,
//! splatting, shadow maps, window and headless images) is not implemented yet.

pub mod light;
pub mod probe;
pub mod relight;

pub use light::Light;
pub use relight::{CpuRelighter, Frame, Relight, StageTimes};
