//! Plain linear-RGB images as the metrics see them: a borrowed view over `[[f32; 3]]` pixels
//! in row-major order (top row first) and a small owned buffer for computed images.
//!
//! Any image type plugs in by lending its pixel slice: `ImageView::new("render", w, h, &pixels)`;
//! the renderer's frames (`nrc_scene::image::Image`) with [`ImageView::of_scene_image`].

use crate::error::{EvalError, Result};

/// A borrowed, named, row-major linear-RGB image. The name appears in error messages.
#[derive(Clone, Copy, Debug)]
pub struct ImageView<'a> {
    name: &'a str,
    width: usize,
    height: usize,
    pixels: &'a [[f32; 3]],
}

impl<'a> ImageView<'a> {
    /// Wraps `pixels` (row-major, top row first); fails when the length is not `width * height`
    /// or a dimension is zero.
    pub fn new(name: &'a str, width: usize, height: usize, pixels: &'a [[f32; 3]]) -> Result<Self> {
        let expected = width.saturating_mul(height);
        if width == 0 || height == 0 || pixels.len() != expected {
            return Err(EvalError::BadDimensions {
                name: name.to_string(),
                width,
                height,
                expected,
                actual: pixels.len(),
            });
        }
        Ok(Self {
            name,
            width,
            height,
            pixels,
        })
    }

    /// A zero-copy view of a rendered frame.
    pub fn of_scene_image(name: &'a str, image: &'a nrc_scene::image::Image) -> Result<Self> {
        Self::new(
            name,
            image.width,
            image.height,
            bytemuck::cast_slice(&image.data),
        )
    }

    pub fn name(&self) -> &'a str {
        self.name
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn pixels(&self) -> &'a [[f32; 3]] {
        self.pixels
    }

    /// Pixel at column `x`, row `y` (row 0 is the top).
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.pixels[y * self.width + x]
    }

    /// Fails with [`EvalError::NonFinite`] naming the first NaN or infinite value.
    pub fn check_finite(&self) -> Result<()> {
        for (i, p) in self.pixels.iter().enumerate() {
            for (c, &v) in p.iter().enumerate() {
                if !v.is_finite() {
                    return Err(EvalError::NonFinite {
                        name: self.name.to_string(),
                        x: i % self.width,
                        y: i / self.width,
                        channel: c,
                        value: v,
                    });
                }
            }
        }
        Ok(())
    }

    /// Fails with [`EvalError::SizeMismatch`] unless `other` has the same size.
    pub fn check_same_size(&self, other: &ImageView<'_>) -> Result<()> {
        if self.width != other.width || self.height != other.height {
            return Err(EvalError::SizeMismatch {
                a_name: self.name.to_string(),
                a_w: self.width,
                a_h: self.height,
                b_name: other.name.to_string(),
                b_w: other.width,
                b_h: other.height,
            });
        }
        Ok(())
    }
}

/// An owned row-major linear-RGB image (per-pixel means, variances and the like).
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    /// The same pixels as a scene image (for EXR output).
    pub fn into_scene_image(self) -> nrc_scene::image::Image {
        let data = self
            .pixels
            .into_iter()
            .map(glam::Vec3::from_array)
            .collect();
        nrc_scene::image::Image {
            width: self.width,
            height: self.height,
            data,
        }
    }

    /// A view of this image under `name`.
    pub fn view<'a>(&'a self, name: &'a str) -> ImageView<'a> {
        ImageView {
            name,
            width: self.width,
            height: self.height,
            pixels: &self.pixels,
        }
    }
}

/// An owned row-major single-channel image (per-pixel error maps).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalarImage {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

impl ScalarImage {
    /// Mean of all values, accumulated in f64.
    pub fn mean(&self) -> f64 {
        if self.values.is_empty() {
            return 0.0;
        }
        self.values.iter().map(|&v| v as f64).sum::<f64>() / self.values.len() as f64
    }
}

/// Checks a test/reference pair: same size, all values finite.
pub(crate) fn check_pair(test: &ImageView<'_>, reference: &ImageView<'_>) -> Result<()> {
    test.check_same_size(reference)?;
    test.check_finite()?;
    reference.check_finite()
}
