//! Why a relighting operator cannot be built.

/// Errors of this crate.
#[derive(Debug, thiserror::Error)]
pub enum RelightError {
    /// The flattening operator does not fit its storage (32-bit offsets, 16-bit local
    /// columns) or was given inconsistent inputs.
    #[error("flattening operator: {0}")]
    FlattenOperator(String),
    /// A setting outside its range.
    #[error("{0}")]
    Invalid(String),
    /// The flat basis cannot be built on the given basis.
    #[error("flat basis: {0}")]
    FlatBasis(#[from] mlt_format::FormatError),
}
