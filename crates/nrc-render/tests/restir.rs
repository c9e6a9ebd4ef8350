//! Reservoirs, resampled importance sampling and the ReSTIR DI pass, checked statistically.

mod common;
#[path = "../../nrc-scene/tests/stat/mod.rs"]
mod stat;

use common::{
    accumulate_frames, last_frame, per_pixel_z, reference_at_centres, reference_at_centres_from,
};
use nrc_render::passes::{self, FrameInput, PassSpec};
use nrc_render::reservoir::Reservoir;
use nrc_render::{PathTracer, PixelSampler, ZeroSource};
use nrc_scene::{Image, Scene};

const WEIGHTS: [f32; 8] = [0.5, 1.0, 3.0, 0.25, 2.0, 0.0, 4.0, 1.25];

/// Streaming weighted reservoir sampling selects candidate `k` with probability
/// `w_k / Σ w` (χ² over 40 000 reservoirs); the same counts tested against a uniform choice
/// fail (the test sees a wrong distribution).
#[test]
fn weighted_reservoir_sampling_picks_in_proportion_to_weight() {
    let trials = 40_000;
    let mut counts = [0.0f64; WEIGHTS.len()];
    for t in 0..trials {
        let mut s = PixelSampler::new(1, t, 0);
        let mut r = Reservoir::new();
        for (k, &w) in WEIGHTS.iter().enumerate() {
            r.update(k, w, w, s.next_1d());
        }
        assert_eq!(r.m, WEIGHTS.len() as f32);
        counts[r.sample.unwrap()] += 1.0;
    }
    let total: f32 = WEIGHTS.iter().sum();
    let expected: Vec<f64> = WEIGHTS
        .iter()
        .map(|&w| (w / total) as f64 * trials as f64)
        .collect();
    let chi2 = stat::chi2_test(&counts, &expected).unwrap();
    assert!(chi2.p_value > 1e-4, "{chi2:?}");
    let uniform = vec![trials as f64 / WEIGHTS.len() as f64; WEIGHTS.len()];
    let wrong = stat::chi2_test(&counts, &uniform)
        .map(|c| c.p_value)
        .unwrap_or(0.0);
    assert!(wrong < 1e-6, "a uniform choice passed: p {wrong}");
}

/// Merging two finished reservoirs (each over half the candidates, target = weight) selects
/// each candidate as streaming the union does: the merged weight sum and count equal the
/// union's, and the selection frequencies pass the same χ² test.
#[test]
fn merging_two_reservoirs_equals_streaming_the_union() {
    let trials = 40_000;
    let mut counts = [0.0f64; 2 * WEIGHTS.len()];
    let weight = |k: usize| WEIGHTS[k % WEIGHTS.len()] * if k < WEIGHTS.len() { 1.0 } else { 0.6 };
    for t in 0..trials {
        let mut s = PixelSampler::new(2, t, 0);
        let mut a = Reservoir::new();
        let mut b = Reservoir::new();
        for k in 0..2 * WEIGHTS.len() {
            let r = if k < WEIGHTS.len() { &mut a } else { &mut b };
            r.update(k, weight(k), weight(k), s.next_1d());
        }
        a.finish(a.m);
        b.finish(b.m);
        let mut merged = Reservoir::new();
        merged.merge(&a, a.target, s.next_1d());
        merged.merge(&b, b.target, s.next_1d());
        let union: f32 = (0..2 * WEIGHTS.len()).map(weight).sum();
        assert!(
            (merged.w_sum - union).abs() <= 1e-5 * union,
            "{} vs {union}",
            merged.w_sum
        );
        assert_eq!(merged.m, 2.0 * WEIGHTS.len() as f32);
        counts[merged.sample.unwrap()] += 1.0;
    }
    let union: f32 = (0..2 * WEIGHTS.len()).map(weight).sum();
    let expected: Vec<f64> = (0..2 * WEIGHTS.len())
        .map(|k| (weight(k) / union) as f64 * trials as f64)
        .collect();
    let chi2 = stat::chi2_test(&counts, &expected).unwrap();
    assert!(chi2.p_value > 1e-4, "{chi2:?}");
}

/// `f(x) = x² + 0.1` on `[0, 1]` (integral 13/30). RIS from `M` uniform candidates with target
/// `p̂ = f`: `f(y) W` is exactly the plain Monte Carlo mean of the candidates. With another
/// target (`p̂ = x + 0.5`) RIS is unbiased: its mean over 20 000 estimates lies within 4
/// standard errors of 13/30; the same estimates without the `1/M` (W = w_sum / p̂) do not.
#[test]
fn ris_with_the_integrand_as_target_is_the_plain_monte_carlo_mean() {
    let f = |x: f32| x * x + 0.1;
    let m = 8;
    let (mut sum, mut sum2, mut wrong) = (0.0f64, 0.0f64, 0.0f64);
    let trials = 20_000;
    for t in 0..trials {
        let mut s = PixelSampler::new(3, t, 0);
        let xs: Vec<f32> = (0..m).map(|_| s.next_1d()).collect();
        let mut exact = Reservoir::new();
        let mut other = Reservoir::new();
        for &x in &xs {
            exact.update(x, f(x), f(x), s.next_1d());
            other.update(x, x + 0.5, x + 0.5, s.next_1d());
        }
        exact.finish(exact.m);
        other.finish(other.m);
        let plain = xs.iter().map(|&x| f(x)).sum::<f32>() / m as f32;
        let ris = f(exact.sample.unwrap()) * exact.w;
        assert!((ris - plain).abs() <= 1e-5 * plain, "{ris} vs {plain}");
        let e = (f(other.sample.unwrap()) * other.w) as f64;
        sum += e;
        sum2 += e * e;
        wrong += e * m as f64;
    }
    let n = trials as f64;
    let mean = sum / n;
    let se = ((sum2 / n - mean * mean) / (n - 1.0)).sqrt();
    let exact = 13.0 / 30.0;
    assert!(
        (mean - exact).abs() < 4.0 * se,
        "{mean} vs {exact} (se {se})"
    );
    let wrong = wrong / n;
    assert!(
        (wrong - exact).abs() > 4.0 * se * m as f64,
        "W without 1/M passed: {wrong}"
    );
}

fn cornell() -> Scene {
    Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap()
}

/// Unbiased ReSTIR DI at `--max-depth 2` (direct light only) matches the path-traced
/// depth-2 reference per pixel: 256 independent runs of 6 frames (temporal and spatial reuse
/// at work), the last frame of each a sample, a z-test per pixel channel (Bonferroni, family
/// false-alarm rate 10⁻³). The biased mode (Z = Σ M) run through the same test fails it.
/// Camera rays go through pixel centres (`jitter=0`) in the runs and in the reference: with
/// jittered rays, a pixel that a bright surface covers by a sliver is hit by few of 48 runs,
/// and the runs' variance misses what they never saw (the first version of this test failed
/// there, for the plain light sampler too).
#[test]
fn unbiased_restir_di_matches_the_depth_two_reference_per_pixel_and_biased_fails() {
    let scene = cornell();
    let tracer = PathTracer {
        max_depth: 2,
        ..Default::default()
    };
    let (w, h) = (24, 24);
    let ref_spp = 4096;
    let (reference, ref_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    let runs = 256;
    for (name, expect_pass) in [
        ("restir-di:jitter=0", true),
        ("restir-di-biased:jitter=0", false),
    ] {
        let spec: PassSpec = name.parse().unwrap();
        let images: Vec<Image> = (0..runs)
            .map(|r| last_frame(&scene, &spec, &tracer, w, h, 6, 1000 + r))
            .collect();
        let (worst, beyond, bound) = per_pixel_z(&images, &reference, &ref_var, ref_spp);
        println!(
            "{name}: worst per-pixel |z| {worst:.2}, {beyond} pixel channels beyond {bound:.2}"
        );
        if expect_pass {
            assert_eq!(beyond, 0, "{name}: worst |z| {worst:.2} (bound {bound:.2})");
        } else {
            assert!(
                beyond > 0,
                "{name} passed the unbiasedness test: worst |z| {worst:.2}"
            );
        }
    }
}

/// The image is a function of the seed alone: 1 and 2 threads give identical frames (three
/// frames, so that temporal and spatial reuse run), for every resampling pass.
#[test]
fn restir_di_is_identical_on_one_and_two_threads() {
    let scene = cornell();
    let tracer = PathTracer::default();
    for name in ["restir-di", "restir-di-biased", "restir-gi", "wsrestir-gi"] {
        let spec: PassSpec = name.parse().unwrap();
        let on = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| last_frame(&scene, &spec, &tracer, 20, 16, 3, 5))
        };
        let (a, b) = (on(1), on(2));
        assert_eq!(a.data, b.data, "{name}");
        assert!(a.data.iter().any(|p| p.max_element() > 0.0));
    }
}

/// The reconnection Jacobian and its inverse multiply to 1, and it is the ratio of the solid
/// angles a small patch around the reconnection vertex subtends at the receiver and at the
/// donor (finite difference: a triangle of side 10⁻³, its solid angle by Van Oosterom and
/// Strackee's formula).
#[test]
fn the_reconnection_jacobian_is_the_ratio_of_solid_angles() {
    use glam::Vec3;
    use nrc_render::passes::restir_gi::reconnection_jacobian;
    let solid_angle = |o: Vec3, a: Vec3, b: Vec3, c: Vec3| {
        let (a, b, c) = ((a - o).as_dvec3(), (b - o).as_dvec3(), (c - o).as_dvec3());
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c)).abs();
        let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        2.0 * num.atan2(den)
    };
    let y = Vec3::new(0.2, -0.1, 0.3);
    let n = Vec3::new(0.1, 1.0, -0.2).normalize();
    let t = n.cross(Vec3::X).normalize();
    let b = n.cross(t);
    let h = 1e-3f32;
    let (p0, p1, p2) = (
        y - (t + b) * h / 3.0,
        y + t * h - (t + b) * h / 3.0,
        y + b * h - (t + b) * h / 3.0,
    );
    for (receiver, donor) in [
        (Vec3::new(1.0, 2.0, 0.5), Vec3::new(-0.7, 1.1, 1.3)),
        (Vec3::new(0.3, 0.4, 0.2), Vec3::new(3.0, 5.0, -2.0)),
        (Vec3::new(-2.0, 0.2, 0.1), Vec3::new(0.5, 0.9, 0.6)),
    ] {
        let j = reconnection_jacobian(receiver, donor, y, n);
        let back = reconnection_jacobian(donor, receiver, y, n);
        assert!((j * back - 1.0).abs() < 1e-5, "{j} · {back}");
        let fd = solid_angle(receiver, p0, p1, p2) / solid_angle(donor, p0, p1, p2);
        assert!(
            (j as f64 / fd - 1.0).abs() < 2e-3,
            "jacobian {j}, solid-angle ratio {fd}"
        );
    }
    assert_eq!(
        reconnection_jacobian(
            Vec3::ONE,
            Vec3::X + y,
            y,
            (Vec3::X).cross(n).normalize() * 0.0
        ),
        0.0
    );
}

/// Per-pixel unbiasedness of the GI passes at `--max-depth 3` (one indirect bounce), as for
/// ReSTIR GI: 256 independent runs of 6 frames through pixel centres, both spatial reuses
/// (screen neighbours, the world-space grid) and temporal reuse at work; screen space also
/// with four light samples at the shading vertex (their MIS weights against the candidate's
/// BSDF ray must still sum to one) and 1/Z merges. Negative control:
/// world-space reuse without the reconnection Jacobian (`jacobian=0`) fails it (its donors lie
/// anywhere in a cell; screen-space neighbours are so close that dropping the Jacobian stayed
/// within the bound here, worst |z| 4.69, so it is not the control).
#[test]
fn unbiased_restir_gi_passes_match_the_depth_three_reference_per_pixel() {
    let scene = cornell();
    let tracer = PathTracer {
        max_depth: 3,
        ..Default::default()
    };
    let (w, h) = (24, 24);
    let ref_spp = 4096;
    let (reference, ref_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    for (name, unbiased) in [
        ("restir-gi:jitter=0", true),
        ("restir-gi:jitter=0,nee=4,pairwise=0", true),
        ("wsrestir-gi:jitter=0", true),
        ("wsrestir-gi:jitter=0,jacobian=0", false),
    ] {
        let spec: PassSpec = name.parse().unwrap();
        let images: Vec<Image> = (0..256)
            .map(|r| last_frame(&scene, &spec, &tracer, w, h, 6, 1000 + r))
            .collect();
        let (worst, beyond, bound) = per_pixel_z(&images, &reference, &ref_var, ref_spp);
        println!(
            "{name}: worst per-pixel |z| {worst:.2}, {beyond} pixel channels beyond {bound:.2}"
        );
        if unbiased {
            assert_eq!(beyond, 0, "{name}: worst |z| {worst:.2} (bound {bound:.2})");
        } else {
            assert!(
                beyond > 0,
                "{name} passed the unbiasedness test: worst |z| {worst:.2}"
            );
        }
    }
}

/// Means over `b × b` blocks (and the matching per-sample variance of a block mean).
fn blocks(img: &Image, b: usize, variance: bool) -> Image {
    let (w, h) = (img.width / b, img.height / b);
    let data = (0..w * h)
        .map(|k| {
            let (bx, by) = (k % w, k / w);
            let mut sum = glam::Vec3::ZERO;
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    sum += img.data[y * img.width + x];
                }
            }
            let n = (b * b) as f32;
            if variance { sum / (n * n) } else { sum / n }
        })
        .collect();
    Image::from_data(w, h, data).unwrap()
}

/// Unbiased `wsrestir-gi` at unlimited depth (Russian roulette; the grid then also holds the
/// second vertices' samples) converges to the path-traced reference on the Cornell box:
/// - over 256 independent runs of 6 frames, the means of 4 × 4 pixel blocks match the
///   reference's (Bonferroni over blocks; per pixel, the estimator's rare large samples —
///   a reused sample whose Jacobian is large — make a few runs' variance miss what they
///   never drew: 512 runs pass per pixel, 128 did not, in either GI pass);
/// - as frames accumulate, a run's running average approaches the reference: the mean
///   squared error of the average of 32 frames is below half a single frame's (one camera
///   ray a pixel sample, `split=1`, here and below);
/// - pairwise MIS (the default merge) gives lower errors than 1/Z (`pairwise=0`), in one
///   frame and accumulated.
#[test]
fn unbiased_wsrestir_gi_converges_to_the_reference_on_the_cornell_box() {
    let scene = cornell();
    let tracer = PathTracer::default();
    let (w, h) = (24, 24);
    let ref_spp = 4096;
    let (reference, ref_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    let spec: PassSpec = "wsrestir-gi:jitter=0".parse().unwrap();
    let images: Vec<Image> = (0..256)
        .map(|r| {
            blocks(
                &last_frame(&scene, &spec, &tracer, w, h, 6, 5000 + r),
                4,
                false,
            )
        })
        .collect();
    let (worst, beyond, bound) = per_pixel_z(
        &images,
        &blocks(&reference, 4, false),
        &blocks(&ref_var, 4, true),
        ref_spp,
    );
    println!(
        "wsrestir-gi, unlimited depth: worst 4x4-block |z| {worst:.2}, {beyond} beyond {bound:.2}"
    );
    assert_eq!(beyond, 0, "worst block |z| {worst:.2} (bound {bound:.2})");

    let mse = |a: &Image| {
        a.data
            .iter()
            .zip(&reference.data)
            .map(|(x, y)| (*x - *y).length_squared() as f64)
            .sum::<f64>()
            / a.data.len() as f64
    };
    // (one frame's MSE, 32 accumulated frames' MSE), mean of 4 runs.
    let errors = |spec: &PassSpec| {
        let mut pass = spec.build(&tracer);
        let (mut single, mut accumulated) = (0.0, 0.0);
        for run in 0..4u64 {
            let (mean, last) =
                accumulate_frames(pass.as_mut(), &scene, w, h, 32, 9000 + run, &ZeroSource);
            single += mse(&last);
            accumulated += mse(&mean);
        }
        (single / 4.0, accumulated / 4.0)
    };
    // With one camera ray a pixel sample (`split=1`), as these figures were written: the
    // split lowers a frame's noise, not what accumulation does to the reuse's.
    let one_ray: PassSpec = "wsrestir-gi:jitter=0,split=1".parse().unwrap();
    let (single, accumulated) = errors(&one_ray);
    println!("wsrestir-gi: MSE of one frame {single:.3e}, of 32 accumulated {accumulated:.3e}");
    assert!(
        accumulated < single / 2.0,
        "accumulation: {accumulated} vs {single}"
    );
    // Pairwise MIS against 1/Z: one frame's error 12x lower (2.9e-3 against 3.47e-2 when
    // written), the accumulated one 4.8x (1.2e-3 against 5.8e-3); accumulation gains less
    // than with 1/Z (2.4x against 6x) because less of the error is noise that averages out.
    let count: PassSpec = "wsrestir-gi:jitter=0,pairwise=0,split=1".parse().unwrap();
    let (single_z, accumulated_z) = errors(&count);
    println!("with 1/Z: one frame {single_z:.3e}, 32 accumulated {accumulated_z:.3e}");
    assert!(
        single < 0.6 * single_z && accumulated < accumulated_z,
        "pairwise MIS {single:.3e}/{accumulated:.3e} against 1/Z {single_z:.3e}/{accumulated_z:.3e}"
    );
}

/// Reprojection under a moving camera: the camera orbits 1° per frame about the box; after 12
/// frames, temporal reuse (history reprojected through the previous frame's camera) leaves a
/// lower error against the reference of the last frame's camera than no temporal reuse, for
/// ReSTIR DI (depth 2, temporal reuse alone: with spatial reuse on, temporal reuse did not
/// lower its error in this one-light scene, 2.55·10⁻⁴ against 2.11·10⁻⁴) and screen-space
/// ReSTIR GI (depth 3, spatial reuse on), mean over 4 runs, pixels seeing
/// the light (and their neighbours) left out; rays through pixel centres in the passes and in
/// the reference, so that the error is the estimator's, not the pixel footprint's.
#[test]
fn temporal_reuse_follows_a_moving_camera() {
    use glam::Vec3;
    let scene = cornell();
    let (w, h) = (32, 32);
    let base = scene.camera;
    let target = base.position + base.forward * 3.0;
    let camera = |f: u32| {
        let angle = (f as f32 - 11.0).to_radians();
        let off = base.position - target;
        let rotated = Vec3::new(
            off.x * angle.cos() + off.z * angle.sin(),
            off.y,
            -off.x * angle.sin() + off.z * angle.cos(),
        );
        nrc_scene::Camera::look_at(target + rotated, target, Vec3::Y, base.fov_y.to_degrees())
            .unwrap()
    };
    let last = camera(11);
    for (base_name, depth, bound) in [
        ("restir-di:k=0,jitter=0", 2, 0.95),
        ("restir-gi:jitter=0", 3, 0.8),
    ] {
        let tracer = PathTracer {
            max_depth: depth,
            ..Default::default()
        };
        let (reference, _) = reference_at_centres_from(&scene, &last, &tracer, w, h, 2048);
        let bright = |x: i64, y: i64| {
            x >= 0
                && y >= 0
                && x < w as i64
                && y < h as i64
                && reference.data[(y * w as i64 + x) as usize].max_element() > 1.0
        };
        let keep: Vec<bool> = (0..(w * h) as i64)
            .map(|p| {
                let (x, y) = (p % w as i64, p / w as i64);
                !(-1..=1).any(|dy| (-1..=1).any(|dx| bright(x + dx, y + dy)))
            })
            .collect();
        let mse = |a: &Image| {
            let n = keep.iter().filter(|k| **k).count() as f64;
            a.data
                .iter()
                .zip(&reference.data)
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|((x, y), _)| (*x - *y).length_squared() as f64)
                .sum::<f64>()
                / n
        };
        let mut errors = [0.0; 2];
        for (k, params) in ["", ",temporal=0"].iter().enumerate() {
            let spec: PassSpec = format!("{base_name}{params}").parse().unwrap();
            let mut pass = spec.build(&tracer);
            for run in 0..4u64 {
                pass.reset();
                let mut img = None;
                for f in 0..12 {
                    let cam = camera(f);
                    let input = FrameInput {
                        scene: &scene,
                        camera: &cam,
                        width: w,
                        height: h,
                        spp: 1,
                        seed: nrc_render::pass_seed(300 + run, f),
                        emitter_samples: 0,
                        sequence: None,
                    };
                    img = Some(passes::run(pass.as_mut(), &input, &ZeroSource).image);
                }
                errors[k] += mse(&img.unwrap()) / 4.0;
            }
        }
        println!(
            "{base_name} under a moving camera: MSE with temporal reuse {:.3e}, without {:.3e}",
            errors[0], errors[1]
        );
        assert!(errors[0] < bound * errors[1], "{base_name}: {errors:?}");
    }
}

/// A source answering the same radiance to every query.
struct Constant(glam::Vec3);

impl nrc_render::RadianceSource for Constant {
    fn radiance(&self, queries: &[nrc_render::RadianceQuery]) -> Vec<glam::Vec3> {
        vec![self.0; queries.len()]
    }
}

/// `-nrc` ReSTIR GI asks its source again, every frame, for the radiance of the history's
/// samples (an online cache trains between frames). Fifteen frames of a source answering 1
/// everywhere and a sixteenth answering 2 give the same image as sixteen frames answering 2:
/// a constant source scales every target and every resampling weight alike, so every choice is
/// the same and only the history's stored radiance could differ. With `refresh=0` (the
/// history keeps the answers of the frames that found its samples) the sixteenth frame is
/// darker by the reused samples' share, and the comparison fails. Screen and world space.
#[test]
fn restir_gi_nrc_refreshes_its_history_from_the_source() {
    let scene = cornell();
    let tracer = PathTracer::default();
    let last = |pass: &str, first: f32| {
        let spec: PassSpec = pass.parse().unwrap();
        let mut p = spec.build(&tracer);
        let mut out = None;
        for f in 0..16u64 {
            let input = FrameInput {
                scene: &scene,
                camera: &scene.camera,
                width: 24,
                height: 24,
                spp: 1,
                seed: 500 + f,
                emitter_samples: 0,
                sequence: None,
            };
            let c = if f < 15 { first } else { 2.0 };
            out = Some(passes::run(p.as_mut(), &input, &Constant(glam::Vec3::splat(c))).image);
        }
        out.unwrap()
    };
    // The largest per-pixel difference, relative to the image's mean.
    let gap = |a: &Image, b: &Image| {
        let mean = b.data.iter().map(|p| p.x + p.y + p.z).sum::<f32>() / b.data.len() as f32;
        let worst = a
            .data
            .iter()
            .zip(&b.data)
            .map(|(p, q)| (*p - *q).abs().max_element())
            .fold(0.0f32, f32::max);
        worst / mean
    };
    for base in ["restir-gi-nrc", "wsrestir-gi-nrc"] {
        let steady = last(&format!("{base}:jitter=0"), 2.0);
        let refreshed = last(&format!("{base}:jitter=0"), 1.0);
        let stale = last(&format!("{base}:jitter=0,refresh=0"), 1.0);
        let (g_refreshed, g_stale) = (gap(&refreshed, &steady), gap(&stale, &steady));
        println!("{base}: refreshed {g_refreshed:.2e}, stale {g_stale:.2e} of the mean");
        assert!(
            g_refreshed < 1e-4,
            "{base}: refreshed history differs by {g_refreshed}"
        );
        assert!(g_stale > 1e-2, "{base}: a stale history passes ({g_stale})");
    }
}

/// A room built to provoke fireflies, as the kitchen does: a large, bright emitter on the back
/// wall (the window) and a glossy coated floor and table top (glTF roughness 0.2 and 0.16, the
/// kitchen's table) that reflect it toward the camera; diffuse walls elsewhere. NEE alone
/// samples the emitter's area uniformly and rarely lands in a glossy lobe's small image of it.
fn firefly_room() -> Scene {
    use common::{Mesh, SceneBuilder, mat};
    use glam::Vec3;
    let mut b = SceneBuilder::new();
    let walls = b.material(mat::diffuse(Vec3::splat(0.6)));
    let floor = b.material(mat::plastic(Vec3::new(0.25, 0.1, 0.05), 0.2));
    let table = b.material(mat::plastic(Vec3::splat(0.5), 0.16));
    let window = b.material(mat::emissive(Vec3::ZERO, Vec3::splat(20.0), false));
    b.mesh(
        &Mesh::cuboid(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 1.5, 1.0), true),
        walls,
        false,
    )
    .mesh(
        &Mesh::quad(
            Vec3::new(0.0, 0.001, 0.0),
            Vec3::new(0.0, 0.0, 0.999),
            Vec3::new(0.999, 0.0, 0.0),
        ),
        floor,
        false,
    )
    .mesh(
        &Mesh::cuboid(Vec3::new(-0.6, 0.0, -0.7), Vec3::new(0.1, 0.4, -0.2), false),
        table,
        false,
    )
    .mesh(
        &Mesh::quad(
            Vec3::new(0.1, 0.9, -0.999),
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::new(0.0, 0.35, 0.0),
        ),
        window,
        false,
    )
    .camera(Vec3::new(0.2, 0.8, 0.95), Vec3::new(-0.1, 0.1, -0.6), 50.0);
    b.build()
}

/// The firefly guard (issue 39): in [`firefly_room`], 8 independent runs of 8 frames of each
/// resampling pass (the harness's accumulation; rays through pixel centres, so that the error
/// is the estimator's), the 99.9th percentile over pixels and runs of the absolute luminance
/// error of the accumulated image stays below 1.5 times the path tracer's at 8 spp through
/// the same centres. Negative control: ReSTIR GI with the direct light at its shading vertex
/// by NEE alone (the `LightOnly` strategy, which the pass follows; before this test that was
/// the pass whatever the strategy, and the kitchen's fireflies) fails it: 5.9 against a bound
/// of 3.9 when written, the passes 3.0 and below. Not asserted: ReSTIR DI with temporal reuse
/// at its default M-cap (20) exceeds the bound (4.5; M-cap 4: 3.6, M-cap 1: 2.7, no temporal
/// reuse: 2.4): a history that outweighs a frame's candidates 20 to 1 keeps one sample for
/// many of the 8 accumulated frames, so they do not average out as independent ones do.
#[test]
fn resampling_passes_keep_the_path_tracers_tails_where_a_small_bright_emitter_meets_gloss() {
    use nrc_render::LightStrategy;
    let scene = firefly_room();
    let tracer = PathTracer {
        max_depth: 4,
        ..Default::default()
    };
    let nee_alone = PathTracer {
        strategy: LightStrategy::LightOnly,
        ..tracer
    };
    let (w, h) = (48, 32);
    let (reference, _) = reference_at_centres(&scene, &tracer, w, h, 4096);
    let lum = |c: glam::Vec3| nrc_scene::sampling::luminance(c) as f64;
    // The 99.9th percentile of |lum(x) − lum(ref)| over the pixels of `runs` images.
    let p999 = |runs: &[Image]| {
        let mut e: Vec<f64> = runs
            .iter()
            .flat_map(|img| img.data.iter().zip(&reference.data))
            .map(|(x, r)| (lum(*x) - lum(*r)).abs())
            .collect();
        e.sort_by(f64::total_cmp);
        e[(e.len() as f64 * 0.999) as usize]
    };
    let accumulate = |spec: &str, tracer: &PathTracer, run: u64| {
        let spec: PassSpec = spec.parse().unwrap();
        accumulate_frames(
            spec.build(tracer).as_mut(),
            &scene,
            w,
            h,
            8,
            7000 + run,
            &ZeroSource,
        )
        .0
    };
    let tails = |spec: &str, tracer: &PathTracer| {
        let runs: Vec<Image> = (0..8).map(|r| accumulate(spec, tracer, r)).collect();
        p999(&runs)
    };
    // The path tracer through pixel centres, 8 samples per pixel per run.
    let pt_runs: Vec<Image> = (0..8u64)
        .map(|run| {
            let data = (0..w * h)
                .map(|p| {
                    let (x, y) = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
                    let ray = scene.camera.generate_ray(glam::Vec2::new(x, y), w, h);
                    let mut stats = nrc_render::PathStats::default();
                    (0..8u64)
                        .map(|s| {
                            let mut u = PixelSampler::new(7000 + run, p as u64, s);
                            tracer.radiance(&scene, ray, &mut u, &mut stats) / 8.0
                        })
                        .sum()
                })
                .collect();
            Image::from_data(w as usize, h as usize, data).unwrap()
        })
        .collect();
    let path_traced = p999(&pt_runs);
    let bound = 1.5 * path_traced;
    println!("pt, 8 spp: 99.9th-percentile error {path_traced:.3}");
    let mut failures = Vec::new();
    for (spec, tracer, calm) in [
        ("restir-gi:jitter=0", &tracer, true),
        ("wsrestir-gi:jitter=0", &tracer, true),
        ("ddgi-restir:jitter=0", &tracer, true),
        ("restir-di:jitter=0,temporal=0", &tracer, true),
        ("restir-gi:jitter=0", &nee_alone, false),
    ] {
        let t = tails(spec, tracer);
        let strategy = format!("{:?}", tracer.strategy);
        println!("{spec} ({strategy}): 99.9th-percentile error {t:.3}, bound {bound:.3}");
        if calm != (t < bound) {
            failures.push(format!("{spec} ({strategy}): {t:.3} against {bound:.3}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// `--glossy-samples` through a pass built on the G-buffer: screen-space ReSTIR GI's direct
/// light at its shading vertex (NEE, the glossy samples and its candidate's BSDF ray, weighed
/// with the counts) in [`firefly_room`] at depth 2 (direct light only: no candidate is kept)
/// matches the path-traced reference without glossy samples per pixel: 192 runs of one frame
/// through pixel centres, Bonferroni (family-wise 10⁻³), each run's variance floored by the
/// reference's per sample over 64 (a glossy pixel's window hit is a rare event in a run).
/// Control, of the test's power only: the same runs 20 % too bright fail it (forgetting to
/// divide the candidate ray's emission by the BSDF count would add up to 80 % of its share).
/// The wrong weight itself, run through the shared walk, is the failing case of
/// `direct_lighting.rs`'s glossy-samples test.
#[test]
fn glossy_samples_keep_restir_gis_direct_light_unbiased_per_pixel() {
    let scene = firefly_room();
    let tracer = PathTracer {
        max_depth: 2,
        ..Default::default()
    };
    let glossy = PathTracer {
        glossy_samples: 4,
        ..tracer
    };
    let (w, h) = (24, 16);
    let ref_spp = 8192;
    let (reference, ref_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    let spec: PassSpec = "restir-gi:jitter=0".parse().unwrap();
    let runs: Vec<Image> = (0..192)
        .map(|r| last_frame(&scene, &spec, &glossy, w, h, 1, 9000 + r))
        .collect();
    let (worst, beyond, bound) =
        common::per_pixel_z_floored(&runs, &reference, &ref_var, ref_spp, 64.0);
    println!("glossy samples: worst per-pixel |z| {worst:.2}, {beyond} beyond {bound:.2}");
    assert_eq!(beyond, 0, "worst |z| {worst:.2} (bound {bound:.2})");
    // (Pixels that every run sees alike, the emitter's, stay as they are: exact.)
    let varies = |p: usize| runs.iter().any(|img| img.data[p] != runs[0].data[p]);
    let bright: Vec<Image> = runs
        .iter()
        .map(|img| {
            let data = (0..img.data.len())
                .map(|p| img.data[p] * if varies(p) { 1.2 } else { 1.0 })
                .collect();
            Image::from_data(w as usize, h as usize, data).unwrap()
        })
        .collect();
    control_fails(&bright, &reference, &ref_var, ref_spp, "20 % too bright");
}

/// A negative control: `runs` must differ from `reference` beyond the per-pixel bound somewhere
/// (each run's variance floored by the reference's per sample over 64, as the tests it
/// controls judge their own runs).
fn control_fails(runs: &[Image], reference: &Image, ref_var: &Image, ref_spp: u32, what: &str) {
    let (worst, beyond, _) = common::per_pixel_z_floored(runs, reference, ref_var, ref_spp, 64.0);
    println!("{what} (control): worst |z| {worst:.2}, {beyond} beyond");
    assert!(beyond > 0, "{what} passed: worst |z| {worst:.2}");
}

/// The split tests' scene, tracer (depth 3: the world-space pass walks through the firefly
/// room's glossy table to its shading vertex) and image (width, height, reference samples).
fn split_setup() -> (Scene, PathTracer, (u32, u32, u32)) {
    let tracer = PathTracer {
        max_depth: 3,
        ..Default::default()
    };
    (firefly_room(), tracer, (24, 16, 8192))
}

/// A split of the light gathered up to the shading vertex (`split=3`: two more camera rays a
/// pixel sample, each traced to `x₁` through the specular vertices before it, with NEE along
/// the way and at `x₁` and a BSDF ray there weighed by MIS) keeps screen- and world-space
/// ReSTIR GI unbiased per pixel in [`firefly_room`] at depth 3, where the world-space pass
/// walks through the glossy table (roughness 0.16, specular by §4.1) and the split follows
/// it: 192 runs of 4 frames through pixel centres, Bonferroni (family-wise 10⁻³), each run's
/// variance floored by the reference's per sample over 64. It lowers the pixels' variance over
/// the runs (asserted below 0.85× of the pass without it, summed over the image's channels).
/// Negative control: the path's own gathered light kept whole beside the split's mean (weight
/// 5/3 in all) fails.
#[test]
fn a_split_of_the_light_up_to_the_shading_vertex_keeps_restir_gi_unbiased_per_pixel() {
    let setup = split_setup();
    let reference = reference_at_centres(&setup.0, &setup.1, setup.2.0, setup.2.1, setup.2.2);
    for base in ["restir-gi:jitter=0", "wsrestir-gi:jitter=0"] {
        let (split, plain) = (format!("{base},split=3"), format!("{base},split=1"));
        check_split(
            &setup,
            &reference,
            &split,
            &plain,
            4,
            11_000,
            base.starts_with("ws"),
        );
    }
}

/// A split whose rays are chosen for each frame by the frames before (`split=0,splitmax=6`,
/// [`nrc_render::passes::split::SplitChooser`]) keeps world-space ReSTIR GI unbiased per pixel
/// in [`firefly_room`] at depth 3: 192 runs of 8 frames through pixel centres (the first two
/// frames at 2 rays, then the chooser's), Bonferroni (family-wise 10⁻³), each run's variance
/// floored by the reference's per sample over 64. Its variance is below the pass's without a
/// split (0.85×, as the fixed split's). Negative control: the path's own gathered light kept
/// whole beside the chosen split's mean fails.
#[test]
fn a_split_chosen_by_the_frames_before_keeps_world_space_restir_gi_unbiased_per_pixel() {
    let setup = split_setup();
    let reference = reference_at_centres(&setup.0, &setup.1, setup.2.0, setup.2.1, setup.2.2);
    let (chosen, plain) = (
        "wsrestir-gi:jitter=0,split=0,splitmax=6",
        "wsrestir-gi:jitter=0,split=1",
    );
    check_split(&setup, &reference, chosen, plain, 8, 13_000, true);
}

/// The split tests' check: 192 runs of `frames` frames of `split` (seeds from `seed`) match
/// `reference` (through pixel centres, with its variance) per pixel, and their variance is
/// below 0.85× that of `plain`'s runs; with `control`, the same split with the path's own
/// gathered light kept whole beside its mean must fail.
fn check_split(
    (scene, tracer, (w, h, ref_spp)): &(Scene, PathTracer, (u32, u32, u32)),
    (reference, ref_var): &(Image, Image),
    split: &str,
    plain: &str,
    frames: u32,
    seed: u64,
    control: bool,
) {
    use nrc_render::passes::RestirGiSettings;
    let runs_of = |spec: &PassSpec| -> Vec<Image> {
        (0..192)
            .map(|r| last_frame(scene, spec, tracer, *w, *h, frames, seed + r))
            .collect()
    };
    let split: PassSpec = split.parse().unwrap();
    let runs = runs_of(&split);
    let (worst, beyond, bound) =
        common::per_pixel_z_floored(&runs, reference, ref_var, *ref_spp, 64.0);
    let plain: PassSpec = plain.parse().unwrap();
    let ratio = common::summed_variance(&runs) / common::summed_variance(&runs_of(&plain));
    println!(
        "{split}: worst per-pixel |z| {worst:.2}, {beyond} beyond {bound:.2}; variance \
         {ratio:.3}× {plain}'s"
    );
    assert_eq!(
        beyond, 0,
        "{split}: worst |z| {worst:.2} (bound {bound:.2})"
    );
    assert!(ratio < 0.85, "{split}: variance {ratio:.3}× {plain}'s");
    if control {
        let mut twice = *split.get::<RestirGiSettings>().unwrap();
        twice.split_keeps_own = true;
        let runs = runs_of(&PassSpec::from(twice));
        control_fails(
            &runs,
            reference,
            ref_var,
            *ref_spp,
            "own gathered light kept whole",
        );
    }
}

/// The split's extra camera rays jittered in the pixel, as `nrc compare` renders
/// (`wsrestir-gi:split=3`, jitter on): the runs match the path tracer's jittered reference
/// (the mean over each pixel's footprint) per pixel in [`firefly_room`] at depth 3, 192 runs of
/// 4 frames, Bonferroni (family-wise 10⁻³), each run's variance floored by the reference's per
/// sample over 64 (an edge crossing a pixel is a rare event in a run). Control, of the test's
/// power to see where in the pixel the rays land: the same runs against the reference through
/// pixel centres fail (so extra rays stuck at the centre, or anywhere else, would be seen).
#[test]
fn a_split_with_jittered_camera_rays_matches_the_pixel_footprint_reference() {
    let (scene, tracer, (w, h, ref_spp)) = split_setup();
    let footprint = common::render_scene(&scene, &tracer, w, h, ref_spp, 77);
    let footprint_var = footprint.variance.expect("the reference's variance");
    let spec: PassSpec = "wsrestir-gi:split=3".parse().unwrap();
    let runs: Vec<Image> = (0..192)
        .map(|r| last_frame(&scene, &spec, &tracer, w, h, 4, 12_000 + r))
        .collect();
    let (worst, beyond, bound) =
        common::per_pixel_z_floored(&runs, &footprint.mean, &footprint_var, ref_spp, 64.0);
    println!("{spec}: worst per-pixel |z| {worst:.2} against the footprint, bound {bound:.2}");
    assert_eq!(beyond, 0, "{spec}: worst |z| {worst:.2} (bound {bound:.2})");
    let (centres, centres_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    control_fails(
        &runs,
        &centres,
        &centres_var,
        ref_spp,
        "jittered runs against the centres",
    );
}

/// World-space ReSTIR GI's `specular` key decides which vertices shade: in [`firefly_room`]
/// (glossy floor of roughness 0.2, table 0.16, the rest diffuse) the thresholds 0.1 and 0.15
/// count the same vertices as rough and render the same bits, 0.1 and the default (0.2, which
/// traces through the table) do not; the default's name omits the key, others print it,
/// and a threshold beyond 1 is refused.
#[test]
fn the_specular_threshold_decides_where_world_space_reuse_shades() {
    let scene = firefly_room();
    let frame = |name: &str| {
        let spec: PassSpec = name.parse().unwrap();
        let mut pass = spec.build(&PathTracer::default());
        let mut img = None;
        for f in 0..3 {
            let input = FrameInput {
                scene: &scene,
                camera: &scene.camera,
                width: 24,
                height: 16,
                spp: 1,
                seed: nrc_render::pass_seed(9, f),
                emitter_samples: 0,
                sequence: None,
            };
            img = Some(passes::run(pass.as_mut(), &input, &ZeroSource).image);
        }
        img.unwrap().data
    };
    let low = frame("wsrestir-gi:specular=0.1");
    assert_eq!(low, frame("wsrestir-gi:specular=0.15"));
    assert_ne!(low, frame("wsrestir-gi"));
    let default: PassSpec = "wsrestir-gi".parse().unwrap();
    assert_eq!(default.to_string(), "wsrestir-gi");
    let set: PassSpec = "wsrestir-gi:specular=0.1".parse().unwrap();
    assert_eq!(set.to_string(), "wsrestir-gi:specular=0.1");
    assert!("wsrestir-gi:specular=1.5".parse::<PassSpec>().is_err());
}
