//! `nrc train`: the online loop on a scene. Per frame: query prediction, the producers, the
//! training steps and the cache-terminated inference pass; per-frame statistics, optional
//! EXR frames, a snapshot at the end.

use std::path::PathBuf;

use anyhow::{Context, Result, bail, ensure};
use nrc_render::PassSpec;
use nrc_render::Termination;
use nrc_render::passes::CacheTerminatedSettings;
use nrc_scene::Scene;
use nrc_train::{OnlineTrainer, ProducerSpec};

use nrc_harness::options::{RadianceCacheArgs, SceneArgs, TracerArgs, parse_termination};
use nrc_harness::progress::{Progress, Unit};

/// Arguments of `nrc train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Read the run's settings from this JSON file: its fields are these flags (`snake_case`
    /// or `kebab-case`), and flags given on the command line override it.
    #[arg(long, value_name = "FILE")]
    pub run: Option<PathBuf>,

    #[command(flatten)]
    pub scene: SceneArgs,

    #[command(flatten)]
    pub emitters: nrc_harness::options::EmitterArgs,

    /// Training-data producer: pt, pt-sl, bt, lt, sppc, or mix:NAME=SHARE,... (e.g.
    /// mix:pt-sl=0.5,sppc=0.5).
    #[arg(long, default_value = "pt-sl")]
    pub producer: ProducerSpec,

    /// Frames to run.
    #[arg(long, default_value_t = 64)]
    pub frames: u32,

    /// Frames per second of scene time on an animated scene (glTF node animation: the scene
    /// is posed at `frame / fps` seconds each frame, and the cache trains while it moves).
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,

    /// Camera path: a JSON list of keyframes `{"position": [x,y,z], "target": [x,y,z],
    /// "up": [x,y,z] (optional), "fov_y": degrees (optional)}`, spread evenly over the frames
    /// and interpolated linearly. Default: the scene's camera, still.
    #[arg(long)]
    pub camera_path: Option<PathBuf>,

    /// Write the cache here at the end (safetensors + JSON metadata; see nrc-cache's snapshot
    /// module).
    #[arg(long)]
    pub snapshot: Option<PathBuf>,

    /// Write inference frames as EXR into this folder (frame-NNNNN.exr).
    #[arg(long)]
    pub frames_out: Option<PathBuf>,

    /// With --frames-out: write every N-th frame (and the last).
    #[arg(long, default_value_t = 1)]
    pub every: u32,

    /// Per-frame statistics (time of each phase, loss, records used and dropped): `.csv` or
    /// `.json`.
    #[arg(long)]
    pub stats: Option<PathBuf>,

    /// Image width of the inference pass (and of query prediction).
    #[arg(long, default_value_t = 256)]
    pub width: u32,

    /// Image height.
    #[arg(long, default_value_t = 256)]
    pub height: u32,

    /// Samples per pixel of the inference pass.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,

    /// Where rendering paths end in the cache: first, diffuse[:R], spread[:C], bth[:K].
    #[arg(long, default_value = "spread", value_parser = parse_termination)]
    pub termination: Termination,

    /// Next-event estimation off in the inference pass (BSDF sampling only).
    #[arg(long)]
    pub no_nee: bool,

    /// The inference pass, instead of --termination/--no-nee (default: cache, paths ending in
    /// the cache by the spread heuristic); `--help` lists every pass and its parameters.
    #[arg(long, conflicts_with_all = ["termination", "no_nee"], long_help = nrc_render::passes::help())]
    pub pass: Option<PassSpec>,

    /// Fraction of training queries aimed at the previous frame's termination points.
    #[arg(long, default_value_t = 0.0)]
    pub from_terminations: f32,

    /// The cache trained: `neural` (the network) or `hash` (the spatial-hash baseline, no
    /// network); `nrc render --cache` reads either kind's snapshot.
    #[arg(long, default_value = "neural")]
    pub cache_kind: nrc_cache::CacheKind,

    #[command(flatten)]
    pub cache: RadianceCacheArgs,

    /// Seed: a seed gives the same run whatever the thread count (on the CPU device).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,

    #[command(flatten)]
    pub tracer: TracerArgs,
}

/// The online trainer `args` describe, on `scene` (loaded from `args.scene`); `print`: say
/// which device the cache computes on.
pub fn trainer(args: &TrainArgs, scene: &Scene, print: bool) -> Result<OnlineTrainer> {
    check(args)?;
    let pass = args.pass.clone().unwrap_or_else(|| {
        CacheTerminatedSettings {
            termination: args.termination,
            nee: !args.no_nee,
        }
        .into()
    });
    nrc_harness::run::check_frame_memory(
        &pass,
        args.width,
        args.height,
        args.spp,
        nrc_harness::run::available_memory(),
    )?;
    let settings = cache_settings(args, scene, print)?;
    let tracer = args.tracer.tracer();
    let mut trainer =
        nrc_harness::methods::scene_trainer(scene, args.producer.clone(), pass, &settings, tracer)
            .map_err(anyhow::Error::msg)?;
    trainer.settings.spp = args.spp;
    trainer.settings.emitter_samples = args.emitters.emitter_samples;
    trainer.settings.from_terminations = args.from_terminations;
    Ok(trainer)
}

/// The cache's settings `args` describe for `scene` (the model sized from the camera where
/// asked); `print`: say how the size was chosen.
pub fn cache_settings(
    args: &TrainArgs,
    scene: &Scene,
    print: bool,
) -> Result<nrc_harness::methods::CacheMethodSettings> {
    let mut settings = args.cache.method_settings(0, args.seed, print)?;
    settings.kind = args.cache_kind;
    if let Some(why) = settings.resolve_resolution(scene, args.width, args.height)?
        && print
    {
        eprintln!("{why}");
    }
    Ok(settings)
}

/// Checks the settings that need no scene.
pub(crate) fn check(args: &TrainArgs) -> Result<()> {
    if args.width == 0 || args.height == 0 {
        bail!("image size {}x{} is empty", args.width, args.height);
    }
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if args.every == 0 {
        bail!("--every must be at least 1");
    }
    if args.spp == 0 {
        bail!("--spp must be at least 1");
    }
    if !(0.0..=1.0).contains(&args.from_terminations) {
        bail!(
            "--from-terminations must be in [0, 1], got {}",
            args.from_terminations
        );
    }
    ensure!(
        args.fps.is_finite() && args.fps > 0.0,
        "--fps must be positive, got {}",
        args.fps
    );
    Ok(())
}

/// Runs `nrc train`.
pub fn run(args: &TrainArgs) -> Result<()> {
    check(args)?;
    let scene: Scene = args.scene.load()?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    let cameras =
        nrc_harness::run::camera_path(args.camera_path.as_deref(), &scene.camera, args.frames)?;
    if let Some(dir) = &args.frames_out {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    // Output folders exist before the run, not only at its end.
    for file in args.snapshot.iter().chain(&args.stats) {
        if let Some(parent) = file.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("cannot create {}", parent.display()))?;
        }
    }
    let mut trainer = trainer(args, &scene, true)?;
    eprintln!("{}", trainer.cache.describe());
    eprintln!("{}", trainer.settings.describe_control());
    let pool = nrc_harness::options::thread_pool(args.threads)?;
    let progress = Progress::new(args.frames as u64, Unit::Frames, "train");
    let frames = args
        .frames_out
        .clone()
        .map(|dir| nrc_harness::run::FrameOutput {
            dir,
            every: args.every,
        });
    let animated = args.scene.load_animated()?;
    let pose = |t: f32| args.scene.pose(&animated, t);
    let scenes = if animated.is_animated() {
        eprintln!(
            "the scene is animated ({:.2} s): posed at frame / {} s each frame",
            animated.animation.duration(),
            args.fps
        );
        nrc_harness::run::Frames::Animated {
            pose: &pose,
            fps: args.fps,
        }
    } else {
        nrc_harness::run::Frames::Static(&scene)
    };
    let all = pool.install(|| {
        nrc_harness::run::train(
            &mut trainer,
            &scenes,
            &cameras,
            (args.width, args.height),
            frames.as_ref(),
            &|stats| {
                progress.set_message(format!(
                    "loss {:.4}, {:.0} ms/frame",
                    stats.loss,
                    stats.produce_ms + stats.train_ms + stats.infer_ms
                ));
                progress.inc(1);
            },
        )
    })?;
    progress.finish();
    if let Some(path) = &args.stats {
        nrc_harness::run::write_stats(path, &all)?;
    }
    if let Some(path) = &args.snapshot {
        // The snapshot names its scene, so that rendering another one with it is refused.
        trainer
            .cache
            .set_scene_content(Some(nrc_harness::reference::scene_content_hash(
                &args.scene.scene,
            )?));
        trainer.cache.save(path)?;
    }
    let sum = nrc_harness::run::TrainSummary::of(&all);
    println!(
        "trained {} frames of {} ({} records/frame): produce {:.1} ms, train {:.1} ms, infer {:.1} ms per frame; final loss {:.5}; {} records dropped, {} non-finite light-path contributions skipped",
        all.len(),
        args.producer,
        args.cache.records,
        sum.produce_ms,
        sum.train_ms,
        sum.infer_ms,
        sum.loss,
        sum.dropped,
        sum.skipped
    );
    if let Some(ms) = args.cache.train_budget_ms {
        println!(
            "training budget {ms} ms/frame: {:.0} records/frame on average; {} of {} frames after the warm-up over 1.2 × their plan",
            sum.records, sum.over_budget, sum.budgeted_frames
        );
        if sum.over_at_minimum > 0 {
            eprintln!(
                "warning: {} frames were over their plan with the fewest records a budget allows ({}): producing and training that few records costs more than the budget; raise --train-budget-ms",
                sum.over_at_minimum,
                nrc_train::schedule::MIN_BUDGET_RECORDS
            );
        }
    }
    if sum.changes > 0 {
        println!(
            "{} change(s) in the scene detected, {} confirmed (the learning rate's decay restarted); {} frames recovering",
            sum.changes, sum.confirmed, sum.recovering_frames
        );
    }
    Ok(())
}
