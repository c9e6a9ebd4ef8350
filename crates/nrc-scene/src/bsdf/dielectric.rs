//! Dielectric interface: smooth (Fresnel reflection and Snell refraction, chosen
//! stochastically in proportion to the exact Fresnel reflectance) or rough (the GGX BSDF of
//! Walter et al. 2007, reflection eq. 20 and transmission eq. 21).
//!
//! `eta` is the index of the inside (below the surface, `z < 0`) over the outside. A
//! direction with `wo.z > 0` is outside; with `wo.z < 0` it is inside and sees the relative
//! index `1/eta`. Internally the configuration is mirrored so that `wo.z > 0`, with
//! `etap` = index on the far side over the index on `wo`'s side.
//!
//! Transport mode is radiance: crossing into the side of `wi` from the side of `wo`, the
//! transmitted radiance is scaled by `1/etap²` (radiance divided by the squared index is
//! invariant along a refracted ray; Veach 1997 §5.2). So the rough BTDF is
//!
//! `f_t(wo, wi) = tint (1 − F(wo·m)) D(m) G2 |wi·m| |wo·m| / (|cos θi| |cos θo| (wi·m + wo·m/etap)²) / etap²`
//!
//! with the generalized half vector `m ∝ wo + etap wi` (Walter eq. 16), and it obeys the
//! generalized reciprocity `f(wo, wi) / η_o² = f(wi, wo) / η_i²`, i.e.
//! `f(wo, wi) = f(wi, wo) / etap²`. The `tint` (glTF base colour of transmissive
//! materials) multiplies transmission only. An index within 1e-4 of 1 is index-matched: the
//! interface is invisible and transmits straight through (a delta pass-through).

use super::fresnel::{fresnel_dielectric, reflect, refract};
use super::microfacet::{ALPHA_DELTA, Ggx};
use super::sample::BsdfSample;
use glam::{Vec2, Vec3};

#[inline]
fn flip(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.y, -v.z)
}

#[inline]
fn index_matched(eta: f32) -> bool {
    (eta - 1.0).abs() < 1e-4
}

#[inline]
pub(super) fn is_delta(eta: f32, alpha: f32) -> bool {
    alpha < ALPHA_DELTA || index_matched(eta)
}

/// Mirrors `(wo, wi)` so that `wo.z > 0` and returns the relative index of the far side.
#[inline]
fn orient(eta: f32, wo: Vec3, wi: Vec3) -> (Vec3, Vec3, f32) {
    if wo.z > 0.0 {
        (wo, wi, eta)
    } else {
        (flip(wo), flip(wi), 1.0 / eta)
    }
}

/// Microfacet normal of the pair `(wo, wi)` (`wo.z > 0`): the half vector for reflection,
/// the generalized half vector `wo + etap wi` for transmission (Walter eq. 13 and 16),
/// facing up. `None` for back-facing or degenerate configurations.
#[inline]
pub(super) fn half_vector(wo: Vec3, wi: Vec3, etap: f32) -> Option<Vec3> {
    let reflection = wi.z > 0.0;
    let h = if reflection { wo + wi } else { wo + etap * wi };
    let mut m = h.try_normalize()?;
    if m.z < 0.0 {
        m = -m;
    }
    let (co, ci) = (wo.dot(m), wi.dot(m));
    // Visible side: wo on the front of m; wi on the front for reflection, the back for
    // transmission.
    let ok = m.z > 0.0 && co > 0.0 && if reflection { ci > 0.0 } else { ci < 0.0 };
    ok.then_some(m)
}

/// `|wi·m| / (wi·m + wo·m/etap)²`: the Jacobian `dω_m/dω_i` of refraction (Walter eq. 17).
#[inline]
pub(super) fn refraction_jacobian(wo: Vec3, wi: Vec3, m: Vec3, etap: f32) -> f32 {
    let denom = wi.dot(m) + wo.dot(m) / etap;
    wi.dot(m).abs() / (denom * denom)
}

pub(super) fn eval(eta: f32, alpha: f32, tint: Vec3, wo: Vec3, wi: Vec3) -> Vec3 {
    if wo.z == 0.0 || wi.z == 0.0 || is_delta(eta, alpha) {
        return Vec3::ZERO;
    }
    let (wo, wi, etap) = orient(eta, wo, wi);
    let Some(m) = half_vector(wo, wi, etap) else {
        return Vec3::ZERO;
    };
    let ggx = Ggx::new(alpha);
    let f = fresnel_dielectric(wo.dot(m), etap);
    let dg = ggx.d(m) * ggx.g2(wo, wi);
    if wi.z > 0.0 {
        Vec3::splat(dg * f / (4.0 * wo.z * wi.z))
    } else {
        let ft = dg * (1.0 - f) * wo.dot(m) * refraction_jacobian(wo, wi, m, etap)
            / (wo.z * wi.z.abs() * etap * etap);
        tint * ft
    }
}

pub(super) fn pdf(eta: f32, alpha: f32, wo: Vec3, wi: Vec3) -> f32 {
    if wo.z == 0.0 || wi.z == 0.0 || is_delta(eta, alpha) {
        return 0.0;
    }
    let (wo, wi, etap) = orient(eta, wo, wi);
    let Some(m) = half_vector(wo, wi, etap) else {
        return 0.0;
    };
    let ggx = Ggx::new(alpha);
    let f = fresnel_dielectric(wo.dot(m), etap);
    if wi.z > 0.0 {
        ggx.reflection_pdf(wo, m) * f
    } else {
        ggx.pdf_visible(wo, m) * refraction_jacobian(wo, wi, m, etap) * (1.0 - f)
    }
}

pub(super) fn sample(
    eta: f32,
    alpha: f32,
    tint: Vec3,
    wo: Vec3,
    u: Vec2,
    uc: f32,
) -> Option<BsdfSample> {
    if wo.z == 0.0 {
        return None;
    }
    let outside = wo.z > 0.0;
    let (wo, _, etap) = orient(eta, wo, Vec3::Z);
    let unorient = |w: Vec3| if outside { w } else { flip(w) };
    if index_matched(eta) {
        return Some(BsdfSample {
            wi: -unorient(wo),
            weight: tint,
            pdf: 1.0,
            delta: true,
        });
    }
    if alpha < ALPHA_DELTA {
        // Smooth interface: reflect with probability F, refract with 1 − F. The weights
        // are f cos/pdf = 1 for reflection and tint/etap² for refraction; `pdf` holds the
        // discrete probability of the event.
        let f = fresnel_dielectric(wo.z, etap);
        if uc < f {
            return Some(BsdfSample {
                wi: unorient(Vec3::new(-wo.x, -wo.y, wo.z)),
                weight: Vec3::ONE,
                pdf: f,
                delta: true,
            });
        }
        let wi = refract(wo, Vec3::Z, etap)?;
        return Some(BsdfSample {
            wi: unorient(wi),
            weight: tint / (etap * etap),
            pdf: 1.0 - f,
            delta: true,
        });
    }
    // Rough interface: a visible normal m, then reflection with probability F(wo·m) or
    // refraction through m (Walter 2007 §5.3, with visible-normal sampling).
    let ggx = Ggx::new(alpha);
    let m = ggx.sample_visible(wo, u)?;
    let f = fresnel_dielectric(wo.dot(m), etap);
    if uc < f {
        let wi = reflect(wo, m);
        if wi.z <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi: unorient(wi),
            weight: Vec3::splat(ggx.g2_over_g1(wo, wi)),
            pdf: ggx.reflection_pdf(wo, m) * f,
            delta: false,
        })
    } else {
        let wi = refract(wo, m, etap)?;
        if wi.z >= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi: unorient(wi),
            weight: tint * (ggx.g2_over_g1(wo, wi) / (etap * etap)),
            pdf: ggx.pdf_visible(wo, m) * refraction_jacobian(wo, wi, m, etap) * (1.0 - f),
            delta: false,
        })
    }
}
