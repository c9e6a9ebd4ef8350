//! Furnace tests: configurations whose radiance is known in closed form.
//!
//! Each pixel's mean must lie within `z · σ̂/√spp` of the answer, σ̂ the pixel's sample
//! standard deviation, with `z` from a Bonferroni correction over all pixels and channels
//! so that the whole image passes with probability 1 − 10⁻⁴ when the renderer is
//! unbiased; the image mean must lie within 4 standard errors.

mod common;

use common::{Mesh, SceneBuilder, channels, mat, render_scene, z_two_sided};
use glam::Vec3;
use nrc_render::{LightStrategy, PathTracer, RenderOutput};

/// Checks every pixel and the image mean of `out` against `expected` (per channel).
fn assert_matches(out: &RenderOutput, spp: u32, expected: Vec3, what: &str) {
    let mean = channels(&out.mean);
    let var = channels(out.variance.as_ref().expect("variance requested"));
    let z = z_two_sided(1e-4 / mean.len() as f64);
    let exp = [expected.x as f64, expected.y as f64, expected.z as f64];
    let mut sum_diff = [0.0f64; 3];
    let mut sum_var = [0.0f64; 3];
    for (i, (&m, &v)) in mean.iter().zip(&var).enumerate() {
        let c = i % 3;
        let se = (v / spp as f64).sqrt();
        let d = m - exp[c];
        // Plus a float-rounding allowance for pixels whose samples are all (nearly) equal.
        assert!(
            d.abs() <= z * se + 1e-5 * exp[c],
            "{what}: pixel {} channel {c}: mean {m:.5}, expected {:.5}, {:.1} standard errors (bound {z:.2})",
            i / 3,
            exp[c],
            d.abs() / se
        );
        sum_diff[c] += d;
        sum_var[c] += v / spp as f64;
    }
    let n = (mean.len() / 3) as f64;
    for c in 0..3 {
        let se = sum_var[c].sqrt() / n;
        let d = sum_diff[c] / n;
        assert!(
            d.abs() <= 4.0 * se,
            "{what}: image mean channel {c} off by {d:.5} = {:.1} standard errors",
            d.abs() / se
        );
    }
}

/// A closed box whose walls emit `Le = 1` inward and reflect diffusely with albedo ρ.
/// Every point sees only walls, so L = Le + ρ L: with unlimited depth L = Le / (1 − ρ),
/// and with at most `k` path segments L = Le (1 + ρ + … + ρ^(k−1)).
fn emissive_enclosure(rho: Vec3) -> nrc_scene::Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(mat::emissive(rho, Vec3::ONE, false));
    b.mesh(
        &Mesh::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), true),
        m,
        false,
    )
    .camera(Vec3::new(0.1, 0.2, 0.3), Vec3::new(1.0, 0.5, -0.7), 90.0);
    b.build()
}

/// The estimators checked in the enclosure. NEE alone (`LightOnly`) is unbiased here too,
/// but in a box its variance is infinite: near an edge the geometry term cos·cos/d² to the
/// adjacent wall is integrable while its square is not, so the sample variance the bound
/// needs means nothing. MIS removes that singularity (BSDF sampling takes over there).
const STRATEGIES: [LightStrategy; 2] = [LightStrategy::Mis, LightStrategy::BsdfOnly];

#[test]
fn emissive_enclosure_unlimited_depth() {
    let rho = Vec3::new(0.2, 0.5, 0.8);
    let scene = emissive_enclosure(rho);
    let expected = Vec3::ONE / (Vec3::ONE - rho);
    let spp = 64;
    for (k, strategy) in STRATEGIES.into_iter().enumerate() {
        let tracer = PathTracer {
            max_depth: -1,
            rr_depth: 3,
            strategy,
            ..PathTracer::default()
        };
        let out = render_scene(&scene, &tracer, 16, 12, spp, 10 + k as u64);
        assert_eq!(out.stats.invalid_samples, 0);
        assert_matches(&out, spp, expected, &format!("{strategy:?}"));
    }
}

#[test]
fn emissive_enclosure_depth_follows_mitsuba_convention() {
    let rho = Vec3::new(0.3, 0.5, 0.7);
    let scene = emissive_enclosure(rho);
    let spp = 32;
    for max_depth in 1..=4 {
        let expected = (0..max_depth).fold(Vec3::ZERO, |s, i| s + rho.powf(i as f32));
        for (k, strategy) in STRATEGIES.into_iter().enumerate() {
            let tracer = PathTracer {
                max_depth,
                rr_depth: 100,
                strategy,
                ..PathTracer::default()
            };
            let out = render_scene(
                &scene,
                &tracer,
                12,
                8,
                spp,
                100 * max_depth as u64 + k as u64,
            );
            if max_depth == 1 {
                // Only the emission seen by camera rays: exact.
                assert!(
                    out.mean
                        .data
                        .iter()
                        .all(|p| (*p - Vec3::ONE).abs().max_element() < 1e-6)
                );
            } else {
                assert_matches(
                    &out,
                    spp,
                    expected,
                    &format!("{strategy:?} max_depth {max_depth}"),
                );
            }
        }
    }
}

/// Russian roulette on the throughput a walk arrives with ([`PathTracer::reflected_after`],
/// what `wsrestir-gi` uses for the walk it continues after a reconnection vertex): in the enclosure the
/// radiance reflected at a wall is `ρ / (1 − ρ)` whatever the throughput the path arrived
/// with, and a walk that arrived with less is shorter. The same check must reject a walk cut
/// at a depth limit (its mean is `ρ + … + ρ^(k−1)`, 9 % low here).
#[test]
fn roulette_on_the_arriving_throughput_stays_exact_with_shorter_walks() {
    let rho = 0.8;
    let scene = emissive_enclosure(Vec3::splat(rho));
    let ray = nrc_scene::Ray::new(Vec3::ZERO, Vec3::new(0.3, -0.2, 1.0).normalize());
    let hit = scene.intersect(&ray).expect("inside the box");
    let si = scene.interaction(&ray, &hit);
    let expected = rho / (1.0 - rho);
    let n = 40_000u64;
    // Mean, its standard error and rays per walk of `reflected_after` with `prefix`.
    let walk = |tracer: &PathTracer, prefix: f32| {
        let (mut sum, mut sum2, mut stats) = (0.0f64, 0.0f64, nrc_render::PathStats::default());
        for j in 0..n {
            let mut s = nrc_render::PixelSampler::new(5, 0, j);
            let l = tracer.reflected_after(&scene, &si, si.wo, 1, prefix, &mut s, &mut stats);
            sum += l.x as f64;
            sum2 += (l.x as f64).powi(2);
        }
        let mean = sum / n as f64;
        let se = ((sum2 / n as f64 - mean * mean) / n as f64).sqrt();
        (mean, se, stats.rays() as f64 / n as f64)
    };
    let within = |(mean, se, _): (f64, f64, f64)| (mean - expected as f64).abs() <= 4.0 * se;
    let tracer = PathTracer {
        rr_depth: 2,
        ..PathTracer::default()
    };
    let whole = walk(&tracer, 1.0);
    let arrived_dim = walk(&tracer, 0.2);
    assert!(within(whole), "prefix 1: {whole:?}, expected {expected}");
    assert!(
        within(arrived_dim),
        "prefix 0.2: {arrived_dim:?}, expected {expected}"
    );
    assert!(
        arrived_dim.2 < 0.8 * whole.2,
        "a walk arriving with throughput 0.2 should trace fewer rays: {:.2} against {:.2}",
        arrived_dim.2,
        whole.2
    );
    // Negative control: cut at 12 segments, the walk misses ρ¹² / (1 − ρ) = 0.34 of 4.
    let cut = walk(
        &PathTracer {
            max_depth: 12,
            rr_depth: 100,
            ..tracer
        },
        1.0,
    );
    println!(
        "(mean, standard error, rays a walk): prefix 1 {whole:?}, prefix 0.2 {arrived_dim:?}, cut {cut:?}"
    );
    assert!(
        !within(cut),
        "a walk cut at 12 segments passed: {cut:?}, expected {expected}"
    );
}

/// A lossless world under a uniform background of radiance 1: a white Lambertian sphere,
/// a smooth glass sphere and a perfect mirror sphere (Fresnel reflectance 1) over a white
/// diffuse floor. Flat facets throughout: interpolated normals would scatter some rays into
/// the surface they leave (a closed lossless cavity, where the answer is not 1). No energy is
/// absorbed anywhere, so the radiance is 1 everywhere; with Russian roulette and unlimited
/// depth every pixel must render 1 within the statistical bound.
#[test]
fn lossless_objects_under_uniform_background() {
    let mut b = SceneBuilder::new();
    let white = b.material(mat::diffuse(Vec3::ONE));
    let glass = b.material(mat::glass(1.5, 0.0));
    let mirror = b.material(mat::metal(Vec3::ONE, 0.0));
    b.mesh(
        &Mesh::sphere(Vec3::new(-1.1, 0.5, 0.0), 0.5, 12, 24),
        white,
        false,
    )
    .mesh(
        &Mesh::sphere(Vec3::new(0.0, 0.5, 0.0), 0.5, 16, 32),
        glass,
        false,
    )
    .mesh(
        &Mesh::sphere(Vec3::new(1.1, 0.5, 0.0), 0.5, 16, 32),
        mirror,
        false,
    )
    .mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -3.0),
        ),
        white,
        false,
    )
    .camera(Vec3::new(0.0, 1.5, 3.5), Vec3::new(0.0, 0.4, 0.0), 45.0)
    .background(Vec3::ONE);
    let scene = b.build();
    let spp = 128;
    let tracer = PathTracer::default();
    let out = render_scene(&scene, &tracer, 32, 24, spp, 7);
    assert_eq!(out.stats.invalid_samples, 0);
    assert_matches(&out, spp, Vec3::ONE, "lossless world");
}
