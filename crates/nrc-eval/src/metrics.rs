//! Pixel error metrics of a test image `x` against a reference `y` (linear RGB).
//!
//! All three are computed per colour channel and averaged over pixels and channels:
//!
//! - **MSE**: `(x − y)²`.
//! - **relMSE** (relative MSE): `(x − y)² / (y² + ε)`, ε = [`REL_MSE_EPSILON`] = 0.01 by default,
//!   the ε of the relative L2 loss the NRC paper trains with (tiny-cuda-nn's `RelativeL2`); it
//!   keeps black pixels from dominating.
//! - **MAPE** (mean absolute percentage error) as the DDGI-resampling paper defines it:
//!   `|x − y| / (y + 0.01)` ([`MAPE_EPSILON`]).
//!
//! HDR-FLIP lives in [`crate::hdr_flip`](mod@crate::hdr_flip); [`compute_metrics`] bundles all four.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::hdr_flip::{HdrFlipParams, hdr_flip};
use crate::image::{ImageView, ScalarImage, check_pair};

/// Default ε of relMSE.
pub const REL_MSE_EPSILON: f64 = 0.01;
/// ε of MAPE as defined in the DDGI-resampling paper.
pub const MAPE_EPSILON: f64 = 0.01;

/// Mean squared error over pixels and channels.
pub fn mse(test: &ImageView<'_>, reference: &ImageView<'_>) -> Result<f64> {
    mean_over_channels(test, reference, |x, y| (x - y) * (x - y))
}

/// Relative MSE `(x − y)² / (y² + ε)` averaged over pixels and channels.
pub fn rel_mse(test: &ImageView<'_>, reference: &ImageView<'_>, epsilon: f64) -> Result<f64> {
    check_epsilon("rel_mse epsilon", epsilon)?;
    mean_over_channels(test, reference, |x, y| {
        (x - y) * (x - y) / (y * y + epsilon)
    })
}

/// MAPE `|x − y| / (y + ε)` averaged over pixels and channels; ε = 0.01 in the DDGI-resampling
/// paper. The reference must be non-negative (radiance), else the denominator can vanish.
pub fn mape(test: &ImageView<'_>, reference: &ImageView<'_>, epsilon: f64) -> Result<f64> {
    check_epsilon("mape epsilon", epsilon)?;
    check_non_negative(reference)?;
    mean_over_channels(test, reference, |x, y| (x - y).abs() / (y + epsilon))
}

/// Per-pixel relMSE (channel mean), for false-colour images.
pub fn rel_mse_map(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    epsilon: f64,
) -> Result<ScalarImage> {
    check_epsilon("rel_mse epsilon", epsilon)?;
    per_pixel_map(test, reference, |x, y| {
        (x - y) * (x - y) / (y * y + epsilon)
    })
}

/// Per-pixel squared error (channel mean), for false-colour images.
pub fn squared_error_map(test: &ImageView<'_>, reference: &ImageView<'_>) -> Result<ScalarImage> {
    per_pixel_map(test, reference, |x, y| (x - y) * (x - y))
}

/// The four errors of one image against its reference.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorMetrics {
    pub mse: f64,
    pub rel_mse: f64,
    pub mape: f64,
    /// Mean HDR-FLIP; `None` when it was not requested.
    pub flip: Option<f64>,
}

/// Which metric to read from [`ErrorMetrics`] (plots, time-to-error tables).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Metric {
    Mse,
    RelMse,
    Mape,
    Flip,
}

impl Metric {
    /// The metric's value, `None` for FLIP when it was not computed.
    pub fn of(self, m: &ErrorMetrics) -> Option<f64> {
        match self {
            Metric::Mse => Some(m.mse),
            Metric::RelMse => Some(m.rel_mse),
            Metric::Mape => Some(m.mape),
            Metric::Flip => m.flip,
        }
    }

    /// Display name used in tables and plot axes.
    pub fn label(self) -> &'static str {
        match self {
            Metric::Mse => "MSE",
            Metric::RelMse => "relMSE",
            Metric::Mape => "MAPE",
            Metric::Flip => "HDR-FLIP",
        }
    }
}

/// Settings of [`compute_metrics`].
#[derive(Clone, Debug)]
pub struct MetricOptions {
    pub rel_mse_epsilon: f64,
    pub mape_epsilon: f64,
    /// HDR-FLIP parameters; `None` skips FLIP (it costs far more than the other three).
    pub flip: Option<HdrFlipParams>,
}

impl Default for MetricOptions {
    fn default() -> Self {
        Self {
            rel_mse_epsilon: REL_MSE_EPSILON,
            mape_epsilon: MAPE_EPSILON,
            flip: Some(HdrFlipParams::default()),
        }
    }
}

/// MSE, relMSE, MAPE and (optionally) mean HDR-FLIP of `test` against `reference`.
pub fn compute_metrics(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    options: &MetricOptions,
) -> Result<ErrorMetrics> {
    let flip = match &options.flip {
        Some(params) => Some(hdr_flip(test, reference, params)?.mean),
        None => None,
    };
    Ok(ErrorMetrics {
        mse: mse(test, reference)?,
        rel_mse: rel_mse(test, reference, options.rel_mse_epsilon)?,
        mape: mape(test, reference, options.mape_epsilon)?,
        flip,
    })
}

fn check_epsilon(name: &'static str, epsilon: f64) -> Result<()> {
    if !(epsilon.is_finite() && epsilon > 0.0) {
        return Err(EvalError::InvalidParameter {
            name,
            reason: format!("must be finite and > 0, got {epsilon}"),
        });
    }
    Ok(())
}

fn check_non_negative(image: &ImageView<'_>) -> Result<()> {
    if let Some((i, c, v)) = image
        .pixels()
        .iter()
        .enumerate()
        .flat_map(|(i, p)| p.iter().enumerate().map(move |(c, &v)| (i, c, v)))
        .find(|&(_, _, v)| v < 0.0)
    {
        return Err(EvalError::InvalidParameter {
            name: "reference",
            reason: format!(
                "'{}' has negative value {v} at pixel ({}, {}) channel {c}; MAPE needs a non-negative reference",
                image.name(),
                i % image.width(),
                i / image.width()
            ),
        });
    }
    Ok(())
}

/// Mean of `f(x, y)` over all pixels and channels, accumulated in f64.
fn mean_over_channels(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    f: impl Fn(f64, f64) -> f64 + Sync,
) -> Result<f64> {
    check_pair(test, reference)?;
    let sum: f64 = test
        .pixels()
        .par_iter()
        .zip(reference.pixels().par_iter())
        .map(|(x, y)| (0..3).map(|c| f(x[c] as f64, y[c] as f64)).sum::<f64>())
        .sum();
    Ok(sum / (3 * test.pixels().len()) as f64)
}

fn per_pixel_map(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    f: impl Fn(f64, f64) -> f64 + Sync,
) -> Result<ScalarImage> {
    check_pair(test, reference)?;
    let values = test
        .pixels()
        .par_iter()
        .zip(reference.pixels().par_iter())
        .map(|(x, y)| ((0..3).map(|c| f(x[c] as f64, y[c] as f64)).sum::<f64>() / 3.0) as f32)
        .collect();
    Ok(ScalarImage {
        width: test.width(),
        height: test.height(),
        values,
    })
}
