//! Linear RGB frames: OpenEXR input and output (32-bit float, lossless) and an 8-bit PNG
//! preview for people (exposure, ACES filmic tone curve, sRGB encoding).
//!
//! Files are written atomically: to a temporary name in the destination folder, then
//! renamed, so that a reader never sees a half-written file.

use std::io::Write;
use std::path::Path;

use glam::Vec3;

use crate::error::{Result, SceneError};
use crate::texture::linear_to_srgb;

/// A frame of linear RGB radiance values, row-major, first row at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<Vec3>,
}

impl Image {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![Vec3::ZERO; width * height],
        }
    }

    /// An image from row-major pixels; `None` when the count does not match.
    pub fn from_data(width: usize, height: usize, data: Vec<Vec3>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// The pixel at column `x`, row `y`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Vec3 {
        self.data[y * self.width + x]
    }

    /// Sets the pixel at column `x`, row `y`.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: Vec3) {
        self.data[y * self.width + x] = v;
    }

    /// Mean of all pixels (in double precision).
    pub fn mean(&self) -> Vec3 {
        let sum = self
            .data
            .iter()
            .fold(glam::DVec3::ZERO, |s, p| s + p.as_dvec3());
        (sum / self.data.len().max(1) as f64).as_vec3()
    }

    /// Writes a 32-bit float RGB OpenEXR file (lossless compression).
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
        let err = |message: String| SceneError::Image {
            path: path.to_path_buf(),
            message,
        };
        if self.width == 0 || self.height == 0 {
            return Err(err("cannot write an empty image".into()));
        }
        let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
            let p = self.data[y * self.width + x];
            (p.x, p.y, p.z)
        });
        let mut bytes = Vec::new();
        exr::image::Image::from_channels((self.width, self.height), channels)
            .write()
            .to_buffered(std::io::Cursor::new(&mut bytes))
            .map_err(|e| err(format!("cannot encode EXR: {e}")))?;
        write_atomic(path, &bytes)
    }

    /// Reads the RGB channels of the first layer of an OpenEXR file (any sample type,
    /// converted to f32).
    pub fn read_exr(path: &Path) -> Result<Image> {
        let image = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |resolution, _| Image::new(resolution.width(), resolution.height()),
            |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                img.set(pos.x(), pos.y(), Vec3::new(r, g, b))
            },
        )
        .map_err(|e| match e {
            exr::error::Error::Io(source) => SceneError::Io {
                path: path.to_path_buf(),
                source,
            },
            e => SceneError::Image {
                path: path.to_path_buf(),
                message: format!("cannot read EXR: {e}"),
            },
        })?;
        Ok(image.layer_data.channel_data.pixels)
    }

    /// The 8-bit sRGB preview of the image: scaled by `2^exposure_stops`, tone mapped by
    /// the ACES filmic curve fit of Narkowicz 2015, sRGB encoded. Non-finite or negative
    /// values show as black. Row-major RGB bytes.
    pub fn to_srgb8(&self, exposure_stops: f32) -> Vec<u8> {
        let scale = exposure_stops.exp2();
        self.data
            .iter()
            .flat_map(|p| {
                let c = *p * scale;
                [c.x, c.y, c.z].map(|v| {
                    let v = if v.is_finite() { v.max(0.0) } else { 0.0 };
                    (linear_to_srgb(aces_filmic(v)) * 255.0 + 0.5) as u8
                })
            })
            .collect()
    }

    /// Writes the 8-bit tone-mapped preview (see [`Image::to_srgb8`]) as a PNG file.
    pub fn write_png_preview(&self, path: &Path, exposure_stops: f32) -> Result<()> {
        let err = |message: String| SceneError::Image {
            path: path.to_path_buf(),
            message,
        };
        if self.width == 0 || self.height == 0 {
            return Err(err("cannot write an empty image".into()));
        }
        let (w, h) = (
            u32::try_from(self.width).map_err(|_| err("image too wide".into()))?,
            u32::try_from(self.height).map_err(|_| err("image too tall".into()))?,
        );
        let mut bytes = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut bytes, w, h);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            let mut writer = encoder
                .write_header()
                .map_err(|e| err(format!("cannot encode PNG: {e}")))?;
            writer
                .write_image_data(&self.to_srgb8(exposure_stops))
                .map_err(|e| err(format!("cannot encode PNG: {e}")))?;
            writer
                .finish()
                .map_err(|e| err(format!("cannot encode PNG: {e}")))?;
        }
        write_atomic(path, &bytes)
    }
}

/// The ACES filmic tone curve as fitted by Narkowicz 2015, clamped to `[0, 1]`.
#[inline]
pub fn aces_filmic(x: f32) -> f32 {
    const A: f32 = 2.51;
    const B: f32 = 0.03;
    const C: f32 = 2.43;
    const D: f32 = 0.59;
    const E: f32 = 0.14;
    ((x * (A * x + B)) / (x * (C * x + D) + E)).clamp(0.0, 1.0)
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder (the `tempfile`
/// crate, as everywhere in the project), flushed to disk, then renamed over the destination.
/// The file gets the permissions `File::create` would give (0o666 less the umask), not
/// tempfile's private 0o600. The one atomic write of the scene, render and evaluation outputs
/// (the cache's snapshots, which know nothing of scenes, do the same in `nrc-cache`).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source: std::io::Error| SceneError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".nrc-").suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir).map_err(io)?;
    tmp.write_all(bytes).map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_curve_is_monotone_and_bounded() {
        let mut last = -1.0;
        for i in 0..1000 {
            let y = aces_filmic(i as f32 * 0.05);
            assert!(y >= last && (0.0..=1.0).contains(&y));
            last = y;
        }
        assert_eq!(aces_filmic(0.0), 0.0);
        assert!(aces_filmic(1e6) > 0.99);
    }

    #[test]
    fn preview_bytes_handle_bad_values() {
        let img = Image::from_data(
            3,
            1,
            vec![
                Vec3::ZERO,
                Vec3::new(f32::NAN, -1.0, f32::INFINITY),
                Vec3::splat(1e9),
            ],
        )
        .unwrap();
        assert_eq!(img.to_srgb8(0.0), vec![0, 0, 0, 0, 0, 0, 255, 255, 255]);
    }
}
