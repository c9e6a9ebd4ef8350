//! PNG output for people: false-colour error images (per-pixel relMSE, FLIP, … through a
//! perceptual colour map) and display-ready versions of linear HDR renders. Written atomically.

use std::path::Path;

use crate::atomic::{atomic_write, encode_png_rgb8};
use crate::error::{EvalError, Result};
use crate::image::{ImageView, ScalarImage};

/// A perceptually uniform colour map (d3's, via `colorous`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorMap {
    /// Black → purple → yellow-white; FLIP's customary map.
    Magma,
    /// Purple → green → yellow.
    Viridis,
}

/// How error values map to the colour map's [0, 1] domain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scale {
    /// `(v − min) / (max − min)`, clamped.
    Linear { min: f32, max: f32 },
    /// `(ln v − ln min) / (ln max − ln min)`, clamped; values ≤ min get the map's bottom colour.
    Log { min: f32, max: f32 },
}

impl Scale {
    /// Log scale spanning the map's largest value and six decades below it (or the smallest
    /// positive value, if that is closer); a map of zeros gets `[1e-6, 1]`.
    pub fn auto_log(map: &ScalarImage) -> Scale {
        let max = map
            .values
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max);
        if max <= 0.0 {
            return Scale::Log {
                min: 1e-6,
                max: 1.0,
            };
        }
        let min_pos = map
            .values
            .iter()
            .copied()
            .filter(|&v| v > 0.0 && v.is_finite())
            .fold(max, f32::min);
        Scale::Log {
            min: min_pos.max(max * 1e-6).min(max * 0.5),
            max,
        }
    }

    fn normalise(self, v: f32) -> f32 {
        let t = match self {
            Scale::Linear { min, max } => (v - min) / (max - min),
            Scale::Log { min, max } => {
                if v <= min {
                    0.0
                } else {
                    (v.ln() - min.ln()) / (max.ln() - min.ln())
                }
            }
        };
        if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) }
    }

    fn validate(self) -> Result<()> {
        let ok = match self {
            Scale::Linear { min, max } => min.is_finite() && max.is_finite() && max > min,
            Scale::Log { min, max } => min.is_finite() && max.is_finite() && min > 0.0 && max > min,
        };
        if ok {
            Ok(())
        } else {
            Err(EvalError::InvalidParameter {
                name: "scale",
                reason: format!("{self:?} is not a valid range"),
            })
        }
    }
}

/// 8-bit RGB pixels of `map` through `colors` on `scale`.
pub fn false_color_rgb8(map: &ScalarImage, colors: ColorMap, scale: Scale) -> Result<Vec<u8>> {
    scale.validate()?;
    let gradient = match colors {
        ColorMap::Magma => colorous::MAGMA,
        ColorMap::Viridis => colorous::VIRIDIS,
    };
    Ok(map
        .values
        .iter()
        .flat_map(|&v| {
            let c = gradient.eval_continuous(scale.normalise(v) as f64);
            [c.r, c.g, c.b]
        })
        .collect())
}

/// Writes `map` as a false-colour PNG at `path` (atomically).
pub fn write_false_color_png(
    path: &Path,
    map: &ScalarImage,
    colors: ColorMap,
    scale: Scale,
) -> Result<()> {
    if map.values.len() != map.width * map.height {
        return Err(EvalError::BadDimensions {
            name: path.display().to_string(),
            width: map.width,
            height: map.height,
            expected: map.width * map.height,
            actual: map.values.len(),
        });
    }
    let rgb = false_color_rgb8(map, colors, scale)?;
    write_rgb8_png(path, map.width, map.height, &rgb)
}

/// Writes 8-bit RGB pixels (row-major, already encoded for display) as a PNG at `path`
/// (atomically).
pub fn write_rgb8_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<()> {
    atomic_write(path, &encode_png_rgb8(path, width, height, rgb)?)
}

/// Writes a linear HDR image as an sRGB PNG for viewing: scaled by 2^`exposure`, clamped to
/// [0, 1] and sRGB-encoded (no tone curve, so values above 1 clip). NaN becomes black.
pub fn write_srgb_png(path: &Path, image: &ImageView<'_>, exposure: f32) -> Result<()> {
    let scale = 2.0f32.powf(exposure);
    let encode = |v: f32| {
        let l = if v.is_nan() {
            0.0
        } else {
            (v * scale).clamp(0.0, 1.0)
        };
        let s = if l <= 0.003_130_8 {
            12.92 * l
        } else {
            1.055 * l.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5) as u8
    };
    let rgb: Vec<u8> = image.pixels().iter().flat_map(|p| p.map(encode)).collect();
    atomic_write(
        path,
        &encode_png_rgb8(path, image.width(), image.height(), &rgb)?,
    )
}
