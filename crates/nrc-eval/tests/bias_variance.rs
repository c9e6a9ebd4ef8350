//! Bias/variance decomposition recovers a known bias and noise level from synthetic renders
//! (reference + constant bias + Gaussian noise of known σ), within statistical bounds.
//!
//! With N = pixels × channels values and R renders, the estimators' standard deviations are
//!   variance:  σ² · √(2 / ((R − 1) N))                   (sample variance of Gaussians)
//!   bias²:     √((2 v² + 4 b² v) / N),  v = σ² / R       (square of a N(b, v) mean error)
//! and every check allows 5 of them (two-sided miss probability < 1e-6 per check; the seeds
//! are fixed, so the test is deterministic).

use nrc_eval::{BiasVarianceAccumulator, EvalError, ImageView, bias_variance};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64Mcg;

const W: usize = 64;
const H: usize = 48;
const R: usize = 64;

fn reference() -> Vec<[f32; 3]> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32 / W as f32, (i / W) as f32 / H as f32);
            [0.5 + 0.4 * (6.0 * x).sin(), 1.0 + y, 0.2 + x * y]
        })
        .collect()
}

fn renders(reference: &[[f32; 3]], bias: f32, sigma: f32, seed: u64) -> Vec<Vec<[f32; 3]>> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let noise = Normal::new(0.0f32, sigma).unwrap();
    (0..R)
        .map(|_| {
            reference
                .iter()
                .map(|p| p.map(|v| v + bias + noise.sample(&mut rng)))
                .collect()
        })
        .collect()
}

fn run(bias: f32, sigma: f32, seed: u64) -> nrc_eval::BiasVariance {
    let y = reference();
    let rs = renders(&y, bias, sigma, seed);
    let views: Vec<ImageView<'_>> = rs
        .iter()
        .map(|r| ImageView::new("render", W, H, r).unwrap())
        .collect();
    bias_variance(
        &views,
        &ImageView::new("reference", W, H, &y).unwrap(),
        None,
    )
    .unwrap()
}

#[test]
fn recovers_known_bias_and_variance() {
    let (b, sigma) = (0.05f64, 0.2f64);
    let n = (W * H * 3) as f64;
    let r = R as f64;
    let got = run(b as f32, sigma as f32, 7);
    assert_eq!(got.renders, R);

    let var_sd = sigma * sigma * (2.0 / ((r - 1.0) * n)).sqrt();
    assert!(
        (got.variance - sigma * sigma).abs() < 5.0 * var_sd,
        "variance {} vs σ² {}",
        got.variance,
        sigma * sigma
    );

    let v = sigma * sigma / r;
    let bias_sd = ((2.0 * v * v + 4.0 * b * b * v) / n).sqrt() + var_sd / r;
    assert!(
        (got.bias_sq - b * b).abs() < 5.0 * bias_sd,
        "bias² {} vs b² {}",
        got.bias_sq,
        b * b
    );
    // Uncorrected, the squared error of the mean also holds the noise σ²/R.
    assert!(
        (got.bias_sq_raw - (b * b + v)).abs() < 5.0 * bias_sd,
        "raw bias² {} vs {}",
        got.bias_sq_raw,
        b * b + v
    );
    assert!((got.bias_sq_raw - got.bias_sq - got.variance / r).abs() < 1e-12);
}

#[test]
fn unbiased_estimator_has_bias_near_zero_but_raw_estimate_does_not() {
    let sigma = 0.2f64;
    let n = (W * H * 3) as f64;
    let v = sigma * sigma / R as f64;
    let got = run(0.0, sigma as f32, 11);
    let sd = (2.0 * v * v / n).sqrt();
    assert!(
        got.bias_sq.abs() < 5.0 * sd,
        "bias² {} (sd {sd})",
        got.bias_sq
    );
    // σ²/R = 6.25e-4 is ~80 standard deviations away from 0: the correction matters.
    assert!(got.bias_sq_raw > v - 5.0 * sd, "raw {}", got.bias_sq_raw);
}

#[test]
fn reference_variance_is_subtracted() {
    let y = reference();
    let rs = renders(&y, 0.1, 0.1, 3);
    let views: Vec<ImageView<'_>> = rs
        .iter()
        .map(|r| ImageView::new("render", W, H, r).unwrap())
        .collect();
    let reference_view = ImageView::new("reference", W, H, &y).unwrap();
    let ref_var = vec![[1e-3f32; 3]; W * H];
    let without = bias_variance(&views, &reference_view, None).unwrap();
    let with = bias_variance(
        &views,
        &reference_view,
        Some(&ImageView::new("reference variance", W, H, &ref_var).unwrap()),
    )
    .unwrap();
    assert!((without.bias_sq - with.bias_sq - 1e-3).abs() < 1e-9);
    assert_eq!(without.variance, with.variance);
}

#[test]
fn streaming_mean_and_variance_match_closed_form() {
    // One pixel, renders 1, 2, 6 in every channel: mean 3, sample variance 7, reference 2.
    let mut acc = BiasVarianceAccumulator::new(1, 1);
    for v in [1.0f32, 2.0, 6.0] {
        acc.add(&ImageView::new("render", 1, 1, &[[v; 3]]).unwrap())
            .unwrap();
    }
    assert_eq!(acc.mean_image().pixels, vec![[3.0; 3]]);
    assert_eq!(acc.variance_image().unwrap().pixels, vec![[7.0; 3]]);
    let bv = acc
        .finish(
            &ImageView::new("reference", 1, 1, &[[2.0; 3]]).unwrap(),
            None,
        )
        .unwrap();
    assert!((bv.bias_sq_raw - 1.0).abs() < 1e-12);
    assert!((bv.bias_sq - (1.0 - 7.0 / 3.0)).abs() < 1e-12);
    assert!((bv.variance - 7.0).abs() < 1e-12);
}

#[test]
fn too_few_or_mismatched_renders_are_errors() {
    let mut acc = BiasVarianceAccumulator::new(2, 1);
    acc.add(&ImageView::new("render 1", 2, 1, &[[1.0; 3], [1.0; 3]]).unwrap())
        .unwrap();
    let reference = [[1.0f32; 3], [1.0; 3]];
    let err = acc
        .finish(
            &ImageView::new("reference", 2, 1, &reference).unwrap(),
            None,
        )
        .unwrap_err();
    assert!(matches!(err, EvalError::NotEnoughData(_)), "{err}");
    let err = acc
        .add(&ImageView::new("render 2", 1, 2, &[[1.0; 3], [1.0; 3]]).unwrap())
        .unwrap_err();
    assert!(err.to_string().contains("render 2"), "{err}");
}

/// The relative form weighs each pixel and channel by `1 / (y² + ε)`, as relMSE does: with a
/// constant bias `b` and noise σ it recovers `mean(b² / (y² + ε))` within five of its standard
/// deviations (`√(Σ w² (2v² + 4b²v)) / N`, `v = σ²/R`), and an unbiased estimator gets about
/// zero while its renders' relMSE, the relative variance, stays far above that.
#[test]
fn relative_bias_is_the_bias_in_rel_mse_units_without_the_variance() {
    let eps = 0.01f64;
    let y = reference();
    let weights: Vec<f64> = y
        .iter()
        .flat_map(|p| p.map(|v| 1.0 / ((v as f64).powi(2) + eps)))
        .collect();
    let n = weights.len() as f64;
    let relative = |bias: f32, sigma: f32, seed: u64| {
        let mut acc = BiasVarianceAccumulator::new(W, H);
        for r in renders(&y, bias, sigma, seed) {
            acc.add(&ImageView::new("render", W, H, &r).unwrap())
                .unwrap();
        }
        acc.finish_relative(&ImageView::new("reference", W, H, &y).unwrap(), eps)
            .unwrap()
    };
    let sd = |b: f64, sigma: f64| {
        let v = sigma * sigma / R as f64;
        (weights.iter().map(|w| w * w).sum::<f64>() * (2.0 * v * v + 4.0 * b * b * v)).sqrt() / n
    };
    let (b, sigma) = (0.05f64, 0.2f64);
    let expected = weights.iter().map(|w| w * b * b).sum::<f64>() / n;
    let got = relative(b as f32, sigma as f32, 5);
    assert!(
        (got.bias_sq - expected).abs() < 5.0 * sd(b, sigma),
        "relative bias² {} vs {expected} (sd {})",
        got.bias_sq,
        sd(b, sigma)
    );
    let unbiased = relative(0.0, sigma as f32, 9);
    assert!(
        unbiased.bias_sq.abs() < 5.0 * sd(0.0, sigma),
        "{}",
        unbiased.bias_sq
    );
    let rel_variance = weights.iter().map(|w| w * sigma * sigma).sum::<f64>() / n;
    assert!((unbiased.variance / rel_variance - 1.0).abs() < 0.05);
    assert!(unbiased.variance > 100.0 * 5.0 * sd(0.0, sigma));
    let mut acc = BiasVarianceAccumulator::new(W, H);
    acc.add(&ImageView::new("render", W, H, &y).unwrap())
        .unwrap();
    acc.add(&ImageView::new("render", W, H, &y).unwrap())
        .unwrap();
    let err = acc
        .finish_relative(&ImageView::new("reference", W, H, &y).unwrap(), 0.0)
        .unwrap_err();
    assert!(err.to_string().contains("epsilon"), "{err}");
}

/// The per-pixel decomposition: its image means are the image-averaged figures, and a pixel
/// given a bias carries it in its green channel while the unbiased ones stay near zero; a
/// decomposition that forgot the variance's correction (the raw `(x̄ − y)²`) would put
/// `σ²/R` into every pixel's bias, which the unbiased pixels' mean shows (the control).
#[test]
fn per_pixel_decomposition_averages_to_the_image_figures_and_finds_a_biased_pixel() {
    let y = reference();
    let mut rs = renders(&y, 0.0, 0.2, 91);
    // Pixel 100 biased by 0.5 in every render.
    for r in &mut rs {
        r[100] = r[100].map(|v| v + 0.5);
    }
    let mut acc = BiasVarianceAccumulator::new(W, H);
    for r in &rs {
        acc.add(&ImageView::new("render", W, H, r).unwrap())
            .unwrap();
    }
    let reference = ImageView::new("reference", W, H, &y).unwrap();
    let whole = acc.finish(&reference, None).unwrap();
    let px = acc.per_pixel(&reference, None).unwrap();
    let n = (W * H) as f64;
    let mean = |c: usize| px.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n;
    assert!(
        (mean(1) - whole.bias_sq).abs() < 1e-6,
        "{} vs {}",
        mean(1),
        whole.bias_sq
    );
    assert!(
        (mean(2) - whole.variance).abs() < 1e-6,
        "{} vs {}",
        mean(2),
        whole.variance
    );
    assert!((mean(0) - whole.bias_sq - whole.variance).abs() < 1e-6);
    // The biased pixel: 0.25 of bias², within 5 standard errors of its mean's noise.
    let (sigma, r) = (0.2f64, R as f64);
    let se = (2.0 * 0.5 * sigma / r.sqrt() + sigma * sigma / r) * 5.0;
    let b = px.pixels[100][1] as f64;
    assert!((b - 0.25).abs() < se, "the biased pixel's bias² {b}");
    // The others: mean bias² near zero (its standard error over the pixels, ×5), where the
    // uncorrected (x̄ − y)² would be σ²/R = 6.25e-4.
    let others: f64 = px
        .pixels
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 100)
        .map(|(_, p)| p[1] as f64)
        .sum::<f64>()
        / (n - 1.0);
    let v = sigma * sigma / r;
    let bound = 5.0 * v * (2.0f64 / (3.0 * (n - 1.0))).sqrt();
    assert!(
        others.abs() < bound,
        "unbiased pixels' mean bias² {others:e} (bound {bound:e})"
    );
    let raw = others + v;
    assert!(
        raw.abs() > bound,
        "the control: the raw estimate {raw:e} would pass"
    );
}
