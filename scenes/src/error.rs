//! Errors raised while loading scenes. Every variant names the file (or built-in) it concerns
//! and what is wrong with it, so a message alone is enough to find the problem.

use std::path::PathBuf;

/// Why a scene could not be loaded.
#[derive(thiserror::Error, Debug)]
pub enum SceneError {
    /// The file could not be opened or read.
    #[error("{}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },

    /// The file extension is not one of `.toml`, `.obj`, `.gltf`, `.glb`.
    #[error("{}: unknown scene format (expected .toml, .obj, .gltf, .glb or builtin:NAME)", path.display())]
    UnknownFormat { path: PathBuf },

    /// The OBJ (or its MTL) could not be parsed.
    #[error("{}: {message}", path.display())]
    Obj { path: PathBuf, message: String },

    /// The glTF file could not be parsed or imported.
    #[error("{}: {message}", path.display())]
    Gltf { path: PathBuf, message: String },

    /// The TOML manifest is malformed or inconsistent.
    #[error("{}: {message}", path.display())]
    Manifest { path: PathBuf, message: String },

    /// The file has no triangles left to cast rays against.
    #[error("{}: no triangles (after dropping points, lines and zero-area triangles)", path.display())]
    NoTriangles { path: PathBuf },

    /// A NaN or infinite number where a finite one is required.
    #[error("{}: {what} is not finite (NaN or infinity)", path.display())]
    NonFinite { path: PathBuf, what: String },

    /// A triangle refers to a vertex that does not exist.
    #[error(
        "{}: triangle {triangle} refers to vertex {index}, but there are only {vertex_count} vertices",
        path.display()
    )]
    IndexOutOfRange {
        path: PathBuf,
        triangle: usize,
        index: u32,
        vertex_count: usize,
    },

    /// A structurally inconsistent mesh (attribute counts that do not match, a material
    /// index out of range, a negative albedo).
    #[error("{}: {message}", path.display())]
    InvalidMesh { path: PathBuf, message: String },

    /// A texture could not be decoded or is malformed.
    #[error("{}: texture: {message}", path.display())]
    Texture { path: PathBuf, message: String },

    /// An unknown built-in scene, an unknown parameter, or a bad parameter value.
    #[error("builtin:{name}: {message}")]
    Builtin { name: String, message: String },

    /// A light that cannot be used (spot without direction, cone out of range, ...).
    #[error("{}: invalid light: {message}", path.display())]
    InvalidLight { path: PathBuf, message: String },
}

impl SceneError {
    /// Shorthand for [`SceneError::Io`].
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        SceneError::Io {
            path: path.into(),
            error,
        }
    }
}
