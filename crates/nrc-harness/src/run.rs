//! A run of the online loop as a library: the camera of each frame (camera paths), the frame
//! loop with its outputs (frames, statistics), the snapshot's scene check before rendering
//! from it, and the render loop of a pass over a camera path. The CLI's `nrc train` and `nrc
//! render` parse their arguments into these.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use nrc_render::passes::{
    self, CacheTerminatedSettings, FrameInput, PassOutput, PassSpec, PathTracedPass,
    PathTracedSettings, RenderPass, path_traced::Progress,
};
use nrc_render::{LightStrategy, PathTracer, Termination, ZeroSource};
use nrc_scene::{Camera, Scene};

use crate::budget::CameraOffsets;
use nrc_train::schedule::Phase;
use nrc_train::{FrameStats, OnlineTrainer, QueryMaker};

/// One keyframe of a camera path.
#[derive(serde::Deserialize, serde::Serialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    pub position: [f32; 3],
    pub target: [f32; 3],
    pub up: Option<[f32; 3]>,
    pub fov_y: Option<f32>,
}

/// The camera of each frame.
pub fn camera_path(path: Option<&Path>, base: &Camera, frames: u32) -> Result<Vec<Camera>> {
    let Some(path) = path else {
        return Ok(vec![*base; frames as usize]);
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read camera path {}", path.display()))?;
    let keys: Vec<Keyframe> =
        serde_json::from_str(&text).with_context(|| format!("camera path {}", path.display()))?;
    if keys.is_empty() {
        bail!("camera path {}: no keyframes", path.display());
    }
    let v = |a: [f32; 3]| Vec3::from_array(a);
    (0..frames)
        .map(|f| {
            let t = if frames > 1 {
                f as f32 / (frames - 1) as f32
            } else {
                0.0
            } * (keys.len() - 1) as f32;
            let i = (t.floor() as usize).min(keys.len() - 1);
            let j = (i + 1).min(keys.len() - 1);
            let s = t - i as f32;
            let (a, b) = (&keys[i], &keys[j]);
            let up = v(a.up.unwrap_or([0.0, 1.0, 0.0])).lerp(v(b.up.unwrap_or([0.0, 1.0, 0.0])), s);
            let fov = a.fov_y.unwrap_or(base.fov_y.to_degrees()) * (1.0 - s)
                + b.fov_y.unwrap_or(base.fov_y.to_degrees()) * s;
            Camera::look_at(
                v(a.position).lerp(v(b.position), s),
                v(a.target).lerp(v(b.target), s),
                up,
                fov,
            )
            .map_err(|e| anyhow::anyhow!("camera path {}, frame {f}: {e}", path.display()))
        })
        .collect()
}

/// Writes the statistics as CSV or JSON (atomically).
pub fn write_stats(path: &Path, stats: &[FrameStats]) -> Result<()> {
    let bytes = if path.extension().is_some_and(|e| e == "json") {
        serde_json::to_vec_pretty(stats)?
    } else {
        let mut s = String::from(
            "frame,produce_ms,train_ms,infer_ms,records,used,dropped_nonfinite,dropped_absurd,steps,loss,target_mean,change_z,phase,spend_ms,learning_rate,clamped,clip_gain,paths,rays,cache_queries,invalid_samples,producer_dropped,producer_skipped\n",
        );
        for f in stats {
            s.push_str(&format!(
                "{},{:.3},{:.3},{:.3},{},{},{},{},{},{},{},{},{},{},{:e},{},{},{},{},{},{},{},{}\n",
                f.frame,
                f.produce_ms,
                f.train_ms,
                f.infer_ms,
                f.records,
                f.used,
                f.dropped_nonfinite,
                f.dropped_absurd,
                f.steps,
                f.loss,
                f.target_mean,
                f.change_z,
                f.phase.name(),
                f.spend_ms,
                f.learning_rate,
                f.clamped,
                f.clip_gain,
                f.producer.paths,
                f.producer.rays + f.inference.rays,
                f.inference.queries,
                f.inference.invalid_samples,
                f.producer.dropped,
                f.producer.skipped
            ));
        }
        s.into_bytes()
    };
    nrc_eval::atomic::atomic_write(path, &bytes)
        .with_context(|| format!("cannot write statistics {}", path.display()))
}

/// Where a training run writes its frames.
#[derive(Clone, Debug)]
pub struct FrameOutput {
    /// Folder of `frame-NNNNN.exr` (exists).
    pub dir: PathBuf,
    /// Every N-th frame (and the last).
    pub every: u32,
}

/// The scene of each frame of a run: one that stands still, or one posed at `frame / fps`
/// seconds (`pose` gives the scene at a time).
pub enum Frames<'a> {
    Static(&'a Scene),
    Animated {
        pose: &'a (dyn Fn(f32) -> Result<Scene> + Sync),
        fps: f32,
    },
}

/// Runs the online loop over `cameras` (one frame each) at `width × height`, rendering every
/// frame and writing those `frames` asks for; `progress` sees each frame's statistics. An
/// animated scene is posed afresh each frame (the cache trains while it moves).
pub fn train(
    trainer: &mut OnlineTrainer,
    scenes: &Frames<'_>,
    cameras: &[Camera],
    (width, height): (u32, u32),
    frames: Option<&FrameOutput>,
    progress: &dyn Fn(&FrameStats),
) -> Result<Vec<FrameStats>> {
    let mut all = Vec::with_capacity(cameras.len());
    for (f, camera) in cameras.iter().enumerate() {
        let posed;
        let scene = match scenes {
            Frames::Static(s) => *s,
            Frames::Animated { pose, fps } => {
                posed = pose(f as f32 / fps)?;
                &posed
            }
        };
        let (stats, out) = trainer.frame(scene, camera, width, height, true)?;
        let last = f + 1 == cameras.len();
        if let (Some(o), Some(out)) = (frames, &out)
            && ((f as u32).is_multiple_of(o.every.max(1)) || last)
        {
            out.image
                .write_exr(&o.dir.join(format!("frame-{f:05}.exr")))?;
        }
        progress(&stats);
        all.push(stats);
    }
    Ok(all)
}

/// Whether `cache` was trained on `scene` (loaded from `scene_path`): its content hash and box
/// against the scene's. `Err` names the mismatch.
pub fn check_snapshot_scene(
    cache: &nrc_cache::Cache,
    scene: &Scene,
    scene_path: &Path,
) -> Result<std::result::Result<(), String>> {
    let content = crate::reference::scene_content_hash(scene_path)?;
    let scene_box = QueryMaker::new(&scene.bounds()).scene_box;
    Ok(nrc_cache::check_scene(
        cache.scene_content(),
        cache.scene_box(),
        &content,
        scene_box,
    ))
}

/// What `nrc render` renders: a pass over the frames of a camera path, its queries answered by
/// a cache (a snapshot) or by nothing.
pub struct RenderJob<'a> {
    pub scene: &'a Scene,
    pub pass: &'a PassSpec,
    /// Depth limit and Russian roulette (the light strategy is the pass's own).
    pub tracer: PathTracer,
    pub cache: Option<&'a nrc_cache::Cache>,
    /// The camera of each frame; the last frame is the one returned.
    pub cameras: &'a [Camera],
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u64,
    /// Extra camera rays at the outline of emitters ([`nrc_render::emitters::supersample`]).
    pub emitter_samples: u32,
    /// Where the camera rays lie in their pixels: with [`CameraOffsets::Sobol`] each frame's
    /// samples are the first points of its pixels' sequences, seeded by the frame's seed.
    pub camera_offsets: CameraOffsets,
    /// The path tracer's per-pixel variance (pt passes only).
    pub variance: bool,
    /// Told of the pixels done as the path tracer's tiles finish (pt passes only).
    pub progress: Option<Progress>,
}

/// A rendered job: the last frame, the pass's name and the wall time per frame.
pub struct Rendered {
    pub output: PassOutput,
    pub pass: String,
    pub seconds_per_frame: f64,
}

/// Renders every frame of `job` on the current rayon pool. One frame is seeded by the seed
/// itself (the image of a single render); frame `f` of several by `pass_seed(seed, f)`, so
/// that stateful passes reuse across independent frames.
pub fn render(job: RenderJob) -> Result<Rendered> {
    if job.variance && job.pass.get::<PathTracedSettings>().is_none() {
        bail!("--variance is only available with the pt passes");
    }
    if job.variance && job.emitter_samples > 0 {
        bail!(
            "--variance is the variance of the pass's own samples, which --emitter-samples \
             changes: give one of them"
        );
    }
    if job.variance && job.camera_offsets == CameraOffsets::Sobol {
        bail!(
            "--variance is the variance of one independent sample, which stratified \
             --camera-offsets sobol samples are not: give one of them"
        );
    }
    check_frame_memory(job.pass, job.width, job.height, job.spp, available_memory())?;
    let mut pass: Box<dyn RenderPass> = match job.pass.get::<PathTracedSettings>() {
        Some(&PathTracedSettings { strategy }) => {
            let mut p = PathTracedPass::new(PathTracer {
                strategy,
                ..job.tracer
            });
            p.variance = job.variance;
            p.progress = job.progress;
            Box::new(p)
        }
        None => job.pass.build(&job.tracer),
    };
    let frames = job.cameras.len();
    let start = std::time::Instant::now();
    let mut out = None;
    for (f, camera) in job.cameras.iter().enumerate() {
        let seed = if frames == 1 {
            job.seed
        } else {
            nrc_render::pass_seed(job.seed, f as u32)
        };
        let input = FrameInput {
            scene: job.scene,
            camera,
            width: job.width,
            height: job.height,
            spp: job.spp,
            seed,
            emitter_samples: job.emitter_samples,
            sequence: (job.camera_offsets == CameraOffsets::Sobol)
                .then_some(nrc_render::PixelSequence { seed, first: 0 }),
        };
        out = Some(match job.cache {
            Some(c) => passes::run(pass.as_mut(), &input, &nrc_train::CacheSource::new(c)),
            None => passes::run(pass.as_mut(), &input, &ZeroSource),
        });
    }
    Ok(Rendered {
        output: out.context("no camera to render from")?,
        pass: pass.name(),
        seconds_per_frame: start.elapsed().as_secs_f64() / frames as f64,
    })
}

/// Refuses a frame whose state cannot fit in `available` bytes (`None`: unknown, not checked).
/// A screen-space pass holds the state of all of a frame's pixel samples at once
/// ([`PassSpec::state_bytes_per_sample`]), so its `spp` multiplies its memory where the path
/// tracer streams tiles: without this, `nrc render --pass wsrestir-gi` at 640 × 360 with the
/// default 64 samples a pixel grew to 24 GB and was killed by the system.
pub fn check_frame_memory(
    pass: &PassSpec,
    width: u32,
    height: u32,
    spp: u32,
    available: Option<u64>,
) -> Result<()> {
    let samples = u64::from(width)
        .saturating_mul(u64::from(height))
        .saturating_mul(u64::from(spp));
    let need = samples.saturating_mul(pass.state_bytes_per_sample());
    match available {
        Some(free) if need > free => bail!(
            "the pass {} holds all {:.1} M pixel samples of a frame at once ({width}x{height} at \
             {spp} spp), about {:.1} GB at {} bytes each, more than the {:.1} GB available: \
             give fewer --spp (a resampling pass accumulates over --frames)",
            pass,
            samples as f64 / 1e6,
            need as f64 / 1e9,
            pass.state_bytes_per_sample(),
            free as f64 / 1e9
        ),
        _ => Ok(()),
    }
}

/// The memory this process can still take: the system's available memory, or its control
/// group's free memory where that is less; `None` where the system does not say.
pub fn available_memory() -> Option<u64> {
    let mut sys = sysinfo::System::new();
    sys.refresh_memory();
    let system = Some(sys.available_memory()).filter(|&m| m > 0)?;
    Some(match sys.cgroup_limits() {
        Some(limits) => system.min(limits.free_memory),
        None => system,
    })
}

/// Loads a cache snapshot to render `scene` (loaded from `scene_path`) with: refused when it
/// was trained on another scene unless `allow_other_scene`, then with a warning returned.
pub fn load_snapshot(
    snapshot: &Path,
    device: nrc_cache::CacheDevice,
    scene: &Scene,
    scene_path: &Path,
    allow_other_scene: bool,
) -> Result<(nrc_cache::Cache, Option<String>)> {
    let cache = nrc_cache::Cache::load(snapshot, device)
        .with_context(|| format!("cannot load the cache snapshot {}", snapshot.display()))?;
    match check_snapshot_scene(&cache, scene, scene_path)? {
        Ok(()) => Ok((cache, None)),
        Err(e) if allow_other_scene => Ok((
            cache,
            Some(format!(
                "{}: {e} (allowed by --allow-other-scene)",
                snapshot.display()
            )),
        )),
        Err(e) => bail!("{}: {e}", snapshot.display()),
    }
}

/// What `nrc render` was asked to render with, before the pass and its source are chosen.
pub struct RenderChoice<'a> {
    /// `--pass`, if given.
    pub pass: Option<PassSpec>,
    /// `--cache`: a snapshot.
    pub snapshot: Option<&'a Path>,
    /// Where paths end in the snapshot when no pass is named.
    pub termination: Termination,
    pub device: crate::options::DeviceArg,
    /// The scene's file (its content names the snapshot's scene).
    pub scene_path: &'a Path,
    pub allow_other_scene: bool,
}

/// The pass of a render and its source: the pass asked for, else the cache-terminated pass
/// (`termination`, NEE as the tracer's strategy allows) when a snapshot is given, else the
/// path tracer; the snapshot loaded and checked against the scene where the pass reads a
/// source (refused where the pass needs one and none is given). Returns the warnings to print.
pub fn choose_pass(
    c: RenderChoice,
    scene: &Scene,
    tracer: &PathTracer,
) -> Result<(PassSpec, Option<nrc_cache::Cache>, Vec<String>)> {
    let spec: PassSpec = c.pass.unwrap_or_else(|| match c.snapshot {
        Some(_) => CacheTerminatedSettings {
            termination: c.termination,
            nee: tracer.strategy != LightStrategy::BsdfOnly,
        }
        .into(),
        None => PathTracedSettings {
            strategy: tracer.strategy,
        }
        .into(),
    });
    match (spec.uses_source(), c.snapshot) {
        (false, Some(snapshot)) => {
            let w = format!(
                "the pass {spec} reads no cache; {} is not used",
                snapshot.display()
            );
            Ok((spec, None, vec![w]))
        }
        (false, None) => Ok((spec, None, Vec::new())),
        (true, None) => {
            bail!("the pass {spec} ends paths in a cache: give it one with --cache snapshot.nrc")
        }
        (true, Some(snapshot)) => {
            let device = c.device.resolve_and_print();
            let (cache, warning) =
                load_snapshot(snapshot, device, scene, c.scene_path, c.allow_other_scene)?;
            Ok((spec, Some(cache), warning.into_iter().collect()))
        }
    }
}

/// Means and totals of a run's frame statistics, for the closing line of `nrc train`.
#[derive(Clone, Copy, Debug, Default)]
pub struct TrainSummary {
    pub produce_ms: f64,
    pub train_ms: f64,
    pub infer_ms: f64,
    /// The last frame's loss.
    pub loss: f32,
    /// Records dropped: non-finite or absurd targets at the cache's filter and the producers'.
    pub dropped: u64,
    /// Light-path contributions the producers skipped as non-finite.
    pub skipped: u64,
    /// Mean records produced per frame.
    pub records: f64,
    /// Changes in the scene the loop detected, those it confirmed a frame later (the learning
    /// rate's decay restarted), and frames it spent recovering.
    pub changes: usize,
    pub confirmed: usize,
    pub recovering_frames: usize,
    /// Under a training budget: frames after the warm-up
    /// ([`nrc_train::schedule::BUDGET_WARM_UP_FRAMES`]), and those whose producing and training
    /// took more than 1.2 × what they planned to spend.
    pub budgeted_frames: usize,
    pub over_budget: usize,
    /// Of those, frames that produced only the fewest records a budget allows
    /// ([`nrc_train::schedule::MIN_BUDGET_RECORDS`]): the budget is below their fixed cost.
    pub over_at_minimum: usize,
}

impl TrainSummary {
    pub fn of(all: &[FrameStats]) -> Self {
        let n = all.len().max(1) as f64;
        let mean = |f: fn(&FrameStats) -> f64| all.iter().map(f).sum::<f64>() / n;
        let budgeted = all
            .iter()
            .skip(nrc_train::schedule::BUDGET_WARM_UP_FRAMES)
            .filter(|s| s.spend_ms > 0.0);
        let over = budgeted
            .clone()
            .filter(|s| s.produce_ms + s.train_ms > 1.2 * s.spend_ms);
        Self {
            produce_ms: mean(|s| s.produce_ms),
            train_ms: mean(|s| s.train_ms),
            infer_ms: mean(|s| s.infer_ms),
            loss: all.last().map_or(0.0, |s| s.loss),
            dropped: all
                .iter()
                .map(|s| (s.dropped_nonfinite + s.dropped_absurd) as u64 + s.producer.dropped)
                .sum(),
            skipped: all.iter().map(|s| s.producer.skipped).sum(),
            records: mean(|s| s.records as f64),
            changes: all.iter().filter(|s| s.phase == Phase::Changed).count(),
            confirmed: all.iter().filter(|s| s.phase == Phase::Confirmed).count(),
            recovering_frames: all
                .iter()
                .filter(|s| {
                    matches!(
                        s.phase,
                        Phase::Confirmed | Phase::Recovering | Phase::Recovered
                    )
                })
                .count(),
            budgeted_frames: budgeted.clone().count(),
            over_budget: over.clone().count(),
            over_at_minimum: over
                .filter(|s| s.records <= nrc_train::schedule::MIN_BUDGET_RECORDS)
                .count(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass's frame is refused where its per-sample state exceeds what is available, the
    /// path tracer's never (it streams tiles), and nothing is refused where the memory is
    /// unknown.
    #[test]
    fn a_frame_is_checked_against_the_memory_available() {
        let ws: PassSpec = "wsrestir-gi".parse().unwrap();
        let pt: PassSpec = "pt".parse().unwrap();
        let gb = Some(1u64 << 30);
        // 640 × 360 at 1 spp: 230,400 samples, about 0.4 GB for wsrestir-gi.
        assert!(check_frame_memory(&ws, 640, 360, 1, gb).is_ok());
        let e = check_frame_memory(&ws, 640, 360, 64, gb)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--spp") && e.contains("14.7 M"), "{e}");
        assert!(check_frame_memory(&ws, 640, 360, 1, Some(100 << 20)).is_err());
        assert!(check_frame_memory(&pt, 640, 360, 1 << 20, gb).is_ok());
        assert!(check_frame_memory(&ws, 1 << 16, 1 << 16, u32::MAX, None).is_ok());
        // Sizes whose product overflows u64 saturate and are refused, not wrapped.
        assert!(check_frame_memory(&ws, u32::MAX, u32::MAX, u32::MAX, gb).is_err());
        assert!(available_memory().is_some_and(|m| m > 0));
    }
}
