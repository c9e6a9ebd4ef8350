//! Mutation tests of the cache's loaders (issue 21): the configurations the project ships
//! (`models/*.json`) and a trained snapshot, mutated by the seeded mutator of
//! `nrc_scene::testing` (bytes flipped, truncated, a range repeated, a number set to NaN, ±Inf,
//! a huge or a negative value; half the snapshot cases aimed at its JSON header, where the
//! configuration and the shapes live). The property: a configuration gives a cache that trains
//! one step and infers finite radiance, a snapshot loads and infers finite radiance, or an
//! error; never a panic or a hang, and no allocation beyond [`MAX_ALLOCATION`] at once whatever
//! size the file claims. `NRC_MUTATIONS=N cargo test --release --test mutated -- --ignored`
//! runs N per file. (The one test that runs by default sees the allocation bound alone.)

use std::path::Path;
use std::time::Duration;

use nrc_cache::{CacheConfig, CacheDevice, CacheQuery, RadianceCache, TrainingBatch};
use nrc_scene::testing::{LargestAllocation, Tally, mutate};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[global_allocator]
static ALLOCATOR: LargestAllocation = LargestAllocation;

const LIMIT: Duration = Duration::from_secs(30);

/// The most a cache may allocate at once: 256 MiB. The hash-grid preset's own largest
/// allocation (186 MiB: its 2^19-entry tables, 16 levels, in the fused trainer's buffers) is
/// measured and printed beside it.
const MAX_ALLOCATION: usize = 256 << 20;

fn batch(n: usize, rng: &mut Pcg64Mcg) -> TrainingBatch {
    let queries: Vec<CacheQuery> = (0..n)
        .map(|_| CacheQuery {
            position: [rng.random(), rng.random(), rng.random()],
            direction: [0.0, 0.6, 0.8],
            normal: [0.0, 0.0, 1.0],
            roughness: 0.3,
            diffuse: [0.6, 0.5, 0.4],
            specular: [0.04; 3],
        })
        .collect();
    let targets = queries.iter().map(|q| [q.position[0], 0.5, 0.2]).collect();
    TrainingBatch {
        queries,
        targets,
        weights: None,
    }
}

/// A configuration's text: parsed, built, one training step and an inference.
fn usable(text: String, data: TrainingBatch) -> impl FnOnce() -> Option<bool> + Send + 'static {
    move || {
        let config = CacheConfig::from_json_str(&text).ok()?;
        let mut cache = RadianceCache::new(config, CacheDevice::Cpu).ok()?;
        cache.train(&data, 1).ok()?;
        Some(
            cache
                .infer(&data.queries)
                .iter()
                .flatten()
                .all(|x| x.is_finite()),
        )
    }
}

fn run(cases: u32, seed: u64) -> (Tally, usize) {
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    let mut files: Vec<_> = std::fs::read_dir(&models)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    assert!(files.len() >= 2, "the shipped configurations");
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut tally = Tally::default();
    let mut baseline = 0;
    // Every input that ever failed (tests/fixtures/mutated/: configurations that built, trained
    // and then inferred non-finite radiance, before the learning rate was bounded).
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/mutated");
    let mut kept: Vec<_> = std::fs::read_dir(&fixtures)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .collect();
    kept.sort();
    for path in kept {
        let bytes = std::fs::read(&path).unwrap();
        let label = format!("fixture-{}", path.file_name().unwrap().to_string_lossy());
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let data = batch(256, &mut rng);
        tally.case(
            "fixture",
            &label,
            &bytes,
            (LIMIT, MAX_ALLOCATION),
            usable(text, data),
        );
    }
    for file in &files {
        let original = std::fs::read(file).unwrap();
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        nrc_scene::testing::reset_largest_allocation();
        let text = String::from_utf8(original.clone()).unwrap();
        assert_eq!(usable(text, batch(256, &mut rng))(), Some(true), "{name}");
        baseline = baseline.max(nrc_scene::testing::largest_allocation());
        for case in 0..cases {
            let mutated = mutate(&original, true, &mut rng);
            let text = String::from_utf8_lossy(&mutated).into_owned();
            let label = format!("{case}-{name}");
            let data = batch(256, &mut rng);
            tally.case(
                "config",
                &label,
                &mutated,
                (LIMIT, MAX_ALLOCATION),
                usable(text, data),
            );
        }
    }
    snapshots(&mut tally, cases * 4, &mut rng);
    hash_snapshots(&mut tally, cases * 2, &mut rng);
    (tally, baseline)
}

/// `cases` mutations of a snapshot of the hash-grid preset with 2^14-entry tables (the preset's
/// 2^19 make a 100 MB file, a second per case to write and read) trained a few steps.
fn snapshots(tally: &mut Tally, cases: u32, rng: &mut Pcg64Mcg) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cache.nrc");
    let text = include_str!("../../../models/nrc-hashgrid.json");
    assert_eq!(text.matches("\"log2_hashmap_size\": 19").count(), 1);
    let small = text.replace("\"log2_hashmap_size\": 19", "\"log2_hashmap_size\": 14");
    let config = CacheConfig::from_json_str(&small).unwrap();
    let mut cache = RadianceCache::new(config, CacheDevice::Cpu).unwrap();
    cache.train(&batch(1024, rng), 4).unwrap();
    cache.save(&file).unwrap();
    let bytes = std::fs::read(&file).unwrap();
    for case in 0..cases {
        let mutated = mutated_snapshot(&bytes, case, rng);
        let f = dir.path().join(format!("m{case}.nrc"));
        std::fs::write(&f, &mutated).unwrap();
        let probe = batch(64, rng).queries;
        let label = format!("{case}.nrc");
        tally.case(
            "snapshot",
            &label,
            &mutated,
            (LIMIT, MAX_ALLOCATION),
            move || {
                let c = RadianceCache::load(&f, CacheDevice::Cpu).ok()?;
                Some(c.infer(&probe).iter().flatten().all(|x| x.is_finite()))
            },
        );
    }
}

/// Mutation `case` of a safetensors snapshot: even cases mutate its JSON header (the length
/// prefix kept consistent), odd ones the whole file.
fn mutated_snapshot(bytes: &[u8], case: u32, rng: &mut Pcg64Mcg) -> Vec<u8> {
    let header = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    if case % 2 == 0 {
        let mut m = mutate(&bytes[8..header], true, rng);
        let mut out = (m.len() as u64).to_le_bytes().to_vec();
        out.append(&mut m);
        out.extend_from_slice(&bytes[header..]);
        out
    } else {
        mutate(bytes, false, rng)
    }
}

/// `cases` mutations of a spatial-hash cache's snapshot (a 2^12-slot table), half aimed at its
/// JSON header (the settings that size the table among them).
fn hash_snapshots(tally: &mut Tally, cases: u32, rng: &mut Pcg64Mcg) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("hash.nrc");
    let config = nrc_cache::HashCacheConfig {
        log2_capacity: 12,
        ..Default::default()
    };
    let mut cache = nrc_cache::HashCache::new(config, Default::default()).unwrap();
    cache.train(&batch(1024, rng)).unwrap();
    cache.save(&file).unwrap();
    // The unmutated file loads and answers as the cache did.
    let probe = batch(64, rng).queries;
    let loaded = nrc_cache::Cache::load(&file, CacheDevice::Cpu).unwrap();
    assert_eq!(loaded.infer(&probe), cache.infer(&probe));
    let bytes = std::fs::read(&file).unwrap();
    for case in 0..cases {
        let mutated = mutated_snapshot(&bytes, case, rng);
        let f = dir.path().join(format!("h{case}.nrc"));
        std::fs::write(&f, &mutated).unwrap();
        let probe = batch(64, rng).queries;
        tally.case(
            "hash snapshot",
            &format!("{case}-hash.nrc"),
            &mutated,
            (LIMIT, MAX_ALLOCATION),
            move || {
                let c = nrc_cache::Cache::load(&f, CacheDevice::Cpu).ok()?;
                Some(c.infer(&probe).iter().flatten().all(|x| x.is_finite()))
            },
        );
    }
}

#[test]
fn mutated_configurations_and_snapshots_load_or_fail_cleanly() {
    let t = std::time::Instant::now();
    let (tally, baseline) = run(50, 21);
    println!(
        "mutated configurations in {:.1} s; largest allocation of a shipped one {:.1} MiB, bound {} MiB:\n{}",
        t.elapsed().as_secs_f64(),
        baseline as f64 / (1 << 20) as f64,
        MAX_ALLOCATION >> 20,
        tally.summary()
    );
    tally.assert_clean();
    assert!(
        tally.kinds["config"].2 > 0,
        "some mutations must break a configuration"
    );
    assert!(
        tally.kinds["snapshot"].2 > 0,
        "some mutations must break a snapshot"
    );
    assert!(
        tally.kinds["hash snapshot"].2 > 0,
        "some mutations must break a hash snapshot"
    );
}

#[test]
#[ignore]
fn many_mutated_configurations_and_snapshots_load_or_fail_cleanly() {
    let cases = nrc_scene::testing::mutation_cases(2000);
    let t = std::time::Instant::now();
    let (tally, _) = run(cases, 2026);
    println!("{:.1} s:\n{}", t.elapsed().as_secs_f64(), tally.summary());
    tally.assert_clean();
}
