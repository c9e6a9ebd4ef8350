//! The reference path tracer as a pass: every path traced to its end, nothing asked of a
//! radiance source. The image loop is [`crate::render::render`] (tiles, per-pixel Welford
//! mean and variance); the per-path estimate is [`PathTracer::radiance`].

use glam::Vec3;

use super::params::{self, Params};
use super::spec::{PassConfig, PassKind};
use super::frame::{FrameInput, PassOutput, PassStats, RenderPass};
use crate::path_tracer::{LightStrategy, PathTracer};
use crate::render::{RenderOutput, RenderSettings, render_seen};
use crate::source::RadianceQuery;

pub const KIND: PassKind = PassKind {
    grammar: "pt, pt-nonee, pt-light",
    about: "the reference path tracer: NEE and BSDF sampling by MIS, BSDF sampling only, NEE only",
    method: false,
    variants: || STRATEGIES.iter().map(|(_, s)| (*s).into()).collect(),
    parse: |name| super::spec::parse_variant(name, STRATEGIES, |_| Ok(())),
};

const STRATEGIES: &[(&str, PathTracedSettings)] = &[
    ("pt", PathTracedSettings { strategy: LightStrategy::Mis }),
    ("pt-nonee", PathTracedSettings { strategy: LightStrategy::BsdfOnly }),
    ("pt-light", PathTracedSettings { strategy: LightStrategy::LightOnly }),
];

/// The reference path tracer's settings: its light strategy (the rest is the tracer's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathTracedSettings {
    pub strategy: LightStrategy,
}

impl Params for PathTracedSettings {
    fn visit(&mut self, _: &mut dyn FnMut(&params::Key, &mut dyn params::Value)) {}
}

impl PassConfig for PathTracedSettings {
    /// (tiles of pixels, each path traced whole.)
    fn state_bytes_per_sample(&self) -> u64 {
        0
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let (name, _) = STRATEGIES
            .iter()
            .find(|(_, s)| s == self)
            .expect("every strategy is named");
        name.to_string()
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(PathTracedPass::new(PathTracer {
            strategy: self.strategy,
            ..*tracer
        }))
    }
}

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
        PathTracedSettings {
            strategy: self.tracer.strategy,
        }
        .name()
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let settings = RenderSettings {
            width: input.width,
            height: input.height,
            spp: input.spp,
            seed: input.seed,
            variance: self.variance,
            sequence: input.sequence,
        };
        let progress = |n: u64| {
            if let Some(p) = &self.progress {
                p(n);
            }
        };
        let (mut out, seen) = render_seen(
            input.scene,
            input.camera,
            &self.tracer,
            &settings,
            &progress,
        );
        if let Some(aa) = input.supersample_emitters(settings.spp.max(1), &seen) {
            aa.apply(&mut out.mean);
            out.stats.rays.closest_rays += aa.rays;
            // The sample variance is that of the pass's own samples, not of the new mean.
            out.variance = None;
        }
        self.traced = Some(out);
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
