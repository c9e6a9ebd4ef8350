//! GGX microfacet conductor (Cook-Torrance with the Walter 2007 normalization):
//! `f(wo, wi) = F(wo·h) D(h) G2(wo, wi) / (4 cos θo cos θi)`.
//!
//! The Fresnel term is Schlick's approximation from the normal-incidence reflectance `F0`,
//! which is how glTF 2.0 parameterizes metals (`F0` = base colour; the specification's
//! `conductor_fresnel`). Below [`ALPHA_DELTA`] the lobe is a perfect mirror.
//! Directions are local with `wo.z > 0` (the caller mirrors two-sided lookups).

use super::fresnel::schlick;
use super::microfacet::{ALPHA_DELTA, Ggx};
use super::sample::BsdfSample;
use glam::{Vec2, Vec3};

#[inline]
pub(super) fn is_delta(alpha: f32) -> bool {
    alpha < ALPHA_DELTA
}

pub(super) fn eval(f0: Vec3, alpha: f32, wo: Vec3, wi: Vec3) -> Vec3 {
    if is_delta(alpha) {
        return Vec3::ZERO;
    }
    match Ggx::new(alpha).reflection(wo, wi) {
        Some((f, h)) => schlick(f0, wo.dot(h)) * f,
        None => Vec3::ZERO,
    }
}

pub(super) fn pdf(alpha: f32, wo: Vec3, wi: Vec3) -> f32 {
    if is_delta(alpha) || wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let ggx = Ggx::new(alpha);
    match (wo + wi).try_normalize() {
        Some(h) => ggx.reflection_pdf(wo, h),
        None => 0.0,
    }
}

pub(super) fn sample(f0: Vec3, alpha: f32, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
    if wo.z <= 0.0 {
        return None;
    }
    if is_delta(alpha) {
        // Perfect mirror: f = F(cos θo) δ(wi − mirror(wo)) / cos θi; pdf is the discrete
        // probability 1 of the single event.
        return Some(BsdfSample {
            wi: Vec3::new(-wo.x, -wo.y, wo.z),
            weight: schlick(f0, wo.z),
            pdf: 1.0,
            delta: true,
        });
    }
    let ggx = Ggx::new(alpha);
    let (wi, m) = ggx.sample_reflection(wo, u)?;
    // f cos θi / pdf = F(wo·m) G2 / G1(wo) for visible-normal sampling.
    Some(BsdfSample {
        wi,
        weight: schlick(f0, wo.dot(m)) * ggx.g2_over_g1(wo, wi),
        pdf: ggx.reflection_pdf(wo, m),
        delta: false,
    })
}
