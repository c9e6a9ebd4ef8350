//! Instant radiosity (issue 19, Hedman et al.): `ir`'s VPL estimate in the emissive enclosure
//! against its clamped expectation as the VPL count grows, the Kollig–Keller residual, and
//! `smc-ir`'s temporal rule (at most `M_max` VPLs replaced per frame, the others kept where
//! they were).

mod common;

use glam::Vec3;
use nrc_render::passes::{self, FrameInput, InstantRadiosityPass, IrSettings, VplMode};
use nrc_render::{PathTracer, ZeroSource};
use nrc_scene::Scene;

/// The enclosure's wall at `z = −1` seen from the centre, 4 × 4 pixels, channel 0 (ρ = ½).
/// `L_refl = ρ L_e/(1 − ρ) = 1` everywhere, so the light the VPLs bring (the indirect light at
/// a wall point: the reflected radiance of the walls it sees) is `ρ · L_refl = ½`.
const UNCLAMPED: f64 = 0.5;

fn tracer() -> PathTracer {
    PathTracer {
        max_depth: -1,
        rr_depth: 3,
        ..PathTracer::default()
    }
}

/// The image mean of `ir`'s indirect light (`indirect=1`, every pixel lit by every VPL) over
/// `runs` frames with distinct seeds.
fn ir_means(scene: &Scene, vpls: u32, clamp: f32, residual: bool, runs: u32) -> Vec<f64> {
    let set = IrSettings {
        mode: VplMode::Classic,
        vpls,
        per_pixel: 0,
        clamp,
        residual,
        indirect: true,
        ..Default::default()
    };
    let mut pass = InstantRadiosityPass::new(set, tracer());
    (0..runs)
        .map(|r| {
            let input = FrameInput {
                scene,
                camera: &scene.camera,
                width: 4,
                height: 4,
                spp: 1,
                seed: 1000 + r as u64,
                emitter_samples: 0,
                sequence: None,
            };
            let img = passes::run(&mut pass, &input, &ZeroSource).image;
            img.data.iter().map(|p| f64::from(p.x)).sum::<f64>() / img.data.len() as f64
        })
        .collect()
}

/// The clamped expectation at the pixels' primary hits: `ρ L_refl E[min(1, G_max/G)]` over
/// cosine-distributed directions (the walls' reflected radiance is 1 everywhere), by 200 000
/// directions per pixel.
fn clamped_reference(scene: &Scene, clamp: f32) -> f64 {
    let b = scene.bounds();
    let g_max = 1.0 / (clamp * (b.max - b.min).length()).powi(2);
    let mut sum = 0.0f64;
    let mut n = 0u64;
    for pixel in 0..16u32 {
        let ray = scene.camera.generate_ray(
            glam::Vec2::new((pixel % 4) as f32 + 0.5, (pixel / 4) as f32 + 0.5),
            4,
            4,
        );
        let hit = scene.intersect(&ray).unwrap();
        let x = scene.interaction(&ray, &hit);
        let frame = nrc_scene::sampling::Frame::from_normal(x.ng);
        let mut s = nrc_render::PixelSampler::new(5, pixel as u64, 0);
        for _ in 0..200_000 {
            let local = nrc_scene::sampling::sample_cosine_hemisphere(s.next_2d());
            let wi = frame.to_world(local);
            let r = nrc_scene::spawn_ray(x.p, x.ng, wi);
            let h = scene.intersect(&r).unwrap();
            let y = scene.interaction(&r, &h);
            let d2 = (y.p - x.p).length_squared();
            let g = local.z * y.ng.dot(-wi).abs() / d2;
            sum += f64::from((g_max / g).min(1.0));
            n += 1;
        }
    }
    0.5 * sum / n as f64
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0);
    (m, var.sqrt())
}

/// With every VPL lighting every pixel and the clamp at `G_max = 1/(diagonal)²` (so that it
/// bites: `clamp=1`), `ir`'s error against the clamped expectation falls like `1/√I`: the RMS
/// error over 32 frames halves (within [1.4, 2.9]: the RMS of 32 runs is known to about 13 %)
/// for each fourfold `I`, and the mean matches the clamped expectation (unbiased but for the
/// clamp).
#[test]
fn ir_error_against_the_clamped_reference_falls_like_one_over_root_i() {
    let scene = common::enclosure(-Vec3::Z);
    let clamp = 1.0;
    let reference = clamped_reference(&scene, clamp);
    assert!(
        reference < 0.9 * UNCLAMPED,
        "the clamp must remove light ({reference})"
    );
    let mut rms = Vec::new();
    for vpls in [64u32, 256, 1024] {
        let m = ir_means(&scene, vpls, clamp, false, 32);
        let e = (m.iter().map(|x| (x - reference).powi(2)).sum::<f64>() / m.len() as f64).sqrt();
        let (mean, sd) = mean_sd(&m);
        println!("I = {vpls}: mean {mean:.4} (clamped reference {reference:.4}), RMS error {e:.4}");
        assert!(
            (mean - reference).abs() < 4.0 * sd / (m.len() as f64).sqrt(),
            "I = {vpls}: mean {mean} vs {reference}"
        );
        rms.push(e);
    }
    for w in rms.windows(2) {
        let ratio = w[0] / w[1];
        assert!(
            (1.4..=2.9).contains(&ratio),
            "RMS error ratio {ratio} for 4× the VPLs"
        );
    }
}

/// Clamped plus residual equals the unclamped light (½), within 4 standard errors; clamped
/// alone does not (the negative control).
#[test]
fn clamped_plus_residual_is_the_unclamped_reference() {
    let scene = common::enclosure(-Vec3::Z);
    for (residual, should_match) in [(true, true), (false, false)] {
        let m = ir_means(&scene, 512, 1.0, residual, 48);
        let (mean, sd) = mean_sd(&m);
        let z = (mean - UNCLAMPED) / (sd / (m.len() as f64).sqrt());
        println!("residual {residual}: mean {mean:.4} vs unclamped {UNCLAMPED} ({z:+.1} se)");
        assert_eq!(
            z.abs() < 4.0,
            should_match,
            "residual {residual}: {z:+.1} se"
        );
    }
}

/// `smc-ir` on the Cornell box while the camera moves: at most `M_max` VPLs change per frame,
/// every other VPL keeps its position (slot by slot), and VPLs do get replaced; with
/// `M_max = 256` (the negative control: no limit in effect) some frame changes more than 8.
#[test]
fn smc_ir_replaces_at_most_m_max_vpls_per_frame() {
    let most = vpl_changes_per_frame(8);
    assert!(most.iter().all(|&c| c <= 8), "{most:?}");
    assert!(most.iter().sum::<usize>() > 0, "the VPL set never changed");
    let unlimited = vpl_changes_per_frame(256);
    assert!(
        unlimited.iter().any(|&c| c > 8),
        "without the limit no frame changed more than 8 VPLs: {unlimited:?}"
    );
    println!("changes per frame with M_max 8: {most:?}; with 256: {unlimited:?}");
}

/// VPLs changed per frame (frames 2–12) of `smc-ir` with `m_max` while the camera turns.
fn vpl_changes_per_frame(m_max: u32) -> Vec<usize> {
    let scene = Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap();
    let set = IrSettings {
        mode: VplMode::Smc,
        vpls: 256,
        m_max,
        per_pixel: 16,
        radiosity_spp: 2,
        rate: 4,
        warmup: 4,
        visible_points: 256,
        ..Default::default()
    };
    let mut pass = InstantRadiosityPass::new(set, tracer());
    let base = scene.camera;
    let mut previous: Option<Vec<Vec3>> = None;
    let mut changes = Vec::new();
    for f in 0..12 {
        // The camera turns 2° a frame about the vertical.
        let turn = glam::Quat::from_rotation_y((2.0 * f as f32).to_radians());
        let camera = nrc_scene::Camera::look_at(
            base.position,
            base.position + turn * base.forward,
            base.up,
            base.fov_y.to_degrees(),
        )
        .unwrap();
        let input = FrameInput {
            scene: &scene,
            camera: &camera,
            width: 16,
            height: 16,
            spp: 1,
            seed: f,
            emitter_samples: 0,
            sequence: None,
        };
        let out = passes::run(&mut pass, &input, &ZeroSource);
        assert!(out.image.data.iter().all(|p| p.is_finite()));
        let now: Vec<Vec3> = pass.vpls().iter().map(|v| v.position).collect();
        assert_eq!(now.len(), 256, "frame {f}: the budget is kept");
        if let Some(prev) = &previous {
            let changed = now.iter().zip(prev).filter(|(a, b)| a != b).count();
            assert_eq!(changed as u32, pass.last.replaced, "frame {f}");
            changes.push(changed);
        }
        previous = Some(now);
    }
    changes
}

/// A static camera over a static scene with a fixed VPL set (`M_max = 0`: nothing replaced),
/// frames of the same seed: identical images, so the error changes by nothing between frames
/// (|E′| = 0: `nrc-eval`'s temporal tests show identical frames give exactly 0).
#[test]
fn a_fixed_vpl_set_renders_a_static_scene_identically() {
    let scene = Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap();
    let set = IrSettings {
        mode: VplMode::Smc,
        vpls: 128,
        m_max: 0,
        per_pixel: 16,
        radiosity_spp: 2,
        rate: 4,
        warmup: 2,
        visible_points: 256,
        indirect: true,
        ..Default::default()
    };
    let mut pass = InstantRadiosityPass::new(set, tracer());
    let input = FrameInput {
        scene: &scene,
        camera: &scene.camera,
        width: 16,
        height: 16,
        spp: 1,
        seed: 3,
        emitter_samples: 0,
        sequence: None,
    };
    let first = passes::run(&mut pass, &input, &ZeroSource).image;
    assert!(
        first.data.iter().any(|p| p.max_element() > 0.0),
        "the VPLs light the box"
    );
    for _ in 0..3 {
        let again = passes::run(&mut pass, &input, &ZeroSource).image;
        assert_eq!(again.data, first.data);
        assert_eq!(pass.last.replaced, 0);
    }
}
