//! The viewer's library: camera and light models, per-frame CPU relighting (section 3.3), the
//! wgpu renderer (section 4.1), headless rendering and the window.

pub mod camera;
pub mod compare;
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
