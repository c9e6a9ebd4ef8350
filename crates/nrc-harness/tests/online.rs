//! The online loop: deterministic for a seed, snapshots reload and render identically, online
//! training brings the cache's error down, and long runs on the hard scenes with every producer
//! stay finite everywhere and do not diverge (shortened in CI, 2000 frames on demand).

use nrc_cache::{CacheConfig, CacheDevice, RadianceCache};
use nrc_harness::methods::{CacheMethodSettings, scene_trainer};
use nrc_render::{FrameInput, PassSpec, PathTracer};
use nrc_scene::Scene;
use nrc_train::{CacheSource, OnlineTrainer, ProducerSpec};

fn scene(name: &str) -> Scene {
    Scene::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenes")
            .join(name),
    )
    .unwrap()
}

fn trainer(scene: &Scene, producer: &str, records: usize) -> OnlineTrainer {
    trainer_with(scene, producer, records, CacheConfig::hash_grid_preset())
}

/// [`trainer`] with the cache configured by `config`.
fn trainer_with(
    scene: &Scene,
    producer: &str,
    records: usize,
    config: CacheConfig,
) -> OnlineTrainer {
    trainer_sized(scene, producer, records, config, 128)
}

/// [`trainer_with`] with the hash grid's finest resolution (cells along the scene's longest
/// axis) given.
fn trainer_sized(
    scene: &Scene,
    producer: &str,
    records: usize,
    config: CacheConfig,
    resolution: u32,
) -> OnlineTrainer {
    let mut s = CacheMethodSettings::new(config, CacheDevice::Cpu);
    s.records_per_frame = records;
    s.batch_size = records / 2;
    s.resolution = resolution;
    s.seed = 11;
    scene_trainer(
        scene,
        producer.parse::<ProducerSpec>().unwrap(),
        PassSpec::default(),
        &s,
        PathTracer::default(),
    )
    .unwrap()
}

/// The loss's `return_clipped` (`nrc_train::clipped`, in the presets) runs in the loop:
/// light-tracing records on the caustics scene (light through glass) are clamped at the bound and their bins' gains rise
/// above 1, within the cap; the description line says so. The negative control, the preset
/// without it, clamps nothing and reports no gain.
#[test]
fn the_loop_returns_the_light_the_bound_clips_when_the_loss_asks() {
    let scene = scene("caustics.gltf");
    let preset = CacheConfig::hash_grid_preset();
    let cap = preset
        .loss
        .return_clipped
        .as_ref()
        .expect("the preset returns the clipped light")
        .max_gain;
    let mut without = preset.clone();
    without.loss.return_clipped = None;
    let mut on = trainer_with(&scene, "lt", 2048, preset);
    let mut off = trainer_with(&scene, "lt", 2048, without);
    let describe = on.cache.neural().unwrap().describe();
    assert!(describe.contains("returns the clipped light"), "{describe}");
    let (mut clamped, mut gain) = (0, 0.0f32);
    for _ in 0..12 {
        let (s, _) = on.frame(&scene, &scene.camera, 16, 16, false).unwrap();
        assert!((1.0..=cap).contains(&s.clip_gain), "gain {}", s.clip_gain);
        clamped += s.clamped;
        gain = gain.max(s.clip_gain);
        let (s, _) = off.frame(&scene, &scene.camera, 16, 16, false).unwrap();
        assert_eq!((s.clamped, s.clip_gain), (0, 0.0));
    }
    println!("clamped records {clamped}, largest mean gain {gain}");
    assert!(clamped > 0 && gain > 1.0, "clamped {clamped}, gain {gain}");
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
    let loaded: nrc_cache::Cache = RadianceCache::load(&path, CacheDevice::Cpu).unwrap().into();
    assert_eq!(loaded.scene_box(), a.cache.scene_box());
    let input = FrameInput {
        scene: &scene,
        camera: &scene.camera,
        width: 24,
        height: 16,
        spp: 2,
        seed: 99,
        emitter_samples: 0,
        sequence: None,
    };
    let before = a.render(&input).image;
    let mut pass = a.settings.pass.build(&a.settings.tracer);
    let after = nrc_render::passes::run(pass.as_mut(), &input, &CacheSource::new(&loaded)).image;
    assert_eq!(
        before.data, after.data,
        "a reloaded cache renders bit-identically"
    );
}

/// What a long online run saw.
struct LongRun {
    records: usize,
    dropped_nonfinite: usize,
    dropped_absurd: usize,
    /// The cache's error ([`cache_error`]) after the early checkpoint and at the end.
    early: f64,
    end: f64,
    /// The error at every tenth of the run.
    trajectory: Vec<f64>,
    /// The lowest error of the checkpoints from the early one on.
    lowest: f64,
    /// The relMSE of the mean of the end's renders.
    end_rel_mse: f64,
    ms_per_frame: f64,
    loss: f32,
    /// Changes in the scene the loop called (the scenes are still: false alarms).
    changes: usize,
}

/// A reference of `scene` at `w × h` (`spp` samples), with its emitter mask.
/// The change detector on a scene: on `cornell-box-jump` (the lamp jumps 0.17 m at 1 s, frame
/// 30 at 30 fps) the frame of the jump or the next is called a change, and none before, and
/// the frame after it confirms it (the learning rate's decay restarts there); the cache infers
/// from its training weights from the change and stops once it has caught up, within the
/// recovery's frame limit. The negative control, the same run on the scene held at its first
/// pose, has no change at all.
#[test]
fn a_jumping_light_is_called_a_change_and_recovered_from_and_a_still_scene_is_not() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box-jump.gltf");
    let animated = nrc_scene::AnimatedScene::load(&path).unwrap();
    let first = animated.at(0.0).unwrap();
    // Posing each frame (also the still run's, at 0 s) keeps the two runs alike but for the jump.
    // A decay that has begun by the jump (the preset's starts at step 400), so that its
    // restart shows: halved every 40 steps from step 1 (two steps a frame).
    let config = edited_preset("optimizer.nested.decay_start=1,optimizer.nested.decay_interval=40");
    let run = |jump: bool| {
        let mut t = trainer_with(&first, "pt-sl", 4096, config.clone());
        let mut phases = Vec::new();
        let mut followed = Vec::new();
        let mut rates = Vec::new();
        for f in 0..70u32 {
            let posed = animated
                .at(if jump { f as f32 / 30.0 } else { 0.0 })
                .unwrap();
            let (stats, _) = t.frame(&posed, &posed.camera, 32, 32, true).unwrap();
            phases.push(stats.phase);
            followed.push(t.cache.neural().unwrap().follows());
            rates.push(stats.learning_rate);
        }
        let full = t.cache.neural().unwrap().learning_rate();
        (phases, followed, rates, full)
    };
    use nrc_train::schedule::Phase;
    let (phases, followed, rates, full) = run(true);
    let changes: Vec<usize> = (0..phases.len())
        .filter(|&f| phases[f] == Phase::Changed)
        .collect();
    assert!(
        !changes.is_empty() && (30..=31).contains(&changes[0]),
        "changes called at frames {changes:?}, the light jumps at frame 30"
    );
    let c = changes[0];
    assert!(
        followed[c],
        "the cache does not follow its weights after the change"
    );
    assert_eq!(
        phases[c + 1],
        Phase::Confirmed,
        "the lamp's jump is not confirmed the frame after it: {phases:?}"
    );
    // The rate's decay restarts at the confirmation, not at the call.
    assert!(
        rates[c] < 0.5 * full && rates[c + 1] == full,
        "learning rates {} at the change, {} at its confirmation (full {full})",
        rates[c],
        rates[c + 1]
    );
    let end = (c..phases.len()).find(|&f| phases[f] == Phase::Recovered);
    let end = end.unwrap_or_else(|| panic!("no recovery ended: {phases:?}"));
    assert!(
        end - c <= nrc_train::schedule::RECOVERY_MAX_FRAMES as usize && !followed[end],
        "recovery from frame {c} to {end}"
    );
    let (still, followed, ..) = run(false);
    assert!(
        !still.contains(&Phase::Changed) && !followed.contains(&true),
        "a change called in a still scene: {still:?}"
    );
}

/// Under a training budget the loop sizes each frame's records so that producing and training
/// them takes about what it planned to spend (half the budget once the cache has settled): at
/// 100 ms a frame the median frame after warm-up within 20 % of its plan, and ten times the
/// budget buys more than twice the records (the negative control: a loop that ignored the
/// budget would produce the same records at both). The bar, every frame within 20 %,
/// is measured on a quiet machine by `scripts/budget-study.sh`; a test shares its cores with
/// the other tests.
#[test]
fn a_training_budget_sizes_the_records_to_fit() {
    let scene = scene("cornell-box.gltf");
    let run = |budget: f64| {
        let mut s = CacheMethodSettings::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu);
        s.resolution = 128;
        s.seed = 11;
        s.train_budget_ms = Some(budget);
        let mut t = scene_trainer(
            &scene,
            "pt-sl".parse().unwrap(),
            PassSpec::default(),
            &s,
            PathTracer::default(),
        )
        .unwrap();
        let (mut ratios, mut records) = (Vec::new(), 0usize);
        for f in 0..40 {
            let (stats, _) = t.frame(&scene, &scene.camera, 16, 16, true).unwrap();
            assert!(
                stats.spend_ms == budget || stats.spend_ms == budget / 2.0,
                "{stats:?}"
            );
            if f >= nrc_train::schedule::BUDGET_WARM_UP_FRAMES {
                ratios.push((stats.produce_ms + stats.train_ms) / stats.spend_ms);
                records += stats.records;
            }
        }
        ratios.sort_by(f64::total_cmp);
        (
            ratios[ratios.len() / 2],
            records as f64 / ratios.len() as f64,
        )
    };
    let (median, generous) = run(100.0);
    assert!(median <= 1.2, "median frame at {median:.2} of its plan");
    let (_, tight) = run(10.0);
    assert!(
        generous > 2.0 * tight,
        "records a frame: {generous:.0} at 100 ms, {tight:.0} at 10 ms"
    );
}

fn reference_of(scene: &Scene, (w, h): (u32, u32), spp: u32) -> (nrc_scene::Image, Vec<bool>) {
    let reference = nrc_render::render(
        scene,
        &scene.camera,
        &PathTracer::default(),
        &nrc_render::RenderSettings {
            width: w,
            height: h,
            spp,
            seed: 3,
            variance: false,
            sequence: None,
        },
        &|_| {},
    )
    .mean;
    let mask = nrc_render::emitters::emitter_pixels(scene, w, h);
    (reference, mask)
}

/// A long online run (issue 21): `frames` frames of `producer` on `scene` (`records` per
/// frame). Every frame's loss is finite and every record used or counted as dropped; every
/// 25th frame is rendered by the trainer's pass (1 spp, the spread termination) and must be
/// finite and non-negative with no invalid sample; the cache's weights are finite at the end.
/// The cache's error ([`cache_error`] of `renders` renders of `spp` samples) after `early`
/// frames, at every tenth of the run and at the end. (A cache-first render would also measure the cache at
/// delta surfaces, where BT and SPPC train nothing: there its error grew steadily with SPPC on
/// both caustic scenes, by extrapolation, while the loss stayed low.)
fn long_run(
    scene: &Scene,
    producer: &str,
    (frames, early, records): (u32, u32, usize),
    (reference, mask): &(nrc_scene::Image, Vec<bool>),
    (renders, spp): (u32, u32),
) -> LongRun {
    let (w, h) = (reference.width as u32, reference.height as u32);
    // `NRC_LONG_VARIANT`: the preset edited as the drift study's variants ([`edited_preset`]).
    let variant = env_or("NRC_LONG_VARIANT", "base");
    // `NRC_LONG_RESOLUTION`: the hash grid's finest resolution (128 by default).
    let resolution = env_or("NRC_LONG_RESOLUTION", "128")
        .parse()
        .expect("NRC_LONG_RESOLUTION: cells, an integer");
    let mut t = trainer_sized(
        scene,
        producer,
        records,
        edited_preset(&variant),
        resolution,
    );
    let input = FrameInput {
        scene,
        camera: &scene.camera,
        width: w,
        height: h,
        spp,
        seed: 17,
        emitter_samples: 0,
        sequence: None,
    };
    let error = |t: &mut OnlineTrainer| cache_error(t, &input, renders, (reference, mask));
    let mut run = LongRun {
        records: 0,
        dropped_nonfinite: 0,
        dropped_absurd: 0,
        early: f64::NAN,
        end: f64::NAN,
        trajectory: Vec::new(),
        lowest: f64::INFINITY,
        end_rel_mse: f64::NAN,
        ms_per_frame: 0.0,
        loss: f32::NAN,
        changes: 0,
    };
    let start = std::time::Instant::now();
    let mut checking = std::time::Duration::ZERO;
    // Experiment (issue 31): `NRC_LONG_LR_DECAY=T,FLOOR`: the learning rate times
    // max(FLOOR, T / (T + f)) at frame f.
    let lr = t.cache.neural().map(|c| c.learning_rate());
    let decay: Option<(f32, f32)> = std::env::var("NRC_LONG_LR_DECAY").ok().map(|v| {
        let (a, b) = v.split_once(',').expect("T,FLOOR");
        (a.parse().unwrap(), b.parse().unwrap())
    });
    for f in 1..=frames {
        if let (Some((tau, floor)), Some(lr)) = (decay, lr) {
            let scale = (tau / (tau + f as f32)).max(floor);
            t.cache
                .neural_mut()
                .unwrap()
                .set_learning_rate(lr * scale)
                .unwrap();
        }
        let render = f % 25 == 0;
        let (s, out) = t.frame(scene, &scene.camera, w, h, render).unwrap();
        assert!(s.loss.is_finite(), "{producer} frame {f}: loss {}", s.loss);
        assert_eq!(
            s.used + s.dropped_nonfinite + s.dropped_absurd,
            s.records,
            "{producer} frame {f}: every record used or counted"
        );
        run.records += s.records;
        run.dropped_nonfinite += s.dropped_nonfinite;
        run.dropped_absurd += s.dropped_absurd;
        run.loss = s.loss;
        run.changes += usize::from(s.phase == nrc_train::schedule::Phase::Changed);
        if matches!(
            s.phase,
            nrc_train::schedule::Phase::Changed | nrc_train::schedule::Phase::Confirmed
        ) {
            eprintln!(
                "    {producer} frame {f}: {} (score {:.1})",
                s.phase.name(),
                s.change_z
            );
        }
        if let Some(out) = out {
            assert_eq!(out.stats.invalid_samples, 0, "{producer} frame {f}");
            assert!(
                out.image
                    .data
                    .iter()
                    .all(|p| p.is_finite() && p.min_element() >= 0.0),
                "{producer} frame {f}: a non-finite or negative pixel"
            );
        }
        let tenth = f % (frames / 10).max(1) == 0;
        if f == early || f == frames || tenth {
            let c = std::time::Instant::now();
            let (e, rel_mse) = error(&mut t);
            checking += c.elapsed();
            if tenth {
                run.trajectory.push(e);
            }
            if f >= early {
                run.lowest = run.lowest.min(e);
            }
            if f == early {
                run.early = e;
            }
            if f == frames {
                run.end = e;
                run.end_rel_mse = rel_mse;
            }
        }
    }
    run.ms_per_frame = (start.elapsed() - checking).as_secs_f64() * 1e3 / frames as f64;
    let (grid, mlp) = t.cache.neural().expect("the neural cache").weights();
    assert!(
        grid.iter().chain(&mlp).all(|w| w.is_finite()),
        "{producer}: non-finite weight"
    );
    run
}

/// The cache's error as its renders show it ([`render_error`] of the trainer's pass: paths
/// ending in the cache by the spread heuristic and continued through delta surfaces).
fn cache_error(
    t: &mut OnlineTrainer,
    input: &FrameInput,
    renders: u32,
    reference: (&nrc_scene::Image, &[bool]),
) -> (f64, f64) {
    render_error(input, renders, reference, |i| t.render(i).image)
}

/// The error of `renders` renders of `input` by `render`, seeds `input.seed + k` (the same at
/// every checkpoint, so that only the cache differs), emitter pixels set to the reference.
/// Returns the error and the relMSE of the renders' mean. With one render the error is that
/// relMSE; with more it is their relative bias²
/// ([`nrc_eval::BiasVarianceAccumulator::finish_relative`]): the relMSE without the renders'
/// variance, which a darker cache lowers (at 4 spp on `photon-nrc-ajar-caustic` a black cache
/// scores 0.36 and one answered by path tracing 4.7: RESULTS.md, "The drift was the
/// measure's"). The reference's own noise (4,096 spp) stays in it, a floor common to all.
fn render_error(
    input: &FrameInput,
    renders: u32,
    (reference, mask): (&nrc_scene::Image, &[bool]),
    mut render: impl FnMut(&FrameInput) -> nrc_scene::Image,
) -> (f64, f64) {
    let mut acc = nrc_eval::BiasVarianceAccumulator::new(reference.width, reference.height);
    let mut last = None;
    for k in 0..renders {
        let mut image = render(&FrameInput {
            seed: input.seed + u64::from(k),
            ..*input
        });
        assert!(image.data.iter().all(|p| p.is_finite()), "cache render");
        nrc_render::emitters::exclude(&mut image, Some(mask), reference);
        acc.add(&nrc_eval::ImageView::of_scene_image("cache", &image).unwrap())
            .unwrap();
        last = Some(image);
    }
    if renders < 2 {
        let e = rel_mse_excluding(&last.expect("a render"), reference, mask);
        return (e, e);
    }
    let b = acc
        .finish_relative(
            &nrc_eval::ImageView::of_scene_image("reference", reference).unwrap(),
            nrc_eval::metrics::REL_MSE_EPSILON,
        )
        .unwrap();
    (b.bias_sq, b.bias_sq_raw)
}

/// The hard scenes of the long runs: `caustics`, `ajar` and, where `../shared/scenes/` is
/// present, `photon-nrc-ajar-caustic`.
fn hard_scenes() -> Vec<(String, Scene)> {
    let mut out = vec![
        ("caustics".to_string(), scene("caustics.gltf")),
        ("ajar".to_string(), scene("ajar.gltf")),
    ];
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/scenes/photon-nrc-ajar-caustic/ajar_caustic.glb");
    if shared.exists() {
        out.push((
            "photon-nrc-ajar-caustic".to_string(),
            Scene::load(&shared).unwrap(),
        ));
    } else {
        nrc_scene::testing::skipped(
            "online runs on photon-nrc-ajar-caustic",
            &format!("{} is absent", shared.display()),
        );
    }
    out
}

/// Each producer alone and the mix.
const LONG_RUN_PRODUCERS: [&str; 6] = [
    "pt",
    "pt-sl",
    "bt",
    "lt",
    "sppc",
    "mix:pt-sl=0.4,bt=0.2,lt=0.2,sppc=0.2",
];

/// Runs known to drift: SPPC alone on `photon-nrc-ajar-caustic` (its error grew 4.4× from frame
/// 15 to 60 in the short run; not yet understood, see RESULTS.md). They must still exceed the
/// slack (so that a fix is noticed and the entry removed).
const KNOWN_DRIFT: [(&str, &str); 1] = [("photon-nrc-ajar-caustic", "sppc")];

/// Long runs on the hard scenes with every producer; the end error at most `slack` times the
/// lowest of the checkpoints from `early` on (no divergence; a negative bias² estimate
/// loosens, not tightens, the bound), but for [`KNOWN_DRIFT`] when `known` is given. Prints
/// the controls ([`measure_controls`]) of each scene and a table row per run.
fn long_runs(
    (frames, early, records): (u32, u32, usize),
    size: (u32, u32),
    (reference_spp, renders, spp): (u32, u32, u32),
    (slack, known): (f64, bool),
) {
    let measure = if renders > 1 {
        "relative bias²"
    } else {
        "relMSE"
    };
    println!(
        "| scene | producer | frames | records | dropped (non-finite / absurd) | {measure} at frame {early} | at frame {frames} | lowest from frame {early} on | relMSE at frame {frames} | ms per frame | changes called | {measure} at every tenth of the run |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    let mut failures = Vec::new();
    // On demand, `NRC_LONG_SCENES` and `NRC_LONG_PRODUCERS` (`;`-separated) pick runs.
    let picked = |var: &str, name: &str| {
        std::env::var(var).map_or(true, |list| list.split(';').any(|n| n == name))
    };
    for (name, scene) in hard_scenes()
        .into_iter()
        .filter(|(n, _)| picked("NRC_LONG_SCENES", n))
    {
        let reference = reference_of(&scene, size, reference_spp);
        let input = FrameInput {
            width: size.0,
            height: size.1,
            spp,
            seed: 17,
            ..small_frame(&scene)
        };
        let [exact, black] = measure_controls(&input, renders, (&reference.0, &reference.1));
        println!(
            "| {name} | controls, {measure} (relMSE at the end): path-traced answers {:.4} ({:.4}), zero answers {:.4} ({:.4}) | | | | | | | | | | |",
            exact.0, exact.1, black.0, black.1
        );
        for producer in LONG_RUN_PRODUCERS
            .into_iter()
            .filter(|p| picked("NRC_LONG_PRODUCERS", p))
        {
            let r = long_run(
                &scene,
                producer,
                (frames, early, records),
                &reference,
                (renders, spp),
            );
            let trajectory: Vec<String> = r.trajectory.iter().map(|e| format!("{e:.3}")).collect();
            println!(
                "| {name} | {producer} | {frames} | {} | {} / {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.1} | {} | {} |",
                r.records,
                r.dropped_nonfinite,
                r.dropped_absurd,
                r.early,
                r.end,
                r.lowest,
                r.end_rel_mse,
                r.ms_per_frame,
                r.changes,
                trajectory.join(" ")
            );
            assert!(r.loss.is_finite());
            let drifts = known && KNOWN_DRIFT.contains(&(name.as_str(), producer));
            let within = r.end <= r.lowest + (slack - 1.0) * r.lowest.abs();
            if drifts && within {
                failures.push(format!(
                    "{name} {producer} no longer drifts ({:.4} at frame {frames}, lowest {:.4} from frame {early} on): remove it from KNOWN_DRIFT",
                    r.end, r.lowest
                ));
            } else if !drifts && !within {
                failures.push(format!(
                    "{name} {producer}: {measure} {:.4} at frame {frames} against a lowest {:.4} from frame {early} on",
                    r.end, r.lowest
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "diverging runs:\n{}",
        failures.join("\n")
    );
}

/// The long runs shortened for CI: 60 frames of 1024 records; the relMSE of one 4-spp render
/// at the end at most twice the lowest from frame 15 on (at 16 × 16 pixels and 4 spp the
/// render's own noise moves the error by ±15 % between checkpoints; a diverging cache, as the
/// one a firefly target kicked before the loss was bounded, went from 0.31 to 10.3). The long
/// runs' measure and bound (relative bias² of four renders, 1.1 ×) do not fit this length:
/// with four 16-spp renders the caches are still learning at frame 60 (`ajar` with `pt`
/// 0.20 at frame 15, 0.33 at frame 60; measured 2026-12-07).
#[test]
fn short_online_runs_on_the_hard_scenes_stay_finite_and_do_not_diverge() {
    long_runs((60, 15, 1024), (16, 16), (1024, 1, 4), (2.0, true));
}

/// The long runs (issues 21 and 31), on demand: 2000 frames of 4096 records; the cache's
/// relative bias² (four 64-spp renders) at the end at most 1.1 × its lowest from frame 200 on
/// (`cargo test --release --test online -- --ignored long`). For experiments, from the
/// environment: `NRC_LONG_VARIANT` (the preset edited, as the drift study's variants),
/// `NRC_LONG_SCENES` and `NRC_LONG_PRODUCERS` (`;`-separated: the runs to take),
/// `NRC_LONG_RESOLUTION` (the hash grid's finest resolution, 128 by default) and
/// `NRC_LONG_LR_DECAY=T,FLOOR` (the learning rate set by the test at each frame, see
/// [`long_run`]). Changes called and confirmed are printed with their frames and scores.
#[test]
#[ignore]
fn long_online_runs_on_the_hard_scenes_stay_finite_and_do_not_diverge() {
    long_runs((2000, 200, 4096), (32, 32), (4096, 4, 64), (1.1, false));
}

/// relMSE of `image` against `reference` on the emitter-excluded image, as `nrc compare
/// --exclude-emitters` computes it (the masked pixels set to the reference).
fn rel_mse_excluding(image: &nrc_scene::Image, reference: &nrc_scene::Image, mask: &[bool]) -> f64 {
    let mut image = image.clone();
    nrc_render::emitters::exclude(&mut image, Some(mask), reference);
    let view = |name, i| nrc_eval::ImageView::of_scene_image(name, i).unwrap();
    nrc_eval::metrics::rel_mse(
        &view("cache", &image),
        &view("reference", reference),
        nrc_eval::metrics::REL_MSE_EPSILON,
    )
    .unwrap()
}

/// The relMSE of the emitter-excluded cache render (paths ending at their primary hit, so the
/// error is the cache's, not path-tracing noise) after 5 and after 100 online frames on the
/// Cornell box, the cache trained with `config`.
fn errors_after_5_and_100_frames(config: CacheConfig) -> [f64; 2] {
    errors_over_a_run(&scene("cornell-box.gltf"), "pt-sl", config)
}

/// [`errors_after_5_and_100_frames`] with the spatial-hash cache of `hash` settings.
fn hash_errors_after_5_and_100_frames(hash: nrc_cache::HashCacheConfig) -> [f64; 2] {
    let mut s = CacheMethodSettings::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu);
    s.kind = nrc_cache::CacheKind::Hash;
    s.hash = hash;
    errors_with(&scene("cornell-box.gltf"), "pt-sl", s)
}

/// [`errors_after_5_and_100_frames`] on any scene, with any producer.
fn errors_over_a_run(scene: &Scene, producer: &str, config: CacheConfig) -> [f64; 2] {
    errors_with(
        scene,
        producer,
        CacheMethodSettings::new(config, CacheDevice::Cpu),
    )
}

/// [`errors_over_a_run`] with the cache `s` describes (its training sizes set here).
fn errors_with(scene: &Scene, producer: &str, mut s: CacheMethodSettings) -> [f64; 2] {
    let (w, h) = (32, 32);
    let tracer = PathTracer::default();
    let (reference, mask) = reference_of(scene, (w, h), 2048);
    assert!(mask.iter().any(|m| !*m));
    s.records_per_frame = 4096;
    s.batch_size = 4096;
    s.resolution = 128;
    s.seed = 5;
    let first = "cache-first".parse::<PassSpec>().unwrap();
    let mut t = scene_trainer(scene, producer.parse().unwrap(), first, &s, tracer).unwrap();
    let input = FrameInput {
        scene,
        camera: &scene.camera,
        width: w,
        height: h,
        spp: 4,
        seed: 17,
        emitter_samples: 0,
        sequence: None,
    };
    let mut errors = [0.0; 2];
    for f in 1..=100 {
        t.frame(scene, &scene.camera, w, h, false).unwrap();
        if f == 5 || f == 100 {
            errors[(f == 100) as usize] =
                rel_mse_excluding(&t.render(&input).image, &reference, &mask);
        }
    }
    println!(
        "{producer}: relMSE (emitter-excluded) after 5 frames {:.4}, after 100 {:.4}",
        errors[0], errors[1]
    );
    errors
}

/// The preset with a learning rate of 10⁻⁹: a cache that barely learns (negative control).
fn frozen_preset() -> CacheConfig {
    let mut frozen = CacheConfig::hash_grid_preset();
    frozen.optimizer.set_learning_rate(1e-9);
    frozen
}

/// The product's main claim: online training on the Cornell box brings the cache render's
/// error against the reference down: after 100 frames the relMSE of the emitter-excluded image
/// is at most half of that after 5 frames. A regression in a producer, the loss or the
/// optimizer fails this; the negative control, an optimizer that barely moves the weights
/// (learning rate 10^-9), must fail it.
#[test]
fn online_training_brings_the_cache_error_down() {
    let errors = errors_after_5_and_100_frames(CacheConfig::hash_grid_preset());
    assert!(
        errors[1].is_finite() && errors[1] <= 0.5 * errors[0],
        "{errors:?}"
    );
    let errors = errors_after_5_and_100_frames(frozen_preset());
    assert!(
        errors[1] > 0.5 * errors[0],
        "a frozen cache passed: {errors:?}"
    );
}

/// The spatial-hash baseline learns online too: after 100 frames its first-vertex render's
/// relMSE is at most 0.6 of that after 5 (measured: 0.0446 → 0.0239; its running means are
/// already useful after 5 frames, so the neural cache's factor of 2 is not asked). Negative control: a table of 256 cells (records
/// beyond it are dropped as collisions) must fail the same bound.
#[test]
fn online_training_brings_the_hash_cache_error_down() {
    let errors = hash_errors_after_5_and_100_frames(Default::default());
    assert!(
        errors[1].is_finite() && errors[1] <= 0.6 * errors[0],
        "{errors:?}"
    );
    let tiny = nrc_cache::HashCacheConfig {
        log2_capacity: 8,
        ..Default::default()
    };
    let errors = hash_errors_after_5_and_100_frames(tiny);
    assert!(
        errors[1] > 0.6 * errors[0],
        "a hash cache of 256 cells passed: {errors:?}"
    );
}

/// `../shared/scenes/kajiya-roughness-scale` under `scenes/sky.exr` (it has no emitter of its
/// own): every producer's online training brings the cache render's error down over the run
/// (relMSE after 100 frames below 0.95 of that after 5; measured 2026-12-02: pt-sl 0.0055 →
/// 0.0021, bt 0.0050 → 0.0038, lt 0.0092 → 0.0043, sppc 0.0050 → 0.0044). A cache that barely
/// learns (learning rate 10⁻⁹, pt-sl) fails the same bound.
#[test]
fn online_training_on_the_environment_lit_kajiya_scene_brings_the_error_down() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let path = root.join("../shared/scenes/kajiya-roughness-scale/scene.gltf");
    if !path.exists() {
        nrc_scene::testing::skipped(
            "online_training_on_the_environment_lit_kajiya_scene_brings_the_error_down",
            &format!("{} is absent", path.display()),
        );
        return;
    }
    let mut scene = Scene::load(&path).unwrap();
    let (sky, _) = nrc_scene::Environment::load(&root.join("scenes/sky.exr"), 1.0, 0.0).unwrap();
    scene.set_environment(sky);
    let all: Vec<[f64; 2]> = ["pt-sl", "bt", "lt", "sppc"]
        .iter()
        .map(|p| errors_over_a_run(&scene, p, CacheConfig::hash_grid_preset()))
        .collect();
    for (producer, errors) in ["pt-sl", "bt", "lt", "sppc"].iter().zip(&all) {
        assert!(
            errors[1].is_finite() && errors[1] <= 0.95 * errors[0],
            "{producer}: {errors:?}"
        );
    }
    let frozen = errors_over_a_run(&scene, "pt-sl", frozen_preset());
    assert!(
        frozen[1] > 0.95 * frozen[0],
        "a frozen cache passed: {frozen:?}"
    );
}

/// `var` from the environment, else `default`.
fn env_or(var: &str, default: &str) -> String {
    std::env::var(var).unwrap_or_else(|_| default.to_string())
}

/// The hash-grid preset with `edits` applied: `path.to.field=value` pairs, `,`-separated, on
/// its JSON form (`optimizer.nested.nested.learning_rate=2e-3`, `optimizer.decay=0.999`,
/// `encoding.nested.0.log2_hashmap_size=21`); `base` is the preset itself.
fn edited_preset(edits: &str) -> CacheConfig {
    let mut json = serde_json::to_value(CacheConfig::hash_grid_preset()).unwrap();
    for edit in edits.split(',').filter(|e| *e != "base") {
        let (path, value) = edit.split_once('=').expect("an edit is path=value");
        let mut at = &mut json;
        for key in path.split('.') {
            at = match key.parse::<usize>() {
                Ok(i) => &mut at[i],
                Err(_) => &mut at[key],
            };
        }
        // Under `loss` a field the preset leaves out may be added: the loss's sections reject
        // unknown fields themselves.
        assert!(
            !at.is_null() || path.starts_with("loss."),
            "{path} is not a field of the preset"
        );
        *at = serde_json::from_str(value).expect("a JSON value");
    }
    serde_json::from_value(json).expect("a valid configuration")
}

/// Issue 31's drift study, on demand (`scripts/drift-study.sh`): long online runs with one
/// training setting changed at a time. Settings from the environment: `NRC_DRIFT_SCENE` (a
/// shipped scene's file or `photon-nrc-ajar-caustic`), `NRC_DRIFT_PRODUCERS` (`,`-separated),
/// `NRC_DRIFT_VARIANTS` (`;`-separated, each an [`edited_preset`] list), `NRC_DRIFT_FRAMES`,
/// `NRC_DRIFT_RECORDS`, `NRC_DRIFT_RESOLUTION`, `NRC_DRIFT_SPP` (the renders' samples, 256).
/// It prints [`measure_controls`] (one render of the samples, and four of a quarter each), and
/// at every tenth of a run it measures (32 × 32, emitter pixels excluded, seed 17):
/// - the relMSE of the render with paths ending at the first vertex (where the camera's
///   records land) and with the spread heuristic (where later vertices query the cache), and
///   the spread render's MSE (luminance);
/// - the spread renders' relative bias² ([`cache_error`]: four renders of a quarter of the
///   samples each, seeds 17 to 20);
/// - the cache's own answers at every query of the spread render at 4 spp against 1,024-spp
///   path-traced answers at the same points: relMSE, mean ratio, MSE, and the part of the
///   MSE from the 1 % of queries whose path-traced answer is brightest.
///
/// Prints a Markdown row per run and indented lines with the rest.
#[test]
#[ignore]
fn drift_study() {
    let name = env_or("NRC_DRIFT_SCENE", "photon-nrc-ajar-caustic");
    let scene = match hard_scenes().into_iter().find(|(n, _)| *n == name) {
        Some((_, s)) => s,
        None => scene(&name),
    };
    let frames: u32 = env_or("NRC_DRIFT_FRAMES", "2000").parse().unwrap();
    let records: usize = env_or("NRC_DRIFT_RECORDS", "4096").parse().unwrap();
    let resolution: u32 = env_or("NRC_DRIFT_RESOLUTION", "128").parse().unwrap();
    let (reference, mask) = reference_of(&scene, (32, 32), 4096);
    let input = FrameInput {
        scene: &scene,
        camera: &scene.camera,
        width: 32,
        height: 32,
        spp: env_or("NRC_DRIFT_SPP", "256").parse().unwrap(),
        seed: 17,
        emitter_samples: 0,
        sequence: None,
    };
    let lum = |p: &glam::Vec3| nrc_scene::sampling::luminance(*p) as f64;
    let first = PassSpec::from(nrc_render::passes::CacheTerminatedSettings {
        termination: nrc_render::Termination::FirstVertex,
        nee: true,
    });
    let spread = PassSpec::default();
    // The spread render's queries (they depend on the geometry alone) and their answers.
    let queries = queries_of(&spread, &FrameInput { spp: 4, ..input });
    let exact = nrc_render::source::PathTracedSource {
        scene: &scene,
        tracer: PathTracer::default(),
        samples: 1024,
        seed: 5,
    };
    let truth = nrc_render::RadianceSource::radiance(&exact, &queries);
    let quarter = FrameInput {
        spp: (input.spp / 4).max(1),
        ..input
    };
    let [exact_one, black_one] = measure_controls(&input, 1, (&reference, &mask));
    let [exact_four, black_four] = measure_controls(&quarter, 4, (&reference, &mask));
    println!(
        "  the spread render's controls, answers by 64-spp path tracing / zero: relMSE of one render {:.3} / {:.3}; relative bias² of four {:.3} / {:.3}",
        exact_one.0, black_one.0, exact_four.0, black_four.0
    );
    let mut brightest: Vec<usize> = (0..queries.len()).collect();
    brightest.sort_by(|&i, &j| lum(&truth[j]).total_cmp(&lum(&truth[i])));
    brightest.truncate(queries.len().div_ceil(100));
    let n = queries.len() as f64;
    let masked = |image: &nrc_scene::Image| {
        image
            .data
            .iter()
            .zip(&reference.data)
            .zip(&mask)
            .filter(|(_, m)| !**m)
            .map(|((a, b), _)| (lum(a), lum(b)))
            .collect::<Vec<_>>()
    };
    println!(
        "| scene | producer | variant | relMSE first-vertex / spread at every tenth of the run | spread: end / min from the tenth on |\n|---|---|---|---|---|"
    );
    for producer in env_or("NRC_DRIFT_PRODUCERS", "pt").split(',') {
        for variant in env_or("NRC_DRIFT_VARIANTS", "base").split(';') {
            let mut s = CacheMethodSettings::new(edited_preset(variant), CacheDevice::Cpu);
            s.records_per_frame = records;
            s.batch_size = records / 2;
            s.resolution = resolution;
            s.seed = 11;
            let spec = producer.parse::<ProducerSpec>().unwrap();
            let mut t =
                scene_trainer(&scene, spec, spread.clone(), &s, PathTracer::default()).unwrap();
            let (mut row, mut spread_rel, mut mse, mut answers) = (vec![], vec![], vec![], vec![]);
            let mut biases = vec![];
            let mut last = Vec::new();
            for f in 1..=frames {
                t.frame(&scene, &scene.camera, 32, 32, false).unwrap();
                if f % (frames / 10).max(1) != 0 {
                    continue;
                }
                let image = nrc_render::passes::run(
                    first.build(&PathTracer::default()).as_mut(),
                    &input,
                    &CacheSource::new(&t.cache),
                )
                .image;
                let e_first = rel_mse_excluding(&image, &reference, &mask);
                let image = t.render(&input).image;
                let e_spread = rel_mse_excluding(&image, &reference, &mask);
                last = masked(&image);
                let m = last.iter().map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 1024.0;
                let (bias, _) = cache_error(&mut t, &quarter, 4, (&reference, &mask));
                row.push(format!("{e_first:.3}/{e_spread:.3}"));
                spread_rel.push(e_spread);
                biases.push(format!("{bias:.3}"));
                mse.push(format!("{m:.3}"));
                let a = nrc_render::RadianceSource::radiance(&CacheSource::new(&t.cache), &queries);
                let sq = |i: usize| (lum(&a[i]) - lum(&truth[i])).powi(2);
                let rel = (0..a.len())
                    .map(|i| sq(i) / (lum(&truth[i]).powi(2) + 0.01))
                    .sum::<f64>()
                    / n;
                let ratio = a.iter().map(lum).sum::<f64>() / truth.iter().map(lum).sum::<f64>();
                let all = (0..a.len()).map(sq).sum::<f64>() / n;
                let top = brightest.iter().map(|&i| sq(i)).sum::<f64>() / n;
                answers.push(format!("{rel:.2}/{ratio:.2}/{all:.2}/{top:.2}"));
            }
            let min = spread_rel.iter().cloned().fold(f64::INFINITY, f64::min);
            println!(
                "| {name} | {producer} | {variant} | {} | {:.2} |",
                row.join(" "),
                spread_rel.last().unwrap() / min
            );
            println!("  spread render MSE: {}", mse.join(" "));
            println!(
                "  spread renders' relative bias² (four of a quarter of the samples each): {}",
                biases.join(" ")
            );
            println!(
                "  the cache at the spread render's {} queries (relMSE/mean ratio/MSE/MSE of the brightest 1 %): {}",
                queries.len(),
                answers.join(" ")
            );
            // Where the last spread render's error is: its mean against the reference's, and
            // the share of its squared relative error in the worst 1 % of pixels.
            let mut rel: Vec<f64> = last
                .iter()
                .map(|(a, b)| (a - b).powi(2) / (b * b + 0.01))
                .collect();
            rel.sort_by(|a, b| b.total_cmp(a));
            let worst =
                rel[..rel.len().div_ceil(100)].iter().sum::<f64>() / rel.iter().sum::<f64>();
            let mean =
                last.iter().map(|p| p.0).sum::<f64>() / last.iter().map(|p| p.1).sum::<f64>();
            println!(
                "  at the end: spread render mean {mean:.3} x the reference's; the worst 1 % of pixels hold {:.0} % of its squared relative error",
                100.0 * worst
            );
        }
    }
}

/// The cache measure's controls: [`render_error`] of the spread render with its queries
/// answered by 64-spp path tracing (an unbiased stand-in for a perfect cache) and by zero (a
/// black cache), in the measure the cache gets (`renders` renders of `input`). A measure that
/// a black cache beats, as one 4-spp render's relMSE on `photon-nrc-ajar-caustic` (0.36
/// black, 4.7 path-traced), rewards a cache for its darkness, not for its accuracy.
fn measure_controls(
    input: &FrameInput,
    renders: u32,
    reference: (&nrc_scene::Image, &[bool]),
) -> [(f64, f64); 2] {
    let exact = nrc_render::source::PathTracedSource {
        scene: input.scene,
        tracer: PathTracer::default(),
        samples: 64,
        seed: 6,
    };
    [
        &exact as &dyn nrc_render::RadianceSource,
        &nrc_render::ZeroSource,
    ]
    .map(|source| {
        render_error(input, renders, reference, |i| {
            nrc_render::passes::run(
                PassSpec::default().build(&PathTracer::default()).as_mut(),
                i,
                source,
            )
            .image
        })
    })
}

/// The radiance queries a frame of pass `spec` makes (they depend on the geometry alone).
fn queries_of(spec: &PassSpec, input: &FrameInput) -> Vec<nrc_render::RadianceQuery> {
    let rec = Recording {
        inner: &nrc_render::ZeroSource,
        log: Default::default(),
    };
    nrc_render::passes::run(spec.build(&PathTracer::default()).as_mut(), input, &rec);
    let log = rec.log.into_inner().unwrap();
    log.into_iter().map(|(q, _)| q).collect()
}

/// A source that remembers every query and its answer.
struct Recording<'a> {
    inner: &'a dyn nrc_render::RadianceSource,
    log: std::sync::Mutex<Vec<(nrc_render::RadianceQuery, glam::Vec3)>>,
}

impl nrc_render::RadianceSource for Recording<'_> {
    fn radiance(&self, queries: &[nrc_render::RadianceQuery]) -> Vec<glam::Vec3> {
        let a = self.inner.radiance(queries);
        self.log
            .lock()
            .unwrap()
            .extend(queries.iter().copied().zip(a.iter().copied()));
        a
    }
}

/// A 32 × 32 frame of `scene` from its camera, one sample a pixel, seed 3.
fn small_frame(scene: &Scene) -> FrameInput<'_> {
    FrameInput {
        scene,
        camera: &scene.camera,
        width: 32,
        height: 32,
        spp: 1,
        seed: 3,
        emitter_samples: 0,
        sequence: None,
    }
}

/// The hash cache's relative error against path-traced radiance at the Cornell box's primary
/// hits (32 × 32), after 16 frames of records whose targets are 64-spp path-traced estimates
/// at those points (an unbiased, nearly exact source), for a finest cell of `cell` of the box.
fn hash_cache_error_against_exact(cell: f32) -> f64 {
    let scene = scene("cornell-box.gltf");
    let input = small_frame(&scene);
    let queries = queries_of(&"cache-first".parse().unwrap(), &input);
    let maker = nrc_train::QueryMaker::new(&scene.bounds());
    let config = nrc_cache::HashCacheConfig {
        cell,
        levels: 1,
        ..Default::default()
    };
    let mut cache = nrc_cache::HashCache::new(config, maker.scene_box).unwrap();
    cache.set_camera(scene.camera.position.to_array());
    let exact = |samples, seed| nrc_render::source::PathTracedSource {
        scene: &scene,
        tracer: PathTracer::default(),
        samples,
        seed,
    };
    let records: Vec<_> = queries.iter().map(|q| maker.cache_query(q)).collect();
    for frame in 0..16 {
        let targets = nrc_render::RadianceSource::radiance(&exact(64, 100 + frame), &queries);
        let batch = nrc_cache::TrainingBatch {
            queries: records.clone(),
            targets: targets.iter().map(|t| t.to_array()).collect(),
            weights: None,
        };
        cache.train(&batch).unwrap();
    }
    let truth = nrc_render::RadianceSource::radiance(&exact(1024, 7), &queries);
    let answers = cache.infer(&records);
    let lum = |c: [f32; 3]| nrc_scene::sampling::luminance(glam::Vec3::from(c)) as f64;
    let error = answers
        .iter()
        .zip(&truth)
        .map(|(a, b)| (lum(*a) - lum(b.to_array())).abs() / (lum(b.to_array()) + 0.01))
        .sum::<f64>()
        / queries.len() as f64;
    println!(
        "hash cache, cell {cell}: mean relative error {error:.4} against 1,024-spp path tracing"
    );
    error
}

/// Each pass that reads a cache, on the Cornell box (32 × 32, one frame), with its queries
/// answered by the hash cache, against the same frame answered by 256-spp path-traced answers
/// at those queries (nearly exact): the same paths (same seed), so the images differ only by
/// the cache's answers. The cache learned the field elsewhere: from 64-spp path-traced answers
/// at the queries of eight other frames of the pass (other seeds: other sub-pixel positions,
/// candidates and VPLs). The relative L1 difference of the two images' luminance stays below
/// `BOUND` with the cache's default settings (finest cells 1/128 of the box, levels of detail
/// by distance to the camera, falling back to coarser cells where a fine one is empty) for
/// every pass (measured: paths ending at the first vertex 0.049, by the spread 0.031, ReSTIR GI
/// 0.041 and 0.042 world-space, DDGI resampling 0.045, DDGI fed by the cache 0.006, SMC-IR
/// 0.016; the cache's answers carry the 64-spp teaching noise of their cells). Negative
/// control: one level of cells of 1/4 of the box (a wrong level of detail) must fail it where
/// the cache's answers make the pixels (paths ending at the first vertex: 0.076). Where the
/// cache answers only past the first bounce, the coarse cells are not worse here (0.007–0.033).
#[test]
fn every_pass_reading_the_hash_cache_renders_as_with_the_field_it_was_fed() {
    const BOUND: f64 = 0.06;
    let scene = scene("cornell-box.gltf");
    let maker = nrc_train::QueryMaker::new(&scene.bounds());
    let input = small_frame(&scene);
    let lum = |v: glam::Vec3| f64::from(nrc_scene::sampling::luminance(v));
    let field = |samples, seed| nrc_render::source::PathTracedSource {
        scene: &scene,
        tracer: PathTracer::default(),
        samples,
        seed,
    };
    let passes = [
        "cache-first",
        "cache",
        "restir-gi-nrc",
        "wsrestir-gi-nrc",
        "nrc-restir",
        "ddgi-nrc-restir:probes=4,rays=64",
        "smc-ir-nrc",
    ];
    for name in passes {
        let spec: PassSpec = name.parse().unwrap();
        let queries = queries_of(&spec, &input);
        let answers = nrc_render::RadianceSource::radiance(&field(256, 11), &queries);
        let fed = Replay {
            answers: queries.iter().copied().zip(answers).collect(),
        };
        // What the cache learns from: other frames' queries and their answers.
        let (mut taught, mut told) = (Vec::new(), Vec::new());
        for k in 0..8 {
            let other = FrameInput {
                seed: 100 + k,
                ..input
            };
            let q = queries_of(&spec, &other);
            told.extend(nrc_render::RadianceSource::radiance(
                &field(64, 200 + k),
                &q,
            ));
            taught.extend(q);
        }
        let frame = |source: &dyn nrc_render::RadianceSource| {
            nrc_render::passes::run(spec.build(&PathTracer::default()).as_mut(), &input, source)
                .image
        };
        let exact = frame(&fed);
        let difference = |config: nrc_cache::HashCacheConfig| {
            let cache = nrc_cache::Cache::from(fed_hash_cache(&scene, &taught, &told, config));
            let image = frame(&CacheSource {
                cache: &cache,
                queries: maker,
            });
            let (num, den) = image
                .data
                .iter()
                .zip(&exact.data)
                .fold((0.0, 0.0), |(n, d), (a, b)| {
                    (n + (lum(*a) - lum(*b)).abs(), d + lum(*b))
                });
            num / den.max(1e-12)
        };
        let fine = difference(nrc_cache::HashCacheConfig::default());
        let coarse = difference(nrc_cache::HashCacheConfig {
            cell: 0.25,
            levels: 1,
            ..Default::default()
        });
        println!(
            "{name}: {} queries, {} taught; relative L1 difference {fine:.4} (default cells), {coarse:.4} (one level of 1/4)",
            queries.len(),
            taught.len()
        );
        assert!(fine < BOUND, "{name}: {fine}");
        if name == "cache-first" {
            assert!(
                coarse >= BOUND,
                "{name}: a wrong level of detail passed ({coarse})"
            );
        }
    }
}

/// Answers recorded for a frame's queries, given back in order (the frame asks the same
/// queries again: they depend on the geometry alone).
struct Replay {
    answers: Vec<(nrc_render::RadianceQuery, glam::Vec3)>,
}

impl nrc_render::RadianceSource for Replay {
    fn radiance(&self, queries: &[nrc_render::RadianceQuery]) -> Vec<glam::Vec3> {
        assert_eq!(queries.len(), self.answers.len(), "another frame's queries");
        self.answers.iter().map(|(_, a)| *a).collect()
    }
}

/// A hash cache of `config` fed `answers` at `queries` 16 times (its running means settle on
/// the mean of the answers in each cell).
fn fed_hash_cache(
    scene: &Scene,
    queries: &[nrc_render::RadianceQuery],
    answers: &[glam::Vec3],
    config: nrc_cache::HashCacheConfig,
) -> nrc_cache::HashCache {
    let maker = nrc_train::QueryMaker::new(&scene.bounds());
    let mut cache = nrc_cache::HashCache::new(config, maker.scene_box).unwrap();
    cache.set_camera(scene.camera.position.to_array());
    let batch = nrc_cache::TrainingBatch {
        queries: queries.iter().map(|q| maker.cache_query(q)).collect(),
        targets: answers.iter().map(|t| t.to_array()).collect(),
        weights: None,
    };
    for _ in 0..16 {
        cache.train(&batch).unwrap();
    }
    cache
}

/// The hash cache converges to the radiance field it is fed: on the Cornell box, trained from
/// nearly exact targets, its mean relative error at the trained points is below 0.1 with cells
/// of 1/128 of the box (measured 0.029: the field's variation within a cell and the targets'
/// own noise). Negative control: cells of 1/4 of the box (a wrong level of detail) average the
/// walls' light and dark parts and must fail the same bound (measured 0.159).
#[test]
fn the_hash_cache_converges_to_the_field_it_is_fed() {
    let fine = hash_cache_error_against_exact(1.0 / 128.0);
    assert!(fine < 0.1, "mean relative error {fine}");
    let coarse = hash_cache_error_against_exact(0.25);
    assert!(coarse >= 0.1, "cells of 1/4 of the box passed: {coarse}");
}
