//! Rendering for the neural radiance cache, free of burn.
//!
//! - [`transport`]: the path-vertex step written once ([`transport::PathWalk`]), used by the
//!   reference path tracer, the cache-terminated pass and the path-tracing producer;
//!   [`nee`]: next-event estimation and its MIS weight; [`light_path`]: paths traced from the
//!   lights (flux weights, the adjoint scale) for the light-side producers.
//! - [`path_tracer`]: the unbiased reference path tracer's settings and per-path estimate;
//!   [`render()`]: its image loop (tiles, per-pixel mean and variance).
//! - [`source`]: the radiance-source interface ([`RadianceSource`]: a batch of queries in, RGB
//!   radiance out) and exact sources for tests.
//! - [`reservoir`]: weighted reservoir sampling and resampled importance sampling (ReSTIR's
//!   core), generic over the sample type.
//! - [`passes`]: the inference passes, one file per technique, behind one trait
//!   ([`RenderPass`]) and one spec enum ([`PassSpec`]).
//! - [`ddgi`]: the DDGI probe volume (irradiance and distance moments in octahedral maps),
//!   a radiance source.
//! - [`emitters`]: the emitter-excluded image (pixels that see an emitter, and their
//!   neighbours), for errors that the emitters' anti-aliasing would dominate;
//! - [`spread`]: the area-spread heuristic of Müller et al. 2021 (termination of inference
//!   paths and of training suffixes).

pub mod ddgi;
pub mod emitters;
pub mod error;
pub mod knn;
pub mod light_path;
pub mod nee;
pub mod passes;
pub mod path_tracer;
pub mod query;
pub mod render;
pub mod reservoir;
pub mod sampler;
pub mod source;
pub mod spread;
pub mod tiles;
pub mod tracer;
pub mod transport;

pub use passes::{FrameInput, PassOutput, PassSpec, PassStats, RenderPass, Termination};
pub use path_tracer::{LightStrategy, PathStats, PathTracer};
pub use render::{Moments, RenderOutput, RenderSettings, RenderStats, render, render_moments};
pub use sampler::{PixelSampler, PixelSequence, pass_seed};
pub use source::{PathTracedSource, RadianceQuery, RadianceSource, ZeroSource};
pub use tracer::{GLOSSY_ROUGHNESS, MAX_DIRECT_SAMPLES, MAX_GLOSSY_SAMPLES};
