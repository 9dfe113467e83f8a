//! The viewer's library: the camera model, the wgpu renderer (section 4.1), the frame driver
//! that the window and headless rendering share, the path-traced reference and the image
//! comparison, the exact per-pixel evaluation of the indirect image, on top of the per-frame relighting of `mlt-relight` (section 3.3; its main types
//! are re-exported here).

pub mod breakdown;
pub mod camera;
pub mod compare;
pub mod exact;
pub mod flat_check;
pub mod frame;
pub mod gpu;
pub mod headless;
pub mod images;
pub mod oracle;
pub mod probe;
pub mod reference;
pub mod window;

pub use camera::Camera;
pub use images::RgbImage;
pub use mlt_relight::{CpuRelighter, Frame, Frustum, Light, Relight, StageTimes};
