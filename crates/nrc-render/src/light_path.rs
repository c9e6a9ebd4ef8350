//! Light paths: traced from the lights, carrying flux weights, for the producers that gather
//! light where it arrives (bidirectional training, light training, photon collection) and for
//! the light-side passes to come (instant radiosity's virtual point lights).
//!
//! **Light transport on light paths.** The BSDFs are written for radiance transport
//! (`f(wo, wi)`, `wo` toward the viewer). A light path samples at `y` with `wo` set to the
//! direction *toward the previous light vertex*, which gives `f(w_prev, w_next)`, while the
//! physical contribution is `f(w_next, w_prev)`. For reflection and for the Lambertian and
//! conductor lobes the two are equal (reciprocity); for refraction the generalized reciprocity
//! `f(wo, wi)/η_o² = f(wi, wo)/η_i²` of the dielectric lobes gives the factor `η_t²/η_i²`
//! ([`adjoint_scale`]), which removes the radiance-only `1/η²` scaling. With shading normals
//! the update also carries Veach's correction `|w_prev·n_s| |w_next·n_g| / (|w_prev·n_g|
//! |w_next·n_s|)` (as PBRT's light tracer does), so that a light-path vertex's weight is the
//! flux arriving per unit *geometric* area while the BSDF integrals use shading cosines.

use glam::Vec3;
use nrc_scene::{
    LightSample, Ray, Scene, SurfaceInteraction, bsdf::Bsdf, sampling::Frame, spawn_ray,
};

use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::PixelSampler;

/// The number of light-path vertices worth tracing when the vertex's light reaches the camera
/// through `camera_segments` more segments, under the tracer's maximum depth (segments from the
/// camera, Mitsuba's convention); `u32::MAX` when unlimited.
pub fn light_vertex_limit(tracer: &PathTracer, camera_segments: u32) -> u32 {
    if tracer.segment_limit() == u32::MAX {
        u32::MAX
    } else {
        tracer.segment_limit().saturating_sub(camera_segments)
    }
}

/// One surface vertex of a light path.
#[derive(Clone, Copy, Debug)]
pub struct LightVertex {
    /// The hit; `si.wo` points back toward the previous light vertex (where the light came
    /// from).
    pub si: SurfaceInteraction,
    pub bsdf: Bsdf,
    pub frame: Frame,
    /// `si.wo` in the local shading frame.
    pub wo_local: Vec3,
    /// Flux weight of the light arriving here, per unit geometric area, with the shading-normal
    /// factor `|w_prev·n_s| / |w_prev·n_g|` applied: the estimate of the irradiance-weighted
    /// integrals `∫ g(ω) L_i(ω) |ω·n_s| dω dA` is the sum of `g(ω_prev) · beta` over vertices.
    pub beta: Vec3,
    /// The direction (world) the BSDF sampled for the path's continuation, if it sampled one
    /// (the path may still have ended there by Russian roulette or the depth limit).
    pub next: Option<Vec3>,
}

/// A light path: the light sample it started from (a point on an emissive triangle, a punctual
/// light, or an environment direction) and its surface vertices `y_1, y_2, ...`.
#[derive(Clone, Debug, Default)]
pub struct LightPath {
    pub origin: Option<LightSample>,
    pub vertices: Vec<LightVertex>,
}

/// The adjoint factor of a light-path scattering event sampled with `wo = w_prev`:
/// `f(w_next, w_prev) / f(w_prev, w_next)`, which is `η_t² / η_i²` for refraction through a
/// dielectric interface (index `η_t` on `w_next`'s side, `η_i` on `w_prev`'s side) and 1
/// otherwise.
pub fn adjoint_scale(bsdf: &Bsdf, w_prev: Vec3, w_next: Vec3) -> f32 {
    if w_prev.z * w_next.z >= 0.0 {
        return 1.0;
    }
    let eta = match *bsdf {
        Bsdf::Dielectric { eta, .. } => eta,
        Bsdf::MetallicRoughness { ior, .. } => ior,
        _ => return 1.0,
    };
    // `eta` is the inside (z < 0) over the outside index.
    let etap = if w_prev.z > 0.0 { eta } else { 1.0 / eta };
    etap * etap
}

/// Traces one light path with at most `max_vertices` surface vertices: a light chosen by power
/// and its first segment ([`LightSample::emit`]: a cosine-distributed direction from a point on
/// an emissive triangle, on a uniformly chosen side of a two-sided one; a direction from a
/// point or spot light's emission distribution; for the environment and directional lights a
/// direction from their distribution and an origin on a disc covering the scene's bounding
/// sphere), then BSDF sampling with Russian roulette from `tracer.rr_depth` scattering events
/// on, relative to the emitted weight. The first vertex's weight is the emission's flux weight
/// (`β₁ = Le cos θ / (p_A(y₀) p_ω(ω₀))` for a triangle); each scattering multiplies by
/// `f(w_next, w_prev) |w_next·n_g| / p(w_next)` times the shading-normal factor described in
/// the module documentation.
pub fn trace_light_path(
    scene: &Scene,
    tracer: &PathTracer,
    max_vertices: u32,
    sampler: &mut PixelSampler,
    stats: &mut PathStats,
) -> LightPath {
    let mut path = LightPath::default();
    let u_light = sampler.next_1d();
    let u_point = sampler.next_2d();
    let u_side = sampler.next_1d();
    let u_dir = sampler.next_2d();
    let Some(ls) = scene.sample_light_by_power(u_light, u_point) else {
        return path;
    };
    path.origin = Some(ls);
    if max_vertices == 0 {
        return path;
    }
    let (center, radius) = scene.bounding_sphere();
    let Some(e) = ls.emit(u_side, u_dir, center, radius) else {
        return path;
    };
    let beta0 = e.beta;
    let beta0_max = beta0.max_element();
    let mut beta = beta0;
    let mut ray = if e.normal == glam::Vec3::ZERO {
        Ray::new(e.origin, e.dir)
    } else {
        spawn_ray(e.origin, e.normal, e.dir)
    };
    let mut events: u32 = 0;
    while (path.vertices.len() as u32) < max_vertices {
        stats.closest_rays += 1;
        let Some(hit) = scene.intersect(&ray) else {
            break;
        };
        let si = scene.interaction(&ray, &hit);
        let cos_s = si.wo.dot(si.ns).abs();
        let cos_g = si.wo.dot(si.ng).abs();
        if cos_g == 0.0 {
            break;
        }
        let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
        let frame = Frame::from_normal(si.ns);
        let wo_local = frame.to_local(si.wo);
        let u_lobe = sampler.next_1d();
        let u = sampler.next_2d();
        let bs = bsdf.sample(wo_local, u, u_lobe);
        let next = bs.map(|s| frame.to_world(s.wi));
        path.vertices.push(LightVertex {
            si,
            bsdf,
            frame,
            wo_local,
            beta: beta * (cos_s / cos_g),
            next,
        });
        let (Some(bs), Some(wn)) = (bs, next) else {
            break;
        };
        let cos_next_s = bs.wi.z.abs();
        if cos_next_s == 0.0 {
            break;
        }
        let correction = adjoint_scale(&bsdf, wo_local, bs.wi) * (cos_s * wn.dot(si.ng).abs())
            / (cos_g * cos_next_s);
        beta *= bs.weight * correction;
        events += 1;
        if !beta.is_finite() || beta.max_element() <= 0.0 {
            break;
        }
        if events >= tracer.rr_depth {
            let q = (beta.max_element() / beta0_max).min(0.95);
            if q.is_nan() || q <= 0.0 || sampler.next_1d() >= q {
                break;
            }
            beta /= q;
        }
        ray = spawn_ray(si.p, si.ng, wn);
    }
    path
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The adjoint factor turns the sampled `f(w_prev, w_next)` into the physical
    /// `f(w_next, w_prev)` for rough refraction in both directions, and is 1 for reflection.
    #[test]
    fn adjoint_scale_matches_reciprocity() {
        let glass = Bsdf::Dielectric {
            eta: 1.5,
            alpha: 0.3,
            tint: Vec3::ONE,
        };
        let (mut checked, mut refracted) = (0, 0);
        for i in 0..64u64 {
            let mut s = PixelSampler::new(5, i, 0);
            let w_prev = nrc_scene::sampling::sample_uniform_sphere(s.next_2d());
            let u = s.next_2d();
            let Some(bs) = glass.sample(w_prev, u, s.next_1d()) else {
                continue;
            };
            if bs.delta {
                continue;
            }
            let forward = glass.eval(w_prev, bs.wi);
            let physical = glass.eval(bs.wi, w_prev);
            if forward.x < 1e-3 {
                continue;
            }
            let scale = adjoint_scale(&glass, w_prev, bs.wi);
            assert!(
                ((forward.x * scale) / physical.x - 1.0).abs() < 1e-3,
                "{w_prev} {:?}: {forward} {physical} {scale}",
                bs.wi
            );
            checked += 1;
            refracted += (w_prev.z * bs.wi.z < 0.0) as u32;
        }
        assert!(
            checked > 20 && refracted > 5,
            "{checked} checked, {refracted} refracted"
        );
        let diffuse = Bsdf::Diffuse { albedo: Vec3::ONE };
        assert_eq!(adjoint_scale(&diffuse, Vec3::Z, -Vec3::Z), 1.0);
        assert_eq!(
            adjoint_scale(&glass, Vec3::Z, Vec3::new(0.6, 0.0, 0.8)),
            1.0
        );
    }
}
