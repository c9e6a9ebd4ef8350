//! `nrc compare`: every method of a list against one reference, at equal samples or equal time.
//! The arguments become a [`nrc_harness::compare::Comparison`]; the loop, the files it writes
//! and the `runs.json` schema are in `nrc_harness::compare`.

use std::path::PathBuf;

use anyhow::{Context, Result, ensure};
use nrc_harness::budget::Budget;
use nrc_harness::compare::{Comparison, Progress as Step, compare, total_frames};
use nrc_harness::progress::{Progress, Unit};
use nrc_harness::reference::{self, ReferenceRequest};
use nrc_harness::{MethodList, MethodSpec};
use nrc_scene::Scene;

use nrc_harness::options::CacheArgs;
use nrc_harness::options::DepthArgs;
use nrc_harness::options::SceneArgs;

/// Arguments of `nrc compare`.
#[derive(clap::Args, Debug)]
#[command(group = clap::ArgGroup::new("budget").required(true).args(["equal_time", "equal_spp"]))]
pub struct CompareArgs {
    /// Read the run's settings from this JSON file: its fields are these flags (`snake_case`
    /// or `kebab-case`), and flags given on the command line override it.
    #[arg(long, value_name = "FILE")]
    pub run: Option<PathBuf>,

    #[command(flatten)]
    pub scene: SceneArgs,

    /// Methods to compare, comma-separated: pt-<N>spp (path tracer, N samples per pixel per
    /// pass, NEE and BSDF sampling by MIS), pt-<N>spp-nonee (BSDF sampling only), or
    /// nrc-<producer>[-<termination>] (a cache trained online by pt, pt-sl, bt, lt or sppc,
    /// rendered at 1 spp with paths ending in it: first, diffuse, spread (default), bth).
    /// A `key=value` item continues the previous method's parameters
    /// (`ddgi-restir:rays=64,k=0,restir-di` is two methods).
    #[arg(long, required = true)]
    pub methods: Vec<MethodList>,

    /// The cache the cache methods train: `neural` (the network), or `hash` (the spatial-hash
    /// baseline, as `nrc train --cache-kind hash`: `nrc-pt-sl` runs as `hash-pt-sl`,
    /// `restir-gi-nrc` as `restir-gi-nrc@1spp+hash:pt-sl`). Methods named for the hash cache
    /// keep it either way.
    #[arg(long, default_value = "neural")]
    pub cache_kind: nrc_cache::CacheKind,

    /// Equal time: each frame renders passes of its method until this many milliseconds are
    /// used (the frame ends within one pass of the budget, typically half a pass).
    #[arg(long)]
    pub equal_time: Option<f64>,

    /// Equal samples: each frame is N passes of its method (pt-4spp at N = 2 holds 8 spp).
    #[arg(long)]
    pub equal_spp: Option<u32>,

    /// Image width in pixels.
    #[arg(long, default_value_t = 320)]
    pub width: u32,

    /// Image height in pixels.
    #[arg(long, default_value_t = 240)]
    pub height: u32,

    /// Independent frames (distinct seeds) per method; errors are averaged over them, and
    /// R ≥ 2 gives bias² and variance.
    #[arg(long, default_value_t = 1)]
    pub runs: u32,

    /// Samples per pixel of the reference (rendered once, then taken from the cache).
    #[arg(long, default_value_t = 1024)]
    pub reference_spp: u32,

    /// Use this reference instead: a cache folder written by `nrc reference`, or an EXR file
    /// (then without variance, so bias² is not corrected for the reference's noise).
    #[arg(long, conflicts_with = "reference_spp")]
    pub reference: Option<PathBuf>,

    /// Also run each method at doubling budgets (the budget × 1, 2, 4, …) and plot error
    /// against time, with the time each method needs to reach the first method's error.
    #[arg(long)]
    pub sweep: bool,

    /// Budgets of the sweep.
    #[arg(long, default_value_t = 5)]
    pub sweep_steps: u32,

    /// Frames to equal error (the DDGI-resampling paper's Table 1): after its runs, each method
    /// renders up to this many consecutive frames from one state (after the untimed warm-up),
    /// averaged progressively; the report gives the frames and milliseconds each needs for its
    /// mean to reach the MAPE of `--converge-target`'s first frame, and `frames-to-error.png`
    /// plots the curves. List the target first: the methods after it stop at twice the frames
    /// they needed.
    #[arg(long, value_name = "FRAMES")]
    pub converge: Option<u32>,

    /// The method whose first frame sets the error of `--converge` (default: the first).
    #[arg(long, value_name = "METHOD", requires = "converge")]
    pub converge_target: Option<MethodSpec>,

    /// An animated sequence instead of one frame: every method renders these many frames of
    /// the scene posed at `frame / fps` seconds (glTF node animation), its state carried over,
    /// each against its own reference (path traced at --reference-spp); writes `sequence.md`,
    /// `sequence.json` and `sequence-mape.png` with |E| and |E′| of Hedman et al. §5.2.
    #[arg(long, value_name = "FRAMES", conflicts_with_all = ["converge", "sweep", "reference", "interleave"])]
    pub sequence: Option<u32>,

    /// Frames per second of scene time in a --sequence.
    #[arg(long, default_value_t = 30.0, requires = "sequence")]
    pub fps: f32,

    /// Camera path of a --sequence (JSON keyframes, as for `nrc train --camera-path`); default:
    /// the scene's camera at each frame's time.
    #[arg(long, requires = "sequence")]
    pub camera_path: Option<PathBuf>,

    /// Pixels tracked by the temporal measures of a --sequence, on a regular grid (0: all).
    #[arg(long, default_value_t = 1024, requires = "sequence")]
    pub tracked: usize,

    /// Skip HDR-FLIP (the costliest metric).
    #[arg(long)]
    pub no_flip: bool,

    /// Output folder.
    #[arg(long, default_value = "out/compare")]
    pub out: PathBuf,

    /// Base seed of the methods' frames (each method and run gets its own streams from it).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Exposure of the PNG previews, in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,

    #[command(flatten)]
    pub depth: DepthArgs,

    #[command(flatten)]
    pub cache: CacheArgs,

    /// Exclude from the errors the pixels that see an emitter, and their 8 neighbours (their
    /// error is set to zero): at low sample counts the emitters' anti-aliasing can dominate
    /// the MSE of every method alike.
    #[arg(long)]
    pub exclude_emitters: bool,

    /// Also write, per method, each pixel's MSE, bias² and variance over the runs
    /// (METHOD-errors.exr) and its pass's state after its last frame (METHOD-view-NAME.exr:
    /// reservoir statistics, probes); needs --runs 2 or more.
    #[arg(long)]
    pub diagnostics: bool,

    /// Render the runs interleaved across methods: for each run, every method restarted (its
    /// untimed warm-up), then their timed frames back to back, in alternating order, so that a
    /// slow moment of a shared machine falls on every method of a run alike instead of on one
    /// method's runs. Each frame keeps its seeds and state (at --equal-spp the same frames as
    /// without); every method's state is held at once (memory).
    #[arg(long)]
    pub interleave: bool,

    #[command(flatten)]
    pub emitters: nrc_harness::options::EmitterArgs,

    #[command(flatten)]
    pub offsets: nrc_harness::options::OffsetArgs,

    /// Cache methods: frames of online training before measurement (untimed).
    #[arg(long, default_value_t = 64)]
    pub train_frames: u32,

    /// Cache methods: stop training once measurement starts (else every pass is a full online
    /// frame: produce, train and render, all timed).
    #[arg(long)]
    pub frozen: bool,

    #[command(flatten)]
    pub model: nrc_harness::options::RadianceCacheArgs,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,

    /// Write the comparison as a plan of independent jobs into this folder instead of running
    /// it: reference chunks and one job per method and run, run by `nrc job DIR K` (or the Ray
    /// driver, or a Slurm array: `scripts/ray_study.py`, `scripts/slurm_study.sh`), then
    /// assembled by `nrc compare --merge DIR`.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["sweep", "converge", "sequence", "interleave"])]
    pub plan: Option<PathBuf>,

    /// With --plan: jobs the reference's samples are split into (merged exactly).
    #[arg(long, default_value_t = 1, requires = "plan")]
    pub chunks: u32,

    /// Assemble the report of a planned study from its jobs' results (into the plan's --out),
    /// as the single process would have written it (timings aside). Given alone.
    #[arg(long, value_name = "DIR", exclusive = true)]
    pub merge: Option<PathBuf>,

    /// With --plan: let the merge compare equal-time frames timed on different kinds of
    /// machine (CPU model, cores or threads), which it otherwise refuses (the plan records
    /// this flag; without --plan it does nothing).
    #[arg(long)]
    pub allow_mixed_machines: bool,
}

impl CompareArgs {
    /// The methods of every `--methods`, in order.
    pub fn methods(&self) -> Vec<MethodSpec> {
        self.methods
            .iter()
            .flat_map(|l| l.0.iter().cloned())
            .map(|mut m| {
                if m.producer.is_some() && self.cache_kind == nrc_cache::CacheKind::Hash {
                    m.cache = nrc_cache::CacheKind::Hash;
                }
                m
            })
            .collect()
    }
}

/// Checks the arguments before any work.
pub(crate) fn validate(args: &CompareArgs) -> Result<Budget> {
    ensure!(
        args.width > 0 && args.height > 0,
        "image size {}x{} is empty",
        args.width,
        args.height
    );
    ensure!(args.runs >= 1, "--runs must be at least 1");
    nrc_harness::compare::check_diagnostics(args.diagnostics, args.runs)?;
    ensure!(
        args.exposure.is_finite(),
        "--exposure must be a finite number"
    );
    ensure!(
        (1..=16).contains(&args.sweep_steps),
        "--sweep-steps must be between 1 and 16, got {}",
        args.sweep_steps
    );
    if let Some(f) = args.converge {
        ensure!(
            (1..=1_000_000).contains(&f),
            "--converge must be between 1 and 1000000 frames, got {f}"
        );
    }
    if let Some(t) = &args.converge_target {
        ensure!(
            args.methods().contains(t),
            "--converge-target {t} is not one of --methods"
        );
    }
    let mut seen = std::collections::HashSet::new();
    for m in &args.methods() {
        ensure!(seen.insert(m.to_string()), "method {m} is listed twice");
        // Before the reference is rendered (a study's jobs check again where they run).
        let memory = nrc_harness::run::available_memory();
        nrc_harness::run::check_frame_memory(&m.pass, args.width, args.height, m.spp, memory)
            .map_err(|e| anyhow::anyhow!("{m}: {e}"))?;
    }
    Budget::from_limits(args.equal_time, args.equal_spp).map_err(anyhow::Error::msg)
}

/// Runs `nrc compare` (with `--plan`, `crate::study` writes the plan instead).
pub fn run(args: &CompareArgs) -> Result<()> {
    if args.merge.is_some() {
        anyhow::bail!("--merge DIR is given alone: the study's settings are its plan's");
    }
    let budget = validate(args)?;
    let scene = args.scene.load()?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    let pool = nrc_harness::options::thread_pool(args.threads)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
    pool.install(|| run_comparison(args, budget, &scene))
}

fn run_comparison(args: &CompareArgs, budget: Budget, scene: &Scene) -> Result<()> {
    let (w, h) = (args.width, args.height);
    let c = comparison(args, budget, scene, true)?;
    if let Some(frames) = args.sequence {
        let seq = nrc_harness::sequence::Sequence {
            frames,
            fps: args.fps,
            reference_spp: args.reference_spp,
            tracked: args.tracked,
            camera_path: args.camera_path.clone(),
        };
        let animated = args.scene.load_animated()?;
        let pose = |t: f32| args.scene.pose(&animated, t);
        let report = nrc_harness::sequence::compare_sequence(
            &c,
            &seq,
            (&pose, animated.is_animated()),
            &|m| eprintln!("{m}"),
        )?;
        print!(
            "{}",
            std::fs::read_to_string(c.out.join("sequence.md")).unwrap_or_default()
        );
        eprintln!(
            "wrote sequence.md, sequence.json and sequence-mape.png to {} ({} methods)",
            args.out.display(),
            report.rows.len()
        );
        return Ok(());
    }
    let req = reference_request(args, scene);
    let reference = match &args.reference {
        Some(path) => {
            let r = reference::load_given(path, w, h)?;
            reference::check_given(&r, &req)?;
            r
        }
        None => reference::obtain_showing_progress(&req, &args.cache.dir(), false)?,
    };
    eprintln!(
        "reference: {} {}",
        if reference.reused {
            "reused"
        } else {
            "rendered"
        },
        reference.location.display()
    );
    let progress = Progress::new(total_frames(&c), Unit::Frames, "compare");
    let (report, markdown) = compare(&c, scene, &reference, &|p| match p {
        Step::Method(name) => progress.set_message(name),
        Step::Frame => progress.inc(1),
    })?;
    progress.finish();
    print_report(&report, &markdown, &args.out);
    Ok(())
}

/// The reference the arguments ask for.
pub(crate) fn reference_request<'a>(
    args: &'a CompareArgs,
    scene: &'a Scene,
) -> ReferenceRequest<'a> {
    ReferenceRequest {
        scene_path: &args.scene.scene,
        scene,
        width: args.width,
        height: args.height,
        spp: args.reference_spp,
        seed: 0,
        tracer: args.depth.tracer(),
    }
}

/// Prints the report and where it went.
pub(crate) fn print_report(
    report: &nrc_eval::Report,
    markdown: &std::path::Path,
    out: &std::path::Path,
) {
    for note in &report.notes {
        if note.contains("NaN or infinite") {
            eprintln!("warning: {note}");
        }
    }
    print!("{}", report.to_markdown());
    eprintln!(
        "wrote {} and the images to {}",
        markdown.display(),
        out.display()
    );
}

/// The comparison the arguments describe, on `scene` (`--resolution auto` is chosen from its
/// camera; `print`: say so, and which device caches compute on).
pub(crate) fn comparison(
    args: &CompareArgs,
    budget: Budget,
    scene: &Scene,
    print: bool,
) -> Result<Comparison> {
    let (w, h) = (args.width, args.height);
    let methods = args.methods();
    let any_cache = methods.iter().any(|m| m.producer.is_some());
    let mut cache_settings =
        args.model
            .method_settings(args.train_frames, args.seed, print && any_cache)?;
    cache_settings.online = !args.frozen;
    if let Some(why) = cache_settings.resolve_resolution(scene, w, h)?
        && print
        && any_cache
    {
        eprintln!("{why}");
    }
    Ok(Comparison {
        methods: methods.clone(),
        budget,
        width: w,
        height: h,
        runs: args.runs,
        sweep_steps: args.sweep.then_some(args.sweep_steps),
        converge: args.converge.map(|frames| nrc_harness::compare::Converge {
            frames,
            target: args
                .converge_target
                .as_ref()
                .unwrap_or(&methods[0])
                .to_string(),
        }),
        flip: !args.no_flip,
        out: args.out.clone(),
        seed: args.seed,
        exposure: args.exposure,
        exclude_emitters: args.exclude_emitters,
        diagnostics: args.diagnostics,
        emitter_samples: args.emitters.emitter_samples,
        camera_offsets: args.offsets.camera_offsets,
        interleave: args.interleave,
        tracer: args.depth.tracer(),
        cache: cache_settings,
        scene_name: args
            .scene
            .scene
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        scene_path: args.scene.scene.display().to_string(),
    })
}
