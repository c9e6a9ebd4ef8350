//! Temporal stability of a frame sequence `I_1 … I_T`, with optional per-frame references `R_t`.
//!
//! Following the error measures of Hedman et al., "Sequential Monte Carlo Instant Radiosity"
//! (the instant-radiosity paper of the issue): with the per-frame error `E_t = I_t − R_t`,
//!
//! - `|E|`  = mean over frames, pixels and channels of `|E_t|`: accuracy;
//! - `|E′|` = mean over t ≥ 2 of `|E_t − E_{t−1}|`: how much the *error* changes from frame to
//!   frame, i.e. flicker that the reference does not have (a moving light changes `I` and `R`
//!   alike and costs nothing here).
//!
//! (This reading of |E′| as the temporal derivative of the error is ours; the paper text was not
//! at hand when this was written.) Without references, only the plain mean absolute
//! frame-to-frame change `|I_t − I_{t−1}|` is available; it is always reported.

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::image::{ImageView, check_pair};

/// Temporal statistics of a frame sequence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TemporalStats {
    pub frames: usize,
    /// Mean absolute frame-to-frame change `|I_t − I_{t−1}|` (0 for a single frame).
    pub mean_abs_change: f64,
    /// `|E|`: mean absolute error against the per-frame reference.
    pub mean_abs_error: Option<f64>,
    /// `|E′|`: mean absolute frame-to-frame change of the error.
    pub mean_abs_error_change: Option<f64>,
    /// Mean absolute frame-to-frame change of the references themselves, for context.
    pub reference_mean_abs_change: Option<f64>,
    /// Per frame t ≥ 2: mean `|I_t − I_{t−1}|`.
    pub per_frame_change: Vec<f64>,
    /// Per frame: mean `|E_t|` (empty without references).
    pub per_frame_error: Vec<f64>,
}

/// Streaming accumulator of [`TemporalStats`]; keeps only the previous frame.
#[derive(Clone, Debug, Default)]
pub struct TemporalAccumulator {
    frames: usize,
    with_reference: Option<bool>,
    previous: Vec<[f32; 3]>,
    previous_error: Vec<[f32; 3]>,
    previous_reference: Vec<[f32; 3]>,
    size: (usize, usize),
    change_sum: f64,
    error_change_sum: f64,
    reference_change_sum: f64,
    per_frame_change: Vec<f64>,
    per_frame_error: Vec<f64>,
}

impl TemporalAccumulator {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the next frame and, if the sequence has them, its reference (all frames or none).
    pub fn push(&mut self, frame: &ImageView<'_>, reference: Option<&ImageView<'_>>) -> Result<()> {
        frame.check_finite()?;
        if let Some(r) = reference {
            check_pair(frame, r)?;
        }
        match self.with_reference {
            None => {
                self.with_reference = Some(reference.is_some());
                self.size = (frame.width(), frame.height());
            }
            Some(w) if w != reference.is_some() => {
                return Err(EvalError::InvalidParameter {
                    name: "reference",
                    reason: format!(
                        "frame {} {} a reference but earlier frames {}",
                        self.frames + 1,
                        if reference.is_some() { "has" } else { "lacks" },
                        if w { "had one" } else { "had none" }
                    ),
                });
            }
            Some(_) => {}
        }
        if (frame.width(), frame.height()) != self.size {
            return Err(EvalError::SizeMismatch {
                a_name: frame.name().to_string(),
                a_w: frame.width(),
                a_h: frame.height(),
                b_name: "earlier frames".to_string(),
                b_w: self.size.0,
                b_h: self.size.1,
            });
        }
        let n = (3 * frame.pixels().len()) as f64;
        let error: Vec<[f32; 3]> = match reference {
            Some(r) => frame
                .pixels()
                .iter()
                .zip(r.pixels())
                .map(|(i, r)| [i[0] - r[0], i[1] - r[1], i[2] - r[2]])
                .collect(),
            None => Vec::new(),
        };
        if reference.is_some() {
            self.per_frame_error.push(sum_abs(&error, None) / n);
        }
        if self.frames > 0 {
            let change = sum_abs(frame.pixels(), Some(&self.previous)) / n;
            self.change_sum += change;
            self.per_frame_change.push(change);
            if let Some(r) = reference {
                self.error_change_sum += sum_abs(&error, Some(&self.previous_error)) / n;
                self.reference_change_sum +=
                    sum_abs(r.pixels(), Some(&self.previous_reference)) / n;
            }
        }
        self.previous = frame.pixels().to_vec();
        if let Some(r) = reference {
            self.previous_error = error;
            self.previous_reference = r.pixels().to_vec();
        }
        self.frames += 1;
        Ok(())
    }

    pub fn finish(&self) -> Result<TemporalStats> {
        if self.frames == 0 {
            return Err(EvalError::NotEnoughData(
                "temporal statistics need at least one frame".into(),
            ));
        }
        let pairs = (self.frames - 1).max(1) as f64;
        let with_reference = self.with_reference == Some(true);
        let per_pair = |sum: f64| if self.frames > 1 { sum / pairs } else { 0.0 };
        Ok(TemporalStats {
            frames: self.frames,
            mean_abs_change: per_pair(self.change_sum),
            mean_abs_error: with_reference
                .then(|| self.per_frame_error.iter().sum::<f64>() / self.frames as f64),
            mean_abs_error_change: with_reference.then(|| per_pair(self.error_change_sum)),
            reference_mean_abs_change: with_reference.then(|| per_pair(self.reference_change_sum)),
            per_frame_change: self.per_frame_change.clone(),
            per_frame_error: self.per_frame_error.clone(),
        })
    }
}

/// Temporal statistics of `frames`, with per-frame `references` if given (same length).
pub fn temporal_stats(
    frames: &[ImageView<'_>],
    references: Option<&[ImageView<'_>]>,
) -> Result<TemporalStats> {
    if let Some(r) = references
        && r.len() != frames.len()
    {
        return Err(EvalError::InvalidParameter {
            name: "references",
            reason: format!("{} frames but {} references", frames.len(), r.len()),
        });
    }
    let mut acc = TemporalAccumulator::new();
    for (t, f) in frames.iter().enumerate() {
        acc.push(f, references.map(|r| &r[t]))?;
    }
    acc.finish()
}

/// The measure of the paper's §5.2: frames reduced to the tone-mapped luminance of a fixed set of
/// tracked pixels, the tone map fixed once from the sequence's first reference so that it adds no
/// flicker of its own. Tone map: Reinhard's `x/(1 + x)` of the luminance scaled so that the
/// reference's log-average luminance maps to 0.18 (his "key"). The reduced frames go into a
/// [`TemporalAccumulator`] as `1 × n` images (the luminance in all three channels, so that the
/// means over pixels and channels are means over the tracked pixels).
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedLuminance {
    /// Indices of the tracked pixels (row-major).
    pub pixels: Vec<usize>,
    /// Luminance scale of the tone map.
    pub scale: f64,
}

impl TrackedLuminance {
    /// `tracked` pixels on a regular grid over the image (every pixel when `tracked` is 0 or at
    /// least the pixel count), the tone map from `reference`.
    pub fn from_reference(reference: &ImageView<'_>, tracked: usize) -> Self {
        let (w, h) = (reference.width(), reference.height());
        let n = w * h;
        let pixels: Vec<usize> = if tracked == 0 || tracked >= n {
            (0..n).collect()
        } else {
            let side = (tracked as f64).sqrt().ceil() as usize;
            let mut out = Vec::new();
            for j in 0..side {
                for i in 0..side {
                    let x = ((i as f64 + 0.5) * w as f64 / side as f64) as usize;
                    let y = ((j as f64 + 0.5) * h as f64 / side as f64) as usize;
                    out.push(y.min(h - 1) * w + x.min(w - 1));
                }
            }
            out.truncate(tracked);
            out
        };
        let lum = |p: &[f32; 3]| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
        let log_avg = (reference
            .pixels()
            .iter()
            .map(|p| (1e-4 + lum(p).max(0.0)).ln())
            .sum::<f64>()
            / n.max(1) as f64)
            .exp();
        Self {
            pixels,
            scale: 0.18 / log_avg.max(1e-12),
        }
    }

    /// The tone-mapped luminance of the tracked pixels of `image`, as `1 × n` RGB pixels.
    pub fn apply(&self, image: &ImageView<'_>) -> Vec<[f32; 3]> {
        let px = image.pixels();
        self.pixels
            .iter()
            .map(|&i| {
                let p = px[i];
                let l = (0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
                    .max(0.0)
                    * self.scale;
                let t = (l / (1.0 + l)) as f32;
                [t; 3]
            })
            .collect()
    }
}

/// Sum over pixels and channels of `|a − b|` (or `|a|` when `b` is `None`).
fn sum_abs(a: &[[f32; 3]], b: Option<&[[f32; 3]]>) -> f64 {
    match b {
        Some(b) => a
            .iter()
            .zip(b)
            .map(|(p, q)| {
                (0..3)
                    .map(|c| (p[c] as f64 - q[c] as f64).abs())
                    .sum::<f64>()
            })
            .sum(),
        None => a
            .iter()
            .map(|p| p.iter().map(|&v| (v as f64).abs()).sum::<f64>())
            .sum(),
    }
}
