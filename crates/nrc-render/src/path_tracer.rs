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
pub use crate::tracer::{LightStrategy, PathStats, PathTracer};
use crate::transport::{Arrival, PathWalk, Vertex};

impl PathTracer {
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
        self.camera_sample(scene, ray, sampler, stats).0
    }

    /// [`PathTracer::radiance`], and the part of it that the camera ray saw directly (the
    /// emission of its first hit, or the environment where it escaped), for the emitters'
    /// anti-aliasing ([`crate::emitters::supersample`]).
    pub fn camera_sample(
        &self,
        scene: &Scene,
        ray: Ray,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> (Vec3, Vec3) {
        let mut walk = PathWalk::from_ray(scene, self, ray);
        match walk.arrive(scene, stats) {
            Arrival::Escaped { le, mis } => (le * mis, le * mis),
            // Emission seen by the camera ray counts fully (no light sample could produce
            // it); accumulated first, so sums come out in the same order as along any path.
            Arrival::Hit(h) => (
                continue_path(scene, walk, h.vertex, h.le, sampler, stats),
                h.le,
            ),
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
        self.reflected_after(scene, si, wo, segments, 1.0, sampler, stats)
    }

    /// [`PathTracer::reflected`] continuing a walk that reaches `si` with `prefix` (its
    /// largest throughput channel): Russian roulette weighs the throughput since that walk's
    /// start ([`PathWalk::with_prefix`]), as if the walk went on.
    #[allow(clippy::too_many_arguments)]
    pub fn reflected_after(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        wo: Vec3,
        segments: u32,
        prefix: f32,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let walk = PathWalk::from_vertex(scene, self, segments).with_prefix(prefix);
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
