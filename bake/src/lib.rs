//! The offline bake of meshless hierarchical light transport (Lehtinen et al. 2008): scene in,
//! basis file out. The `bake` binary is a thin command line over [`bake_scene`].
//!
//! - [`albedo`]: the check that refuses an albedo of 1 or more before any work;
//! - [`candidates`]: importance particles from the viewpoint (section 2.3);
//! - [`poisson`], [`grid`]: dart throwing in the metric of Eq. 11 with the harmonic mean
//!   distance test; [`placement`]: the hierarchy of levels and the `R_coarse` search;
//! - [`gather`]: the hemispherical gather of Eq. 16, with [`sender_cells`] evaluating the
//!   senders' weights at its hits from per-cell lists instead of R-tree queries;
//! - [`occluders`]: the clip planes of the basis functions' supports, from a ring of rays along each
//!   point's surface (so that no function reaches under a wall);
//! - [`params`]: the bake's parameters, one struct for the command line, manifests and batch
//!   jobs ([`BakeOptions`]), and their resolution;
//! - [`pipeline`]: everything together, with statistics; [`report`]: human-readable output.

pub mod albedo;
pub mod batch;
pub mod camera_check;
pub mod candidates;
pub mod coverage;
pub mod drop_estimate;
pub mod error;
pub mod gather;
pub mod grid;
pub mod neumann;
pub mod observer;
pub mod occluders;
pub mod output_check;
pub mod params;
pub mod path_bounces;
pub mod pipeline;
pub mod placement;
pub mod poisson;
pub mod refine;
pub mod report;
pub mod rng;
pub mod sender_cells;
pub mod shard;
pub mod surface_samples;
pub mod table1;
pub mod transport;

pub use error::BakeError;
pub use observer::{Observer, Silent};
pub use params::{BakeOptions, Preset};
pub use pipeline::{bake_scene, tool_version, BakeOutput};
