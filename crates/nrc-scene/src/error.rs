//! Errors of scene loading and image input/output. Every message names the file, mesh,
//! buffer or extension at fault so that one line tells the user what to fix.

use std::path::PathBuf;

/// Everything that can go wrong while loading a scene or reading/writing an image.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },

    /// The glTF document itself is malformed: invalid JSON, a truncated or corrupt `.glb`
    /// container, or a document that fails glTF validation.
    #[error("{}: not a valid glTF file: {message}", path.display())]
    Parse { path: PathBuf, message: String },

    /// The file lists an extension in `extensionsRequired` that this loader does not implement.
    #[error("{}: unsupported required glTF extension `{name}`", path.display())]
    UnsupportedExtension { path: PathBuf, name: String },

    /// A buffer could not be loaded (missing external file, bad data URI, too short).
    #[error("{}: buffer {index} ({uri}): {message}", path.display())]
    Buffer {
        path: PathBuf,
        index: usize,
        uri: String,
        message: String,
    },

    /// A texture image could not be loaded or decoded.
    #[error("{}: image {index} ({uri}): {message}", path.display())]
    Texture {
        path: PathBuf,
        index: usize,
        uri: String,
        message: String,
    },

    /// A mesh holds data that cannot be turned into triangles (non-finite positions,
    /// indices out of range, accessors of the wrong type or outside their buffer, ...).
    #[error("{}: mesh `{mesh}`: {message}", path.display())]
    Mesh {
        path: PathBuf,
        mesh: String,
        message: String,
    },

    /// Some other part of the document is invalid (a material, a camera, a node transform).
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },

    /// The scene holds no (non-degenerate) triangle to render.
    #[error("{}: the scene contains no triangles", path.display())]
    Empty { path: PathBuf },

    /// An image file (EXR, PNG) could not be encoded, decoded or has unusable contents.
    #[error("{}: {message}", path.display())]
    Image { path: PathBuf, message: String },
}

/// Shorthand for results of this crate.
pub type Result<T, E = SceneError> = std::result::Result<T, E>;
