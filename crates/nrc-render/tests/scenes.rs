//! Every shipped scene (`scenes/`) and every third-party scene (`../shared/scenes/`, skipped
//! with a message when absent) loads and renders a small image with only finite,
//! non-negative values, and something in it is lit. Scenes without emitters (the kajiya
//! roughness scale) are lit by a uniform background of radiance 1.

mod common;

use std::path::{Path, PathBuf};

use common::{project_scenes, render_scene, shared_scenes};
use glam::Vec3;
use nrc_render::PathTracer;
use nrc_scene::Scene;

fn gltf_files(dir: &Path, recursive: bool) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = entry.unwrap().path();
        if p.is_dir() && recursive {
            out.extend(gltf_files(&p, false));
        } else if matches!(p.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")) {
            out.push(p);
        }
    }
    out.sort();
    out
}

fn check(path: &Path) {
    let mut scene = Scene::load(path).unwrap_or_else(|e| panic!("{e}"));
    if scene.light_count() == 0 {
        scene.set_environment(nrc_scene::Environment::constant(Vec3::ONE));
    }
    let out = render_scene(&scene, &PathTracer::default(), 32, 24, 4, 1);
    for (i, p) in out.mean.data.iter().enumerate() {
        assert!(
            p.is_finite() && p.min_element() >= 0.0,
            "{}: pixel {i} = {p}",
            path.display()
        );
    }
    assert_eq!(
        out.stats.invalid_samples,
        0,
        "{}: NaN or infinite samples",
        path.display()
    );
    assert!(
        out.mean.mean().max_element() > 0.0,
        "{}: black image",
        path.display()
    );
    eprintln!("{}: ok, mean {:.4}", path.display(), out.mean.mean());
}

#[test]
fn shipped_scenes_render() {
    let files = gltf_files(&project_scenes(), false);
    for name in ["cornell-box", "caustics", "ajar", "glossy"] {
        assert!(
            files
                .iter()
                .any(|f| f.file_stem().is_some_and(|s| s == name)),
            "scenes/{name}.gltf is missing"
        );
    }
    files.iter().for_each(|f| check(f));
}

#[test]
fn shared_scenes_render() {
    let Some(dir) = shared_scenes() else {
        nrc_scene::testing::skipped("shared_scenes_render", "../shared/scenes is absent");
        return;
    };
    let files = gltf_files(&dir, true);
    if files.is_empty() {
        nrc_scene::testing::skipped(
            "shared_scenes_render",
            &format!("no glTF files under {}", dir.display()),
        );
    }
    files.iter().for_each(|f| check(f));
}
