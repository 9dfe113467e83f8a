//! Errors of the format crate.

use std::path::PathBuf;

/// Everything that can go wrong reading, writing or validating a baked file.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: not a baked light-transport file (bad magic bytes)")]
    BadMagic { path: PathBuf },
    #[error(
        "{path}: format version {major}.{minor} is not supported (this build reads {supported}.x)"
    )]
    WrongVersion {
        path: PathBuf,
        major: u16,
        minor: u16,
        supported: u16,
    },
    #[error("{path}: truncated or malformed: {detail}")]
    Truncated { path: PathBuf, detail: String },
    #[error("{path}: checksum mismatch in {what} (stored {stored:016x}, computed {computed:016x}); the file is corrupted")]
    Checksum {
        path: PathBuf,
        what: &'static str,
        stored: u64,
        computed: u64,
    },
    #[error("{path}: required section '{tag}' is missing")]
    MissingSection { path: PathBuf, tag: String },
    #[error("{path}: section '{tag}' is invalid: {detail}")]
    BadSection {
        path: PathBuf,
        tag: String,
        detail: String,
    },
    #[error("invalid basis: {0}")]
    InvalidBasis(String),
    #[error("serialising section '{tag}': {detail}")]
    Serialize { tag: String, detail: String },
}
