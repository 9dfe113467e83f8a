//! Errors of the bake library.

use mlt_format::FormatError;
use mlt_scenes::SceneError;

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("{path}: {message}")]
    Batch {
        path: std::path::PathBuf,
        message: String,
    },
    /// A manifest's `[bake]` table or a batch job's table that does not parse.
    #[error("{path}: {message}")]
    Options {
        path: std::path::PathBuf,
        message: String,
    },
    #[error("cannot merge the shards: {0}")]
    Merge(String),
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    #[error("{scene}: no importance particle from the viewpoint {viewpoint:?} reached a surface; is the viewpoint inside the scene?")]
    NoCandidates { scene: String, viewpoint: [f32; 3] },
    #[error("the light transport does not converge: the estimated spectral radius of the bounce operator is {spectral_radius:.5}, at or too close to 1 for S = T + T^2 + ... to converge; is an albedo 1 or more?")]
    Divergent { spectral_radius: f64 },
    #[error("{scene}: {what} has albedo {albedo:?}, not below 1 in every channel: it loses no energy, so the bounces cannot converge; lower it below 1 (real surfaces reflect at most about 0.9)")]
    AlbedoNotBelowOne {
        scene: String,
        what: String,
        albedo: [f32; 3],
    },
    #[error("{scene}: the viewpoint {viewpoint:?} is not finite")]
    BadViewpoint { scene: String, viewpoint: [f32; 3] },
}
