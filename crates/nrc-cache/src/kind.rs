//! Which cache a run trains: the neural cache or the spatial-hash baseline
//! ([`crate::hash_cache`]), behind one type so that the online loop, the comparison and the
//! renders take either ("which cache" is one switch, `--cache-kind`).

use std::path::Path;

use crate::hash_cache::{HashCache, HashCacheConfig};
use crate::{
    CacheError, CacheQuery, PendingTrain, RadianceCache, SceneBox, TrainStats, TrainingBatch,
};

/// The kinds of cache, as `--cache-kind` names them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CacheKind {
    /// The MLP behind the hash-grid encoding.
    #[default]
    Neural,
    /// The spatially hashed radiance cache (no network).
    Hash,
}

impl std::str::FromStr for CacheKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "neural" => Ok(Self::Neural),
            "hash" => Ok(Self::Hash),
            _ => Err(format!("unknown cache kind `{s}` (neural or hash)")),
        }
    }
}

impl std::fmt::Display for CacheKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Neural => "neural",
            Self::Hash => "hash",
        })
    }
}

/// A cache of either kind.
#[derive(Debug)]
pub enum Cache {
    Neural(Box<RadianceCache>),
    Hash(Box<HashCache>),
}

impl From<RadianceCache> for Cache {
    fn from(c: RadianceCache) -> Self {
        Self::Neural(Box::new(c))
    }
}

impl From<HashCache> for Cache {
    fn from(c: HashCache) -> Self {
        Self::Hash(Box::new(c))
    }
}

impl Cache {
    /// An empty hash cache over `scene_box`.
    pub fn hash(config: HashCacheConfig, scene_box: SceneBox) -> Result<Self, CacheError> {
        HashCache::new(config, scene_box)
            .map(Self::from)
            .map_err(|message| CacheError::Config {
                field: "hash cache".into(),
                message,
            })
    }

    pub fn kind(&self) -> CacheKind {
        match self {
            Self::Neural(_) => CacheKind::Neural,
            Self::Hash(_) => CacheKind::Hash,
        }
    }

    /// The neural cache, if this is one.
    pub fn neural(&self) -> Option<&RadianceCache> {
        match self {
            Self::Neural(c) => Some(c),
            Self::Hash(_) => None,
        }
    }

    pub fn neural_mut(&mut self) -> Option<&mut RadianceCache> {
        match self {
            Self::Neural(c) => Some(c),
            Self::Hash(_) => None,
        }
    }

    /// Learns from `batch`: `steps` optimiser steps for the neural cache, one frame's update
    /// for the hash cache (its statistics in the neural cache's form: one step, the relative
    /// L2 error of the cells before the update as the loss).
    pub fn train(&mut self, batch: &TrainingBatch, steps: u32) -> Result<TrainStats, CacheError> {
        Ok(self.train_submit(batch, steps)?.wait())
    }

    /// [`Cache::train`] without waiting for a GPU's steps ([`RadianceCache::train_submit`]); the
    /// hash cache trains at once.
    pub fn train_submit(
        &mut self,
        batch: &TrainingBatch,
        steps: u32,
    ) -> Result<PendingTrain, CacheError> {
        match self {
            Self::Neural(c) => c.train_submit(batch, steps),
            Self::Hash(c) => {
                let s = c.train(batch).map_err(CacheError::Input)?;
                Ok(PendingTrain::ready(TrainStats {
                    loss: s.loss,
                    first_loss: s.loss,
                    steps: u32::from(s.used > 0),
                    total_steps: 0,
                    used: s.used,
                    dropped_nonfinite: s.dropped_nonfinite,
                    dropped_absurd: s.dropped_absurd,
                    ..Default::default()
                }))
            }
        }
    }

    /// Samples' weight a hash-cache cell keeps when a change in the scene is detected (of its
    /// `max_samples`, 256 by default; see [`HashCache::forget`]). On `cornell-box-jump` (64²)
    /// the first-vertex render's MAPE over frames 45–59 is 0.392 without forgetting, 0.337
    /// keeping 16, 0.284 keeping 4 and 0.278 keeping 1, whose frame-to-frame flicker is 11 %
    /// above 4's (RESULTS.md, "Recovery after a sudden change").
    pub const HASH_RECOVERY_KEEP: f32 = 4.0;

    /// A change in the scene was detected: the neural cache infers from its training weights
    /// until [`Cache::end_recovery`] ([`RadianceCache::set_follow`]); the hash cache's cells
    /// keep at most [`Cache::HASH_RECOVERY_KEEP`] samples' weight, so that the next records
    /// move them quickly.
    pub fn begin_recovery(&mut self) {
        match self {
            Self::Neural(c) => c.set_follow(true),
            Self::Hash(c) => c.forget(Self::HASH_RECOVERY_KEEP),
        }
    }

    /// The change is confirmed (its score still up a frame later): the neural cache restarts
    /// its learning rate's decay ([`RadianceCache::restart_learning_rate`]), so that it learns
    /// the change at the full rate. Not at the change itself: two of the three false alarms in
    /// 34,000 frames of still scenes were one frame's outlier of the score, and a restart there
    /// gave up the settled rate (RESULTS.md, "A restart of the rate only for a change that
    /// lasts"). Nothing for the hash cache, which forgot at the change.
    pub fn confirm_change(&mut self) {
        if let Self::Neural(c) = self {
            c.restart_learning_rate();
        }
    }

    /// The cache has caught up with the change: the neural cache restarts its average at its
    /// weights and infers from it again; nothing for the hash cache.
    pub fn end_recovery(&mut self) {
        if let Self::Neural(c) = self {
            c.set_follow(false);
        }
    }

    pub fn infer(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        match self {
            Self::Neural(c) => c.infer(queries),
            Self::Hash(c) => c.infer(queries),
        }
    }

    /// The camera of the frame being produced and rendered (the hash cache's levels of detail
    /// follow it; the neural cache has none).
    pub fn set_camera(&mut self, position: [f32; 3]) {
        if let Self::Hash(c) = self {
            c.set_camera(position);
        }
    }

    pub fn scene_box(&self) -> SceneBox {
        match self {
            Self::Neural(c) => c.scene_box(),
            Self::Hash(c) => c.scene_box(),
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Self::Neural(c) => c.describe(),
            Self::Hash(c) => c.describe(),
        }
    }

    pub fn memory_bytes(&self) -> usize {
        match self {
            Self::Neural(c) => c.memory_bytes(),
            Self::Hash(c) => c.memory_bytes(),
        }
    }

    /// Names the scene the cache was trained on (written into snapshots).
    pub fn set_scene_content(&mut self, content: Option<String>) {
        match self {
            Self::Neural(c) => c.set_scene_content(content),
            Self::Hash(c) => c.set_scene_content(content),
        }
    }

    /// The content hash of the scene it was trained on, where known.
    pub fn scene_content(&self) -> Option<&str> {
        match self {
            Self::Neural(c) => c.scene_content(),
            Self::Hash(c) => c.scene_content(),
        }
    }

    /// Writes a snapshot of its kind (both in the same safetensors envelope, told apart by
    /// their `magic`), atomically.
    pub fn save(&mut self, path: &Path) -> Result<(), CacheError> {
        match self {
            Self::Neural(c) => c.save(path),
            Self::Hash(c) => c.save(path),
        }
    }

    /// Loads a snapshot of either kind (the neural one onto `device`).
    pub fn load(path: &Path, device: crate::CacheDevice) -> Result<Self, CacheError> {
        if crate::snapshot::magic_of(path)? == crate::hash_cache::SNAPSHOT_MAGIC {
            Ok(HashCache::load(path)?.into())
        } else {
            Ok(RadianceCache::load(path, device)?.into())
        }
    }
}
