//! The comparison loop of `nrc compare`: every method of a list against one reference, at equal samples or equal time.
//!
//! For each method, `--runs R` frames with distinct seeds; their errors against the reference
//! (MSE, relMSE, MAPE, HDR-FLIP) are averaged over the runs, and from R ≥ 2 runs the per-pixel
//! mean and variance give bias² and variance (bias² corrected for the noise of the mean and of
//! the reference, see `nrc_eval::bias_variance`). `--sweep` adds frames at doubling budgets,
//! plotted as error against wall time with the "time to reach the error of the first method"
//! table. The budget and its tolerance are those of `nrc_harness::budget::render_frame`.
//!
//! The report also says where each method's error is (`nrc_eval::concentration`): the share of
//! its squared error in its worst 1 % of pixels and in the pixels that see an emitter, and the
//! 99.9th percentile of pixel squared error, averaged over runs.
//!
//! Output folder: `report.md`, `report.json`, `runs.json` (every frame: seed, passes, spp, time,
//! longest pass, errors), `error-vs-time.png`/`.svg` (relMSE against time per frame),
//! `reference.png`, and per method (its first run) `<method>.exr`, `<method>.png` (tone-mapped
//! preview), `<method>-relmse.png` (per-pixel relMSE, viridis, log scale 10⁻⁴…10) and
//! `<method>-flip.png` (per-pixel HDR-FLIP, magma, 0…1). Every file is written atomically.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use nrc_eval::convergence::{ConvergencePoint, ConvergenceSeries, frames_to_error_table};
use nrc_eval::metrics::{MAPE_EPSILON, Metric, REL_MSE_EPSILON, mape, mse, rel_mse, rel_mse_map};
use nrc_eval::plot::plot_error_vs_time;
use nrc_eval::png_output::{ColorMap, Scale, write_false_color_png};
use nrc_eval::sweep::time_to_error_table;
use nrc_eval::{
    BiasVarianceAccumulator, ErrorMetrics, HdrFlipParams, ImageView, PassCost, Report, ReportRow,
    ScalarImage, SweepPoint, SweepSeries, concentration, hdr_flip, mean_concentration,
    write_report,
};
use nrc_render::emitters::{emitter_pixels, exclude};
use nrc_render::passes::PhaseTimes;
use nrc_render::sampler::Stream;
use nrc_render::{PathTracer, pass_seed};
use nrc_scene::{Image, Scene};
use serde::{Deserialize, Serialize};

use crate::budget::{Budget, CameraOffsets, Frame, FrameRequest, Method, render_frame};
use crate::methods::{CacheMethodSettings, MethodSpec};
use crate::reference::Reference;

/// A comparison: the methods, the budget and what to write.
#[derive(Clone, Debug)]
pub struct Comparison {
    pub methods: Vec<MethodSpec>,
    pub budget: Budget,
    pub width: u32,
    pub height: u32,
    /// Independent frames (distinct seeds) per method; R ≥ 2 gives bias² and variance.
    pub runs: u32,
    /// Budgets of the sweep (the budget × 1, 2, 4, …), if one is run.
    pub sweep_steps: Option<u32>,
    /// Compute HDR-FLIP (the costliest metric).
    pub flip: bool,
    /// Output folder (exists).
    pub out: PathBuf,
    /// Base seed of the methods' frames.
    pub seed: u64,
    /// Exposure of the PNG previews, in stops.
    pub exposure: f32,
    /// Leave the pixels that see an emitter (and their neighbours) out of the errors.
    pub exclude_emitters: bool,
    /// Write each method's per-pixel error decomposition (`METHOD-errors.exr`) and its pass's
    /// state after its last frame (`METHOD-view-NAME.exr`: reservoir statistics, probes);
    /// needs 2 runs or more.
    pub diagnostics: bool,
    /// Extra camera rays at the outline of emitters, every method alike
    /// ([`nrc_render::emitters::supersample`]; 0: none).
    pub emitter_samples: u32,
    /// Where a run's passes put their camera rays in each pixel, every method alike.
    pub camera_offsets: CameraOffsets,
    /// Render the runs interleaved across methods ([`interleaved_frames`]): run `r` of every
    /// method restarted first, then their timed frames back to back, so that a slow moment of
    /// a shared machine falls on every method of that run alike. Every method's state is held
    /// at once. Runs from `stored` frames, sweeps and frames to error are not interleaved.
    pub interleave: bool,
    /// Depth limit and Russian roulette shared by every method and the reference.
    pub tracer: PathTracer,
    /// How cache methods are set up.
    pub cache: CacheMethodSettings,
    /// Frames to equal error (progressive frames of one state), if measured.
    pub converge: Option<Converge>,
    /// The scene's name (titles) and path (the report).
    pub scene_name: String,
    pub scene_path: String,
}

/// The frames-to-equal-error measurement (the DDGI-resampling paper's Table 1 protocol, see
/// `nrc_eval::convergence`): after its runs, each method restarts (untimed warm-up, as for a
/// run) and renders up to `frames` consecutive frames at the comparison's budget; the error
/// of their running mean (MAPE, ε = 0.01) after each frame, against the target: the MAPE of
/// `target`'s first frame. Methods after the target in the list stop at twice the frames
/// they needed to reach it.
#[derive(Clone, Debug)]
pub struct Converge {
    pub frames: u32,
    pub target: String,
}

/// What the comparison loop reports as it goes.
#[derive(Clone, Copy, Debug)]
pub enum Progress<'a> {
    /// A method starts (after its untimed preparation), or with `--interleave` a method's
    /// run starts its untimed warm-up.
    Method(&'a str),
    /// A frame is done.
    Frame,
}

/// Frames the comparison renders in all (for progress bars).
pub fn total_frames(c: &Comparison) -> u64 {
    c.methods.len() as u64
        * (c.runs + c.sweep_steps.unwrap_or(1) - 1 + c.converge.as_ref().map_or(0, |v| v.frames))
            as u64
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
    /// Stateful methods: frames of this size their state rendered before this frame since it
    /// was last reset (untimed warm-up included), i.e. how warm the history was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warm_frames: Option<u32>,
    /// Rays traced in the frame (closest-hit and shadow, all passes).
    pub rays: u64,
    /// The phase times, summed over the frame's passes (ms).
    pub phases: PhaseTimes,
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

pub const TOLERANCE: &str = "equal time: passes continue while the next is predicted to end nearer the budget than stopping \
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
        warm_frames: f.warm_frames,
        rays: f.rays,
        phases: f.phases,
        metrics: m,
    }
}

/// The mean cost of a pass from totals over a method's runs (`None` if it made none).
fn pass_cost(
    time_ms: f64,
    passes: u64,
    rays: u64,
    phases: &PhaseTimes,
    w: u32,
    h: u32,
) -> Option<PassCost> {
    (passes > 0).then(|| {
        let n = passes as f64;
        PassCost {
            ms_per_pass: time_ms / n,
            rays_per_pixel: rays as f64 / (n * f64::from(w) * f64::from(h)),
            phases: phases
                .named()
                .iter()
                .map(|(name, ms)| (name.to_string(), ms / n))
                .collect(),
        }
    })
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

/// A method ready to render its runs: built, prepared for the comparison's image and warmed
/// up (an untimed pass on a small image: thread pool, caches, so that the first timed frame is
/// not charged for start-up; not where `prepare` rendered at this size, since a frame of
/// another size would leave a stateful pass's history cold).
pub fn ready_method(c: &Comparison, scene: &Scene, spec: &MethodSpec) -> Result<Box<dyn Method>> {
    let (w, h) = (c.width, c.height);
    crate::run::check_frame_memory(&spec.pass, w, h, spec.spp, crate::run::available_memory())
        .map_err(|e| anyhow::anyhow!("{spec}: {e}"))?;
    let mut method = spec.build(&c.tracer, &c.cache, c.emitter_samples);
    method
        .prepare(scene, &scene.camera, w, h)
        .map_err(|e| anyhow::anyhow!("{spec}: {e}"))?;
    if !method.warm_after_prepare() {
        method.render_estimate(scene, &scene.camera, w.min(16), h.min(16), u64::MAX, None);
    }
    Ok(method)
}

/// The base seed of a method's frames (its runs' seeds are [`pass_seed`] of it and the run).
pub fn method_seed(c: &Comparison, name: &str) -> u64 {
    c.seed ^ name_hash(name)
}

/// Run `r` of a ready method: restarted (its state reset, untimed warm-up included) and one
/// frame rendered within the comparison's budget.
pub fn run_frame(c: &Comparison, scene: &Scene, method: &mut dyn Method, r: u32) -> Result<Frame> {
    restart_run(c, scene, method, r)?;
    timed_frame(c, scene, method, r)
}

/// The untimed half of [`run_frame`]: the method's state reset and warmed up for run `r`.
fn restart_run(c: &Comparison, scene: &Scene, method: &mut dyn Method, r: u32) -> Result<()> {
    let name = method.name().to_string();
    let seed = pass_seed(method_seed(c, &name), r);
    method
        .restart(scene, &scene.camera, c.width, c.height, r, seed)
        .map_err(|e| anyhow::anyhow!("{name}: {e}"))
}

/// The timed half of [`run_frame`]: run `r`'s frame of a restarted method.
fn timed_frame(c: &Comparison, scene: &Scene, method: &mut dyn Method, r: u32) -> Result<Frame> {
    let seed = pass_seed(method_seed(c, method.name()), r);
    Ok(render_frame(
        method,
        scene,
        &scene.camera,
        &FrameRequest {
            width: c.width,
            height: c.height,
            seed,
            budget: c.budget,
            offsets: c.camera_offsets,
        },
    )?)
}

/// Every run of every method, interleaved (`--interleave`): for each run, every method is
/// restarted (its untimed warm-up), then their timed frames are rendered back to back. Even runs
/// go in the methods' order, odd ones in reverse, restarts and frames alike, so that over a
/// pair of runs each position in the run (first or last timed, timed soonest after its own
/// warm-up) is taken by the methods at the two ends in turn, and a steady drift of the
/// machine's speed does not favour the first methods. Each frame has the seed and state that
/// [`run_frame`] gives it method by method (at equal samples the same frame, bit for bit);
/// only when it is timed changes. `frames[i][r]` is method `i`'s run `r`.
pub fn interleaved_frames(
    c: &Comparison,
    scene: &Scene,
    methods: &mut [Box<dyn Method>],
    progress: &dyn Fn(Progress<'_>),
) -> Result<Vec<Vec<Frame>>> {
    let mut frames: Vec<Vec<Frame>> = methods.iter().map(|_| Vec::new()).collect();
    for r in 0..c.runs {
        let mut order: Vec<usize> = (0..methods.len()).collect();
        if r % 2 == 1 {
            order.reverse();
        }
        for &i in &order {
            progress(Progress::Method(methods[i].name()));
            restart_run(c, scene, methods[i].as_mut(), r)?;
        }
        for &i in &order {
            frames[i].push(timed_frame(c, scene, methods[i].as_mut(), r)?);
            progress(Progress::Frame);
        }
    }
    Ok(frames)
}

/// Run frames rendered elsewhere (the jobs of a study, [`crate::study`]): method `i`'s name
/// and its frame of run `r`, exactly as [`run_frame`] rendered them.
pub trait StoredRuns {
    fn name(&self, method: usize) -> Result<String>;
    fn frame(&self, method: usize, run: u32) -> Result<Frame>;
}

/// Runs the comparison of `c` on `scene` against `reference` (on the current rayon pool),
/// writing every file into `c.out`; returns the report and the path of `report.md`.
pub fn compare(
    c: &Comparison,
    scene: &Scene,
    reference: &Reference,
    progress: &dyn Fn(Progress<'_>),
) -> Result<(Report, PathBuf)> {
    compare_runs(c, scene, reference, None, progress)
}

/// [`compare`], with the run frames from `stored` where given (then without sweeps or
/// frames-to-error measurements, which render from the methods' state).
pub fn compare_runs(
    c: &Comparison,
    scene: &Scene,
    reference: &Reference,
    stored: Option<&dyn StoredRuns>,
    progress: &dyn Fn(Progress<'_>),
) -> Result<(Report, PathBuf)> {
    anyhow::ensure!(
        stored.is_none() || (c.sweep_steps.is_none() && c.converge.is_none()),
        "a comparison from stored runs has no sweep and no frames-to-error measurement"
    );
    check_diagnostics(c.diagnostics, c.runs)?;
    let (w, h) = (c.width, c.height);
    let budget = c.budget;
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
    ref_image.write_png_preview(&c.out.join("reference.png"), c.exposure)?;

    // The pixels that see an emitter: excluded from the errors with `--exclude-emitters`, and
    // the concentration table's share either way.
    let emitter_pixels = emitter_pixels(scene, w, h);
    let emitter_mask = c.exclude_emitters.then_some(&emitter_pixels);
    let steps = c.sweep_steps.unwrap_or(1);
    let mode = match budget {
        Budget::Time(t) => format!("equal time, {} ms per frame", t.as_secs_f64() * 1e3),
        Budget::Passes(n) => format!("equal samples, {n} pass(es) per frame"),
    };
    let mut report = Report::new(format!("{}: {mode}", c.scene_name), w as usize, h as usize);
    if let Some(m) = &emitter_mask {
        let n = m.iter().filter(|x| **x).count();
        report.notes.push(format!(
            "Errors exclude the {n} pixels that see an emitter or touch one that does (their error is set to zero; means are still over all pixels)."
        ));
    }
    report.scene = Some(c.scene_path.clone());
    report.reference = Some(match ref_meta {
        Some(m) => format!("{} ({})", m.describe(), ref_location.display()),
        None => format!("{} (no variance)", ref_location.display()),
    });
    if let Some(v) = &ref_var_view {
        report.notes.push(reference_error_note(
            &ref_view,
            v,
            emitter_mask.map(|m| m.as_slice()),
        ));
    }
    let mut runs = Vec::new();
    let mut plot_series = Vec::new();
    let mut target_error: Option<f64> = None;

    // --interleave: every method built and its runs rendered first (then taken in turn).
    let mut ready: Vec<Option<Box<dyn Method>>> = Vec::new();
    let mut rendered: Vec<std::vec::IntoIter<Frame>> = Vec::new();
    if c.interleave && stored.is_none() {
        let mut built = c
            .methods
            .iter()
            .map(|spec| ready_method(c, scene, spec))
            .collect::<Result<Vec<_>>>()?;
        rendered = interleaved_frames(c, scene, &mut built, progress)?
            .into_iter()
            .map(Vec::into_iter)
            .collect();
        ready = built.into_iter().map(Some).collect();
    }

    for (index, spec) in c.methods.iter().enumerate() {
        let mut method = match (stored, ready.get_mut(index).and_then(Option::take)) {
            (None, Some(m)) => Some(m),
            (None, None) => Some(ready_method(c, scene, spec)?),
            (Some(_), _) => None,
        };
        let mut pre_rendered = rendered.get_mut(index);
        let name = match (&method, stored) {
            (Some(m), _) => m.name().to_string(),
            (None, Some(s)) => s.name(index)?,
            (None, None) => unreachable!("a method is built where no runs are stored"),
        };
        progress(Progress::Method(&name));

        // The measure of a frame: the excluded pixels set to the reference, its errors (and
        // HDR-FLIP map) against the reference.
        let evaluate = |mut frame: Frame| {
            exclude(
                &mut frame.image,
                emitter_mask.map(|m| m.as_slice()),
                ref_image,
            );
            let (m, flip_map) = errors(&frame.image, &ref_view, c.flip, &name)?;
            let spread = concentration(
                &ImageView::of_scene_image(&name, &frame.image)?,
                &ref_view,
                Some(&emitter_pixels),
            )?;
            anyhow::Ok((frame, m, flip_map, spread))
        };
        // One measured frame, rendered within its budget.
        let measure = |method: &mut dyn Method, seed: u64, budget: Budget| {
            let frame = render_frame(
                method,
                scene,
                &scene.camera,
                &FrameRequest {
                    width: w,
                    height: h,
                    seed,
                    budget,
                    offsets: c.camera_offsets,
                },
            )?;
            evaluate(frame)
        };
        let base = method_seed(c, &name);
        let mut acc = BiasVarianceAccumulator::new(w as usize, h as usize);
        let mut metrics = Vec::new();
        let mut spreads = Vec::new();
        let (mut time_ms, mut spp) = (0.0, 0.0);
        let (mut passes, mut rays) = (0u64, 0u64);
        let mut phases = PhaseTimes::default();
        let mut first: Option<(Frame, ErrorMetrics)> = None;
        for r in 0..c.runs {
            let seed = pass_seed(base, r);
            let frame = match (&mut method, stored, pre_rendered.as_mut()) {
                (_, _, Some(frames)) => frames.next().context("an interleaved run per run")?,
                (Some(m), _, None) => run_frame(c, scene, m.as_mut(), r)?,
                (None, Some(s), None) => s.frame(index, r)?,
                (None, None, None) => {
                    unreachable!("a method is built where no runs are stored")
                }
            };
            let (frame, m, flip_map, spread) = evaluate(frame)?;
            spreads.push(spread);
            if c.runs >= 2 {
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
            passes += u64::from(frame.passes);
            rays += frame.rays;
            phases.add(&frame.phases);
            if r == 0 {
                write_images(c, &name, &frame.image, &ref_view, flip_map.as_ref())?;
                first = Some((frame, m));
            }
            if pre_rendered.is_none() {
                progress(Progress::Frame);
            }
        }
        if c.diagnostics {
            write_diagnostics(
                c,
                &name,
                &acc,
                &ref_view,
                ref_var_view.as_ref(),
                method.as_deref(),
            )?;
        }
        let (first_frame, first_metrics) = first.expect("at least one run");
        let n = c.runs as f64;
        report.rows.push(ReportRow {
            method: name.clone(),
            time_per_frame_ms: time_ms / n,
            samples_per_pixel: spp / n,
            metrics: mean_metrics(&metrics),
            bias_variance: if c.runs >= 2 {
                Some(acc.finish(&ref_view, ref_var_view.as_ref())?)
            } else {
                None
            },
            temporal: None,
            concentration: mean_concentration(&spreads),
            cost: pass_cost(time_ms, passes, rays, &phases, w, h),
        });

        // Plot points: the sweep (run 0 is its first budget), else every run.
        let mut series = SweepSeries {
            method: name.clone(),
            points: Vec::new(),
        };
        if c.sweep_steps.is_some() {
            series.points.push(SweepPoint {
                time_ms: first_frame.elapsed.as_secs_f64() * 1e3,
                samples_per_pixel: first_frame.samples_per_pixel as f64,
                metrics: first_metrics,
            });
            let method = method
                .as_mut()
                .context("a sweep renders from the method itself, not stored runs")?;
            for step in 1..steps {
                let seed = Stream::SweepStep(step).seed(base);
                let b = scaled_budget(budget, step);
                let (frame, m, _, _) = measure(method.as_mut(), seed, b)?;
                runs.push(record(&name, None, Some(step), seed, b, &frame, m));
                series.points.push(SweepPoint {
                    time_ms: frame.elapsed.as_secs_f64() * 1e3,
                    samples_per_pixel: frame.samples_per_pixel as f64,
                    metrics: m,
                });
                progress(Progress::Frame);
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

        if let Some(cv) = &c.converge {
            let method = method
                .as_mut()
                .context("frames to error render from the method itself, not stored runs")?;
            let warm = Instant::now();
            method
                .restart(
                    scene,
                    &scene.camera,
                    w,
                    h,
                    c.runs,
                    Stream::ConvergeRestart.seed(base),
                )
                .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
            let warm_up_ms = warm.elapsed().as_secs_f64() * 1e3;
            // f64 sums: thousands of frames.
            let mut sum = vec![glam::DVec3::ZERO; (w * h) as usize];
            let mut curve = ConvergenceSeries {
                method: name.clone(),
                points: Vec::new(),
                warm_up_ms,
            };
            let mut time_ms = 0.0;
            let mut stop_at = cv.frames;
            for f in 1..=cv.frames {
                let seed = Stream::ConvergeFrame(f).seed(base);
                let (frame, _, _, _) = measure(method.as_mut(), seed, budget)?;
                time_ms += frame.elapsed.as_secs_f64() * 1e3;
                for (s, x) in sum.iter_mut().zip(&frame.image.data) {
                    *s += x.as_dvec3();
                }
                let mean = Image::from_data(
                    w as usize,
                    h as usize,
                    sum.iter().map(|s| (*s / f as f64).as_vec3()).collect(),
                )
                .expect("the frame's size");
                let (m, _) = errors(&mean, &ref_view, false, &name)?;
                curve.points.push(ConvergencePoint {
                    frames: f,
                    time_ms,
                    metrics: m,
                });
                progress(Progress::Frame);
                if f == 1 && name == cv.target {
                    target_error = Some(m.mape);
                }
                if stop_at == cv.frames
                    && let Some(t) = target_error
                    && m.mape <= t
                {
                    stop_at = (2 * f).min(cv.frames);
                }
                if f >= stop_at {
                    break;
                }
            }
            report.convergence.push(curve);
        }
    }
    if let Some(cv) = &c.converge {
        // A target without a usable first-frame error (an exact frame: MAPE 0) leaves the
        // table out, not the report.
        match frames_to_error_table(&report.convergence, Metric::Mape, &cv.target) {
            Ok(table) => report.frames_to_error.push(table),
            Err(e) => report.notes.push(format!(
                "No frames-to-error table (target {}): {e}.",
                cv.target
            )),
        }
        let title = format!(
            "MAPE of the running mean against accumulated time: {}, {}x{}",
            c.scene_name, w, h
        );
        let curves: Vec<SweepSeries> = report.convergence.iter().map(|s| s.as_sweep()).collect();
        plot_error_vs_time(
            &curves,
            Metric::Mape,
            &title,
            &c.out.join("frames-to-error.png"),
            &c.out.join("frames-to-error.svg"),
        )
        .context("cannot draw the frames-to-error plot")?;
    }

    if c.sweep_steps.is_some() {
        let baseline = &report.sweeps[0];
        let last = baseline.curve(Metric::RelMse).last().map(|p| p.0);
        if let Some(t) = last {
            let table =
                time_to_error_table(&report.sweeps, Metric::RelMse, &baseline.method.clone(), t)?;
            report.time_to_error.push(table);
        }
    }
    if c.diagnostics {
        report.notes.push(
            "Diagnostics: METHOD-errors.exr holds each pixel's error over the runs, the channels \
             averaged: red the expected squared error of one run against the true image (bias² + \
             variance: the reference's own noise removed, so its mean is a little below the \
             table's MSE), green bias² (corrected for the \
             runs' and the reference's noise, so slightly negative where unbiased), blue the \
             variance of one run; METHOD-view-NAME.exr the pass's state after its last frame \
             (reservoir-m: the final reservoirs' mean M; reservoir-contribution: their mean W·p̂, \
             where fireflies start; probes; vpls)."
                .into(),
        );
    }
    let invalid: u64 = runs.iter().map(|r| r.invalid_samples).sum();
    report.notes.push(format!(
        "Budget: {mode}; a pass is one estimate at the method's stated spp. Errors are means over {} run(s) with \
         distinct seeds (per-run values in runs.json); images show run 0.",
        c.runs
    ));
    if let Budget::Time(_) = budget {
        report
            .notes
            .push(format!("Equal-time tolerance: {TOLERANCE}."));
    }
    if c.camera_offsets == CameraOffsets::Sobol {
        report.notes.push(
            "Camera offsets: sobol (each run's passes take consecutive points of one \
             Owen-scrambled Sobol sequence per pixel; --converge frames and sweep steps each \
             start a sequence of their own)."
                .into(),
        );
    }
    if c.interleave && stored.is_none() {
        report.notes.push(
            "Runs interleaved: for each run every method was restarted (its untimed warm-up), \
             then their timed frames rendered back to back, in the methods' order on even runs \
             and in reverse on odd ones (sweeps and frames to error are not interleaved)."
                .into(),
        );
    }
    if c.sweep_steps.is_some() {
        report.notes.push(format!(
            "Sweep: each method at the budget × 1, 2, …, {} (one frame each; the first is run 0).",
            1u64 << (steps - 1)
        ));
    }
    if invalid > 0 {
        report.notes.push(format!(
            "{invalid} samples were NaN or infinite and counted as black."
        ));
    }

    let title = format!(
        "relMSE against time per frame: {}, {}x{}",
        c.scene_name, w, h
    );
    plot_error_vs_time(
        &plot_series,
        Metric::RelMse,
        &title,
        &c.out.join("error-vs-time.png"),
        &c.out.join("error-vs-time.svg"),
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
    nrc_eval::atomic::atomic_write(&c.out.join("runs.json"), json.as_bytes())?;
    let files = write_report(&c.out, &report)?;
    Ok((report, files.markdown))
}

/// The reference's own expected error, from its variance of the mean σ² per pixel channel (over
/// all pixels, the excluded ones at zero as in the metrics): MSE ≈ mean σ², relMSE ≈ mean σ²/(y² + ε), and MAPE ≈ mean
/// σ·√(2/π)/(y + ε) (the mean absolute deviation of a normal error).
fn reference_error_note(
    reference: &ImageView<'_>,
    variance: &ImageView<'_>,
    excluded: Option<&[bool]>,
) -> String {
    let (mut mse, mut rel, mut mape, mut n) = (0.0, 0.0, 0.0, 0.0f64);
    for (i, (y, v)) in reference.pixels().iter().zip(variance.pixels()).enumerate() {
        if excluded.is_some_and(|m| m[i]) {
            n += 3.0; // zero error, as in the metrics
            continue;
        }
        for c in 0..3 {
            let (y, v) = (y[c] as f64, (v[c] as f64).max(0.0));
            mse += v;
            rel += v / (y * y + REL_MSE_EPSILON);
            mape += v.sqrt() * (2.0 / std::f64::consts::PI).sqrt() / (y.abs() + MAPE_EPSILON);
            n += 1.0;
        }
    }
    let n = n.max(1.0);
    format!(
        "The reference's own expected error (from its variance of the mean): MSE {}, relMSE {}, MAPE {}.",
        nrc_eval::report::fmt_num(mse / n),
        nrc_eval::report::fmt_num(rel / n),
        nrc_eval::report::fmt_num(mape / n)
    )
}

/// Whether `--diagnostics` can be written with `runs` runs (a pixel's bias and variance come
/// from its runs: two at least).
pub fn check_diagnostics(diagnostics: bool, runs: u32) -> Result<()> {
    anyhow::ensure!(
        !diagnostics || runs >= 2,
        "--diagnostics needs --runs 2 or more (a pixel's bias and variance come from its runs)"
    );
    Ok(())
}

/// `--diagnostics`: the per-pixel bias and variance of `name`'s runs and its pass's views.
fn write_diagnostics(
    c: &Comparison,
    name: &str,
    runs: &BiasVarianceAccumulator,
    reference: &ImageView<'_>,
    reference_variance: Option<&ImageView<'_>>,
    method: Option<&dyn Method>,
) -> Result<()> {
    let px = runs.per_pixel(reference, reference_variance)?;
    let data = px
        .pixels
        .iter()
        .map(|p| glam::Vec3::from_array(*p))
        .collect();
    let image = Image::from_data(px.width, px.height, data).context("the error image's size")?;
    image.write_exr(&c.out.join(format!("{name}-errors.exr")))?;
    for view in method.map(|m| m.debug_views()).unwrap_or_default() {
        view.image
            .write_exr(&c.out.join(format!("{name}-view-{}.exr", view.name)))?;
    }
    Ok(())
}

/// The rendered frame (EXR and PNG preview) and its false-colour error maps.
fn write_images(
    c: &Comparison,
    name: &str,
    image: &Image,
    reference: &ImageView<'_>,
    flip: Option<&ScalarImage>,
) -> Result<()> {
    image.write_exr(&c.out.join(format!("{name}.exr")))?;
    image.write_png_preview(&c.out.join(format!("{name}.png")), c.exposure)?;
    let x = ImageView::of_scene_image(name, image)?;
    write_false_color_png(
        &c.out.join(format!("{name}-relmse.png")),
        &rel_mse_map(&x, reference, REL_MSE_EPSILON)?,
        ColorMap::Viridis,
        Scale::Log {
            min: 1e-4,
            max: 10.0,
        },
    )?;
    if let Some(map) = flip {
        write_false_color_png(
            &c.out.join(format!("{name}-flip.png")),
            map,
            ColorMap::Magma,
            Scale::Linear { min: 0.0, max: 1.0 },
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use nrc_cache::{CacheConfig, CacheDevice};
    use nrc_render::PixelSequence;
    use nrc_scene::Camera;

    use super::*;
    use crate::budget::Estimate;
    use crate::budget::tests::{constant_estimate, empty_scene};
    use crate::error::HarnessError;

    /// A method that logs its restarts and passes (`"restart NAME RUN"`, `"pass NAME"`) and
    /// renders a constant image.
    struct Logged {
        name: String,
        /// Its place in the list: its frames are worth `10 · index + run`.
        index: u32,
        run: u32,
        log: Arc<Mutex<Vec<String>>>,
    }

    impl Method for Logged {
        fn name(&self) -> &str {
            &self.name
        }
        fn samples_per_pass(&self) -> u32 {
            1
        }
        fn restart(
            &mut self,
            _: &Scene,
            _: &Camera,
            _: u32,
            _: u32,
            run: u32,
            _: u64,
        ) -> Result<(), HarnessError> {
            let line = format!("restart {} {run}", self.name);
            self.log.lock().unwrap().push(line);
            self.run = run;
            Ok(())
        }
        fn render_estimate(
            &mut self,
            _: &Scene,
            _: &Camera,
            width: u32,
            height: u32,
            _: u64,
            _: Option<PixelSequence>,
        ) -> Estimate {
            self.log.lock().unwrap().push(format!("pass {}", self.name));
            constant_estimate(width, height, (10 * self.index + self.run) as f32)
        }
    }

    fn comparison(runs: u32) -> Comparison {
        Comparison {
            methods: Vec::new(),
            budget: Budget::Passes(1),
            width: 2,
            height: 2,
            runs,
            sweep_steps: None,
            flip: false,
            out: PathBuf::new(),
            seed: 1,
            exposure: 0.0,
            exclude_emitters: false,
            diagnostics: false,
            emitter_samples: 0,
            camera_offsets: CameraOffsets::Independent,
            interleave: true,
            tracer: PathTracer::default(),
            cache: CacheMethodSettings::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu),
            converge: None,
            scene_name: String::new(),
            scene_path: String::new(),
        }
    }

    /// Each run restarts every method before any of them renders, then renders them back to
    /// back, in turn forwards and backwards (restarts too); method i's frames are its runs', in
    /// run order.
    /// (Method by method, [`run_frame`] restarts and renders each in one go: the control.)
    #[test]
    fn interleaved_runs_restart_all_then_time_all_in_alternating_order() {
        let scene = empty_scene();
        let log = Arc::new(Mutex::new(Vec::new()));
        let mut methods: Vec<Box<dyn Method>> = ["a", "b", "c"]
            .iter()
            .enumerate()
            .map(|(index, n)| {
                Box::new(Logged {
                    name: n.to_string(),
                    index: index as u32,
                    run: 0,
                    log: log.clone(),
                }) as Box<dyn Method>
            })
            .collect();
        let c = comparison(3);
        let frames = interleaved_frames(&c, &scene, &mut methods, &|_| {}).unwrap();
        // Method i's run r is its frame worth 10 i + r.
        assert_eq!(frames.len(), 3);
        for (i, f) in frames.iter().enumerate() {
            let values: Vec<f32> = f.iter().map(|x| x.image.data[0].x).collect();
            let expected: Vec<f32> = (0..3).map(|r| (10 * i + r) as f32).collect();
            assert_eq!(values, expected, "method {i}");
        }
        let expected: Vec<String> = [
            "restart a 0",
            "restart b 0",
            "restart c 0",
            "pass a",
            "pass b",
            "pass c",
            "restart c 1",
            "restart b 1",
            "restart a 1",
            "pass c",
            "pass b",
            "pass a",
            "restart a 2",
            "restart b 2",
            "restart c 2",
            "pass a",
            "pass b",
            "pass c",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        assert_eq!(*log.lock().unwrap(), expected);

        // The control: method by method, each run restarts and renders one method at a time.
        log.lock().unwrap().clear();
        for m in methods.iter_mut() {
            run_frame(&c, &scene, m.as_mut(), 0).unwrap();
        }
        assert_ne!(log.lock().unwrap()[..6], expected[..6]);
    }
}
