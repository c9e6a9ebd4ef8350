//! # nrc-train: training the neural radiance cache online, and rendering with it
//!
//! The product's main job joins the scene ([`nrc_scene`]), the cache ([`nrc_cache`]) and the
//! reference path tracer ([`nrc_render`]):
//!
//! - [`starts`]: *query prediction*, the rays whose first hits become training queries
//!   (camera primary hits in jittered tiles, and optionally the previous frame's inference
//!   termination points).
//! - [`producer`]: the [`Producer`] trait and the configuration that chooses and mixes
//!   producers; the producers themselves in [`producers`] (path tracing with self-learning,
//!   bidirectional training, light training, sparse progressive photon collection).
//! - [`inference`]: cache-terminated camera paths with the termination strategies
//!   ([`Termination`]), all termination queries of a frame answered by one cache call.
//! - [`online`]: the per-frame loop produce → train → infer, with per-phase statistics.
//! - [`methods`]: the cache methods of the comparison registry (`nrc-pt`, `nrc-sppc`, ...).
//!
//! Shared vocabulary: [`query::QueryMaker`] turns a surface point into a
//! [`nrc_cache::CacheQuery`]; [`view::RadianceView`] is the read-only face of a cache (the
//! trained cache, or an exact radiance field in tests); [`spread::Spread`] is the area-spread
//! heuristic of Müller et al. 2021 used both to terminate rendering paths and training
//! suffixes.

pub mod inference;
pub mod methods;
pub mod online;
pub mod producer;
pub mod producers;
pub mod query;
pub mod spread;
pub mod starts;
pub mod view;

pub use inference::{CacheRenderer, InferenceOutput, Termination};
pub use online::{FrameStats, OnlineSettings, OnlineTrainer};
pub use producer::{Produced, Producer, ProducerContext, ProducerSpec};
pub use query::QueryMaker;
pub use view::RadianceView;
