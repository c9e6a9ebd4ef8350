//! A run of the online loop as a library: the camera of each frame (camera paths), the frame
//! loop with its outputs (frames, statistics), and the snapshot's scene check before rendering
//! from it. The CLI's `nrc train` and `nrc render --cache` parse their arguments into these.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use nrc_cache::RadianceCache;
use nrc_scene::{Camera, Scene};
use nrc_train::{FrameStats, OnlineTrainer, QueryMaker};

/// One keyframe of a camera path.
#[derive(serde::Deserialize, Debug, Clone)]
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
            "frame,produce_ms,train_ms,infer_ms,records,used,dropped_nonfinite,dropped_absurd,steps,loss,target_mean,paths,rays,cache_queries,invalid_samples,producer_dropped\n",
        );
        for f in stats {
            s.push_str(&format!(
                "{},{:.3},{:.3},{:.3},{},{},{},{},{},{},{},{},{},{},{},{}\n",
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
                f.producer.paths,
                f.producer.rays + f.inference.rays,
                f.inference.queries,
                f.inference.invalid_samples,
                f.producer.dropped
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
    cache: &RadianceCache,
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
