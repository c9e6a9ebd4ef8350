//! Next-event estimation: direct light sampled at a path vertex, and the multiple-importance
//! weight of emission found by BSDF sampling against it (Veach 1997, ch. 9, the power
//! heuristic). ReSTIR DI's resampled candidates will sit beside this one-sample estimator.

use glam::Vec3;
use nrc_scene::{
    Scene, SurfaceInteraction,
    bsdf::Bsdf,
    sampling::{Frame, power_heuristic},
    spawn_ray_between,
};

use crate::path_tracer::PathStats;
use crate::sampler::PixelSampler;

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
