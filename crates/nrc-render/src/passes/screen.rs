//! What the screen-space resampling passes share: the frame's primary vertices (a G-buffer),
//! reprojection into the previous frame, the similarity test that rejects a neighbour or a
//! history sample on another surface, and the choice of spatial neighbours (Bitterli et al.
//! 2020, §4–5; Ouyang et al. 2021, §4: normals within 25°, depths within 10 %).
//!
//! Buffers are indexed by *pixel sample* `i = (y · width + x) · spp + s`: a pass with `spp`
//! samples per pixel keeps `spp` independent reservoir chains per pixel, chain `s` reusing
//! only chain `s` of its neighbours and of the previous frame.

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Ray, Scene};
use rayon::prelude::*;

use super::frame::{FrameInput, PassOutput, PassStats, PhaseTimes};
use crate::path_tracer::PathStats;
use crate::sampler::PixelSampler;
use crate::transport::Vertex;

/// Cosine of the largest angle between the normals of two vertices that may share samples.
pub const NORMAL_COS: f32 = 0.906; // 25°
/// Largest relative difference of two vertices' camera distances that may share samples.
pub const DEPTH_TOLERANCE: f32 = 0.1;

/// The largest candidate or neighbour count a resampling pass accepts.
pub const MAX_COUNT: u32 = 1024;
/// [`MAX_COUNT`] as a parameter's bound.
pub const MAX: f64 = MAX_COUNT as f64;

/// Stream ids of a pixel sample's random numbers, one per phase of a frame, so that a phase's
/// numbers do not depend on how many another drew.
#[derive(Clone, Copy, Debug)]
#[repr(u64)]
pub enum Phase {
    Camera = 0,
    Candidates = 1,
    Temporal = 2,
    Spatial = 3,
    Shading = 4,
    Path = 5,
    Extra = 6,
    /// The choice among a pixel's initial candidates (resampled importance sampling).
    Resample = 7,
    /// Lookups of the radiance a candidate reflects (probes with stochastic offsets).
    SourceLookup = 8,
    /// The history's radiance asked again toward its owner.
    HistoryRefresh = 9,
    /// The near-specular recursion at shading (DDGI resampling's eqs. 7–8).
    Footprint = 10,
    /// The offsets of a split's extra camera rays in the pixel
    /// ([`super::split::split_camera_rays`]).
    Split = 11,
}

/// The random stream of pixel sample `i` in `phase` of the frame seeded `seed`.
#[inline]
pub fn stream(seed: u64, i: usize, phase: Phase) -> PixelSampler {
    PixelSampler::new(seed, i as u64, phase as u64)
}

/// A pixel sample's primary vertex: the camera ray's first hit.
#[derive(Clone, Copy, Debug)]
pub struct Primary {
    pub v: Vertex,
    /// Distance from the camera.
    pub depth: f32,
}

/// One frame's camera rays and what they saw.
#[derive(Clone, Debug)]
pub struct GBuffer {
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// The primary vertex of each pixel sample (`None`: the ray escaped).
    pub primary: Vec<Option<Primary>>,
    /// Radiance the camera ray sees directly (emission of its hit, or the environment), which
    /// counts fully (a pass's split averages it with its extra rays',
    /// [`super::split::split_emission`]).
    pub emitted: Vec<Vec3>,
    /// Per pixel, whether its emission was supersampled on an emitter's outline (empty: none
    /// was); [`GBuffer::emission_rays`].
    outline: Vec<bool>,
    /// The outline's extra camera rays a pixel.
    outline_rays: u32,
    /// Rays traced.
    pub rays: u64,
}

impl GBuffer {
    /// Traces the camera rays of `input`'s frame (`width × height × spp`, its seed):
    /// jittered in the pixel with the [`Phase::Camera`] stream, or through pixel centres
    /// without `jitter` (tests against a reference at fixed primary rays). With jitter, the
    /// emission seen at the outline of emitters gets `input.emitter_samples` more camera rays
    /// a pixel ([`crate::emitters::supersample`]), each of the pixel's samples shifted by the
    /// same amount so that their mean is the supersampled one.
    pub fn trace(input: &FrameInput, jitter: bool) -> Self {
        let (scene, camera, seed) = (input.scene, input.camera, input.seed);
        let (width, height) = (input.width, input.height);
        let spp = input.spp.max(1);
        let n = width as usize * height as usize * spp as usize;
        let hits: Vec<(Option<Primary>, Vec3)> = (0..n)
            .into_par_iter()
            .map(|i| {
                let pixel = i / spp as usize;
                let (x, y) = (
                    (pixel % width as usize) as f32,
                    (pixel / width as usize) as f32,
                );
                let offset = if jitter {
                    input.camera_offset(
                        pixel as u64,
                        (i % spp as usize) as u32,
                        stream(seed, i, Phase::Camera).next_2d(),
                    )
                } else {
                    Vec2::splat(0.5)
                };
                let ray = camera.generate_ray(Vec2::new(x, y) + offset, width, height);
                primary_hit(scene, &ray)
            })
            .collect();
        let (primary, mut emitted): (Vec<_>, Vec<Vec3>) = hits.into_iter().unzip();
        let mut rays = n as u64;
        let mut outline = Vec::new();
        if jitter && input.emitter_samples > 0 {
            // Non-finite values are a pass's invalid samples, counted as black in the image.
            let means: Vec<Vec3> = emitted
                .chunks(spp as usize)
                .map(|c| c.iter().filter(|l| l.is_finite()).sum::<Vec3>() / spp as f32)
                .collect();
            let aa = input
                .supersample_emitters(spp, &means)
                .expect("emitter samples asked");
            for (i, e) in emitted.iter_mut().enumerate() {
                *e += aa.delta[i / spp as usize];
            }
            rays += aa.rays;
            outline = aa.flags;
        }
        Self {
            camera: *camera,
            width,
            height,
            spp,
            primary,
            emitted,
            outline,
            outline_rays: input.emitter_samples,
            rays,
        }
    }

    /// The camera rays whose seen emission pixel sample `i`'s [`GBuffer::emitted`] stands
    /// for: 1, or on an emitter's outline its share of the pixel's samples and extra rays,
    /// `(spp + extra) / spp` (the samples' mean is the supersampled one). A pass with more
    /// camera rays of its own through the pixel weighs the two by these counts.
    pub fn emission_rays(&self, i: usize) -> f32 {
        let pixel = i / self.spp as usize;
        if self.outline.get(pixel).copied().unwrap_or(false) {
            (self.spp + self.outline_rays) as f32 / self.spp as f32
        } else {
            1.0
        }
    }

    /// Pixel samples in the frame.
    pub fn len(&self) -> usize {
        self.primary.len()
    }

    /// Whether the frame is empty.
    pub fn is_empty(&self) -> bool {
        self.primary.is_empty()
    }

    /// Whether `other` holds frames of the same shape (history is usable).
    pub fn same_shape(&self, other: &GBuffer) -> bool {
        (self.width, self.height, self.spp) == (other.width, other.height, other.spp)
    }

    /// The pixel sample of this (previous) frame that saw the point `p` with normal `n`
    /// (reprojection through this frame's camera), if that sample's vertex is similar: the
    /// temporal neighbour of a vertex of chain `s` of the current frame.
    pub fn reproject(&self, p: Vec3, n: Vec3, s: u32) -> Option<usize> {
        let film = self.camera.project(p, self.width, self.height)?;
        let pixel = film.y as usize * self.width as usize + film.x as usize;
        let j = pixel * self.spp as usize + s as usize;
        let q = self.primary[j].as_ref()?;
        let depth = (p - self.camera.position).length();
        similar(q, n, depth).then_some(j)
    }

    /// The temporal neighbour in this (previous) frame of the current frame's pixel sample `i`
    /// with vertex `v`: its index and vertex (see [`GBuffer::reproject`]).
    pub fn temporal_neighbour(&self, v: &Vertex, i: usize) -> Option<(usize, &Vertex)> {
        let j = self.reproject(v.si.p, v.si.ns, (i % self.spp as usize) as u32)?;
        Some((j, &self.primary[j].as_ref()?.v))
    }

    /// Up to `k` spatial neighbours of pixel sample `i` (chain `s`): pixels uniform in a disc
    /// of `radius` pixels, kept where their vertex is similar to `me` (Bitterli et al. 2020:
    /// rejected candidates are not replaced).
    pub fn neighbours(
        &self,
        i: usize,
        me: &Primary,
        k: u32,
        radius: f32,
        sampler: &mut PixelSampler,
        out: &mut Vec<usize>,
    ) {
        out.clear();
        let spp = self.spp as usize;
        let pixel = i / spp;
        let s = i % spp;
        let (x, y) = (
            (pixel % self.width as usize) as f32,
            (pixel / self.width as usize) as f32,
        );
        for _ in 0..k {
            let u = sampler.next_2d();
            let r = radius * u.x.sqrt();
            let phi = std::f32::consts::TAU * u.y;
            let (nx, ny) = (
                (x + 0.5 + r * phi.cos()).floor(),
                (y + 0.5 + r * phi.sin()).floor(),
            );
            if nx < 0.0 || ny < 0.0 || nx >= self.width as f32 || ny >= self.height as f32 {
                continue;
            }
            let q = (ny as usize * self.width as usize + nx as usize) * spp + s;
            if q == i {
                continue;
            }
            if let Some(p) = &self.primary[q]
                && similar(p, me.v.si.ns, me.depth)
            {
                out.push(q);
            }
        }
    }
}

/// Whether `q` lies on the same surface as a vertex with normal `n` at camera distance
/// `depth`: normals within 25°, depths within 10 %.
#[inline]
pub fn similar(q: &Primary, n: Vec3, depth: f32) -> bool {
    q.v.si.ns.dot(n) >= NORMAL_COS
        && (q.depth - depth).abs() <= DEPTH_TOLERANCE * depth.max(q.depth)
}

/// The first hit of camera ray `ray` and the radiance it sees there directly.
pub(crate) fn primary_hit(scene: &Scene, ray: &Ray) -> (Option<Primary>, Vec3) {
    let Some(hit) = scene.intersect(ray) else {
        return (None, scene.environment().radiance(ray.d.normalize()));
    };
    let si = scene.interaction(ray, &hit);
    let le = scene.emission(&si);
    let v = Vertex::new(scene, &si, si.wo);
    (
        Some(Primary {
            v,
            depth: hit.t * ray.d.length(),
        }),
        le,
    )
}

/// Whether the segment from `a` (a surface point with geometric normal `ng_a`) to `b` (with
/// `ng_b`) is unoccluded; counts the shadow ray.
#[inline]
pub fn visible_between(
    scene: &Scene,
    a: Vec3,
    ng_a: Vec3,
    b: Vec3,
    ng_b: Vec3,
    stats: &mut PathStats,
) -> bool {
    stats.shadow_rays += 1;
    !scene.occluded(&nrc_scene::spawn_ray_between(a, ng_a, b, ng_b))
}

/// `f` over the pixel samples `0..n`, in parallel, results in order.
pub fn par_map<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    (0..n).into_par_iter().map(f).collect()
}

/// [`par_map`] into `buf`, replacing its contents and keeping its allocation: a pass that
/// keeps a frame-sized buffer across frames writes the same pages each frame, where a fresh
/// allocation of that size (hundreds of MB at 640 × 360) is mapped anew and every page of it
/// faulted in and zeroed by the system first.
pub fn par_map_into<T: Send>(buf: &mut Vec<T>, n: usize, f: impl Fn(usize) -> T + Sync + Send) {
    buf.clear();
    buf.par_extend((0..n).into_par_iter().map(f));
}

/// The frame from each pixel sample's radiance, state and counters: pixels average their
/// samples (non-finite ones counted and zeroed), rays add up. Returns the output and the
/// per-sample states (the next frame's history).
pub fn assemble<R>(
    g: &GBuffer,
    input: &FrameInput,
    shaded: Vec<(Vec3, R, PathStats)>,
    phases: PhaseTimes,
) -> (PassOutput, Vec<R>) {
    let mut stats = PassStats {
        paths: g.len() as u64,
        rays: g.rays,
        phases,
        ..Default::default()
    };
    let spp = g.spp as usize;
    let mut image = vec![Vec3::ZERO; g.len() / spp];
    let mut states = Vec::with_capacity(g.len());
    for (i, (l, r, ps)) in shaded.into_iter().enumerate() {
        stats.rays += ps.rays();
        let l = if l.is_finite() {
            l
        } else {
            stats.invalid_samples += 1;
            Vec3::ZERO
        };
        image[i / spp] += l / spp as f32;
        states.push(r);
    }
    let out = PassOutput {
        image: nrc_scene::Image::from_data(input.width as usize, input.height as usize, image)
            .expect("one value per pixel"),
        variance: None,
        terminations: Vec::new(),
        stats,
    };
    (out, states)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The buffer's allocation is kept from one frame to the next (the same pages), and its
    /// contents are only the new frame's.
    #[test]
    fn par_map_into_refills_the_same_allocation() {
        let mut buf: Vec<u64> = Vec::new();
        par_map_into(&mut buf, 100_000, |i| i as u64);
        let at = buf.as_ptr();
        par_map_into(&mut buf, 60_000, |i| 2 * i as u64);
        assert_eq!(buf.as_ptr(), at, "a new allocation for a smaller frame");
        assert_eq!(buf.len(), 60_000);
        assert!(buf.iter().enumerate().all(|(i, &v)| v == 2 * i as u64));
        par_map_into(&mut buf, 100_000, |i| 3 * i as u64);
        assert_eq!(
            buf.as_ptr(),
            at,
            "a new allocation for a frame of the first size"
        );
        assert!(buf.iter().enumerate().all(|(i, &v)| v == 3 * i as u64));
    }
}
