//! Atomic file output: every file is written to a temporary name in its target directory and
//! renamed over the target, so readers never see a half-written report, plot or image.

use std::path::Path;

use crate::error::{EvalError, Result};

/// Writes `bytes` to `path` atomically (the project's one way,
/// [`nrc_scene::image::write_atomic`]: a temporary file in the same directory, then renamed).
pub fn atomic_write(path: &Path, bytes: &[u8]) -> Result<()> {
    nrc_scene::image::write_atomic(path, bytes).map_err(|e| EvalError::Io {
        action: "writing",
        path: path.to_path_buf(),
        source: match e {
            nrc_scene::SceneError::Io { source, .. } => source,
            other => std::io::Error::other(other.to_string()),
        },
    })
}

/// Encodes 8-bit RGB pixels (row-major, top row first) as PNG bytes.
pub(crate) fn encode_png_rgb8(
    path_for_errors: &Path,
    width: usize,
    height: usize,
    rgb: &[u8],
) -> Result<Vec<u8>> {
    let draw_err = |reason: String| EvalError::Draw {
        path: path_for_errors.to_path_buf(),
        reason,
    };
    let (w, h) = (
        u32::try_from(width).map_err(|e| draw_err(e.to_string()))?,
        u32::try_from(height).map_err(|e| draw_err(e.to_string()))?,
    );
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, w, h);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder
            .write_header()
            .map_err(|e| draw_err(format!("PNG header: {e}")))?;
        writer
            .write_image_data(rgb)
            .map_err(|e| draw_err(format!("PNG data: {e}")))?;
        writer
            .finish()
            .map_err(|e| draw_err(format!("PNG finish: {e}")))?;
    }
    Ok(out)
}
