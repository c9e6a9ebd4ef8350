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
//! - [`source`]: the cache as an [`nrc_render::RadianceSource`] (the adapter the passes
//!   reach it through).
//! - [`online`]: the per-frame loop produce → train → infer, with per-phase statistics.
//! - [`clipped`]: the light the loss bound clips, returned to the bins it was clipped in.
//! - [`schedule`]: the loop's control: noticing that the scene changed under the cache (and
//!   recovering), and fitting a frame's training records to a time budget.
//!
//! Shared vocabulary: [`query::QueryMaker`] turns a surface point into a
//! [`nrc_cache::CacheQuery`]. The inference passes, the path-vertex step, light paths and the
//! area-spread heuristic live in [`nrc_render`].

pub mod clipped;
pub mod error;
pub mod mix;
pub mod online;
pub mod producer;
pub mod producers;
pub mod query;
pub mod schedule;
pub mod source;
pub mod starts;

pub use mix::ProducerSpec;
pub use online::{FrameStats, OnlineSettings, OnlineTrainer};
pub use producer::{Produced, Producer, ProducerContext};
pub use query::QueryMaker;
pub use source::CacheSource;
