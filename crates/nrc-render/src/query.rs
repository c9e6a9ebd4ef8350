//! A radiance query: the radiance leaving a surface point toward a direction, with what a
//! learned source needs of the surface there. What a walk asks and a source answers
//! ([`crate::source`]).

use glam::Vec3;
use nrc_scene::{SurfaceInteraction, bsdf::Bsdf};

/// The radiance leaving a surface point toward a direction, with what a learned source needs
/// to know of the surface there (the inputs of the reflectance factorisation). World space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadianceQuery {
    pub position: Vec3,
    /// Unit direction the radiance leaves in.
    pub direction: Vec3,
    /// Shading normal.
    pub normal: Vec3,
    /// Perceptual roughness of the BSDF.
    pub roughness: f32,
    pub diffuse: Vec3,
    pub specular: Vec3,
}

impl RadianceQuery {
    /// The query for the radiance leaving `si` toward `wo` (unit, world space).
    pub fn at(si: &SurfaceInteraction, bsdf: &Bsdf, wo: Vec3) -> Self {
        Self {
            position: si.p,
            direction: wo,
            normal: si.ns,
            roughness: bsdf.roughness(),
            diffuse: bsdf.diffuse_reflectance(),
            specular: bsdf.specular_reflectance(),
        }
    }
}
