//! `nrc render`: the reference path tracer on a scene, written as EXR (and PNG preview).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, bail};
use nrc_harness::options::{SceneArgs, TracerArgs};
use nrc_harness::progress::{Progress, Unit};
use nrc_harness::run::RenderChoice;
use nrc_render::passes::PassSpec;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Read the run's settings from this JSON file: its fields are these flags (`snake_case`
    /// or `kebab-case`), and flags given on the command line override it.
    #[arg(long, value_name = "FILE")]
    pub run: Option<PathBuf>,

    #[command(flatten)]
    pub scene: SceneArgs,

    /// Samples (paths) per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,

    /// Image width in pixels.
    #[arg(long, default_value_t = 640)]
    pub width: u32,

    /// Image height in pixels.
    #[arg(long, default_value_t = 480)]
    pub height: u32,

    /// Output image: OpenEXR, linear RGB, 32-bit float.
    #[arg(long)]
    pub out: PathBuf,

    /// Also write a tone-mapped 8-bit PNG preview (ACES filmic, sRGB).
    #[arg(long)]
    pub png: Option<PathBuf>,

    /// Exposure of the PNG preview in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,

    /// Also write the per-pixel sample variance of one path's estimate as OpenEXR
    /// (divide by spp for the variance of the pixel mean).
    #[arg(long)]
    pub variance: Option<PathBuf>,

    /// Seed of the random numbers; a seed gives the same image whatever the thread count.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,

    #[command(flatten)]
    pub tracer: TracerArgs,

    #[command(flatten)]
    pub emitters: nrc_harness::options::EmitterArgs,

    #[command(flatten)]
    pub offsets: nrc_harness::options::OffsetArgs,

    /// Render from a saved cache (a snapshot written by `nrc train --snapshot`): camera
    /// paths end in the cache by --termination instead of being traced to the end.
    #[arg(long)]
    pub cache: Option<PathBuf>,

    /// With --cache: where paths end in it (first, diffuse[:R], spread[:C], bth[:K]).
    #[arg(long, default_value = "spread", value_parser = nrc_harness::options::parse_termination)]
    pub termination: nrc_render::Termination,

    /// With --cache: where the cache computes.
    #[arg(long, value_enum, default_value_t = nrc_harness::options::DeviceArg::Cpu)]
    pub device: nrc_harness::options::DeviceArg,

    /// The pass (default: pt, or cache with --cache); `--help` lists every pass and its
    /// parameters. Stateful passes reuse samples across --frames.
    #[arg(long, long_help = nrc_render::passes::help())]
    pub pass: Option<PassSpec>,

    /// Frames to render, the last one written: the resampling passes (restir-*) reuse samples
    /// across them (temporal reuse), the others simply render each anew.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,

    /// With --frames: the camera of each frame from a camera path (JSON keyframes, as for
    /// `nrc train --camera-path`); default: the scene's camera throughout.
    #[arg(long)]
    pub camera_path: Option<PathBuf>,

    /// Render with a --cache snapshot trained on another scene (or another version of this
    /// one) instead of refusing it.
    #[arg(long)]
    pub allow_other_scene: bool,
}

/// Renders and writes the image(s), with progress and a closing line.
pub fn run(args: &RenderArgs) -> Result<()> {
    if args.width == 0 || args.height == 0 {
        bail!("image size {}x{} is empty", args.width, args.height);
    }
    if args.spp == 0 || args.frames == 0 {
        bail!("--spp and --frames must be at least 1");
    }
    if !args.exposure.is_finite() {
        bail!("--exposure must be a finite number");
    }
    // Fail before a long render, not after it, when an output cannot be written.
    let outputs = std::iter::once(&args.out)
        .chain(&args.png)
        .chain(&args.variance);
    nrc_harness::options::check_output_folders(outputs)?;
    let scene = args.scene.load()?;
    let tracer = args.tracer.tracer();
    let choice = RenderChoice {
        pass: args.pass.clone(),
        snapshot: args.cache.as_deref(),
        termination: args.termination,
        device: args.device,
        scene_path: &args.scene.scene,
        allow_other_scene: args.allow_other_scene,
    };
    let (spec, cache, warnings) = nrc_harness::run::choose_pass(choice, &scene, &tracer)?;
    for w in scene.warnings().iter().chain(&warnings) {
        eprintln!("warning: {w}");
    }
    // The path tracer counts pixels as its tiles finish, in every frame.
    let pixels = args.width as u64 * args.height as u64 * u64::from(args.frames);
    let progress = Arc::new(Progress::new(pixels, Unit::Pixels, "render"));
    let cameras =
        nrc_harness::run::camera_path(args.camera_path.as_deref(), &scene.camera, args.frames)?;
    let pool = nrc_harness::options::thread_pool(args.threads)?;
    let counter = progress.clone();
    // CPU time of the rendering alone (all threads; the scene's loading is not in it), for
    // comparisons per CPU-second on a shared machine (scripts/mitsuba_compare.py).
    let cpu0 = nrc_scene::cpu::process_cpu_time();
    let rendered = pool.install(|| {
        nrc_harness::run::render(nrc_harness::run::RenderJob {
            scene: &scene,
            pass: &spec,
            tracer,
            cache: cache.as_ref(),
            cameras: &cameras,
            width: args.width,
            height: args.height,
            spp: args.spp,
            seed: args.seed,
            emitter_samples: args.emitters.emitter_samples,
            camera_offsets: args.offsets.camera_offsets,
            variance: args.variance.is_some(),
            progress: Some(Box::new(move |n| counter.inc(n))),
        })
    })?;
    let (out, seconds) = (rendered.output, rendered.seconds_per_frame);
    let cpu = match (cpu0, nrc_scene::cpu::process_cpu_time()) {
        (Some(a), Some(b)) => format!("; {:.2} CPU-s rendering", (b - a).as_secs_f64()),
        _ => String::new(),
    };
    progress.finish();

    out.image.write_exr(&args.out)?;
    if let Some(png) = &args.png {
        out.image.write_png_preview(png, args.exposure)?;
    }
    if let Some(path) = &args.variance {
        match &out.variance {
            Some(v) => v.write_exr(path)?,
            None => bail!("--variance needs at least 2 samples per pixel"),
        }
    }
    let s = &out.stats;
    if s.invalid_samples > 0 {
        eprintln!(
            "warning: {} samples were NaN or infinite and counted as black",
            s.invalid_samples
        );
    }
    let from = match (&args.cache, &cache) {
        (Some(p), Some(_)) => format!(
            " from the cache {} ({} cache queries)",
            p.display(),
            s.queries
        ),
        _ => String::new(),
    };
    let frames = if args.frames > 1 {
        format!(" (last of {} frames, each)", args.frames)
    } else {
        String::new()
    };
    let phases = s.phases.describe().map(|p| format!("; phases: {p}"));
    println!(
        "rendered {}x{} at {} spp with {}{from} in {seconds:.3} s{frames} on {} threads: {:.3} M samples/s, {:.2} M rays/s{cpu}{}",
        args.width,
        args.height,
        args.spp,
        rendered.pass,
        pool.current_num_threads(),
        s.paths as f64 / seconds * 1e-6,
        s.rays as f64 / seconds * 1e-6,
        phases.unwrap_or_default()
    );
    Ok(())
}
