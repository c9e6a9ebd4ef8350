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
        nrc_scene::testing::skipped(
            "shared scenes (load.rs)",
            &format!("{} is absent", dir.display()),
        );
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
    assert!(
        scene.light_count() > 0,
        "the ceiling light must be an area light"
    );
    // KHR_materials_emissive_strength = 30 is applied to the emitter.
    let light = scene.lights().triangles()[0];
    let m = &scene.materials()[scene.triangle_material(light) as usize];
    assert!(
        m.emissive.max_element() >= 29.0,
        "emissive strength applied: {:?}",
        m.emissive
    );
    // KHR_materials_specular factor 0: purely diffuse surfaces.
    assert!(scene.materials().iter().any(|m| m.specular == 0.0));
    // The default camera sees the box.
    let hits = check_camera_rays(&scene);
    assert!(
        hits > 32 * 24 / 4,
        "default camera frames the scene: {hits} hits"
    );
    // Sampled light points lie on their triangles and face into the box.
    let s = *scene
        .sample_light_by_power(0.5, Vec2::new(0.3, 0.6))
        .unwrap()
        .surface()
        .unwrap();
    assert!(s.pdf_area > 0.0 && s.le.max_element() > 0.0);
    assert_eq!(
        scene.light_pdf_area(
            &nrc_scene::LightContext::new(glam::Vec3::ZERO, glam::Vec3::ZERO),
            s.tri
        ),
        s.pdf_area
    );
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
            std::fs::read_dir(&p)
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.path())
                .collect()
        } else {
            vec![p]
        };
        for f in files {
            if matches!(f.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")) {
                let scene = load(&f);
                println!("{}", scene.summary());
                assert!(
                    scene.camera_from_file(),
                    "{}: shipped scenes have a camera",
                    f.display()
                );
                assert!(check_camera_rays(&scene) > 0);
                n += 1;
            }
        }
    }
    println!("{n} project scenes loaded from {}", dir.display());
}

/// Encodes an 8-bit RGB PNG.
fn png_rgb(width: u32, height: u32, pixels: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().unwrap();
        w.write_image_data(pixels).unwrap();
    }
    out
}

/// A textured quad with every material extension the loader implements, placed by a
/// non-uniformly scaled node and by a mirrored node.
#[test]
fn textures_extensions_and_transforms() {
    use nrc_scene::texture::srgb_to_linear;
    let dir = tempfile::tempdir().unwrap();
    // 2×1 textures: texel 0 covers u < 0.5.
    std::fs::write(
        dir.path().join("base.png"),
        png_rgb(2, 1, &[128, 0, 255, 255, 255, 255]),
    )
    .unwrap();
    std::fs::write(
        dir.path().join("mr.png"),
        png_rgb(2, 1, &[0, 64, 191, 0, 255, 255]),
    )
    .unwrap();
    std::fs::write(
        dir.path().join("emit.png"),
        png_rgb(2, 1, &[255, 128, 0, 0, 0, 0]),
    )
    .unwrap();
    let mut bin: Vec<u8> = Vec::new();
    let f32s = |v: &[f32], bin: &mut Vec<u8>| {
        v.iter()
            .for_each(|x| bin.extend_from_slice(&x.to_le_bytes()))
    };
    f32s(&[0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.], &mut bin); // positions, 48 B
    let s = std::f32::consts::FRAC_1_SQRT_2;
    f32s(&[0., s, s, 0., s, s, 0., s, s, 0., s, s], &mut bin); // normals, 48 B
    f32s(&[0., 0., 1., 0., 1., 1., 0., 1.], &mut bin); // uvs, 32 B
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes()); // indices, 12 B
    }
    std::fs::write(dir.path().join("quad.bin"), &bin).unwrap();
    let json = r#"{
      "asset": {"version": "2.0"},
      "extensionsUsed": ["KHR_materials_emissive_strength", "KHR_materials_transmission",
                         "KHR_materials_ior", "KHR_materials_specular", "KHR_texture_transform"],
      "scene": 0,
      "scenes": [{"nodes": [0, 1, 2]}],
      "nodes": [
        {"mesh": 0, "scale": [1, 4, 1]},
        {"mesh": 0, "scale": [-1, 1, 1]},
        {"camera": 0, "translation": [0, 0, 5]}
      ],
      "cameras": [{"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}],
      "meshes": [{"name": "quad", "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0}]}],
      "materials": [{
        "name": "everything",
        "pbrMetallicRoughness": {
          "baseColorFactor": [0.5, 1, 1, 1], "baseColorTexture": {"index": 0},
          "metallicFactor": 1, "roughnessFactor": 0.5, "metallicRoughnessTexture": {"index": 1}
        },
        "emissiveFactor": [1, 1, 0.5], "emissiveTexture": {"index": 2},
        "extensions": {
          "KHR_materials_emissive_strength": {"emissiveStrength": 4},
          "KHR_materials_transmission": {"transmissionFactor": 0.7},
          "KHR_materials_ior": {"ior": 1.33},
          "KHR_materials_specular": {"specularFactor": 0.5, "specularColorFactor": [1, 0.5, 0.25]}
        }
      }],
      "samplers": [{"magFilter": 9728, "wrapS": 33071, "wrapT": 33071}],
      "images": [{"uri": "base.png"}, {"uri": "mr.png"}, {"uri": "emit.png"}],
      "textures": [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}, {"source": 2, "sampler": 0}],
      "buffers": [{"uri": "quad.bin", "byteLength": 140}],
      "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": 48},
        {"buffer": 0, "byteOffset": 48, "byteLength": 48},
        {"buffer": 0, "byteOffset": 96, "byteLength": 32},
        {"buffer": 0, "byteOffset": 128, "byteLength": 12}
      ],
      "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
        {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
        {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
      ]
    }"#;
    let path = dir.path().join("quad.gltf");
    std::fs::write(&path, json).unwrap();
    let scene = load(&path);
    println!("{}", scene.summary());
    assert_eq!(scene.triangle_count(), 4);
    assert_eq!(scene.textures().len(), 3);
    assert!(scene.camera_from_file());
    assert_eq!(scene.camera.position, Vec3::new(0.0, 0.0, 5.0));
    assert_eq!(scene.camera.forward, -Vec3::Z);
    assert!((scene.camera.fov_y - 0.5).abs() < 1e-6);

    // Hit the scaled quad at uv (0.25, 0.5): texel 0 of every texture.
    let ray = Ray::new(Vec3::new(0.25, 2.0, 1.0), -Vec3::Z);
    let hit = scene.intersect(&ray).unwrap();
    let si = scene.interaction(&ray, &hit);
    assert!((si.uv[0] - Vec2::new(0.25, 0.5)).length() < 1e-5);
    assert!((si.ng - Vec3::Z).length() < 1e-6);
    // Normals transform by the inverse transpose: (0, 1, 1) under scale (1, 4, 1) → (0, ¼, 1).
    assert!(
        (si.ns - Vec3::new(0.0, 0.25, 1.0).normalize()).length() < 1e-5,
        "{:?}",
        si.ns
    );
    let pbr = scene.pbr(&si);
    let expect_base = Vec3::new(0.5 * srgb_to_linear(128.0 / 255.0), 0.0, 1.0);
    assert!(
        (pbr.base_color - expect_base).length() < 1e-5,
        "{:?}",
        pbr.base_color
    );
    assert!(
        (pbr.roughness - 0.5 * 64.0 / 255.0).abs() < 1e-5,
        "G channel is roughness"
    );
    assert!(
        (pbr.metallic - 191.0 / 255.0).abs() < 1e-5,
        "B channel is metallic"
    );
    assert!((pbr.transmission - 0.7).abs() < 1e-6);
    assert!((pbr.ior - 1.33).abs() < 1e-6);
    assert!((pbr.specular - 0.5).abs() < 1e-6);
    assert!((pbr.specular_color - Vec3::new(1.0, 0.5, 0.25)).length() < 1e-6);
    let le = scene.emission(&si);
    let expect_le = 4.0 * Vec3::new(1.0, srgb_to_linear(128.0 / 255.0), 0.0);
    assert!((le - expect_le).length() < 1e-5, "{le:?}");
    // The material is single-sided: its back face does not emit.
    let below = Ray::new(Vec3::new(0.25, 2.0, -1.0), Vec3::Z);
    let h = scene.intersect(&below).unwrap();
    assert_eq!(scene.emission(&scene.interaction(&below, &h)), Vec3::ZERO);
    // Texel 1 (u > 0.5): black emission; the triangles there are lights only through u < 0.5.
    let ray = Ray::new(Vec3::new(0.75, 2.0, 1.0), -Vec3::Z);
    let si = scene.interaction(&ray, &scene.intersect(&ray).unwrap());
    assert_eq!(scene.emission(&si), Vec3::ZERO);
    assert!(scene.light_count() > 0);

    // The mirrored copy (scale x by −1) keeps its front face up: glTF flips the winding of
    // nodes with a negative determinant.
    let ray = Ray::new(Vec3::new(-0.25, 0.5, 1.0), -Vec3::Z);
    let si = scene.interaction(&ray, &scene.intersect(&ray).unwrap());
    assert!((si.ng - Vec3::Z).length() < 1e-6, "{:?}", si.ng);
    assert!(si.ns.z > 0.0);
    assert!(si.front_face());
}
