//! `nrc view`: the online loop of `nrc train` live in a window (crates/nrc-view), or headless
//! for pictures and tests.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nrc_train::QueryMaker;
use nrc_view::display::ToneMap;

use crate::train::TrainArgs;

/// Arguments of `nrc view`: every flag of `nrc train` (the loop it runs), and the viewer's.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    #[command(flatten)]
    pub train: TrainArgs,

    /// No window: run the loop for --frames frames, then write the pictures asked for
    /// (--screenshot, --viewport-png, --views-out). Needs an adapter, not a display.
    #[arg(long)]
    pub headless: bool,

    /// The whole UI as a PNG: written at the end with --headless, on F12 in a window
    /// (default there: nrc-view.png).
    #[arg(long)]
    pub screenshot: Option<PathBuf>,

    /// With --headless: the viewport alone as a PNG (one pixel per image pixel).
    #[arg(long)]
    pub viewport_png: Option<PathBuf>,

    /// With --headless: every debug view as a PNG into this folder (final.png, raw.png,
    /// cache.png, records.png, error.png and the pass's own).
    #[arg(long)]
    pub views_out: Option<PathBuf>,

    /// The debug view shown: final (accumulated), raw (the last frame), cache (the cache at the
    /// first vertex), records (where the frame's training records landed), error (against
    /// --reference), or the pass's own (e.g. reservoir-m).
    #[arg(long)]
    pub view: Option<String>,

    /// Size of the window (logical pixels) or of the headless UI, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x800", value_parser = parse_size)]
    pub window_size: [u32; 2],

    /// Exposure of the tone-mapped views, in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,

    /// Tone curve: aces (as nrc render --png), clamp, reinhard.
    #[arg(long, default_value = "aces", value_parser = parse_tonemap)]
    pub tonemap: ToneMap,

    /// A reference for the error view: an EXR of the scene's camera at --width x --height, or
    /// a stored reference's folder. Default: the stored reference (--cache-dir) made for this
    /// scene, camera, size and depth with the most samples, if there is one.
    #[arg(long)]
    pub reference: Option<PathBuf>,

    #[command(flatten)]
    pub store: nrc_harness::options::CacheArgs,

    /// Start from this cache snapshot (trained on this scene) instead of an untrained cache.
    #[arg(long)]
    pub load: Option<PathBuf>,

    /// Start with training paused: the pass renders from the cache as it is.
    #[arg(long)]
    pub paused: bool,

    /// In a window: print the UI's and the loop's frame rates every 5 s.
    #[arg(long)]
    pub print_rates: bool,
}

fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("{s:?} is not WIDTHxHEIGHT"))?;
    let n = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (64..=8192).contains(n))
            .ok_or_else(|| format!("{v:?} is not a size from 64 to 8192"))
    };
    Ok([n(w)?, n(h)?])
}

fn parse_tonemap(s: &str) -> Result<ToneMap, String> {
    match s {
        "aces" => Ok(ToneMap::Aces),
        "clamp" => Ok(ToneMap::Clamp),
        "reinhard" => Ok(ToneMap::Reinhard),
        _ => Err(format!("{s:?}: the tone curves are aces, clamp, reinhard")),
    }
}

/// Runs `nrc view`.
pub fn run(args: &ViewArgs) -> Result<()> {
    let t = &args.train;
    crate::train::check(t)?;
    if t.frames_out.is_some() || t.stats.is_some() {
        bail!("nrc view writes no frames or statistics (--frames-out, --stats): nrc train does");
    }
    if !args.exposure.is_finite() {
        bail!("--exposure must be a finite number");
    }
    if !args.headless && (args.viewport_png.is_some() || args.views_out.is_some()) {
        bail!("--viewport-png and --views-out are for --headless");
    }
    let outputs = args
        .screenshot
        .iter()
        .chain(&args.viewport_png)
        .chain(&t.snapshot);
    nrc_harness::options::check_output_folders(outputs)?;
    let scene = t.scene.load()?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    let request = nrc_harness::reference::ReferenceRequest {
        scene_path: &t.scene.scene,
        scene: &scene,
        width: t.width,
        height: t.height,
        spp: 2,
        seed: 0,
        tracer: t.tracer.tracer(),
    };
    let reference = match &args.reference {
        Some(path) => {
            let r = nrc_harness::reference::load_given(path, t.width, t.height)?;
            nrc_harness::reference::check_given(&r, &request)?;
            Some(r)
        }
        None => nrc_harness::reference::find_stored(&request, &args.store.dir())?,
    };
    match &reference {
        Some(r) => eprintln!(
            "error view: the reference {}{}",
            r.location.display(),
            r.meta
                .as_ref()
                .map(|m| format!(" ({} spp)", m.spp))
                .unwrap_or_default()
        ),
        None => eprintln!(
            "error view: no reference (none stored in {} for this scene, camera and size; nrc reference makes one)",
            args.store.dir().display()
        ),
    }
    let reference = reference.map(|r| r.mean);
    let settings = crate::train::cache_settings(t, &scene, true)?;
    let mut trainer = crate::train::trainer(t, &scene, false)?;
    let scene_box = QueryMaker::new(&scene.bounds()).scene_box;
    let content = nrc_harness::reference::scene_content_hash(&t.scene.scene)?;
    let load_snapshot = {
        let (device, content) = (settings.device, content.clone());
        move |path: &std::path::Path| -> Result<nrc_cache::Cache, String> {
            let cache = nrc_cache::Cache::load(path, device)
                .map_err(|e| format!("cannot load the snapshot {}: {e}", path.display()))?;
            nrc_cache::check_scene(
                cache.scene_content(),
                cache.scene_box(),
                &content,
                scene_box,
            )
            .map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(cache)
        }
    };
    if let Some(path) = &args.load {
        trainer.set_cache(load_snapshot(path).map_err(anyhow::Error::msg)?);
    }
    eprintln!("{}", trainer.cache.describe());
    let fresh_cache =
        move || nrc_harness::methods::scene_cache(scene_box, &settings).map_err(|e| e.to_string());
    let animated = t.scene.load_animated()?;
    let animation = animated.is_animated().then(|| {
        let scene_args = t.scene.clone();
        let duration = animated.animation.duration();
        nrc_view::Animation {
            duration,
            fps: t.fps,
            pose: Box::new(move |time| {
                scene_args
                    .pose(&animated, time)
                    .map_err(|e| format!("{e:#}"))
            }),
        }
    });
    let extent = {
        let b = scene.bounds();
        (b.max - b.min).max_element()
    };
    let camera = scene.camera;
    // A camera path plays over --frames frames from the start, as in `nrc train`.
    let path = match &t.camera_path {
        Some(p) => Some(nrc_harness::run::camera_path(Some(p), &camera, t.frames)?),
        None => None,
    };
    let setup = nrc_view::LoopSetup {
        scene,
        animation,
        trainer,
        fresh_cache: Box::new(fresh_cache),
        load_snapshot: Box::new(load_snapshot),
        scene_content: Some(content),
        camera,
        path,
        width: t.width,
        height: t.height,
        train: !args.paused,
        reference,
    };
    let pool = nrc_harness::options::thread_pool(t.threads)?;
    let snapshot = t
        .snapshot
        .clone()
        .unwrap_or_else(|| PathBuf::from("nrc-view.nrc"));
    if args.headless {
        let options = nrc_view::HeadlessOptions {
            frames: t.frames,
            screenshot: args.screenshot.clone(),
            viewport: args.viewport_png.clone(),
            views: args.views_out.clone(),
            view: args.view.clone(),
            size: args.window_size,
            exposure: args.exposure,
            tonemap: args.tonemap,
            snapshot,
            extent,
        };
        let report = nrc_view::run_headless(setup, &options, &pool)?;
        println!(
            "viewed {} frames of {} at {}x{} ({:.3} s a frame on {} threads), drawn with {}{}",
            report.frames,
            t.scene.scene.display(),
            t.width,
            t.height,
            report.seconds_per_frame,
            pool.current_num_threads(),
            report.adapter,
            if report.views.is_empty() {
                String::new()
            } else {
                format!("; views written: {}", report.views.join(", "))
            }
        );
        return Ok(());
    }
    // A pass's own views exist from its first frame on: in a window, keys 6-9 reach them.
    let view = match &args.view {
        Some(name) => nrc_view::View::parse(name, &[]).with_context(|| {
            format!(
                "no view called {name:?} to start a window with: the views are {}",
                nrc_view::headless::all_views(&[]).join(", ")
            )
        })?,
        None => nrc_view::View::Final,
    };
    let options = nrc_view::WindowOptions {
        title: format!("nrc view — {}", t.scene.scene.display()),
        size: args.window_size,
        snapshot,
        screenshot: args
            .screenshot
            .clone()
            .unwrap_or_else(|| PathBuf::from("nrc-view.png")),
        exposure: args.exposure,
        tonemap: args.tonemap,
        extent,
        print_rates: args.print_rates,
        view,
    };
    nrc_view::run_window(setup, options, pool)?;
    Ok(())
}
