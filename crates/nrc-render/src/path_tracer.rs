//! The unbiased reference path tracer.
//!
//! Unidirectional path tracing (the walk itself is [`crate::transport::PathWalk`]) with next-event estimation (NEE) over the scene's emissive
//! triangles (chosen in proportion to emitted power, a point uniform on the triangle),
//! BSDF importance sampling, and multiple importance sampling of the two with the power
//! heuristic (Veach 1997, ch. 9). Specular (delta) scattering skips NEE, and emission
//! found after it counts fully. Paths end by Russian roulette on the throughput, at the
//! maximum depth, or when they escape to the environment.
//!
//! Depth counts path *segments* as Mitsuba 3's `path` integrator does, so that a render
//! agrees with Mitsuba's at the same `max_depth`: 1 shows emitters seen directly, 2 adds
//! direct illumination, 3 one indirect bounce, and so on.

use glam::Vec3;
use nrc_scene::{Ray, Scene, SurfaceInteraction};

use crate::sampler::PixelSampler;
use crate::transport::{Arrival, PathWalk, Vertex};

/// Which estimators of direct illumination a path uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightStrategy {
    /// NEE and BSDF sampling combined by multiple importance sampling (the default).
    #[default]
    Mis,
    /// BSDF sampling alone: emitters count only when a scattered ray hits them (NEE off).
    BsdfOnly,
    /// NEE alone: emitters hit by rays scattered from non-delta surfaces are ignored (they
    /// are accounted for by the light sample). Emitters seen by the camera or through delta
    /// scattering still count, as no light sample can reach them.
    LightOnly,
}

/// Settings of the path tracer (per-path behaviour, not the image).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathTracer {
    /// Maximum number of path segments, Mitsuba's convention: 1 = emitters seen directly,
    /// 2 = plus direct illumination, ... `0` or negative: unlimited (Russian roulette ends
    /// paths).
    pub max_depth: i32,
    /// Depth (in scattering events) from which Russian roulette may end a path; Mitsuba's
    /// `rr_depth` (default 5).
    pub rr_depth: u32,
    /// Estimators of direct illumination.
    pub strategy: LightStrategy,
}

impl Default for PathTracer {
    fn default() -> Self {
        Self {
            max_depth: -1,
            rr_depth: 5,
            strategy: LightStrategy::Mis,
        }
    }
}

/// Counters a path adds to (for rays/s statistics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathStats {
    /// Closest-hit rays traced.
    pub closest_rays: u64,
    /// Shadow (occlusion) rays traced.
    pub shadow_rays: u64,
}

impl PathStats {
    /// All rays traced.
    pub fn rays(&self) -> u64 {
        self.closest_rays + self.shadow_rays
    }

    /// Adds another set of counters to this one.
    pub fn add(&mut self, o: &PathStats) {
        self.closest_rays += o.closest_rays;
        self.shadow_rays += o.shadow_rays;
    }
}

impl PathTracer {
    /// The maximum number of segments as an unsigned bound (`u32::MAX` for unlimited): the
    /// one place where `max_depth` is interpreted.
    pub fn segment_limit(&self) -> u32 {
        if self.max_depth <= 0 {
            u32::MAX
        } else {
            self.max_depth as u32
        }
    }

    /// One sample of the radiance arriving at `ray.o` along `-ray.d`: the estimate of one
    /// path started with `ray`. Allocation-free; the random numbers come from `sampler`.
    ///
    /// `ray` is treated as a camera ray: emission it finds counts fully (no strategy could
    /// have sampled it otherwise), and it is the path's first segment for `max_depth`.
    /// With unlimited depth, paths end only by Russian roulette (which ends at least 5% of
    /// paths per scattering event from `rr_depth` on) or by escaping, so `rr_depth` bounds
    /// the cost of a path in a closed, lossless scene.
    pub fn radiance(
        &self,
        scene: &Scene,
        ray: Ray,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let mut walk = PathWalk::from_ray(scene, self, ray);
        match walk.arrive(scene, stats) {
            Arrival::Escaped { le, mis } => le * mis,
            // Emission seen by the camera ray counts fully (no light sample could produce
            // it); accumulated first, so sums come out in the same order as along any path.
            Arrival::Hit(h) => continue_path(scene, walk, h.vertex, h.le, sampler, stats),
        }
    }

    /// One sample of the radiance leaving the surface point `si` toward `wo` (unit, world
    /// space), the point's own emission excluded, for a path that has already used `segments`
    /// segments to reach `si` (1 for a camera primary hit; they count toward `max_depth` and
    /// `segments − 1` scattering events toward `rr_depth`). The loop of [`PathTracer::radiance`]
    /// after its first hit; producers that need the radiance of a point in a chosen direction
    /// call it directly.
    pub fn reflected(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        wo: Vec3,
        segments: u32,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let walk = PathWalk::from_vertex(scene, self, segments);
        let v = Vertex::new(scene, si, wo);
        continue_path(scene, walk, v, Vec3::ZERO, sampler, stats)
    }
}

impl PathTracer {
    /// One sample of the *indirect* radiance leaving vertex `v` toward its `wo`: the path
    /// continued from `v` by BSDF sampling, with `v`'s direct light left out (NEE at `v`, and
    /// the emission or environment its first segment reaches), everything after counted as
    /// [`PathTracer::radiance`] counts it. For passes that estimate `v`'s direct light
    /// themselves (ReSTIR DI). `segments`: as for [`PathTracer::reflected`].
    pub fn indirect(
        &self,
        scene: &Scene,
        v: &Vertex,
        segments: u32,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let mut walk = PathWalk::from_vertex(scene, self, segments);
        if walk.at_depth_limit() || walk.scatter(v, sampler).is_none() {
            return Vec3::ZERO;
        }
        match walk.arrive(scene, stats) {
            Arrival::Escaped { .. } => Vec3::ZERO,
            Arrival::Hit(h) => continue_path(scene, walk, h.vertex, Vec3::ZERO, sampler, stats),
        }
    }
}

/// The walk from vertex `v` on, added onto `radiance` (what the path found before `v`).
fn continue_path(
    scene: &Scene,
    mut walk: PathWalk,
    mut v: Vertex,
    mut radiance: Vec3,
    sampler: &mut PixelSampler,
    stats: &mut PathStats,
) -> Vec3 {
    loop {
        if walk.at_depth_limit() {
            break;
        }
        radiance += walk.throughput() * walk.next_event(scene, &v, sampler, stats);
        if walk.scatter(&v, sampler).is_none() {
            break;
        }
        match walk.arrive(scene, stats) {
            Arrival::Escaped { le, mis } => {
                radiance += walk.throughput() * le * mis;
                break;
            }
            Arrival::Hit(h) => {
                if h.le != Vec3::ZERO {
                    radiance += walk.throughput() * h.le * h.mis;
                }
                v = h.vertex;
            }
        }
    }
    radiance
}
