//! `rocks`: a field of 256 rocks on a ground plane, 5.12 M triangles from 0.34 MB of files.
//! One rock (a sphere of 20,000 triangles, displaced by a smooth function of the direction)
//! is stored once and instanced by 256 nodes, each with its own position, scale, rotation
//! and one of four materials (three diffuse greys and browns, one rough metal). Lit by a low
//! sun (a directional light) and a square ceiling-less area light above the field. The scale
//! test of the loader and the BVH: what a production scene's triangle count costs in load
//! time and memory, and that glTF meshes instanced by many nodes are loaded as such.

use glam::{Quat, Vec3};

use crate::gltf_doc::{Document, Light, LightKind, Material, Transform};
use crate::hash;
use crate::mesh::Mesh;

/// Rocks along x and z.
pub const GRID: u32 = 16;
/// Distance between neighbouring rocks' grid places, metres.
pub const SPACING: f32 = 1.6;
/// The rock's sphere: segments around, rings from pole to pole (20,000 triangles).
const SEGMENTS: u32 = 100;
const RINGS: u32 = 101;

/// A number in [0, 1) from `hash(seed)`.
fn unit(seed: u32) -> f32 {
    (hash(seed) >> 8) as f32 / (1u32 << 24) as f32
}

/// The rock: a unit sphere whose radius varies smoothly with the direction (by up to about
/// ±25 %), flat-shaded (no vertex normals: the loader takes each triangle's own). The
/// displacement is a function of the direction's coordinates, so the sphere's seam and
/// poles, whose vertices coincide, stay closed.
fn rock() -> Mesh {
    let mut m = Mesh::uv_sphere(1.0, SEGMENTS, RINGS);
    for p in &mut m.positions {
        let n = *p;
        let r = 1.0
            + 0.14 * (3.1 * n.x + 1.7 * n.y).sin() * (2.3 * n.z).cos()
            + 0.07 * (7.3 * n.y - 2.9 * n.z).sin()
            + 0.03 * (13.0 * n.x + 11.0 * n.z).sin();
        *p = n * r;
    }
    m.normals = None;
    m.uvs = None;
    m
}

pub fn build() -> Document {
    let mut doc = Document::default();
    let ground_m = doc.add_material(Material::diffuse("ground", Vec3::new(0.42, 0.4, 0.36)));
    let materials = [
        doc.add_material(Material::diffuse("granite", Vec3::new(0.55, 0.55, 0.53))),
        doc.add_material(Material::diffuse("sandstone", Vec3::new(0.62, 0.45, 0.3))),
        doc.add_material(Material::diffuse("basalt", Vec3::new(0.18, 0.18, 0.2))),
        doc.add_material(Material::conductor("ore", Vec3::new(0.75, 0.6, 0.4), 0.45)),
    ];
    let light_m = doc.add_material(Material::emitter(
        "panel",
        Vec3::new(6.0, 6.0, 5.5),
        Vec3::ZERO,
        false,
    ));

    let half = 0.5 * GRID as f32 * SPACING + 2.0;
    let ground = Mesh::quad(
        Vec3::new(-half, 0.0, -half),
        Vec3::new(-half, 0.0, half),
        Vec3::new(half, 0.0, half),
        Vec3::new(half, 0.0, -half),
    );
    doc.add_object("ground", &ground, ground_m, Transform::IDENTITY);

    // One geometry, four glTF meshes (one per material) sharing it, 256 nodes.
    let geometry = doc.add_geometry(&rock());
    let meshes = materials.map(|m| doc.add_mesh("rock", geometry, m));
    for i in 0..GRID {
        for j in 0..GRID {
            let k = i * GRID + j;
            let scale = 0.3 + 0.35 * unit(4 * k);
            let jitter = Vec3::new(unit(4 * k + 1) - 0.5, 0.0, unit(4 * k + 2) - 0.5) * 0.5;
            let place = Vec3::new(
                (i as f32 + 0.5 - 0.5 * GRID as f32) * SPACING,
                0.6 * scale,
                (j as f32 + 0.5 - 0.5 * GRID as f32) * SPACING,
            ) + jitter * SPACING;
            let transform = Transform {
                translation: place,
                rotation: Quat::from_rotation_y(std::f32::consts::TAU * unit(4 * k + 3)),
                scale,
            };
            let mesh = meshes[hash(k + 101) as usize % meshes.len()];
            doc.add_mesh_node(&format!("rock_{k:03}"), mesh, transform);
        }
    }

    // A square panel light 6 m above the field's centre, facing down.
    let h = 1.5;
    let y = 6.0;
    let panel = Mesh::quad_facing(
        [
            Vec3::new(-h, y, -h),
            Vec3::new(h, y, -h),
            Vec3::new(h, y, h),
            Vec3::new(-h, y, h),
        ],
        Vec3::ZERO,
    );
    doc.add_object("panel", &panel, light_m, Transform::IDENTITY);
    doc.add_light(
        Light {
            name: "sun".into(),
            kind: LightKind::Directional,
            color: Vec3::new(1.0, 0.9, 0.75),
            intensity: 2.5,
        },
        Transform::facing(Vec3::ZERO, Vec3::new(0.6, -0.45, 0.35), Vec3::Y),
    );

    doc.add_camera(
        "camera",
        45.0,
        Transform::look_at(
            Vec3::new(-15.0, 4.5, 11.0),
            Vec3::new(0.5, 0.0, -0.5),
            Vec3::Y,
        ),
    );
    doc
}
