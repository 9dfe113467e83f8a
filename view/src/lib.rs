//! The viewer's library: camera and light models, per-frame CPU relighting (section 3.3), the
//! wgpu renderer (section 4.1), the frame driver that the window and headless rendering share,
//! the path-traced reference and the image comparison.

pub mod camera;
pub mod compare;
pub mod frame;
pub mod gpu;
pub mod headless;
pub mod images;
pub mod light;
pub mod probe;
pub mod reference;
pub mod relight;
pub mod window;

pub use camera::Camera;
pub use images::RgbImage;
pub use light::Light;
pub use relight::{CpuRelighter, Frame, Relight, StageTimes};
