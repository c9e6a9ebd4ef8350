//! Mutation tests of the harness's loaders (issue 21): camera paths (`--camera-path`, JSON
//! keyframes) and references, as a stored entry (`reference.json`, `mean.exr`,
//! `variance.exr`) and as a bare EXR given by `--reference`. Seed inputs: a camera path through
//! the Cornell box and a reference of it rendered here; one file mutated by the seeded mutator
//! of `nrc_scene::testing`. The property: a usable result (finite cameras; a reference of the
//! size asked for, finite and non-negative) or an error, never a panic or a hang, and no
//! allocation beyond [`MAX_ALLOCATION`] at once. `NRC_MUTATIONS=N cargo test --release --test
//! mutated -- --ignored` runs N per file. (The one test that runs by default sees the
//! allocation bound alone.)

use std::path::{Path, PathBuf};
use std::time::Duration;

use nrc_harness::reference::{self, ReferenceRequest};
use nrc_render::PathTracer;
use nrc_scene::Scene;
use nrc_scene::testing::{LargestAllocation, Tally, mutate};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[global_allocator]
static ALLOCATOR: LargestAllocation = LargestAllocation;

const LIMIT: Duration = Duration::from_secs(20);

/// 64 MiB at once: a camera path of 64 frames and a 16 × 16 reference need well under 1 MiB.
const MAX_ALLOCATION: usize = 64 << 20;

const CAMERA_PATH: &str = r#"[
  {"position": [0.278, 0.273, -0.8], "target": [0.278, 0.273, 0.0]},
  {"position": [0.1, 0.3, -0.7], "target": [0.3, 0.25, 0.3], "fov_y": 35.0},
  {"position": [0.45, 0.35, -0.6], "target": [0.25, 0.2, 0.3], "up": [0.1, 1.0, 0.0], "fov_y": 42.5}
]"#;

fn scene_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.gltf")
}

fn run(cases: u32, seed: u64) -> Tally {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut tally = Tally::default();
    let scene = Scene::load(&scene_path()).unwrap();
    let base = scene.camera;
    let dir = tempfile::tempdir().unwrap();

    // Camera paths.
    for case in 0..cases {
        let mutated = mutate(CAMERA_PATH.as_bytes(), true, &mut rng);
        let path = dir.path().join(format!("path-{case}.json"));
        std::fs::write(&path, &mutated).unwrap();
        let label = format!("{case}-camera-path.json");
        tally.case(
            "camera path",
            &label,
            &mutated,
            (LIMIT, MAX_ALLOCATION),
            move || {
                let cams = nrc_harness::run::camera_path(Some(&path), &base, 64).ok()?;
                Some(
                    cams.len() == 64
                        && cams
                            .iter()
                            .all(|c| c.position.is_finite() && c.forward.is_finite()),
                )
            },
        );
    }

    // A stored reference entry, and its mean image as a bare EXR.
    let store = dir.path().join("references");
    let req = ReferenceRequest {
        scene_path: &scene_path(),
        scene: &scene,
        width: 16,
        height: 16,
        spp: 4,
        seed: 3,
        tracer: PathTracer::default(),
    };
    let entry = reference::obtain(&req, &store, false, &|_| ())
        .unwrap()
        .location;
    let files: Vec<String> = ["reference.json", "mean.exr", "variance.exr"]
        .iter()
        .map(|f| f.to_string())
        .filter(|f| entry.join(f).exists())
        .collect();
    assert_eq!(files.len(), 3, "the entry's files in {}", entry.display());
    let good = |r: &reference::Reference| {
        r.mean.width == 16
            && r.mean.height == 16
            && r.mean
                .data
                .iter()
                .all(|p| p.is_finite() && p.min_element() >= 0.0)
    };
    for case in 0..cases {
        let target = &files[rng.random_range(0..files.len())];
        let original = std::fs::read(entry.join(target)).unwrap();
        let mutated = mutate(&original, target.ends_with(".json"), &mut rng);
        let copy = dir.path().join(format!("entry-{case}"));
        std::fs::create_dir_all(&copy).unwrap();
        for f in &files {
            std::fs::copy(entry.join(f), copy.join(f)).unwrap();
        }
        std::fs::write(copy.join(target), &mutated).unwrap();
        let label = format!("{case}-entry-{target}");
        tally.case(
            "reference entry",
            &label,
            &mutated,
            (LIMIT, MAX_ALLOCATION),
            move || reference::load_given(&copy, 16, 16).ok().map(|r| good(&r)),
        );
        if target == "mean.exr" {
            let bare = dir.path().join(format!("bare-{case}.exr"));
            std::fs::write(&bare, &mutated).unwrap();
            let label = format!("{case}-bare.exr");
            tally.case(
                "reference exr",
                &label,
                &mutated,
                (LIMIT, MAX_ALLOCATION),
                move || reference::load_given(&bare, 16, 16).ok().map(|r| good(&r)),
            );
        }
    }
    tally
}

#[test]
fn mutated_camera_paths_and_references_load_or_fail_cleanly() {
    let t = std::time::Instant::now();
    let tally = run(300, 21);
    println!(
        "mutated inputs in {:.1} s (allocation bound {} MiB):\n{}",
        t.elapsed().as_secs_f64(),
        MAX_ALLOCATION >> 20,
        tally.summary()
    );
    tally.assert_clean();
    for (kind, (_, loaded, refused)) in &tally.kinds {
        assert!(*refused > 0, "{kind}: some mutations must break a file");
        let _ = loaded;
    }
}

#[test]
#[ignore]
fn many_mutated_camera_paths_and_references_load_or_fail_cleanly() {
    let cases = nrc_scene::testing::mutation_cases(5000);
    let t = std::time::Instant::now();
    let tally = run(cases, 2026);
    println!("{:.1} s:\n{}", t.elapsed().as_secs_f64(), tally.summary());
    tally.assert_clean();
}
