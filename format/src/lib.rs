//! The baked representation of meshless hierarchical light transport (Lehtinen et al. 2008)
//! and the mathematics that reads it.
//!
//! - [`kernel`]: weight functions (Eqs. 8-10) and the Poisson-disk metric (Eq. 11);
//! - [`basis`]: the hierarchical point set; [`rtree`]: one R-tree per level;
//! - [`shepard`]: per-level Shepard basis (Eq. 2) and hierarchical reconstruction (Eq. 6);
//!   [`support_average`]: a point light's irradiance averaged over a basis function (the
//!   direct-light sample near the light, which the viewer and the bake's estimates share);
//!   [`support_clip`]: supports clipped at the occluders their points see;
//! - [`pull_push`]: coarse-to-fine projection `P` (Eq. 7) and pull-push `P-dagger`;
//! - [`flat_basis`]: the single-level basis the viewer splats, stored in a file by
//!   [`flat_section`]; [`flatten`]: resampling to a single level (the reference the viewer's precomputed
//!   operator is tested against); [`adjacency`]: neighbours, parents, children; [`morton`]:
//!   the point order;
//! - [`links`]: the stored direct-to-indirect operator `S`;
//! - [`container`], [`meta`], [`file`]: the versioned, memory-mappable file; [`light`]: the
//!   scene's light, from the manifest to the file; [`camera`]: the scene camera's primary rays.
//!
//! The per-frame operators built from a file (precomputed pull-push, receiver-major links,
//! sparse flattening) belong to the viewer's relighting crate, `mlt-relight`. This crate
//! depends on no mesh, GPU or windowing crate.

pub mod adjacency;
pub mod basis;
pub mod camera;
pub mod container;
pub mod error;
pub mod file;
pub mod flat_basis;
pub mod flat_section;
pub mod flatten;
pub mod kernel;
pub mod light;
pub mod light_model;
pub mod links;
pub mod meta;
pub mod morton;
pub mod pull_push;
pub mod rtree;
pub mod shard;
pub mod shepard;
pub mod support_average;
pub mod support_clip;
#[cfg(any(test, feature = "test-support"))]
pub mod test_support;

pub use basis::Basis;
pub use error::FormatError;
pub use file::{BakeContents, BakedFile, Transport, WriteOptions};
pub use meta::Meta;
pub use rtree::RTree;
pub use shepard::{IndexedBasis, Support};
