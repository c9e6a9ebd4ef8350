//! Surface scattering: the closed `Bsdf` enum and its parameters.

use glam::Vec3;

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
