//! Statistical tests of the warps in `nrc_scene::sampling`: χ² goodness of fit of each
//! sampler against its density, densities integrating to 1, and the MIS weights.

mod stat;

use glam::{Vec2, Vec3};
use nrc_scene::sampling::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use stat::{SphereBins, chi2_p_value, chi2_test, ln_gamma, sidak};

/// Number of χ² tests in this file, for the Šidák correction (family-wise level 1%).
const CHI2_TESTS: usize = 6;
const SAMPLES: usize = 400_000;

fn level() -> f64 {
    sidak(0.01, CHI2_TESTS)
}

fn u2(rng: &mut Pcg64) -> Vec2 {
    Vec2::new(rng.random(), rng.random())
}

#[test]
fn statistics_match_reference_values() {
    assert!(ln_gamma(1.0).abs() < 1e-12 && ln_gamma(2.0).abs() < 1e-12);
    assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12);
    for x in [0.1, 1.0, 3.0, 20.0] {
        // Two degrees of freedom: the tail is exp(−x/2).
        assert!((chi2_p_value(x, 2) - (-0.5 * x).exp()).abs() < 1e-12);
    }
    // Critical values from standard χ² tables.
    for (x, dof, p) in [
        (3.841_459, 1, 0.05),
        (23.209_251, 10, 0.01),
        (135.806_723, 100, 0.01),
        (1_106.969_2, 1000, 0.01),
    ] {
        let got = chi2_p_value(x, dof);
        assert!(
            (got - p).abs() < 1e-5 * p.max(1e-3) * 10.0,
            "dof {dof}: {got} vs {p}"
        );
    }
}

/// χ² of a direction sampler against its density over a (cos θ, φ) histogram; asserts a fit.
fn sphere_chi2(name: &str, seed: u64, sample: impl Fn(Vec2) -> Vec3, pdf: impl Fn(Vec3) -> f32) {
    let p = sphere_chi2_p(name, seed, sample, pdf);
    assert!(p > level(), "{name}: p = {p:.2e} below {:.2e}", level());
}

/// The negative control of [`sphere_chi2`]: cosine-hemisphere samples scored against the
/// normalised `cos^1.1` lobe (10 % off in the exponent, a density that still integrates to 1)
/// must be rejected at the same level.
#[test]
fn chi2_rejects_a_slightly_wrong_density() {
    let n = 1.1f32;
    let p = sphere_chi2_p(
        "cosine samples against cos^1.1",
        1,
        sample_cosine_hemisphere,
        |w| {
            if w.z > 0.0 {
                (n + 1.0) / (2.0 * std::f32::consts::PI) * w.z.powf(n)
            } else {
                0.0
            }
        },
    );
    assert!(
        p < level(),
        "the χ² test accepted a wrong density: p = {p:.3}"
    );
}

/// The p-value of [`sphere_chi2`]'s test.
fn sphere_chi2_p(
    name: &str,
    seed: u64,
    sample: impl Fn(Vec2) -> Vec3,
    pdf: impl Fn(Vec3) -> f32,
) -> f64 {
    let bins = SphereBins {
        cos_bins: 16,
        phi_bins: 32,
    };
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut observed = vec![0.0; bins.len()];
    for _ in 0..SAMPLES {
        let w = sample(u2(&mut rng));
        assert!((w.length() - 1.0).abs() < 1e-4, "{name}: not unit {w}");
        observed[bins.index(w)] += 1.0;
    }
    let mass = bins.integrate(&|w| f64::from(pdf(w)), 1e-9, 1e-6, &|_| 1);
    let total: f64 = mass.iter().sum();
    assert!(
        (total - 1.0).abs() < 1e-4,
        "{name}: density integrates to {total}"
    );
    let expected: Vec<f64> = mass.iter().map(|m| m * SAMPLES as f64).collect();
    let r = chi2_test(&observed, &expected).unwrap_or_else(|e| panic!("{name}: {e}"));
    eprintln!(
        "{name}: χ² = {:.1}, dof {}, p = {:.3}",
        r.statistic, r.dof, r.p_value
    );
    r.p_value
}

#[test]
fn cosine_hemisphere_fits_its_pdf() {
    sphere_chi2("cosine hemisphere", 1, sample_cosine_hemisphere, |w| {
        cosine_hemisphere_pdf(w.z)
    });
}

#[test]
fn uniform_sphere_fits_its_pdf() {
    sphere_chi2("uniform sphere", 2, sample_uniform_sphere, |_| {
        uniform_sphere_pdf()
    });
}

#[test]
fn uniform_hemisphere_fits_its_pdf() {
    sphere_chi2("uniform hemisphere", 3, sample_uniform_hemisphere, |w| {
        if w.z >= 0.0 {
            uniform_hemisphere_pdf()
        } else {
            0.0
        }
    });
}

/// Barycentrics on a K × K grid of the (b1, b2) square: cells below the diagonal hold area
/// 1/K², cells cut by it 1/(2K²), the rest none; the triangle has area 1/2.
#[test]
fn triangle_samples_are_uniform() {
    const K: usize = 24;
    let mut rng = Pcg64::seed_from_u64(4);
    let mut observed = vec![0.0; K * K];
    for _ in 0..SAMPLES {
        let (b1, b2) = sample_uniform_triangle(u2(&mut rng));
        assert!(
            b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 + 1e-6,
            "({b1}, {b2})"
        );
        let i = ((b1 * K as f32) as usize).min(K - 1);
        let j = ((b2 * K as f32) as usize).min(K - 1);
        observed[i * K + j] += 1.0;
    }
    let expected: Vec<f64> = (0..K * K)
        .map(|c| {
            let (i, j) = (c / K, c % K);
            let area = match (i + j + 1).cmp(&K) {
                std::cmp::Ordering::Less => 1.0,
                std::cmp::Ordering::Equal => 0.5,
                std::cmp::Ordering::Greater => 0.0,
            };
            2.0 * area / (K * K) as f64 * SAMPLES as f64
        })
        .collect();
    let r = chi2_test(&observed, &expected).unwrap();
    eprintln!(
        "uniform triangle: χ² = {:.1}, dof {}, p = {:.3}",
        r.statistic, r.dof, r.p_value
    );
    assert!(r.p_value > level());
}

/// Uniform on the disk: uniform in (r², φ).
#[test]
fn concentric_disk_is_uniform() {
    const K: usize = 20;
    let mut rng = Pcg64::seed_from_u64(5);
    let mut observed = vec![0.0; K * K];
    for _ in 0..SAMPLES {
        let p = sample_concentric_disk(u2(&mut rng));
        let r2 = p.length_squared();
        assert!(r2 <= 1.0 + 1e-5);
        let phi = p.y.atan2(p.x).rem_euclid(std::f32::consts::TAU);
        let i = ((r2 * K as f32) as usize).min(K - 1);
        let j = ((phi / std::f32::consts::TAU * K as f32) as usize).min(K - 1);
        observed[i * K + j] += 1.0;
    }
    let expected = vec![SAMPLES as f64 / (K * K) as f64; K * K];
    let r = chi2_test(&observed, &expected).unwrap();
    eprintln!(
        "concentric disk: χ² = {:.1}, dof {}, p = {:.3}",
        r.statistic, r.dof, r.p_value
    );
    assert!(r.p_value > level());
}

/// Frame round trip on random normals, and the χ² of a cosine lobe around a tilted normal
/// brought to world space.
#[test]
fn frame_maps_cosine_lobe_to_world() {
    let mut rng = Pcg64::seed_from_u64(6);
    for _ in 0..10_000 {
        let n = sample_uniform_sphere(u2(&mut rng));
        let f = Frame::from_normal(n);
        let v = sample_uniform_sphere(u2(&mut rng));
        assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        assert!(f.s.cross(f.t).dot(n) > 0.9999);
    }
    let n = Vec3::new(0.3, -0.5, 0.8).normalize();
    let f = Frame::from_normal(n);
    sphere_chi2(
        "cosine lobe in a frame",
        7,
        |u| f.to_world(sample_cosine_hemisphere(u)),
        |w| cosine_hemisphere_pdf(w.dot(n)),
    );
}

#[test]
fn power_heuristic_weights_sum_to_one() {
    let mut rng = Pcg64::seed_from_u64(8);
    for _ in 0..10_000 {
        let (a, b): (f32, f32) = (rng.random::<f32>() * 100.0, rng.random::<f32>() * 100.0);
        let (na, nb) = (1.0 + (rng.random::<f32>() * 4.0).floor(), 1.0);
        let s = power_heuristic(na, a, nb, b) + power_heuristic(nb, b, na, a);
        assert!(
            (s - 1.0).abs() < 1e-5 || (a == 0.0 && b == 0.0),
            "{a} {b}: {s}"
        );
    }
    assert!((luminance(Vec3::ONE) - 1.0).abs() < 1e-6);
    assert!(luminance(Vec3::new(0.0, 1.0, 0.0)) > luminance(Vec3::new(1.0, 0.0, 1.0)));
}
