//! A pass's split of the light gathered up to its shading vertex over more camera rays than
//! the one path its reservoir keeps ([`split_camera_rays`], [`split_emission`]), and the
//! choice of how many rays from the frames before ([`SplitChooser`]).

use glam::{Vec2, Vec3};

use super::frame::FrameInput;
use super::screen::{GBuffer, Phase, Primary, primary_hit, stream};
use crate::path_tracer::PathStats;
use crate::sampler::Stream;

/// The light a pass gathers up to its shading vertex, split over more camera rays: `extra`
/// more camera rays in the pixel of pixel sample `i` (uniform in it, or through its centre
/// without `jitter`), `gather` estimating that light from each one's primary vertex with the
/// seed it is given (each ray its own, for the pass's named streams); returns their sum, and
/// the sum of what they saw directly (emission or the environment). A pass
/// that takes a split replaces its path's own estimate `D₀` of that light by
/// `(D₀ + sum) / (extra + 1)`: each term estimates the same mean over the pixel, so the pixel
/// stays unbiased, and a term costs a camera ray and the rays to the shading vertex and of its
/// direct light, not a path (but where a pass traces a pixel's path whole, as screen-space
/// ReSTIR GI does at a specular primary, the term is that whole path). The seen light joins
/// the G-buffer's by [`split_emission`], for no ray more.
///
/// With the frame's [`FrameInput::sequence`] (a run's frames stratifying each pixel), extra
/// ray `k` takes the same point of a sequence of its own (another scramble): each of the
/// `extra + 1` rays of a pixel sample is stratified over the run's frames with its
/// like-numbered rays, so averaging them keeps the stratification of each. (Independent
/// offsets here would average stratified rays with unstratified ones; consecutive points of
/// one sequence would put every frame's G-buffer ray in the same half of the pixel.)
pub(crate) fn split_camera_rays(
    input: &FrameInput,
    i: usize,
    jitter: bool,
    extra: u32,
    stats: &mut PathStats,
    mut gather: impl FnMut(&Primary, u64, &mut PathStats) -> Vec3,
) -> (Vec3, Vec3) {
    let spp = input.spp.max(1) as usize;
    let pixel = i / spp;
    let xy = Vec2::new(
        (pixel % input.width as usize) as f32,
        (pixel / input.width as usize) as f32,
    );
    let mut s = stream(input.seed, i, Phase::Split);
    let (mut sum, mut seen) = (Vec3::ZERO, Vec3::ZERO);
    for k in 0..extra {
        let offset = if jitter {
            let independent = s.next_2d();
            let sequence = input.sequence.map(|q| q.for_split_ray(k));
            crate::sampler::camera_offset(sequence, pixel as u64, (i % spp) as u32, independent)
        } else {
            Vec2::splat(0.5)
        };
        let ray = input
            .camera
            .generate_ray(xy + offset, input.width, input.height);
        stats.closest_rays += 1;
        let (p, le) = primary_hit(input.scene, &ray);
        // A non-finite value counts as black, as the outline's extra rays do.
        if le.is_finite() {
            seen += le;
        }
        if let Some(p) = p {
            // A seed of its own for each extra ray: the pass's streams of pixel sample `i`
            // under it are independent of the frame's.
            sum += gather(&p, Stream::SplitRay(k).seed(input.seed), stats);
        }
    }
    (sum, seen)
}

/// The emission seen directly at pixel sample `i`, over the G-buffer's ray and a split's
/// `extra` rays, which saw `seen` in all ([`split_camera_rays`]): every ray weighs the same,
/// the G-buffer's value counting for [`GBuffer::emission_rays`] of them (on an emitter's
/// outline, the supersampled mean). The outline is decided from the neighbours' samples alone
/// (`crate::emitters`), so the weights are independent of the pixel's rays and each term's
/// expectation is the pixel's mean emission: unbiased.
pub(crate) fn split_emission(g: &GBuffer, i: usize, extra: u32, seen: Vec3) -> Vec3 {
    if extra == 0 {
        return g.emitted[i];
    }
    let m = g.emission_rays(i);
    (g.emitted[i] * m + seen) / (m + extra as f32)
}

/// One pixel sample's terms of a frame with a split, for [`SplitChooser::observe`]: the
/// frame's estimate there is `E + (D₀ + D₁ + … + D_m) / (m + 1) + R`.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplitTerms {
    /// `D₀`: the path's own estimate of the light gathered up to its shading vertex.
    pub own: Vec3,
    /// The mean of the `m` extra rays' estimates of the same.
    pub extras: Vec3,
    /// `R`: the reservoir's reflected light at the shading vertex, with the path's
    /// throughput to it (zero where there is none).
    pub reflected: Vec3,
}

/// Frames an estimate of [`SplitChooser`] remembers (the weight of an exponential moving
/// average, once this many frames have been seen).
const SPLIT_MEMORY: u32 = 16;

/// Chooses a split's camera rays for the next frame (`splitmax=N`: between 2 and `N`) by the
/// efficiency of the frame's estimate, 1 / (variance × cost), as splitting factors are chosen
/// from estimated variances and costs in Rath et al. 2022 (EARS, "Efficiency-Aware Russian
/// Roulette and Splitting"), here for one factor per frame.
///
/// With `n` rays, the estimate at a pixel sample is `X = E + (D₀ + … + D_{n−1}) / n + R`:
/// `Dₖ` the light gathered up to the shading vertex by camera ray `k` (`D₀` the path's own) and
/// `R` the reservoir's reflected light, found by the path's own ray. So
/// `Var X = A / n + B` (the emission `E` seen aside: on an emitter's edge the outline's rays
/// are what lowers its variance), `A = Var D + 2 Cov(D₀, R)`,
/// `B = Var R`; the frame costs `c₀ + (n − 1) c₁`; the chosen `n` minimises
/// `(A / n + B)(c₀ + (n − 1) c₁)` over the image's means.
///
/// Estimates, from a frame with `m = n − 1 ≥ 1` extra rays: with `q = D₀ − D̄` (`D̄` the
/// extras' mean, independent of `D₀` and `R`), `E[q²] = Var D · (1 + 1/m)` and
/// `E[q · R] = Cov(D₀, R)`; `B` per pixel sample by an exponential moving variance of `R`
/// over frames. That is a frame's variance: the correlation between frames is left out both
/// ways, the reservoir's positive one (temporal reuse; the lag-one autocorrelation of `R`
/// measured 0.25–0.43 on the kitchen and the door scenes) and the negative one of camera rays
/// stratified over a run's frames (`--camera-offsets sobol`). The costs are what the pass
/// gives: the frame's and the split's share of it, in any unit. Each estimate is an
/// exponential moving average with weight `1 / min(frames, SPLIT_MEMORY)`; pixel samples
/// with a non-finite term (counted black by the pass) are left out. Only frames before the
/// one it sizes decide `n`, so a frame's ray count is fixed before its random numbers are
/// drawn and each frame stays unbiased.
#[derive(Clone, Debug)]
pub struct SplitChooser {
    max: u32,
    /// Per pixel sample: the moving mean of `R` and its moving variance.
    reflected: Vec<(Vec3, f32)>,
    /// Frames seen since the pixel samples last changed.
    frames: u32,
    /// Frames taken into the moving averages of the image's estimates.
    observed: u32,
    /// Moving averages over frames of the image's `A`, `B`, `c₀` and `c₁`.
    a: f64,
    b: f64,
    c0: f64,
    c1: f64,
    /// The rays the last choice gave.
    rays: u32,
}

impl SplitChooser {
    /// A chooser between 2 and `max` rays (at least 2), starting at 2.
    pub fn new(max: u32) -> Self {
        Self {
            max: max.max(2),
            reflected: Vec::new(),
            frames: 0,
            observed: 0,
            a: 0.0,
            b: 0.0,
            c0: 0.0,
            c1: 0.0,
            rays: 2,
        }
    }

    /// Camera rays a pixel sample for the next frame.
    pub fn rays(&self) -> u32 {
        self.rays
    }

    /// The estimates as `(A, B, c₀, c₁)`, for reports and tests.
    pub fn estimates(&self) -> (f64, f64, f64, f64) {
        (self.a, self.b, self.c0, self.c1)
    }

    /// Takes a frame rendered with `rays` camera rays a pixel sample (at least 2): its terms
    /// per pixel sample, its cost `frame` and the split's share of it `split`; then chooses
    /// the next frame's rays.
    pub fn observe(&mut self, terms: &[SplitTerms], rays: u32, frame: f64, split: f64) {
        if rays < 2 || terms.is_empty() {
            return;
        }
        let finite =
            |t: &SplitTerms| t.own.is_finite() && t.extras.is_finite() && t.reflected.is_finite();
        if self.reflected.len() != terms.len() {
            self.reflected = terms
                .iter()
                .map(|t| (if finite(t) { t.reflected } else { Vec3::ZERO }, 0.0))
                .collect();
            self.frames = 1;
            self.observed = 0;
            return;
        }
        self.frames += 1;
        let w = 1.0 / self.frames.min(SPLIT_MEMORY) as f32;
        let m = (rays - 1) as f64;
        let (mut qq, mut qr, mut var_r, mut kept) = (0.0f64, 0.0f64, 0.0f64, 0usize);
        for (t, (mean, var)) in terms.iter().zip(&mut self.reflected) {
            // A sample the pass counted as black (non-finite) tells nothing of the variances.
            if finite(t) {
                let q = t.own - t.extras;
                qq += (q.dot(q) / 3.0) as f64;
                qr += (q.dot(t.reflected) / 3.0) as f64;
                let d = t.reflected - *mean;
                *mean += w * d;
                *var = (1.0 - w) * (*var + w * d.dot(d) / 3.0);
                kept += 1;
            }
            var_r += *var as f64;
        }
        let count = kept as f64;
        let a = qq / count / (1.0 + 1.0 / m) + 2.0 * qr / count;
        let b = var_r / terms.len() as f64;
        let c1 = split / m;
        let c0 = (frame - split).max(0.0);
        if kept == 0 || !(a.is_finite() && b.is_finite() && c0.is_finite() && c1.is_finite()) {
            return;
        }
        // The moving averages start with the first frame that has a variance of `R`.
        self.observed += 1;
        let k = 1.0 / self.observed.min(SPLIT_MEMORY) as f64;
        self.a += k * (a - self.a);
        self.b += k * (b - self.b);
        self.c0 += k * (c0 - self.c0);
        self.c1 += k * (c1 - self.c1);
        self.rays = best_split(self.a, self.b, self.c0, self.c1, self.max);
    }
}

/// The `n` in `2..=max` minimising `(A / n + B)(c₀ + (n − 1) c₁)` (negative `A` or `B`, from
/// noisy estimates, taken as zero).
pub fn best_split(a: f64, b: f64, c0: f64, c1: f64, max: u32) -> u32 {
    let (a, b) = (a.max(0.0), b.max(0.0));
    let cost = |n: u32| (a / n as f64 + b) * (c0 + (n - 1) as f64 * c1);
    (2..=max.max(2))
        .min_by(|&x, &y| cost(x).total_cmp(&cost(y)))
        .unwrap_or(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_split_follows_the_variances_and_costs() {
        // Only the split's variance: as many rays as allowed while a ray costs less than the rest.
        assert_eq!(best_split(1.0, 0.0, 10.0, 1.0, 8), 8);
        // Only the reservoir's: the fewest.
        assert_eq!(best_split(0.0, 1.0, 10.0, 1.0, 8), 2);
        // Balanced: n* = √(A c₀' / (B c₁)) with c₀' = c₀ − c₁ = 9 and A = 4B: 6.
        assert_eq!(best_split(4.0, 1.0, 10.0, 1.0, 8), 6);
        // Rays that cost as much as the rest: fewer.
        assert_eq!(best_split(4.0, 1.0, 10.0, 9.0, 8), 2);
    }

    /// A frame of `n` pixel samples whose gathered light has variance `var_d` (independent
    /// draws) and whose reflected light is `1 + coupling · D₀` plus noise of variance `var_r`
    /// (so `Cov(D₀, R) = coupling · var_d`).
    fn frame(
        n: usize,
        rays: u32,
        var_d: f32,
        var_r: f32,
        coupling: f32,
        seed: u64,
    ) -> Vec<SplitTerms> {
        let mut s = crate::sampler::PixelSampler::new(seed, 0, 0);
        let mut noise = |var: f32| {
            // Uniform on [−√(3 var), √(3 var)]: variance var.
            let u = s.next_1d() * 2.0 - 1.0;
            Vec3::splat(u * (3.0 * var).sqrt())
        };
        (0..n)
            .map(|_| {
                let own = noise(var_d);
                let m = (rays - 1) as f32;
                let extras = (0..rays - 1).map(|_| noise(var_d)).sum::<Vec3>() / m;
                SplitTerms {
                    own,
                    extras,
                    reflected: Vec3::ONE + coupling * own + noise(var_r),
                }
            })
            .collect()
    }

    /// The chooser's estimates settle after `frames` frames of `frame(…)`, at a cost of 9 a
    /// frame and 1 an extra ray.
    fn settled(frames: u64, var_d: f32, var_r: f32, coupling: f32) -> SplitChooser {
        let mut c = SplitChooser::new(8);
        for f in 0..frames {
            let rays = c.rays();
            let split = (rays - 1) as f64;
            let terms = frame(4096, rays, var_d, var_r, coupling, f);
            c.observe(&terms, rays, 9.0 + split, split);
        }
        c
    }

    /// The path's own gathered light anticorrelated with its reservoir's (`Cov(D₀, R)` =
    /// −var D): `A` = Var D + 2 Cov is negative, so averaging `D₀` down with more rays loses
    /// the cancellation and the chooser stays at 2; with the covariance term dropped (the
    /// control) `A` would be Var D and the choice more rays.
    #[test]
    fn the_chooser_counts_the_own_rays_covariance_with_the_reservoir() {
        let c = settled(48, 2.0, 0.5, -1.0);
        let (a, b, c0, c1) = c.estimates();
        assert!((a + 2.0).abs() < 0.15, "A {a} (expected −2)");
        assert_eq!(c.rays(), 2);
        // Without the covariance: A = 2, B = 2.5 (the coupled part included) chooses more.
        assert!(best_split(2.0, b, c0, c1, 8) > 2, "B {b}");
    }

    #[test]
    fn the_chooser_estimates_the_variances_it_is_shown() {
        let c = settled(64, 2.0, 0.5, 0.0);
        let (a, b, c0, c1) = c.estimates();
        assert!((a - 2.0).abs() < 0.1, "A {a}");
        // The moving variance with weight 1/16 settles at 2(1 − w)/(2 − w) = 30/31 of it.
        assert!((b - 0.5).abs() < 0.06, "B {b}");
        assert!(
            (c1 - 1.0).abs() < 1e-9 && (c0 - 9.0).abs() < 1e-9,
            "c₀ {c0}, c₁ {c1}"
        );
        assert_eq!(c.rays(), best_split(a, b, c0, c1, 8));
        assert!(c.rays() >= 4, "rays {}", c.rays());
        // The reflected light's variance dominating: the fewest rays.
        assert_eq!(settled(32, 0.01, 4.0, 0.0).rays(), 2);
    }
}
