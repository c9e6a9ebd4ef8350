//! `caustics`: a smooth glass sphere on a diffuse floor before a back wall, lit by one
//! small, bright, one-sided square light high up to the left and behind. The sphere focuses
//! the light into a caustic on the floor inside its shadow: light reaches the camera there
//! only along light → glass → glass → floor → camera, a path a camera-side path tracer finds
//! only by hitting the small light with a sampled direction.

use glam::Vec3;

use crate::gltf_doc::{Document, Material, Transform};
use crate::mesh::Mesh;

pub const SPHERE_RADIUS: f32 = 0.5;
pub const SPHERE_CENTRE: Vec3 = Vec3::new(0.0, SPHERE_RADIUS, 0.0);
/// Glass index of refraction (crown glass, as glTF's default).
pub const IOR: f32 = 1.5;
/// Side of the square light (metres).
pub const LIGHT_SIZE: f32 = 0.1;
/// Distance from the sphere's centre to the light's centre (metres).
pub const LIGHT_DISTANCE: f32 = 3.0;
/// Elevation of the light seen from the sphere's centre. A ball lens of index n focuses
/// parallel light at n·R / (2(n − 1)) = 1.5 R from its centre; a ray through the centre at
/// elevation θ meets the floor R / sin θ from the centre. At sin θ = 2/3 (41.8°) the focus
/// would lie on the floor (a tiny, very bright spot); at 60° the floor cuts the converging
/// beam at 1.15 R, before the focus, giving a bright caustic pool under the sphere.
pub const LIGHT_ELEVATION_DEG: f32 = 60.0;
/// Azimuth of the light, from −x towards −z (to the left and behind, seen from the camera).
pub const LIGHT_AZIMUTH_DEG: f32 = 30.0;
/// Warm-white radiance of the light; with the floor's albedo this exposes the lit floor at
/// about 0.5 (see scenes/README.md).
pub const LIGHT_RADIANCE: Vec3 = Vec3::new(3000.0, 2790.0, 2550.0);

pub fn build() -> Document {
    let mut doc = Document::default();
    let floor_material = doc.add_material(Material::diffuse("floor", Vec3::new(0.75, 0.75, 0.72)));
    let wall_material =
        doc.add_material(Material::diffuse("back_wall", Vec3::new(0.55, 0.6, 0.65)));
    let glass = doc.add_material(Material::dielectric("glass", 0.0, IOR));
    let light_material = doc.add_material(Material::emitter(
        "light",
        LIGHT_RADIANCE,
        Vec3::ZERO,
        false,
    ));

    let h = 4.0;
    let floor = Mesh::quad(
        Vec3::new(-h, 0.0, -2.0),
        Vec3::new(-h, 0.0, h),
        Vec3::new(h, 0.0, h),
        Vec3::new(h, 0.0, -2.0),
    );
    let wall = Mesh::quad(
        Vec3::new(-h, 0.0, -2.0),
        Vec3::new(h, 0.0, -2.0),
        Vec3::new(h, 4.0, -2.0),
        Vec3::new(-h, 4.0, -2.0),
    );
    doc.add_object("floor", &floor, floor_material, Transform::IDENTITY);
    doc.add_object("back_wall", &wall, wall_material, Transform::IDENTITY);

    // A finely tessellated sphere: smooth normals hide the facets in shading, and fine
    // facets keep the caustic's outline round.
    let sphere = Mesh::uv_sphere(1.0, 128, 64);
    doc.add_object(
        "glass_sphere",
        &sphere,
        glass,
        Transform {
            scale: SPHERE_RADIUS,
            ..Transform::at(SPHERE_CENTRE)
        },
    );

    // The light: a square facing the sphere's centre.
    let (el, az) = (
        LIGHT_ELEVATION_DEG.to_radians(),
        LIGHT_AZIMUTH_DEG.to_radians(),
    );
    let to_light = Vec3::new(-el.cos() * az.cos(), el.sin(), -el.cos() * az.sin());
    let centre = SPHERE_CENTRE + LIGHT_DISTANCE * to_light;
    let u = to_light.cross(Vec3::Y).normalize() * (LIGHT_SIZE / 2.0);
    let v = u.cross(to_light).normalize() * (LIGHT_SIZE / 2.0);
    let lamp = Mesh::quad_facing(
        [
            centre - u - v,
            centre + u - v,
            centre + u + v,
            centre - u + v,
        ],
        SPHERE_CENTRE,
    );
    doc.add_object("light", &lamp, light_material, Transform::IDENTITY);

    doc.add_camera(
        "camera",
        38.0,
        Transform::look_at(Vec3::new(0.3, 1.6, 3.2), Vec3::new(0.2, 0.3, 0.0), Vec3::Y),
    );
    doc
}
