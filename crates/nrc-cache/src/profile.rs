//! Where a cache call's time went, by named phase, returned with the call's result
//! ([`crate::TrainStats::profile`], [`crate::RadianceCache::infer_profiled`]): each call owns its
//! clock, so two caches (or two threads) never mix their figures.

use std::ops::AddAssign;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// The phases of a training call. The fused CPU step fills all of them; the other paths fill
/// `packing` only. "Thread time" phases are summed over the worker threads.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrainProfile {
    /// Encoding the batch's inputs (thread time).
    pub encode: Duration,
    /// MLP forward, loss and MLP backward (thread time).
    pub mlp: Duration,
    /// Scattering the hash-grid gradient (thread time).
    pub grid_scatter: Duration,
    /// Sparse Adam and EMA of the hash table (thread time).
    pub grid_adam: Duration,
    /// The scatter and sparse update together (wall time).
    pub grid_wall: Duration,
    /// Dense Adam and EMA of the MLP (wall time).
    pub mlp_adam: Duration,
    /// Checking, packing and uploading the batch (wall time).
    pub packing: Duration,
}

impl AddAssign for TrainProfile {
    fn add_assign(&mut self, o: Self) {
        self.encode += o.encode;
        self.mlp += o.mlp;
        self.grid_scatter += o.grid_scatter;
        self.grid_adam += o.grid_adam;
        self.grid_wall += o.grid_wall;
        self.mlp_adam += o.mlp_adam;
        self.packing += o.packing;
    }
}

/// The phases of an inference call on the fused CPU path (the other paths fill `call` only).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct InferProfile {
    /// Encoding the queries (thread time), the hash grid included.
    pub encode: Duration,
    /// The hash-grid part of `encode` (thread time).
    pub hash_grid: Duration,
    /// MLP forward (thread time).
    pub mlp: Duration,
    /// The fused kernel (wall time).
    pub kernel: Duration,
    /// The whole call, packing and copies included (wall time).
    pub call: Duration,
}

impl AddAssign for InferProfile {
    fn add_assign(&mut self, o: Self) {
        self.encode += o.encode;
        self.hash_grid += o.hash_grid;
        self.mlp += o.mlp;
        self.kernel += o.kernel;
        self.call += o.call;
    }
}

/// A phase's accumulated nanoseconds, added to from many threads.
#[derive(Debug, Default)]
pub struct Phase(AtomicU64);

impl Phase {
    /// Adds the time since `since`.
    pub fn since(&self, since: Instant) {
        self.add(since.elapsed());
    }

    /// Adds `d`.
    pub fn add(&self, d: Duration) {
        self.0.fetch_add(
            d.as_nanos().min(u128::from(u64::MAX)) as u64,
            Ordering::Relaxed,
        );
    }

    fn get(&self) -> Duration {
        Duration::from_nanos(self.0.load(Ordering::Relaxed))
    }
}

/// The clock of one training call, shared with its worker threads.
#[derive(Debug, Default)]
pub struct TrainClock {
    pub encode: Phase,
    pub mlp: Phase,
    pub grid_scatter: Phase,
    pub grid_adam: Phase,
    pub grid_wall: Phase,
    pub mlp_adam: Phase,
    pub packing: Phase,
}

impl TrainClock {
    /// The profile measured so far.
    pub fn profile(&self) -> TrainProfile {
        TrainProfile {
            encode: self.encode.get(),
            mlp: self.mlp.get(),
            grid_scatter: self.grid_scatter.get(),
            grid_adam: self.grid_adam.get(),
            grid_wall: self.grid_wall.get(),
            mlp_adam: self.mlp_adam.get(),
            packing: self.packing.get(),
        }
    }
}

/// The clock of one inference call, shared with its worker threads.
#[derive(Debug, Default)]
pub struct InferClock {
    pub encode: Phase,
    pub hash_grid: Phase,
    pub mlp: Phase,
    pub kernel: Phase,
    pub call: Phase,
}

impl InferClock {
    /// The profile measured so far.
    pub fn profile(&self) -> InferProfile {
        InferProfile {
            encode: self.encode.get(),
            hash_grid: self.hash_grid.get(),
            mlp: self.mlp.get(),
            kernel: self.kernel.get(),
            call: self.call.get(),
        }
    }
}
