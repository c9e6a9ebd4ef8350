//! Camera paths that end in a DDGI probe volume the pass keeps and updates every frame (all
//! its probes, or, where the volume is sized to the frame, the share of them the frame's ray
//! budget affords, in turn):
//! `ddgi-secondary` (the seed paper's "+Secondary DDGI" column: the primary vertex's direct
//! light traced, the rest from the probes at the secondary vertex) and, with any other
//! termination, `ddgi-<termination>`. The probe update is part of the frame (it runs in
//! [`RenderPass::prepare`], inside the timed frame of every comparison).

use glam::Vec3;

use crate::error::{PassError, SettingsError};
use super::cache_terminated::{CacheTerminatedPass, Termination};
use super::params::{Key, Params, Value};
use super::spec::{PassConfig, PassKind};
use super::frame::{FrameInput, PassOutput, RenderPass};
use crate::ddgi::{DdgiSettings, ProbeRadiance, ProbeRays, ProbeVolume};
use crate::path_tracer::PathTracer;
use crate::sampler::Stream;
use crate::source::{RadianceQuery, RadianceSource};

pub const KIND: PassKind = PassKind {
    grammar: "ddgi-TERMINATION",
    about: "camera paths ending in a DDGI probe volume updated every frame, by a termination \
            of cache[-TERMINATION] (e.g. ddgi-secondary: the primary vertex's direct light \
            traced, the rest from the probes); radiance=nrc: the probe rays' radiance from the \
            cache",
    method: true,
    variants: || {
        [Termination::Secondary, Termination::FirstVertex]
            .into_iter()
            .map(|termination| {
                let volume = DdgiSettings::default();
                DdgiTerminatedSettings { termination, volume }.into()
            })
            .collect()
    },
    parse: |name| {
        let rest = name.strip_prefix("ddgi-")?;
        let (term, params) = rest.split_once(':').unwrap_or((rest, ""));
        let termination = term.parse::<Termination>().ok()?;
        let mut set = DdgiTerminatedSettings {
            termination,
            volume: DdgiSettings::default(),
        };
        Some(
            super::params::set(name, &mut set, params)
                .and_then(|()| {
                    validate_volume(&set.volume).map_err(|source| PassError::Invalid {
                        pass: name.to_string(),
                        source,
                    })
                })
                .map(|()| set.into()),
        )
    },
};

/// The DDGI-terminated pass's settings: where paths end, and the volume.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdgiTerminatedSettings {
    pub termination: Termination,
    pub volume: DdgiSettings,
}

/// Errors for volume settings that cannot work (checked on a unit box).
pub(super) fn validate_volume(volume: &DdgiSettings) -> Result<(), SettingsError> {
    let unit = nrc_scene::Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    ProbeVolume::new(&unit, *volume)?;
    Ok(())
}

/// The probe volume's keys, shared by every pass that keeps one.
impl Params for DdgiSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        let probes = Key::new(
            "probes",
            "probes per axis (auto: what the frame's rays refresh within the sweep, cubic cells, at most 4,096)",
        );
        f(&probes.range(1.0, 64.0), &mut self.counts);
        let sweep = Key::new(
            "sweep",
            "auto probes and rays: the most frames between a probe's updates",
        );
        f(&sweep.range(1.0, 1024.0), &mut self.sweep);
        let rays = Key::new(
            "rays",
            "rays per probe and frame (auto: a quarter of the frame's pixels over the probes, 32-256)",
        );
        f(&rays.range(1.0, 16384.0), &mut self.rays_per_probe);
        let hysteresis = Key::new("hysteresis", "weight of the old irradiance in each update");
        f(&hysteresis.range(0.0, 1.0), &mut self.hysteresis);
        let relocate = Key::new("relocate", "move probes out of geometry");
        f(&relocate, &mut self.relocate);
        let classify = Key::new("classify", "switch off probes that see no surface");
        f(&classify, &mut self.classify);
        let attenuation = Key::new("attenuation", "§3.3's attenuation of emission (0: off)");
        f(&attenuation.range(0.0, f64::INFINITY), &mut self.attenuation);
    }
}

/// What probe rays bring back, as text.
impl Value for ProbeRadiance {
    fn read(&mut self, text: &str) -> Option<()> {
        *self = match text {
            "full" => Self::Full,
            "indirect" => Self::Indirect,
            "nrc" => Self::Source,
            _ => return None,
        };
        Some(())
    }
    fn write(&self) -> String {
        match self {
            Self::Full => "full",
            Self::Indirect => "indirect",
            Self::Source => "nrc",
        }
        .into()
    }
    fn grammar(&self) -> &'static str {
        "full|indirect|nrc"
    }
}

impl Params for DdgiTerminatedSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        self.volume.visit(f);
        let radiance = Key::new(
            "radiance",
            "probe rays bring eq. 5's full, eq. 4's indirect or the cache's radiance",
        );
        f(&radiance, &mut self.volume.radiance);
    }
}

impl PassConfig for DdgiTerminatedSettings {
    /// (measured 206 (`ddgi-secondary`).)
    fn state_bytes_per_sample(&self) -> u64 {
        250
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let defaults = DdgiTerminatedSettings {
            volume: DdgiSettings::default(),
            ..*self
        };
        super::params::name(&format!("ddgi-{}", self.termination), self, &defaults)
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(DdgiTerminatedPass::new(self.termination, self.volume, tracer))
    }

    fn is_stateful(&self) -> bool {
        true
    }

    fn uses_source(&self) -> bool {
        self.volume.radiance == ProbeRadiance::Source
    }

    fn params(&self) -> Vec<super::params::Param> {
        super::params::list(self)
    }
}

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
    /// The last frame's camera and size (the probe view).
    view: Option<(nrc_scene::Camera, u32, u32)>,
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
            view: None,
        }
    }

    /// The volume, once a frame has built it.
    pub fn volume(&self) -> Option<&ProbeVolume> {
        self.volume.as_ref()
    }
}

impl RenderPass for DdgiTerminatedPass {
    fn name(&self) -> String {
        DdgiTerminatedSettings {
            termination: self.inner.termination,
            volume: self.settings,
        }
        .name()
    }

    fn reset(&mut self) {
        self.volume = None;
        self.rays = None;
    }

    fn debug_views(&self) -> Vec<super::frame::PassView> {
        match (&self.volume, &self.view) {
            (Some(v), Some((camera, w, h))) => vec![probe_view(v, camera, *w, *h)],
            _ => Vec::new(),
        }
    }

    fn prepare(&mut self, input: &FrameInput) {
        self.view = Some((*input.camera, input.width, input.height));
        let t = std::time::Instant::now();
        let pixels = u64::from(input.width) * u64::from(input.height);
        if self.volume.is_none() {
            // Settings were validated when the pass was named; an empty scene box leaves the
            // pass without probes (every query answers zero).
            self.volume = ProbeVolume::for_frame(&input.scene.bounds(), self.settings, pixels).ok();
        }
        if let Some(v) = &mut self.volume {
            v.fit_rays_to_frame(pixels);
            if self.settings.radiance == ProbeRadiance::Source {
                // The rays' queries go to the source with the frame's batch (`trace`).
                self.rays = Some(v.trace_rays(input.scene, Stream::ProbeRays.seed(input.seed)));
            } else {
                v.update(input.scene, Stream::ProbeRays.seed(input.seed));
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

/// The viewer's view of a probe volume: each active probe that has been updated where it is
/// (relocation included), a disc in its mean irradiance, through `camera` in a `width ×
/// height` image.
pub(super) fn probe_view(
    volume: &ProbeVolume,
    camera: &nrc_scene::Camera,
    width: u32,
    height: u32,
) -> super::frame::PassView {
    let radius = (width.max(height) as f32 / 160.0).max(1.5);
    let probes = (0..volume.probe_count())
        .filter(|&p| volume.probe_active(p) && volume.probe_updates(p) > 0)
        .map(|p| {
            let texels = volume.probe_irradiance(p);
            let mean = texels.iter().copied().sum::<Vec3>() / texels.len().max(1) as f32;
            (volume.probe_origin(p), mean)
        });
    super::frame::PassView::points("probes", camera, width, height, probes, radius)
}
