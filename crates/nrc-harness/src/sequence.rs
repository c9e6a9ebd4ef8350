//! Comparisons over animated sequences (`nrc compare --sequence FRAMES`): every method renders
//! the same frames of a scene that moves (glTF node animation sampled at `frame / fps`
//! seconds) seen by a camera that may move (a camera path), each frame against its own
//! path-traced reference, with the temporal measures of Hedman et al. §5.2 (`|E|`, `|E′|` of
//! the tone-mapped luminance of tracked pixels, the tone map fixed from the first reference;
//! see `nrc_eval::temporal`).
//!
//! Fairness: each method is prepared and restarted (untimed) on the first frame's scene, then
//! renders the frames in order at the comparison's budget, its state carried from frame to
//! frame as it would be while the user watches (a cache trains inside each timed frame). The
//! scene's posing (vertices moved, acceleration structure and light sampler built afresh) is
//! the same work for every method: it is done once per frame before the methods take their
//! turns at that frame (so only one posed scene is held at a time), and reported on its own
//! line, not charged to them.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use nrc_eval::metrics::{MAPE_EPSILON, REL_MSE_EPSILON, mape, rel_mse};
use nrc_eval::plot::plot_series;
use nrc_eval::{ErrorMetrics, ImageView, SweepPoint, SweepSeries, TemporalAccumulator};
use nrc_eval::{Metric, TrackedLuminance};
use nrc_render::sampler::Stream;
use nrc_render::{RenderSettings, render};
use nrc_scene::{Camera, Image, Scene};

use crate::budget::{FrameRequest, render_frame};
use crate::compare::Comparison;

/// What a sequence renders.
#[derive(Clone, Debug)]
pub struct Sequence {
    pub frames: u32,
    /// Frames per second of scene time.
    pub fps: f32,
    /// Samples per pixel of each frame's reference.
    pub reference_spp: u32,
    /// Pixels tracked by the temporal measure (0: all).
    pub tracked: usize,
    /// A camera path (JSON keyframes, as for `nrc train --camera-path`); without one the
    /// scene's camera at each frame's time (animated when its node is).
    pub camera_path: Option<PathBuf>,
}

/// One method's figures over the sequence.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SequenceRow {
    pub method: String,
    pub ms_per_frame: f64,
    /// `|E|` and `|E′|` of the tracked tone-mapped luminance.
    pub mean_abs_error: f64,
    pub mean_abs_error_change: f64,
    /// Per frame: MAPE and relMSE of the whole image against its reference, and `|E_t|`.
    pub mape: Vec<f64>,
    pub rel_mse: Vec<f64>,
    pub tracked_error: Vec<f64>,
    pub time_ms: Vec<f64>,
}

/// The sequence's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SequenceReport {
    pub scene: String,
    pub frames: u32,
    pub fps: f32,
    pub width: u32,
    pub height: u32,
    pub reference_spp: u32,
    pub tracked_pixels: usize,
    /// Mean milliseconds to pose the scene and build its acceleration structure and light
    /// sampler, per frame.
    pub pose_ms: f64,
    /// Whether anything in the scene moves.
    pub animated: bool,
    pub rows: Vec<SequenceRow>,
}

/// Runs the sequence comparison for the methods and budget of `c` on the scene `pose(t)` gives
/// at time `t` seconds (`animated`: whether it moves); writes `sequence.md`, `sequence.json`
/// and `sequence-mape.png` into `c.out`.
pub fn compare_sequence(
    c: &Comparison,
    seq: &Sequence,
    (pose, animated): (&dyn Fn(f32) -> Result<Scene>, bool),
    progress: &dyn Fn(&str),
) -> Result<SequenceReport> {
    anyhow::ensure!(
        (2..=1_000_000).contains(&seq.frames),
        "--sequence needs between 2 and 1000000 frames, got {}",
        seq.frames
    );
    anyhow::ensure!(
        seq.fps.is_finite() && seq.fps > 0.0,
        "--fps must be positive, got {}",
        seq.fps
    );
    anyhow::ensure!(
        seq.reference_spp >= 1,
        "the sequence's references need at least 1 sample per pixel"
    );
    let (w, h) = (c.width, c.height);
    // Frame by frame: one posed scene at a time (a long sequence of a big scene would not fit
    // in memory as a list of scenes); each method keeps its own state across the frames.
    let mut pose_time = std::time::Duration::ZERO;
    let mut posed = |f: u32| -> Result<Scene> {
        let t0 = Instant::now();
        let s = pose(f as f32 / seq.fps)
            .with_context(|| format!("posing {} at frame {f}", c.scene_path))?;
        pose_time += t0.elapsed();
        Ok(s)
    };
    let first = posed(0)?;
    let cameras: Vec<Camera> = match &seq.camera_path {
        Some(p) => crate::run::camera_path(Some(p), &first.camera, seq.frames)?,
        None => Vec::new(),
    };
    let camera_at = |f: usize, scene: &Scene| cameras.get(f).copied().unwrap_or(scene.camera);
    progress(&format!(
        "sequence: {} frames at {} fps, references at {} spp",
        seq.frames, seq.fps, seq.reference_spp
    ));
    struct Run {
        method: Box<dyn crate::budget::Method>,
        acc: TemporalAccumulator,
        row: SequenceRow,
    }
    let mut runs = Vec::new();
    for spec in &c.methods {
        let mut method = spec.build(&c.tracer, &c.cache, c.emitter_samples);
        let cam = camera_at(0, &first);
        method
            .prepare(&first, &cam, w, h)
            .map_err(|e| anyhow::anyhow!("{spec}: {e}"))?;
        let name = method.name().to_string();
        progress(&name);
        method
            .restart(&first, &cam, w, h, 0, c.seed)
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        runs.push(Run {
            method,
            acc: TemporalAccumulator::new(),
            row: SequenceRow {
                method: name,
                ms_per_frame: 0.0,
                mean_abs_error: 0.0,
                mean_abs_error_change: 0.0,
                mape: Vec::new(),
                rel_mse: Vec::new(),
                tracked_error: Vec::new(),
                time_ms: Vec::new(),
            },
        });
    }
    let mut tracker: Option<TrackedLuminance> = None;
    let mut scene = first;
    for f in 0..seq.frames as usize {
        if f > 0 {
            scene = posed(f as u32)?;
        }
        let cam = camera_at(f, &scene);
        let reference: Image = render(
            &scene,
            &cam,
            &c.tracer,
            &RenderSettings {
                width: w,
                height: h,
                spp: seq.reference_spp,
                seed: 0x5e9 + f as u64,
                variance: false,
                sequence: None,
            },
            &|_| {},
        )
        .mean;
        let ref_view = ImageView::of_scene_image("reference", &reference)?;
        let tracker =
            tracker.get_or_insert_with(|| TrackedLuminance::from_reference(&ref_view, seq.tracked));
        let tracked_ref = tracker.apply(&ref_view);
        for run in &mut runs {
            let frame = render_frame(
                run.method.as_mut(),
                &scene,
                &cam,
                &FrameRequest {
                    width: w,
                    height: h,
                    seed: Stream::SequenceFrame(f as u32).seed(c.seed),
                    budget: c.budget,
                    offsets: c.camera_offsets,
                },
            )?;
            let view = ImageView::of_scene_image(&run.row.method, &frame.image)?;
            run.row.mape.push(mape(&view, &ref_view, MAPE_EPSILON)?);
            run.row
                .rel_mse
                .push(rel_mse(&view, &ref_view, REL_MSE_EPSILON)?);
            run.row.time_ms.push(frame.elapsed.as_secs_f64() * 1e3);
            let tracked = tracker.apply(&view);
            run.acc.push(
                &ImageView::new(&run.row.method, tracked.len(), 1, &tracked)?,
                Some(&ImageView::new(
                    "reference",
                    tracked.len(),
                    1,
                    &tracked_ref,
                )?),
            )?;
        }
    }
    let pose_ms = pose_time.as_secs_f64() * 1e3 / seq.frames as f64;
    let tracked_pixels = tracker.map_or(0, |t| t.pixels.len());
    let mut rows = Vec::new();
    for mut run in runs {
        let stats = run.acc.finish()?;
        run.row.mean_abs_error = stats.mean_abs_error.unwrap_or(f64::NAN);
        run.row.mean_abs_error_change = stats.mean_abs_error_change.unwrap_or(f64::NAN);
        // Per-pixel-and-channel means: the three channels hold the same luminance.
        run.row.tracked_error = stats.per_frame_error;
        run.row.ms_per_frame = run.row.time_ms.iter().sum::<f64>() / run.row.time_ms.len() as f64;
        rows.push(run.row);
    }
    let report = SequenceReport {
        scene: c.scene_path.clone(),
        frames: seq.frames,
        fps: seq.fps,
        width: w,
        height: h,
        reference_spp: seq.reference_spp,
        tracked_pixels,
        pose_ms,
        animated,
        rows,
    };
    write(&report, c)?;
    Ok(report)
}

/// `sequence.md`, `sequence.json` and the per-frame MAPE plot.
fn write(r: &SequenceReport, c: &Comparison) -> Result<()> {
    let mut md = format!(
        "# {}: {} frames at {} fps, {}×{}\n\n",
        c.scene_name, r.frames, r.fps, r.width, r.height
    );
    md += &format!(
        "Per-frame references: path tracer at {} spp. Temporal measures (Hedman et al. §5.2) on the tone-mapped \
         luminance of {} tracked pixels (Reinhard, key 0.18 from the first reference): |E| the mean absolute error, \
         |E′| the mean absolute change of the error between frames. The scene {} posed and rebuilt (acceleration \
         structure, light sampler) in {:.2} ms per frame, the same for every method and not in their times.\n\n",
        r.reference_spp,
        r.tracked_pixels,
        if r.animated {
            "is"
        } else {
            "(not animated) is"
        },
        r.pose_ms
    );
    md += "| method | ms per frame | \\|E\\| | \\|E′\\| | mean MAPE | mean relMSE |\n|---|---:|---:|---:|---:|---:|\n";
    for row in &r.rows {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        md += &format!(
            "| {} | {:.1} | {:.5} | {:.5} | {:.4} | {:.4} |\n",
            row.method,
            row.ms_per_frame,
            row.mean_abs_error,
            row.mean_abs_error_change,
            mean(&row.mape),
            mean(&row.rel_mse)
        );
    }
    md += "\nPer-frame errors are in `sequence.json`; `sequence-mape.png` plots each frame's MAPE against its frame number.\n";
    nrc_scene::image::write_atomic(&c.out.join("sequence.md"), md.as_bytes())?;
    let json = serde_json::to_string_pretty(r)?;
    nrc_scene::image::write_atomic(&c.out.join("sequence.json"), json.as_bytes())?;
    let series: Vec<SweepSeries> = r
        .rows
        .iter()
        .map(|row| SweepSeries {
            method: row.method.clone(),
            points: row
                .mape
                .iter()
                .enumerate()
                .map(|(f, m)| SweepPoint {
                    time_ms: (f + 1) as f64,
                    samples_per_pixel: 0.0,
                    metrics: ErrorMetrics {
                        mse: f64::NAN,
                        rel_mse: row.rel_mse[f],
                        mape: *m,
                        flip: None,
                    },
                })
                .collect(),
        })
        .collect();
    plot_series(
        &series,
        Metric::Mape,
        (&format!("{}: MAPE per frame", c.scene_name), "frame"),
        &c.out.join("sequence-mape.png"),
        &c.out.join("sequence-mape.svg"),
    )?;
    Ok(())
}
