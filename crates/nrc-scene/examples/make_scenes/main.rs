//! Writes the scenes the project ships: `scenes/<name>.gltf` with its `.bin` buffer and PNG
//! textures, for `cornell-box` (and `cornell-box-moving` and `cornell-box-jump`, its light
//! animated, linearly and in steps), `caustics`,
//! `ajar`, `glossy`, `sun-spot-env` (with the
//! HDR sky `sky.exr` it is rendered under), `many-lights` and `large/rocks` (5.12 M
//! triangles by instancing), then checks each file
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
mod many_lights;
mod mesh;
mod rocks;
mod sun_spot_env;
mod textures;

use std::path::PathBuf;
use std::process::ExitCode;

/// A 32-bit integer hash (lowbias32), for the generators' pseudo-random choices.
pub fn hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// Builds one scene's document.
type Builder = fn() -> gltf_doc::Document;

const SCENES: [(&str, Builder); 9] = [
    ("cornell-box", cornell_box::build),
    ("cornell-box-moving", cornell_box::build_moving),
    ("cornell-box-jump", cornell_box::build_jump),
    ("caustics", caustics::build),
    ("ajar", ajar::build),
    ("glossy", glossy::build),
    ("sun-spot-env", sun_spot_env::build),
    ("many-lights", many_lights::build),
    // In its own folder: the tests that load every scene in `scenes/` many times (the
    // mutation tests) would spend minutes on its 5 M triangles.
    ("large/rocks", rocks::build),
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
    for (path, build) in SCENES {
        let (dir, name) = match path.rsplit_once('/') {
            Some((sub, name)) => (dir.join(sub), name),
            None => (dir.clone(), path),
        };
        if let Err(e) = std::fs::create_dir_all(&dir) {
            eprintln!("error: cannot create {}: {e}", dir.display());
            return ExitCode::FAILURE;
        }
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
            "{name:12} {:6} triangles, {:2} emissive, emitted power ({:.3}, {:.3}, {:.3}) W, {} punctual",
            s.triangles,
            s.emissive_triangles,
            s.power.x,
            s.power.y,
            s.power.z,
            s.punctual.len()
        );
    }
    if let Err(e) = sun_spot_env::write_sky(&dir) {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    println!(
        "sky.exr      {}x{} equirectangular sky",
        sun_spot_env::SKY_SIZE.0,
        sun_spot_env::SKY_SIZE.1
    );
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
    if scene.light_count() != stats.emissive_triangles + stats.punctual.len() {
        return Err(format!(
            "loader sees {} lights, {} emissive triangles and {} punctual lights written",
            scene.light_count(),
            stats.emissive_triangles,
            stats.punctual.len()
        ));
    }
    let loaded = scene.punctual_lights();
    if loaded.len() != stats.punctual.len() {
        return Err(format!(
            "loader sees {} punctual lights, {} written",
            loaded.len(),
            stats.punctual.len()
        ));
    }
    // Every written light must have its own loaded twin (the orders may differ).
    let mut unmatched: Vec<&nrc_scene::light::PunctualLight> = loaded.iter().collect();
    for (kind, intensity, position, direction) in &stats.punctual {
        let close = |a: glam::Vec3, b: glam::Vec3| {
            (a - b).abs().max_element() <= 1e-5 * (1.0 + b.abs().max_element())
        };
        let same = |l: &nrc_scene::light::PunctualLight| {
            let kind_ok = match (l.kind, kind) {
                (nrc_scene::light::PunctualKind::Point, gltf_doc::LightKind::Point)
                | (nrc_scene::light::PunctualKind::Directional, gltf_doc::LightKind::Directional) => {
                    true
                }
                (
                    nrc_scene::light::PunctualKind::Spot {
                        cos_inner,
                        cos_outer,
                    },
                    gltf_doc::LightKind::Spot {
                        inner_cone_angle,
                        outer_cone_angle,
                    },
                ) => {
                    (cos_inner - inner_cone_angle.cos()).abs() < 1e-6
                        && (cos_outer - outer_cone_angle.cos()).abs() < 1e-6
                }
                _ => false,
            };
            let placed = l.kind == nrc_scene::light::PunctualKind::Directional
                || close(l.position, *position);
            kind_ok && placed && close(l.intensity, *intensity) && close(l.direction, *direction)
        };
        match unmatched.iter().position(|l| same(l)) {
            Some(i) => {
                unmatched.swap_remove(i);
            }
            None => {
                return Err(format!(
                    "the loader has no light like the written {kind:?}, intensity {intensity}, position {position}, direction {direction}"
                ));
            }
        }
    }
    // The loader weighs lights by luminance × area × sides, without the Lambertian π, and
    // punctual lights by their own power (checked against the written lights above).
    let radius = scene.bounding_sphere().1;
    let expected = nrc_scene::sampling::luminance(stats.power) as f64 / std::f64::consts::PI
        + loaded
            .iter()
            .map(|l| f64::from(l.power(radius)))
            .sum::<f64>();
    let loaded = scene.lights().total_power();
    if ((loaded - expected) / expected).abs() > 1e-3 {
        return Err(format!(
            "loader's light power {loaded} differs from the written {expected}"
        ));
    }
    Ok(())
}
