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
use super::params::{Key, Value};
use crate::error::SettingsError;
use crate::path_tracer::PathStats;
use crate::reservoir::Reservoir;
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
    /// counts fully.
    pub emitted: Vec<Vec3>,
    /// Rays traced.
    pub rays: u64,
}

impl GBuffer {
    /// Traces the camera rays of a `width × height × spp` frame: jittered in the pixel with
    /// the [`Phase::Camera`] stream, or through pixel centres without `jitter` (tests against
    /// a reference at fixed primary rays).
    pub fn trace(
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        spp: u32,
        seed: u64,
        jitter: bool,
    ) -> Self {
        let spp = spp.max(1);
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
                    stream(seed, i, Phase::Camera).next_2d()
                } else {
                    Vec2::splat(0.5)
                };
                let ray = camera.generate_ray(Vec2::new(x, y) + offset, width, height);
                primary_hit(scene, &ray)
            })
            .collect();
        let (primary, emitted) = hits.into_iter().unzip();
        Self {
            camera: *camera,
            width,
            height,
            spp,
            primary,
            emitted,
            rays: n as u64,
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

    /// The neighbours `near` as `(res(q), vertex)` pairs, for [`combine`].
    pub fn with_vertices<R>(&self, near: &[usize], res: impl Fn(usize) -> R) -> Vec<(R, &Vertex)> {
        near.iter()
            .map(|&q| {
                let v = &self.primary[q]
                    .as_ref()
                    .expect("neighbours have vertices")
                    .v;
                (res(q), v)
            })
            .collect()
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
fn primary_hit(scene: &Scene, ray: &Ray) -> (Option<Primary>, Vec3) {
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

/// Merges `others` (finished reservoirs with their owners' vertices) into `own` (the reservoir
/// of `v`) for a sample type whose target at a vertex is `target` (the same measure at every
/// vertex: no shift Jacobian), finishing with the unbiased `Z` (Bitterli et al. 2020, Alg. 6:
/// the `M` of the inputs whose owner has `p̂ > 0` for the chosen `y` and, by `sees`, sees it)
/// or, `biased`, `Z = Σ M`. Returns the merged reservoir and whether its sample is `own`'s.
pub fn combine<T: Copy>(
    v: &Vertex,
    own: &Reservoir<T>,
    others: &[(Reservoir<T>, &Vertex)],
    biased: bool,
    u: &mut PixelSampler,
    target: impl Fn(&Vertex, &T) -> f32,
    mut sees: impl FnMut(&Vertex, &T) -> bool,
) -> (Reservoir<T>, bool) {
    let mut out = Reservoir::new();
    let mut is_own = out.merge(own, own.target, u.next_1d());
    for (o, _) in others {
        let t = o.sample.map_or(0.0, |y| target(v, &y));
        if out.merge(o, t, u.next_1d()) {
            is_own = false;
        }
    }
    let z = match out.sample {
        None => out.m,
        Some(_) if biased => out.m,
        Some(y) => {
            let mut z = own.m;
            for (o, ov) in others {
                if target(ov, &y) > 0.0 && sees(ov, &y) {
                    z += o.m;
                }
            }
            z
        }
    };
    out.finish(z);
    (out, is_own)
}

/// `f` over the pixel samples `0..n`, in parallel, results in order.
pub fn par_map<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    (0..n).into_par_iter().map(f).collect()
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

/// The keys of the screen-space reuse every resampling pass of the primary vertex shares:
/// `k` neighbours in a disc of `radius` pixels, the history's `mcap`, and `temporal`.
pub(super) fn visit_reuse(
    f: &mut dyn FnMut(&Key, &mut dyn Value),
    neighbours: &mut u32,
    radius: &mut f32,
    m_cap: &mut f32,
    temporal: &mut bool,
) {
    let k = Key::new("k", "spatial neighbours (0: no spatial reuse)");
    f(&k.range(0.0, MAX), neighbours);
    let r = Key::new("radius", "radius of the spatial neighbourhood, pixels");
    f(&r.range(0.0, f64::INFINITY), radius);
    let mcap = Key::new(
        "mcap",
        "the history's M capped at this multiple of the candidates",
    );
    f(&mcap.positive(f64::INFINITY), m_cap);
    f(
        &Key::new("temporal", "reuse the previous frame's reservoirs"),
        temporal,
    );
}

/// The bounds every resampling pass puts on its reuse settings (`counts`: its candidate and
/// neighbour counts; absurd values would be loops per pixel).
pub(super) fn validate_reuse(counts: &[u32], radius: f32, m_cap: f32) -> Result<(), SettingsError> {
    let max = MAX_COUNT;
    if let Some(c) = counts.iter().find(|&&c| c > max) {
        return Err(SettingsError::bounds(
            "candidate and neighbour counts",
            format!("be at most {max}"),
            c,
        ));
    }
    if !(radius >= 0.0 && radius.is_finite()) {
        return Err(SettingsError::bounds(
            "spatial radius",
            "be finite and ≥ 0",
            radius,
        ));
    }
    if !(m_cap > 0.0 && m_cap.is_finite()) {
        return Err(SettingsError::bounds("M-cap", "be positive", m_cap));
    }
    Ok(())
}
