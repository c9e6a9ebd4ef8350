//! `ajar`: a room lit only through a door left ajar, after Veach's "door" scene (Veach 1997,
//! ch. 10). The only light is a ceiling panel in a small room next door; it reaches the main
//! room through the wedge-shaped gap between the open door and its frame, so almost all of
//! what the camera sees is lit by paths of three and more segments. No emitter is visible
//! from the camera (a render at `--max-depth 1` is black).
//!
//! Everything is built from closed boxes (walls 0.1 m thick) so that no surface is seen from
//! behind. Units are metres; +y is up.

use glam::{Quat, Vec3};

use crate::gltf_doc::{Document, Material, Transform};
use crate::mesh::Mesh;

/// Main room interior: x ∈ [0, 5], y ∈ [0, 2.6], z ∈ [0, 5].
pub const ROOM: Vec3 = Vec3::new(5.0, 2.6, 5.0);
/// The wall between the rooms: x ∈ [5, 5.1].
pub const DIVIDER: (f32, f32) = (5.0, 5.1);
/// The doorway in the divider: z ∈ [2.0, 2.9], y ∈ [0, 2.1].
pub const DOORWAY_Z: (f32, f32) = (2.0, 2.9);
pub const DOORWAY_HEIGHT: f32 = 2.1;
/// The room next door: x ∈ [5.1, 7.1], z ∈ [1.0, 4.0].
pub const NEXT_ROOM_X: (f32, f32) = (5.1, 7.1);
pub const NEXT_ROOM_Z: (f32, f32) = (1.0, 4.0);
/// How far the door is opened, swinging into the room next door about its hinge at z = 2.0.
pub const DOOR_ANGLE_DEG: f32 = 20.0;
/// The light: a 0.6 m × 1.0 m ceiling panel in the room next door, facing down.
pub const LIGHT_MIN: Vec3 = Vec3::new(6.3, 2.59, 2.6);
pub const LIGHT_MAX: Vec3 = Vec3::new(6.9, 2.59, 3.6);
pub const LIGHT_RADIANCE: Vec3 = Vec3::new(600.0, 570.0, 510.0);

const T: f32 = 0.1;

fn cuboid(min: [f32; 3], max: [f32; 3]) -> Mesh {
    Mesh::cuboid(Vec3::from(min), Vec3::from(max))
}

pub fn build() -> Document {
    let mut doc = Document::default();
    let wall = doc.add_material(Material::diffuse("wall", Vec3::new(0.75, 0.74, 0.7)));
    let ceiling = doc.add_material(Material::diffuse("ceiling", Vec3::splat(0.8)));
    let floor = doc.add_material(Material::diffuse("floor_wood", Vec3::new(0.42, 0.3, 0.2)));
    let next_wall = doc.add_material(Material::diffuse("next_room_wall", Vec3::splat(0.8)));
    let door = doc.add_material(Material::diffuse("door", Vec3::new(0.6, 0.56, 0.5)));
    let table = doc.add_material(Material::diffuse("table", Vec3::new(0.45, 0.28, 0.15)));
    let cabinet = doc.add_material(Material::diffuse("cabinet", Vec3::new(0.2, 0.3, 0.5)));
    let cube = doc.add_material(Material::diffuse("red_cube", Vec3::new(0.6, 0.12, 0.08)));
    let bench = doc.add_material(Material::diffuse("bench", Vec3::new(0.35, 0.45, 0.3)));
    let copper = doc.add_material(Material::conductor(
        "copper",
        Vec3::new(0.955, 0.638, 0.538),
        0.25,
    ));
    let light = doc.add_material(Material::emitter(
        "light",
        LIGHT_RADIANCE,
        Vec3::ZERO,
        false,
    ));

    let (x, y, z) = (ROOM.x, ROOM.y, ROOM.z);
    let (d0, d1) = DIVIDER;
    let (g0, g1) = DOORWAY_Z;
    let (n0, n1) = NEXT_ROOM_X;
    let (m0, m1) = NEXT_ROOM_Z;

    // Main room shell.
    let mut walls = Mesh::default();
    walls.append(&cuboid([-T, 0.0, -T], [0.0, y, z + T]));
    walls.append(&cuboid([0.0, 0.0, -T], [x, y, 0.0]));
    walls.append(&cuboid([0.0, 0.0, z], [x, y, z + T]));
    // The divider with its doorway: beside the door on both sides, and the lintel above it.
    walls.append(&cuboid([d0, 0.0, -T], [d1, y, g0]));
    walls.append(&cuboid([d0, 0.0, g1], [d1, y, z + T]));
    walls.append(&cuboid([d0, DOORWAY_HEIGHT, g0], [d1, y, g1]));
    doc.add_object("walls", &walls, wall, Transform::IDENTITY);
    doc.add_object(
        "floor",
        &cuboid([-T, -T, -T], [d1, 0.0, z + T]),
        floor,
        Transform::IDENTITY,
    );
    doc.add_object(
        "ceiling",
        &cuboid([-T, y, -T], [d1, y + T, z + T]),
        ceiling,
        Transform::IDENTITY,
    );

    // The room next door, closed on its three other sides, floor and ceiling.
    let mut next = Mesh::default();
    next.append(&cuboid([d1, -T, m0 - T], [n1 + T, 0.0, m1 + T]));
    next.append(&cuboid([d1, y, m0 - T], [n1 + T, y + T, m1 + T]));
    next.append(&cuboid([n1, 0.0, m0 - T], [n1 + T, y, m1 + T]));
    next.append(&cuboid([d1, 0.0, m0 - T], [n1, y, m0]));
    next.append(&cuboid([d1, 0.0, m1], [n1, y, m1 + T]));
    doc.add_object("next_room", &next, next_wall, Transform::IDENTITY);
    debug_assert!(n0 == d1);

    // The door: 0.88 m × 2.08 m × 0.04 m, hinged at the doorway's z = 2.0 edge inside the
    // wall's thickness, opened into the room next door (a rotation about +y turns its free
    // edge from +z towards +x).
    let slab = cuboid(
        [-0.02, 0.01, 0.0],
        [0.02, DOORWAY_HEIGHT - 0.01, g1 - g0 - 0.02],
    );
    let hinge = Vec3::new((d0 + d1) / 2.0, 0.0, g0 + 0.005);
    let placement = Transform {
        translation: hinge,
        rotation: Quat::from_rotation_y(DOOR_ANGLE_DEG.to_radians()),
        scale: 1.0,
    };
    doc.add_object("door", &slab, door, placement);

    // Furniture: a table with a red cube and a copper ball on it, a cabinet in the far
    // corner and a bench under the window-less wall. Rotations are node transforms.
    doc.add_object(
        "table",
        &cuboid([-0.6, 0.0, -0.4], [0.6, 0.75, 0.4]),
        table,
        Transform {
            translation: Vec3::new(2.8, 0.0, 3.5),
            rotation: Quat::from_rotation_y(12f32.to_radians()),
            scale: 1.0,
        },
    );
    doc.add_object(
        "red_cube",
        &cuboid([-0.12, 0.0, -0.12], [0.12, 0.24, 0.12]),
        cube,
        Transform {
            translation: Vec3::new(2.5, 0.75, 3.4),
            rotation: Quat::from_rotation_y(35f32.to_radians()),
            scale: 1.0,
        },
    );
    doc.add_object(
        "copper_ball",
        &Mesh::uv_sphere(1.0, 64, 32),
        copper,
        Transform {
            scale: 0.18,
            ..Transform::at(Vec3::new(3.15, 0.75 + 0.18, 3.65))
        },
    );
    doc.add_object(
        "cabinet",
        &cuboid([-0.3, 0.0, -0.25], [0.3, 1.8, 0.25]),
        cabinet,
        Transform::at(Vec3::new(4.6, 0.0, 4.7)),
    );
    doc.add_object(
        "bench",
        &cuboid([-0.7, 0.0, -0.2], [0.7, 0.45, 0.2]),
        bench,
        Transform::at(Vec3::new(3.6, 0.0, 0.35)),
    );

    let lamp = Mesh::quad_facing(
        [
            Vec3::new(LIGHT_MIN.x, LIGHT_MIN.y, LIGHT_MIN.z),
            Vec3::new(LIGHT_MAX.x, LIGHT_MIN.y, LIGHT_MIN.z),
            Vec3::new(LIGHT_MAX.x, LIGHT_MIN.y, LIGHT_MAX.z),
            Vec3::new(LIGHT_MIN.x, LIGHT_MIN.y, LIGHT_MAX.z),
        ],
        Vec3::new(6.6, 0.0, 3.1),
    );
    doc.add_object("light", &lamp, light, Transform::IDENTITY);

    doc.add_camera(
        "camera",
        65.0,
        Transform::look_at(Vec3::new(0.5, 1.5, 0.7), Vec3::new(4.5, 0.9, 3.4), Vec3::Y),
    );
    doc
}
