//! DDGI resampling (`ddgi-restir`, `nrc-restir`): with an exact source of the surfaces'
//! radiance, the estimator (clamped geometry term, residual, balance-heuristic candidate
//! weights, spatial and temporal reuse with the unbiased `Z`) matches the reference per
//! pixel; without the residual it does not.

mod common;

use common::{last_frame, last_frame_with, per_pixel_z, reference_at_centres};
use glam::Vec3;
use nrc_render::passes::PassSpec;
use nrc_render::{PathTracedSource, PathTracer, RadianceQuery, RadianceSource};
use nrc_scene::Image;
use std::sync::atomic::{AtomicU64, Ordering};

/// An exact source whose noise is fresh at every call (the path tracer's streams seeded by
/// the call count): with one seed, frame after frame would draw the same numbers for the same
/// query index, correlating a reused sample's radiance with its refreshed value.
struct FreshSource<'a> {
    inner: PathTracedSource<'a>,
    calls: AtomicU64,
}

impl RadianceSource for FreshSource<'_> {
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3> {
        let call = self.calls.fetch_add(1, Ordering::Relaxed);
        PathTracedSource {
            seed: self.inner.seed.wrapping_mul(1_000_003) + call,
            ..self.inner
        }
        .radiance(queries)
    }
}

/// Runs of `pass` each restarted, the last of `frames` frames of each.
fn runs(
    scene: &nrc_scene::Scene,
    pass: &str,
    tracer: &PathTracer,
    source: Option<&PathTracedSource>,
    (w, h, frames, n): (u32, u32, u32, u64),
) -> Vec<Image> {
    let spec: PassSpec = pass.parse().unwrap();
    (0..n)
        .map(|r| match source {
            Some(s) => {
                let s = FreshSource {
                    inner: PathTracedSource { seed: 90 + r, ..*s },
                    calls: AtomicU64::new(0),
                };
                last_frame_with(scene, &spec, tracer, w, h, frames, 3000 + r, &s)
            }
            None => last_frame(scene, &spec, tracer, w, h, frames, 3000 + r),
        })
        .collect()
}

/// `ddgi-restir` in the emissive enclosure (`L = 2` everywhere, the camera looking into a
/// corner where the geometry term is clamped): its eq. 5 probes converge to the exact
/// irradiance, so with the residual the image is 2 per pixel (z-test over 96 independent runs
/// of 24 frames, Bonferroni, family-wise 10⁻³); without the residual (`residual=0`) the
/// clamped-away transport is missing near the corner and the test fails.
#[test]
fn ddgi_restir_renders_the_enclosure_exactly_per_pixel_and_fails_without_its_residual() {
    let scene = common::enclosure(Vec3::ONE);
    let tracer = PathTracer::default();
    let (w, h) = (16, 16);
    let exact = Image::from_data(w, h, vec![Vec3::splat(2.0); w * h]).unwrap();
    let zero = Image::from_data(w, h, vec![Vec3::ZERO; w * h]).unwrap();
    for (residual, unbiased) in [(1, true), (0, false)] {
        let pass = format!(
            "ddgi-restir:probes=3,hysteresis=0.2,mcap=4,clamp=0.3,jitter=0,residual={residual}"
        );
        let images = runs(&scene, &pass, &tracer, None, (16, 16, 16, 128));
        let (worst, beyond, bound) = per_pixel_z(&images, &exact, &zero, 1);
        let mean = images
            .iter()
            .flat_map(|i| i.data.iter().map(|p| p.x as f64))
            .sum::<f64>()
            / (images.len() * w * h) as f64;
        println!(
            "{pass}: image mean {mean:.4} (exact 2), worst |z| {worst:.2}, {beyond} pixel channels beyond {bound:.2}"
        );
        if unbiased {
            assert_eq!(beyond, 0, "{pass}: worst |z| {worst:.2}");
        } else {
            assert!(beyond > 0, "{pass} passed: worst |z| {worst:.2}");
        }
    }
}

/// `nrc-restir` on the Cornell box with an exact source (one path-traced estimate of the
/// direct light reflected at each queried point, `--max-depth 2` from there) matches the
/// path-traced depth-3 reference per pixel: 512 independent runs of 4 frames through pixel
/// centres, a z-test per pixel channel (Bonferroni, family-wise 10⁻³). `clamp=0.3` makes the
/// clamp take a large share of the transport (pairs closer than 0.3 of the diagonal), so that
/// the residual's negative control (`residual=0`) must fail (216 channels beyond). The
/// reused samples' contributions are heavy-tailed: at 256 runs one channel reached |z| 5.1–5.6,
/// at 512 runs the worst is 4.76 and at 1024 runs 4.69, where a bias of that size would have
/// doubled its z (so, rare large samples, not bias; 512 is the fewest runs that pass).
#[test]
fn nrc_restir_with_an_exact_source_matches_the_reference_per_pixel_and_fails_without_its_residual()
{
    let scene = nrc_scene::Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap();
    let tracer = PathTracer {
        max_depth: 3,
        ..Default::default()
    };
    let (w, h) = (24, 24);
    let ref_spp = 4096;
    let (reference, ref_var) = reference_at_centres(&scene, &tracer, w, h, ref_spp);
    let source = PathTracedSource {
        scene: &scene,
        tracer: PathTracer {
            max_depth: 2,
            ..Default::default()
        },
        samples: 1,
        seed: 0,
    };
    for (residual, unbiased) in [(1, true), (0, false)] {
        let pass = format!("nrc-restir:mcap=4,clamp=0.3,jitter=0,residual={residual}");
        let images = runs(&scene, &pass, &tracer, Some(&source), (24, 24, 4, 512));
        let (worst, beyond, bound) = per_pixel_z(&images, &reference, &ref_var, ref_spp);
        println!(
            "{pass}: worst per-pixel |z| {worst:.2}, {beyond} pixel channels beyond {bound:.2}"
        );
        if unbiased {
            assert_eq!(beyond, 0, "{pass}: worst |z| {worst:.2} (bound {bound:.2})");
        } else {
            assert!(beyond > 0, "{pass} passed: worst |z| {worst:.2}");
        }
    }
}
