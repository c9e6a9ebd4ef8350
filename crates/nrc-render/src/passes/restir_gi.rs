//! ReSTIR GI, in screen space (`restir-gi`: Ouyang et al. 2021, the seed paper's baseline) and
//! in world space (`wsrestir-gi`: `world-space-restir-gi.txt`, Zhang and Wang), and with the
//! neural cache at the reconnection vertex (`-nrc`, beyond the paper).
//!
//! A sample is a *reconnection vertex* `y` (a surface point reached from the shading vertex
//! `x₁` by BSDF sampling) with the radiance `L` leaving it toward `x₁`, emission excluded (the
//! direct light at `x₁` is the path tracer's: NEE weighted by MIS against the candidate's BSDF
//! ray finding the emitter; NEE alone, as before, turned glossy reflections of the kitchen's
//! window into fireflies). A candidate drawn from a delta lobe of a mixed BSDF (a smooth coat)
//! cannot be resampled; it is estimated whole, `weight · L(y)`, beside the reservoir. The target at a
//! vertex `v` is `p̂_v(y) = lum(f_v(ω_o, ω_y) |cos θ| L)`, per solid angle at `v`; the initial
//! reservoir holds one BSDF sample, `W = 1/p_ω`. `L` is a traced path tail (NEE and MIS at
//! `y`, further bounces) or, for `-nrc`, one cache query at `y`.
//!
//! - **Shading vertex `x₁`**: `restir-gi` uses the primary vertex (non-delta; delta primaries
//!   fall back to the path tracer); `wsrestir-gi` the first vertex of roughness ≥ 0.2 (§4.1),
//!   the path traced through the specular ones before it (their NEE and emission counted as
//!   the path tracer counts them). A traced tail `L` is one walk from `y` on, Russian roulette
//!   on its throughput from `y` (not restarted at the vertex after `y`, whose sample the grid
//!   also holds).
//! - **Temporal reuse** (both): the previous frame's final reservoir at the reprojected pixel
//!   (normals within 25°, depths within 10 %), `M` capped at `m_cap`; only where `x₁` is the
//!   primary vertex.
//! - **Spatial reuse**: `restir-gi` from `k` screen neighbours in a disc of `radius` pixels
//!   (read from the temporal buffer); `wsrestir-gi` from up to `samples` entries of the cell of
//!   the previous frame's hash grid ([`super::hash_grid`], Alg. 2: a random offset and a fixed
//!   stride through the cell) whose owner's normal is within 15°. The grid read while the new
//!   one is built holds, per path, the temporal reservoir keyed at `x₁` and (traced tails only)
//!   the initial sample of the next non-specular vertex `x₂` keyed at `x₂` (Alg. 1: vertices
//!   from the first non-specular one on), so a vertex also reuses paths that passed it at
//!   their second bounce.
//! - **Shift**: the donor's `y` and `L` kept, `W` carried by the reconnection Jacobian
//!   [`reconnection_jacobian`]; visibility from the receiver tested by the final shadow ray
//!   where the sample came from another vertex (the pixel's own candidate was found by a ray
//!   from `x₁`; a history sample the temporal step took was shadow-tested there).
//! - **Bias**: unbiased (default) — pairwise MIS ([`reuse::Merge`]: each input weighed against
//!   the receiver's own by its target and visibility, a shadow ray per input; `pairwise=0`:
//!   `Z` sums the `M` of the inputs whose owner has `p̂ > 0` for `y` and sees it); `-biased`:
//!   `Z = Σ M`. Reusing `L` toward another
//!   receiver is exact where `y` is diffuse; at glossy `y` it is the method's approximation.

use std::time::Instant;

use glam::Vec3;
use nrc_scene::{Scene, sampling::luminance};
use rayon::prelude::*;

use crate::error::SettingsError;
use super::reuse::{self, Entry, Merge, Resampling, Slot, WorldHistory};
use super::screen::{
    GBuffer, MAX, MAX_COUNT, Phase, Primary, par_map, par_map_into, stream, visible_between,
};
use super::split::{SplitChooser, SplitTerms, split_camera_rays, split_emission};
use super::params::{Key, Params, Value};
use super::spec::{PassConfig, PassKind, parse_variant};
use super::frame::{FrameInput, PassOutput, PhaseTimes, RenderPass};
use crate::path_tracer::{PathStats, PathTracer};
use crate::reservoir::Reservoir;
use crate::source::{RadianceQuery, usable_answer};
use crate::transport::{Arrival, PathWalk, Vertex};

/// Vertices below this roughness (perceptual, √α) count as specular in world space and are
/// traced through (§4.1: "smaller than 0.2", which does not say whether of α or of √α); the
/// `specular` key sets it. `specular=0.24` makes `glossy`'s gold of roughness 0.2 (α 0.04, a
/// near-mirror whose reconnections are mostly zero or fireflies) specular: its median MSE at
/// equal time fell from 0.0145–0.0155 to 0.0121–0.0123 (two sets of 8 runs) and the kitchen
/// at 160 × 90 stayed level, but at 640 × 360 the frames cost about 10 % more and one
/// command's mean MSE came out 1.05× above path tracing, so 0.2 stays the default (RESULTS.md,
/// "A specular threshold above the near-mirrors").
pub const SPECULAR_ROUGHNESS: f32 = 0.2;
/// The shift from a donor to a receiver is defined only where the reconnection Jacobian lies
/// in `[1/JACOBIAN_MAX, JACOBIAN_MAX]` (Ouyang et al. reject reuse beyond such a bound): a
/// donor never lends a sample outside it, and counts in `Z` only for samples inside it, so the
/// estimator stays unbiased (the receiver's own samples cover everything) and loses the
/// fireflies of near-singular shifts.
pub const JACOBIAN_MAX: f32 = 10.0;

/// The reconnection Jacobian where the shift is defined, else 0.
#[inline]
fn bounded_jacobian(receiver: Vec3, donor: Vec3, y: &GiSample) -> f32 {
    let j = reconnection_jacobian(receiver, donor, y.x, y.n);
    if (1.0 / JACOBIAN_MAX..=JACOBIAN_MAX).contains(&j) {
        j
    } else {
        0.0
    }
}

pub const KIND: PassKind = PassKind {
    grammar: "restir-gi[-biased][-nrc], wsrestir-gi[-biased][-nrc]",
    about: "ReSTIR GI in screen space (restir-gi: screen neighbours) or world space \
            (wsrestir-gi: a hash grid of cells sized by eq. 11): the reconnection vertex and its \
            outgoing radiance, shifted with the reconnection Jacobian, merged by pairwise MIS; -biased: Z = sum M \
            without visibility rays; -nrc: the reconnection vertex's radiance from the cache",
    method: true,
    variants: || variants().into_iter().map(|(_, s)| s.into()).collect(),
    parse: |name| parse_variant(name, &variants(), RestirGiSettings::validate),
};

/// Every variant's name and default settings.
fn variants() -> Vec<(String, RestirGiSettings)> {
    let mut out = Vec::new();
    for reuse in [GiReuse::screen(), GiReuse::world()] {
        for biased in [false, true] {
            for cache in [false, true] {
                let set = RestirGiSettings::variant(reuse, biased, cache);
                out.push((set.base_name(), set));
            }
        }
    }
    out
}

/// Where spatial reuse finds its donors, with that kind's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GiReuse {
    /// Screen space (`restir-gi`): neighbours in a disc around the pixel.
    Screen {
        /// Spatial neighbours per pixel (0: none).
        neighbours: u32,
        /// Radius of the neighbourhood, pixels.
        radius: f32,
    },
    /// World space (`wsrestir-gi`): the previous frame's hash grid.
    World {
        /// Samples drawn from the cell (Alg. 2: 3).
        samples: u32,
        /// Projected cell size as a fraction of the image width (eq. 11's `s`: 10 %).
        cell_scale: f32,
        /// The smallest cell as a fraction of the scene box's smallest extent (1 %).
        d_min: f32,
    },
}

impl GiReuse {
    /// Screen-space reuse with the defaults (Ouyang et al.: 3 neighbours in 30 pixels).
    pub fn screen() -> Self {
        Self::Screen {
            neighbours: 3,
            radius: 30.0,
        }
    }

    /// World-space reuse with the seed paper's defaults.
    pub fn world() -> Self {
        Self::World {
            samples: 3,
            cell_scale: 0.1,
            d_min: 0.01,
        }
    }
}

/// ReSTIR GI's parameters; defaults from Ouyang et al. 2021 and the seed paper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestirGiSettings {
    /// Screen- or world-space spatial reuse.
    pub reuse: GiReuse,
    /// The reconnection vertex's radiance from the radiance source (`-nrc`).
    pub cache: bool,
    /// `Z = Σ M`: biased.
    pub biased: bool,
    /// Unbiased merges by pairwise MIS (off: 1/Z), [`reuse::Merge`].
    pub pairwise: bool,
    /// Light samples of NEE at the shading vertex `x₁` (MIS counts them).
    pub light_samples: u32,
    pub temporal: bool,
    /// The history's `M` cap (Ouyang et al.: 30 frames).
    pub m_cap: f32,
    /// Jitter camera rays in the pixel.
    pub jitter: bool,
    /// Carry `W` across a shift with the reconnection Jacobian (off: the biased shortcut of
    /// reusing `W` unchanged; an ablation and the tests' negative control).
    pub jacobian: bool,
    /// `-nrc`: ask the source again, each frame, for the radiance of the history's samples
    /// (the cache trains between frames; off: keep the answers from the frames that found
    /// them, an ablation and the refresh test's negative control).
    pub refresh: bool,
    /// Camera rays a pixel sample for the light gathered up to the shading vertex `x₁`: the
    /// emission seen directly, the emission and NEE along the specular chain before `x₁` and
    /// the direct light at `x₁` (1: the path's own alone; N: N − 1 more,
    /// [`super::split::split_camera_rays`]; 0: chosen for each frame between 2 and
    /// `split_max` by the variances and costs of the frames before, [`SplitChooser`]). The
    /// reservoir's reflected light keeps one path a frame.
    pub split: u32,
    /// The most camera rays a chosen split (`split` 0) takes.
    pub split_max: u32,
    /// The split's negative control for the tests: the path's own gathered light is kept
    /// whole beside the split's mean instead of entering it (weight (2N − 1)/N in all). No
    /// key.
    pub split_keeps_own: bool,
    /// World space: vertices of roughness below this are specular, traced through to the first
    /// vertex at or above it, which shades ([`SPECULAR_ROUGHNESS`] by default).
    pub specular: f32,
}

impl Default for RestirGiSettings {
    fn default() -> Self {
        Self {
            reuse: GiReuse::screen(),
            cache: false,
            biased: false,
            pairwise: true,
            light_samples: 1,
            temporal: true,
            m_cap: 30.0,
            jitter: true,
            jacobian: true,
            refresh: true,
            split: 1,
            split_max: 8,
            split_keeps_own: false,
            specular: SPECULAR_ROUGHNESS,
        }
    }
}

impl RestirGiSettings {
    /// A variant's defaults. World-space ReSTIR GI with traced tails splits the light gathered
    /// up to its shading vertex over two camera rays (`split=2`): measured at equal time
    /// against one ray, 1.2–1.45× lower MSE on the kitchen at 160 × 90 and 640 × 360, and
    /// lower or level on the door scenes (RESULTS.md, "Splitting the light gathered before the
    /// reservoir" and "`split=2` the default for world-space ReSTIR GI"); a count chosen each
    /// frame (`split=0`, [`SplitChooser`]) was not measured better on the kitchen ("A split
    /// chosen by variance and cost"). `-biased` shares the split's part of the estimator (the
    /// light before the reservoir) and follows; it was not measured with it. Screen space and
    /// `-nrc` (whose frames are cheaper, so an extra ray weighs more) were not measured with it
    /// and keep one.
    pub fn variant(reuse: GiReuse, biased: bool, cache: bool) -> Self {
        let world = matches!(reuse, GiReuse::World { .. });
        Self {
            reuse,
            biased,
            cache,
            split: if world && !cache { 2 } else { 1 },
            ..Default::default()
        }
    }

    /// Errors for settings that cannot work.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if self.light_samples == 0 {
            return Err(SettingsError::bounds("light samples", "be at least 1", 0));
        }
        if !(2..=MAX_COUNT).contains(&self.split_max) {
            let what = format!("be between 2 and {MAX_COUNT}");
            return Err(SettingsError::bounds("splitmax", what, self.split_max));
        }
        if self.split == 0 && !(self.is_world() && !self.cache) {
            // Tested and measured with world-space traced tails only (a cache's answers would
            // be a cost the rays do not count).
            return Err(SettingsError::bounds(
                "split",
                "be at least 1 here (0, a split chosen each frame, is for wsrestir-gi)",
                0,
            ));
        }
        match self.reuse {
            GiReuse::Screen { neighbours, radius } => {
                reuse::validate_reuse(&[neighbours, self.light_samples], radius, self.m_cap)
            }
            GiReuse::World {
                samples,
                cell_scale,
                d_min,
            } => {
                reuse::validate_reuse(&[samples, self.light_samples], 0.0, self.m_cap)?;
                if !(cell_scale > 0.0 && d_min > 0.0) {
                    return Err(SettingsError::bounds(
                        "cell scale and d_min",
                        "be positive",
                        format!("{cell_scale} and {d_min}"),
                    ));
                }
                Ok(())
            }
        }
    }

    /// World-space reuse.
    pub fn is_world(&self) -> bool {
        matches!(self.reuse, GiReuse::World { .. })
    }

    /// The variant's name, without parameters.
    fn base_name(&self) -> String {
        format!(
            "{}restir-gi{}{}",
            if self.is_world() { "ws" } else { "" },
            if self.biased { "-biased" } else { "" },
            if self.cache { "-nrc" } else { "" }
        )
    }
}

impl Params for RestirGiSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        match &mut self.reuse {
            GiReuse::Screen { neighbours, radius } => {
                let k = Key::new("k", "spatial neighbours per pixel (0: none)");
                f(&k.range(0.0, MAX), neighbours);
                let r = Key::new("radius", "radius of the neighbourhood, pixels");
                f(&r.range(0.0, f64::INFINITY), radius);
            }
            GiReuse::World {
                samples,
                cell_scale,
                d_min,
            } => {
                let k = Key::new("samples", "samples drawn from the cell (Alg. 2)");
                f(&k.range(0.0, MAX), samples);
                let c = Key::new("cell", "projected cell size, fraction of the image width");
                f(&c.positive(f64::INFINITY), cell_scale);
                let d = Key::new("dmin", "smallest cell, fraction of the scene's smallest extent");
                f(&d.positive(f64::INFINITY), d_min);
                let s = Key::new(
                    "specular",
                    "roughness below which a vertex is specular and traced through",
                );
                f(&s.range(0.0, 1.0), &mut self.specular);
            }
        }
        let mcap = Key::new("mcap", "the history's M cap, frames");
        f(&mcap.positive(f64::INFINITY), &mut self.m_cap);
        f(&Key::new("temporal", "reuse the previous frame's reservoirs"), &mut self.temporal);
        reuse::visit_pairwise(f, &mut self.pairwise);
        let nee = Key::new("nee", "light samples of NEE at the shading vertex");
        f(&nee.range(1.0, MAX), &mut self.light_samples);
        let split = Key::new(
            "split",
            "camera rays a pixel sample for the light up to the shading vertex \
             (1: the path's; 0: chosen each frame)",
        );
        f(&split.range(0.0, MAX), &mut self.split);
        let split_max = Key::new("splitmax", "the most camera rays a chosen split (split=0) takes");
        f(&split_max.range(2.0, MAX), &mut self.split_max);
        let jacobian = Key::new("jacobian", "shift W by the reconnection Jacobian (0: biased)");
        f(&jacobian, &mut self.jacobian);
        f(&Key::new("jitter", "jitter camera rays in the pixel"), &mut self.jitter);
        if self.cache {
            let refresh = Key::new("refresh", "ask the source again for the history's samples");
            f(&refresh, &mut self.refresh);
        }
    }
}

impl PassConfig for RestirGiSettings {
    /// (Measured 1,216 in screen space and 1,669 in world space, which keeps a grid entry
    /// with a vertex for each of its two vertices.)
    fn state_bytes_per_sample(&self) -> u64 {
        if self.is_world() { 1_800 } else { 1_300 }
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let reuse = match self.reuse {
            GiReuse::Screen { .. } => GiReuse::screen(),
            GiReuse::World { .. } => GiReuse::world(),
        };
        let base = RestirGiSettings::variant(reuse, self.biased, self.cache);
        super::params::name(&self.base_name(), self, &base)
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(RestirGiPass::new(*self, tracer))
    }

    fn is_stateful(&self) -> bool {
        true
    }

    fn uses_source(&self) -> bool {
        self.cache
    }

    fn params(&self) -> Vec<super::params::Param> {
        super::params::list(self)
    }
}

/// A reconnection vertex and the radiance leaving it toward the vertex that found it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GiSample {
    pub x: Vec3,
    /// Its geometric normal.
    pub n: Vec3,
    pub l: Vec3,
    /// Its triangle (to find the surface again when the history's radiance is refreshed).
    pub tri: u32,
}

pub type GiReservoir = Reservoir<GiSample>;

/// `|∂ω_receiver / ∂ω_donor|` for a sample `y` (normal `n_y`) found from `donor` and reused at
/// `receiver`: `(|cos φ_r| / |cos φ_d|) · (‖donor − y‖² / ‖receiver − y‖²)`, the angles at `y`
/// between `n_y` and the directions to the two vertices (Ouyang et al. 2021, eq. 11). 0 where
/// undefined.
#[inline]
pub fn reconnection_jacobian(receiver: Vec3, donor: Vec3, y: Vec3, n_y: Vec3) -> f32 {
    let (to_r, to_d) = (receiver - y, donor - y);
    let (dr2, dd2) = (to_r.length_squared(), to_d.length_squared());
    let cos_r = n_y.dot(to_r).abs() / dr2.sqrt();
    let cos_d = n_y.dot(to_d).abs() / dd2.sqrt();
    let j = (cos_r / cos_d) * (dd2 / dr2);
    if j.is_finite() && j > 0.0 { j } else { 0.0 }
}

/// `f · |cos| · L` of sample `y` at vertex `v` (per solid angle) and its luminance `p̂`.
#[inline]
fn contribution(v: &Vertex, y: &GiSample) -> Option<(Vec3, f32)> {
    let d = y.x - v.si.p;
    let wi = v.frame.to_local(d.normalize());
    let c = v.bsdf.eval(v.wo, wi) * wi.z.abs() * y.l;
    let t = luminance(c);
    (t > 0.0 && t.is_finite()).then_some((c, t))
}

#[inline]
fn target_at(v: &Vertex, y: &GiSample) -> f32 {
    contribution(v, y).map_or(0.0, |c| c.1)
}

/// The shading vertex `x₁` of a pixel sample and what its path gathered before it.
#[derive(Clone, Copy, Debug)]
struct Shading {
    v: Vertex,
    /// Throughput from the camera to `x₁` (1 at the primary vertex).
    throughput: Vec3,
    /// `x₁` is the primary vertex (temporal reuse applies).
    primary: bool,
    /// NEE at `x₁`.
    direct: Vec3,
    /// The initial candidate: its vertex (radiance filled in later for `-nrc`) and BSDF pdf.
    candidate: Option<(GiSample, f32)>,
    /// The candidate was drawn from a delta lobe, with this BSDF weight: it is not resampled
    /// but estimated as `weight · L(y)` beside the reservoir (whose sample is then none).
    delta: Option<Vec3>,
    /// `-nrc`: the cache query at the candidate's vertex, then its index in the frame's batch.
    query: Option<RadianceQuery>,
    query_index: Option<usize>,
}

/// One pixel sample after the trace phase.
#[derive(Clone, Copy, Debug, Default)]
struct Traced {
    /// Radiance gathered before `x₁` (emission and NEE at specular vertices, the emission
    /// the camera ray sees excluded), or the whole path tracer's estimate where there is no
    /// `x₁`.
    radiance: Vec3,
    shading: Option<Shading>,
    /// World space, traced tails, rough `x₂`: its initial sample (sample and pdf; `None`: its
    /// path found none) with its owner, for the grid.
    second: Option<(Vertex, Option<(GiSample, f32)>)>,
    /// The split's extra camera rays ([`RestirGiSettings::split`]): the sum of their
    /// estimates of the light gathered up to the shading vertex ([`Traced::gathered`]).
    split: Vec3,
    /// The sum of what the split's extra camera rays saw directly ([`split_emission`]).
    split_seen: Vec3,
    /// Rays the split's extra camera rays traced (in `stats` too).
    split_rays: u64,
    stats: PathStats,
}

impl Traced {
    /// The light the path gathers up to its shading vertex `x₁`, the direct light there
    /// included (NEE and the emission its candidate's BSDF ray finds, by MIS): all but the
    /// camera ray's own emission and the reflected light the reservoir estimates.
    fn gathered(&self) -> Vec3 {
        self.radiance + self.shading.map_or(Vec3::ZERO, |sh| sh.throughput * sh.direct)
    }
}

struct History {
    screen: reuse::History<GiSample>,
    /// World space: the frame's hash grid of reservoirs.
    world: Option<WorldHistory<GiSample>>,
}

/// The ReSTIR GI pass (screen or world space) and its history.
pub struct RestirGiPass {
    pub settings: RestirGiSettings,
    tracer: PathTracer,
    history: Option<History>,
    /// The traced frame: its G-buffer, pixel samples, history to refresh, trace time (ms) and
    /// split.
    frame: Option<(GBuffer, Vec<Traced>, Vec<(Refresh, Vertex)>, f64, u32)>,
    /// `split=0`: the split's chooser, kept across frames.
    chooser: Option<SplitChooser>,
    /// The last frame's trace buffer, its allocation reused ([`par_map_into`]).
    spare: Vec<Traced>,
}

/// A history sample to ask the source about again: a screen reservoir or a grid entry.
#[derive(Clone, Copy, Debug)]
enum Refresh {
    Reservoir(usize),
    Entry(usize),
}

impl RestirGiPass {
    pub fn new(settings: RestirGiSettings, tracer: &PathTracer) -> Self {
        Self {
            settings,
            tracer: *tracer,
            history: None,
            frame: None,
            chooser: None,
            spare: Vec::new(),
        }
    }

    /// The factor carrying a donor's `W` to the receiver: the bounded reconnection Jacobian, or
    /// 1 with the Jacobian switched off.
    fn shift_jacobian(&self, receiver: Vec3, donor: Vec3, y: &GiSample) -> f32 {
        if self.settings.jacobian {
            bounded_jacobian(receiver, donor, y)
        } else {
            1.0
        }
    }

    /// Whether `v` is rough enough to be the shading vertex.
    fn is_rough(&self, v: &Vertex) -> bool {
        !v.bsdf.is_delta()
            && (!self.settings.is_world() || v.bsdf.roughness() >= self.settings.specular)
    }

    /// The trace phase of one pixel sample: the path to `x₁`, NEE there, the initial
    /// candidate and (traced tails) its radiance; with `gather_only`, no candidate (its BSDF
    /// ray still finds the emission that completes the direct light's MIS): a split's extra
    /// camera ray, which estimates only [`Traced::gathered`].
    fn trace_one(
        &self,
        scene: &Scene,
        seed: u64,
        i: usize,
        p: Option<&Primary>,
        gather_only: bool,
    ) -> Traced {
        let mut out = Traced::default();
        let Some(p) = p else { return out };
        let mut s = stream(seed, i, Phase::Path);
        let limit = self.tracer.segment_limit();
        // The path to the first rough vertex.
        let (mut v, mut throughput, mut segments) = (p.v, Vec3::ONE, 1u32);
        if !self.is_rough(&v) {
            if !self.settings.is_world() {
                out.radiance +=
                    self.tracer
                        .reflected(scene, &v.si, v.wo_world, 1, &mut s, &mut out.stats);
                return out;
            }
            let mut walk = PathWalk::from_vertex(scene, &self.tracer, 1);
            loop {
                if walk.at_depth_limit() {
                    return out;
                }
                out.radiance +=
                    walk.throughput() * walk.next_event(scene, &v, &mut s, &mut out.stats);
                if walk.scatter(&v, &mut s).is_none() {
                    return out;
                }
                segments += 1;
                match walk.arrive(scene, &mut out.stats) {
                    Arrival::Escaped { le, mis } => {
                        out.radiance += walk.throughput() * le * mis;
                        return out;
                    }
                    Arrival::Hit(h) => {
                        out.radiance += walk.throughput() * h.le * h.mis;
                        v = h.vertex;
                        if self.is_rough(&v) {
                            throughput = walk.throughput();
                            break;
                        }
                    }
                }
            }
        }
        if segments >= limit {
            return out;
        }
        // Direct light at x₁: NEE, weighted by MIS against the candidate's BSDF sample finding
        // the emitter (the path tracer's rule; NEE alone turned glossy reflections of a small
        // bright emitter into fireflies).
        let mut walk = PathWalk::from_vertex(scene, &self.tracer, segments)
            .with_light_samples(self.settings.light_samples);
        let direct = walk.next_event(scene, &v, &mut s, &mut out.stats);
        let mut shading = Shading {
            v,
            throughput,
            primary: segments == 1,
            direct,
            candidate: None,
            delta: None,
            query: None,
            query_index: None,
        };
        // The BSDF sample: the emission it finds completes the direct light's MIS (within the
        // depth limit whenever NEE is: without it, NEE's weight alone would darken the direct
        // light at the last vertex a depth limit allows); the initial candidate where one
        // more segment is left for the indirect light beyond it.
        if segments < limit {
            let mut sc = stream(seed, i, Phase::Candidates);
            let u_lobe = sc.next_1d();
            let u_dir = sc.next_2d();
            if let Some(bs) = v.bsdf.sample(v.wo, u_dir, u_lobe).filter(|b| b.pdf > 0.0) {
                walk.follow(&v, &bs);
                let y = match walk.arrive(scene, &mut out.stats) {
                    Arrival::Escaped { le, mis } => {
                        shading.direct += bs.weight * le * mis;
                        None
                    }
                    Arrival::Hit(h) => {
                        shading.direct += bs.weight * h.le * h.mis;
                        Some(h.vertex)
                    }
                };
                if let Some(y) = y.filter(|_| segments + 1 < limit && !gather_only) {
                    let mut sample = GiSample {
                        x: y.si.p,
                        n: y.si.ng,
                        l: Vec3::ZERO,
                        tri: y.si.tri,
                    };
                    if self.settings.cache {
                        shading.query = Some(y.query());
                    } else {
                        let (l, second) =
                            self.tail(scene, &y, segments + 1, &mut sc, &mut out.stats);
                        sample.l = l;
                        // x₂'s sample has one segment less left than x₁'s: reused at another
                        // x₁ it is right only when depth is unlimited (Russian roulette alone).
                        let unlimited = self.tracer.segment_limit() == u32::MAX;
                        out.second = second
                            .filter(|_| self.settings.is_world() && unlimited && segments == 1)
                            .map(|y3| (y, y3));
                    }
                    // A delta lobe of a mixed BSDF (a smooth coat), which no reservoir can
                    // hold, is estimated whole by its sample: `weight · L(y)`.
                    if bs.delta {
                        shading.delta = Some(bs.weight);
                    }
                    shading.candidate = Some((sample, bs.pdf));
                }
            }
        }
        out.shading = Some(shading);
        out
    }

    /// The radiance leaving `y` toward the vertex before it (`segments` used to reach it),
    /// emission excluded, by a traced path; and where `y` is rough, its own initial sample
    /// (the next vertex with the radiance leaving it toward `y`, and its BSDF pdf).
    fn tail(
        &self,
        scene: &Scene,
        y: &Vertex,
        segments: u32,
        s: &mut crate::sampler::PixelSampler,
        stats: &mut PathStats,
    ) -> (Vec3, Option<Option<(GiSample, f32)>>) {
        let mut walk = PathWalk::from_vertex(scene, &self.tracer, segments);
        if walk.at_depth_limit() {
            return (Vec3::ZERO, None);
        }
        // y's own sample for the grid, where y is rough: `Some(None)` when its path found
        // none (an empty reservoir of one candidate: it counts in Z like any other).
        let rough = self.is_rough(y);
        let nee = walk.next_event(scene, y, s, stats);
        let Some(bs) = walk.scatter(y, s) else {
            return (nee, rough.then_some(None));
        };
        match walk.arrive(scene, stats) {
            Arrival::Escaped { le, mis } => (nee + bs.weight * le * mis, rough.then_some(None)),
            Arrival::Hit(h) => {
                // The walk goes on from x₃ with Russian roulette on its throughput from `y`
                // (restarted at 1 there, paths ran longer than the path tracer's: 0.5 rays
                // more a pixel sample on the kitchen). Not on the throughput from the camera:
                // `L(y)` is lent to other receivers and does not depend on which found `y`.
                // The grid's sample at x₃ (`l3`, lent too) has its roulette scaled by `y`'s
                // scattering: noisier where `y` is dark, unbiased either way.
                let l3 = self.tracer.reflected_after(
                    scene,
                    &h.vertex.si,
                    h.vertex.wo_world,
                    segments + 1,
                    walk.throughput().max_element(),
                    s,
                    stats,
                );
                let l = nee + bs.weight * (h.le * h.mis + l3);
                let sample = (!bs.delta && bs.pdf > 0.0).then_some((
                    GiSample {
                        x: h.vertex.si.p,
                        n: h.vertex.si.ng,
                        l: l3,
                        tri: h.vertex.si.tri,
                    },
                    bs.pdf,
                ));
                (l, rough.then_some(sample))
            }
        }
    }
}

/// A frame of ReSTIR GI as the reuse driver sees it: reconnection vertices at the shading
/// vertices `x₁` (temporal and screen reuse only where `x₁` is the primary vertex), shifted by
/// the bounded reconnection Jacobian.
struct GiFrame<'a> {
    pass: &'a RestirGiPass,
    scene: &'a Scene,
    traced: &'a [Traced],
}

impl Resampling for GiFrame<'_> {
    type Sample = GiSample;

    fn receiver(&self, i: usize) -> Option<&Vertex> {
        self.traced[i]
            .shading
            .as_ref()
            .filter(|sh| sh.primary)
            .map(|sh| &sh.v)
    }

    fn donor(&self, q: usize) -> Option<&Vertex> {
        self.receiver(q)
    }

    fn target(&self, v: &Vertex, y: &GiSample) -> f32 {
        target_at(v, y)
    }

    fn jacobian(&self, receiver: &Vertex, donor: &Vertex, y: &GiSample) -> f32 {
        self.pass.shift_jacobian(receiver.si.p, donor.si.p, y)
    }

    fn visible(&self, v: &Vertex, y: &GiSample, stats: &mut PathStats) -> bool {
        visible_between(self.scene, v.si.p, v.si.ng, y.x, y.n, stats)
    }

    fn merge(&self) -> Merge {
        Merge::of(self.pass.settings.biased, self.pass.settings.pairwise)
    }
}

impl RenderPass for RestirGiPass {
    fn name(&self) -> String {
        self.settings.name()
    }

    fn reset(&mut self) {
        self.history = None;
        self.chooser = None;
    }

    fn debug_views(&self) -> Vec<super::frame::PassView> {
        self.history.iter().flat_map(|h| h.screen.views()).collect()
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let scene = input.scene;
        let t = Instant::now();
        let g = GBuffer::trace(input, self.settings.jitter);
        let split = self.split();
        let extra = split.saturating_sub(1);
        let mut traced = std::mem::take(&mut self.spare);
        par_map_into(&mut traced, g.len(), |i| {
            let mut t = self.trace_one(scene, input.seed, i, g.primary[i].as_ref(), false);
            if extra > 0 {
                let jitter = self.settings.jitter;
                let mut stats = PathStats::default();
                (t.split, t.split_seen) =
                    split_camera_rays(input, i, jitter, extra, &mut stats, |p, seed, stats| {
                        let ray = self.trace_one(scene, seed, i, Some(p), true);
                        stats.add(&ray.stats);
                        ray.gathered()
                    });
                t.split_rays = stats.rays();
                t.stats.add(&stats);
            }
            t
        });
        let mut queries = Vec::new();
        for t in traced.iter_mut() {
            if let Some(sh) = &mut t.shading
                && let Some(q) = sh.query.take()
            {
                sh.query_index = Some(queries.len());
                queries.push(q);
            }
        }
        // -nrc: the history's samples carry the cache's answers from the frames that found
        // them, and the cache has trained since; each is asked again toward its owner, after
        // this frame's queries (as DDGI resampling refreshes its history, ddgi_restir.rs).
        let refresh = match self.history.as_ref().filter(|h| h.screen.g.same_shape(&g)) {
            Some(h) if self.settings.cache && self.settings.refresh => {
                self.refresh_list(scene, h)
            }
            _ => Vec::new(),
        };
        queries.extend(refresh.iter().map(|(_, v)| v.query()));
        self.frame = Some((g, traced, refresh, t.elapsed().as_secs_f64() * 1e3, split));
        queries
    }

    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput {
        if self.frame.is_none() {
            let q = self.trace(input);
            assert!(
                q.is_empty(),
                "resolve without trace needs a pass that asks no source"
            );
        }
        let (g, traced, refresh, trace_ms, split) = self.frame.take().expect("just traced");
        let scene = input.scene;
        let seed = input.seed;
        let n = g.len();
        let set = self.settings;
        let mut times = PhaseTimes {
            candidates_ms: trace_ms,
            ..Default::default()
        };

        // The initial candidate of a pixel sample, with its radiance (`-nrc`: the source's).
        let candidate = |sh: &Shading| {
            sh.candidate.map(|(mut y, pdf)| {
                if let Some(q) = sh.query_index {
                    y.l = usable_answer(answers[q]);
                }
                (y, pdf)
            })
        };
        // Initial reservoirs: one candidate, W = 1/p (none for a delta lobe's sample).
        let initial: Vec<(GiReservoir, PathStats)> = par_map(n, |i| {
            let t = &traced[i];
            let mut r = GiReservoir::new();
            if let Some(sh) = &t.shading {
                r.m = 0.0;
                match candidate(sh) {
                    Some((y, pdf)) if sh.delta.is_none() => {
                        let target = target_at(&sh.v, &y);
                        r.update(
                            y,
                            target / pdf,
                            target,
                            stream(seed, i, Phase::Extra).next_1d(),
                        );
                    }
                    _ => r.m = 1.0,
                }
                r.finish(r.m);
            }
            (r, t.stats)
        });

        // Temporal reuse, after the history's samples took the source's new answers.
        let t0 = Instant::now();
        let mut history = self.history.take();
        if let Some(h) = &mut history {
            let fresh = &answers[answers.len() - refresh.len()..];
            for (&(slot, _), &l) in refresh.iter().zip(fresh) {
                let sample = match slot {
                    Refresh::Reservoir(j) => &mut h.screen.res[j].sample,
                    Refresh::Entry(k) => match h.world.as_mut() {
                        Some(w) => &mut w.entries_mut()[k].res.sample,
                        None => continue,
                    },
                };
                if let Some(y) = sample {
                    y.l = usable_answer(l);
                }
            }
        }
        let history = history.filter(|h| h.screen.g.same_shape(&g));
        let frame = GiFrame {
            pass: self,
            scene,
            traced: &traced,
        };
        let screen = history
            .as_ref()
            .filter(|_| set.temporal)
            .map(|h| &h.screen);
        let temporal = reuse::temporal(&frame, seed, screen, set.m_cap, true, &initial);
        times.temporal_ms = t0.elapsed().as_secs_f64() * 1e3;

        // Spatial reuse: screen neighbours from the temporal buffer, or the previous grid.
        let t0 = Instant::now();
        let spatial = match set.reuse {
            GiReuse::World { samples, .. } => {
                let unlimited = self.tracer.segment_limit() == u32::MAX;
                let at = |i: usize| traced[i].shading.as_ref().map(|sh| (&sh.v, sh.primary));
                let grid = history.as_ref().and_then(|h| h.world.as_ref());
                reuse::world_spatial(
                    &frame, at, seed, grid, samples, set.m_cap, unlimited, &temporal,
                )
            }
            GiReuse::Screen { neighbours, radius } => {
                reuse::spatial(&frame, &g, seed, neighbours, radius, &temporal)
            }
        };
        times.spatial_ms = t0.elapsed().as_secs_f64() * 1e3;

        // Shading: one shadow ray for the chosen sample where spatial reuse took it from
        // another vertex. The temporal step's sample is known to be seen from `x₁`: the
        // pixel's own candidate was found by a ray from it, and a history sample taken there
        // was shadow-tested (`recheck`).
        let t0 = Instant::now();
        let shaded: Vec<(Vec3, GiReservoir, PathStats)> = par_map(n, |i| {
            let (mut r, mut stats) = spatial[i];
            let t = &traced[i];
            // The light before the reservoir, then the reflected light of the reservoir at x₁.
            let mut l = self.before_reservoir(&g, t, i, split);
            if let Some(sh) = &t.shading {
                let mut indirect = Vec3::ZERO;
                if let Some(y) = r.sample {
                    let seen = temporal[i].0.sample == Some(y)
                        || visible_between(scene, sh.v.si.p, sh.v.si.ng, y.x, y.n, &mut stats);
                    if seen {
                        indirect = contribution(&sh.v, &y).map_or(Vec3::ZERO, |c| c.0) * r.w;
                    } else {
                        r.clear_sample();
                    }
                }
                let delta = match (sh.delta, candidate(sh)) {
                    (Some(weight), Some((y, _))) => weight * y.l,
                    _ => Vec3::ZERO,
                };
                l += sh.throughput * (delta + indirect);
            }
            (l, r, stats)
        });
        times.shading_ms = t0.elapsed().as_secs_f64() * 1e3;

        // The grid for the next frame: temporal reservoirs keyed at x₁, second samples at x₂
        // (its build is counted in the spatial phase).
        let t0 = Instant::now();
        let world = match set.reuse {
            GiReuse::World {
                cell_scale, d_min, ..
            } => {
                // The last grid's entries buffer, its allocation reused.
                let spare = history.and_then(|h| h.world).map(WorldHistory::into_entries);
                let entries = spare.unwrap_or_default();
                Some(Self::world_history(input, &traced, &temporal, entries, cell_scale, d_min))
            }
            GiReuse::Screen { .. } => None,
        };
        times.spatial_ms += t0.elapsed().as_secs_f64() * 1e3;
        if self.chooser.is_some() {
            self.observe_split(&g, &traced, &shaded, split);
        }
        self.spare = traced;

        let (out, res) = super::screen::assemble(&g, input, shaded, times);
        self.history = Some(History {
            screen: reuse::History { g, res },
            world,
        });
        out
    }
}

impl RestirGiPass {
    /// The light of pixel sample `i` before the reservoir: the emission the camera sees and
    /// the light gathered up to `x₁` (the path's own, or with a split of `split` rays the mean
    /// of its camera rays').
    fn before_reservoir(&self, g: &GBuffer, t: &Traced, i: usize, split: u32) -> Vec3 {
        let n = split.max(1) as f32;
        let own = if self.settings.split_keeps_own { n } else { 1.0 };
        let seen = split_emission(g, i, split.saturating_sub(1), t.split_seen);
        seen + (own * t.gathered() + t.split) / n
    }

    /// Gives the chooser a frame of `split` camera rays a pixel sample: each pixel sample's
    /// terms ([`SplitTerms`]: its reflected light is its shaded value less the light before
    /// the reservoir, so the hot path keeps no buffer for it; the emission the rays see is
    /// left to the outline's rays, `--emitter-samples`), and the frame's cost and the split's
    /// share of it, counted in rays traced (so that a seed renders the same frames on any
    /// machine; on the kitchen at 160 × 90 the split's share by rays, 0.23 of the rest, is its
    /// share by time, 0.25).
    fn observe_split(
        &mut self,
        g: &GBuffer,
        traced: &[Traced],
        shaded: &[(Vec3, GiReservoir, PathStats)],
        split: u32,
    ) {
        let m = split.saturating_sub(1).max(1) as f32;
        let terms: Vec<SplitTerms> = (0..traced.len())
            .into_par_iter()
            .map(|i| {
                let t = &traced[i];
                SplitTerms {
                    own: t.gathered(),
                    extras: t.split / m,
                    reflected: shaded[i].0 - self.before_reservoir(g, t, i, split),
                }
            })
            .collect();
        let frame_rays = g.rays + shaded.iter().map(|s| s.2.rays()).sum::<u64>();
        let split_rays: u64 = traced.iter().map(|t| t.split_rays).sum();
        if let Some(chooser) = &mut self.chooser {
            chooser.observe(&terms, split, frame_rays as f64, split_rays as f64);
        }
    }

    /// The camera rays of the next frame's split: the fixed count, or (`split=0`) the
    /// chooser's.
    fn split(&mut self) -> u32 {
        if self.settings.split > 0 {
            return self.settings.split;
        }
        let max = self.settings.split_max;
        self.chooser.get_or_insert_with(|| SplitChooser::new(max)).rays()
    }

    /// The history's samples that reuse can reach, each with the vertex at its sample facing
    /// its owner: the screen reservoirs (with temporal reuse on) and the grid's entries.
    fn refresh_list(&self, scene: &Scene, h: &History) -> Vec<(Refresh, Vertex)> {
        let at = |y: &GiSample, owner: Vec3| {
            let wo = (owner - y.x).normalize_or_zero();
            Vertex::new(scene, &scene.interaction_at(y.tri, y.x, wo), wo)
        };
        let mut out: Vec<(Refresh, Vertex)> = Vec::new();
        if self.settings.temporal {
            let h = &h.screen;
            out.par_extend(h.res.par_iter().enumerate().filter_map(|(j, r)| {
                let y = r.sample.as_ref()?;
                let owner = h.g.primary[j].as_ref()?.v.si.p;
                Some((Refresh::Reservoir(j), at(y, owner)))
            }));
        }
        if let Some(w) = &h.world {
            out.par_extend(w.entries().par_iter().enumerate().filter_map(|(k, e)| {
                let y = e.res.sample.as_ref()?;
                Some((Refresh::Entry(k), at(y, e.owner.si.p)))
            }));
        }
        out
    }

    /// World space: the grid for the next frame, temporal reservoirs keyed at x₁ and second
    /// samples at x₂. Empty reservoirs go in too: a donor that found nothing still counts in Z
    /// (leaving them out made reuse select only lucky donors and brightened dark regions 2×).
    fn world_history(
        input: &FrameInput,
        traced: &[Traced],
        temporal: &[Slot<GiSample>],
        mut entries: Vec<Entry<GiSample>>,
        cell_scale: f32,
        d_min: f32,
    ) -> WorldHistory<GiSample> {
        entries.clear();
        for (i, t) in traced.iter().enumerate() {
            if let Some(sh) = &t.shading {
                entries.push(Entry {
                    owner: sh.v,
                    res: temporal[i].0,
                    primary: sh.primary,
                });
            }
            if let Some((owner, sample)) = t.second {
                let mut res = GiReservoir::new();
                match sample {
                    Some((y, pdf)) => {
                        let target = target_at(&owner, &y);
                        res.update(y, target / pdf, target, 0.5);
                    }
                    None => res.m = 1.0,
                }
                res.finish(1.0);
                entries.push(Entry {
                    owner,
                    res,
                    primary: false,
                });
            }
        }
        WorldHistory::build(input, entries, cell_scale, d_min)
    }
}
