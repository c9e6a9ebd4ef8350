//! # nrc-cache: the neural radiance cache
//!
//! Learns the outgoing radiance `L(x, ω)` of a scene from [`CacheQuery`] records and radiance
//! targets, trains online with burn on the Flex CPU backend or wgpu, answers batched queries,
//! and saves and restores itself. It knows nothing of scenes.
//!
//! ```no_run
//! use nrc_cache::{CacheConfig, CacheDevice, CacheQuery, RadianceCache, TrainingBatch};
//!
//! let mut cache = RadianceCache::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu).unwrap();
//! let q = CacheQuery { position: [0.5; 3], normal: [0.0, 0.0, 1.0], direction: [0.0, 0.0, 1.0], diffuse: [0.5; 3], ..Default::default() };
//! let batch = TrainingBatch { queries: vec![q; 256], targets: vec![[1.0, 0.5, 0.25]; 256], weights: None };
//! let stats = cache.train(&batch, 4).unwrap();
//! let radiance = cache.infer(&[q]);
//! println!("loss {} → {:?}", stats.loss, radiance[0]);
//! ```
//!
//! The pieces, in data-flow order: [`record`] (queries and batches, raw inputs) → [`encoding`]
//! (hash grid, one-blob, triangle wave, identity, composite) → [`model`] (64-wide bias-free MLP,
//! parameter layout) → [`loss`] (reflectance factorisation, output mapping, relative L2) →
//! Adam and the weight EMA ([`cpu::optim`], [`tensor_path`]) → [`snapshot`]. The custom burn ops
//! are in [`ops`] and [`hash_grid_op`]; their CPU kernels in [`cpu`], their GPU kernels in
//! [`gpu`] (the fused step's CubeCL kernels in the `nrc-gpu` crate, the custom-ops path's WGSL in
//! `shaders/`).

pub mod batch;
pub mod bench;
pub mod cache;
pub mod config;
mod config_serde;
pub mod cpu;
pub mod device;
pub mod encoding;
pub mod error;
pub mod export;
pub mod gpu;
pub mod hash_cache;
pub mod hash_grid_op;
pub mod kind;
pub mod loss;
pub mod model;
pub mod ops;
pub mod profile;
pub mod record;
pub mod snapshot;
pub mod state;
pub mod tensor_path;

pub use cache::{PendingTrain, RadianceCache, TrainStats};
pub use config::{CacheConfig, SceneBox, Sizing};
pub use device::{CacheDevice, ComputePath};
pub use error::CacheError;
pub use hash_cache::{HashCache, HashCacheConfig};
pub use kind::{Cache, CacheKind};
pub use profile::{InferProfile, TrainProfile};
pub use record::{CacheQuery, TrainingBatch};
pub use snapshot::check_scene;
