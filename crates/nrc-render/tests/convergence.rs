//! Convergence on the shipped Cornell box.
//!
//! 1. The mean of 16 independent 4-spp renders agrees with a 1024-spp render per pixel:
//!    the difference over its standard error (both renders' sample variances) is about
//!    standard normal for unbiased estimators, so about 1% of pixel channels exceed the 99%
//!    bound (2.576); the test allows 3%. The per-sample variance is pooled from all renders.
//! 2. The mean squared error against the 1024-spp render falls like 1/spp: after removing
//!    the reference's own noise (E[(X − R)²] = Var X + Var R for independent X, R), the
//!    least-squares slope of log MSE against log spp over 1…32 spp is −1 ± 0.2. (Over four
//!    seed sets the slope came out between −0.99 and −1.10: a few bright indirect paths
//!    make the MSE estimate itself noisy. A bias would flatten the curve toward 0.)

mod common;

use common::{channels, project_scenes, render_scene};
use nrc_render::PathTracer;
use nrc_scene::Scene;

const W: u32 = 32;
const H: u32 = 32;

#[test]
fn cornell_box_converges_to_the_reference() {
    let path = project_scenes().join("cornell-box.gltf");
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let tracer = PathTracer::default();

    let n_ref = 1024;
    let reference = render_scene(&scene, &tracer, W, H, n_ref, 1000);
    let r_mean = channels(&reference.mean);
    let r_var = channels(reference.variance.as_ref().unwrap());
    let n = r_mean.len();

    // 1. Mean of independent low-spp renders.
    let (k, spp) = (16u32, 4u32);
    let mut sum = vec![0.0f64; n];
    let mut var_sum = vec![0.0f64; n];
    for i in 0..k {
        let out = render_scene(&scene, &tracer, W, H, spp, i as u64);
        for (j, (m, v)) in channels(&out.mean)
            .iter()
            .zip(channels(out.variance.as_ref().unwrap()))
            .enumerate()
        {
            sum[j] += m;
            var_sum[j] += v;
        }
    }
    let mut outside = 0;
    let mut tested = 0;
    for j in 0..n {
        let mean = sum[j] / k as f64;
        // Both sides sample the same estimator, so its per-sample variance is pooled from
        // all renders (dominated by the reference's 1024 samples). A variance estimated from
        // the 64 low-spp samples alone would be correlated with their mean: in dark corners
        // lit by rare paths, a mean that missed them comes with a small variance too.
        let dof_low = (k * (spp - 1)) as f64;
        let dof_ref = (n_ref - 1) as f64;
        let sigma2 = (var_sum[j] * (spp - 1) as f64 + r_var[j] * dof_ref) / (dof_low + dof_ref);
        let var = sigma2 / (k * spp) as f64 + sigma2 / n_ref as f64;
        if var > 0.0 {
            tested += 1;
            if (mean - r_mean[j]).abs() > 2.576 * var.sqrt() {
                outside += 1;
            }
        } else {
            assert!(
                (mean - r_mean[j]).abs() < 1e-6,
                "channel {j}: exact values differ"
            );
        }
    }
    let frac = outside as f64 / tested as f64;
    eprintln!(
        "{:.2}% of {tested} pixel channels outside the 99% bound",
        100.0 * frac
    );
    assert!(tested > n / 2, "only {tested} of {n} pixel channels vary");
    assert!(
        frac < 0.03,
        "{:.2}% of pixel channels outside the 99% bound",
        100.0 * frac
    );

    // 2. MSE against spp.
    let ref_noise = r_var.iter().sum::<f64>() / n as f64 / n_ref as f64;
    let mut points = Vec::new();
    for (i, spp) in [1u32, 2, 4, 8, 16, 32].into_iter().enumerate() {
        // The MSE of one render is itself a noisy, skewed estimate (a few bright paths
        // dominate it at low spp): average it over 128/spp renders, so that every point
        // rests on the same number of paths.
        let renders = 128 / spp;
        let mut mse = 0.0;
        for s in 0..renders {
            let out = render_scene(&scene, &tracer, W, H, spp, 100 * (i as u64 + 1) + s as u64);
            mse += channels(&out.mean)
                .iter()
                .zip(&r_mean)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                / n as f64;
        }
        let mse = mse / renders as f64 - ref_noise;
        assert!(mse > 0.0, "MSE at {spp} spp below the reference noise");
        points.push(((spp as f64).ln(), mse.ln()));
    }
    let m = points.len() as f64;
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / m, sy / m);
    let slope = points.iter().map(|(x, y)| (x - mx) * (y - my)).sum::<f64>()
        / points.iter().map(|(x, _)| (x - mx).powi(2)).sum::<f64>();
    eprintln!("log MSE vs log spp: slope {slope:.3}; points {points:.3?}");
    assert!(
        (slope + 1.0).abs() < 0.2,
        "MSE falls with slope {slope:.3}, expected −1"
    );
}
