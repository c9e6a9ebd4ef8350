//! Rendering an image with the path tracer: pixels in parallel over tiles, a fixed number
//! of samples per pixel, the per-pixel mean and (optionally) the per-pixel sample variance.

use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Image, Scene};

use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::PixelSampler;
use crate::tiles::map_pixels;

/// What to render: image size, samples per pixel and the seed of the random streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Samples (paths) per pixel, at least 1.
    pub spp: u32,
    /// Seed of the per-pixel random streams; the image is a function of the seed alone,
    /// whatever the thread count.
    pub seed: u64,
    /// Also compute the per-pixel sample variance.
    pub variance: bool,
}

/// A rendered frame and what it cost.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// Per-pixel mean radiance (the estimate).
    pub mean: Image,
    /// Per-pixel, per-channel unbiased sample variance of one path's estimate
    /// (divide by `spp` for the variance of the mean); present when requested and spp ≥ 2.
    pub variance: Option<Image>,
    pub stats: RenderStats,
}

/// Totals of one render.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    /// Paths traced (pixels × spp).
    pub samples: u64,
    /// Rays traced (closest-hit and shadow).
    pub rays: PathStats,
    /// Samples whose estimate was NaN or infinite and was replaced by zero.
    pub invalid_samples: u64,
    /// Wall-clock time of the render.
    pub elapsed: Duration,
}

/// Per-pixel accumulator (Welford's algorithm in f64, stable for many samples).
#[derive(Clone, Copy, Debug, Default)]
struct PixelResult {
    mean: [f64; 3],
    m2: [f64; 3],
    rays: PathStats,
    invalid: u64,
}

/// Renders `scene` from `camera` with `tracer`, on the current rayon pool.
/// `progress(pixels)` is called as tiles finish, with the number of pixels just done.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    tracer: &PathTracer,
    settings: &RenderSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> RenderOutput {
    let (w, h) = (settings.width, settings.height);
    let spp = settings.spp.max(1);
    let start = Instant::now();
    let pixels = map_pixels(
        w,
        h,
        |x, y| {
            let mut acc = PixelResult::default();
            let index = y as u64 * w as u64 + x as u64;
            for s in 0..spp {
                let mut sampler = PixelSampler::new(settings.seed, index, s as u64);
                let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                let ray = camera.generate_ray(film, w, h);
                let mut l = tracer.radiance(scene, ray, &mut sampler, &mut acc.rays);
                if !l.is_finite() {
                    acc.invalid += 1;
                    l = Vec3::ZERO;
                }
                let n = (s + 1) as f64;
                for c in 0..3 {
                    let v = l[c] as f64;
                    let delta = v - acc.mean[c];
                    acc.mean[c] += delta / n;
                    acc.m2[c] += delta * (v - acc.mean[c]);
                }
            }
            acc
        },
        |n| progress(n as u64),
    );
    let elapsed = start.elapsed();

    let mut stats = RenderStats {
        samples: w as u64 * h as u64 * spp as u64,
        elapsed,
        ..Default::default()
    };
    let mut mean = Vec::with_capacity(pixels.len());
    let mut var = Vec::with_capacity(if settings.variance { pixels.len() } else { 0 });
    for p in &pixels {
        stats.rays.add(&p.rays);
        stats.invalid_samples += p.invalid;
        mean.push(Vec3::new(
            p.mean[0] as f32,
            p.mean[1] as f32,
            p.mean[2] as f32,
        ));
        if settings.variance && spp >= 2 {
            let d = (spp - 1) as f64;
            var.push(Vec3::new(
                (p.m2[0] / d) as f32,
                (p.m2[1] / d) as f32,
                (p.m2[2] / d) as f32,
            ));
        }
    }
    RenderOutput {
        mean: Image::from_data(w as usize, h as usize, mean).expect("one value per pixel"),
        variance: (!var.is_empty())
            .then(|| Image::from_data(w as usize, h as usize, var).expect("one value per pixel")),
        stats,
    }
}
