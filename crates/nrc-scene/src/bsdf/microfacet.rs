//! The isotropic GGX (Trowbridge-Reitz) microfacet distribution (Walter et al. 2007,
//! "Microfacet Models for Refraction through Rough Surfaces"), the height-correlated Smith
//! masking-shadowing function (Heitz 2014, "Understanding the Masking-Shadowing Function in
//! Microfacet-Based BRDFs"), and sampling of the distribution of visible normals with the
//! spherical-cap method of Dupuy and Benyoub 2023, "Sampling Visible GGX Normals with
//! Spherical Caps" (the same distribution as Heitz 2018, "Sampling the GGX Distribution of
//! Visible Normals").
//!
//! All directions are in the local shading frame (`z` = normal). The functions here assume the
//! outgoing direction `wo` lies in the upper hemisphere; callers mirror it there first.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Below this α a GGX lobe is treated as perfectly smooth: a Dirac delta (mirror or
/// refraction). `α = roughness²`, so this is perceptual roughness 0.01.
pub const ALPHA_DELTA: f32 = 1e-4;

/// Isotropic GGX distribution of width `alpha` (α = roughness²).
#[derive(Clone, Copy, Debug)]
pub struct Ggx {
    pub alpha: f32,
}

impl Ggx {
    pub fn new(alpha: f32) -> Self {
        Self {
            alpha: alpha.clamp(ALPHA_DELTA, 1.0),
        }
    }

    /// Normal distribution `D(m) = α² / (π cos⁴θm (α² + tan²θm)²)` (Walter 2007 eq. 33),
    /// written as `1 / (π α² (cos²θm + sin²θm/α²)²)` to keep precision near the peak.
    #[inline]
    pub fn d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let t = m.z * m.z + (m.x * m.x + m.y * m.y) / a2;
        1.0 / (PI * a2 * t * t)
    }

    /// Smith's `Λ(ω) = (−1 + √(1 + α² tan²θ)) / 2` (Heitz 2014 eq. 72), in the
    /// cancellation-free form `x / (2(√(1 + x) + 1))` with `x = α² tan²θ`.
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        let z2 = w.z * w.z;
        let x = self.alpha * self.alpha * (w.x * w.x + w.y * w.y) / z2;
        if !x.is_finite() {
            return f32::INFINITY;
        }
        x / (2.0 * ((1.0 + x).sqrt() + 1.0))
    }

    /// Smith masking `G1(ω) = 1 / (1 + Λ(ω))`.
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking-shadowing `G2(ωo, ωi) = 1 / (1 + Λ(ωo) + Λ(ωi))`
    /// (Heitz 2014 eq. 99).
    #[inline]
    pub fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Samples a microfacet normal from the distribution of normals visible from `wo`
    /// (`wo.z > 0`), `D_wo(m) = G1(wo) max(0, wo·m) D(m) / wo.z` (Heitz 2018 eq. 1), by the
    /// spherical-cap construction of Dupuy & Benyoub 2023: stretch `wo` to the α = 1
    /// configuration, sample the spherical cap of directions `c` with `c·z > −wo_std.z`,
    /// take the half vector `c + wo_std`, and unstretch it.
    #[inline]
    pub fn sample_visible(&self, wo: Vec3, u: Vec2) -> Option<Vec3> {
        let a = self.alpha;
        let wo_std = Vec3::new(a * wo.x, a * wo.y, wo.z).try_normalize()?;
        let phi = 2.0 * PI * u.x;
        let z = (1.0 - u.y) * (1.0 + wo_std.z) - wo_std.z;
        let sin_theta = (1.0 - z * z).max(0.0).sqrt();
        let (sin_phi, cos_phi) = phi.sin_cos();
        let c = Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, z);
        let h = c + wo_std;
        let m = Vec3::new(a * h.x, a * h.y, h.z.max(0.0)).try_normalize()?;
        (m.z > 0.0).then_some(m)
    }

    /// Density of [`Ggx::sample_visible`] over microfacet normals (solid angle):
    /// `D_wo(m) = G1(wo) max(0, wo·m) D(m) / wo.z`.
    #[inline]
    pub fn pdf_visible(&self, wo: Vec3, m: Vec3) -> f32 {
        let cos = wo.dot(m);
        if cos <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        self.g1(wo) * cos * self.d(m) / wo.z
    }

    /// Microfacet reflection without Fresnel, `D(h) G2(wo, wi) / (4 cos θo cos θi)` with the
    /// half vector `h = (wo + wi)/|wo + wi|`, for `wo`, `wi` in the upper hemisphere.
    /// Returns `(value, h)`, or `None` when the configuration carries no energy.
    #[inline]
    pub fn reflection(&self, wo: Vec3, wi: Vec3) -> Option<(f32, Vec3)> {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return None;
        }
        let h = (wo + wi).try_normalize()?;
        let f = self.d(h) * self.g2(wo, wi) / (4.0 * wo.z * wi.z);
        (f.is_finite() && f > 0.0).then_some((f, h))
    }

    /// Solid-angle density of [`Ggx::sample_reflection`] at `wi` with half vector `h`:
    /// `D_wo(h) / (4 wo·h)` (the Jacobian of mirror reflection, Walter 2007 eq. 14).
    #[inline]
    pub fn reflection_pdf(&self, wo: Vec3, h: Vec3) -> f32 {
        let cos = wo.dot(h);
        if cos <= 0.0 {
            return 0.0;
        }
        self.pdf_visible(wo, h) / (4.0 * cos)
    }

    /// Samples a reflected direction: a visible normal `m`, then `wi` = mirror of `wo` about
    /// it. Returns `(wi, m)`; `None` when `wi` falls below the horizon (the sample is lost,
    /// which is the energy the single-scattering model does not reflect).
    #[inline]
    pub fn sample_reflection(&self, wo: Vec3, u: Vec2) -> Option<(Vec3, Vec3)> {
        let m = self.sample_visible(wo, u)?;
        let wi = super::fresnel::reflect(wo, m);
        (wi.z > 0.0).then_some((wi, m))
    }

    /// Ratio `G2(wo, wi) / G1(wo)`: the sample weight of visible-normal sampling of a
    /// Fresnel-free microfacet lobe.
    #[inline]
    pub fn g2_over_g1(&self, wo: Vec3, wi: Vec3) -> f32 {
        let lo = self.lambda(wo);
        let li = self.lambda(wi);
        (1.0 + lo) / (1.0 + lo + li)
    }
}
