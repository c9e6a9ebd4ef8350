//! Emitters seen by the camera: their anti-aliasing ([`supersample`]: extra camera rays, their
//! emission only, at the pixels on an emitter's outline) and the emitter-excluded image (pixels
//! that see an emitter, and their 8 neighbours, left out of the errors, since at low sample
//! counts the emitters' anti-aliasing can dominate every method's error alike).
//!
//! **Why supersample the emission alone.** In the Country Kitchen at 160 × 90 the window's
//! outline holds most of every method's squared error (RESULTS.md, issue 39: 56–68 % of it in
//! the pixels that see the window and their neighbours; path tracing's emission alone, at one
//! sample, has MSE 0.91 against 1.30 for the direct light and the emission together). A pixel
//! that the window's frame or a blind crosses averages a two-valued integrand, the emitter's
//! radiance or the frame's far smaller one, and only more camera samples lower that. A
//! pixel's value splits as `∫ L_e(x(u)) du + ∫ L_r(x(u)) du` over its footprint `u`; the
//! first part costs one ray per sample and no shading. A pass's own samples estimate both
//! parts; at a flagged pixel [`supersample`] adds `extra` samples of the first part alone and
//! averages them with the pass's own: `(n ē + Σ_k L_e(x(u_k))) / (n + extra)` in place of `ē`,
//! the mean of what the pass's `n` camera rays saw directly.
//!
//! **Unbiased.** Which pixels get the extra rays is decided from their eight neighbours'
//! seen emission, never from the pixel's own: the neighbours' samples are independent of
//! the pixel's, so the choice is too, and both averages have the expectation `∫ L_e`.
//! Deciding from the pixel's own sample would bias it (a pixel whose ray missed the window
//! would keep its zero, one whose ray hit it would be averaged down: `c² L_e` in place of
//! `c L_e` for a coverage `c`); the tests hold that variant as their negative control. A
//! pixel is flagged where its neighbours disagree: the brightest sees emission and the
//! dimmest less than half of it, so the inside of a uniform emitter and of a smooth sky cost
//! nothing (the sky's silhouettes do get the extra rays: they are edges of what the camera
//! sees directly too).

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Image, Ray, Scene, sampling::luminance};
use rayon::prelude::*;

use crate::sampler::PixelSampler;

/// The sample index of a pixel's first extra camera ray in its stream: above any pass's
/// sample or phase index, so the extra rays are independent of the pass's numbers.
const STREAM: u64 = 1 << 40;

/// Radiance the camera ray `ray` sees directly: the emission of its first hit, or the
/// environment where it escapes (what a path's first segment counts fully).
pub fn seen(scene: &Scene, ray: &Ray) -> Vec3 {
    match scene.intersect(ray) {
        Some(hit) => scene.emission(&scene.interaction(ray, &hit)),
        None => scene.environment().radiance(ray.d.normalize()),
    }
}

/// The pixels of a `width × height` image whose eight neighbours disagree about the emission
/// they saw (`seen`: each pixel's mean, row-major): the brightest neighbour's luminance is
/// positive and the dimmest's below half of it. A pixel's own value is never read (see the
/// module documentation).
pub fn outline(width: u32, height: u32, seen: &[Vec3]) -> Vec<bool> {
    let (w, h) = (width as i64, height as i64);
    assert_eq!(seen.len() as i64, w * h, "one value per pixel");
    let lum: Vec<f32> = seen.iter().map(|&l| luminance(l)).collect();
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (u, v) = (x + dx, y + dy);
                    if (dx, dy) != (0, 0) && u >= 0 && v >= 0 && u < w && v < h {
                        let l = lum[(v * w + u) as usize];
                        lo = lo.min(l);
                        hi = hi.max(l);
                    }
                }
            }
            hi > 0.0 && lo < 0.5 * hi
        })
        .collect()
}

/// What [`supersample`] changed: per pixel, the amount to add to the image (the new emission
/// mean less the pass's own), and the rays it traced.
#[derive(Clone, Debug)]
pub struct Supersampled {
    pub delta: Vec<Vec3>,
    pub rays: u64,
    /// Pixels that got extra rays.
    pub pixels: usize,
}

/// Anti-aliases the emission seen by the camera (module documentation): `seen_means` holds
/// each pixel's mean of what its `taken` camera rays saw directly, row-major (a non-finite
/// mean leaves its pixel as it is); every pixel of
/// [`outline`] gets `extra` more camera rays, jittered in the pixel with the frame's `seed`.
/// `flags` overrides [`outline`] (tests).
#[allow(clippy::too_many_arguments)]
pub fn supersample(
    scene: &Scene,
    camera: &Camera,
    (width, height): (u32, u32),
    seed: u64,
    taken: u32,
    extra: u32,
    seen_means: &[Vec3],
    flags: Option<&[bool]>,
) -> Supersampled {
    let owned;
    let flags = match flags {
        Some(f) => f,
        None => {
            owned = outline(width, height, seen_means);
            &owned
        }
    };
    let (n, extra_f) = (taken.max(1) as f32, extra as f32);
    let delta: Vec<Vec3> = (0..seen_means.len())
        .into_par_iter()
        .map(|pixel| {
            if extra == 0 || !flags[pixel] {
                return Vec3::ZERO;
            }
            let (x, y) = (pixel as u32 % width, pixel as u32 / width);
            let own = seen_means[pixel];
            if !own.is_finite() {
                return Vec3::ZERO;
            }
            let mut sum = Vec3::ZERO;
            for k in 0..extra {
                let mut s = PixelSampler::new(seed, pixel as u64, STREAM + k as u64);
                let film = Vec2::new(x as f32, y as f32) + s.next_2d();
                let l = seen(scene, &camera.generate_ray(film, width, height));
                // A non-finite value counts as black, as a pass's invalid samples do.
                if l.is_finite() {
                    sum += l;
                }
            }
            (n * own + sum) / (n + extra_f) - own
        })
        .collect();
    let pixels = if extra == 0 {
        0
    } else {
        flags.iter().filter(|&&f| f).count()
    };
    Supersampled {
        delta,
        rays: pixels as u64 * extra as u64,
        pixels,
    }
}

impl Supersampled {
    /// Adds [`Supersampled::delta`] to `image`.
    pub fn apply(&self, image: &mut Image) {
        for (p, d) in image.data.iter_mut().zip(&self.delta) {
            *p += *d;
        }
    }
}

/// Pixels whose footprint sees an emitter (4×4 primary rays per pixel), dilated by one pixel.
pub fn emitter_pixels(scene: &Scene, w: u32, h: u32) -> Vec<bool> {
    let sees = |x: u32, y: u32| {
        (0..16).any(|k| {
            let film = Vec2::new(
                x as f32 + ((k % 4) as f32 + 0.5) / 4.0,
                y as f32 + ((k / 4) as f32 + 0.5) / 4.0,
            );
            let ray = scene.camera.generate_ray(film, w, h);
            scene
                .intersect(&ray)
                .is_some_and(|hit| scene.emission(&scene.interaction(&ray, &hit)) != Vec3::ZERO)
        })
    };
    let direct: Vec<bool> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| sees(x, y))
        .collect();
    let (wi, hi) = (w as i64, h as i64);
    (0..hi)
        .flat_map(|y| (0..wi).map(move |x| (x, y)))
        .map(|(x, y)| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    u >= 0 && v >= 0 && u < wi && v < hi && direct[(v * wi + u) as usize]
                })
            })
        })
        .collect()
}

/// Copies the reference into the excluded pixels (zero error there).
pub fn exclude(image: &mut Image, mask: Option<&[bool]>, reference: &Image) {
    if let Some(mask) = mask {
        for ((p, r), m) in image.data.iter_mut().zip(&reference.data).zip(mask) {
            if *m {
                *p = *r;
            }
        }
    }
}
