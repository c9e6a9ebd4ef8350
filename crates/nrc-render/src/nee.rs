//! Next-event estimation: direct light sampled at a path vertex, and the multiple-importance
//! weight of emission found by BSDF sampling against it (Veach 1997, ch. 9, the power
//! heuristic). ReSTIR DI's resampled candidates will sit beside this one-sample estimator.

use glam::Vec3;
use nrc_scene::{
    LightContext, Scene, SurfaceInteraction,
    bsdf::Bsdf,
    sampling::{Frame, power_heuristic},
};

use crate::tracer::PathStats;

/// How many samples each strategy took at the previous vertex: `light` NEE samples and `bsdf`
/// BSDF samples (the path's own and any [`crate::PathTracer::glossy_samples`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Counts {
    pub light: f32,
    pub bsdf: f32,
}

impl Counts {
    /// One sample of each.
    pub const ONE: Counts = Counts {
        light: 1.0,
        bsdf: 1.0,
    };
}

/// The factor of emission found at `si` by one of the previous vertex's BSDF samples (a ray of
/// length `dist`, chosen with solid-angle density `prev_pdf` at `from`): its MIS weight (power
/// heuristic with the counts) against NEE choosing the same point, over the number of BSDF
/// samples (they are averaged). `force_one`: the previous event could not have been
/// light-sampled (a camera ray, delta scattering, or NEE off), so the emission counts fully.
#[inline]
pub fn emission_mis_weight(
    scene: &Scene,
    from: &LightContext,
    si: &SurfaceInteraction,
    dist: f32,
    prev_pdf: f32,
    counts: Counts,
    force_one: bool,
) -> f32 {
    // Area density with which NEE picks this point (0: NEE cannot reach it).
    let pdf_area = scene.light_pdf_area(from, si.tri);
    if force_one || pdf_area == 0.0 {
        return 1.0 / counts.bsdf;
    }
    // Density with which NEE would have chosen this point, per solid angle at the previous
    // vertex.
    let cos_light = si.ng.dot(si.wo).abs();
    let pdf_light = pdf_area * dist * dist / cos_light;
    power_heuristic(counts.bsdf, prev_pdf, counts.light, pdf_light) / counts.bsdf
}

/// The MIS weight (power heuristic) of environment radiance reached by a ray leaving in unit
/// direction `d` that BSDF sampling chose with solid-angle density `prev_pdf`, against NEE
/// choosing the same direction. `light_samples` and `force_one` as for
/// [`emission_mis_weight`].
#[inline]
pub fn environment_mis_weight(
    scene: &Scene,
    from: &LightContext,
    d: Vec3,
    prev_pdf: f32,
    counts: Counts,
    force_one: bool,
) -> f32 {
    let pdf_light = scene.environment_light_pdf(from, d);
    if force_one || pdf_light == 0.0 {
        return 1.0 / counts.bsdf;
    }
    power_heuristic(counts.bsdf, prev_pdf, counts.light, pdf_light) / counts.bsdf
}

/// Next-event estimation at a non-delta vertex: one light sample chosen by the scene's light
/// sampler for this point (a point on
/// an emissive triangle, a punctual light, or an environment direction), its unoccluded
/// contribution `f · L_i · |cos| / pdf`, weighted against BSDF sampling by the power heuristic
/// when `mis` (else weight 1; delta lights always have weight 1, BSDF sampling cannot find
/// them), as one of `counts.light` such samples (the caller averages them; the heuristic counts
/// them and the `counts.bsdf` BSDF samples). `u_light` chooses the light, `u_point` the point on
/// it (callers draw them whether or not NEE runs, so that their random streams stay aligned).
#[inline]
pub fn next_event(
    scene: &Scene,
    si: &SurfaceInteraction,
    bsdf: &Bsdf,
    frame: &Frame,
    wo: Vec3,
    mis: bool,
    counts: Counts,
    u_light: f32,
    u_point: glam::Vec2,
    stats: &mut PathStats,
) -> Vec3 {
    let at = LightContext::new(si.p, si.ns);
    let Some(ls) = scene.sample_light(&at, u_light, u_point) else {
        return Vec3::ZERO;
    };
    let Some(inc) = ls.incident(si.p) else {
        return Vec3::ZERO;
    };
    let wi_local = frame.to_local(inc.wi);
    let f = bsdf.eval(wo, wi_local) * wi_local.z.abs();
    // Test visibility only for samples that can contribute.
    if f == Vec3::ZERO {
        return Vec3::ZERO;
    }
    stats.shadow_rays += 1;
    if scene.occluded(&ls.shadow_ray(si.p, si.ng, &inc)) {
        return Vec3::ZERO;
    }
    let weight = if mis && !inc.delta {
        power_heuristic(counts.light, inc.pdf, counts.bsdf, bsdf.pdf(wo, wi_local))
    } else {
        1.0
    };
    f * inc.li * (weight / inc.pdf)
}
