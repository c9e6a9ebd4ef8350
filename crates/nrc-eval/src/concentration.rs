//! Where an image's error sits: a few fireflies or a spread of noise, the pixels that see an
//! emitter (whose anti-aliasing noise only more camera samples lower) or the rest. The same
//! MSE can be either, and the fixes differ (issue 39's diagnosis of the kitchen: the brightest
//! 1 % of pixels carried 79–89 % of the resampling passes' MSE and 64 % of path tracing's).

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::image::ImageView;
use crate::metrics::squared_error_map;

/// How an image's squared error (per pixel, the mean over channels) is spread over its pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorConcentration {
    /// Share of the summed squared error in the 1 % of pixels with the largest (at least one
    /// pixel); 0.01 for an error spread evenly, 1 for a single firefly.
    pub top_percent: f64,
    /// Share in the pixels of the emitter mask (those that see an emitter and their
    /// neighbours), where one was given.
    pub emitters: Option<f64>,
    /// The 99.9th percentile of the per-pixel squared error.
    pub p999: f64,
}

/// The concentration of `test`'s error against `reference`; `emitters`, a mask of the
/// pixels that see an emitter (row-major, one entry per pixel). An image equal to its
/// reference has no error to spread: shares of 0.
pub fn concentration(
    test: &ImageView<'_>,
    reference: &ImageView<'_>,
    emitters: Option<&[bool]>,
) -> Result<ErrorConcentration> {
    let map = squared_error_map(test, reference)?;
    let n = map.values.len();
    if let Some(m) = emitters
        && m.len() != n
    {
        return Err(EvalError::InvalidParameter {
            name: "emitter mask",
            reason: format!("{} entries for an image of {n} pixels", m.len()),
        });
    }
    let mut sorted: Vec<f64> = map.values.iter().map(|&v| v as f64).collect();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let total: f64 = sorted.iter().sum();
    let share = |part: f64| if total > 0.0 { part / total } else { 0.0 };
    let top = n.div_ceil(100).max(1);
    let in_mask = |m: &[bool]| {
        let sum: f64 = map
            .values
            .iter()
            .zip(m)
            .filter(|(_, inside)| **inside)
            .map(|(&v, _)| v as f64)
            .sum();
        share(sum)
    };
    // The 99.9th percentile of the ascending order is the element this far from the top.
    let p999 = sorted[((n - 1) as f64 * 0.001).round() as usize];
    Ok(ErrorConcentration {
        top_percent: share(sorted[..top].iter().sum()),
        emitters: emitters.map(in_mask),
        p999,
    })
}

/// The mean of the concentrations of several images (runs), `None` for none.
pub fn mean_concentration(cs: &[ErrorConcentration]) -> Option<ErrorConcentration> {
    if cs.is_empty() {
        return None;
    }
    let n = cs.len() as f64;
    let avg = |f: fn(&ErrorConcentration) -> f64| cs.iter().map(f).sum::<f64>() / n;
    Some(ErrorConcentration {
        top_percent: avg(|c| c.top_percent),
        emitters: cs
            .iter()
            .map(|c| c.emitters)
            .sum::<Option<f64>>()
            .map(|s| s / n),
        p999: avg(|c| c.p999),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view<'a>(name: &'a str, px: &'a [[f32; 3]]) -> ImageView<'a> {
        ImageView::new(name, 20, 10, px).unwrap()
    }

    /// One firefly carries all the error; the same total spread evenly puts 1 % in the top
    /// 1 % (the negative control: the measure tells the two apart); the mask's share follows
    /// where the error is.
    #[test]
    fn a_firefly_and_an_even_spread_are_told_apart() {
        let reference = vec![[1.0f32; 3]; 200];
        let mut firefly = reference.clone();
        firefly[37] = [15.0; 3];
        let even = vec![[1.0 + 1.0f32; 3]; 200];
        let mut mask = vec![false; 200];
        mask[37] = true;
        mask[38] = true;
        let r = view("reference", &reference);
        let f = concentration(&view("firefly", &firefly), &r, Some(&mask)).unwrap();
        assert!((f.top_percent - 1.0).abs() < 1e-9, "{f:?}");
        assert!((f.emitters.unwrap() - 1.0).abs() < 1e-9, "{f:?}");
        let e = concentration(&view("even", &even), &r, Some(&mask)).unwrap();
        assert!((e.top_percent - 0.01).abs() < 1e-9, "{e:?}");
        assert!((e.emitters.unwrap() - 0.01).abs() < 1e-9, "{e:?}");
        assert!(
            (e.p999 - 1.0).abs() < 1e-9 && f.p999 == 196.0,
            "{e:?} {f:?}"
        );
        let none = concentration(&r, &r, None).unwrap();
        assert_eq!((none.top_percent, none.emitters), (0.0, None));
        let mean = mean_concentration(&[f, e]).unwrap();
        assert!((mean.top_percent - 0.505).abs() < 1e-9);
    }

    #[test]
    fn a_mask_of_another_size_is_refused() {
        let reference = vec![[1.0f32; 3]; 200];
        let r = view("reference", &reference);
        let err = concentration(&r, &r, Some(&[true; 3])).unwrap_err();
        assert!(err.to_string().contains("emitter mask"), "{err}");
    }
}
