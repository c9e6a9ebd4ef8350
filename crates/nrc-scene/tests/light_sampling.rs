//! χ² goodness of fit of the light samplers against their densities: environment-map
//! directions (the piecewise-constant 2D distribution, sin θ weighted, rotated) and a spot
//! light's emission cone (proportional to glTF's falloff). Each has a negative control: the
//! same samples binned against a plausible but wrong density must fail.

mod stat;

use std::path::Path;

use glam::{Vec2, Vec3};
use nrc_scene::{Environment, PunctualKind, PunctualLight};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use stat::{SphereBins, chi2_test, sidak};

const SAMPLES: usize = 300_000;

/// χ² p-value of `samples` (directions) against the solid-angle density `pdf`.
fn p_value(samples: &[Vec3], pdf: &dyn Fn(Vec3) -> f64) -> f64 {
    let bins = SphereBins {
        cos_bins: 24,
        phi_bins: 48,
    };
    let mut observed = vec![0.0; bins.len()];
    for &w in samples {
        observed[bins.index(w)] += 1.0;
    }
    let mass = bins.integrate(pdf, 1e-9, 1e-5, &|_| 3);
    let total: f64 = mass.iter().sum();
    // Adaptive Simpson meets the environment density's 1/sin θ at its poles (integrable): 0.5 %.
    assert!(
        (total - 1.0).abs() < 5e-3,
        "the density integrates to {total}"
    );
    let expected: Vec<f64> = mass.iter().map(|m| m * samples.len() as f64).collect();
    let r = chi2_test(&observed, &expected).unwrap_or_else(|e| panic!("{e}"));
    println!("χ² {:.1} dof {} p {:.3e}", r.statistic, r.dof, r.p_value);
    r.p_value
}

/// Texel `i` of the test sky (`w` wide): bright rows near the zenith, a hot spot, a dark band.
fn texel(i: usize, w: usize) -> Vec3 {
    let (x, y) = (i % w, i / w);
    let base = if y < 4 { 2.0 } else { 0.3 };
    let spot = if (10..13).contains(&x) && (5..8).contains(&y) {
        20.0
    } else {
        0.0
    };
    let band = if y == 12 { 0.0 } else { 1.0 };
    Vec3::new(base + spot, 0.5 * base + spot, base) * band
}

fn sky(rotate_degrees: f32) -> Environment {
    let (w, h) = (32, 16);
    let texels = (0..w * h).map(|i| texel(i, w)).collect();
    Environment::from_texels(Path::new("<sky>"), w, h, texels, 1.5, rotate_degrees)
        .unwrap()
        .0
}

#[test]
fn environment_sampling_matches_its_density() {
    let (w, h, rot) = (32usize, 16usize, 37f32);
    let env = sky(rot);
    let mut rng = Pcg64::seed_from_u64(3);
    // The density a sample reports is the one `pdf` gives its direction, except where the
    // direction rounds across a texel edge (a neighbouring texel's density).
    let mut mismatched = 0;
    let mut observed = vec![0.0; w * h];
    let r = rot.to_radians();
    for _ in 0..SAMPLES {
        let Some((d, pdf)) = env.sample(Vec2::new(rng.random(), rng.random())) else {
            continue;
        };
        assert!(pdf > 0.0);
        mismatched += ((env.pdf(d) / pdf - 1.0).abs() > 1e-4) as usize;
        let map = Vec3::new(
            r.cos() * d.x - r.sin() * d.z,
            d.y,
            r.sin() * d.x + r.cos() * d.z,
        );
        let uv = nrc_scene::environment::direction_to_uv(map);
        let (x, y) = ((uv.x * w as f32) as usize, (uv.y * h as f32) as usize);
        observed[y.min(h - 1) * w + x.min(w - 1)] += 1.0;
    }
    assert!(mismatched < SAMPLES / 1000, "{mismatched} densities differ");
    let total: f64 = observed.iter().sum();
    assert!(total > 0.99 * SAMPLES as f64);
    let expected_with = |sin_weighted: bool| -> Vec<f64> {
        let weights: Vec<f64> = (0..w * h)
            .map(|i| {
                let sin = (std::f64::consts::PI * ((i / w) as f64 + 0.5) / h as f64).sin();
                let l = nrc_scene::sampling::luminance(texel(i, w)) as f64;
                if sin_weighted { l * sin } else { l }
            })
            .collect();
        let sum: f64 = weights.iter().sum();
        weights.iter().map(|x| x / sum * total).collect()
    };
    let good = chi2_test(&observed, &expected_with(true)).unwrap();
    println!(
        "χ² {:.1} dof {} p {:.3e}",
        good.statistic, good.dof, good.p_value
    );
    assert!(good.p_value > sidak(0.01, 3));
    let bad = chi2_test(&observed, &expected_with(false)).unwrap();
    println!(
        "without sin θ: χ² {:.1} p {:.3e}",
        bad.statistic, bad.p_value
    );
    assert!(bad.p_value < 1e-6);
    // ∫ pdf dω = Σ over a fine (u, v) grid of pdf · 2π² sin θ Δu Δv.
    let n = 1024;
    let mut integral = 0.0f64;
    for a in 0..n {
        for b in 0..n / 2 {
            let uv = Vec2::new(
                (a as f32 + 0.5) / n as f32,
                (b as f32 + 0.5) / (n / 2) as f32,
            );
            let d = nrc_scene::environment::uv_to_direction(uv);
            let world = Vec3::new(
                r.cos() * d.x + r.sin() * d.z,
                d.y,
                -r.sin() * d.x + r.cos() * d.z,
            );
            let jac =
                2.0 * std::f64::consts::PI.powi(2) * (std::f64::consts::PI * uv.y as f64).sin();
            integral += env.pdf(world) as f64 * jac / (n * n / 2) as f64;
        }
    }
    assert!((integral - 1.0).abs() < 1e-3, "∫ pdf dω = {integral}");
    // The constant environment samples the sphere uniformly.
    let uniform = Environment::constant(Vec3::ONE);
    let u: Vec<Vec3> = (0..SAMPLES)
        .map(|_| {
            uniform
                .sample(Vec2::new(rng.random(), rng.random()))
                .unwrap()
                .0
        })
        .collect();
    assert!(p_value(&u, &|w| uniform.pdf(w) as f64) > sidak(0.01, 3));
}

#[test]
fn spot_cone_sampling_matches_its_falloff() {
    let spot = PunctualLight {
        kind: PunctualKind::Spot {
            cos_inner: 0.25f32.cos(),
            cos_outer: 0.7f32.cos(),
        },
        position: Vec3::ZERO,
        direction: Vec3::new(0.2, 0.1, 1.0).normalize(),
        intensity: Vec3::ONE,
        range: None,
    };
    let mut rng = Pcg64::seed_from_u64(5);
    let samples: Vec<Vec3> = (0..SAMPLES)
        .filter_map(|_| spot.sample_direction(Vec2::new(rng.random(), rng.random())))
        .map(|(d, _)| d)
        .collect();
    assert!(samples.len() > SAMPLES * 99 / 100);
    assert!(p_value(&samples, &|w| spot.direction_pdf(w) as f64) > sidak(0.01, 2));
    // Negative control: a uniform cone out to the outer angle is the wrong density.
    let cos_outer = 0.7f64.cos();
    let uniform_cone = |w: Vec3| {
        if (w.dot(spot.direction) as f64) >= cos_outer {
            1.0 / (2.0 * std::f64::consts::PI * (1.0 - cos_outer))
        } else {
            0.0
        }
    };
    assert!(p_value(&samples, &uniform_cone) < 1e-6);
}
