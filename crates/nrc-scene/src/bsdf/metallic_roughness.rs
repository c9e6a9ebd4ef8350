//! The glTF 2.0 metallic-roughness material (specification appendix B) with
//! `KHR_materials_specular`, `KHR_materials_ior` and `KHR_materials_transmission`:
//!
//! `material = mix(dielectric_brdf, metal_brdf, metallic)`
//! `metal_brdf = conductor_fresnel(f0 = base_color) · specular_brdf(α)`
//! `dielectric_brdf = fresnel_mix(specular · F_d, layer = specular_brdf(α),
//!                                base = mix(diffuse_brdf(base_color), specular_btdf(α), transmission))`
//!
//! with α = roughness², the dielectric Schlick reflectance `F_d = F0_d + (1 − F0_d)(1 − |v·h|)⁵`,
//! `F0_d = min(((ior − 1)/(ior + 1))² · specular_color, 1)`, and the layer scaled by the
//! `specular` factor (0: purely diffuse). The specular BRDF is the GGX microfacet lobe
//! `D G2 / (4 cos θo cos θi)` of [`super::microfacet`]; both Fresnel terms weight one shared
//! lobe, so it is evaluated once with `F = (1 − metallic) specular F_d + metallic F_m`.
//!
//! Energy: appendix B's `fresnel_mix` weights the base by `1 − specular · max(F_d(v·h))`, which
//! can reflect more than it receives at grazing angles. This module instead uses the
//! albedo-scaling form that appendix B and `KHR_materials_sheen` describe, symmetrized as in
//! the sheen extension: the diffuse base is weighted by
//! `min(1 − Ê(wo), 1 − Ê(wi))`, where `Ê` bounds the directional albedo of the
//! `specular · F_d` layer (tabulated, [`super::layer_albedo`]). Then
//! `E_layer(wo) + (1 − Ê(wo)) · albedo_base ≤ 1`, and the lobe stays reciprocal.
//!
//! Transmission: the base's transmissive part is the GGX BTDF of Walter 2007 through the
//! interface of relative index `ior` (the same geometry as [`super::dielectric`], including
//! the radiance scaling `1/etap²`), tinted by the base colour, without its own Fresnel factor
//! and weighted by `1 − specular · max(F_d)` evaluated at the microfacet cosine on the
//! outside, so that reflection and transmission through one microfacet never exceed 1.
//! Reflection lobes are two-sided (a direction below the surface sees the mirrored
//! configuration); the transmission lobe uses the side of `wo`.

use super::dielectric::{half_vector, refraction_jacobian};
use super::fresnel::{f0_from_ior, refract, schlick};
use super::layer_albedo;
use super::microfacet::{ALPHA_DELTA, Ggx};
use super::sample::BsdfSample;
use crate::sampling::{cosine_hemisphere_pdf, luminance, sample_cosine_hemisphere};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[inline]
fn flip(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.y, -v.z)
}

/// Mirrors `w` into the upper hemisphere.
#[inline]
fn up(w: Vec3) -> Vec3 {
    Vec3::new(w.x, w.y, w.z.abs())
}

/// The parameters of the blend, already sanitized.
#[derive(Clone, Copy, Debug)]
pub(super) struct MetallicRoughness {
    pub base: Vec3,
    pub metallic: f32,
    pub alpha: f32,
    pub transmission: f32,
    /// Relative index of refraction inside over outside.
    pub eta: f32,
    pub specular: f32,
    /// Dielectric normal reflectance `min(((ior − 1)/(ior + 1))² specular_color, 1)`.
    pub f0_d: Vec3,
}

/// Lobe selection probabilities `[specular reflection, diffuse, transmission]`.
type LobeProbs = [f32; 3];

impl MetallicRoughness {
    pub fn new(
        base: Vec3,
        metallic: f32,
        alpha: f32,
        transmission: f32,
        eta: f32,
        specular: f32,
        specular_color: Vec3,
    ) -> Self {
        Self {
            base,
            metallic,
            alpha,
            transmission,
            eta,
            specular,
            f0_d: (f0_from_ior(eta) * specular_color).min(Vec3::ONE),
        }
    }

    #[inline]
    fn smooth(&self) -> bool {
        self.alpha < ALPHA_DELTA
    }

    /// Transmission is a delta lobe for a smooth or index-matched interface.
    #[inline]
    fn delta_transmission(&self) -> bool {
        self.smooth() || (self.eta - 1.0).abs() < 1e-4
    }

    /// All lobes with energy are delta lobes.
    pub fn is_delta(&self) -> bool {
        let diffuse = (1.0 - self.metallic) * (1.0 - self.transmission);
        self.smooth() && (diffuse <= 0.0 || self.base == Vec3::ZERO)
    }

    /// Combined Fresnel of the shared specular lobe:
    /// `(1 − metallic) specular F_d(c) + metallic F_m(c)`.
    #[inline]
    fn spec_fresnel(&self, c: f32) -> Vec3 {
        (1.0 - self.metallic) * self.specular * schlick(self.f0_d, c)
            + self.metallic * schlick(self.base, c)
    }

    /// `specular · max_channel F_d(c)`: the weight the layer takes from the base through one
    /// microfacet of cosine `c`.
    #[inline]
    fn layer_max(&self, c: f32) -> f32 {
        self.specular * schlick(self.f0_d, c).max_element()
    }

    /// `Ê(w)`: upper bound of the dielectric layer's directional albedo (max channel) at
    /// `cos θ = c`.
    fn layer_albedo_bound(&self, c: f32) -> f32 {
        if self.specular <= 0.0 {
            0.0
        } else if self.smooth() {
            self.layer_max(c)
        } else {
            self.specular * layer_albedo::albedo_bound(self.alpha, c, self.f0_d.max_element())
        }
    }

    /// Lobe probabilities at `|cos θo| = c`, proportional to estimates of each lobe's albedo.
    /// Only depends on `wo`, so `pdf` reproduces the choice of `sample`.
    fn lobe_probs(&self, c: f32) -> Option<LobeProbs> {
        let m = self.metallic;
        let spec = if self.smooth() {
            luminance(self.spec_fresnel(c))
        } else {
            let [a, b] = layer_albedo::lookup(self.alpha, c);
            (1.0 - m) * self.specular * (luminance(self.f0_d) * a + b)
                + m * (luminance(self.base) * a + b)
        };
        let base = (1.0 - m) * (1.0 - self.layer_max(c)).max(0.0) * luminance(self.base);
        let diffuse = base * (1.0 - self.transmission);
        let transmission = base * self.transmission;
        let total = spec + diffuse + transmission;
        (total > 0.0 && total.is_finite())
            .then(|| [spec / total, diffuse / total, transmission / total])
    }

    /// Diffuse base `(1 − metallic)(1 − transmission) min(1 − Ê(wo), 1 − Ê(wi)) base / π`
    /// for `wo`, `wi` in the upper hemisphere.
    fn diffuse(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let k = (1.0 - self.metallic) * (1.0 - self.transmission);
        if k <= 0.0 {
            return Vec3::ZERO;
        }
        let scale = (1.0 - self.layer_albedo_bound(wo.z)).min(1.0 - self.layer_albedo_bound(wi.z));
        self.base * (k * scale.max(0.0) * FRAC_1_PI)
    }

    /// Tint and Fresnel weight of the transmission lobe through a microfacet whose cosine
    /// with the outside direction is `c_out`.
    #[inline]
    fn transmission_weight(&self, c_out: f32) -> Vec3 {
        self.base
            * ((1.0 - self.metallic) * self.transmission * (1.0 - self.layer_max(c_out)).max(0.0))
    }

    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z == 0.0 || wi.z == 0.0 {
            return Vec3::ZERO;
        }
        if wo.z * wi.z > 0.0 {
            let (o, i) = (up(wo), up(wi));
            let mut f = self.diffuse(o, i);
            if !self.smooth()
                && let Some((g, h)) = Ggx::new(self.alpha).reflection(o, i)
            {
                f += self.spec_fresnel(o.dot(h)) * g;
            }
            f
        } else {
            if self.transmission <= 0.0 || self.delta_transmission() {
                return Vec3::ZERO;
            }
            let outside = wo.z > 0.0;
            let (o, i, etap) = if outside {
                (wo, wi, self.eta)
            } else {
                (flip(wo), flip(wi), 1.0 / self.eta)
            };
            let Some(m) = half_vector(o, i, etap) else {
                return Vec3::ZERO;
            };
            let c_out = if outside { o.dot(m) } else { i.dot(m).abs() };
            let ggx = Ggx::new(self.alpha);
            let ft = ggx.d(m) * ggx.g2(o, i) * o.dot(m) * refraction_jacobian(o, i, m, etap)
                / (o.z * i.z.abs() * etap * etap);
            self.transmission_weight(c_out) * ft
        }
    }

    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z == 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        let Some([p_spec, p_diffuse, p_trans]) = self.lobe_probs(wo.z.abs()) else {
            return 0.0;
        };
        if wo.z * wi.z > 0.0 {
            let (o, i) = (up(wo), up(wi));
            let mut pdf = p_diffuse * cosine_hemisphere_pdf(i.z);
            if !self.smooth()
                && p_spec > 0.0
                && let Some(h) = (o + i).try_normalize()
            {
                pdf += p_spec * Ggx::new(self.alpha).reflection_pdf(o, h);
            }
            pdf
        } else {
            if p_trans <= 0.0 || self.delta_transmission() {
                return 0.0;
            }
            let (o, i, etap) = if wo.z > 0.0 {
                (wo, wi, self.eta)
            } else {
                (flip(wo), flip(wi), 1.0 / self.eta)
            };
            let Some(m) = half_vector(o, i, etap) else {
                return 0.0;
            };
            p_trans * Ggx::new(self.alpha).pdf_visible(o, m) * refraction_jacobian(o, i, m, etap)
        }
    }

    /// Samples one lobe with probability `lobe_probs`, then its direction. Non-delta samples
    /// are weighted by the whole non-delta BSDF over the whole non-delta pdf (the one-sample
    /// mixture estimator); delta samples by the lobe's delta weight over its probability.
    pub fn sample(&self, wo: Vec3, u: Vec2, uc: f32) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let [p_spec, p_diffuse, p_trans] = self.lobe_probs(wo.z.abs())?;
        let below = wo.z < 0.0;
        let o = up(wo);
        let to_side = |w: Vec3| if below { flip(w) } else { w };
        let wi = if uc < p_spec {
            if self.smooth() {
                return Some(BsdfSample {
                    wi: to_side(Vec3::new(-o.x, -o.y, o.z)),
                    weight: self.spec_fresnel(o.z) / p_spec,
                    pdf: p_spec,
                    delta: true,
                });
            }
            let (wi, _) = Ggx::new(self.alpha).sample_reflection(o, u)?;
            to_side(wi)
        } else if uc < p_spec + p_diffuse || p_trans <= 0.0 {
            to_side(sample_cosine_hemisphere(u))
        } else {
            let etap = if below { 1.0 / self.eta } else { self.eta };
            if self.delta_transmission() {
                // Smooth (or index-matched) refraction through the macro-normal.
                let wi = if (self.eta - 1.0).abs() < 1e-4 {
                    -o
                } else {
                    refract(o, Vec3::Z, etap)?
                };
                let c_out = if below { wi.z.abs() } else { o.z };
                return Some(BsdfSample {
                    wi: to_side(wi),
                    weight: self.transmission_weight(c_out) / (etap * etap * p_trans),
                    pdf: p_trans,
                    delta: true,
                });
            }
            let m = Ggx::new(self.alpha).sample_visible(o, u)?;
            let wi = refract(o, m, etap)?;
            if wi.z >= 0.0 {
                return None;
            }
            to_side(wi)
        };
        let pdf = self.pdf(wo, wi);
        if pdf <= 0.0 {
            return None;
        }
        let weight = self.eval(wo, wi) * (wi.z.abs() / pdf);
        Some(BsdfSample {
            wi,
            weight,
            pdf,
            delta: false,
        })
    }

    pub fn diffuse_reflectance(&self) -> Vec3 {
        self.base * ((1.0 - self.metallic) * (1.0 - self.transmission))
    }

    pub fn specular_reflectance(&self) -> Vec3 {
        (1.0 - self.metallic) * self.specular * self.f0_d + self.metallic * self.base
    }
}
