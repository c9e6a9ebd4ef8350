//! Bias and variance of an estimator from R independent renders (distinct seeds, same method
//! state), as the NRC thesis reports them from 1,000 renders at 1 spp.
//!
//! Per pixel and channel, with renders `x_1 … x_R`, their mean `x̄` and sample variance
//! `s² = Σ (x_r − x̄)² / (R − 1)` (Welford's streaming update, so renders need not be kept):
//!
//! - **variance** = image average of `s²`: the variance of one render (unbiased for σ²).
//! - **bias²** = image average of `(x̄ − y)² − s²/R − v_ref`, where `y` is the reference and
//!   `v_ref` its own per-pixel variance of the mean, if known. Because `E[(x̄ − y)²] =
//!   bias² + σ²/R + v_ref`, this is an unbiased estimate of the squared bias; it can come out
//!   slightly negative for an unbiased method. The uncorrected `(x̄ − y)²` average is reported as
//!   `bias_sq_raw`.
//!
//! Then `bias² + variance` estimates the MSE of a single render.

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::image::{ImageView, RgbImage, check_pair};

/// Image-averaged bias and variance of an estimator.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BiasVariance {
    /// Number of renders R.
    pub renders: usize,
    /// Unbiased estimate of the squared bias (corrected for the noise of the mean and of the reference).
    pub bias_sq: f64,
    /// Image average of `(x̄ − y)²` without the corrections.
    pub bias_sq_raw: f64,
    /// Image average of the per-pixel sample variance of one render.
    pub variance: f64,
}

/// Streaming per-pixel mean and variance over renders (Welford), accumulated in f64.
#[derive(Clone, Debug)]
pub struct BiasVarianceAccumulator {
    width: usize,
    height: usize,
    count: usize,
    mean: Vec<[f64; 3]>,
    m2: Vec<[f64; 3]>,
}

impl BiasVarianceAccumulator {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            count: 0,
            mean: vec![[0.0; 3]; width * height],
            m2: vec![[0.0; 3]; width * height],
        }
    }

    /// Number of renders added so far.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Adds one render; it must match the accumulator's size and be finite.
    pub fn add(&mut self, render: &ImageView<'_>) -> Result<()> {
        if render.width() != self.width || render.height() != self.height {
            return Err(EvalError::SizeMismatch {
                a_name: render.name().to_string(),
                a_w: render.width(),
                a_h: render.height(),
                b_name: "earlier renders".to_string(),
                b_w: self.width,
                b_h: self.height,
            });
        }
        render.check_finite()?;
        self.count += 1;
        let n = self.count as f64;
        for ((m, m2), p) in self.mean.iter_mut().zip(&mut self.m2).zip(render.pixels()) {
            for c in 0..3 {
                let x = p[c] as f64;
                let delta = x - m[c];
                m[c] += delta / n;
                m2[c] += delta * (x - m[c]);
            }
        }
        Ok(())
    }

    /// Per-pixel mean of the renders.
    pub fn mean_image(&self) -> RgbImage {
        RgbImage {
            width: self.width,
            height: self.height,
            pixels: self.mean.iter().map(|m| m.map(|v| v as f32)).collect(),
        }
    }

    /// Per-pixel sample variance (denominator R − 1) of one render.
    pub fn variance_image(&self) -> Result<RgbImage> {
        let denom = self.variance_denominator()?;
        Ok(RgbImage {
            width: self.width,
            height: self.height,
            pixels: self
                .m2
                .iter()
                .map(|m| m.map(|v| (v / denom) as f32))
                .collect(),
        })
    }

    fn variance_denominator(&self) -> Result<f64> {
        if self.count < 2 {
            return Err(EvalError::NotEnoughData(format!(
                "variance needs at least 2 renders, got {}",
                self.count
            )));
        }
        Ok((self.count - 1) as f64)
    }

    /// Bias² and variance against `reference`. `reference_variance`, when given, is the
    /// per-pixel variance of the reference's own estimate (its sample variance divided by its
    /// sample count), subtracted from the bias².
    pub fn finish(
        &self,
        reference: &ImageView<'_>,
        reference_variance: Option<&ImageView<'_>>,
    ) -> Result<BiasVariance> {
        if let Some(rv) = reference_variance {
            check_pair(rv, reference)?;
        }
        self.weighted(reference, reference_variance, |_| 1.0)
    }

    /// The decomposition per pixel (the channels averaged): red the estimated MSE of one
    /// render, `bias² + variance`; green `bias²` (corrected as [`BiasVarianceAccumulator::finish`]
    /// corrects it, so it can be slightly negative where a pixel is unbiased); blue the
    /// variance of one render. The image mean of each channel is `finish`'s figure: where the
    /// error of an estimator is, and whether it is its bias or its noise.
    pub fn per_pixel(
        &self,
        reference: &ImageView<'_>,
        reference_variance: Option<&ImageView<'_>>,
    ) -> Result<RgbImage> {
        if let Some(rv) = reference_variance {
            check_pair(rv, reference)?;
        }
        let denom = self.variance_denominator()?;
        check_pair(&self.mean_image().view("mean of renders"), reference)?;
        let r = self.count as f64;
        let pixels = self
            .mean
            .iter()
            .zip(&self.m2)
            .enumerate()
            .map(|(i, (m, m2))| {
                let y = reference.pixels()[i];
                let (mut bias_sq, mut var) = (0.0f64, 0.0f64);
                for c in 0..3 {
                    let d = m[c] - y[c] as f64;
                    let v = m2[c] / denom;
                    let rv = reference_variance.map_or(0.0, |rv| rv.pixels()[i][c] as f64);
                    bias_sq += d * d - v / r - rv;
                    var += v;
                }
                let (b, v) = (bias_sq / 3.0, var / 3.0);
                [(b + v) as f32, b as f32, v as f32]
            })
            .collect();
        Ok(RgbImage {
            width: self.width,
            height: self.height,
            pixels,
        })
    }

    /// The same in relMSE's units: every pixel and channel's terms divided by `y² + epsilon`
    /// (`y` the reference), so that `bias_sq` is the relMSE a render would have without its
    /// variance: the part of relMSE the method's bias makes, which more samples do not remove.
    pub fn finish_relative(&self, reference: &ImageView<'_>, epsilon: f64) -> Result<BiasVariance> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(EvalError::InvalidParameter {
                name: "relative bias epsilon",
                reason: format!("must be finite and > 0, got {epsilon}"),
            });
        }
        self.weighted(reference, None, |y| 1.0 / (y * y + epsilon))
    }

    fn weighted(
        &self,
        reference: &ImageView<'_>,
        reference_variance: Option<&ImageView<'_>>,
        weight: impl Fn(f64) -> f64,
    ) -> Result<BiasVariance> {
        let denom = self.variance_denominator()?;
        let mean = self.mean_image();
        check_pair(&mean.view("mean of renders"), reference)?;
        let r = self.count as f64;
        let (mut raw, mut var, mut ref_var) = (0.0f64, 0.0f64, 0.0f64);
        for (i, (m, m2)) in self.mean.iter().zip(&self.m2).enumerate() {
            let y = reference.pixels()[i];
            for c in 0..3 {
                let w = weight(y[c] as f64);
                let d = m[c] - y[c] as f64;
                raw += w * d * d;
                var += w * m2[c] / denom;
                if let Some(rv) = reference_variance {
                    ref_var += w * rv.pixels()[i][c] as f64;
                }
            }
        }
        let n = (3 * self.mean.len()) as f64;
        let (raw, var, ref_var) = (raw / n, var / n, ref_var / n);
        Ok(BiasVariance {
            renders: self.count,
            bias_sq: raw - var / r - ref_var,
            bias_sq_raw: raw,
            variance: var,
        })
    }
}

/// Bias² and variance of `renders` (R ≥ 2 independent renders) against `reference`.
pub fn bias_variance(
    renders: &[ImageView<'_>],
    reference: &ImageView<'_>,
    reference_variance: Option<&ImageView<'_>>,
) -> Result<BiasVariance> {
    let mut acc = BiasVarianceAccumulator::new(reference.width(), reference.height());
    for r in renders {
        acc.add(r)?;
    }
    acc.finish(reference, reference_variance)
}
