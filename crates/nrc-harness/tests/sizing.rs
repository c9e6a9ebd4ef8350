//! `--resolution auto`: the cache's finest resolution from the camera's pixel footprint
//! (`methods::footprint_resolution`), on scenes of very different extents, and its errors.

use glam::Vec3;
use nrc_harness::methods::{CacheMethodSettings, footprint_resolution, scene_cache};
use nrc_scene::{Camera, Scene, SceneDescription};

/// A floor of `length × width` (x by z, metres) at y = 0, seen from `eye` looking at `target`.
fn floor(length: f32, width: f32, eye: Vec3, target: Vec3) -> Scene {
    let p = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(length, 0.0, 0.0),
        Vec3::new(length, 0.0, width),
        Vec3::new(0.0, 0.0, width),
        // A post at the far corner, so the box has height.
        Vec3::new(length, 0.0, width),
        Vec3::new(length, 0.1 * width, width),
        Vec3::new(length - 0.01 * width, 0.0, width),
    ];
    Scene::from_description(SceneDescription {
        positions: p,
        triangles: vec![[0, 2, 1], [0, 3, 2], [4, 5, 6]],
        triangle_materials: vec![0, 0, 0],
        triangle_meshes: vec![0, 0, 0],
        mesh_names: vec!["floor".into()],
        materials: vec![nrc_scene::Material::default()],
        camera: Some(Camera::look_at(eye, target, Vec3::Y, 40.0).unwrap()),
        ..Default::default()
    })
    .unwrap()
}

#[test]
fn resolution_follows_the_footprint_not_the_units() {
    // A 1 m square seen from 1 m, and the same 100 times larger seen from 100 m: the same
    // pixels per cell, so the same resolution.
    let small = floor(
        1.0,
        1.0,
        Vec3::new(0.5, 1.0, -0.5),
        Vec3::new(0.5, 0.0, 0.5),
    );
    let large = floor(
        100.0,
        100.0,
        Vec3::new(50.0, 100.0, -50.0),
        Vec3::new(50.0, 0.0, 50.0),
    );
    let (a, why) = footprint_resolution(&small, &small.camera, 128, 128).unwrap();
    let (b, _) = footprint_resolution(&large, &large.camera, 128, 128).unwrap();
    assert!(why.contains("median distance"), "{why}");
    assert!(a.abs_diff(b) <= 1, "{a} against {b}");
    // Twice the image height, twice the resolution.
    let (c, _) = footprint_resolution(&small, &small.camera, 256, 256).unwrap();
    assert!(c.abs_diff(2 * a) <= 2, "{c} against 2 × {a}");
}

#[test]
fn a_street_gets_more_cells_and_a_larger_table_than_a_room() {
    // A 100 m street and a 5 m room, both seen from 3 m above their near end.
    let street = floor(
        100.0,
        10.0,
        Vec3::new(-3.0, 3.0, 5.0),
        Vec3::new(10.0, 0.0, 5.0),
    );
    let room = floor(
        5.0,
        5.0,
        Vec3::new(-3.0, 3.0, 2.5),
        Vec3::new(2.5, 0.0, 2.5),
    );
    let (s, _) = footprint_resolution(&street, &street.camera, 160, 90).unwrap();
    let (r, _) = footprint_resolution(&room, &room.camera, 160, 90).unwrap();
    assert!(s > 4 * r, "street {s} cells, room {r}");
    // The table follows the cells (the preset's log2 size is the ceiling).
    let size = |scene: &Scene, cells: u32| {
        let mut settings = CacheMethodSettings::new(
            nrc_cache::CacheConfig::hash_grid_preset(),
            nrc_cache::CacheDevice::Cpu,
        );
        settings.resolution = cells;
        let boxed = nrc_train::QueryMaker::new(&scene.bounds()).scene_box;
        scene_cache(boxed, &settings).unwrap().memory_bytes()
    };
    assert!(size(&street, s) > size(&room, r));
}

#[test]
fn auto_without_a_view_or_a_surface_is_a_clear_error() {
    // A camera looking away from everything.
    let away = floor(
        1.0,
        1.0,
        Vec3::new(0.5, 1.0, -0.5),
        Vec3::new(0.5, 2.0, -3.0),
    );
    let e = footprint_resolution(&away, &away.camera, 64, 64)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no camera ray hits the scene"), "{e}");
    let e = footprint_resolution(&away, &away.camera, 0, 64)
        .unwrap_err()
        .to_string();
    assert!(e.contains("image size"), "{e}");
    // `auto` not resolved before a cache is made (no camera given): refused, not guessed.
    let mut settings = CacheMethodSettings::new(
        nrc_cache::CacheConfig::hash_grid_preset(),
        nrc_cache::CacheDevice::Cpu,
    );
    settings.resolution_auto = true;
    let e = scene_cache(nrc_cache::SceneBox::default(), &settings)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--resolution auto"), "{e}");
    // Resolved, it is a number of cells.
    let scene = floor(
        1.0,
        1.0,
        Vec3::new(0.5, 1.0, -0.5),
        Vec3::new(0.5, 0.0, 0.5),
    );
    let why = settings
        .resolve_resolution(&scene, 64, 64)
        .unwrap()
        .unwrap();
    assert!(
        !settings.resolution_auto && settings.resolution >= 16,
        "{why}"
    );
}
