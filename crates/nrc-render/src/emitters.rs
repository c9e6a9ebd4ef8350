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
//! sees directly too). Where the neighbours agree that they see emission, a pixel may still
//! hold an edge its neighbours do not: a window's bar thinner than a pixel, bright on both
//! sides. There [`outline_of`] looks at the pixel's footprint through a fixed 4 × 4 grid of
//! rays, the same whatever the seed, so the choice is still independent of the samples; it
//! is flagged where they disagree by the same rule. (In the Country Kitchen at 160 × 90 the
//! window's bars are such pixels: the neighbours' rule alone left most of the emission's
//! error in them.)
//!
//! **Stratified.** A pixel's extra rays are spread over a `g × g` grid of equal cells
//! (`g = ⌈√extra⌉`), one ray in each of `extra` distinct cells drawn at random, jittered in its
//! cell ([`crate::sampler::stratified`]). Each ray is still uniform over the pixel, so the mean stays unbiased;
//! an edge crossing the pixel now leaves its variance only in the `≈ g` cells it cuts, not in
//! every ray (for a straight edge and a full grid, `O(extra^-1.5)` instead of `1/extra`).

use std::sync::{Arc, Mutex, OnceLock};

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Image, Ray, Scene, sampling::luminance};
use rayon::prelude::*;

use crate::sampler::{MAX_STRATA, PixelSampler, stratified};

/// The sample index of a pixel's first extra camera ray in its stream: above any pass's
/// sample or phase index, so the extra rays are independent of the pass's numbers.
const STREAM: u64 = 1 << 40;
/// Extra rays per pixel at most (`--emitter-samples`).
pub const MAX_EXTRA: u32 = MAX_STRATA;

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
    neighbour_ranges(width, height, seen)
        .into_iter()
        .map(|(lo, hi)| disagree(lo, hi))
        .collect()
}

/// The outline's rule on the dimmest and brightest luminance seen.
fn disagree(lo: f32, hi: f32) -> bool {
    hi > 0.0 && lo < 0.5 * hi
}

/// The pixels around pixel `p` of a `w × h` image (up to eight, `p` excluded), row-major.
fn neighbours(w: u32, h: u32, p: usize) -> impl Iterator<Item = usize> {
    let (w, h) = (w as i64, h as i64);
    let (x, y) = (p as i64 % w, p as i64 / w);
    (-1..=1i64)
        .flat_map(|dy| (-1..=1i64).map(move |dx| (dx, dy)))
        .filter(|&d| d != (0, 0))
        .map(move |(dx, dy)| (x + dx, y + dy))
        .filter(move |&(u, v)| u >= 0 && v >= 0 && u < w && v < h)
        .map(move |(u, v)| (v * w + u) as usize)
}

/// Per pixel, the dimmest and the brightest luminance its neighbours saw (`seen`, row-major);
/// `(∞, 0)` for a pixel without neighbours.
fn neighbour_ranges(w: u32, h: u32, seen: &[Vec3]) -> Vec<(f32, f32)> {
    assert_eq!(seen.len(), w as usize * h as usize, "one value per pixel");
    let lum: Vec<f32> = seen.iter().map(|&l| luminance(l)).collect();
    (0..lum.len())
        .map(|p| {
            neighbours(w, h, p).fold((f32::INFINITY, 0.0f32), |(lo, hi), q| {
                (lo.min(lum[q]), hi.max(lum[q]))
            })
        })
        .collect()
}

/// The film position of ray `k` of the fixed `FOOTPRINT × FOOTPRINT` grid in pixel `(x, y)`.
fn grid_film(x: u32, y: u32, k: u32) -> Vec2 {
    let cell = |i: u32| (i as f32 + 0.5) / FOOTPRINT as f32;
    Vec2::new(
        x as f32 + cell(k % FOOTPRINT),
        y as f32 + cell(k / FOOTPRINT),
    )
}

/// The pixels [`supersample`] gives extra rays, and the rays it took to find them.
#[derive(Clone, Debug)]
pub struct Outline {
    pub flags: Vec<bool>,
    /// Rays of the footprint grids.
    pub rays: u64,
}

/// Side of the fixed grid that looks at a pixel's footprint.
const FOOTPRINT: u32 = 4;

/// The luminance of the emission seen through a fixed `FOOTPRINT × FOOTPRINT` grid of the
/// pixel `(x, y)` of a `w × h` image: the dimmest and the brightest.
fn footprint(scene: &Scene, camera: &Camera, (w, h): (u32, u32), x: u32, y: u32) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
    for k in 0..FOOTPRINT * FOOTPRINT {
        let film = grid_film(x, y, k);
        let l = luminance(seen(scene, &camera.generate_ray(film, w, h)));
        let l = if l.is_finite() { l } else { 0.0 };
        lo = lo.min(l);
        hi = hi.max(l);
    }
    (lo, hi)
}

/// What the footprint grids found for one scene, camera and image size: per pixel, whether its
/// footprint disagrees. A pure function of the three, so a frame of the same view reuses the
/// last frames' (an equal-time frame renders many passes of one view; a moving camera computes
/// them anew). The key holds the scene's address, size and bounds: a scene taking a freed
/// one's address with the same size, bounds and view would reuse stale grids, which costs
/// rays in the wrong pixels but no bias (the flags never read a pixel's samples).
struct Footprints {
    key: (usize, usize, [u32; 6], Camera, u32, u32),
    disagrees: Vec<OnceLock<bool>>,
}

static FOOTPRINTS: Mutex<Vec<Arc<Footprints>>> = Mutex::new(Vec::new());
/// Views whose footprints are kept.
const FOOTPRINT_VIEWS: usize = 4;

fn footprints(scene: &Scene, camera: &Camera, (w, h): (u32, u32)) -> Arc<Footprints> {
    let b = scene.bounds();
    let key = (
        scene as *const Scene as usize,
        scene.triangle_count(),
        [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits),
        *camera,
        w,
        h,
    );
    let mut kept = FOOTPRINTS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(f) = kept.iter().find(|f| f.key == key) {
        return f.clone();
    }
    let f = Arc::new(Footprints {
        key,
        disagrees: (0..w as usize * h as usize)
            .map(|_| OnceLock::new())
            .collect(),
    });
    if kept.len() == FOOTPRINT_VIEWS {
        kept.remove(0);
    }
    kept.push(f.clone());
    f
}

/// [`outline`], and where a pixel's neighbours agree that they see emission, its footprint
/// through the fixed grid (module documentation): never the pixel's own samples. `rays`
/// counts the grids traced by this call (none where an earlier frame of the view traced them).
pub fn outline_of(scene: &Scene, camera: &Camera, (w, h): (u32, u32), seen: &[Vec3]) -> Outline {
    let ranges = neighbour_ranges(w, h, seen);
    let grids = footprints(scene, camera, (w, h));
    let looked: Vec<(bool, bool)> = ranges
        .par_iter()
        .enumerate()
        .map(|(p, &(lo, hi))| {
            if disagree(lo, hi) {
                return (true, false);
            }
            // Neighbours that agree on no emission at all: nothing to look for.
            if hi <= 0.0 {
                return (false, false);
            }
            let mut traced = false;
            let disagrees = *grids.disagrees[p].get_or_init(|| {
                traced = true;
                let (lo, hi) = footprint(scene, camera, (w, h), p as u32 % w, p as u32 / w);
                disagree(lo, hi)
            });
            (disagrees, traced)
        })
        .collect();
    let grids = looked.iter().filter(|l| l.1).count() as u64;
    Outline {
        flags: looked.iter().map(|l| l.0).collect(),
        rays: grids * u64::from(FOOTPRINT * FOOTPRINT),
    }
}

/// What [`supersample`] changed: per pixel, the amount to add to the image (the new emission
/// mean less the pass's own), and the rays it traced.
#[derive(Clone, Debug)]
pub struct Supersampled {
    pub delta: Vec<Vec3>,
    pub rays: u64,
    /// Pixels that got extra rays.
    pub pixels: usize,
    /// Which pixels got them, row-major (empty where no pixel could: `extra` 0).
    pub flags: Vec<bool>,
}

/// Anti-aliases the emission seen by the camera (module documentation): `seen_means` holds
/// each pixel's mean of what its `taken` camera rays saw directly, row-major (a non-finite
/// mean leaves its pixel as it is); every pixel of [`outline_of`] gets `extra` more camera
/// rays, stratified in the pixel with the frame's `seed`. `flags` overrides [`outline_of`]
/// (tests).
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
    let mut grid_rays = 0;
    let flags = match flags {
        _ if extra == 0 => &[][..],
        Some(f) => f,
        None => {
            let o = outline_of(scene, camera, (width, height), seen_means);
            grid_rays = o.rays;
            owned = o.flags;
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
            let s = PixelSampler::new(seed, pixel as u64, STREAM);
            for offset in stratified(extra, s) {
                let film = Vec2::new(x as f32, y as f32) + offset;
                let l = seen(scene, &camera.generate_ray(film, width, height));
                // A non-finite value counts as black, as a pass's invalid samples do.
                if l.is_finite() {
                    sum += l;
                }
            }
            (n * own + sum) / (n + extra_f) - own
        })
        .collect();
    // The pixels that got the extra rays: flagged, with a finite mean of their own.
    let flags: Vec<bool> = flags
        .iter()
        .zip(seen_means)
        .map(|(&f, own)| f && own.is_finite())
        .collect();
    let pixels = flags.iter().filter(|&&f| f).count();
    Supersampled {
        delta,
        rays: pixels as u64 * extra as u64 + grid_rays,
        pixels,
        flags,
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
        (0..FOOTPRINT * FOOTPRINT).any(|k| {
            let ray = scene.camera.generate_ray(grid_film(x, y, k), w, h);
            scene
                .intersect(&ray)
                .is_some_and(|hit| scene.emission(&scene.interaction(&ray, &hit)) != Vec3::ZERO)
        })
    };
    let direct: Vec<bool> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| sees(x, y))
        .collect();
    (0..direct.len())
        .map(|p| direct[p] || neighbours(w, h, p).any(|q| direct[q]))
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
