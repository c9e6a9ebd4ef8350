//! `many-lights`: a closed hall (24 × 8 × 4 m) lit by 1,040 small ceiling lamps (each a
//! 12 cm square, one-sided, facing down) of 24 emissive materials, six colours at four powers
//! spread over a factor of 16, assigned by a hash of the lamp's place, plus four point lights
//! and two spots. Two rows of pillars and a few boxes cast shadows. The regime ReSTIR DI and
//! light trees are made for: from any point most of the emitted power is far away, so choosing
//! lights by power alone wastes nearly every sample.

use glam::Vec3;

use crate::gltf_doc::{Document, Light, LightKind, Material, Transform};
use crate::hash;
use crate::mesh::Mesh;

/// The hall's extent.
pub const HALL_MIN: Vec3 = Vec3::new(-12.0, 0.0, -4.0);
pub const HALL_MAX: Vec3 = Vec3::new(12.0, 4.0, 4.0);
/// Lamps along x and z.
pub const LAMPS: (usize, usize) = (52, 20);
/// Edge of a lamp's square, metres.
pub const LAMP_SIZE: f32 = 0.12;
/// Radiance of the weakest lamp of luminance-1 colour.
pub const LAMP_RADIANCE: f32 = 4.0;
/// The lamps' colours (luminance near 1).
const COLOURS: [Vec3; 6] = [
    Vec3::new(1.0, 0.92, 0.8),
    Vec3::new(1.3, 0.85, 0.45),
    Vec3::new(0.7, 0.95, 1.4),
    Vec3::new(1.6, 0.7, 0.6),
    Vec3::new(0.6, 1.2, 0.8),
    Vec3::new(1.1, 0.8, 1.5),
];
/// Power factors.
const POWERS: [f32; 4] = [1.0, 2.0, 5.0, 16.0];

pub fn build() -> Document {
    let mut doc = Document::default();
    let wall = doc.add_material(Material::diffuse("wall", Vec3::new(0.7, 0.68, 0.64)));
    let floor_m = doc.add_material(Material::diffuse("floor", Vec3::new(0.45, 0.42, 0.38)));
    let pillar_m = doc.add_material(Material::diffuse("pillar", Vec3::new(0.6, 0.6, 0.62)));
    let box_m = doc.add_material(Material::diffuse("crate", Vec3::new(0.55, 0.3, 0.15)));

    // The hall: a box seen from inside (floor separate, for its own material).
    let mut shell = Mesh::cuboid(HALL_MIN, HALL_MAX);
    shell.flip();
    let (lo, hi) = (HALL_MIN, HALL_MAX);
    let floor = Mesh::quad(
        Vec3::new(lo.x, 0.001, lo.z),
        Vec3::new(lo.x, 0.001, hi.z),
        Vec3::new(hi.x, 0.001, hi.z),
        Vec3::new(hi.x, 0.001, lo.z),
    );
    doc.add_object("hall", &shell, wall, Transform::IDENTITY);
    doc.add_object("floor", &floor, floor_m, Transform::IDENTITY);
    let mut pillars = Mesh::default();
    for k in 0..7 {
        let x = -9.0 + 3.0 * k as f32;
        for z in [-2.2f32, 2.2] {
            pillars.append(&Mesh::cuboid(
                Vec3::new(x - 0.2, 0.0, z - 0.2),
                Vec3::new(x + 0.2, 4.0, z + 0.2),
            ));
        }
    }
    doc.add_object("pillars", &pillars, pillar_m, Transform::IDENTITY);
    let mut crates = Mesh::default();
    for (c, s) in [
        (Vec3::new(-6.5, 0.0, 0.8), 0.5),
        (Vec3::new(-2.0, 0.0, -0.9), 0.7),
        (Vec3::new(3.5, 0.0, 0.4), 0.6),
        (Vec3::new(8.0, 0.0, -0.5), 0.8),
    ] {
        crates.append(&Mesh::cuboid(
            c - Vec3::new(s, 0.0, s),
            c + Vec3::new(s, 2.0 * s, s),
        ));
    }
    doc.add_object("crates", &crates, box_m, Transform::IDENTITY);

    // The lamps, grouped into one mesh per material.
    let mut lamps: Vec<Mesh> = vec![Mesh::default(); COLOURS.len() * POWERS.len()];
    let (nx, nz) = LAMPS;
    let y = HALL_MAX.y - 0.01;
    let h = LAMP_SIZE / 2.0;
    for i in 0..nx {
        for j in 0..nz {
            let x = lo.x + (hi.x - lo.x) * (i as f32 + 0.5) / nx as f32;
            let z = lo.z + (hi.z - lo.z) * (j as f32 + 0.5) / nz as f32;
            let kind = hash((i * nz + j) as u32 + 17) as usize % lamps.len();
            lamps[kind].append(&Mesh::quad_facing(
                [
                    Vec3::new(x - h, y, z - h),
                    Vec3::new(x + h, y, z - h),
                    Vec3::new(x + h, y, z + h),
                    Vec3::new(x - h, y, z + h),
                ],
                Vec3::new(x, 0.0, z),
            ));
        }
    }
    for (kind, mesh) in lamps.iter().enumerate() {
        let (c, p) = (COLOURS[kind % COLOURS.len()], POWERS[kind / COLOURS.len()]);
        let name = format!("lamp_{kind:02}");
        let m = doc.add_material(Material::emitter(
            &name,
            c * (LAMP_RADIANCE * p),
            Vec3::splat(0.8),
            false,
        ));
        doc.add_object(&name, mesh, m, Transform::IDENTITY);
    }

    for (k, (p, c, i)) in [
        (Vec3::new(-8.0, 0.6, -3.2), Vec3::new(1.0, 0.6, 0.3), 4.0),
        (Vec3::new(-1.0, 0.4, 3.3), Vec3::new(0.4, 0.7, 1.0), 3.0),
        (Vec3::new(5.0, 0.8, -3.3), Vec3::new(1.0, 0.9, 0.7), 5.0),
        (Vec3::new(10.5, 0.5, 2.5), Vec3::new(0.9, 0.4, 0.9), 4.0),
    ]
    .into_iter()
    .enumerate()
    {
        doc.add_light(
            Light {
                name: format!("point_{k}"),
                kind: LightKind::Point,
                color: c,
                intensity: i,
            },
            Transform::at(p),
        );
    }
    for (k, (p, target)) in [
        (Vec3::new(-4.5, 3.5, -3.8), Vec3::new(-6.0, 0.0, 0.8)),
        (Vec3::new(6.0, 3.5, 3.8), Vec3::new(3.5, 0.0, 0.4)),
    ]
    .into_iter()
    .enumerate()
    {
        doc.add_light(
            Light {
                name: format!("spot_{k}"),
                kind: LightKind::Spot {
                    // Nearly hard, as `sun-spot-env`'s: Mitsuba's falloff differs between
                    // the cones.
                    inner_cone_angle: 21.5f32.to_radians(),
                    outer_cone_angle: 22f32.to_radians(),
                },
                color: Vec3::new(1.0, 0.95, 0.85),
                intensity: 120.0,
            },
            Transform::facing(p, target - p, Vec3::Y),
        );
    }

    doc.add_camera(
        "camera",
        50.0,
        Transform::look_at(
            Vec3::new(-11.3, 1.7, 0.6),
            Vec3::new(0.0, 1.1, -0.3),
            Vec3::Y,
        ),
    );
    doc
}
