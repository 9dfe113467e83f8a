//! GPU rendering with wgpu (Lehtinen et al. 2008, section 4.1): a deferred renderer that
//! splats the flat basis, composited with shadow-mapped direct light.
//!
//! - [`bvh`]: a bounding volume hierarchy of the triangles, for the GPU's shadow rays;
//! - [`context`]: the device (headless or for a window), with a clear error when there is none;
//! - [`mesh`]: the scene's triangles as GPU vertex data, grouped by material;
//! - [`materials`]: the mesh's albedo colours and textures as bind groups;
//! - [`scene_buffers`]: vertices, per-frame globals, basis points and their coefficients;
//! - [`cull`]: frustum culling of basis functions through the R-tree's visitor;
//! - [`flatten`]: the flattening operator as a compute pass;
//! - [`relight`]: the relighting after the direct light as compute passes ([`GpuRelighter`]);
//! - [`uniforms`]: camera, light and shadow-face parameters in the shaders' layout;
//! - [`pipeline`]: the boilerplate the passes share (layouts, the pipeline helper);
//! - [`targets`]: the image-sized render targets;
//! - [`passes`]: one module per pass (G-buffer, shadow maps, splatting, resolve, display,
//!   points);
//! - [`renderer`]: the renderer of a scene, running the passes frame by frame;
//! - [`readback`]: copying textures back to the CPU.

pub mod bvh;
pub mod context;
pub mod cull;
pub mod flatten;
pub mod materials;
pub mod mesh;
pub mod passes;
pub mod pipeline;
pub mod readback;
pub mod relight;
pub mod renderer;
pub mod scene_buffers;
pub mod targets;
pub mod uniforms;

pub use context::{Gpu, GpuError};
pub use relight::{BoundGpuRelighter, GpuArray, GpuRelighter};
pub use renderer::{Buffers, GBuffer, RenderTimes, Renderer, ViewMode};
