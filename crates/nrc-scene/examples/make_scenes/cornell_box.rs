//! `cornell-box`: the Cornell box as measured by the Cornell University Program of Computer
//! Graphics ("Cornell Box Data", graphics.cornell.edu/online/box/data.html): geometry in
//! millimetres (here scaled to metres), camera, reflectance and emission spectra. The spectra
//! are converted to linear sRGB by `scenes/cornell_colors.py`; scenes/README.md gives the method.

use glam::{Quat, Vec3};

use crate::gltf_doc::{Document, Material, Transform};
use crate::mesh::Mesh;

/// Measured diffuse reflectances, as linear sRGB (D65 white): the spectra integrated against
/// the CIE 1931 2° observer under illuminant D65, normalised so that a perfect white is 1.
pub const WHITE: Vec3 = Vec3::new(0.7383, 0.7360, 0.7386);
pub const RED: Vec3 = Vec3::new(0.4939, 0.0489, 0.0512);
pub const GREEN: Vec3 = Vec3::new(0.0684, 0.3985, 0.0866);
/// The light's emitted spectral radiance (400:0, 500:8, 600:15.6, 700:18.4, linear between)
/// as linear sRGB, with Y = ∫L ȳ / ∫ȳ.
pub const LIGHT_RADIANCE: Vec3 = Vec3::new(20.72, 10.86, 2.771);
/// Albedo of the light's diffuser, as in Mitsuba's `cbox` scene.
pub const LIGHT_ALBEDO: Vec3 = Vec3::splat(0.78);
/// The luminaire hangs this far below the ceiling (Mitsuba's `cbox` translates it by −0.5 mm),
/// so that it neither coincides with the ceiling nor leaves a visible gap.
const LIGHT_DROP_MM: f32 = 0.5;

/// A point given in the data's millimetres, in metres (divided in f64, so that 559.2 mm
/// becomes the `f32` nearest 0.5592 m).
fn mm(x: f32, y: f32, z: f32) -> Vec3 {
    let m = |v: f32| (f64::from(v) / 1000.0) as f32;
    Vec3::new(m(x), m(y), m(z))
}

/// A face from the data, wound so that its front looks towards `toward` (millimetres).
fn face(corners: [[f32; 3]; 4], toward: [f32; 3]) -> Mesh {
    Mesh::quad_facing(
        corners.map(|[x, y, z]| mm(x, y, z)),
        mm(toward[0], toward[1], toward[2]),
    )
}

/// A block from the data (five faces, no bottom), faces pointing away from its centre.
fn block(faces: [[[f32; 3]; 4]; 5]) -> Mesh {
    let corners: Vec<[f32; 3]> = faces.iter().flatten().copied().collect();
    let centre = corners
        .iter()
        .fold([0.0; 3], |s, c| [s[0] + c[0], s[1] + c[1], s[2] + c[2]])
        .map(|s| s / corners.len() as f32);
    let mut mesh = Mesh::default();
    for f in faces {
        let fc = f
            .iter()
            .fold([0.0; 3], |s, c| [s[0] + c[0], s[1] + c[1], s[2] + c[2]])
            .map(|s| s / 4.0);
        // A point beyond the face, away from the block's centre.
        let away = [
            2.0 * fc[0] - centre[0],
            2.0 * fc[1] - centre[1],
            2.0 * fc[2] - centre[2],
        ];
        mesh.append(&face(f, away));
    }
    mesh
}

pub fn build() -> Document {
    build_with_light_node().0
}

/// Seconds the light of `cornell-box-moving` takes to cross the ceiling and come back.
pub const MOVING_PERIOD: f32 = 4.0;

/// `cornell-box-moving`: the Cornell box whose light moves along the ceiling, linearly, from
/// the middle toward the red wall, across to the green wall and back to the middle in
/// [`MOVING_PERIOD`] seconds (0.17 m each way: the lamp's edge stays 4 cm from the walls).
pub fn build_moving() -> Document {
    moving("LINEAR")
}

/// `cornell-box-jump`: the same keys with STEP interpolation: the lamp stays in the middle for
/// the first second, jumps 0.17 m toward the red wall at 1 s and across to the green side at
/// 3 s (a sudden change, to measure how fast the caches recover).
pub fn build_jump() -> Document {
    moving("STEP")
}

fn moving(interpolation: &str) -> Document {
    let (mut doc, light) = build_with_light_node();
    let x = |d: f32| Vec3::new(d, 0.0, 0.0);
    let q = MOVING_PERIOD / 4.0;
    doc.add_vec3_animation(
        "light moves along the ceiling",
        light,
        "translation",
        interpolation,
        &[
            (0.0, x(0.0)),
            (q, x(0.17)),
            (3.0 * q, x(-0.17)),
            (4.0 * q, x(0.0)),
        ],
    );
    doc
}

/// The Cornell box and the index of its light's node.
fn build_with_light_node() -> (Document, usize) {
    let mut doc = Document::default();
    let white = doc.add_material(Material::diffuse("white", WHITE));
    let red = doc.add_material(Material::diffuse("red", RED));
    let green = doc.add_material(Material::diffuse("green", GREEN));
    let light = doc.add_material(Material::emitter(
        "light",
        LIGHT_RADIANCE,
        LIGHT_ALBEDO,
        false,
    ));

    // The room's faces look towards the inside of the box.
    let inside = [278.0, 274.4, 279.6];
    let floor = face(
        [
            [552.8, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 559.2],
            [549.6, 0.0, 559.2],
        ],
        inside,
    );
    let ceiling = face(
        [
            [556.0, 548.8, 0.0],
            [556.0, 548.8, 559.2],
            [0.0, 548.8, 559.2],
            [0.0, 548.8, 0.0],
        ],
        inside,
    );
    let back = face(
        [
            [549.6, 0.0, 559.2],
            [0.0, 0.0, 559.2],
            [0.0, 548.8, 559.2],
            [556.0, 548.8, 559.2],
        ],
        inside,
    );
    let right = face(
        [
            [0.0, 0.0, 559.2],
            [0.0, 0.0, 0.0],
            [0.0, 548.8, 0.0],
            [0.0, 548.8, 559.2],
        ],
        inside,
    );
    let left = face(
        [
            [552.8, 0.0, 0.0],
            [549.6, 0.0, 559.2],
            [556.0, 548.8, 559.2],
            [556.0, 548.8, 0.0],
        ],
        inside,
    );
    let y = 548.8 - LIGHT_DROP_MM;
    let lamp = face(
        [
            [343.0, y, 227.0],
            [343.0, y, 332.0],
            [213.0, y, 332.0],
            [213.0, y, 227.0],
        ],
        [278.0, 0.0, 279.5],
    );

    let short_block = block([
        [
            [130.0, 165.0, 65.0],
            [82.0, 165.0, 225.0],
            [240.0, 165.0, 272.0],
            [290.0, 165.0, 114.0],
        ],
        [
            [290.0, 0.0, 114.0],
            [290.0, 165.0, 114.0],
            [240.0, 165.0, 272.0],
            [240.0, 0.0, 272.0],
        ],
        [
            [130.0, 0.0, 65.0],
            [130.0, 165.0, 65.0],
            [290.0, 165.0, 114.0],
            [290.0, 0.0, 114.0],
        ],
        [
            [82.0, 0.0, 225.0],
            [82.0, 165.0, 225.0],
            [130.0, 165.0, 65.0],
            [130.0, 0.0, 65.0],
        ],
        [
            [240.0, 0.0, 272.0],
            [240.0, 165.0, 272.0],
            [82.0, 165.0, 225.0],
            [82.0, 0.0, 225.0],
        ],
    ]);
    let tall_block = block([
        [
            [423.0, 330.0, 247.0],
            [265.0, 330.0, 296.0],
            [314.0, 330.0, 456.0],
            [472.0, 330.0, 406.0],
        ],
        [
            [423.0, 0.0, 247.0],
            [423.0, 330.0, 247.0],
            [472.0, 330.0, 406.0],
            [472.0, 0.0, 406.0],
        ],
        [
            [472.0, 0.0, 406.0],
            [472.0, 330.0, 406.0],
            [314.0, 330.0, 456.0],
            [314.0, 0.0, 456.0],
        ],
        [
            [314.0, 0.0, 456.0],
            [314.0, 330.0, 456.0],
            [265.0, 330.0, 296.0],
            [265.0, 0.0, 296.0],
        ],
        [
            [265.0, 0.0, 296.0],
            [265.0, 330.0, 296.0],
            [423.0, 330.0, 247.0],
            [423.0, 0.0, 247.0],
        ],
    ]);

    let mut light_node = usize::MAX;
    for (name, mesh, material) in [
        ("floor", floor, white),
        ("ceiling", ceiling, white),
        ("back_wall", back, white),
        ("right_wall_green", right, green),
        ("left_wall_red", left, red),
        ("short_block", short_block, white),
        ("tall_block", tall_block, white),
        ("light", lamp, light),
    ] {
        let node = doc.add_object(name, &mesh, material, Transform::IDENTITY);
        if name == "light" {
            light_node = node;
        }
    }

    // Camera: position (278, 273, −800) mm looking along +z with +y up; focal length 35 mm
    // over a 25 mm × 25 mm film, so yfov = 2·atan(12.5 / 35) = 39.3077°. glTF cameras look
    // down −z, so the node turns half a turn about +y (which also keeps +x to the viewer's
    // left: the red wall at x ≈ 0.55 m on the left, the green one on the right).
    let yfov = 2.0 * (12.5_f32 / 35.0).atan().to_degrees();
    let placement = Transform {
        translation: mm(278.0, 273.0, -800.0),
        rotation: Quat::from_xyzw(0.0, 1.0, 0.0, 0.0),
        scale: 1.0,
    };
    doc.add_camera("camera", yfov, placement);
    (doc, light_node)
}
