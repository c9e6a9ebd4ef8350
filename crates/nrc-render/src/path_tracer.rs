//! The unbiased reference path tracer.
//!
//! Unidirectional path tracing with next-event estimation (NEE) over the scene's emissive
//! triangles (chosen in proportion to emitted power, a point uniform on the triangle),
//! BSDF importance sampling, and multiple importance sampling of the two with the power
//! heuristic (Veach 1997, ch. 9). Specular (delta) scattering skips NEE, and emission
//! found after it counts fully. Paths end by Russian roulette on the throughput, at the
//! maximum depth, or when they escape to the constant background.
//!
//! Depth counts path *segments* as Mitsuba 3's `path` integrator does, so that a render
//! agrees with Mitsuba's at the same `max_depth`: 1 shows emitters seen directly, 2 adds
//! direct illumination, 3 one indirect bounce, and so on.

use glam::Vec3;
use nrc_scene::{
    Ray, Scene, SurfaceInteraction,
    bsdf::Bsdf,
    sampling::{Frame, power_heuristic},
    spawn_ray, spawn_ray_between,
};

use crate::sampler::PixelSampler;

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
    /// The maximum number of segments as an unsigned bound (`u32::MAX` for unlimited).
    fn segment_limit(&self) -> u32 {
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
        stats.closest_rays += 1;
        let Some(hit) = scene.intersect(&ray) else {
            // Escaped: constant background radiance (not light-sampled, so weight 1).
            return scene.background;
        };
        let si = scene.interaction(&ray, &hit);
        // Emission seen by the camera ray counts fully (no light sample could produce it);
        // the ray is the path's first segment.
        // (Accumulated first, so sums come out in the same order as along any path.)
        self.continue_path(scene, &si, si.wo, 1, scene.emission(&si), sampler, stats)
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
        self.continue_path(scene, si, wo, segments, Vec3::ZERO, sampler, stats)
    }

    /// [`PathTracer::reflected`] added onto `radiance` (what the path found before `si`).
    fn continue_path(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        wo: Vec3,
        segments: u32,
        mut radiance: Vec3,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let limit = self.segment_limit();
        let use_nee = self.strategy != LightStrategy::BsdfOnly && scene.light_count() > 0;
        let mut throughput = Vec3::ONE;
        let (mut si, mut wo_world) = (*si, wo);
        let mut segments = segments.max(1);
        // Scattering events so far.
        let mut depth = segments - 1;
        loop {
            // A further segment would exceed the maximum depth.
            if segments >= limit {
                break;
            }

            let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
            let frame = Frame::from_normal(si.ns);
            let wo = frame.to_local(wo_world);

            // Next-event estimation: one point on an emitter, chosen by power.
            if use_nee && !bsdf.is_delta() {
                let mis = self.strategy == LightStrategy::Mis;
                radiance +=
                    throughput * next_event(scene, &si, &bsdf, &frame, wo, mis, sampler, stats);
            } else {
                // Keep the random stream aligned whatever the strategy.
                sampler.next_1d();
                sampler.next_2d();
            }

            // BSDF sampling: the direction of the next segment.
            let u_lobe = sampler.next_1d();
            let u_dir = sampler.next_2d();
            let Some(bs) = bsdf.sample(wo, u_dir, u_lobe) else {
                break;
            };
            throughput *= bs.weight;
            let ray = spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
            depth += 1;
            segments += 1;
            if throughput == Vec3::ZERO {
                break;
            }

            // Russian roulette (Mitsuba's rule): from `rr_depth` on, continue with
            // probability min(max throughput, 0.95) and divide by it, which keeps the
            // estimate unbiased.
            if depth >= self.rr_depth {
                let q = throughput.max_element().min(0.95);
                if sampler.next_1d() >= q {
                    break;
                }
                throughput /= q;
            }

            stats.closest_rays += 1;
            let Some(hit) = scene.intersect(&ray) else {
                // Escaped: constant background radiance (not light-sampled, so weight 1).
                radiance += throughput * scene.background;
                break;
            };
            si = scene.interaction(&ray, &hit);
            wo_world = si.wo;

            // Emission found by the ray, weighted against NEE finding it (the solid-angle
            // density of the sampled direction, and whether it was a delta lobe).
            let le = scene.emission(&si);
            if le != Vec3::ZERO {
                let weight = if self.strategy == LightStrategy::LightOnly
                    && use_nee
                    && !bs.delta
                    && scene.light_pdf_area(si.tri) > 0.0
                {
                    0.0
                } else {
                    emission_mis_weight(
                        scene,
                        &si,
                        hit.t * ray.d.length(),
                        bs.pdf,
                        bs.delta || !use_nee,
                    )
                };
                radiance += throughput * le * weight;
            }
        }
        radiance
    }
}

/// The MIS weight (power heuristic) of emission found at `si` by a ray of length `dist` that
/// BSDF sampling at the previous vertex chose with solid-angle density `prev_pdf`, against NEE
/// choosing the same point. `force_one`: the previous event could not have been light-sampled
/// (a camera ray, delta scattering, or NEE off), so the emission counts fully.
#[inline]
pub fn emission_mis_weight(
    scene: &Scene,
    si: &SurfaceInteraction,
    dist: f32,
    prev_pdf: f32,
    force_one: bool,
) -> f32 {
    // Area density with which NEE picks this point (0: NEE cannot reach it).
    let pdf_area = scene.light_pdf_area(si.tri);
    if force_one || pdf_area == 0.0 {
        return 1.0;
    }
    // Density with which NEE would have chosen this point, per solid angle at the previous
    // vertex.
    let cos_light = si.ng.dot(si.wo).abs();
    let pdf_light = pdf_area * dist * dist / cos_light;
    power_heuristic(1.0, prev_pdf, 1.0, pdf_light)
}

/// Next-event estimation at a non-delta vertex: one point on an emitter chosen by power,
/// its unoccluded contribution `f · Le · |cos| / pdf`, weighted against BSDF sampling by the
/// power heuristic when `mis` (else weight 1). Draws three numbers from `sampler` always.
#[inline]
pub fn next_event(
    scene: &Scene,
    si: &SurfaceInteraction,
    bsdf: &Bsdf,
    frame: &Frame,
    wo: Vec3,
    mis: bool,
    sampler: &mut PixelSampler,
    stats: &mut PathStats,
) -> Vec3 {
    let u_light = sampler.next_1d();
    let u_point = sampler.next_2d();
    let Some(ls) = scene.sample_light(u_light, u_point) else {
        return Vec3::ZERO;
    };
    let to_light = ls.p - si.p;
    let dist2 = to_light.length_squared();
    let wi = to_light / dist2.sqrt();
    // Cosine at the light, and its radiance toward the shading point (zero behind a
    // single-sided emitter).
    let cos_light = ls.n.dot(-wi).abs();
    let le = ls.le_toward(-wi);
    let wi_local = frame.to_local(wi);
    let f = bsdf.eval(wo, wi_local) * wi_local.z.abs();
    // Test visibility only for samples that can contribute.
    if ls.pdf_area <= 0.0 || cos_light <= 0.0 || le == Vec3::ZERO || f == Vec3::ZERO {
        return Vec3::ZERO;
    }
    stats.shadow_rays += 1;
    if scene.occluded(&spawn_ray_between(si.p, si.ng, ls.p, ls.n)) {
        return Vec3::ZERO;
    }
    // Area density to solid angle at the shading point.
    let pdf_light = ls.pdf_area * dist2 / cos_light;
    let weight = if mis {
        power_heuristic(1.0, pdf_light, 1.0, bsdf.pdf(wo, wi_local))
    } else {
        1.0
    };
    f * le * (weight / pdf_light)
}
