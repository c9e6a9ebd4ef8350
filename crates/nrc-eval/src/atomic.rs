//! Atomic file output: every file is written to a temporary name in its target directory and
//! renamed over the target, so readers never see a half-written report, plot or image.

use std::io::Write;
use std::path::Path;

use crate::error::{EvalError, Result};

/// Writes `bytes` to `path` atomically (temporary file in the same directory, then rename).
pub fn atomic_write(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |action: &'static str| {
        move |source: std::io::Error| EvalError::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".nrc-eval-")
        .tempfile_in(dir)
        .map_err(io("creating a temporary file for"))?;
    tmp.write_all(bytes).map_err(io("writing"))?;
    tmp.as_file().sync_all().map_err(io("syncing"))?;
    tmp.persist(path)
        .map_err(|e| io("renaming the temporary file onto")(e.error))?;
    Ok(())
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
