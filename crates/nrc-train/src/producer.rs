//! The producer interface: what a producer reads in a frame, what it returns, and the record
//! helpers every producer shares. Which producers run, and how they mix, is [`crate::mix`].

use glam::Vec3;
use nrc_cache::{CacheQuery, TrainingBatch};
use nrc_render::{PathTracer, RadianceSource};
use nrc_scene::{Camera, Scene};
use rayon::prelude::*;

use crate::error::TrainError;
use crate::query::QueryMaker;
use crate::starts::StartRay;

/// What a producer may read in a frame.
pub struct ProducerContext<'a> {
    pub scene: &'a Scene,
    pub camera: &'a Camera,
    /// The cache, read-only, as a radiance source (self-learning targets).
    pub cache: &'a dyn RadianceSource,
    pub queries: &'a QueryMaker,
    /// Query prediction: the rays whose first hits are this frame's training queries (camera
    /// tiles and previous termination points); producers that start at the camera use them in
    /// order, cycling if they need more.
    pub starts: &'a [StartRay],
    /// Depth and Russian roulette of training paths.
    pub tracer: PathTracer,
}

/// What a producer counted while producing.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ProducerStats {
    /// Paths traced (camera, light or photon paths).
    pub paths: u64,
    /// Rays traced (closest hit and shadow).
    pub rays: u64,
    /// Records whose target was not finite or was negative, left out of the batch.
    pub dropped: u64,
    /// Light-path contributions (BT connections, SPPC photon hits) that were NaN or infinite
    /// and were left out of their targets.
    pub skipped: u64,
}

impl ProducerStats {
    pub fn add(&mut self, o: &ProducerStats) {
        self.paths += o.paths;
        self.rays += o.rays;
        self.dropped += o.dropped;
        self.skipped += o.skipped;
    }
}

/// A producer's output for one frame.
#[derive(Clone, Debug, Default)]
pub struct Produced {
    pub batch: TrainingBatch,
    pub stats: ProducerStats,
}

/// A source of training records. Deterministic: the same context, budget and seed give the
/// same batch whatever the thread count.
pub trait Producer: Send {
    /// The producer's name as configured (`pt-sl`, `sppc`, ...).
    fn name(&self) -> &str;

    /// About `budget` training records (never more) for this frame; `seed` chooses the random
    /// streams.
    fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced;

    /// Whether the producer can serve `scene`; an error names why not. Default: any scene.
    fn check(&self, _scene: &Scene) -> Result<(), TrainError> {
        Ok(())
    }
}

/// The check of the producers that start light paths: a scene that nothing lights (no
/// emissive triangle, punctual light or environment) has no light to start them from, and
/// they would produce no target at all. Refused rather than trained silently on nothing.
pub(crate) fn check_light_paths(name: &str, scene: &Scene) -> Result<(), TrainError> {
    if scene.light_count() == 0 {
        return Err(TrainError::Unlit {
            producer: name.to_string(),
        });
    }
    Ok(())
}

/// Items produced per parallel round (each index has its own random stream, so the result does
/// not depend on the thread count).
pub(crate) const ROUND: usize = 1024;

/// One training record before filtering.
pub(crate) type Record = (CacheQuery, Vec3);

/// Appends records with finite, non-negative targets; counts the others as dropped.
pub(crate) fn push_records(
    batch: &mut TrainingBatch,
    stats: &mut ProducerStats,
    records: impl Iterator<Item = Record>,
) {
    for (q, t) in records {
        if t.is_finite() && t.min_element() >= 0.0 {
            batch.queries.push(q);
            batch.targets.push(t.to_array());
        } else {
            stats.dropped += 1;
        }
    }
}

/// What [`fill_rounds`] collected.
#[derive(Debug)]
pub(crate) struct Rounds<T> {
    /// The items, in index order.
    pub items: Vec<T>,
    /// Indices tried.
    pub tried: usize,
    /// Rays traced.
    pub rays: u64,
}

impl<T> Default for Rounds<T> {
    fn default() -> Self {
        Self {
            items: Vec::new(),
            tried: 0,
            rays: 0,
        }
    }
}

/// Calls `f(i)` for `i = 0, 1, ...` in parallel rounds of [`ROUND`] indices and concatenates
/// the items in index order until there are at least `want`. Deterministic whatever the thread
/// count. Stops early when a round yields nothing (after at least four rounds: nothing in the
/// scene produces items, e.g. no lights or starts that miss).
pub(crate) fn fill_rounds<T: Send>(
    want: usize,
    f: impl Fn(usize) -> (Vec<T>, u64) + Sync,
) -> Rounds<T> {
    let mut out = Rounds::default();
    let mut round = 0;
    while out.items.len() < want {
        let first = out.tried;
        let results: Vec<(Vec<T>, u64)> = (first..first + ROUND).into_par_iter().map(&f).collect();
        out.tried += ROUND;
        let before = out.items.len();
        for (items, rays) in results {
            out.items.extend(items);
            out.rays += rays;
        }
        round += 1;
        if out.items.len() == before && round >= 4 {
            break;
        }
    }
    out
}
