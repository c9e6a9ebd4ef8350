//! `sun-spot-env`: a few diffuse objects and one rough conductor on a floor, lit by the three
//! `KHR_lights_punctual` kinds (a directional sun placed by its node's rotation, a warm spot
//! and a cool point light) and meant to be rendered under `sky.exr`, a small smooth HDR sky
//! with a soft sun blob in the sun's direction (`--env scenes/sky.exr`). It tests delta lights
//! and the environment map, alone and together; the scene has no emissive triangle.
//!
//! Units: `color × intensity` is used as radiant intensity (point, spot; W sr⁻¹ per channel)
//! or irradiance (sun; W m⁻² per channel), as the loader reads glTF's candela and lux.

use std::f32::consts::PI;
use std::path::Path;

use glam::Vec3;

use crate::gltf_doc::{Document, Light, LightKind, Material, Transform};
use crate::mesh::Mesh;

/// Direction the sunlight travels: from elevation 40°, azimuth such that it comes from the
/// left and behind, seen from the camera (from −x and −z).
pub fn sun_travel() -> Vec3 {
    let (el, az) = (SUN_ELEVATION_DEG.to_radians(), SUN_AZIMUTH_DEG.to_radians());
    -Vec3::new(-el.cos() * az.cos(), el.sin(), -el.cos() * az.sin())
}
pub const SUN_ELEVATION_DEG: f32 = 40.0;
/// From −x towards −z.
pub const SUN_AZIMUTH_DEG: f32 = 35.0;
/// Sun irradiance at normal incidence (warm white).
pub const SUN_COLOR: Vec3 = Vec3::new(1.0, 0.93, 0.8);
pub const SUN_IRRADIANCE: f32 = 1.5;
/// The spot: above and to the right of the camera, aimed at the floor before the objects;
/// a nearly hard cone (inner 24.5°, outer 25°) so that renderers with other falloff curves
/// (Mitsuba's is linear in angle) agree except in a thin band.
pub const SPOT_POSITION: Vec3 = Vec3::new(1.6, 3.2, 2.2);
pub const SPOT_TARGET: Vec3 = Vec3::new(0.4, 0.0, 0.4);
pub const SPOT_INNER_DEG: f32 = 24.5;
pub const SPOT_OUTER_DEG: f32 = 25.0;
pub const SPOT_COLOR: Vec3 = Vec3::new(1.0, 0.75, 0.45);
pub const SPOT_INTENSITY: f32 = 30.0;
/// The point light: low, to the left of the objects.
pub const POINT_POSITION: Vec3 = Vec3::new(-1.5, 0.5, 1.6);
pub const POINT_COLOR: Vec3 = Vec3::new(0.55, 0.75, 1.0);
pub const POINT_INTENSITY: f32 = 6.0;

pub fn build() -> Document {
    let mut doc = Document::default();
    let floor_m = doc.add_material(Material::diffuse("floor", Vec3::new(0.6, 0.6, 0.58)));
    let red = doc.add_material(Material::diffuse("red", Vec3::new(0.6, 0.12, 0.08)));
    let white = doc.add_material(Material::diffuse("white", Vec3::new(0.75, 0.74, 0.7)));
    let blue = doc.add_material(Material::diffuse("blue", Vec3::new(0.15, 0.3, 0.6)));
    // Copper (the normal-incidence reflectance used in `ajar`), roughness 0.4.
    let copper = doc.add_material(Material::conductor(
        "rough_copper",
        Vec3::new(0.955, 0.638, 0.538),
        0.4,
    ));

    let h = 5.0;
    let floor = Mesh::quad(
        Vec3::new(-h, 0.0, -h),
        Vec3::new(-h, 0.0, h),
        Vec3::new(h, 0.0, h),
        Vec3::new(h, 0.0, -h),
    );
    doc.add_object("floor", &floor, floor_m, Transform::IDENTITY);
    doc.add_object(
        "red_box",
        &Mesh::cuboid(Vec3::new(-1.6, 0.0, -0.9), Vec3::new(-0.8, 0.8, -0.1)),
        red,
        Transform::IDENTITY,
    );
    doc.add_object(
        "white_pillar",
        &Mesh::cuboid(Vec3::new(0.9, 0.0, -1.4), Vec3::new(1.4, 1.6, -0.9)),
        white,
        Transform::IDENTITY,
    );
    let sphere = doc.add_geometry(&Mesh::uv_sphere(1.0, 32, 16));
    let blue_mesh = doc.add_mesh("blue_ball", sphere, blue);
    doc.add_mesh_node(
        "blue_ball",
        blue_mesh,
        Transform {
            scale: 0.35,
            ..Transform::at(Vec3::new(-0.5, 0.35, 0.9))
        },
    );
    let copper_mesh = doc.add_mesh("copper_ball", sphere, copper);
    doc.add_mesh_node(
        "copper_ball",
        copper_mesh,
        Transform {
            scale: 0.5,
            ..Transform::at(Vec3::new(0.35, 0.5, 0.0))
        },
    );

    // The sun: a directional light; only its node's rotation matters.
    doc.add_light(
        Light {
            name: "sun".into(),
            kind: LightKind::Directional,
            color: SUN_COLOR,
            intensity: SUN_IRRADIANCE,
        },
        Transform::facing(Vec3::ZERO, sun_travel(), Vec3::Y),
    );
    doc.add_light(
        Light {
            name: "spot".into(),
            kind: LightKind::Spot {
                inner_cone_angle: SPOT_INNER_DEG.to_radians(),
                outer_cone_angle: SPOT_OUTER_DEG.to_radians(),
            },
            color: SPOT_COLOR,
            intensity: SPOT_INTENSITY,
        },
        Transform::facing(SPOT_POSITION, SPOT_TARGET - SPOT_POSITION, Vec3::Y),
    );
    doc.add_light(
        Light {
            name: "point".into(),
            kind: LightKind::Point,
            color: POINT_COLOR,
            intensity: POINT_INTENSITY,
        },
        Transform::at(POINT_POSITION),
    );

    doc.add_camera(
        "camera",
        40.0,
        Transform::look_at(Vec3::new(0.0, 2.0, 5.0), Vec3::new(0.0, 0.45, 0.0), Vec3::Y),
    );
    doc
}

/// Width and height of `sky.exr` (equirectangular, 2:1).
pub const SKY_SIZE: (usize, usize) = (128, 64);
/// Sky radiance at the zenith and at the horizon, and of the ground below the horizon.
pub const SKY_ZENITH: Vec3 = Vec3::new(0.12, 0.25, 0.6);
pub const SKY_HORIZON: Vec3 = Vec3::new(0.6, 0.65, 0.7);
pub const SKY_GROUND: Vec3 = Vec3::new(0.12, 0.11, 0.1);
/// The sun blob: peak radiance added and angular standard deviation of its Gaussian.
pub const SKY_SUN_PEAK: Vec3 = Vec3::new(12.0, 11.0, 9.0);
pub const SKY_SUN_SIGMA_DEG: f32 = 6.0;

/// The sky as seen looking along unit direction `d` (Mitsuba's `envmap` orientation, +y up):
/// a gradient in elevation (horizon to zenith as the square root of sin(elevation); the ground
/// blends from the horizon colour within 5° below it) plus a Gaussian blob toward the sun.
pub fn sky_radiance(d: Vec3) -> Vec3 {
    let y = d.y.clamp(-1.0, 1.0);
    let base = if y >= 0.0 {
        SKY_HORIZON.lerp(SKY_ZENITH, y.sqrt())
    } else {
        let t = (-y / 5f32.to_radians().sin()).min(1.0);
        SKY_HORIZON.lerp(SKY_GROUND, t * t * (3.0 - 2.0 * t))
    };
    let angle = d.dot(-sun_travel()).clamp(-1.0, 1.0).acos();
    let s = SKY_SUN_SIGMA_DEG.to_radians();
    base + SKY_SUN_PEAK * (-0.5 * (angle / s) * (angle / s)).exp()
}

/// Writes `sky.exr` into `dir`: each texel holds the sky at its centre's direction
/// (u = atan2(d.x, −d.z)/2π, v = acos(d.y)/π, row 0 the zenith).
pub fn write_sky(dir: &Path) -> Result<(), String> {
    let (w, h) = SKY_SIZE;
    let mut image = nrc_scene::Image::new(w, h);
    for row in 0..h {
        for col in 0..w {
            let (u, v) = ((col as f32 + 0.5) / w as f32, (row as f32 + 0.5) / h as f32);
            let (sp, cp) = (2.0 * PI * u).sin_cos();
            let (st, ct) = (PI * v).sin_cos();
            let d = Vec3::new(sp * st, ct, -cp * st);
            image.set(col, row, sky_radiance(d));
        }
    }
    let path = dir.join("sky.exr");
    image
        .write_exr(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    // Read it back through the loader's environment path: the same texels, no warning.
    let (env, warning) = nrc_scene::Environment::load(&path, 1.0, 0.0)
        .map_err(|e| format!("{}: environment loader: {e}", path.display()))?;
    if let Some(w) = warning {
        return Err(format!("{}: environment loader warns: {w}", path.display()));
    }
    let probe = -sun_travel();
    let (got, want) = (env.radiance(probe), sky_radiance(probe));
    if (got - want).abs().max_element() > 0.1 * want.max_element() {
        return Err(format!(
            "{}: the loader sees {got} toward the sun, the sky there is {want}",
            path.display()
        ));
    }
    Ok(())
}
