//! Surface materials as glTF describes them: constant factors times optional textures,
//! resolved at a surface point into [`PbrParams`] (for the BSDF) and emitted radiance.

use glam::{Vec2, Vec3, Vec4};

use crate::bsdf::PbrParams;
use crate::texture::{Texture, TextureRef};

/// A glTF 2.0 metallic-roughness material with the extensions this crate implements:
/// `KHR_materials_emissive_strength` (folded into `emissive`), `KHR_materials_transmission`,
/// `KHR_materials_ior` and `KHR_materials_specular`. Colour factors are linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub base_color: Vec3,
    /// sRGB-decoded RGB multiplies `base_color`.
    pub base_color_texture: Option<TextureRef>,
    pub metallic: f32,
    /// Perceptual roughness (α = roughness²).
    pub roughness: f32,
    /// Linear; G multiplies `roughness`, B multiplies `metallic`.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Emitted radiance factor: `emissiveFactor × emissive_strength`.
    pub emissive: Vec3,
    /// sRGB-decoded RGB multiplies `emissive`.
    pub emissive_texture: Option<TextureRef>,
    pub transmission: f32,
    /// Linear; R multiplies `transmission`.
    pub transmission_texture: Option<TextureRef>,
    pub ior: f32,
    pub specular: f32,
    /// Linear; A multiplies `specular`.
    pub specular_texture: Option<TextureRef>,
    pub specular_color: Vec3,
    /// sRGB-decoded RGB multiplies `specular_color`.
    pub specular_color_texture: Option<TextureRef>,
    /// Tangent-space normal map (linear RGB), and its `scale` (glTF's `normalTexture.scale`).
    pub normal_texture: Option<TextureRef>,
    pub normal_scale: f32,
    /// How the base colour's alpha (factor × texture) cuts the surface.
    pub alpha_mode: AlphaMode,
    /// Base colour factor's alpha.
    pub alpha: f32,
    /// glTF `alphaCutoff` (MASK, and BLEND as this renderer treats it).
    pub alpha_cutoff: f32,
    /// glTF `doubleSided`. Geometry is always intersected from both sides; the flag only
    /// decides whether the back face emits (see [`Material::emits_toward`]).
    pub double_sided: bool,
}

impl Default for Material {
    /// The glTF default material (white, fully metallic, fully rough, not emissive).
    fn default() -> Self {
        let p = PbrParams::default();
        Self {
            name: "default".into(),
            base_color: p.base_color,
            base_color_texture: None,
            metallic: p.metallic,
            roughness: p.roughness,
            metallic_roughness_texture: None,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            transmission: p.transmission,
            transmission_texture: None,
            ior: p.ior,
            specular: p.specular,
            specular_texture: None,
            specular_color: p.specular_color,
            specular_color_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            alpha_mode: AlphaMode::Opaque,
            alpha: 1.0,
            alpha_cutoff: 0.5,
            double_sided: false,
        }
    }
}

/// glTF `alphaMode`. A path tracer has no draw order to blend in, so `Blend` is rendered as
/// coverage: the surface exists where alpha ≥ `alphaCutoff` (0.5 unless the file sets one),
/// exactly like `Mask`; the loader says so in a warning. Cut-away points are skipped by every
/// ray, shadow rays included.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AlphaMode {
    #[default]
    Opaque,
    Mask,
    Blend,
}

#[inline]
fn lookup(textures: &[Texture], r: &Option<TextureRef>, uv: &[Vec2; 2]) -> Vec4 {
    match r {
        Some(r) => textures[r.texture as usize].sample(r.uv(uv)),
        None => Vec4::ONE,
    }
}

impl Material {
    /// Whether the material emits light anywhere (a non-zero emissive factor).
    pub fn is_emissive(&self) -> bool {
        self.emissive.max_element() > 0.0
    }

    /// Material parameters at texture coordinate sets `uv` (`TEXCOORD_0`, `TEXCOORD_1`),
    /// textures applied and every value clamped to its valid range.
    #[inline]
    pub fn pbr(&self, textures: &[Texture], uv: &[Vec2; 2]) -> PbrParams {
        let base = lookup(textures, &self.base_color_texture, uv);
        let mr = lookup(textures, &self.metallic_roughness_texture, uv);
        let transmission = lookup(textures, &self.transmission_texture, uv).x;
        let specular = lookup(textures, &self.specular_texture, uv).w;
        let specular_color = lookup(textures, &self.specular_color_texture, uv).truncate();
        PbrParams {
            base_color: (self.base_color * base.truncate()).clamp(Vec3::ZERO, Vec3::ONE),
            metallic: (self.metallic * mr.z).clamp(0.0, 1.0),
            roughness: (self.roughness * mr.y).clamp(0.0, 1.0),
            transmission: (self.transmission * transmission).clamp(0.0, 1.0),
            ior: self.ior,
            specular: (self.specular * specular).clamp(0.0, 1.0),
            specular_color: (self.specular_color * specular_color).max(Vec3::ZERO),
        }
    }

    /// Emitted radiance of the front face at texture coordinate sets `uv` (no side test).
    #[inline]
    pub fn emission(&self, textures: &[Texture], uv: &[Vec2; 2]) -> Vec3 {
        if !self.is_emissive() {
            return Vec3::ZERO;
        }
        self.emissive
            * lookup(textures, &self.emissive_texture, uv)
                .truncate()
                .max(Vec3::ZERO)
    }

    /// Whether the material can cut surfaces away (MASK or BLEND).
    #[inline]
    pub fn has_cutout(&self) -> bool {
        self.alpha_mode != AlphaMode::Opaque
    }

    /// Whether the surface exists at texture coordinate sets `uv`: always for OPAQUE, else
    /// where alpha (factor × base colour texture's A) reaches the cutoff.
    #[inline]
    pub fn is_solid(&self, textures: &[Texture], uv: &[Vec2; 2]) -> bool {
        !self.has_cutout()
            || self.alpha * lookup(textures, &self.base_color_texture, uv).w >= self.alpha_cutoff
    }

    /// The tangent-space normal at `uv`: the texture's RGB mapped to `[−1, 1]`, x and y scaled
    /// by `normal_scale` (glTF's rule), normalised; `None` without a normal map.
    #[inline]
    pub fn mapped_normal(&self, textures: &[Texture], uv: &[Vec2; 2]) -> Option<Vec3> {
        let t = self.normal_texture.as_ref()?;
        let c = textures[t.texture as usize].sample(t.uv(uv)).truncate() * 2.0 - Vec3::ONE;
        let n = Vec3::new(c.x * self.normal_scale, c.y * self.normal_scale, c.z);
        let n = n.normalize_or_zero();
        (n != Vec3::ZERO && n.is_finite()).then_some(n)
    }

    /// Whether a surface with geometric normal `ng` emits toward direction `w` (pointing
    /// away from the surface). Decision: single-sided materials emit from the front face
    /// only (the side `ng`, from counter-clockwise winding, points to), as glTF back-face
    /// culling implies; `doubleSided` materials emit from both faces.
    #[inline]
    pub fn emits_toward(&self, ng: Vec3, w: Vec3) -> bool {
        self.double_sided || ng.dot(w) > 0.0
    }
}
