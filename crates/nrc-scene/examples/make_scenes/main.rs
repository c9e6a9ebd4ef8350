//! Writes the scenes the project ships: `scenes/<name>.gltf` with its `.bin` buffer and PNG
//! textures, for `cornell-box`, `caustics`, `ajar` and `glossy`, then checks each file
//! against the glTF 2.0 rules (see `check.rs`), loads it with the project's own loader
//! (`nrc_scene::Scene::load`), checks that the loader sees what was written (triangles,
//! lights, emitted power, the camera, no warnings), and prints the figures.
//!
//! ```text
//! cargo run --release -p nrc-scene --example make_scenes [-- OUTPUT_DIR]
//! ```
//!
//! scenes/README.md describes each scene and the sources of its numbers.

mod ajar;
mod caustics;
mod check;
mod cornell_box;
mod glossy;
mod gltf_doc;
mod mesh;
mod textures;

use std::path::PathBuf;
use std::process::ExitCode;

/// Builds one scene's document.
type Builder = fn() -> gltf_doc::Document;

const SCENES: [(&str, Builder); 4] = [
    ("cornell-box", cornell_box::build),
    ("caustics", caustics::build),
    ("ajar", ajar::build),
    ("glossy", glossy::build),
];

fn main() -> ExitCode {
    let dir = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes"));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("error: cannot create {}: {e}", dir.display());
        return ExitCode::FAILURE;
    }
    for (name, build) in SCENES {
        let doc = build();
        if let Err(e) = doc.write(&dir, name) {
            eprintln!("error: writing {name} into {}: {e}", dir.display());
            return ExitCode::FAILURE;
        }
        if let Err(e) = check::validate(&dir, name) {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
        let s = doc.stats();
        if let Err(e) = check_loaded(&dir, name, &s) {
            eprintln!("error: {name}: {e}");
            return ExitCode::FAILURE;
        }
        println!(
            "{name:12} {:6} triangles, {:2} emissive, emitted power ({:.3}, {:.3}, {:.3}) W",
            s.triangles, s.emissive_triangles, s.power.x, s.power.y, s.power.z
        );
    }
    ExitCode::SUCCESS
}

/// Loads the written scene with the project's loader and compares it with the generator's
/// own figures.
fn check_loaded(dir: &std::path::Path, name: &str, stats: &gltf_doc::Stats) -> Result<(), String> {
    let scene = nrc_scene::Scene::load(&dir.join(format!("{name}.gltf")))
        .map_err(|e| format!("loader: {e}"))?;
    if scene.triangle_count() != stats.triangles {
        return Err(format!(
            "loader sees {} triangles, {} written",
            scene.triangle_count(),
            stats.triangles
        ));
    }
    if scene.light_count() != stats.emissive_triangles {
        return Err(format!(
            "loader sees {} lights, {} written",
            scene.light_count(),
            stats.emissive_triangles
        ));
    }
    if !scene.camera_from_file() {
        return Err("loader did not take the camera from the file".into());
    }
    if let Some(w) = scene.warnings().first() {
        return Err(format!("loader warns: {w}"));
    }
    // The loader weighs lights by luminance × area × sides, without the Lambertian π.
    let expected = nrc_scene::sampling::luminance(stats.power) as f64 / std::f64::consts::PI;
    let loaded = scene.lights().total_power();
    if ((loaded - expected) / expected).abs() > 1e-3 {
        return Err(format!(
            "loader's light power {loaded} differs from the written {expected}"
        ));
    }
    Ok(())
}
