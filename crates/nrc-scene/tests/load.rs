//! Loading the scenes the project ships (`scenes/`) and the third-party scenes in
//! `../shared/scenes/` (skipped with a message when that folder is absent).

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use nrc_scene::{Ray, Scene};

fn shared_scenes() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if dir.is_dir() {
        Some(dir)
    } else {
        println!("skipping: {} is absent", dir.display());
        None
    }
}

fn load(path: &Path) -> Scene {
    Scene::load(path).unwrap_or_else(|e| panic!("{e}"))
}

/// Every camera ray of a small image hits something or escapes; hits give finite,
/// unit normals and valid material indices.
fn check_camera_rays(scene: &Scene) -> usize {
    let (w, h) = (32, 24);
    let mut hits = 0;
    for y in 0..h {
        for x in 0..w {
            let ray = scene
                .camera
                .generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5), w, h);
            assert!((ray.d.length() - 1.0).abs() < 1e-5);
            if let Some(hit) = scene.intersect(&ray) {
                hits += 1;
                let si = scene.interaction(&ray, &hit);
                assert!(si.p.is_finite());
                assert!((si.ng.length() - 1.0).abs() < 1e-4);
                assert!((si.ns.length() - 1.0).abs() < 1e-4);
                assert!(si.ns.dot(si.ng) >= 0.0);
                assert!((si.p - ray.at(hit.t)).length() < 1e-3 * (1.0 + hit.t));
                assert!((si.material as usize) < scene.materials().len());
                let pbr = scene.pbr(&si);
                assert!(pbr.base_color.is_finite() && pbr.roughness.is_finite());
                assert!(scene.emission(&si).is_finite());
            }
        }
    }
    hits
}

#[test]
fn cornell_box_glb() {
    let Some(dir) = shared_scenes() else { return };
    let scene = load(&dir.join("hwrt-cornell-box/cornell_box.glb"));
    println!("{}", scene.summary());
    assert!(!scene.camera_from_file(), "this file has no camera");
    assert!(scene.triangle_count() >= 30);
    assert!(scene.light_count() > 0, "the ceiling light must be an area light");
    // KHR_materials_emissive_strength = 30 is applied to the emitter.
    let light = scene.lights().triangles()[0];
    let m = &scene.materials()[scene.triangle_material(light) as usize];
    assert!(m.emissive.max_element() >= 29.0, "emissive strength applied: {:?}", m.emissive);
    // KHR_materials_specular factor 0: purely diffuse surfaces.
    assert!(scene.materials().iter().any(|m| m.specular == 0.0));
    // The default camera sees the box.
    let hits = check_camera_rays(&scene);
    assert!(hits > 32 * 24 / 4, "default camera frames the scene: {hits} hits");
    // Sampled light points lie on their triangles and face into the box.
    let s = scene.sample_light(0.5, Vec2::new(0.3, 0.6)).unwrap();
    assert!(s.pdf_area > 0.0 && s.le.max_element() > 0.0);
    assert_eq!(scene.light_pdf_area(s.tri), s.pdf_area);
    let probe = Ray::new(s.p - s.n * 1e-2, s.n);
    let _ = scene.intersect(&probe);
}

#[test]
fn ajar_caustic_glb() {
    let Some(dir) = shared_scenes() else { return };
    let scene = load(&dir.join("photon-nrc-ajar-caustic/ajar_caustic.glb"));
    println!("{}", scene.summary());
    assert!(scene.camera_from_file(), "this file has a camera");
    assert!(scene.light_count() > 0);
    assert!(
        scene.materials().iter().any(|m| m.transmission > 0.0),
        "the water sphere is transmissive"
    );
    assert!(check_camera_rays(&scene) > 0);
}

#[test]
fn kajiya_roughness_scale_gltf() {
    let Some(dir) = shared_scenes() else { return };
    let scene = load(&dir.join("kajiya-roughness-scale/scene.gltf"));
    println!("{}", scene.summary());
    assert_eq!(scene.light_count(), 0, "this scene has no emitters");
    assert!(!scene.textures().is_empty(), "PNG textures are loaded");
    assert!(check_camera_rays(&scene) > 0);
    let b = scene.bounds();
    assert!(b.extent().max_element() > 0.0 && b.min.is_finite() && b.max.is_finite());
    let _ = Vec3::ZERO;
}

#[test]
fn project_scenes_load() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
        let p = entry.path();
        let files: Vec<PathBuf> = if p.is_dir() {
            std::fs::read_dir(&p).into_iter().flatten().flatten().map(|e| e.path()).collect()
        } else {
            vec![p]
        };
        for f in files {
            if matches!(f.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")) {
                let scene = load(&f);
                println!("{}", scene.summary());
                assert!(scene.camera_from_file(), "{}: shipped scenes have a camera", f.display());
                assert!(check_camera_rays(&scene) > 0);
                n += 1;
            }
        }
    }
    println!("{n} project scenes loaded from {}", dir.display());
}
