//! The online loop: deterministic for a seed, snapshots reload and render identically, and a
//! long run on the caustics scene stays finite everywhere.

use nrc_cache::{CacheConfig, CacheDevice, RadianceCache};
use nrc_render::PathTracer;
use nrc_scene::Scene;
use nrc_train::methods::{CacheMethodSettings, scene_trainer};
use nrc_train::{OnlineTrainer, ProducerSpec, Termination};

fn scene(name: &str) -> Scene {
    Scene::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenes")
            .join(name),
    )
    .unwrap()
}

fn trainer(scene: &Scene, producer: &str, records: usize) -> OnlineTrainer {
    let mut s = CacheMethodSettings::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu);
    s.records_per_frame = records;
    s.batch_size = records / 2;
    s.resolution = 128;
    s.seed = 11;
    scene_trainer(
        scene,
        producer.parse::<ProducerSpec>().unwrap(),
        Termination::default(),
        &s,
        PathTracer::default(),
    )
    .unwrap()
}

#[test]
fn online_loop_is_deterministic_and_snapshots_render_identically() {
    let scene = scene("cornell-box.gltf");
    let run = || {
        let mut t = trainer(&scene, "pt-sl", 2048);
        // Half the training queries from the previous frame's termination points.
        t.settings.from_terminations = 0.5;
        let mut last = None;
        for _ in 0..3 {
            let (stats, out) = t.frame(&scene, &scene.camera, 24, 16, true).unwrap();
            assert_eq!(stats.used, stats.records);
            assert_eq!(stats.steps, 2);
            last = Some((stats.loss, out.unwrap().image));
        }
        (t, last.unwrap())
    };
    let (mut a, (loss_a, img_a)) = run();
    let (_, (loss_b, img_b)) = run();
    assert_eq!(loss_a, loss_b);
    assert_eq!(img_a.data, img_b.data);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cache.nrc");
    a.cache.save(&path).unwrap();
    let loaded = RadianceCache::load(&path, CacheDevice::Cpu).unwrap();
    assert_eq!(loaded.scene_box(), a.cache.scene_box());
    let r = a.settings.renderer;
    let before = r
        .render(&scene, &scene.camera, &a.cache, 24, 16, 2, 99)
        .image;
    let after = r
        .render(&scene, &scene.camera, &loaded, 24, 16, 2, 99)
        .image;
    assert_eq!(
        before.data, after.data,
        "a reloaded cache renders bit-identically"
    );
}

#[test]
fn a_long_run_on_caustics_stays_finite() {
    let scene = scene("caustics.gltf");
    for producer in ["mix:pt-sl=0.4,bt=0.2,lt=0.2,sppc=0.2", "pt"] {
        let mut t = trainer(&scene, producer, 2048);
        let (mut records, mut dropped) = (0, 0);
        for f in 0..40 {
            let render = f % 8 == 7;
            let (s, out) = t.frame(&scene, &scene.camera, 24, 24, render).unwrap();
            assert!(s.loss.is_finite(), "{producer} frame {f}: loss {}", s.loss);
            assert_eq!(
                s.used + s.dropped_nonfinite + s.dropped_absurd,
                s.records,
                "every record used or counted"
            );
            records += s.records;
            dropped += s.dropped_nonfinite + s.dropped_absurd;
            if let Some(out) = out {
                assert_eq!(out.stats.invalid_samples, 0, "{producer} frame {f}");
                assert!(
                    out.image
                        .data
                        .iter()
                        .all(|p| p.is_finite() && p.min_element() >= 0.0)
                );
            }
        }
        let (grid, mlp) = t.cache.weights();
        assert!(
            grid.iter().chain(&mlp).all(|w| w.is_finite()),
            "{producer}: non-finite weight"
        );
        println!("{producer}: {records} records, {dropped} dropped, final loss finite");
    }
}
