//! Inference passes: the techniques that turn a scene, a camera and (for most) a radiance
//! source into a frame. One file per technique, each a state struct kept across frames with
//! named phases, in the manner of kajiya's renderers:
//!
//! 1. [`RenderPass::prepare`]: per-frame upkeep before tracing (history buffers, probe or
//!    light updates);
//! 2. [`RenderPass::trace`]: the frame's paths, up to the points where they want far-field
//!    radiance; returns those queries;
//! 3. the radiance source answers every query of the frame in one batch ([`run`] does this);
//! 4. [`RenderPass::resolve`]: the answers combined into the image.
//!
//! A pass is chosen by a [`PassSpec`], which parses from the command line (`--pass NAME`) and
//! from JSON (the same name as a string). Adding a technique: one file here with its state
//! struct and its [`RenderPass`] implementation, one variant of [`PassSpec`] (with its name in
//! `FromStr`/`Display` and its `build` arm).
//!
//! Passes know nothing of burn: the cache reaches them as a [`RadianceSource`].

pub mod cache_terminated;
pub mod ddgi_restir;
pub mod ddgi_terminated;
pub mod hash_grid;
pub mod instant_radiosity;
pub mod path_traced;
pub mod restir_di;
pub mod restir_gi;
pub mod screen;

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use glam::Vec3;
use nrc_scene::{Camera, Image, Scene};

use crate::path_tracer::{LightStrategy, PathTracer};
use crate::source::{RadianceQuery, RadianceSource};
pub use cache_terminated::{CacheTerminatedPass, TERMINATION_NAMES, Termination, TerminationPoint};
pub use ddgi_restir::{DdgiRestirPass, DdgiRestirSettings, SurfaceLight};
pub use ddgi_terminated::DdgiTerminatedPass;
pub use instant_radiosity::{InstantRadiosityPass, IrSettings, VplMode};
pub use path_traced::PathTracedPass;
pub use restir_di::{RestirDiPass, RestirDiSettings};
pub use restir_gi::{RestirGiPass, RestirGiSettings};

/// What a pass renders this frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameInput<'a> {
    pub scene: &'a Scene,
    pub camera: &'a Camera,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel, at least 1.
    pub spp: u32,
    /// Seed of the frame's random streams: the image is a function of it alone, whatever the
    /// thread count.
    pub seed: u64,
}

/// What a pass counted in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PassStats {
    /// Camera paths traced (pixels × samples).
    pub paths: u64,
    /// Rays traced (closest-hit and shadow).
    pub rays: u64,
    /// Queries sent to the radiance source.
    pub queries: u64,
    /// Samples whose value was NaN or infinite (counted as black).
    pub invalid_samples: u64,
    /// Milliseconds in the trace phase.
    pub trace_ms: f64,
    /// Milliseconds in the radiance source's call.
    pub cache_ms: f64,
    /// The resampling passes' phases (zero for the others).
    pub phases: PhaseTimes,
}

/// Milliseconds per phase of a resampling pass's frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PhaseTimes {
    /// The probe volume's update (its rays traced and blended), for the DDGI passes.
    pub probes_ms: f64,
    /// Camera rays and initial candidates.
    pub candidates_ms: f64,
    pub temporal_ms: f64,
    pub spatial_ms: f64,
    /// Final visibility, shading and the rest of the path.
    pub shading_ms: f64,
}

/// A rendered frame.
#[derive(Clone, Debug)]
pub struct PassOutput {
    /// Per-pixel mean radiance.
    pub image: Image,
    /// Per-pixel sample variance of one sample's estimate, where the pass computes it.
    pub variance: Option<Image>,
    /// Where paths ended in the source (the next frame's training-query prediction).
    pub terminations: Vec<TerminationPoint>,
    pub stats: PassStats,
}

/// An inference pass with its state across frames (see the module documentation).
pub trait RenderPass: Send {
    /// The pass's canonical name (parses back to its spec).
    fn name(&self) -> String;

    /// Per-frame upkeep before tracing. Default: nothing.
    fn prepare(&mut self, _input: &FrameInput) {}

    /// Forgets the state kept across frames (history, reservoirs), as at the start of an
    /// independent run. Default: nothing (stateless passes).
    fn reset(&mut self) {}

    /// Traces the frame's paths; returns the queries the radiance source must answer.
    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery>;

    /// Combines the answers (one per query of [`RenderPass::trace`], in order) into the frame.
    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput;
}

/// One frame of `pass`: prepare, trace, one batch call of `source`, resolve; the trace and
/// source phases timed in the output's statistics.
pub fn run(
    pass: &mut dyn RenderPass,
    input: &FrameInput,
    source: &dyn RadianceSource,
) -> PassOutput {
    pass.prepare(input);
    let t0 = Instant::now();
    let queries = pass.trace(input);
    let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let answers = if queries.is_empty() {
        Vec::new()
    } else {
        source.radiance(&queries)
    };
    assert_eq!(
        answers.len(),
        queries.len(),
        "a radiance source answers every query"
    );
    let cache_ms = t1.elapsed().as_secs_f64() * 1e3;
    let mut out = pass.resolve(input, &answers);
    out.stats.trace_ms = trace_ms;
    out.stats.cache_ms = cache_ms;
    out.stats.queries = queries.len() as u64;
    out
}

/// A pass and its settings, as named on the command line and in run files.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PassSpec {
    /// The reference path tracer: `pt` (NEE and BSDF sampling by MIS), `pt-nonee` (BSDF
    /// sampling only), `pt-light` (NEE only).
    PathTraced { strategy: LightStrategy },
    /// Camera paths that end in the radiance source: `cache[-TERMINATION][-nonee]`, e.g.
    /// `cache` (the spread heuristic), `cache-first`, `cache-bth:8`.
    CacheTerminated { termination: Termination, nee: bool },
    /// ReSTIR DI at the primary vertex, the rest of the path traced: `restir-di[-biased]`,
    /// parameters after a colon (see [`RestirDiSettings`]), e.g. `restir-di:light=16,k=3`.
    RestirDi(RestirDiSettings),
    /// ReSTIR GI: `restir-gi` (screen space) or `wsrestir-gi` (world-space hash grid), each
    /// with `-biased` and `-nrc` (the reconnection vertex's radiance from the radiance source),
    /// parameters after a colon (see [`RestirGiSettings`]), e.g. `wsrestir-gi-nrc:cell=0.05`.
    RestirGi(RestirGiSettings),
    /// Camera paths ending in a DDGI probe volume the pass updates each frame:
    /// `ddgi-TERMINATION[:probes=N,rays=R,hysteresis=H,radiance=full|indirect]`, e.g.
    /// `ddgi-secondary`, `ddgi-first:probes=16`.
    DdgiTerminated {
        termination: Termination,
        settings: crate::ddgi::DdgiSettings,
    },
    /// DDGI resampling: the scene's surfaces as the light of ReSTIR at the primary vertex,
    /// shining with their emission plus probes' (`ddgi-restir`), the cache's (`nrc-restir`) or
    /// cache-fed probes' (`ddgi-nrc-restir`) radiance; parameters after a colon (see
    /// [`DdgiRestirSettings`]), e.g. `nrc-restir:clamp=0.05`.
    DdgiRestir(DdgiRestirSettings),
    /// Instant radiosity: `ir` (VPLs traced from the lights each frame), `smc-ir` (sequential
    /// Monte Carlo instant radiosity), `smc-ir-nrc` (its radiosities from the radiance source);
    /// parameters after a colon (see [`IrSettings`]), e.g. `smc-ir:vpls=1024,mmax=8`.
    InstantRadiosity(IrSettings),
}

impl Default for PassSpec {
    fn default() -> Self {
        Self::CacheTerminated {
            termination: Termination::default(),
            nee: true,
        }
    }
}

/// The grammar of pass names, for help texts and errors.
pub fn pass_names() -> String {
    format!(
        "pt, pt-nonee, pt-light (the reference path tracer: MIS, BSDF sampling only, NEE only); \
         cache[-TERMINATION][-nonee] (paths ending in the radiance source; terminations: {TERMINATION_NAMES}); \
         restir-di[-biased][:light=N,bsdf=N,k=N,radius=PX,mcap=X,temporal=0|1,jitter=0|1] (ReSTIR DI at the primary vertex; \
         defaults light=32,bsdf=1,k=5,radius=30,mcap=20,temporal=1); \
         restir-gi[-biased][-nrc][:k=N,radius=PX,mcap=X,temporal=0|1,jitter=0|1] (screen-space ReSTIR GI, defaults k=3,radius=30,mcap=30); \
         wsrestir-gi[-biased][-nrc][:samples=N,cell=S,dmin=F,mcap=X,temporal=0|1,jitter=0|1] (world-space ReSTIR GI, defaults samples=3,cell=0.1,dmin=0.01,mcap=30); \
         -nrc: the reconnection vertex's radiance from the cache; \
         ddgi-TERMINATION[:probes=N,rays=R,hysteresis=H,radiance=full|indirect] (paths ending in a DDGI probe volume \
         updated every frame, e.g. ddgi-secondary; probes: per axis, default 8 along the longest; radiance=nrc: \
         the probe rays' radiance from the cache); \
         ddgi-restir, nrc-restir, ddgi-nrc-restir[:light=N,bsdf=N,k=N,radius=PX,mcap=X,temporal=0|1,clamp=F,residual=0|1,\
         requery=0|1,jitter=0|1,probes=N,rays=R,hysteresis=H] (DDGI resampling: every surface a light, lit by probes, \
         the cache or cache-fed probes; defaults light=8,bsdf=1,k=3,radius=30,mcap=20,clamp=0.1 (G_max = 1/(clamp·diagonal)²)); \
         ir, smc-ir, smc-ir-nrc[:vpls=N,mmax=N,per_pixel=N,clamp=F,residual=0|1,spp=N,rate=N,warmup=N,points=N,indirect=0|1] \
         (instant radiosity: VPLs from the lights each frame, sequential Monte Carlo VPLs with path-traced or cache radiosities; \
         defaults vpls=2048,mmax=16,per_pixel=64,clamp=0.1,spp=16,rate=16,warmup=100,points=1024)"
    )
}

/// Adds `KEY=VALUE` to a pass name's parameters where the value is not the default.
/// A probe volume's parameter in a pass string (`probes`, `rays`, `hysteresis`, `relocate`,
/// `classify`, `attenuation`): set, or `false` when `p` is none of them.
fn volume_param(settings: &mut crate::ddgi::DdgiSettings, p: &PassParam) -> Result<bool, String> {
    match p.key {
        "probes" => settings.counts = Some(glam::UVec3::splat(p.count()?)),
        "rays" => settings.rays_per_probe = p.count()?,
        "hysteresis" => settings.hysteresis = p.real()?,
        "relocate" => settings.relocate = p.flag()?,
        "classify" => settings.classify = p.flag()?,
        "attenuation" => settings.attenuation = p.real()?,
        _ => return Ok(false),
    }
    Ok(true)
}

/// The probe volume's parameters that differ from the defaults, as `key=value`.
fn volume_params(params: &mut Vec<String>, s: &crate::ddgi::DdgiSettings) {
    let d = crate::ddgi::DdgiSettings::default();
    if let Some(c) = s.counts {
        params.push(format!("probes={}", c.x));
    }
    param(params, "rays", s.rays_per_probe, d.rays_per_probe);
    param(params, "hysteresis", s.hysteresis, d.hysteresis);
    param(params, "relocate", s.relocate as u32, d.relocate as u32);
    param(params, "classify", s.classify as u32, d.classify as u32);
    param(params, "attenuation", s.attenuation, d.attenuation);
}

fn param<T: PartialEq + fmt::Display>(params: &mut Vec<String>, key: &str, value: T, default: T) {
    if value != default {
        params.push(format!("{key}={value}"));
    }
}

/// One `KEY=VALUE` parameter of a pass name (after its colon).
struct PassParam<'a> {
    pass: &'a str,
    key: &'a str,
    value: &'a str,
}

impl PassParam<'_> {
    fn bad(&self) -> String {
        format!(
            "pass `{}`: bad value `{}` for `{}`",
            self.pass, self.value, self.key
        )
    }

    fn count(&self) -> Result<u32, String> {
        self.value.parse().map_err(|_| self.bad())
    }

    fn real(&self) -> Result<f32, String> {
        self.value.parse().map_err(|_| self.bad())
    }

    fn flag(&self) -> Result<bool, String> {
        Ok(self.count()? != 0)
    }
}

/// The comma-separated parameters `params` of pass name `pass`.
fn pass_params<'a>(
    pass: &'a str,
    params: &'a str,
) -> impl Iterator<Item = Result<PassParam<'a>, String>> {
    params.split(',').filter(|p| !p.is_empty()).map(move |kv| {
        let (key, value) = kv
            .split_once('=')
            .ok_or_else(|| format!("pass `{pass}`: parameter `{kv}` is not KEY=VALUE"))?;
        Ok(PassParam { pass, key, value })
    })
}

impl FromStr for PassSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        let err = || format!("unknown pass `{s}`; known: {}", pass_names());
        match s {
            "pt" => {
                return Ok(Self::PathTraced {
                    strategy: LightStrategy::Mis,
                });
            }
            "pt-nonee" => {
                return Ok(Self::PathTraced {
                    strategy: LightStrategy::BsdfOnly,
                });
            }
            "pt-light" => {
                return Ok(Self::PathTraced {
                    strategy: LightStrategy::LightOnly,
                });
            }
            _ => {}
        }
        for (prefix, mode) in [
            ("smc-ir-nrc", VplMode::SmcSource),
            ("smc-ir", VplMode::Smc),
            ("ir", VplMode::Classic),
        ] {
            let Some(rest) = s.strip_prefix(prefix) else {
                continue;
            };
            let params = match rest.strip_prefix(':') {
                Some(p) => p,
                None if rest.is_empty() => "",
                None => continue,
            };
            let mut set = IrSettings {
                mode,
                ..Default::default()
            };
            for param in pass_params(s, params) {
                let p = param?;
                match p.key {
                    "vpls" => set.vpls = p.count()?,
                    "mmax" => set.m_max = p.count()?,
                    "per_pixel" => set.per_pixel = p.count()?,
                    "clamp" => set.clamp = p.real()?,
                    "residual" => set.residual = p.flag()?,
                    "spp" => set.radiosity_spp = p.count()?,
                    "rate" => set.rate = p.count()?,
                    "warmup" => set.warmup = p.count()?,
                    "points" => set.visible_points = p.count()?,
                    "indirect" => set.indirect = p.flag()?,
                    k => {
                        return Err(format!(
                            "pass `{s}`: unknown parameter `{k}` (known: vpls, mmax, per_pixel, clamp, residual, spp, rate, warmup, points, indirect)"
                        ));
                    }
                }
            }
            set.validate().map_err(|e| format!("pass `{s}`: {e}"))?;
            return Ok(Self::InstantRadiosity(set));
        }
        if let Some(rest) = s.strip_prefix("restir-di") {
            let (variant, params) = rest.split_once(':').unwrap_or((rest, ""));
            let mut set = RestirDiSettings {
                biased: match variant {
                    "" => false,
                    "-biased" => true,
                    _ => return Err(err()),
                },
                ..Default::default()
            };
            for param in pass_params(s, params) {
                let p = param?;
                match p.key {
                    "light" => set.light_candidates = p.count()?,
                    "bsdf" => set.bsdf_candidates = p.count()?,
                    "k" => set.spatial_neighbours = p.count()?,
                    "radius" => set.spatial_radius = p.real()?,
                    "mcap" => set.m_cap = p.real()?,
                    "temporal" => set.temporal = p.flag()?,
                    "jitter" => set.jitter = p.flag()?,
                    k => {
                        return Err(format!(
                            "pass `{s}`: unknown parameter `{k}` (known: light, bsdf, k, radius, mcap, temporal, jitter)"
                        ));
                    }
                }
            }
            set.validate().map_err(|e| format!("pass `{s}`: {e}"))?;
            return Ok(Self::RestirDi(set));
        }
        for (prefix, light) in [
            ("ddgi-nrc-restir", SurfaceLight::CacheProbes),
            ("ddgi-restir", SurfaceLight::Probes),
            ("nrc-restir", SurfaceLight::Cache),
        ] {
            let Some(rest) = s.strip_prefix(prefix) else {
                continue;
            };
            let params = match rest.strip_prefix(':') {
                Some(p) => p,
                None if rest.is_empty() => "",
                None => return Err(err()),
            };
            let mut set = DdgiRestirSettings {
                light,
                ..Default::default()
            };
            for param in pass_params(s, params) {
                let p = param?;
                match p.key {
                    "light" => set.light_candidates = p.count()?,
                    "bsdf" => set.bsdf_candidates = p.count()?,
                    "k" => set.spatial_neighbours = p.count()?,
                    "radius" => set.spatial_radius = p.real()?,
                    "mcap" => set.m_cap = p.real()?,
                    "temporal" => set.temporal = p.flag()?,
                    "clamp" => set.clamp = p.real()?,
                    "residual" => set.residual = p.flag()?,
                    "requery" => set.requery = p.flag()?,
                    "jitter" => set.jitter = p.flag()?,
                    "smooth" => set.smooth = p.real()?,
                    "footprint" => set.footprint = p.real()?,
                    _ if light != SurfaceLight::Cache && volume_param(&mut set.ddgi, &p)? => {}
                    k => {
                        return Err(format!(
                            "pass `{s}`: unknown parameter `{k}` (known: light, bsdf, k, radius, mcap, temporal, \
                             clamp, residual, requery, jitter, smooth, footprint{})",
                            if light == SurfaceLight::Cache {
                                ""
                            } else {
                                ", probes, rays, hysteresis, relocate, classify, attenuation"
                            }
                        ));
                    }
                }
            }
            set.validate().map_err(|e| format!("pass `{s}`: {e}"))?;
            return Ok(Self::DdgiRestir(set));
        }
        if let Some(rest) = s.strip_prefix("ddgi-") {
            let (term, params) = rest.split_once(':').unwrap_or((rest, ""));
            // `diffuse:R` style terminations take no parameters here (their defaults).
            let termination = term
                .parse::<Termination>()
                .map_err(|e| format!("pass `{s}`: {e}"))?;
            let mut settings = crate::ddgi::DdgiSettings::default();
            for param in pass_params(s, params) {
                let p = param?;
                match p.key {
                    _ if volume_param(&mut settings, &p)? => {}
                    "radiance" => {
                        settings.radiance = match p.value {
                            "full" => crate::ddgi::ProbeRadiance::Full,
                            "indirect" => crate::ddgi::ProbeRadiance::Indirect,
                            "nrc" => crate::ddgi::ProbeRadiance::Source,
                            _ => return Err(p.bad()),
                        }
                    }
                    k => {
                        return Err(format!(
                            "pass `{s}`: unknown parameter `{k}` (known: probes, rays, hysteresis, relocate, classify, attenuation, radiance)"
                        ));
                    }
                }
            }
            let unit = nrc_scene::Aabb {
                min: glam::Vec3::ZERO,
                max: glam::Vec3::ONE,
            };
            crate::ddgi::ProbeVolume::new(&unit, settings)
                .map_err(|e| format!("pass `{s}`: {e}"))?;
            return Ok(Self::DdgiTerminated {
                termination,
                settings,
            });
        }
        for (prefix, world) in [("wsrestir-gi", true), ("restir-gi", false)] {
            let Some(rest) = s.strip_prefix(prefix) else {
                continue;
            };
            let (variant, params) = rest.split_once(':').unwrap_or((rest, ""));
            let (variant, cache) = match variant.strip_suffix("-nrc") {
                Some(v) => (v, true),
                None => (variant, false),
            };
            let biased = match variant {
                "" => false,
                "-biased" => true,
                _ => return Err(err()),
            };
            let mut set = RestirGiSettings {
                world,
                cache,
                biased,
                ..Default::default()
            };
            for param in pass_params(s, params) {
                let p = param?;
                match (p.key, world) {
                    ("k", false) => set.spatial_neighbours = p.count()?,
                    ("radius", false) => set.spatial_radius = p.real()?,
                    ("samples", true) => set.grid_samples = p.count()?,
                    ("cell", true) => set.cell_scale = p.real()?,
                    ("dmin", true) => set.d_min = p.real()?,
                    ("mcap", _) => set.m_cap = p.real()?,
                    ("temporal", _) => set.temporal = p.flag()?,
                    ("jitter", _) => set.jitter = p.flag()?,
                    ("jacobian", _) => set.jacobian = p.flag()?,
                    (k, _) => {
                        return Err(format!(
                            "pass `{s}`: unknown parameter `{k}` (known: {})",
                            if world {
                                "samples, cell, dmin, mcap, temporal, jitter, jacobian"
                            } else {
                                "k, radius, mcap, temporal, jitter, jacobian"
                            }
                        ));
                    }
                }
            }
            set.validate().map_err(|e| format!("pass `{s}`: {e}"))?;
            return Ok(Self::RestirGi(set));
        }
        let rest = s.strip_prefix("cache").ok_or_else(err)?;
        let (rest, nee) = match rest.strip_suffix("-nonee") {
            Some(r) => (r, false),
            None => (rest, true),
        };
        let termination = match rest {
            "" => Termination::default(),
            r => r
                .strip_prefix('-')
                .ok_or_else(err)?
                .parse::<Termination>()
                .map_err(|e| format!("pass `{s}`: {e}"))?,
        };
        Ok(Self::CacheTerminated { termination, nee })
    }
}

impl fmt::Display for PassSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::PathTraced { strategy } => f.write_str(match strategy {
                LightStrategy::Mis => "pt",
                LightStrategy::BsdfOnly => "pt-nonee",
                LightStrategy::LightOnly => "pt-light",
            }),
            Self::CacheTerminated { termination, nee } => {
                f.write_str("cache")?;
                if termination != Termination::default() {
                    write!(f, "-{termination}")?;
                }
                if !nee {
                    f.write_str("-nonee")?;
                }
                Ok(())
            }
            Self::RestirDi(set) => {
                f.write_str(if set.biased {
                    "restir-di-biased"
                } else {
                    "restir-di"
                })?;
                let d = RestirDiSettings::default();
                let mut params = Vec::new();
                param(
                    &mut params,
                    "light",
                    set.light_candidates,
                    d.light_candidates,
                );
                param(&mut params, "bsdf", set.bsdf_candidates, d.bsdf_candidates);
                param(
                    &mut params,
                    "k",
                    set.spatial_neighbours,
                    d.spatial_neighbours,
                );
                param(&mut params, "radius", set.spatial_radius, d.spatial_radius);
                param(&mut params, "mcap", set.m_cap, d.m_cap);
                param(
                    &mut params,
                    "temporal",
                    set.temporal as u32,
                    d.temporal as u32,
                );
                param(&mut params, "jitter", set.jitter as u32, d.jitter as u32);
                if !params.is_empty() {
                    write!(f, ":{}", params.join(","))?;
                }
                Ok(())
            }
            Self::DdgiTerminated {
                termination,
                settings,
            } => {
                write!(f, "ddgi-{termination}")?;
                let mut params = Vec::new();
                volume_params(&mut params, &settings);
                match settings.radiance {
                    crate::ddgi::ProbeRadiance::Full => {}
                    crate::ddgi::ProbeRadiance::Indirect => params.push("radiance=indirect".into()),
                    crate::ddgi::ProbeRadiance::Source => params.push("radiance=nrc".into()),
                }
                if !params.is_empty() {
                    write!(f, ":{}", params.join(","))?;
                }
                Ok(())
            }
            Self::InstantRadiosity(set) => f.write_str(&set.name()),
            Self::DdgiRestir(set) => {
                f.write_str(match set.light {
                    SurfaceLight::Probes => "ddgi-restir",
                    SurfaceLight::Cache => "nrc-restir",
                    SurfaceLight::CacheProbes => "ddgi-nrc-restir",
                })?;
                let d = DdgiRestirSettings::default();
                let mut params = Vec::new();
                param(
                    &mut params,
                    "light",
                    set.light_candidates,
                    d.light_candidates,
                );
                param(&mut params, "bsdf", set.bsdf_candidates, d.bsdf_candidates);
                param(
                    &mut params,
                    "k",
                    set.spatial_neighbours,
                    d.spatial_neighbours,
                );
                param(&mut params, "radius", set.spatial_radius, d.spatial_radius);
                param(&mut params, "mcap", set.m_cap, d.m_cap);
                param(
                    &mut params,
                    "temporal",
                    set.temporal as u32,
                    d.temporal as u32,
                );
                param(&mut params, "clamp", set.clamp, d.clamp);
                param(
                    &mut params,
                    "residual",
                    set.residual as u32,
                    d.residual as u32,
                );
                param(&mut params, "requery", set.requery as u32, d.requery as u32);
                param(&mut params, "jitter", set.jitter as u32, d.jitter as u32);
                param(&mut params, "smooth", set.smooth, d.smooth);
                param(&mut params, "footprint", set.footprint, d.footprint);
                volume_params(&mut params, &set.ddgi);
                if !params.is_empty() {
                    write!(f, ":{}", params.join(","))?;
                }
                Ok(())
            }
            Self::RestirGi(set) => {
                f.write_str(if set.world {
                    "wsrestir-gi"
                } else {
                    "restir-gi"
                })?;
                if set.biased {
                    f.write_str("-biased")?;
                }
                if set.cache {
                    f.write_str("-nrc")?;
                }
                let d = RestirGiSettings::default();
                let mut params = Vec::new();
                if set.world {
                    param(&mut params, "samples", set.grid_samples, d.grid_samples);
                    param(&mut params, "cell", set.cell_scale, d.cell_scale);
                    param(&mut params, "dmin", set.d_min, d.d_min);
                } else {
                    param(
                        &mut params,
                        "k",
                        set.spatial_neighbours,
                        d.spatial_neighbours,
                    );
                    param(&mut params, "radius", set.spatial_radius, d.spatial_radius);
                }
                param(&mut params, "mcap", set.m_cap, d.m_cap);
                param(
                    &mut params,
                    "temporal",
                    set.temporal as u32,
                    d.temporal as u32,
                );
                param(
                    &mut params,
                    "jacobian",
                    set.jacobian as u32,
                    d.jacobian as u32,
                );
                param(&mut params, "jitter", set.jitter as u32, d.jitter as u32);
                if !params.is_empty() {
                    write!(f, ":{}", params.join(","))?;
                }
                Ok(())
            }
        }
    }
}

impl serde::Serialize for PassSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for PassSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

impl PassSpec {
    /// Whether the pass keeps state across frames (history, reservoirs): such passes get
    /// warm-up frames and a [`RenderPass::reset`] per independent run.
    pub fn is_stateful(&self) -> bool {
        matches!(
            self,
            Self::RestirDi(_)
                | Self::RestirGi(_)
                | Self::DdgiTerminated { .. }
                | Self::DdgiRestir(_)
                | Self::InstantRadiosity(IrSettings {
                    mode: VplMode::Smc | VplMode::SmcSource,
                    ..
                })
        )
    }

    /// Whether the pass asks a radiance source anything.
    pub fn uses_source(&self) -> bool {
        matches!(
            self,
            Self::CacheTerminated { .. }
                | Self::RestirGi(RestirGiSettings { cache: true, .. })
                | Self::DdgiTerminated {
                    settings: crate::ddgi::DdgiSettings {
                        radiance: crate::ddgi::ProbeRadiance::Source,
                        ..
                    },
                    ..
                }
        ) || matches!(self, Self::DdgiRestir(s) if s.light != SurfaceLight::Probes)
            || matches!(
                self,
                Self::InstantRadiosity(IrSettings {
                    mode: VplMode::SmcSource,
                    ..
                })
            )
    }

    /// The pass's state, with `tracer`'s depth limit and Russian roulette (its light strategy
    /// is the pass's own).
    pub fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        match *self {
            Self::PathTraced { strategy } => Box::new(PathTracedPass::new(PathTracer {
                strategy,
                ..*tracer
            })),
            Self::CacheTerminated { termination, nee } => {
                Box::new(CacheTerminatedPass::new(termination, nee, tracer))
            }
            Self::RestirDi(set) => Box::new(RestirDiPass::new(set, tracer)),
            Self::RestirGi(set) => Box::new(RestirGiPass::new(set, tracer)),
            Self::DdgiTerminated {
                termination,
                settings,
            } => Box::new(DdgiTerminatedPass::new(termination, settings, tracer)),
            Self::DdgiRestir(set) => Box::new(DdgiRestirPass::new(set, tracer)),
            Self::InstantRadiosity(set) => Box::new(InstantRadiosityPass::new(set, *tracer)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_print_and_round_trip_through_json() {
        for name in [
            "pt",
            "pt-nonee",
            "pt-light",
            "cache",
            "cache-first",
            "cache-diffuse:0.5",
            "cache-bth:8",
            "cache-nonee",
            "cache-first-nonee",
            "ir",
            "smc-ir",
            "smc-ir-nrc:vpls=256,mmax=8,residual=1",
            "ir:per_pixel=0,clamp=0.05,indirect=1",
            "restir-di",
            "restir-di-biased",
            "restir-di:light=16,k=3",
            "restir-di-biased:bsdf=0,radius=10,mcap=4,temporal=0,jitter=0",
            "restir-gi",
            "restir-gi-biased",
            "restir-gi-nrc",
            "restir-gi-biased-nrc:k=5,radius=12",
            "wsrestir-gi",
            "wsrestir-gi-nrc",
            "wsrestir-gi-biased:samples=5,cell=0.05,dmin=0.02,mcap=10,temporal=0,jacobian=0,jitter=0",
            "cache-secondary",
            "ddgi-secondary",
            "ddgi-first:probes=4,rays=64,hysteresis=0.9,radiance=indirect",
            "ddgi-secondary:radiance=nrc",
            "ddgi-secondary:relocate=1,classify=1",
            "ddgi-restir",
            "nrc-restir",
            "ddgi-nrc-restir",
            "ddgi-restir:light=4,bsdf=2,k=0,radius=10,mcap=5,temporal=0,clamp=0,residual=0,requery=1,jitter=0,smooth=0.5,footprint=0.2,probes=4,rays=64,hysteresis=0.9,relocate=1,classify=1,attenuation=0.5",
            "nrc-restir:clamp=0.05",
        ] {
            let spec: PassSpec = name.parse().unwrap();
            assert_eq!(spec.to_string(), name);
            let json = serde_json::to_string(&spec).unwrap();
            assert_eq!(serde_json::from_str::<PassSpec>(&json).unwrap(), spec);
        }
        assert_eq!(
            "cache-spread".parse::<PassSpec>().unwrap().to_string(),
            "cache"
        );
        for bad in [
            "",
            "ptx",
            "cache-",
            "cache-last",
            "cachefirst",
            "cache-spread:0",
            "pt-first",
            "restir-di-",
            "restir-di:light",
            "restir-di:light=x",
            "restir-di:nope=1",
            "restir-di:light=0,bsdf=0",
            "restir-di:mcap=-1",
            "restir-di:light=4294967295,bsdf=1",
            "restir-di:k=100000",
            "restir-gi:k=4000000000",
            "wsrestir-gi:samples=100000",
            "ddgi-secondary:probes=100",
            "ddgi-secondary:rays=1000000000",
            "restir-di:radius=nan",
            "restir-gi-nrc-biased",
            "restir-gi:samples=3",
            "wsrestir-gi:k=3",
            "wsrestir-gi:cell=0",
            "ddgi-",
            "ddgi-secondary:probes=0",
            "ddgi-secondary:hysteresis=1",
            "ddgi-secondary:radiance=x",
            "ddgi-restirx",
            "nrc-restir:probes=4",
            "nrc-restir:requery=1",
            "ddgi-restir:bsdf=0",
            "nrc-restir:classify=1",
            "ddgi-restir:clamp=-1",
            "ddgi-restir:clamp=nan",
            "ddgi-nrc-restir:probes=0",
        ] {
            let e = bad.parse::<PassSpec>().unwrap_err();
            assert!(e.contains("pass"), "{bad}: {e}");
        }
        assert!(serde_json::from_str::<PassSpec>("\"cache-nope\"").is_err());
    }
}
