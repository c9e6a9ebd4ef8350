//! Errors of the cache: every message names what was wrong.

/// Everything that can go wrong in the cache's public API.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum CacheError {
    /// A configuration field is malformed or out of range.
    #[error("invalid cache configuration: {field}: {message}")]
    Config {
        /// JSON path of the field (`encoding.nested[0].n_levels`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// A snapshot is truncated, corrupted, foreign or does not match.
    #[error("invalid cache snapshot {path}: {message}")]
    Snapshot {
        /// The file.
        path: String,
        /// What is wrong with it.
        message: String,
    },
    /// The requested compute device cannot be used.
    #[error("cache device: {0}")]
    Device(String),
    /// Malformed call arguments (mismatched lengths, ...).
    #[error("invalid input: {0}")]
    Input(String),
}
