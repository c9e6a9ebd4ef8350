//! Rendering for the neural radiance cache.
//!
//! Today: the unbiased reference path tracer that every cache estimator is judged against.
//! Later: the cache inference passes (cache-terminated rendering) and the online frame loop.

pub mod sampler;
pub mod tiles;

pub use sampler::PixelSampler;
