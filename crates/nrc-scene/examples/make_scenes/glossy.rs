//! `glossy`: glossy transport from mirror-like to rough. A back row of gold conductors
//! (metallic 1) at roughness 0.05 … 0.8, a front row of clear glass spheres at roughness
//! 0 … 0.6, and behind them a panel with textured metallic-roughness (metal and paint
//! cells, roughness growing from left to right), all on a checkered diffuse floor under a
//! large overhead light, with a dim emissive backdrop behind the panel standing in for a sky.

use glam::Vec3;

use crate::gltf_doc::{Document, Material, Transform};
use crate::mesh::Mesh;
use crate::textures::{Image, checker, srgb_pixel, unorm};

/// Normal-incidence reflectance of gold as linear RGB (the usual F0 table of real-time
/// rendering: Hoffman, "Physics and Math of Shading", SIGGRAPH 2015 course).
pub const GOLD: Vec3 = Vec3::new(1.0, 0.782, 0.344);
pub const SILVER: Vec3 = Vec3::new(0.972, 0.960, 0.915);
pub const CONDUCTOR_ROUGHNESS: [f32; 5] = [0.05, 0.2, 0.35, 0.5, 0.8];
pub const GLASS_ROUGHNESS: [f32; 5] = [0.0, 0.1, 0.25, 0.4, 0.6];
pub const GLASS_IOR: f32 = 1.5;
pub const SPHERE_RADIUS: f32 = 0.3;
pub const SPACING: f32 = 0.8;
/// Overhead light: 3 m × 1.5 m at height 3 m, facing down.
pub const LIGHT_RADIANCE: Vec3 = Vec3::splat(6.0);
/// Backdrop: a dim emitter far behind the scene, facing it.
pub const BACKDROP_RADIANCE: Vec3 = Vec3::new(0.25, 0.3, 0.4);

/// Panel texture layout: 8 columns × 4 rows of 64-pixel cells.
const COLS: u32 = 8;
const ROWS: u32 = 4;
const CELL: u32 = 64;

/// The roughness of column `c` of the panel's texture.
pub fn panel_roughness(col: u32) -> f32 {
    0.05 + (0.8 - 0.05) * col as f32 / (COLS - 1) as f32
}

/// Whether a panel cell is metal (checkerboard of metal and paint).
pub fn panel_is_metal(col: u32, row: u32) -> bool {
    (col + row).is_multiple_of(2)
}

fn panel_textures() -> (Image, Image) {
    let paint = [Vec3::new(0.05, 0.15, 0.55), Vec3::new(0.6, 0.08, 0.05)];
    let base = Image::from_fn(COLS * CELL, ROWS * CELL, |x, y| {
        let (col, row) = (x / CELL, y / CELL);
        let top = row < ROWS / 2;
        if panel_is_metal(col, row) {
            srgb_pixel(if top { GOLD } else { SILVER })
        } else {
            srgb_pixel(paint[usize::from(!top)])
        }
    });
    // glTF metallic-roughness texture: G = roughness, B = metallic (R unused: left at 1).
    let metallic_roughness = Image::from_fn(COLS * CELL, ROWS * CELL, |x, y| {
        let (col, row) = (x / CELL, y / CELL);
        [
            255,
            unorm(panel_roughness(col)),
            if panel_is_metal(col, row) { 255 } else { 0 },
        ]
    });
    (base, metallic_roughness)
}

pub fn build() -> Document {
    let mut doc = Document::default();

    // Floor: a 10 m × 10 m checkerboard of 0.25 m squares.
    let floor_texture = doc.add_png_texture(
        "glossy-floor.png",
        checker(40, 16, Vec3::splat(0.6), Vec3::splat(0.15)).encode_png(),
        true,
    );
    let floor_material = doc.add_material(Material {
        base_color: Vec3::ONE,
        base_color_texture: Some(floor_texture),
        ..Material::diffuse("floor", Vec3::ONE)
    });
    let h = 5.0;
    let floor = Mesh::textured_quad(
        Vec3::new(-h, 0.0, -h),
        Vec3::new(-h, 0.0, h),
        Vec3::new(h, 0.0, h),
        Vec3::new(h, 0.0, -h),
    );
    doc.add_object("floor", &floor, floor_material, Transform::IDENTITY);

    // One sphere geometry shared by all ten spheres; each row is a group node.
    let sphere = doc.add_geometry(&Mesh::uv_sphere(1.0, 64, 32));
    let rows = [
        (
            "conductors",
            -0.9,
            CONDUCTOR_ROUGHNESS.map(|r| Material::conductor(&format!("gold_r{r:.2}"), GOLD, r)),
        ),
        (
            "dielectrics",
            0.2,
            GLASS_ROUGHNESS.map(|r| Material::dielectric(&format!("glass_r{r:.2}"), r, GLASS_IOR)),
        ),
    ];
    for (row_name, z, materials) in rows {
        let group = doc.add_group(row_name, Transform::at(Vec3::new(0.0, SPHERE_RADIUS, z)));
        for (i, material) in materials.into_iter().enumerate() {
            let name = material.name.clone();
            let m = doc.add_material(material);
            let mesh = doc.add_mesh(&name, sphere, m);
            let x = (i as f32 - 2.0) * SPACING;
            let node = doc.add_mesh_node(
                &name,
                mesh,
                Transform {
                    scale: SPHERE_RADIUS,
                    ..Transform::at(Vec3::new(x, 0.0, 0.0))
                },
            );
            doc.add_child(group, node);
        }
    }

    // The textured panel: 3.2 m × 1.6 m, standing on the floor behind the spheres.
    let (base, metallic_roughness) = panel_textures();
    let base_texture = doc.add_png_texture("glossy-panel-base-color.png", base.encode_png(), true);
    let mr_texture = doc.add_png_texture(
        "glossy-panel-metallic-roughness.png",
        metallic_roughness.encode_png(),
        true,
    );
    let panel_material = doc.add_material(Material {
        base_color: Vec3::ONE,
        base_color_texture: Some(base_texture),
        metallic: 1.0,
        roughness: 1.0,
        metallic_roughness_texture: Some(mr_texture),
        specular: None,
        ..Material::diffuse("textured_panel", Vec3::ONE)
    });
    let (pz, pw, ph) = (-2.0, 1.6, 1.6);
    let panel = Mesh::textured_quad(
        Vec3::new(-pw, ph, pz),
        Vec3::new(-pw, 0.0, pz),
        Vec3::new(pw, 0.0, pz),
        Vec3::new(pw, ph, pz),
    );
    doc.add_object(
        "textured_panel",
        &panel,
        panel_material,
        Transform::IDENTITY,
    );

    // Lights: the overhead panel, facing down, and the dim backdrop far behind.
    let light = doc.add_material(Material::emitter(
        "overhead_light",
        LIGHT_RADIANCE,
        Vec3::ZERO,
        false,
    ));
    let lamp = Mesh::quad_facing(
        [
            Vec3::new(-1.5, 3.0, -1.25),
            Vec3::new(1.5, 3.0, -1.25),
            Vec3::new(1.5, 3.0, 0.25),
            Vec3::new(-1.5, 3.0, 0.25),
        ],
        Vec3::ZERO,
    );
    doc.add_object("overhead_light", &lamp, light, Transform::IDENTITY);
    let backdrop_material = doc.add_material(Material::emitter(
        "backdrop",
        BACKDROP_RADIANCE,
        Vec3::ZERO,
        false,
    ));
    let backdrop = Mesh::quad(
        Vec3::new(-h, 0.0, -h),
        Vec3::new(h, 0.0, -h),
        Vec3::new(h, 5.0, -h),
        Vec3::new(-h, 5.0, -h),
    );
    doc.add_object(
        "backdrop",
        &backdrop,
        backdrop_material,
        Transform::IDENTITY,
    );

    doc.add_camera(
        "camera",
        42.0,
        Transform::look_at(
            Vec3::new(0.0, 2.0, 5.2),
            Vec3::new(0.0, 0.45, -0.6),
            Vec3::Y,
        ),
    );
    doc
}
