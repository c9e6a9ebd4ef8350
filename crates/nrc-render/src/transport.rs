//! The path-vertex step, written once: every camera-side path in the project (the reference
//! path tracer, the cache-terminated pass, the path-tracing producer) walks the scene through
//! a [`PathWalk`]:
//!
//! ```text
//! walk.arrive()  → Hit { vertex, emission and its MIS weight, segment length } | Escaped
//! (the caller adds the emission, tests its own termination rule)
//! walk.at_depth_limit()   the maximum-depth rule (Mitsuba's segment count)
//! walk.next_event()       direct light at the vertex (NEE), MIS-weighted against BSDF sampling
//! walk.scatter()          BSDF sample, throughput update, Russian roulette, the next ray
//! ```
//!
//! The random numbers are drawn in the same order whoever walks: three for NEE at every vertex
//! that reaches it (drawn even where NEE is skipped, so streams stay aligned whatever the
//! strategy), three for the BSDF sample, one for Russian roulette from `rr_depth` on. The
//! reference path tracer's images are bit for bit those it made before this module existed.

use glam::{Vec2, Vec3};
use nrc_scene::bsdf::{Bsdf, BsdfSample};
use nrc_scene::{LightContext, Ray, Scene, SurfaceInteraction, sampling::Frame, spawn_ray};

use crate::nee::{Counts, emission_mis_weight, environment_mis_weight, next_event};
use crate::query::RadianceQuery;
use crate::sampler::{MAX_STRATA, PixelSampler, stratified_pairs};
use crate::tracer::{GLOSSY_ROUGHNESS, LightStrategy, PathStats, PathTracer};

/// A surface vertex of a path, with its BSDF in its shading frame.
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    pub si: SurfaceInteraction,
    pub bsdf: Bsdf,
    pub frame: Frame,
    /// The direction the radiance is wanted in (toward the previous vertex, unless the walk
    /// started here with another), in the shading frame.
    pub wo: Vec3,
    /// The same direction in world space.
    pub wo_world: Vec3,
}

impl Vertex {
    /// The vertex at `si`, asked for the radiance leaving toward `wo_world` (unit).
    pub fn new(scene: &Scene, si: &SurfaceInteraction, wo_world: Vec3) -> Self {
        let bsdf = Bsdf::from_pbr(&scene.pbr(si));
        let frame = Frame::from_normal(si.ns);
        Self {
            si: *si,
            bsdf,
            frame,
            wo: frame.to_local(wo_world),
            wo_world,
        }
    }

    /// The radiance query of this vertex (toward `wo_world`).
    pub fn query(&self) -> RadianceQuery {
        RadianceQuery::at(&self.si, &self.bsdf, self.wo_world)
    }
}

/// What the segment just traced reached.
#[derive(Clone, Copy, Debug)]
pub enum Arrival {
    /// A surface.
    Hit(Hit),
    /// Nothing: the path left the scene and sees the environment's radiance `le`, with its
    /// MIS weight against NEE at the previous vertex; the path's radiance gains
    /// `throughput · le · mis`.
    Escaped { le: Vec3, mis: f32 },
}

/// A surface reached by a segment.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub vertex: Vertex,
    /// The emission of the surface toward the path (zero for non-emitters) ...
    pub le: Vec3,
    /// ... and its MIS weight against NEE at the previous vertex (1 where NEE could not have
    /// found it). The path's radiance gains `throughput · le · mis`.
    pub mis: f32,
    /// Length of the segment.
    pub dist: f32,
    /// Solid-angle density with which the previous vertex sampled the segment; `None` for the
    /// first segment and after delta scattering (the area-spread heuristic's input).
    pub prev_pdf: Option<f32>,
}

/// A BSDF sample taken by [`PathWalk::scatter`].
#[derive(Clone, Copy, Debug)]
pub struct Scatter {
    /// `f |cos| / p`, divided by the Russian-roulette survival probability where that applied:
    /// the factor by which the throughput grew.
    pub weight: Vec3,
    /// Solid-angle density of the sampled direction.
    pub pdf: f32,
    pub delta: bool,
}

/// One path being traced: its throughput, segment count and the previous scattering event.
#[derive(Clone, Copy, Debug)]
pub struct PathWalk {
    tracer: PathTracer,
    /// NEE runs at non-delta vertices (the strategy allows it and the scene has lights).
    use_nee: bool,
    ray: Ray,
    throughput: Vec3,
    /// How much of its caller's path reaches the walk's start, as one positive number (1 for
    /// a camera ray): Russian roulette's survival probability is `prefix · max throughput`,
    /// so that a walk continuing another walk's vertex ends as that walk would have.
    prefix: f32,
    prev_pdf: f32,
    prev_delta: bool,
    /// The previous scattering vertex, for the light sampler's density there.
    prev_at: LightContext,
    /// Segments used, including the one in flight.
    segments: u32,
    /// Light samples NEE takes at each vertex (their MIS against BSDF sampling counts them).
    light_samples: u32,
    /// Light samples NEE took at the latest vertex: `light_samples`, or more at the walk's first
    /// vertex ([`PathTracer::direct_samples`]; set by [`PathWalk::next_event`], read by the
    /// next [`PathWalk::arrive`]).
    nee_samples: u32,
    /// BSDF samples of the direct light at the latest vertex: 1, or more where
    /// [`PathTracer::glossy_samples`] applied there (set by [`PathWalk::next_event`], read by
    /// the next [`PathWalk::arrive`]).
    bsdf_samples: u32,
    limit: u32,
    /// End the path when its throughput from the start is zero (rendering); training-record
    /// producers keep going, since a later vertex's own record does not depend on it.
    zero_throughput_ends: bool,
}

impl PathWalk {
    /// A path whose first segment is `ray` (a camera ray, or any ray whose first hit counts
    /// fully: emission found by it has weight 1).
    pub fn from_ray(scene: &Scene, tracer: &PathTracer, ray: Ray) -> Self {
        Self {
            tracer: *tracer,
            use_nee: tracer.strategy != LightStrategy::BsdfOnly && scene.light_count() > 0,
            ray,
            throughput: Vec3::ONE,
            prefix: 1.0,
            prev_pdf: 0.0,
            prev_delta: true,
            prev_at: LightContext::new(Vec3::ZERO, Vec3::ZERO),
            segments: 1,
            light_samples: 1,
            nee_samples: 1,
            bsdf_samples: 1,
            limit: tracer.segment_limit(),
            zero_throughput_ends: true,
        }
    }

    /// The same walk for a producer of per-vertex training records: a zero throughput from the
    /// path's start does not end it (each vertex's record needs only its own continuation);
    /// Russian roulette, relative to that throughput, still ends it from `rr_depth` on.
    pub fn for_records(self) -> Self {
        Self {
            zero_throughput_ends: false,
            ..self
        }
    }

    /// A path that has used `segments` segments (at least 1) to reach the vertex it continues
    /// from; the caller starts with [`PathWalk::next_event`] and [`PathWalk::scatter`] there.
    pub fn from_vertex(scene: &Scene, tracer: &PathTracer, segments: u32) -> Self {
        Self {
            segments: segments.max(1),
            ..Self::from_ray(scene, tracer, Ray::new(Vec3::ZERO, Vec3::Z))
        }
    }

    /// The same walk continuing a path that reaches its start with `prefix` (the caller's
    /// largest throughput channel): Russian roulette weighs `prefix` times the walk's own
    /// throughput. A walk restarted at 1 at a later vertex survives longer than the walk it
    /// continues, at the cost of more rays. Any survival probability in (0, 1] keeps the
    /// estimate unbiased; a scalar keeps it above 0 wherever the walk's own throughput is
    /// (per channel, a caller lit only in red times a walk carrying only green would end
    /// every walk). A prefix that is not positive and finite counts as 1.
    pub fn with_prefix(self, prefix: f32) -> Self {
        let prefix = if prefix > 0.0 && prefix.is_finite() {
            prefix
        } else {
            1.0
        };
        Self { prefix, ..self }
    }

    /// The throughput of the path up to its latest vertex (or segment in flight), from the
    /// walk's start.
    pub fn throughput(&self) -> Vec3 {
        self.throughput
    }

    /// Traces the segment in flight.
    pub fn arrive(&mut self, scene: &Scene, stats: &mut PathStats) -> Arrival {
        stats.closest_rays += 1;
        let ray = self.ray;
        let Some(hit) = scene.intersect(&ray) else {
            let d = ray.d.normalize();
            let le = scene.environment().radiance(d);
            let mis = if le == Vec3::ZERO {
                0.0
            } else if self.tracer.strategy == LightStrategy::LightOnly
                && self.use_nee
                && !self.prev_delta
                && scene.environment_light_pdf(&self.prev_at, d) > 0.0
            {
                0.0
            } else {
                environment_mis_weight(
                    scene,
                    &self.prev_at,
                    d,
                    self.prev_pdf,
                    self.counts(),
                    self.prev_delta || !self.use_nee,
                )
            };
            return Arrival::Escaped { le, mis };
        };
        let si = scene.interaction(&ray, &hit);
        let dist = hit.t * ray.d.length();
        let le = scene.emission(&si);
        // Emission found by the ray, weighted against NEE finding it (the solid-angle density
        // of the sampled direction, and whether it was a delta lobe).
        let mis = if le == Vec3::ZERO {
            0.0
        } else if self.tracer.strategy == LightStrategy::LightOnly
            && self.use_nee
            && !self.prev_delta
            && scene.light_pdf_area(&self.prev_at, si.tri) > 0.0
        {
            // NEE alone accounts for emitters it can reach after non-delta scattering.
            0.0
        } else {
            emission_mis_weight(
                scene,
                &self.prev_at,
                &si,
                dist,
                self.prev_pdf,
                self.counts(),
                self.prev_delta || !self.use_nee,
            )
        };
        // The new vertex's own direct light starts at one BSDF sample and the walk's light
        // samples.
        self.bsdf_samples = 1;
        self.nee_samples = self.light_samples;
        Arrival::Hit(Hit {
            vertex: Vertex::new(scene, &si, si.wo),
            le,
            mis,
            dist,
            prev_pdf: (!self.prev_delta).then_some(self.prev_pdf),
        })
    }

    /// The same walk taking `n` (at least 1) light samples per NEE, weighed against BSDF
    /// sampling by the power heuristic with the counts (Veach 1997, §9.2): more shadow rays
    /// where the direct light is the noise, none of the path's further bounces.
    pub fn with_light_samples(self, n: u32) -> Self {
        Self {
            light_samples: n.max(1),
            nee_samples: n.max(1),
            ..self
        }
    }

    /// Whether a further segment would exceed the maximum depth.
    pub fn at_depth_limit(&self) -> bool {
        self.segments >= self.limit
    }

    /// Next-event estimation at `v` (zero at delta vertices or with NEE off): the direct light
    /// leaving `v` toward its `wo`, not yet multiplied by the throughput, the mean of the
    /// vertex's light samples (the walk's, or [`PathTracer::direct_samples`] at its first
    /// vertex, stratified together there). Draws three numbers per light sample (two for a
    /// stratified set) whether NEE runs or not.
    pub fn next_event(
        &mut self,
        scene: &Scene,
        v: &Vertex,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let first = self.segments == 1;
        let n = if first {
            self.light_samples.max(self.tracer.direct_samples)
        } else {
            self.light_samples
        };
        // The first vertex's own count stratified together; a pass's count elsewhere (and a
        // set larger than the strata allow) independent, as before.
        let stratify = first && n > self.light_samples && self.tracer.stratified && n <= MAX_STRATA;
        self.nee_samples = n;
        let extra = self.glossy_samples_at(v);
        self.bsdf_samples = 1 + extra;
        let nee_runs = self.use_nee && !v.bsdf.is_delta();
        let mis = self.tracer.strategy == LightStrategy::Mis;
        let counts = self.counts();
        let one = |u_light: f32, u_point: Vec2, stats: &mut PathStats| {
            if nee_runs {
                next_event(
                    scene, &v.si, &v.bsdf, &v.frame, v.wo, mis, counts, u_light, u_point, stats,
                )
            } else {
                Vec3::ZERO
            }
        };
        let nee = if stratify {
            stratified_pairs(n, sampler)
                .map(|(u_light, u_point)| one(u_light, u_point, stats))
                .sum::<Vec3>()
                / n as f32
        } else if n == 1 {
            // The path tracer's case: no averaging on its hot path.
            let u_light = sampler.next_1d();
            one(u_light, sampler.next_2d(), stats)
        } else {
            (0..n)
                .map(|_| {
                    let u_light = sampler.next_1d();
                    one(u_light, sampler.next_2d(), stats)
                })
                .sum::<Vec3>()
                / n as f32
        };
        if !nee_runs || extra == 0 {
            return nee;
        }
        nee + self.glossy_direct(scene, v, extra, sampler, stats)
    }

    /// The samples of each strategy at the latest vertex, for MIS.
    fn counts(&self) -> Counts {
        Counts {
            light: self.nee_samples as f32,
            bsdf: self.bsdf_samples as f32,
        }
    }

    /// [`PathTracer::glossy_samples`] where they apply at `v`: the walk's first vertex, glossy and
    /// not a pure delta, with NEE and MIS on; else 0.
    fn glossy_samples_at(&self, v: &Vertex) -> u32 {
        let on = self.tracer.glossy_samples > 0
            && self.segments == 1
            && self.use_nee
            && self.tracer.strategy == LightStrategy::Mis
            && !v.bsdf.is_delta()
            && v.bsdf.roughness() < GLOSSY_ROUGHNESS;
        if on { self.tracer.glossy_samples } else { 0 }
    }

    /// The `extra` BSDF samples of the direct light at `v` ([`PathTracer::glossy_samples`]),
    /// summed. Stratified (unless [`PathTracer::stratified`] is off): the directions'
    /// numbers one in each of `extra` distinct cells of a `⌈√extra⌉²` grid, the lobe choices one
    /// in each of `extra` strata in random order ([`stratified_pairs`]). A sample at a random
    /// index has uniform numbers, so the sum is the independent samples' in expectation; where the lobe sees an edge (the window's bars behind a glossy table)
    /// only the cells the edge cuts keep its variance. Draws two numbers of `sampler`
    /// (independent samples: three per sample).
    fn glossy_direct(
        &self,
        scene: &Scene,
        v: &Vertex,
        extra: u32,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        // Beyond MAX_STRATA a stratified set would be cut short while the MIS counts take
        // them all: independent samples there (the CLI allows 64).
        if !self.tracer.stratified || extra > MAX_STRATA {
            return (0..extra)
                .map(|_| {
                    let u_lobe = sampler.next_1d();
                    let u_dir = sampler.next_2d();
                    self.glossy_sample(scene, v, u_lobe, u_dir, stats)
                })
                .sum();
        }
        stratified_pairs(extra, sampler)
            .map(|(u_lobe, u_dir)| self.glossy_sample(scene, v, u_lobe, u_dir, stats))
            .sum()
    }

    /// One more BSDF sample of the direct light at `v`, from the numbers `u_lobe`, `u_dir`: one
    /// segment, followed and weighed as the path's own sample would be (on a copy of the walk,
    /// whose count of BSDF samples is already `counts.bsdf`), its emission only.
    fn glossy_sample(
        &self,
        scene: &Scene,
        v: &Vertex,
        u_lobe: f32,
        u_dir: Vec2,
        stats: &mut PathStats,
    ) -> Vec3 {
        let Some(bs) = v.bsdf.sample(v.wo, u_dir, u_lobe) else {
            return Vec3::ZERO;
        };
        let mut walk = *self;
        walk.follow(v, &bs);
        match walk.arrive(scene, stats) {
            Arrival::Escaped { le, mis } => bs.weight * le * mis,
            Arrival::Hit(h) => bs.weight * h.le * h.mis,
        }
    }

    /// Continues the path from `v` along the BSDF sample `bs` drawn there (no Russian
    /// roulette): the next [`PathWalk::arrive`] traces it and weighs the emission it finds
    /// against NEE at `v` by `bs`'s density. For passes that sample the BSDF themselves.
    pub fn follow(&mut self, v: &Vertex, bs: &BsdfSample) {
        self.throughput *= bs.weight;
        self.ray = spawn_ray(v.si.p, v.si.ng, v.frame.to_world(bs.wi));
        self.segments += 1;
        self.prev_pdf = bs.pdf;
        self.prev_delta = bs.delta;
        self.prev_at = LightContext::new(v.si.p, v.si.ns);
    }

    /// Samples the BSDF at `v` for the next segment, updates the throughput and applies
    /// Russian roulette (Mitsuba's rule: from `rr_depth` scattering events on, continue with
    /// probability min(max throughput, 0.95), the throughput scaled by
    /// [`PathWalk::with_prefix`]'s, and divide by it, which keeps the estimate unbiased).
    /// `None`: the path ends here (no sample, zero throughput, or roulette).
    pub fn scatter(&mut self, v: &Vertex, sampler: &mut PixelSampler) -> Option<Scatter> {
        let u_lobe = sampler.next_1d();
        let u_dir = sampler.next_2d();
        let bs = v.bsdf.sample(v.wo, u_dir, u_lobe)?;
        self.follow(v, &bs);
        if self.zero_throughput_ends && self.throughput == Vec3::ZERO {
            return None;
        }
        let mut weight = bs.weight;
        // Scattering events so far (segments − 1) at least rr_depth.
        if self.segments > self.tracer.rr_depth {
            let q = (self.prefix * self.throughput.max_element()).min(0.95);
            if q.is_nan() || q <= 0.0 || sampler.next_1d() >= q {
                return None;
            }
            self.throughput /= q;
            weight /= q;
        }
        Some(Scatter {
            weight,
            pdf: bs.pdf,
            delta: bs.delta,
        })
    }
}
