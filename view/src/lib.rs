//! The viewer's library: the camera model, the wgpu renderer (section 4.1), headless rendering
//! and the window, on top of the per-frame relighting of `mlt-relight` (section 3.3; its main
//! types are re-exported here).

pub mod camera;
pub mod compare;
pub mod gpu;
pub mod headless;
pub mod images;
pub mod probe;
pub mod reference;
pub mod window;

pub use camera::Camera;
pub use images::RgbImage;
pub use mlt_relight::{CpuRelighter, Frame, Light, Relight, StageTimes};
