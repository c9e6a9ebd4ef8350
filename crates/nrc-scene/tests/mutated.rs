//! Mutation tests of the glTF loader (issue 21): the scenes the project ships, copied into a
//! temporary folder with their buffers and textures, then one file mutated by a seeded
//! mutator (bytes flipped, truncated, a range repeated, a JSON number set to NaN, ±Inf, a
//! huge or a negative value, an index broken). The property: `Scene::load` returns (a scene
//! or an error), never panics, and ends within a time limit. A bounded number of cases run
//! in CI; `NRC_MUTATIONS=N cargo test --release --test mutated -- --ignored` runs N per scene.
//! A failing input is written to the system's temporary folder and named in the failure, to be
//! kept as a fixture.

use std::path::{Path, PathBuf};
use std::time::Duration;

use nrc_scene::Scene;
use nrc_scene::testing::{guarded, mutate};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Longest a load may take (the largest shipped scene loads in well under a second).
const LIMIT: Duration = Duration::from_secs(20);

fn project_scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

/// The files a `.gltf` names by `"uri"` (buffers and images), besides itself.
fn companions(gltf: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(gltf).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut out = Vec::new();
    for key in ["buffers", "images"] {
        for item in json[key].as_array().into_iter().flatten() {
            if let Some(uri) = item["uri"].as_str() {
                out.push(uri.to_string());
            }
        }
    }
    out
}

/// Loads `path` on its own thread, within the time limit.
fn load_guarded(path: &Path) -> Result<bool, String> {
    let p = path.to_path_buf();
    guarded(LIMIT, move || Scene::load(&p).is_ok())
}

/// `cases` mutations of every shipped scene (each case one file: the `.gltf` itself or one of
/// its companions); returns (cases, loaded, errors) or panics naming the failing inputs, which
/// are copied to the system's temporary folder to be kept as fixtures.
fn run(cases: u32, seed: u64) -> (u32, u32, u32) {
    let mut gltfs: Vec<PathBuf> = std::fs::read_dir(project_scenes())
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "gltf"))
        .collect();
    gltfs.sort();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let (mut total, mut loaded, mut errors) = (0, 0, 0);
    let mut failures = Vec::new();
    for gltf in &gltfs {
        let dir = tempfile::tempdir().unwrap();
        let name = gltf.file_name().unwrap().to_string_lossy().into_owned();
        let files: Vec<String> = std::iter::once(name.clone())
            .chain(companions(gltf))
            .collect();
        for f in &files {
            std::fs::copy(project_scenes().join(f), dir.path().join(f)).unwrap();
        }
        for _ in 0..cases {
            // Mostly the document (where the counts and indices live), else a companion.
            let target = if rng.random_bool(0.7) || files.len() == 1 {
                &files[0]
            } else {
                &files[rng.random_range(1..files.len())]
            };
            let original = std::fs::read(project_scenes().join(target)).unwrap();
            let mutated = mutate(&original, target.ends_with(".gltf"), &mut rng);
            std::fs::write(dir.path().join(target), &mutated).unwrap();
            match load_guarded(&dir.path().join(&name)) {
                Ok(true) => loaded += 1,
                Ok(false) => errors += 1,
                Err(why) => {
                    let keep =
                        std::env::temp_dir().join(format!("nrc-mutated-{}-{}", total, target));
                    let _ = std::fs::write(&keep, &mutated);
                    failures.push(format!(
                        "{name} with {target} mutated ({why}), kept as {}",
                        keep.display()
                    ));
                }
            }
            std::fs::write(dir.path().join(target), &original).unwrap();
            total += 1;
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {total} mutated inputs failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
    (total, loaded, errors)
}

#[test]
fn mutated_shipped_scenes_load_or_fail_cleanly() {
    let t = std::time::Instant::now();
    let (total, loaded, errors) = run(200, 21);
    println!(
        "{total} mutated inputs in {:.1} s: {loaded} loaded, {errors} clean errors",
        t.elapsed().as_secs_f64()
    );
    assert!(
        errors > 0 && loaded > 0,
        "the mutations should both break and spare files"
    );
}

/// The long run: `NRC_MUTATIONS` cases per scene (default 2000).
#[test]
#[ignore]
fn many_mutated_shipped_scenes_load_or_fail_cleanly() {
    let cases = std::env::var("NRC_MUTATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000);
    let t = std::time::Instant::now();
    let (total, loaded, errors) = run(cases, 2026);
    println!(
        "{total} mutated inputs in {:.1} s: {loaded} loaded, {errors} clean errors",
        t.elapsed().as_secs_f64()
    );
}
