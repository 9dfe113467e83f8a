//! Per-frame relighting of a baked meshless hierarchical light transport file (Lehtinen et al.
//! 2008, section 3.3): from a light to the flat coefficients a renderer splats.
//!
//! - [`light`]: the point and spot light, and its direct irradiance;
//! - [`relight`]: the [`Relight`] interface, the [`Frame`] it produces and its [`StageTimes`];
//! - [`cpu`]: [`CpuRelighter`], the CPU implementation: direct light by shadow rays, then the
//!   three operators below, built once per file;
//! - [`support_average`] (from `mlt_format`, which the bake's estimates share): the direct
//!   light averaged over a sender's basis function, the sample of a light close to the surface;
//! - [`pull_push_op`]: the pull-push projection `e = P-dagger E` (section 2.1) with precomputed
//!   weights;
//! - [`receiver_links`]: `i = S e` receiver-major, the file's half floats converted in the
//!   product (sections 3.1-3.3);
//! - [`fine_bounce`]: bounces 2 and later at the finer receivers, which the bake leaves to
//!   the coarsest level, chained per frame through the level-0 coefficients of `S e`;
//! - [`bounce_feedback`]: the finer receivers' bounce light re-emitted through `S`'s level-0
//!   rows, the fixed point `i = S (e + P-dagger (n . R i) - y(i))` that the bake's chain of
//!   bounces through the coarsest receivers falls short of;
//! - [`flatten_op`]: the sparse flattening operator (section 4.1), whose packed arrays a GPU
//!   compute pass can also apply ([`flatten_op::FlattenOp::parts`]);
//! - [`frustum`] and [`view_cull`]: a view's frustum, and the blocks of flat points whose
//!   flattening and sharpening rows that view needs (the rest are left out of the products).
//!
//! Each operator gives the same bits for any rayon thread count. The file, the basis and the
//! reference (per-query) versions of these operators are in `mlt-format`.

pub mod bounce_feedback;
pub mod cpu;
pub mod error;
pub mod fine_bounce;
pub mod flatten_op;
pub mod frustum;
pub mod light;
pub mod pull_push_op;
pub mod receiver_links;
pub mod relight;
pub mod view_cull;
pub use mlt_format::support_average;

pub use bounce_feedback::{BounceFeedbackOp, ReconstructionParts};
pub use cpu::{CpuRelighter, FineEmission, LoadStats, NearLight};
pub use error::RelightError;
pub use fine_bounce::FineBounceOp;
pub use flatten_op::{
    FlattenOp, FlattenOptions, FlattenScratch, Kernel, RowMask, SharpenOp, SharpenScratch,
};
pub use frustum::Frustum;
pub use light::{Light, LightError};
pub use pull_push_op::{PullPushOp, PullPushParts};
pub use receiver_links::{ReceiverLinks, TransposedLinks};
pub use relight::{Frame, Relight, StageTimes};
pub use support_average::SupportAverage;
pub use view_cull::{FlatCulling, ViewMasks};
