//! The local description of a ray–surface intersection.

use glam::{Vec2, Vec3};

use crate::geometry::{Ray, spawn_ray, spawn_ray_to};

/// Everything a shading routine needs to know about a surface point hit by a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceInteraction {
    /// Position, interpolated from the triangle's vertices with the hit's barycentrics.
    pub p: Vec3,
    /// Unit geometric normal, on the front side of the triangle (counter-clockwise winding
    /// as seen from it); not flipped toward the ray.
    pub ng: Vec3,
    /// Unit shading normal: interpolated vertex normal (or `ng` when the mesh has none),
    /// flipped into the hemisphere of `ng`.
    pub ns: Vec3,
    /// Texture coordinates `TEXCOORD_0` and `TEXCOORD_1` (zero when absent).
    pub uv: [Vec2; 2],
    /// Unit direction back along the incoming ray (toward its origin).
    pub wo: Vec3,
    /// Material index into the scene's materials.
    pub material: u32,
    /// Scene triangle index.
    pub tri: u32,
}

impl SurfaceInteraction {
    /// Whether the ray arrived on the front face (the side `ng` points to).
    #[inline]
    pub fn front_face(&self) -> bool {
        self.wo.dot(self.ng) > 0.0
    }

    /// A ray leaving this point in unit direction `dir`, offset against self-intersection.
    #[inline]
    pub fn spawn_ray(&self, dir: Vec3) -> Ray {
        spawn_ray(self.p, self.ng, dir)
    }

    /// A shadow ray from this point toward `target` that stops just before it.
    #[inline]
    pub fn spawn_ray_to(&self, target: Vec3) -> Ray {
        spawn_ray_to(self.p, self.ng, target)
    }
}
