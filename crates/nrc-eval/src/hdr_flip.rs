//! HDR-FLIP (Andersson, Nilsson, Shirley, Akenine-Möller, "Visualizing Errors in Rendered High
//! Dynamic Range Images", Eurographics 2021).
//!
//! Both images are exposure-compensated (×2^c) and tone mapped (ACES filmic by default) at a
//! range of exposures `c_start … c_stop`; LDR-FLIP compares each tone-mapped pair, and the HDR-FLIP
//! value of a pixel is its maximum over exposures. The range comes from the reference: `c_start`
//! maps the largest luminance to t = 0.85 of the tone curve, `c_stop` maps the median luminance
//! there, and the number of exposures is `max(2, ⌈c_stop − c_start⌉)`.
//!
//! Deviations from NVIDIA's tool, where the tool has no defined result: negative input values are
//! clamped to 0 (as the authors' PyTorch HDR-FLIP does); when the median luminance is 0 (more than
//! half of the reference black) the median of the non-zero luminances is used instead of an
//! infinite stop exposure; an all-black reference is an error.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::flip::{FlipFilters, default_pixels_per_degree, ldr_flip_linear};
use crate::flip_color::luminance;
use crate::image::{ImageView, ScalarImage, check_pair};

/// The tone curve HDR-FLIP assumes the viewer applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ToneMapper {
    /// Narkowicz's fit of the ACES filmic curve, with its 0.6 pre-exposure cancelled (the paper's choice).
    #[default]
    Aces,
    /// Hable's (Uncharted 2) filmic curve, white point 11.2.
    Hable,
    /// Reinhard's `c / (1 + L)` on luminance `L`.
    Reinhard,
}

impl ToneMapper {
    /// Coefficients k of the rational curve `(k0 x² + k1 x + k2) / (k3 x² + k4 x + k5)`.
    fn coefficients(self) -> [f32; 6] {
        match self {
            ToneMapper::Reinhard => [0.0, 1.0, 0.0, 0.0, 1.0, 1.0],
            ToneMapper::Aces => [
                0.6 * 0.6 * 2.51,
                0.6 * 0.03,
                0.0,
                0.6 * 0.6 * 2.43,
                0.6 * 0.59,
                0.14,
            ],
            ToneMapper::Hable => [0.231683, 0.013791, 0.0, 0.18, 0.3, 0.018],
        }
    }

    /// Tone maps one linear-RGB colour (already exposed) and clamps it to [0, 1].
    fn apply(self, c: [f32; 3]) -> [f32; 3] {
        let out = match self {
            ToneMapper::Reinhard => {
                let s = 1.0 / (1.0 + luminance(c));
                [c[0] * s, c[1] * s, c[2] * s]
            }
            _ => {
                let k = self.coefficients();
                c.map(|x| (x * x * k[0] + x * k[1] + k[2]) / (x * x * k[3] + x * k[4] + k[5]))
            }
        };
        // A huge input gives inf/inf = NaN; it is the brightest possible pixel, so 1.
        out.map(|v| if v.is_nan() { 1.0 } else { v.clamp(0.0, 1.0) })
    }

    /// The input x at which the tone curve reaches `t` (larger root of the quadratic).
    fn inverse(self, t: f32) -> f32 {
        let k = self.coefficients();
        let (a, b, c) = (k[0] - t * k[3], k[1] - t * k[4], k[2] - t * k[5]);
        if a == 0.0 {
            return -c / b;
        }
        let d1 = -0.5 * (b / a);
        let d2 = (d1 * d1 - c / a).sqrt();
        d1 + d2
    }
}

/// Parameters of HDR-FLIP; the defaults are the tool's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HdrFlipParams {
    /// Pixels per degree of visual angle (default ≈ 67.02: 0.7 m from a 0.7 m wide 4K monitor).
    pub ppd: f32,
    pub tone_mapper: ToneMapper,
    /// Start exposure c_start (log2); `None` computes it from the reference.
    pub start_exposure: Option<f32>,
    /// Stop exposure c_stop (log2); `None` computes it from the reference.
    pub stop_exposure: Option<f32>,
    /// Number of exposures (≥ 2); `None` uses `max(2, ⌈c_stop − c_start⌉)`.
    pub num_exposures: Option<usize>,
}

impl Default for HdrFlipParams {
    fn default() -> Self {
        Self {
            ppd: default_pixels_per_degree(),
            tone_mapper: ToneMapper::Aces,
            start_exposure: None,
            stop_exposure: None,
            num_exposures: None,
        }
    }
}

/// The result of [`hdr_flip`]: the per-pixel error map, its mean, and the exposures used.
#[derive(Clone, Debug)]
pub struct HdrFlipResult {
    pub mean: f64,
    pub error_map: ScalarImage,
    pub start_exposure: f32,
    pub stop_exposure: f32,
    pub num_exposures: usize,
}

/// The target tone-curve value of the brightest (start) and median (stop) luminance.
const T_EXPOSURE: f32 = 0.85;

/// The exposure range `(c_start, c_stop)` that HDR-FLIP derives from `reference`.
pub fn exposure_range(reference: &ImageView<'_>, tone_mapper: ToneMapper) -> Result<(f32, f32)> {
    reference.check_finite()?;
    let x_max = tone_mapper.inverse(T_EXPOSURE);
    let mut lum: Vec<f32> = reference
        .pixels()
        .iter()
        .map(|p| luminance(clamp_non_negative(*p)))
        .collect();
    let y_max = lum.iter().fold(0.0f32, |m, &v| m.max(v));
    if y_max <= 0.0 {
        return Err(EvalError::InvalidParameter {
            name: "reference",
            reason: format!(
                "'{}' is black everywhere; HDR-FLIP's exposure range is undefined",
                reference.name()
            ),
        });
    }
    // The tool's median: the element at index n/2 of the sorted luminances.
    let mid = lum.len() / 2;
    let mut y_median = *lum.select_nth_unstable_by(mid, f32::total_cmp).1;
    if y_median <= 0.0 {
        let mut positive: Vec<f32> = lum.into_iter().filter(|&v| v > 0.0).collect();
        let mid = positive.len() / 2;
        y_median = *positive.select_nth_unstable_by(mid, f32::total_cmp).1;
    }
    Ok(((x_max / y_max).log2(), (x_max / y_median).log2()))
}

/// HDR-FLIP of `test` against `reference` (linear RGB, any non-negative range).
pub fn hdr_flip(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    params: &HdrFlipParams,
) -> Result<HdrFlipResult> {
    check_pair(test, reference)?;
    let filters = FlipFilters::new(params.ppd)?;
    let (start, stop) = match (params.start_exposure, params.stop_exposure) {
        (Some(a), Some(b)) => (a, b),
        (a, b) => {
            let (s, e) = exposure_range(reference, params.tone_mapper)?;
            (a.unwrap_or(s), b.unwrap_or(e))
        }
    };
    if !(start.is_finite() && stop.is_finite() && start <= stop) {
        return Err(EvalError::InvalidParameter {
            name: "exposures",
            reason: format!("need finite start <= stop, got start {start}, stop {stop}"),
        });
    }
    let count = params
        .num_exposures
        .unwrap_or_else(|| (stop - start).ceil().max(2.0) as usize);
    if count < 2 {
        return Err(EvalError::InvalidParameter {
            name: "num_exposures",
            reason: format!("must be >= 2, got {count}"),
        });
    }
    let step = (stop - start) / (count - 1) as f32;

    let (w, h) = (test.width(), test.height());
    let reference_px: Vec<[f32; 3]> = reference
        .pixels()
        .iter()
        .map(|p| clamp_non_negative(*p))
        .collect();
    let test_px: Vec<[f32; 3]> = test
        .pixels()
        .iter()
        .map(|p| clamp_non_negative(*p))
        .collect();
    let mut error = vec![0.0f32; w * h];
    for i in 0..count {
        let exposure = start + i as f32 * step;
        let scale = 2.0f32.powf(exposure);
        let expose = |img: &[[f32; 3]]| -> Vec<[f32; 3]> {
            img.par_iter()
                .map(|c| {
                    params
                        .tone_mapper
                        .apply([c[0] * scale, c[1] * scale, c[2] * scale])
                })
                .collect()
        };
        let ldr = ldr_flip_linear(&expose(&reference_px), &expose(&test_px), w, h, &filters);
        error
            .par_iter_mut()
            .zip(ldr.par_iter())
            .for_each(|(e, &v)| *e = e.max(v));
    }
    let error_map = ScalarImage {
        width: w,
        height: h,
        values: error,
    };
    Ok(HdrFlipResult {
        mean: error_map.mean(),
        error_map,
        start_exposure: start,
        stop_exposure: stop,
        num_exposures: count,
    })
}

fn clamp_non_negative(p: [f32; 3]) -> [f32; 3] {
    p.map(|v| v.max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_curve_inverse_hits_target() {
        for tm in [ToneMapper::Aces, ToneMapper::Hable, ToneMapper::Reinhard] {
            let x = tm.inverse(T_EXPOSURE);
            let k = tm.coefficients();
            let t = (k[0] * x * x + k[1] * x + k[2]) / (k[3] * x * x + k[4] * x + k[5]);
            assert!((t - T_EXPOSURE).abs() < 1e-4, "{tm:?}: x {x}, t {t}");
        }
    }

    #[test]
    fn exposure_range_of_two_level_image() {
        // 3 of 4 pixels at luminance 1, one at 8: start maps 8 to x_max, stop maps the median 1.
        let px = vec![[1.0f32; 3], [1.0; 3], [8.0; 3], [1.0; 3]];
        let (s, e) =
            exposure_range(&ImageView::new("r", 2, 2, &px).unwrap(), ToneMapper::Aces).unwrap();
        let x_max = ToneMapper::Aces.inverse(T_EXPOSURE);
        assert!(
            (s - (x_max / 8.0).log2()).abs() < 1e-5
                && (e - x_max.log2()).abs() < 1e-5
                && (e - s - 3.0).abs() < 1e-5
        );
    }

    #[test]
    fn black_reference_is_an_error() {
        let px = vec![[0.0f32; 3]; 4];
        let v = ImageView::new("black", 2, 2, &px).unwrap();
        let err = hdr_flip(&v, &v, &HdrFlipParams::default()).unwrap_err();
        assert!(err.to_string().contains("black everywhere"), "{err}");
    }
}
