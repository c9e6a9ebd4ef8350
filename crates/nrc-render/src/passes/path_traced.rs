//! The reference path tracer as a pass: every path traced to its end, nothing asked of a
//! radiance source. The image loop is [`crate::render::render`] (tiles, per-pixel Welford
//! mean and variance); the per-path estimate is [`PathTracer::radiance`].

use glam::Vec3;

use super::{FrameInput, PassOutput, PassSpec, PassStats, RenderPass};
use crate::path_tracer::PathTracer;
use crate::render::{RenderOutput, RenderSettings, render};
use crate::source::RadianceQuery;

/// Called with the number of pixels just finished, as tiles finish (progress bars).
pub type Progress = Box<dyn Fn(u64) + Send + Sync>;

/// The reference path tracer's pass state: its settings and the frame traced last.
pub struct PathTracedPass {
    pub tracer: PathTracer,
    /// Also compute the per-pixel sample variance (needs at least 2 samples per pixel).
    pub variance: bool,
    /// Told of the pixels done as the trace phase goes.
    pub progress: Option<Progress>,
    traced: Option<RenderOutput>,
}

impl std::fmt::Debug for PathTracedPass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathTracedPass")
            .field("tracer", &self.tracer)
            .field("variance", &self.variance)
            .finish_non_exhaustive()
    }
}

impl PathTracedPass {
    pub fn new(tracer: PathTracer) -> Self {
        Self {
            tracer,
            variance: false,
            progress: None,
            traced: None,
        }
    }
}

impl RenderPass for PathTracedPass {
    fn name(&self) -> String {
        PassSpec::PathTraced {
            strategy: self.tracer.strategy,
        }
        .to_string()
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let settings = RenderSettings {
            width: input.width,
            height: input.height,
            spp: input.spp,
            seed: input.seed,
            variance: self.variance,
        };
        let progress = |n: u64| {
            if let Some(p) = &self.progress {
                p(n);
            }
        };
        self.traced = Some(render(
            input.scene,
            input.camera,
            &self.tracer,
            &settings,
            &progress,
        ));
        Vec::new()
    }

    fn resolve(&mut self, input: &FrameInput, _answers: &[Vec3]) -> PassOutput {
        let out = self.traced.take().unwrap_or_else(|| {
            // resolve without trace: trace now (the phases are meant to run in order).
            self.trace(input);
            self.traced.take().expect("just traced")
        });
        PassOutput {
            image: out.mean,
            variance: out.variance,
            terminations: Vec::new(),
            stats: PassStats {
                paths: out.stats.samples,
                rays: out.stats.rays.rays(),
                invalid_samples: out.stats.invalid_samples,
                ..Default::default()
            },
        }
    }
}
