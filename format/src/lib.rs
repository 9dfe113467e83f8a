//! The baked representation of meshless hierarchical light transport (Lehtinen et al. 2008)
//! and the mathematics that reads it.
//!
//! - [`kernel`]: weight functions (Eqs. 8-10) and the Poisson-disk metric (Eq. 11);
//! - [`basis`]: the hierarchical point set; [`rtree`]: one R-tree per level;
//! - [`shepard`]: per-level Shepard basis (Eq. 2) and hierarchical reconstruction (Eq. 6);
//! - [`pull_push`]: coarse-to-fine projection `P` (Eq. 7) and pull-push `P-dagger`;
//! - [`flatten`]: resampling to a single level, [`flatten_op`]: its precomputed sparse
//!   operator; [`adjacency`]: neighbours, parents, children; [`morton`]: the point order;
//! - [`container`], [`meta`], [`file`]: the versioned, memory-mappable file; [`light`]: the
//!   scene's light, from the manifest to the file.
//!
//! This crate depends on no mesh, GPU or windowing crate.

pub mod adjacency;
pub mod basis;
pub mod container;
pub mod error;
pub mod file;
pub mod flatten;
pub mod flatten_op;
pub mod kernel;
pub mod light;
pub mod links;
pub mod meta;
pub mod morton;
pub mod pull_push;
pub mod rtree;
pub mod shard;
pub mod shepard;

pub use basis::Basis;
pub use error::FormatError;
pub use file::{BakeContents, BakedFile, Transport, WriteOptions};
pub use meta::Meta;
pub use rtree::RTree;
pub use shepard::{IndexedBasis, Support};
