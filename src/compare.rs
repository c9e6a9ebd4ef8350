//! `nrc compare`: every method of a list against one reference, at equal samples or equal time.
//!
//! For each method, `--runs R` frames with distinct seeds; their errors against the reference
//! (MSE, relMSE, MAPE, HDR-FLIP) are averaged over the runs, and from R ≥ 2 runs the per-pixel
//! mean and variance give bias² and variance (bias² corrected for the noise of the mean and of
//! the reference, see `nrc_eval::bias_variance`). `--sweep` adds frames at doubling budgets,
//! plotted as error against wall time with the "time to reach the error of the first method"
//! table. The budget and its tolerance are those of `nrc_render::methods::render_frame`.
//!
//! Output folder: `report.md`, `report.json`, `runs.json` (every frame: seed, passes, spp, time,
//! longest pass, errors), `error-vs-time.png`/`.svg` (relMSE against time per frame),
//! `reference.png`, and per method (its first run) `<method>.exr`, `<method>.png` (tone-mapped
//! preview), `<method>-relmse.png` (per-pixel relMSE, viridis, log scale 10⁻⁴…10) and
//! `<method>-flip.png` (per-pixel HDR-FLIP, magma, 0…1). Every file is written atomically.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail, ensure};
use indicatif::{ProgressBar, ProgressStyle};
use nrc_eval::metrics::{MAPE_EPSILON, Metric, REL_MSE_EPSILON, mape, mse, rel_mse, rel_mse_map};
use nrc_eval::plot::plot_error_vs_time;
use nrc_eval::png_output::{ColorMap, Scale, write_false_color_png};
use nrc_eval::sweep::time_to_error_table;
use nrc_eval::{
    BiasVarianceAccumulator, ErrorMetrics, HdrFlipParams, ImageView, Report, ReportRow,
    ScalarImage, SweepPoint, SweepSeries, hdr_flip, write_report,
};
use nrc_render::methods::{Budget, Frame, FrameRequest, MethodSettings, pass_seed, render_frame};
use nrc_scene::{Image, Scene};
use nrc_train::methods::MethodSpec;
use serde::{Deserialize, Serialize};

use crate::reference::{self, CacheArgs, DepthArgs, Reference, ReferenceRequest};
use crate::scene_args::SceneArgs;

/// Arguments of `nrc compare`.
#[derive(clap::Args, Debug)]
#[command(group = clap::ArgGroup::new("budget").required(true).args(["equal_time", "equal_spp"]))]
pub struct CompareArgs {
    #[command(flatten)]
    pub scene: SceneArgs,

    /// Methods to compare, comma-separated: pt-<N>spp (path tracer, N samples per pixel per
    /// pass, NEE and BSDF sampling by MIS), pt-<N>spp-nonee (BSDF sampling only), or
    /// nrc-<producer>[-<termination>] (a cache trained online by pt, pt-sl, bt, lt or sppc,
    /// rendered at 1 spp with paths ending in it: first, diffuse, spread (default), bth).
    #[arg(long, value_delimiter = ',', required = true)]
    pub methods: Vec<MethodSpec>,

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

    /// Cache methods: frames of online training before measurement (untimed).
    #[arg(long, default_value_t = 64)]
    pub train_frames: u32,

    /// Cache methods: stop training once measurement starts (else every pass is a full online
    /// frame: produce, train and render, all timed).
    #[arg(long)]
    pub frozen: bool,

    #[command(flatten)]
    pub model: crate::cache_args::RadianceCacheArgs,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// One rendered frame, as recorded in `runs.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub method: String,
    /// Run index (0 … R−1) of the main comparison; `None` for sweep frames.
    pub run: Option<u32>,
    /// Sweep step k (budget × 2^k); `None` for frames of the main comparison except run 0,
    /// which is also step 0 of the sweep.
    pub sweep_step: Option<u32>,
    pub seed: u64,
    /// The frame's budget: milliseconds (equal time) or passes (equal samples).
    pub budget_ms: Option<f64>,
    pub budget_passes: Option<u32>,
    pub passes: u32,
    pub samples_per_pixel: u64,
    pub time_ms: f64,
    pub longest_pass_ms: f64,
    pub invalid_samples: u64,
    pub metrics: ErrorMetrics,
}

/// `runs.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunsFile {
    /// "equal-time" or "equal-spp".
    pub mode: String,
    /// How equal-time frames meet their budget.
    pub tolerance: String,
    pub runs: Vec<RunRecord>,
}

const TOLERANCE: &str = "equal time: passes continue while the next is predicted to end nearer the budget than stopping \
     (elapsed + mean pass / 2 <= budget), at least one pass, the last pass kept whole; so |time - budget| <= longest pass \
     (typically <= half a pass)";

/// Stable 64-bit FNV-1a of a method name, so a method's random streams do not depend on which
/// other methods are compared with it.
fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The budget scaled by 2^step.
fn scaled_budget(base: Budget, step: u32) -> Budget {
    match base {
        Budget::Passes(n) => Budget::Passes(n.saturating_mul(1 << step)),
        Budget::Time(t) => Budget::Time(t * (1 << step)),
    }
}

/// Errors of a frame against the reference, and the per-pixel HDR-FLIP map when computed.
fn errors(
    image: &Image,
    reference: &ImageView<'_>,
    flip: bool,
    name: &str,
) -> Result<(ErrorMetrics, Option<ScalarImage>)> {
    let x = ImageView::of_scene_image(name, image)?;
    let flip = if flip {
        Some(
            hdr_flip(&x, reference, &HdrFlipParams::default())
                .with_context(|| format!("HDR-FLIP of {name} (pass --no-flip to skip it)"))?,
        )
    } else {
        None
    };
    let m = ErrorMetrics {
        mse: mse(&x, reference)?,
        rel_mse: rel_mse(&x, reference, REL_MSE_EPSILON)?,
        mape: mape(&x, reference, MAPE_EPSILON)?,
        flip: flip.as_ref().map(|f| f.mean),
    };
    Ok((m, flip.map(|f| f.error_map)))
}

fn record(
    method: &str,
    run: Option<u32>,
    step: Option<u32>,
    seed: u64,
    budget: Budget,
    f: &Frame,
    m: ErrorMetrics,
) -> RunRecord {
    RunRecord {
        method: method.to_string(),
        run,
        sweep_step: step,
        seed,
        budget_ms: match budget {
            Budget::Time(t) => Some(t.as_secs_f64() * 1e3),
            Budget::Passes(_) => None,
        },
        budget_passes: match budget {
            Budget::Passes(n) => Some(n),
            Budget::Time(_) => None,
        },
        passes: f.passes,
        samples_per_pixel: f.samples_per_pixel,
        time_ms: f.elapsed.as_secs_f64() * 1e3,
        longest_pass_ms: f.longest_pass.as_secs_f64() * 1e3,
        invalid_samples: f.invalid_samples,
        metrics: m,
    }
}

fn mean_metrics(ms: &[ErrorMetrics]) -> ErrorMetrics {
    let n = ms.len() as f64;
    let avg = |f: fn(&ErrorMetrics) -> f64| ms.iter().map(f).sum::<f64>() / n;
    ErrorMetrics {
        mse: avg(|m| m.mse),
        rel_mse: avg(|m| m.rel_mse),
        mape: avg(|m| m.mape),
        flip: ms
            .iter()
            .map(|m| m.flip)
            .sum::<Option<f64>>()
            .map(|s| s / n),
    }
}

/// Checks the arguments before any work.
fn validate(args: &CompareArgs) -> Result<Budget> {
    ensure!(
        args.width > 0 && args.height > 0,
        "image size {}x{} is empty",
        args.width,
        args.height
    );
    ensure!(args.runs >= 1, "--runs must be at least 1");
    ensure!(
        args.exposure.is_finite(),
        "--exposure must be a finite number"
    );
    ensure!(
        (1..=16).contains(&args.sweep_steps),
        "--sweep-steps must be between 1 and 16, got {}",
        args.sweep_steps
    );
    let mut seen = std::collections::HashSet::new();
    for m in &args.methods {
        ensure!(seen.insert(m.to_string()), "method {m} is listed twice");
    }
    Ok(match (args.equal_time, args.equal_spp) {
        (Some(ms), None) => {
            ensure!(
                ms.is_finite() && ms > 0.0 && ms <= 3.6e6,
                "--equal-time must be between 0 and one hour in milliseconds, got {ms}"
            );
            Budget::Time(Duration::from_secs_f64(ms * 1e-3))
        }
        (None, Some(n)) => {
            ensure!(n >= 1, "--equal-spp must be at least 1");
            Budget::Passes(n)
        }
        _ => bail!("give exactly one of --equal-time MS and --equal-spp N"),
    })
}

/// Runs `nrc compare`.
pub fn run(args: &CompareArgs) -> Result<()> {
    let budget = validate(args)?;
    let scene = args.scene.load()?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    let pool = crate::render::thread_pool(args.threads)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
    pool.install(|| compare(args, budget, &scene))
}

fn compare(args: &CompareArgs, budget: Budget, scene: &Scene) -> Result<()> {
    let (w, h) = (args.width, args.height);
    let reference = match &args.reference {
        Some(path) => reference::load_given(path, w, h)?,
        None => {
            let req = ReferenceRequest {
                scene_path: &args.scene.scene,
                scene,
                width: w,
                height: h,
                spp: args.reference_spp,
                seed: 0,
                tracer: args.depth.tracer(),
            };
            reference::obtain(&req, &args.cache.dir(), false)?
        }
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
    let Reference {
        mean: ref_image,
        variance: ref_variance,
        meta: ref_meta,
        location: ref_location,
        ..
    } = &reference;
    let ref_view = ImageView::of_scene_image("reference", ref_image)?;
    let ref_var_view = ref_variance
        .as_ref()
        .map(|v| ImageView::of_scene_image("reference variance", v))
        .transpose()?;
    ref_image.write_png_preview(&args.out.join("reference.png"), args.exposure)?;

    let settings = MethodSettings {
        tracer: args.depth.tracer(),
    };
    let emitter_mask = args.exclude_emitters.then(|| emitter_pixels(scene, w, h));
    let any_cache = args
        .methods
        .iter()
        .any(|m| matches!(m, MethodSpec::Cache(_)));
    let mut cache_settings = args
        .model
        .method_settings(args.train_frames, args.seed, any_cache)?;
    cache_settings.online = !args.frozen;
    let steps = if args.sweep { args.sweep_steps } else { 1 };
    let total = args.methods.len() as u64 * (args.runs + steps - 1) as u64;
    let bar = ProgressBar::new(total).with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} frames {msg}")
            .expect("valid progress template")
            .progress_chars("=> "),
    );

    let mode = match budget {
        Budget::Time(t) => format!("equal time, {} ms per frame", t.as_secs_f64() * 1e3),
        Budget::Passes(n) => format!("equal samples, {n} pass(es) per frame"),
    };
    let scene_name = args
        .scene
        .scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut report = Report::new(format!("{scene_name}: {mode}"), w as usize, h as usize);
    if let Some(m) = &emitter_mask {
        let n = m.iter().filter(|x| **x).count();
        eprintln!(
            "excluding {n} pixels that see an emitter (and their neighbours) from the errors"
        );
        report.notes.push(format!(
            "Errors exclude the {n} pixels that see an emitter or touch one that does (their error is set to zero; means are still over all pixels)."
        ));
    }
    report.scene = Some(args.scene.scene.display().to_string());
    report.reference = Some(match ref_meta {
        Some(m) => format!("{} ({})", m.describe(), ref_location.display()),
        None => format!("{} (no variance)", ref_location.display()),
    });
    let mut runs = Vec::new();
    let mut plot_series = Vec::new();

    for spec in &args.methods {
        let mut method = spec.build(&settings, &cache_settings);
        method
            .prepare(scene, &scene.camera, w, h)
            .map_err(|e| anyhow::anyhow!("{spec}: {e}"))?;
        let name = method.name().to_string();
        bar.set_message(name.clone());
        // Untimed warm-up pass on a small image (thread pool, caches), so that the first
        // timed frame is not charged for start-up.
        method.render_pass(scene, &scene.camera, w.min(16), h.min(16), u64::MAX);

        let base = args.seed ^ name_hash(&name);
        let mut acc = BiasVarianceAccumulator::new(w as usize, h as usize);
        let mut metrics = Vec::new();
        let (mut time_ms, mut spp) = (0.0, 0.0);
        let mut first: Option<(Frame, ErrorMetrics)> = None;
        for r in 0..args.runs {
            let seed = pass_seed(base, r);
            let mut frame = render_frame(
                method.as_mut(),
                scene,
                &scene.camera,
                &FrameRequest {
                    width: w,
                    height: h,
                    seed,
                    budget,
                },
            )?;
            exclude(&mut frame.image, emitter_mask.as_deref(), ref_image);
            let (m, flip_map) = errors(&frame.image, &ref_view, !args.no_flip, &name)?;
            if args.runs >= 2 {
                acc.add(&ImageView::of_scene_image(&name, &frame.image)?)?;
            }
            runs.push(record(
                &name,
                Some(r),
                (r == 0).then_some(0),
                seed,
                budget,
                &frame,
                m,
            ));
            metrics.push(m);
            time_ms += frame.elapsed.as_secs_f64() * 1e3;
            spp += frame.samples_per_pixel as f64;
            if r == 0 {
                write_images(args, &name, &frame.image, &ref_view, flip_map.as_ref())?;
                first = Some((frame, m));
            }
            bar.inc(1);
        }
        let (first_frame, first_metrics) = first.expect("at least one run");
        let n = args.runs as f64;
        report.rows.push(ReportRow {
            method: name.clone(),
            time_per_frame_ms: time_ms / n,
            samples_per_pixel: spp / n,
            metrics: mean_metrics(&metrics),
            bias_variance: if args.runs >= 2 {
                Some(acc.finish(&ref_view, ref_var_view.as_ref())?)
            } else {
                None
            },
            temporal: None,
        });

        // Plot points: the sweep (run 0 is its first budget), else every run.
        let mut series = SweepSeries {
            method: name.clone(),
            points: Vec::new(),
        };
        if args.sweep {
            series.points.push(SweepPoint {
                time_ms: first_frame.elapsed.as_secs_f64() * 1e3,
                samples_per_pixel: first_frame.samples_per_pixel as f64,
                metrics: first_metrics,
            });
            for step in 1..steps {
                let seed = pass_seed(base ^ 0x5EE9_5EE9_5EE9_5EE9, step);
                let b = scaled_budget(budget, step);
                let mut frame = render_frame(
                    method.as_mut(),
                    scene,
                    &scene.camera,
                    &FrameRequest {
                        width: w,
                        height: h,
                        seed,
                        budget: b,
                    },
                )?;
                exclude(&mut frame.image, emitter_mask.as_deref(), ref_image);
                let (m, _) = errors(&frame.image, &ref_view, !args.no_flip, &name)?;
                runs.push(record(&name, None, Some(step), seed, b, &frame, m));
                series.points.push(SweepPoint {
                    time_ms: frame.elapsed.as_secs_f64() * 1e3,
                    samples_per_pixel: frame.samples_per_pixel as f64,
                    metrics: m,
                });
                bar.inc(1);
            }
            report.sweeps.push(series.clone());
        } else {
            series.points = runs
                .iter()
                .filter(|r| r.method == name)
                .map(|r| SweepPoint {
                    time_ms: r.time_ms,
                    samples_per_pixel: r.samples_per_pixel as f64,
                    metrics: r.metrics,
                })
                .collect();
        }
        plot_series.push(series);
    }
    bar.finish_and_clear();

    if args.sweep {
        let baseline = &report.sweeps[0];
        let last = baseline.curve(Metric::RelMse).last().map(|p| p.0);
        if let Some(t) = last {
            let table =
                time_to_error_table(&report.sweeps, Metric::RelMse, &baseline.method.clone(), t)?;
            report.time_to_error.push(table);
        }
    }
    let invalid: u64 = runs.iter().map(|r| r.invalid_samples).sum();
    report.notes.push(format!(
        "Budget: {mode}; a pass is one estimate at the method's stated spp. Errors are means over {} run(s) with \
         distinct seeds (per-run values in runs.json); images show run 0.",
        args.runs
    ));
    if let Budget::Time(_) = budget {
        report
            .notes
            .push(format!("Equal-time tolerance: {TOLERANCE}."));
    }
    if args.sweep {
        report.notes.push(format!(
            "Sweep: each method at the budget × 1, 2, …, {} (one frame each; the first is run 0).",
            1u64 << (steps - 1)
        ));
    }
    if invalid > 0 {
        report.notes.push(format!(
            "{invalid} samples were NaN or infinite and counted as black."
        ));
        eprintln!("warning: {invalid} samples were NaN or infinite and counted as black");
    }

    let title = format!("relMSE against time per frame: {scene_name}, {}x{}", w, h);
    plot_error_vs_time(
        &plot_series,
        Metric::RelMse,
        &title,
        &args.out.join("error-vs-time.png"),
        &args.out.join("error-vs-time.svg"),
    )
    .context("cannot draw the error-against-time plot")?;
    let runs_file = RunsFile {
        mode: match budget {
            Budget::Time(_) => "equal-time",
            Budget::Passes(_) => "equal-spp",
        }
        .into(),
        tolerance: TOLERANCE.into(),
        runs,
    };
    let json = serde_json::to_string_pretty(&runs_file).expect("runs serialise");
    nrc_eval::atomic::atomic_write(&args.out.join("runs.json"), json.as_bytes())?;
    let files = write_report(&args.out, &report)?;
    print!("{}", report.to_markdown());
    eprintln!(
        "wrote {} and the images to {}",
        files.markdown.display(),
        args.out.display()
    );
    Ok(())
}

/// The rendered frame (EXR and PNG preview) and its false-colour error maps.
fn write_images(
    args: &CompareArgs,
    name: &str,
    image: &Image,
    reference: &ImageView<'_>,
    flip: Option<&ScalarImage>,
) -> Result<()> {
    image.write_exr(&args.out.join(format!("{name}.exr")))?;
    image.write_png_preview(&args.out.join(format!("{name}.png")), args.exposure)?;
    let x = ImageView::of_scene_image(name, image)?;
    write_false_color_png(
        &args.out.join(format!("{name}-relmse.png")),
        &rel_mse_map(&x, reference, REL_MSE_EPSILON)?,
        ColorMap::Viridis,
        Scale::Log {
            min: 1e-4,
            max: 10.0,
        },
    )?;
    if let Some(map) = flip {
        write_false_color_png(
            &args.out.join(format!("{name}-flip.png")),
            map,
            ColorMap::Magma,
            Scale::Linear { min: 0.0, max: 1.0 },
        )?;
    }
    Ok(())
}

/// Pixels whose footprint sees an emitter (4×4 primary rays per pixel), dilated by one pixel.
fn emitter_pixels(scene: &Scene, w: u32, h: u32) -> Vec<bool> {
    let sees = |x: u32, y: u32| {
        (0..16).any(|k| {
            let film = glam::Vec2::new(
                x as f32 + ((k % 4) as f32 + 0.5) / 4.0,
                y as f32 + ((k / 4) as f32 + 0.5) / 4.0,
            );
            let ray = scene.camera.generate_ray(film, w, h);
            scene.intersect(&ray).is_some_and(|hit| {
                scene.emission(&scene.interaction(&ray, &hit)) != glam::Vec3::ZERO
            })
        })
    };
    let direct: Vec<bool> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| sees(x, y))
        .collect();
    let (wi, hi) = (w as i64, h as i64);
    (0..hi)
        .flat_map(|y| (0..wi).map(move |x| (x, y)))
        .map(|(x, y)| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    u >= 0 && v >= 0 && u < wi && v < hi && direct[(v * wi + u) as usize]
                })
            })
        })
        .collect()
}

/// Copies the reference into the excluded pixels (zero error there).
fn exclude(image: &mut Image, mask: Option<&[bool]>, reference: &Image) {
    if let Some(mask) = mask {
        for ((p, r), m) in image.data.iter_mut().zip(&reference.data).zip(mask) {
            if *m {
                *p = *r;
            }
        }
    }
}
