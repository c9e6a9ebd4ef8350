//! Mutation tests of the scene loaders (issue 21): glTF (`.gltf` with its buffers and PNG
//! textures, and `.glb`) and EXR environments, starting from the files the project ships
//! (`scenes/`, each `.gltf` also packed into a `.glb` here) and those in `../shared/scenes/`
//! (skipped with a message where that folder is absent). One file of a copy is mutated by the
//! seeded mutator of `nrc_scene::testing` (bytes flipped, truncated, a range repeated, a JSON
//! number set to NaN, ±Inf, a huge or a negative value, an index broken; a `.glb`'s JSON chunk
//! mutated as text and packed again). The property: the loader returns a usable result (a
//! scene with a finite bounding box, an environment) or an error, never panics, answers
//! within [`LIMIT`], and allocates no more than [`MAX_ALLOCATION`] at once (or ten times what
//! the unmutated scene needs, for a scene that needs more than a tenth of it), whatever count
//! a file claims.
//!
//! A bounded number of cases run in CI; `NRC_MUTATIONS=N cargo test --release -p nrc-scene --test
//! mutated -- --ignored` runs N per file. A failing input is written to the system's temporary folder
//! and named in the failure; inputs that ever failed are kept in `tests/fixtures/mutated/` and
//! loaded by every run. The two tests of this binary never run together (one is ignored), so
//! the allocation bound sees one case at a time.

use std::path::{Path, PathBuf};
use std::time::Duration;

use nrc_scene::testing::{LargestAllocation, Tally, mutate, skipped};
use nrc_scene::{Environment, Scene};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[global_allocator]
static ALLOCATOR: LargestAllocation = LargestAllocation;

/// Longest a load may take (the largest scene here loads in well under a second).
const LIMIT: Duration = Duration::from_secs(20);

/// The most a load may allocate at once: 256 MiB, about 280 times the largest file here
/// (`../shared/scenes/kajiya-roughness-scale/scene.bin`, 0.9 MB); the unmutated files need
/// less than a tenth of it.
const MAX_ALLOCATION: usize = 256 << 20;

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

/// A `.glb` container: the 12-byte header, the JSON chunk (padded with spaces) and, when
/// given, the BIN chunk (padded with zeros).
fn pack_glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    let pad = |v: &mut Vec<u8>, with: u8| {
        while !v.len().is_multiple_of(4) {
            v.push(with);
        }
    };
    let mut j = json.to_vec();
    pad(&mut j, b' ');
    let mut chunks = Vec::new();
    chunks.extend((j.len() as u32).to_le_bytes());
    chunks.extend(b"JSON");
    chunks.extend(&j);
    if let Some(bin) = bin {
        let mut b = bin.to_vec();
        pad(&mut b, 0);
        chunks.extend((b.len() as u32).to_le_bytes());
        chunks.extend(b"BIN\0");
        chunks.extend(&b);
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend((12 + chunks.len() as u32).to_le_bytes());
    out.extend(chunks);
    out
}

/// The JSON and BIN chunks of a `.glb` this file packed (or a well-formed one).
fn unpack_glb(glb: &[u8]) -> (Vec<u8>, Option<Vec<u8>>) {
    let len = |at: usize| u32::from_le_bytes(glb[at..at + 4].try_into().unwrap()) as usize;
    let j = len(12);
    let json = glb[20..20 + j].to_vec();
    let bin = (glb.len() > 20 + j + 8).then(|| {
        let b = len(20 + j);
        glb[28 + j..28 + j + b].to_vec()
    });
    (json, bin)
}

/// A shipped `.gltf` with one external buffer as a `.glb` (its images stay external files).
fn glb_of(gltf: &Path) -> Option<Vec<u8>> {
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(gltf).unwrap()).unwrap();
    let buffers = json["buffers"].as_array_mut()?;
    if buffers.len() != 1 {
        return None;
    }
    let uri = buffers[0]["uri"].as_str()?.to_string();
    buffers[0].as_object_mut()?.remove("uri");
    let bin = std::fs::read(gltf.parent()?.join(uri)).ok()?;
    Some(pack_glb(json.to_string().as_bytes(), Some(&bin)))
}

/// One mutation of a `.glb`: half the time of the whole container as bytes, else of its JSON
/// chunk as text, packed again with correct lengths.
fn mutate_glb(glb: &[u8], rng: &mut Pcg64Mcg) -> Vec<u8> {
    if rng.random_bool(0.5) {
        return mutate(glb, false, rng);
    }
    let (json, bin) = unpack_glb(glb);
    pack_glb(&mutate(&json, true, rng), bin.as_deref())
}

fn scene_loads(path: PathBuf) -> impl FnOnce() -> Option<bool> + Send + 'static {
    move || {
        Scene::load(&path).ok().map(|s| {
            let b = s.bounds();
            b.min.is_finite() && b.max.is_finite()
        })
    }
}

/// A scene folder copied into a temporary one: `main` (a `.gltf` or `.glb`) and its companions.
struct Copy {
    dir: tempfile::TempDir,
    files: Vec<String>,
}

impl Copy {
    fn of(main: &Path, extra: &[(String, Vec<u8>)]) -> Self {
        let source = main.parent().unwrap();
        let name = main.file_name().unwrap().to_string_lossy().into_owned();
        let dir = tempfile::tempdir().unwrap();
        let mut files = vec![name];
        if main.extension().is_some_and(|e| e == "gltf") {
            files.extend(companions(main));
        }
        for f in &files {
            std::fs::copy(source.join(f), dir.path().join(f)).unwrap();
        }
        for (f, bytes) in extra {
            std::fs::write(dir.path().join(f), bytes).unwrap();
            files.insert(0, f.clone());
        }
        Self { dir, files }
    }
}

/// `cases` mutations of the scene `main` (the first file of `copy`), each of one file: mostly
/// the document (where counts and indices live), else a companion. First the unmutated scene,
/// whose largest allocation is returned (the bound's baseline). A mutated scene may allocate
/// [`MAX_ALLOCATION`] at once, or ten times its unmutated scene where that is more (the
/// kitchen of `../shared/scenes`, 1.44 M triangles, needs 154 MiB at once unmutated).
fn mutate_scene(
    tally: &mut Tally,
    copy: &Copy,
    cases: u32,
    rng: &mut Pcg64Mcg,
    tag: &str,
) -> usize {
    let main = copy.files[0].clone();
    nrc_scene::testing::reset_largest_allocation();
    assert!(
        scene_loads(copy.dir.path().join(&main))() == Some(true),
        "{tag} loads unmutated"
    );
    let baseline = nrc_scene::testing::largest_allocation();
    let bound = MAX_ALLOCATION.max(10 * baseline);
    for case in 0..cases {
        let target = if rng.random_bool(0.7) || copy.files.len() == 1 {
            main.clone()
        } else {
            copy.files[rng.random_range(1..copy.files.len())].clone()
        };
        let original = std::fs::read(copy.dir.path().join(&target)).unwrap();
        let ext = Path::new(&target)
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let mutated = match ext.as_str() {
            "glb" => mutate_glb(&original, rng),
            "gltf" => mutate(&original, true, rng),
            _ => mutate(&original, false, rng),
        };
        std::fs::write(copy.dir.path().join(&target), &mutated).unwrap();
        tally.case(
            &ext,
            &format!("{tag}-{case}-{target}"),
            &mutated,
            (LIMIT, bound),
            scene_loads(copy.dir.path().join(&main)),
        );
        std::fs::write(copy.dir.path().join(&target), &original).unwrap();
    }
    baseline
}

/// The scenes of `../shared/scenes/` (a `.glb` or a `.gltf` per folder), or `None` with a
/// skip message where that folder is absent.
fn shared_scenes() -> Option<Vec<PathBuf>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    let Ok(dirs) = std::fs::read_dir(&root) else {
        skipped(
            "mutated_inputs (../shared/scenes)",
            &format!("{} is absent", root.display()),
        );
        return None;
    };
    let mut out: Vec<PathBuf> = dirs
        .flatten()
        .flat_map(|d| std::fs::read_dir(d.path()).into_iter().flatten().flatten())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "glb" || e == "gltf"))
        .collect();
    out.sort();
    Some(out)
}

/// Every input that ever failed, kept in `tests/fixtures/mutated/`: each loads or fails cleanly.
fn fixtures(tally: &mut Tally) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/mutated");
    for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
        let path = e.path();
        let bytes = std::fs::read(&path).unwrap();
        let label = format!("fixture-{}", path.file_name().unwrap().to_string_lossy());
        if path.extension().is_some_and(|e| e == "exr") {
            tally.case(
                "fixture",
                &label,
                &bytes,
                (LIMIT, MAX_ALLOCATION),
                move || Environment::load(&path, 1.0, 0.0).ok().map(|_| true),
            );
        } else {
            let load = scene_loads(path);
            tally.case("fixture", &label, &bytes, (LIMIT, MAX_ALLOCATION), load);
        }
    }
}

/// `cases` mutations per file: every shipped scene as `.gltf` (with companions) and as `.glb`,
/// every scene of `../shared/scenes/`, and the shipped EXR sky as an environment.
fn run(cases: u32, seed: u64) -> (Tally, usize) {
    let mut tally = Tally::default();
    let mut baseline = 0;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    fixtures(&mut tally);
    let mut gltfs: Vec<PathBuf> = std::fs::read_dir(project_scenes())
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "gltf"))
        .collect();
    gltfs.sort();
    for gltf in &gltfs {
        let stem = gltf.file_stem().unwrap().to_string_lossy().into_owned();
        let b = mutate_scene(&mut tally, &Copy::of(gltf, &[]), cases, &mut rng, &stem);
        baseline = baseline.max(b);
        if let Some(glb) = glb_of(gltf) {
            // The packed `.glb` beside the `.gltf`'s images.
            let name = format!("{stem}.glb");
            let copy = Copy::of(gltf, &[(name, glb)]);
            // Only the `.glb` itself is mutated (its images were mutated with the `.gltf`).
            let only = Copy {
                files: vec![copy.files[0].clone()],
                ..copy
            };
            let b = mutate_scene(&mut tally, &only, cases, &mut rng, &format!("{stem}-glb"));
            baseline = baseline.max(b);
        }
    }
    for shared in shared_scenes().into_iter().flatten() {
        let tag = format!(
            "shared-{}",
            shared
                .parent()
                .unwrap()
                .file_name()
                .unwrap()
                .to_string_lossy()
        );
        let b = mutate_scene(&mut tally, &Copy::of(&shared, &[]), cases, &mut rng, &tag);
        if b >= MAX_ALLOCATION / 10 {
            println!(
                "{tag}: largest allocation unmutated {:.1} MiB, so its bound is {:.0} MiB",
                b as f64 / (1 << 20) as f64,
                (10 * b) as f64 / (1 << 20) as f64
            );
        } else {
            baseline = baseline.max(b);
        }
    }
    let sky = std::fs::read(project_scenes().join("sky.exr")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for case in 0..cases {
        let mutated = mutate(&sky, false, &mut rng);
        let path = dir.path().join(format!("sky-{case}.exr"));
        std::fs::write(&path, &mutated).unwrap();
        tally.case(
            "exr",
            &format!("sky-{case}.exr"),
            &mutated,
            (LIMIT, MAX_ALLOCATION),
            move || {
                Environment::load(&path, 1.0, 0.0)
                    .ok()
                    .map(|(env, _)| env.radiance(glam::Vec3::Y).is_finite())
            },
        );
    }
    (tally, baseline)
}

#[test]
fn mutated_inputs_load_or_fail_cleanly() {
    let t = std::time::Instant::now();
    let (tally, baseline) = run(100, 21);
    println!(
        "mutated inputs in {:.1} s; largest allocation of an unmutated scene under the fixed bound {:.1} MiB, bound {} MiB:\n{}",
        t.elapsed().as_secs_f64(),
        baseline as f64 / (1 << 20) as f64,
        MAX_ALLOCATION >> 20,
        tally.summary()
    );
    assert!(
        baseline < MAX_ALLOCATION / 10,
        "the bound is tight for the real files"
    );
    tally.assert_clean();
    let (loaded, refused) = tally
        .kinds
        .values()
        .fold((0, 0), |(a, b), k| (a + k.1, b + k.2));
    assert!(
        refused > 0 && loaded > 0,
        "the mutations should both break and spare files"
    );
}

/// The long run: `NRC_MUTATIONS` cases per file (default 2000).
#[test]
#[ignore]
fn many_mutated_inputs_load_or_fail_cleanly() {
    let cases = nrc_scene::testing::mutation_cases(2000);
    let t = std::time::Instant::now();
    let (tally, _) = run(cases, 2026);
    println!(
        "mutated inputs in {:.1} s:\n{}",
        t.elapsed().as_secs_f64(),
        tally.summary()
    );
    tally.assert_clean();
}
