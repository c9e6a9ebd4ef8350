//! Surface scattering: the closed `Bsdf` enum and its parameters.
//!
//! Conventions (every variant):
//! - Directions are in the local shading frame ([`crate::sampling::Frame`]), `z` = shading
//!   normal, unit length. `wo` (towards the viewer / previous vertex) and `wi` (towards the
//!   light / next vertex) both point away from the surface.
//! - Transport mode is radiance. `eval` returns `f(wo, wi)` without the cosine factor.
//! - Opaque lobes are two-sided: when `wo.z < 0` the configuration is mirrored into the upper
//!   hemisphere, so callers may pass directions on either side. Transmission lobes use the
//!   sign of `wo.z` to tell outside (`> 0`, relative index `eta`) from inside (`1/eta`).
//! - Degenerate input (grazing `cos = 0`, back-facing microfacets, total internal reflection
//!   in a lobe that cannot reflect) yields 0 / `None`, never NaN or infinity.
//! - A GGX lobe with α below [`ALPHA_DELTA`] is a Dirac delta (mirror or smooth refraction):
//!   `eval` and `pdf` ignore it, `sample` returns it with `delta: true`.

mod conductor;
mod dielectric;
mod fresnel;
mod layer_albedo;
mod metallic_roughness;
mod microfacet;
mod sample;

pub use fresnel::{f0_from_ior, fresnel_dielectric, reflect, refract, schlick};
pub use microfacet::{ALPHA_DELTA, Ggx};
pub use sample::BsdfSample;

use crate::sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere};
use glam::{Vec2, Vec3};
use metallic_roughness::MetallicRoughness;
use std::f32::consts::FRAC_1_PI;

/// Material parameters at one surface point after textures are applied: the glTF 2.0
/// metallic-roughness model with `KHR_materials_transmission`, `KHR_materials_ior` and
/// `KHR_materials_specular`. Colours are linear RGB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PbrParams {
    pub base_color: Vec3,
    pub metallic: f32,
    /// Perceptual roughness; the GGX α is `roughness²` as glTF defines.
    pub roughness: f32,
    /// `KHR_materials_transmission` factor (0: opaque).
    pub transmission: f32,
    /// `KHR_materials_ior` (glTF default 1.5).
    pub ior: f32,
    /// `KHR_materials_specular` `specularFactor`: scales the specular layer; 0 is purely diffuse.
    pub specular: f32,
    /// `KHR_materials_specular` `specularColorFactor`.
    pub specular_color: Vec3,
}

impl Default for PbrParams {
    fn default() -> Self {
        Self {
            base_color: Vec3::ONE,
            metallic: 1.0,
            roughness: 1.0,
            transmission: 0.0,
            ior: 1.5,
            specular: 1.0,
            specular_color: Vec3::ONE,
        }
    }
}

/// Surface scattering model at one point. A closed set of variants; see the module docs for
/// the conventions shared by all of them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflection `albedo / π`.
    Diffuse { albedo: Vec3 },
    /// GGX microfacet conductor with Schlick Fresnel from the normal reflectance `f0`
    /// (glTF's metal model); `alpha` = roughness², below [`ALPHA_DELTA`] a perfect mirror.
    Conductor { f0: Vec3, alpha: f32 },
    /// Dielectric interface of relative index `eta` (inside over outside), exact Fresnel:
    /// smooth (delta reflection/refraction) below [`ALPHA_DELTA`], else the rough GGX BSDF of
    /// Walter et al. 2007. `tint` multiplies transmission. Refraction scales radiance by
    /// `1/etap²` (radiance transport).
    Dielectric { eta: f32, alpha: f32, tint: Vec3 },
    /// The glTF metallic-roughness blend with `KHR_materials_specular`, `_ior` and
    /// `_transmission`: a Lambertian base (and transmission lobe) under a Fresnel-weighted
    /// GGX layer; see `bsdf/metallic_roughness.rs` for the model and its energy compensation.
    MetallicRoughness {
        base_color: Vec3,
        metallic: f32,
        alpha: f32,
        transmission: f32,
        ior: f32,
        specular: f32,
        specular_color: Vec3,
    },
}

#[inline]
fn mirror_up(w: Vec3) -> Vec3 {
    Vec3::new(w.x, w.y, w.z.abs())
}

#[inline]
fn finite_or_zero(v: Vec3) -> Vec3 {
    if v.is_finite() {
        v.max(Vec3::ZERO)
    } else {
        Vec3::ZERO
    }
}

/// Clamps a colour to `[0, 1]`, mapping NaN to 0.
#[inline]
fn unit_color(c: Vec3) -> Vec3 {
    Vec3::new(unit(c.x), unit(c.y), unit(c.z))
}

/// Clamps to `[0, 1]`, mapping NaN to 0.
#[inline]
fn unit(x: f32) -> f32 {
    if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) }
}

impl Bsdf {
    /// The simplest exact variant for glTF parameters. Inputs are sanitized: colours and
    /// factors are clamped to `[0, 1]` (NaN → 0), roughness to `[0, 1]` with α = roughness²,
    /// and `ior` to `[1, 10]` (NaN → 1.5).
    ///
    /// - metallic 0, transmission 0, specular 0 → `Diffuse { albedo: base_color }`
    /// - metallic 1, transmission 0 → `Conductor { f0: base_color }`
    /// - transmission 1, metallic 0, specular 1 and white specular colour →
    ///   `Dielectric { eta: ior, tint: base_color }`
    /// - otherwise `MetallicRoughness`.
    pub fn from_pbr(p: &PbrParams) -> Bsdf {
        let base_color = unit_color(p.base_color);
        let metallic = unit(p.metallic);
        let roughness = unit(p.roughness);
        let alpha = roughness * roughness;
        let transmission = unit(p.transmission);
        let ior = if p.ior.is_nan() {
            1.5
        } else {
            p.ior.clamp(1.0, 10.0)
        };
        let specular = unit(p.specular);
        let specular_color = if p.specular_color.is_nan() {
            Vec3::ONE
        } else {
            p.specular_color.clamp(Vec3::ZERO, Vec3::splat(f32::MAX))
        };
        if metallic == 0.0 && transmission == 0.0 && specular == 0.0 {
            Bsdf::Diffuse { albedo: base_color }
        } else if metallic == 1.0 && transmission == 0.0 {
            Bsdf::Conductor {
                f0: base_color,
                alpha,
            }
        } else if transmission == 1.0
            && metallic == 0.0
            && specular == 1.0
            && specular_color == Vec3::ONE
        {
            Bsdf::Dielectric {
                eta: ior,
                alpha,
                tint: base_color,
            }
        } else {
            Bsdf::MetallicRoughness {
                base_color,
                metallic,
                alpha,
                transmission,
                ior,
                specular,
                specular_color,
            }
        }
    }

    #[inline]
    fn metallic_roughness(&self) -> Option<MetallicRoughness> {
        match *self {
            Bsdf::MetallicRoughness {
                base_color,
                metallic,
                alpha,
                transmission,
                ior,
                specular,
                specular_color,
            } => Some(MetallicRoughness::new(
                base_color,
                metallic,
                alpha,
                transmission,
                ior,
                specular,
                specular_color,
            )),
            _ => None,
        }
    }

    /// `f(wo, wi)` without the cosine factor; 0 for delta lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let f = match *self {
            Bsdf::Diffuse { albedo } => {
                if wo.z * wi.z > 0.0 {
                    albedo * FRAC_1_PI
                } else {
                    Vec3::ZERO
                }
            }
            Bsdf::Conductor { f0, alpha } => {
                if wo.z * wi.z > 0.0 {
                    conductor::eval(f0, alpha, mirror_up(wo), mirror_up(wi))
                } else {
                    Vec3::ZERO
                }
            }
            Bsdf::Dielectric { eta, alpha, tint } => dielectric::eval(eta, alpha, tint, wo, wi),
            Bsdf::MetallicRoughness { .. } => self
                .metallic_roughness()
                .map_or(Vec3::ZERO, |m| m.eval(wo, wi)),
        };
        finite_or_zero(f)
    }

    /// Solid-angle density with which `sample` produces `wi` from its non-delta lobes,
    /// including the lobe-selection probabilities; 0 for delta-only BSDFs.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let p = match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z * wi.z > 0.0 {
                    cosine_hemisphere_pdf(wi.z.abs())
                } else {
                    0.0
                }
            }
            Bsdf::Conductor { alpha, .. } => {
                if wo.z * wi.z > 0.0 {
                    conductor::pdf(alpha, mirror_up(wo), mirror_up(wi))
                } else {
                    0.0
                }
            }
            Bsdf::Dielectric { eta, alpha, .. } => dielectric::pdf(eta, alpha, wo, wi),
            Bsdf::MetallicRoughness { .. } => {
                self.metallic_roughness().map_or(0.0, |m| m.pdf(wo, wi))
            }
        };
        if p.is_finite() && p > 0.0 { p } else { 0.0 }
    }

    /// Samples `wi` given `wo`, two uniform numbers `u` for the direction and one `uc` for
    /// the choice of lobe / reflection versus refraction. `None` when the sample carries no
    /// energy (below the horizon, total internal reflection in a lobe that cannot reflect,
    /// grazing `wo`).
    pub fn sample(&self, wo: Vec3, u: Vec2, uc: f32) -> Option<BsdfSample> {
        let s = match *self {
            Bsdf::Diffuse { albedo } => {
                if wo.z == 0.0 {
                    return None;
                }
                let mut wi = sample_cosine_hemisphere(u);
                let pdf = cosine_hemisphere_pdf(wi.z);
                if wo.z < 0.0 {
                    wi.z = -wi.z;
                }
                // f cos/pdf = (albedo/π) cos / (cos/π) = albedo.
                BsdfSample {
                    wi,
                    weight: albedo,
                    pdf,
                    delta: false,
                }
            }
            Bsdf::Conductor { f0, alpha } => {
                if wo.z == 0.0 {
                    return None;
                }
                let mut s = conductor::sample(f0, alpha, mirror_up(wo), u)?;
                if wo.z < 0.0 {
                    s.wi.z = -s.wi.z;
                }
                s
            }
            Bsdf::Dielectric { eta, alpha, tint } => {
                dielectric::sample(eta, alpha, tint, wo, u, uc)?
            }
            Bsdf::MetallicRoughness { .. } => self.metallic_roughness()?.sample(wo, u, uc)?,
        };
        let ok = s.pdf > 0.0
            && s.pdf.is_finite()
            && s.weight.is_finite()
            && s.wi.is_finite()
            && s.wi.z != 0.0;
        ok.then_some(BsdfSample {
            weight: s.weight.max(Vec3::ZERO),
            ..s
        })
    }

    /// All lobes with energy are Dirac deltas (`eval` and `pdf` are identically 0).
    pub fn is_delta(&self) -> bool {
        match *self {
            Bsdf::Diffuse { .. } => false,
            Bsdf::Conductor { alpha, .. } => conductor::is_delta(alpha),
            Bsdf::Dielectric { eta, alpha, .. } => dielectric::is_delta(eta, alpha),
            Bsdf::MetallicRoughness { .. } => {
                self.metallic_roughness().is_some_and(|m| m.is_delta())
            }
        }
    }

    /// Reflects and transmits nothing, in any direction (`eval` is identically 0 and no
    /// sample carries energy): a black Lambertian surface, or a metallic-roughness one with a
    /// black base, no metal and no specular layer (glTF's `KHR_materials_specular` factor 0,
    /// as the converted scenes' emitters have). A conductor or a dielectric layer always
    /// reflects at grazing angles (Fresnel), whatever its colour.
    pub fn is_black(&self) -> bool {
        match *self {
            Bsdf::Diffuse { albedo } => albedo == Vec3::ZERO,
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } => false,
            Bsdf::MetallicRoughness {
                base_color,
                metallic,
                specular,
                ..
            } => base_color == Vec3::ZERO && metallic == 0.0 && specular == 0.0,
        }
    }

    /// Perceptual roughness `√α` in `[0, 1]` (1 for Lambertian): a radiance-cache input.
    pub fn roughness(&self) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => 1.0,
            Bsdf::Conductor { alpha, .. }
            | Bsdf::Dielectric { alpha, .. }
            | Bsdf::MetallicRoughness { alpha, .. } => unit(alpha).sqrt(),
        }
    }

    /// Albedo-like summary of the diffuse part (radiance-cache input).
    pub fn diffuse_reflectance(&self) -> Vec3 {
        match *self {
            Bsdf::Diffuse { albedo } => albedo,
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } => Vec3::ZERO,
            Bsdf::MetallicRoughness { .. } => self
                .metallic_roughness()
                .map_or(Vec3::ZERO, |m| m.diffuse_reflectance()),
        }
    }

    /// Albedo-like summary of the specular part: the normal-incidence reflectance
    /// (radiance-cache input).
    pub fn specular_reflectance(&self) -> Vec3 {
        match *self {
            Bsdf::Diffuse { .. } => Vec3::ZERO,
            Bsdf::Conductor { f0, .. } => f0,
            Bsdf::Dielectric { eta, .. } => Vec3::splat(f0_from_ior(eta)),
            Bsdf::MetallicRoughness { .. } => self
                .metallic_roughness()
                .map_or(Vec3::ZERO, |m| m.specular_reflectance()),
        }
    }
}
