//! The passes of the deferred renderer (section 4.1), each owning its bind-group layout,
//! pipeline and `encode`; [`crate::gpu::renderer::Renderer::render`] runs them in order:
//! 1. [`gbuffer`]: world position, shading normal and albedo (textures included) per pixel;
//! 2. [`shadow`]: linear light distance, a cube of maps for a point light, one map for a spot;
//! 3. [`splat`]: every flat basis function that survives frustum culling, accumulated;
//! 4. [`resolve`]: direct, indirect and final linear radiance;
//! 5. [`display`]: a buffer or debug view, tone mapped, into a window or image, with
//!    [`points`] drawn over it in the basis-points view.
//!
//! Flattening, the compute pass that feeds the splatted coefficients when it runs on the GPU,
//! is [`crate::gpu::flatten`].

pub mod display;
pub mod gbuffer;
pub mod points;
pub mod resolve;
pub mod shadow;
pub mod splat;
