//! GPU rendering with wgpu (Lehtinen et al. 2008, section 4.1): a deferred renderer that
//! splats the flat basis, composited with shadow-mapped direct light.
//!
//! - [`context`]: the device (headless or for a window), with a clear error when there is none;
//! - [`mesh`]: the scene's triangles as GPU vertex data, grouped by material;
//! - [`cull`]: frustum culling of basis functions with the R-tree's nodes;
//! - [`flatten`]: the flattening operator as a compute pass;
//! - [`uniforms`]: camera, light and shadow-face parameters in the shaders' layout;
//! - [`renderer`]: the passes (G-buffer, shadow maps, splatting, resolve, display);
//! - [`readback`]: copying textures back to the CPU.

pub mod context;
pub mod cull;
pub mod flatten;
pub mod mesh;
pub mod readback;
pub mod renderer;
pub mod uniforms;

pub use context::{Gpu, GpuError};
pub use renderer::{Buffers, GBuffer, RenderTimes, Renderer, ViewMode};
