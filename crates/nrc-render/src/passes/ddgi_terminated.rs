//! Camera paths that end in a DDGI probe volume the pass keeps and updates every frame:
//! `ddgi-secondary` (the seed paper's "+Secondary DDGI" column: the primary vertex's direct
//! light traced, the rest from the probes at the secondary vertex) and, with any other
//! termination, `ddgi-<termination>`. The probe update is part of the frame (it runs in
//! [`RenderPass::prepare`], inside the timed frame of every comparison).

use glam::Vec3;

use super::cache_terminated::{CacheTerminatedPass, Termination};
use super::{FrameInput, PassOutput, PassSpec, RenderPass};
use crate::ddgi::{DdgiSettings, ProbeRadiance, ProbeRays, ProbeVolume};
use crate::path_tracer::PathTracer;
use crate::source::{RadianceQuery, RadianceSource};

/// The pass: its volume (built at the first frame, over that frame's scene box) and the
/// cache-terminated path logic, its queries answered by the volume.
pub struct DdgiTerminatedPass {
    pub settings: DdgiSettings,
    inner: CacheTerminatedPass,
    volume: Option<ProbeVolume>,
    queries: Vec<RadianceQuery>,
    /// `radiance=nrc`: this frame's probe rays, waiting for the source's answers.
    rays: Option<ProbeRays>,
    /// Milliseconds of the last probe update.
    pub update_ms: f64,
}

impl DdgiTerminatedPass {
    pub fn new(termination: Termination, settings: DdgiSettings, tracer: &PathTracer) -> Self {
        Self {
            settings,
            inner: CacheTerminatedPass::new(termination, true, tracer),
            volume: None,
            queries: Vec::new(),
            rays: None,
            update_ms: 0.0,
        }
    }

    /// The volume, once a frame has built it.
    pub fn volume(&self) -> Option<&ProbeVolume> {
        self.volume.as_ref()
    }
}

impl RenderPass for DdgiTerminatedPass {
    fn name(&self) -> String {
        PassSpec::DdgiTerminated {
            termination: self.inner.termination,
            settings: self.settings,
        }
        .to_string()
    }

    fn reset(&mut self) {
        self.volume = None;
    }

    fn prepare(&mut self, input: &FrameInput) {
        let t = std::time::Instant::now();
        if self.volume.is_none() {
            // Settings were validated when the pass was named; an empty scene box leaves the
            // pass without probes (every query answers zero).
            self.volume = ProbeVolume::new(&input.scene.bounds(), self.settings).ok();
        }
        if let Some(v) = &mut self.volume {
            if self.settings.radiance == ProbeRadiance::Source {
                // The rays' queries go to the source with the frame's batch (`trace`).
                self.rays = Some(v.trace_rays(input.scene, input.seed ^ 0xDD61));
            } else {
                v.update(input.scene, input.seed ^ 0xDD61);
            }
        }
        self.update_ms = t.elapsed().as_secs_f64() * 1e3;
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        self.queries = self.inner.trace(input);
        self.rays
            .as_ref()
            .map_or_else(Vec::new, |r| r.queries.clone())
    }

    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput {
        let t = std::time::Instant::now();
        if let (Some(v), Some(r)) = (&mut self.volume, self.rays.take()) {
            v.blend(r, answers);
        }
        self.update_ms += t.elapsed().as_secs_f64() * 1e3;
        let answers = match &self.volume {
            Some(v) => v.radiance(&self.queries),
            None => vec![Vec3::ZERO; self.queries.len()],
        };
        let mut out = self.inner.resolve(input, &answers);
        out.stats.queries = self.queries.len() as u64;
        out.stats.phases.probes_ms = self.update_ms;
        out
    }
}
