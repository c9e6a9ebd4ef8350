//! The light sampler chooses emissive triangles in proportion to their power and points
//! uniformly on them, and its area densities are consistent with what it samples.

use glam::{Vec2, Vec3};
use nrc_scene::sampling::luminance;
use nrc_scene::{Material, Scene, SceneDescription};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Pearson's χ² statistic of observed counts against expected probabilities.
fn chi2(counts: &[u64], probs: &[f64]) -> f64 {
    let n: u64 = counts.iter().sum();
    counts
        .iter()
        .zip(probs)
        .map(|(&c, &p)| {
            let e = p * n as f64;
            (c as f64 - e).powi(2) / e
        })
        .sum()
}

/// Upper quantile of χ² with `k` degrees of freedom at significance ~1e-6 (Wilson–Hilferty
/// approximation with z = 4.75).
fn chi2_critical(k: usize) -> f64 {
    let k = k as f64;
    let z = 4.75;
    k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3)
}

/// Twelve emissive triangles of different sizes, colours and sidedness, plus a diffuse
/// floor that does not emit.
fn light_scene() -> Scene {
    let mut desc = SceneDescription::default();
    let mut materials = vec![Material {
        name: "floor".into(),
        ..Material::default()
    }];
    desc.positions.extend([
        Vec3::new(-10.0, -1.0, -10.0),
        Vec3::new(10.0, -1.0, -10.0),
        Vec3::new(0.0, -1.0, 10.0),
    ]);
    desc.triangles.push([0, 2, 1]);
    desc.triangle_materials.push(0);
    for i in 0..12u32 {
        let s = 0.2 + 0.15 * i as f32;
        let base = desc.positions.len() as u32;
        let o = Vec3::new(i as f32 * 2.0, 1.0 + (i % 3) as f32, 0.3 * i as f32);
        desc.positions
            .extend([o, o + Vec3::X * s, o + Vec3::new(0.3, 0.2, 1.0) * s]);
        desc.triangles.push([base, base + 1, base + 2]);
        materials.push(Material {
            name: format!("light{i}"),
            emissive: Vec3::new(1.0 + i as f32, 0.5 * (i % 4) as f32, 3.0 / (1.0 + i as f32)),
            double_sided: i.is_multiple_of(3),
            ..Material::default()
        });
        desc.triangle_materials.push(i + 1);
    }
    desc.materials = materials;
    Scene::from_description(desc).unwrap()
}

fn power(scene: &Scene, tri: u32) -> f64 {
    let m = &scene.materials()[scene.triangle_material(tri) as usize];
    let sides = if m.double_sided { 2.0 } else { 1.0 };
    luminance(m.emissive) as f64 * scene.triangle_area(tri) as f64 * sides
}

#[test]
fn selection_frequencies_follow_power() {
    let scene = light_scene();
    assert_eq!(scene.light_count(), 12);
    let lights = scene.lights().triangles().to_vec();
    let total: f64 = lights.iter().map(|&t| power(&scene, t)).sum();
    let probs: Vec<f64> = lights.iter().map(|&t| power(&scene, t) / total).collect();
    for (&t, &p) in lights.iter().zip(&probs) {
        assert!(
            (scene.lights().pmf(t) as f64 - p).abs() < 1e-6,
            "pmf ∝ power"
        );
    }
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let mut counts = vec![0u64; lights.len()];
    for _ in 0..200_000 {
        let s = scene
            .sample_light_by_power(rng.random(), Vec2::new(rng.random(), rng.random()))
            .and_then(|s| s.surface().copied())
            .unwrap();
        let k = lights.iter().position(|&t| t == s.tri).unwrap();
        counts[k] += 1;
    }
    let x2 = chi2(&counts, &probs);
    assert!(x2 < chi2_critical(lights.len() - 1), "χ² = {x2}");
}

#[test]
fn points_are_uniform_on_the_triangle() {
    let scene = light_scene();
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    // Midpoint subdivision gives four sub-triangles of equal area.
    let mut counts = [0u64; 4];
    let mut n = 0;
    while n < 100_000 {
        let s = scene
            .sample_light_by_power(rng.random(), Vec2::new(rng.random(), rng.random()))
            .and_then(|s| s.surface().copied())
            .unwrap();
        if s.tri != scene.lights().triangles()[5] {
            continue;
        }
        n += 1;
        let [a, b, c] = scene.triangle_vertices(s.tri);
        // Barycentrics of the sample.
        let (e1, e2, q) = (b - a, c - a, s.p - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (dq1, dq2) = (q.dot(e1), q.dot(e2));
        let det = d11 * d22 - d12 * d12;
        let b1 = (d22 * dq1 - d12 * dq2) / det;
        let b2 = (d11 * dq2 - d12 * dq1) / det;
        let b0 = 1.0 - b1 - b2;
        assert!(
            b0 > -1e-5 && b1 > -1e-5 && b2 > -1e-5,
            "point off the triangle"
        );
        assert!(
            (s.p - a).dot(s.n).abs() < 1e-5 * (b - a).length(),
            "point off the plane"
        );
        let k = if b0 > 0.5 {
            0
        } else if b1 > 0.5 {
            1
        } else if b2 > 0.5 {
            2
        } else {
            3
        };
        counts[k] += 1;
    }
    let x2 = chi2(&counts, &[0.25; 4]);
    assert!(x2 < chi2_critical(3), "χ² = {x2}");
}

#[test]
fn area_densities_are_consistent() {
    let scene = light_scene();
    // Σ pdf_area · area = Σ pmf = 1 over the lights; zero elsewhere.
    let sum: f64 = scene
        .lights()
        .triangles()
        .iter()
        .map(|&t| {
            scene.light_pdf_area(
                &nrc_scene::LightContext::new(glam::Vec3::ZERO, glam::Vec3::ZERO),
                t,
            ) as f64
                * scene.triangle_area(t) as f64
        })
        .sum();
    assert!((sum - 1.0).abs() < 1e-5, "{sum}");
    let floor = (0..scene.triangle_count() as u32)
        .find(|&t| !scene.lights().triangles().contains(&t))
        .unwrap();
    assert_eq!(
        scene.light_pdf_area(
            &nrc_scene::LightContext::new(glam::Vec3::ZERO, glam::Vec3::ZERO),
            floor
        ),
        0.0
    );
    // Monte Carlo estimate of the emitted luminance integral ∫ L dA (both faces of
    // two-sided lights counted once, as radiance is per face): E[L / pdf_area].
    let exact: f64 = scene
        .lights()
        .triangles()
        .iter()
        .map(|&t| {
            let m = &scene.materials()[scene.triangle_material(t) as usize];
            luminance(m.emissive) as f64 * scene.triangle_area(t) as f64
        })
        .sum();
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let n = 100_000;
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let s = scene
            .sample_light_by_power(rng.random(), Vec2::new(rng.random(), rng.random()))
            .and_then(|s| s.surface().copied())
            .unwrap();
        assert_eq!(
            s.pdf_area,
            scene.light_pdf_area(
                &nrc_scene::LightContext::new(glam::Vec3::ZERO, glam::Vec3::ZERO),
                s.tri
            )
        );
        let x = luminance(s.le) as f64 / s.pdf_area as f64;
        sum += x;
        sum2 += x * x;
    }
    let mean = sum / n as f64;
    let std_err = ((sum2 / n as f64 - mean * mean) / n as f64).sqrt();
    assert!(
        (mean - exact).abs() < 5.0 * std_err + 1e-4 * exact,
        "estimate {mean} ± {std_err} vs exact {exact}"
    );
}

#[test]
fn one_sided_lights_emit_from_the_front_only() {
    let scene = light_scene();
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    for _ in 0..1000 {
        let s = scene
            .sample_light_by_power(rng.random(), Vec2::new(rng.random(), rng.random()))
            .and_then(|s| s.surface().copied())
            .unwrap();
        assert_eq!(s.le_toward(s.n), s.le);
        if s.two_sided {
            assert_eq!(s.le_toward(-s.n), s.le);
        } else {
            assert_eq!(s.le_toward(-s.n), Vec3::ZERO);
        }
        // The same radiance is seen by a ray hitting the light from the front.
        let ray = nrc_scene::Ray::new(s.p + s.n, -s.n);
        if let Some(hit) = scene.intersect(&ray)
            && hit.tri == s.tri
        {
            let si = scene.interaction(&ray, &hit);
            assert!((scene.emission(&si) - s.le).abs().max_element() < 1e-4);
            let back = nrc_scene::Ray::new(s.p - s.n, s.n);
            if let Some(h) = scene.intersect(&back)
                && h.tri == s.tri
            {
                let si = scene.interaction(&back, &h);
                let expected = if s.two_sided { s.le } else { Vec3::ZERO };
                assert!((scene.emission(&si) - expected).abs().max_element() < 1e-4);
            }
        }
    }
}
