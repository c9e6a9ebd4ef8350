//! Rendering for the neural radiance cache.
//!
//! Today: the unbiased reference path tracer that every cache estimator is judged against
//! ([`PathTracer`], whose per-path estimate [`PathTracer::radiance`] later passes reuse) and
//! the image loop around it ([`render()`]). Later: the cache inference passes
//! (cache-terminated rendering) and the online frame loop.

pub mod methods;
pub mod path_tracer;
pub mod render;
pub mod sampler;
pub mod tiles;

pub use methods::{Budget, Frame, FrameRequest, Method, MethodSettings, MethodSpec, render_frame};
pub use path_tracer::{LightStrategy, PathStats, PathTracer};
pub use render::{RenderOutput, RenderSettings, RenderStats, render};
pub use sampler::PixelSampler;
