//! Rendering an image with the path tracer: pixels in parallel over tiles, a fixed number
//! of samples per pixel, the per-pixel mean and (optionally) the per-pixel sample variance.

use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Image, Scene};

use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::{PixelSampler, PixelSequence, camera_offset};
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
    /// The camera offsets' sequence ([`PixelSequence`]; `None`: independent offsets). With
    /// one, `variance` is the spread of the pixel's stratified samples, not the variance of
    /// one independent sample (`nrc render` refuses the pair).
    pub sequence: Option<PixelSequence>,
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
    /// Mean of what the camera rays saw directly (the emitters' anti-aliasing).
    seen: Vec3,
    rays: PathStats,
    invalid: u64,
}

/// The per-pixel sample moments of a range of sample indices: how many samples, their mean
/// and the sum of squared deviations from it (Welford, f64), per pixel and channel. Sample `s`
/// of pixel `p` depends only on the seed, `p` and `s`, so a render split into ranges of sample
/// indices and [`Moments::merge`]d gives the mean and variance of the whole render, up to the
/// order of the floating-point sums.
#[derive(Clone, Debug, PartialEq)]
pub struct Moments {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel.
    pub count: u64,
    /// Per pixel (row-major), per channel.
    pub mean: Vec<[f64; 3]>,
    pub m2: Vec<[f64; 3]>,
    /// Samples whose estimate was NaN or infinite and counted as zero.
    pub invalid_samples: u64,
}

impl Moments {
    /// Adds the samples of `other` (same image, disjoint samples): Chan, Golub and LeVeque's
    /// pairwise update of the mean and the sum of squared deviations.
    pub fn merge(&mut self, other: &Moments) -> Result<(), String> {
        if (self.width, self.height) != (other.width, other.height) {
            return Err(format!(
                "moments of a {}x{} image cannot merge with a {}x{} one",
                other.width, other.height, self.width, self.height
            ));
        }
        let (na, nb) = (self.count as f64, other.count as f64);
        let n = na + nb;
        if nb == 0.0 {
            return Ok(());
        }
        for ((ma, qa), (mb, qb)) in self
            .mean
            .iter_mut()
            .zip(self.m2.iter_mut())
            .zip(other.mean.iter().zip(&other.m2))
        {
            for c in 0..3 {
                let delta = mb[c] - ma[c];
                ma[c] += delta * nb / n;
                qa[c] += qb[c] + delta * delta * na * nb / n;
            }
        }
        self.count += other.count;
        self.invalid_samples += other.invalid_samples;
        Ok(())
    }

    /// The per-pixel mean.
    pub fn mean_image(&self) -> Image {
        let data = self
            .mean
            .iter()
            .map(|m| Vec3::new(m[0] as f32, m[1] as f32, m[2] as f32))
            .collect();
        Image::from_data(self.width as usize, self.height as usize, data)
            .expect("one value per pixel")
    }

    /// The per-pixel unbiased sample variance of one sample (at least 2 samples).
    pub fn variance_image(&self) -> Option<Image> {
        if self.count < 2 {
            return None;
        }
        let d = (self.count - 1) as f64;
        let data = self
            .m2
            .iter()
            .map(|q| Vec3::new((q[0] / d) as f32, (q[1] / d) as f32, (q[2] / d) as f32))
            .collect();
        Some(
            Image::from_data(self.width as usize, self.height as usize, data)
                .expect("one value per pixel"),
        )
    }
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
    render_seen(scene, camera, tracer, settings, progress).0
}

/// [`render`], and each pixel's mean of what its camera rays saw directly (row-major), for
/// the emitters' anti-aliasing ([`crate::emitters::supersample`]).
pub fn render_seen(
    scene: &Scene,
    camera: &Camera,
    tracer: &PathTracer,
    settings: &RenderSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> (RenderOutput, Vec<Vec3>) {
    let spp = settings.spp.max(1);
    let (moments, stats, seen) = trace_pixels(
        scene,
        camera,
        tracer,
        (settings.width, settings.height),
        (settings.seed, settings.sequence),
        0..spp,
        progress,
    );
    let out = RenderOutput {
        mean: moments.mean_image(),
        variance: if settings.variance {
            moments.variance_image()
        } else {
            None
        },
        stats,
    };
    (out, seen)
}

/// The moments of the samples with indices in `samples` (each pixel's sample `s` as in a
/// render of more samples), on the current rayon pool; `progress` as for [`render`].
pub fn render_moments(
    scene: &Scene,
    camera: &Camera,
    tracer: &PathTracer,
    (w, h): (u32, u32),
    seed: u64,
    samples: std::ops::Range<u32>,
    progress: &(dyn Fn(u64) + Sync),
) -> (Moments, RenderStats) {
    let (moments, stats, _) = trace_pixels(
        scene,
        camera,
        tracer,
        (w, h),
        (seed, None),
        samples,
        progress,
    );
    (moments, stats)
}

/// [`render_moments`] and each pixel's mean of what its camera rays saw directly.
fn trace_pixels(
    scene: &Scene,
    camera: &Camera,
    tracer: &PathTracer,
    (w, h): (u32, u32),
    (seed, sequence): (u64, Option<PixelSequence>),
    samples: std::ops::Range<u32>,
    progress: &(dyn Fn(u64) + Sync),
) -> (Moments, RenderStats, Vec<Vec3>) {
    let start = Instant::now();
    let first = samples.start;
    let pixels = map_pixels(
        w,
        h,
        |x, y| {
            let mut acc = PixelResult::default();
            let index = y as u64 * w as u64 + x as u64;
            for s in samples.clone() {
                let mut sampler = PixelSampler::new(seed, index, s as u64);
                let offset = camera_offset(sequence, index, s, sampler.next_2d());
                let ray = camera.generate_ray(Vec2::new(x as f32, y as f32) + offset, w, h);
                let (mut l, mut seen) =
                    tracer.camera_sample(scene, ray, &mut sampler, &mut acc.rays);
                if !l.is_finite() {
                    // The sample counts as black, what it saw directly included.
                    acc.invalid += 1;
                    (l, seen) = (Vec3::ZERO, Vec3::ZERO);
                }
                let n = (s - first + 1) as f64;
                acc.seen += (seen - acc.seen) / n as f32;
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
    let count = samples.len() as u64;
    let mut stats = RenderStats {
        samples: w as u64 * h as u64 * count,
        elapsed: start.elapsed(),
        ..Default::default()
    };
    for p in &pixels {
        stats.rays.add(&p.rays);
        stats.invalid_samples += p.invalid;
    }
    let moments = Moments {
        width: w,
        height: h,
        count,
        mean: pixels.iter().map(|p| p.mean).collect(),
        m2: pixels.iter().map(|p| p.m2).collect(),
        invalid_samples: stats.invalid_samples,
    };
    let seen = pixels.iter().map(|p| p.seen).collect();
    (moments, stats, seen)
}
