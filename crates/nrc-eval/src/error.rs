//! The one error type of the evaluation crate: every bad input names what was wrong.

use std::path::PathBuf;

/// Errors of metric computation, report writing and plotting.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A pixel slice does not hold `width * height` pixels, or a dimension is zero.
    #[error("image '{name}': {width}x{height} needs {expected} pixels, got {actual}")]
    BadDimensions {
        name: String,
        width: usize,
        height: usize,
        expected: usize,
        actual: usize,
    },

    /// Two images that must be the same size are not.
    #[error("image size mismatch: {a_name} is {a_w}x{a_h}, {b_name} is {b_w}x{b_h}")]
    SizeMismatch {
        a_name: String,
        a_w: usize,
        a_h: usize,
        b_name: String,
        b_w: usize,
        b_h: usize,
    },

    /// A pixel holds NaN or infinity.
    #[error("image '{name}': non-finite value {value} at pixel ({x}, {y}) channel {channel}")]
    NonFinite {
        name: String,
        x: usize,
        y: usize,
        channel: usize,
        value: f32,
    },

    /// A parameter is out of its valid range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter { name: &'static str, reason: String },

    /// Not enough data for the requested statistic (e.g. variance from fewer than 2 renders).
    #[error("not enough data: {0}")]
    NotEnoughData(String),

    /// Reading or writing a file failed.
    #[error("{action} '{path}': {source}")]
    Io {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A report could not be (de)serialised.
    #[error("report JSON '{path}': {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },

    /// Drawing a plot or encoding an image failed.
    #[error("drawing '{path}': {reason}")]
    Draw { path: PathBuf, reason: String },
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, EvalError>;
