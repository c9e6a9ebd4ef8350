//! glTF node animation on the shipped animated scene (`scenes/cornell-box-moving.gltf`, made by
//! the scene generator): the light's node translation read from the file and sampled at a
//! frame's time as the keys say, the light met where it moved to (the acceleration structure
//! is built for the posed scene) and sampled there (so is the light sampler), and a STEP
//! sampler written into a copy of the file holding its keys.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use nrc_scene::animation::{Interpolation, Property};
use nrc_scene::{AnimatedScene, LightSample, Ray, Scene};

fn moving() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box-moving.gltf")
}

/// The centre of the light's quad in a posed scene: the mean of sampled light points.
fn light_centre(scene: &Scene) -> Vec3 {
    let mut sum = Vec3::ZERO;
    let n = 64;
    for i in 0..n {
        let u = Vec2::new(
            (i % 8) as f32 / 8.0 + 1.0 / 16.0,
            (i / 8) as f32 / 8.0 + 1.0 / 16.0,
        );
        match scene.sample_light_by_power((i as f32 + 0.5) / n as f32, u) {
            Some(LightSample::Surface(s)) => sum += s.p,
            other => panic!("the box's only light is its lamp, got {other:?}"),
        }
    }
    sum / n as f32
}

#[test]
fn the_light_moves_as_its_keys_say_and_is_met_where_it_moved() {
    let a = AnimatedScene::load(&moving()).unwrap();
    assert!(a.is_animated());
    assert_eq!(a.animation.duration(), 4.0);
    let c = &a.animation.channels[0];
    assert_eq!(
        (c.property, c.interpolation),
        (Property::Translation, Interpolation::Linear)
    );
    assert_eq!(c.times, vec![0.0, 1.0, 3.0, 4.0]);
    let rest = light_centre(&a.at(0.0).unwrap());
    // Keys: x + 0 at 0 s, + 0.17 at 1 s, − 0.17 at 3 s, + 0 at 4 s; linear between.
    for (t, dx) in [
        (0.0, 0.0),
        (0.5, 0.085),
        (1.0, 0.17),
        (2.0, 0.0),
        (2.5, -0.085),
        (3.0, -0.17),
        (4.0, 0.0),
        (9.0, 0.0),
    ] {
        let scene = a.at(t).unwrap();
        let moved = light_centre(&scene) - rest;
        assert!(
            (moved - Vec3::new(dx, 0.0, 0.0)).length() < 1e-5,
            "t = {t}: the light moved by {moved}, expected ({dx}, 0, 0)"
        );
        // A ray straight up under the moved lamp meets it (emissive seen from below); under
        // where it was at rest (when it moved away by more than its half-width) it meets the
        // ceiling, which does not emit.
        let up = |x: f32| {
            // From above the blocks (the tall one is 0.33 high).
            let ray = Ray::new(Vec3::new(x, 0.45, rest.z), Vec3::Y);
            let hit = scene.intersect(&ray).expect("the ceiling closes the box");
            scene.emission(&scene.interaction(&ray, &hit)).max_element() > 0.0
        };
        assert!(
            up(rest.x + dx),
            "t = {t}: the lamp is not where it moved to"
        );
        if dx.abs() > 0.1 {
            assert!(!up(rest.x), "t = {t}: the lamp is still met where it was");
        }
    }
    // Scene::load gives the rest pose.
    let loaded = light_centre(&Scene::load(&moving()).unwrap());
    assert!((loaded - rest).length() < 1e-6);
}

#[test]
fn a_step_sampler_holds_each_key() {
    let text = std::fs::read_to_string(moving()).unwrap();
    assert_eq!(text.matches("\"LINEAR\"").count(), 1);
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("step.gltf"),
        text.replace("\"LINEAR\"", "\"STEP\""),
    )
    .unwrap();
    std::fs::copy(
        moving().with_extension("bin"),
        dir.path().join("cornell-box-moving.bin"),
    )
    .unwrap();
    let a = AnimatedScene::load(&dir.path().join("step.gltf")).unwrap();
    assert_eq!(a.animation.channels[0].interpolation, Interpolation::Step);
    let rest = light_centre(&a.at(0.0).unwrap());
    for (t, dx) in [
        (0.5, 0.0),
        (1.0, 0.17),
        (2.9, 0.17),
        (3.0, -0.17),
        (3.99, -0.17),
    ] {
        let moved = light_centre(&a.at(t).unwrap()) - rest;
        assert!((moved.x - dx).abs() < 1e-5, "t = {t}: {moved}");
    }
}

#[test]
fn a_scene_without_animations_is_the_same_at_every_time() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.gltf");
    let a = AnimatedScene::load(&path).unwrap();
    assert!(!a.is_animated());
    assert_eq!(
        light_centre(&a.at(0.0).unwrap()),
        light_centre(&a.at(3.0).unwrap())
    );
}
