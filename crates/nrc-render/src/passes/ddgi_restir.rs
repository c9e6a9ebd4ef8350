//! DDGI resampling (the seed paper `ddgi-resampling.txt`, §3.2–3.7): the whole scene surface
//! as the light of ReSTIR at the primary vertex, each surface point shining with its emission
//! plus a radiance source's estimate of the light it reflects. Three passes share this file:
//!
//! - `ddgi-restir` (the paper's method): the source is a DDGI probe volume the pass keeps and
//!   updates every frame (eq. 5 probes; all of them, or the share of a frame-sized volume the
//!   frame's ray budget affords, in turn), answering `L_DDGI+` of eq. 6 (the diffuse `ρ/π E`
//!   plus one sample of the glossy integral);
//! - `nrc-restir` (beyond the paper): the neural cache, trained online by the harness, as the
//!   light: it answers the reflected radiance in every direction, where the probes hold only
//!   irradiance;
//! - `ddgi-nrc-restir`: probes whose rays take their radiance from the cache at their hits.
//!
//! Per frame and pixel sample at the primary vertex `x` (non-delta, perceptual roughness at
//! least `smooth` = 0.2; delta and near-specular primaries are path traced, whole or, with
//! `smoothend=1` (`nrc-restir`'s default), to their first rough vertex, where the source's
//! answer ends them):
//!
//! 1. **Candidates** (§3.2 step 1; as the paper, with `direct=0`): `light` points from the
//!    light sampler and `bsdf` BSDF samples, each ray's first hit a candidate wherever it lands (an escaped ray: the
//!    environment). A surface candidate `y` carries its emission and the source's radiance
//!    `L_src(y → x)`; its target is `p̂(y) = lum(f · (L_e + L_src) · min(G, G_max))` in area
//!    measure, with the balance-heuristic RIS weight `p̂ / (M_l p_l + M_b p_b)` (`p_l` the light
//!    sampler's area density, zero off emitters; `p_b` the BSDF density converted to area).
//!    Punctual and environment samples enter in their own measures, unclamped, as in ReSTIR DI.
//!
//!    With `direct=1`, the default, the emission leaves the reservoir: the direct light at `x`
//!    is the path tracer's next-event estimation (one light sample and its shadow ray, the
//!    first BSDF candidate's ray as the path's BSDF sample, MIS by the power heuristic, and
//!    the tracer's extra glossy samples), no light candidates are drawn, escaped BSDF rays
//!    are no candidates, and the surface candidates carry only `L_src`. On the
//!    Country Kitchen most of the window is hidden from most points behind its frame and
//!    blinds, so an unshadowed target keeps choosing occluded points of it (RESULTS.md, "The
//!    direct light out of the reservoir").
//! 2. **Spatial then temporal reuse** (§3.2 step 2): `k` screen neighbours' initial
//!    reservoirs, then (`temporal=1`; off by default) the previous frame's final one at the
//!    reprojected pixel (`M` capped); each merge is unbiased, by pairwise MIS ([`reuse::Merge`]; `pairwise=0`: `1/Z` over the
//!    owners that see `y`), one shadow ray per reused reservoir.
//!    A reused sample keeps the source radiance its finder stored (§3.7's query reuse: the
//!    target is approximate, the estimator stays unbiased for its integrand because the BSDF
//!    candidates cover every direction); `requery=1` (probes only) evaluates `L_DDGI+` toward
//!    each receiver instead. The history's samples are asked again each frame: with a source
//!    whose every answer is fresh noise, a sample kept because its last answer was high is
//!    then weighed by that answer and shaded with a new one, which darkens the image (3 % at
//!    a few pixels of the exact-source test with `direct=1,temporal=1`, where the exact
//!    emission does not dilute it: `tests/ddgi_restir.rs`); a trained cache answers
//!    deterministically and changes slowly.
//! 3. **Shading** (§3.2 steps 3–4): one shadow ray to the chosen sample where reuse brought
//!    it (the pixel's own was shadow-tested, or found by its BSDF ray), `f · L · G_c · W`.
//! 4. **Residual** (§3.6, eq. 9): the clamped-away part `max(0, 1 − G_max/G)` of the
//!    first BSDF candidate's own estimate `f cos / p · L`, which needs no extra ray (the
//!    paper's auxiliary BSDF sample is that candidate). A delta lobe of a mixed BSDF, which
//!    the reservoir cannot hold, is estimated the same way, whole.
//!
//! `G_max = 1 / (clamp · diagonal)²`: the paper's `G_max = 1 m⁻²` is absolute, which in a
//! small box clamps almost every pair of points (`../shared/PASSES.md`); relative to the
//! scene's extent, `clamp = 0.1` clamps pairs closer than a tenth of the diagonal (about the
//! paper's metre in its rooms). `clamp=0` turns the clamp off; `residual=0` drops the residual
//! (biased: the negative control of the unbiasedness test).
//!
//! What the estimator converges to is `L_e(x) + T(L_e + L_src)`: exact where the source is
//! exact, and, with probes or a cache, biased by the source's error one bounce away from the
//! camera (the paper's premise: the error is hidden behind a scattering event); with
//! `smoothend=1` a smooth primary shows the source's error through its glossy chain, less
//! hidden. §3.3's
//! attenuation of `L_e` in the probe update is the volume's option (`attenuation=S`). The
//! near-specular recursion of eqs. 7–8 (`footprint=c`, the paper's 0.2; off by default, see
//! the setting) follows, at shading,
//! the chosen glossy sample point's lobe until the path's footprint is wide enough to blur the
//! probes, in the probe modes; with the cache as the light the sample point's radiance is the
//! cache's answer (it holds glossy radiance in every direction, and is asked once a frame).

use std::f32::consts::PI;
use std::time::Instant;

use glam::Vec3;
use nrc_scene::{Hit, LightSample, Ray, Scene, sampling::luminance, spawn_ray};

use crate::error::SettingsError;
use super::restir_di;
use super::reuse::{self, History, Merge, Resampling, Slot};
use super::screen::{GBuffer, Phase, Primary, par_map, stream, visible_between};
use super::params::{Key, Params, Value};
use super::screen::MAX;
use super::spec::{PassConfig, PassKind, parse_variant};
use super::frame::{FrameInput, PassOutput, PhaseTimes, RenderPass};
use crate::ddgi::{DdgiSettings, ProbeRadiance, ProbeRays, ProbeVolume};
use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::Stream;
use crate::reservoir::Reservoir;
use crate::sampler::PixelSampler;
use crate::source::{RadianceQuery, usable_answer};
use crate::spread::Spread;
use crate::transport::{Arrival, PathWalk, Vertex};
use rayon::prelude::*;

/// What lights the scene's surfaces in the resampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceLight {
    /// A DDGI volume with eq. 5 probes (`ddgi-restir`).
    Probes,
    /// The radiance source (the neural cache; `nrc-restir`).
    Cache,
    /// A DDGI volume whose rays ask the radiance source at their hits (`ddgi-nrc-restir`).
    CacheProbes,
}

pub const KIND: PassKind = PassKind {
    grammar: "ddgi-restir, nrc-restir, ddgi-nrc-restir",
    about: "DDGI resampling: at the primary vertex, BSDF-sampled surface points resampled by \
            the radiance they reflect (eq. 6) from probes (ddgi-restir), the cache \
            (nrc-restir) or cache-fed probes (ddgi-nrc-restir), the direct light by the path \
            tracer's NEE (direct=0: emitters and light-sampler candidates in the reservoir, \
            the paper), the geometry term clamped at 1/(clamp · diagonal)² with the residual \
            of eq. 9; spatial reuse (temporal=1: and temporal), a shadow ray to a reused chosen sample",
    method: true,
    variants: || variants().into_iter().map(|(_, s)| s.into()).collect(),
    parse: |name| parse_variant(name, &variants(), DdgiRestirSettings::validate),
};

fn variants() -> [(&'static str, DdgiRestirSettings); 3] {
    let d = DdgiRestirSettings::default();
    [
        ("ddgi-restir", d),
        (
            "nrc-restir",
            DdgiRestirSettings {
                light: SurfaceLight::Cache,
                smooth_ends_in_source: true,
                ..d
            },
        ),
        ("ddgi-nrc-restir", DdgiRestirSettings { light: SurfaceLight::CacheProbes, ..d }),
    ]
}

/// DDGI resampling's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdgiRestirSettings {
    pub light: SurfaceLight,
    /// Light-sampler candidates per pixel sample ("a small number", §3.2); none are drawn
    /// with [`DdgiRestirSettings::direct_nee`].
    pub light_candidates: u32,
    /// BSDF-sampled candidates (a ray each); the first also estimates the residual.
    pub bsdf_candidates: u32,
    /// Spatial neighbours (the paper: 3) and their disc's radius in pixels.
    pub spatial_neighbours: u32,
    pub spatial_radius: f32,
    /// Reuse the previous frame's reservoir (the paper: 1 temporal candidate). Off by default:
    /// measured on the kitchen and the four door scenes with the direct light by NEE, the
    /// history cost more time than it saved error in every case, at equal time, whether
    /// frames were averaged (their shared history correlates them) or a single warm frame
    /// was judged (the kitchen); RESULTS.md, "The direct light out of the reservoir".
    pub temporal: bool,
    /// With `temporal`, the history's `M` is capped at this multiple of the candidate count
    /// (a frame's candidates: 9 with `direct=0`, 1 with `direct=1`): 5 by default, not
    /// ReSTIR DI's 20. Consecutive frames of a view that stands still share their history's
    /// samples, and the longer it is kept the less their average gains from each new frame:
    /// at 8 frames averaged and equal samples, 5 gave lower MSE than 20 on the kitchen, the
    /// Cornell box and `glossy` for `ddgi-restir` and `nrc-restir` (and on `ajar` for
    /// `ddgi-restir`; `caustics` is decided by single fireflies), and a single frame's error
    /// on the kitchen fell too (RESULTS.md, "Where a pass's frame time goes");
    /// `ddgi-nrc-restir` shares the default.
    pub m_cap: f32,
    /// Merges by pairwise MIS (off: 1/Z), [`reuse::Merge`].
    pub pairwise: bool,
    /// `G_max = 1/(clamp · diagonal)²`; 0: no clamp.
    pub clamp: f32,
    /// Estimate the clamped-away transport (eq. 9); off: biased.
    pub residual: bool,
    /// Probes: evaluate `L_DDGI+` toward each receiver instead of reusing the finder's (§3.7).
    pub requery: bool,
    /// Jitter camera rays in the pixel.
    pub jitter: bool,
    /// Primaries of perceptual roughness below this are path traced, as delta ones are (the
    /// paper traces near-specular transport recursively; a reservoir of 9 candidates cannot
    /// follow a mirror-like lobe, and neighbours' samples rarely fall in it). 0: delta only.
    pub smooth: f32,
    /// Eqs. 7–8's threshold `c` of the near-specular recursion (the paper's 0.2; 0, the
    /// default: off, because on the shipped glossy scene the paper's 0.2 raised a frame's MSE
    /// by 76 % for 14 % less bias², RESULTS.md): at
    /// shading, the chosen glossy sample point's radiance follows its glossy lobe while the
    /// path's footprint from the primary vertex stays below `c · a0`, then ends in eq. 6
    /// (probe modes; the resampling's targets keep eq. 6 itself, as in the paper).
    pub footprint: f32,
    /// The direct light at the primary vertex by the path tracer's next-event estimation (one
    /// light sample and the first BSDF candidate, by MIS, with the tracer's extra glossy
    /// samples), and the reservoir resampling only the light the surfaces reflect (emission
    /// excluded, no light candidates). Off: emitters are surfaces of the reservoir like any
    /// other (the paper, §3.2), whose unshadowed targets choose occluded points of a window
    /// behind blinds. On by default (RESULTS.md, "The direct light out of the reservoir").
    /// See [`DdgiRestirSettings::light_candidates_used`].
    pub direct_nee: bool,
    /// Primaries smoother than `smooth` (glossy and mirror-like, which the reservoir does not
    /// serve) are path traced to their first vertex of roughness at least `smooth` and end in
    /// the source there (the cache's answer, or the probes' `L_DDGI+`), instead of being path
    /// traced whole: their direct light at each vertex before it is NEE's, as the path
    /// tracer's. Biased by the source's error seen through the glossy chain, as the rest of
    /// the image is by the source's error one bounce away. With a depth limit, a chain ends
    /// only at its second vertex (where the candidates, whose source answers match the limit
    /// there, sit); longer chains are traced whole. On for `nrc-restir`, whose cache answers
    /// the radiance leaving a point in each direction (at equal samples lower error on
    /// `glossy` and `caustics`, within 2 % on the Cornell box and `ajar`; on the kitchen
    /// within the runs' spread); off for the probe modes, whose `L_DDGI+` is irradiance and
    /// one glossy sample (6–38 % higher error on the door scenes). RESULTS.md, "The direct
    /// light out of the reservoir".
    pub smooth_ends_in_source: bool,
    /// The probe volume (probe modes).
    pub ddgi: DdgiSettings,
}

impl Default for DdgiRestirSettings {
    fn default() -> Self {
        Self {
            light: SurfaceLight::Probes,
            light_candidates: 8,
            bsdf_candidates: 1,
            spatial_neighbours: 3,
            spatial_radius: 30.0,
            temporal: false,
            m_cap: 5.0,
            pairwise: true,
            clamp: 0.1,
            residual: true,
            requery: false,
            jitter: true,
            smooth: 0.2,
            footprint: 0.0,
            direct_nee: true,
            smooth_ends_in_source: false,
            ddgi: DdgiSettings::default(),
        }
    }
}

impl DdgiRestirSettings {
    /// Errors for settings that cannot work.
    pub fn validate(&self) -> Result<(), SettingsError> {
        reuse::validate_reuse(
            &[
                self.light_candidates,
                self.bsdf_candidates,
                self.spatial_neighbours,
            ],
            self.spatial_radius,
            self.m_cap,
        )?;
        if self.bsdf_candidates == 0 {
            return Err(SettingsError::Combination(
                "at least one BSDF candidate is needed (it covers every surface)",
            ));
        }
        if !(self.footprint >= 0.0 && self.footprint <= 1e3) {
            return Err(SettingsError::bounds(
                "footprint",
                "lie in [0, 1000]",
                self.footprint,
            ));
        }
        if !(0.0..=1.0).contains(&self.smooth) {
            return Err(SettingsError::bounds("smooth", "lie in [0, 1]", self.smooth));
        }
        if !(self.clamp >= 0.0 && self.clamp <= 10.0) {
            return Err(SettingsError::bounds("clamp", "lie in [0, 10]", self.clamp));
        }
        if self.requery && self.light == SurfaceLight::Cache {
            return Err(SettingsError::Combination(
                "requery needs probes (the cache is asked once per frame)",
            ));
        }
        let unit = nrc_scene::Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        ProbeVolume::new(&unit, self.ddgi)?;
        Ok(())
    }

    fn uses_probes(&self) -> bool {
        self.light != SurfaceLight::Cache
    }

    /// The light-sampler candidates a pixel sample draws: none with [`DdgiRestirSettings::direct_nee`],
    /// whose reservoir holds no emission (a light sample would bring only what the emitter's
    /// own surface reflects, which the BSDF candidates cover).
    pub fn light_candidates_used(&self) -> u32 {
        if self.direct_nee { 0 } else { self.light_candidates }
    }
}

impl Params for DdgiRestirSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        let light = Key::new("light", "light-sampler candidates per pixel sample (none with direct=1)");
        f(&light.range(0.0, MAX), &mut self.light_candidates);
        let bsdf = Key::new("bsdf", "BSDF-sampled candidates (the first also for the residual)");
        f(&bsdf.range(1.0, MAX), &mut self.bsdf_candidates);
        let (k, radius) = (&mut self.spatial_neighbours, &mut self.spatial_radius);
        let (m_cap, temporal, pairwise) = (&mut self.m_cap, &mut self.temporal, &mut self.pairwise);
        reuse::visit_reuse(f, k, radius, m_cap, temporal, pairwise);
        let clamp = Key::new("clamp", "G_max = 1/(clamp · diagonal)²; 0: no clamp");
        f(&clamp.range(0.0, 10.0), &mut self.clamp);
        let residual = Key::new("residual", "estimate the clamped-away transport (eq. 9)");
        f(&residual, &mut self.residual);
        if self.uses_probes() {
            let requery = Key::new("requery", "evaluate the probes toward each receiver (§3.7)");
            f(&requery, &mut self.requery);
        }
        f(&Key::new("jitter", "jitter camera rays in the pixel"), &mut self.jitter);
        let smooth = Key::new("smooth", "primaries smoother than this are path traced");
        f(&smooth.range(0.0, 1.0), &mut self.smooth);
        let footprint = Key::new("footprint", "eqs. 7-8's near-specular recursion, c (0: off)");
        f(&footprint.range(0.0, 1e3), &mut self.footprint);
        let direct = Key::new(
            "direct",
            "the direct light by the path tracer's NEE, the reservoir only the reflected light",
        );
        f(&direct, &mut self.direct_nee);
        let smooth_end = Key::new(
            "smoothend",
            "smooth primaries' paths end in the source at their first rough vertex (0: traced whole)",
        );
        f(&smooth_end, &mut self.smooth_ends_in_source);
        if self.uses_probes() {
            self.ddgi.visit(f);
        }
    }
}

impl PassConfig for DdgiRestirSettings {
    /// (measured 1,160 (`ddgi-restir`) and 1,244 (`nrc-restir`).)
    fn state_bytes_per_sample(&self) -> u64 {
        1_300
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let (base, defaults) = variants()
            .into_iter()
            .find(|(_, d)| d.light == self.light)
            .expect("every light is a variant");
        super::params::name(base, self, &defaults)
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(DdgiRestirPass::new(*self, tracer))
    }

    fn is_stateful(&self) -> bool {
        true
    }

    fn uses_source(&self) -> bool {
        self.light != SurfaceLight::Probes
    }

    fn params(&self) -> Vec<super::params::Param> {
        super::params::list(self)
    }
}

/// A surface point as a light: what it emits and what the source says it reflects toward the
/// vertex that found it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    pub x: Vec3,
    /// Geometric normal.
    pub ng: Vec3,
    /// Emission of the front face (`ng`'s side), and whether the back face emits too.
    pub le: Vec3,
    pub two_sided: bool,
    /// The source's reflected radiance toward the finder, valid on the finder's side.
    pub l: Vec3,
    /// Sign of `ng · (finder − x)`.
    pub side: f32,
    /// The light sampler's area density at `x` (zero off emitters).
    pub pdf_light: f32,
    /// Its triangle (to find the surface again when the history's radiance is refreshed).
    pub tri: u32,
    /// Diffuse reflectance (for `requery`).
    pub rho: Vec3,
}

/// A resampled light: a surface point, or a punctual or environment light sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DdgiSample {
    Surface(SurfacePoint),
    Light(LightSample),
}

pub type DdgiReservoir = Reservoir<DdgiSample>;

/// What a sample brings to a vertex, unshadowed.
#[derive(Clone, Copy, Debug)]
struct Contribution {
    /// Per unit of the sample's measure: `f · L · min(G, G_max)` for surfaces.
    c: Vec3,
    target: f32,
    p_light: f32,
    p_bsdf: f32,
}

/// The constants a frame's contributions need.
#[derive(Clone, Copy)]
struct Ctx<'a> {
    g_max: f32,
    /// `requery`: the volume that answers toward every receiver.
    requery: Option<&'a ProbeVolume>,
}

#[inline]
fn contribution(ctx: &Ctx, v: &Vertex, y: &DdgiSample) -> Option<Contribution> {
    match y {
        DdgiSample::Light(ls) => {
            let c = restir_di::contribution(v, ls)?;
            Some(Contribution {
                c: c.c,
                target: c.target,
                p_light: c.p_light,
                p_bsdf: c.p_bsdf,
            })
        }
        DdgiSample::Surface(y) => {
            let a = arriving(ctx, y, v.si.p)?;
            let wl = v.frame.to_local(a.wi);
            let f = v.bsdf.eval(v.wo, wl);
            let g = wl.z.abs() * a.cos_y / a.dist2;
            let c = f * a.li * g.min(ctx.g_max);
            let target = luminance(c);
            if !(target > 0.0 && target.is_finite()) {
                return None;
            }
            Some(Contribution {
                c,
                target,
                p_light: y.pdf_light,
                p_bsdf: v.bsdf.pdf(v.wo, wl) * a.cos_y / a.dist2,
            })
        }
    }
}

/// The light of surface point `y` arriving at point `p`.
struct Arriving {
    /// Unit direction from `p` to `y`.
    wi: Vec3,
    dist2: f32,
    /// `|cos|` at `y`.
    cos_y: f32,
    /// `L_e + L_src` from `y` toward `p`.
    li: Vec3,
}

#[inline]
fn arriving(ctx: &Ctx, y: &SurfacePoint, p: Vec3) -> Option<Arriving> {
    let d = y.x - p;
    let dist2 = d.length_squared();
    let wi = d / dist2.sqrt();
    if !(dist2 > 0.0 && wi.is_finite()) {
        return None;
    }
    // Where the receiver lies seen from y.
    let side = -y.ng.dot(wi);
    let mut li = if y.two_sided || side > 0.0 {
        y.le
    } else {
        Vec3::ZERO
    };
    if side * y.side > 0.0 {
        li += match ctx.requery {
            Some(vol) => y.rho / PI * vol.irradiance(y.x, y.ng * side.signum(), -wi),
            None => y.l,
        };
    }
    Some(Arriving {
        wi,
        dist2,
        cos_y: side.abs(),
        li,
    })
}

/// Whether `v` sees sample `y`; counts the ray.
fn sees(scene: &Scene, v: &Vertex, y: &DdgiSample, stats: &mut PathStats) -> bool {
    match y {
        DdgiSample::Light(ls) => ls
            .incident(v.si.p)
            .is_some_and(|inc| restir_di::sees(scene, v, ls, &inc, stats)),
        DdgiSample::Surface(s) => visible_between(scene, v.si.p, v.si.ng, s.x, s.ng, stats),
    }
}

/// A candidate before its source radiance is known: the sample, and the vertex at a surface
/// point (asked for its radiance toward the finder; none for a light sample or a black
/// surface, whose reflected radiance is zero).
#[derive(Clone, Copy, Debug)]
struct Candidate {
    y: DdgiSample,
    at: Option<At>,
    from_bsdf: bool,
}

/// Where a surface candidate lies, for the source to answer the radiance it reflects: kept
/// small, since a frame holds every pixel's candidates until the source answers them all (whole
/// shading vertices, 9 a pixel, took 4.4 GiB at 1280 × 720: BENCHMARKS.md), and its vertex
/// rebuilt when it is asked (with the same bits from a hit; from a point, by its triangle's
/// interpolation at `p`, equal to rounding).
#[derive(Clone, Copy, Debug)]
enum At {
    /// A point `p` on triangle `tri`, seen from `wo`: a light sample's, or the surface the
    /// first BSDF candidate's ray found with `direct=1`.
    Point { tri: u32, p: Vec3, wo: Vec3 },
    /// A BSDF ray's hit, seen from the ray.
    Hit { ray: Ray, hit: Hit },
}

impl At {
    /// The surface point of `si`, seen from its `wo`.
    fn point(si: &nrc_scene::SurfaceInteraction) -> Self {
        At::Point {
            tri: si.tri,
            p: si.p,
            wo: si.wo,
        }
    }

    /// The direction the radiance is asked toward (world space, unit).
    fn wo(&self) -> Vec3 {
        match *self {
            At::Point { wo, .. } => wo,
            At::Hit { ray, .. } => -ray.d.normalize(),
        }
    }

    fn vertex(&self, scene: &Scene) -> Vertex {
        match *self {
            At::Point { tri, p, wo } => Vertex::new(scene, &scene.interaction_at(tri, p, wo), wo),
            At::Hit { ray, hit } => {
                let si = scene.interaction(&ray, &hit);
                Vertex::new(scene, &si, si.wo)
            }
        }
    }
}

/// The first BSDF candidate's own estimate: its weight `f cos / p` and whether it was a delta
/// lobe's (the residual of eq. 9, or the whole delta lobe).
#[derive(Clone, Copy, Debug)]
struct Aux {
    candidate: usize,
    weight: Vec3,
    delta: bool,
}

/// A pixel sample after the trace phase.
#[derive(Clone, Debug, Default)]
struct Traced {
    candidates: Vec<Candidate>,
    aux: Option<Aux>,
    /// The direct light at the vertex ([`DdgiRestirSettings::direct_nee`]; zero otherwise).
    direct: Vec3,
    /// A smooth primary's path ([`DdgiRestirSettings::smooth_ends_in_source`]).
    smooth: Option<SmoothPath>,
    stats: PathStats,
}

/// A smooth primary's path up to its first rough vertex: the light found on the way
/// (emission, NEE), the throughput to the end, where it ends in the source, and the source's
/// answer there once known.
#[derive(Clone, Copy, Debug, Default)]
struct SmoothPath {
    prefix: Vec3,
    throughput: Vec3,
    end: Option<At>,
    l: Vec3,
}

/// A frame between trace and resolve.
struct Frame {
    g: GBuffer,
    traced: Vec<Traced>,
    /// `ddgi-nrc-restir`: the probe rays waiting for the source.
    rays: Option<ProbeRays>,
    /// The history's surface samples to refresh: reservoir index and where the sample is,
    /// asked toward the reservoir's owner.
    refresh: Vec<(usize, At)>,
    trace_ms: f64,
}

/// The pass and its state: the probe volume (probe modes) and the previous frame.
pub struct DdgiRestirPass {
    pub settings: DdgiRestirSettings,
    tracer: PathTracer,
    volume: Option<ProbeVolume>,
    history: Option<History<DdgiSample>>,
    frame: Option<Frame>,
    /// Milliseconds of the last probe update.
    pub update_ms: f64,
}

impl DdgiRestirPass {
    pub fn new(settings: DdgiRestirSettings, tracer: &PathTracer) -> Self {
        Self {
            settings,
            tracer: *tracer,
            volume: None,
            history: None,
            frame: None,
            update_ms: 0.0,
        }
    }

    /// The volume, once a frame has built it (probe modes).
    pub fn volume(&self) -> Option<&ProbeVolume> {
        self.volume.as_ref()
    }

    /// The candidates of vertex `v` (step 1, before the source answers).
    fn candidates(&self, scene: &Scene, v: &Vertex, s: &mut PixelSampler) -> Traced {
        let set = &self.settings;
        // Room for every candidate at once: growing the vector cost a twentieth of a frame.
        let light_candidates = set.light_candidates_used();
        let mut t = Traced {
            candidates: Vec::with_capacity((light_candidates + set.bsdf_candidates) as usize),
            ..Default::default()
        };
        let from = nrc_scene::LightContext::new(v.si.p, v.si.ns);
        // With `direct_nee` the emission is the direct light's, estimated here as the path tracer
        // does; the first BSDF candidate's ray is the path's own BSDF sample of it.
        let mut walk = set
            .direct_nee
            .then(|| PathWalk::from_vertex(scene, &self.tracer, 1))
            .filter(|w| !w.at_depth_limit());
        if let Some(w) = &mut walk {
            t.direct = w.next_event(scene, v, s, &mut t.stats);
        }
        let surface = |si: &nrc_scene::SurfaceInteraction, at: Vertex| {
            let m = &scene.materials()[si.material as usize];
            let emits = m.is_emissive() && !set.direct_nee;
            DdgiSample::Surface(SurfacePoint {
                x: si.p,
                ng: si.ng,
                le: if emits {
                    m.emission(scene.textures(), &si.uv)
                } else {
                    Vec3::ZERO
                },
                two_sided: m.double_sided,
                l: Vec3::ZERO,
                side: si.ng.dot(si.wo).signum(),
                tri: si.tri,
                pdf_light: if emits {
                    scene.light_pdf_area(&from, si.tri)
                } else {
                    0.0
                },
                rho: at.bsdf.diffuse_reflectance(),
            })
        };
        // The vertex at a surface candidate, for the source to answer the radiance it
        // reflects; none where its BSDF is black (the converted scenes' emitters): that
        // radiance is exactly zero, and asking costs a cache query or a probe lookup.
        let reflecting = |at: Vertex, place: At| (!at.bsdf.is_black()).then_some(place);
        for _ in 0..light_candidates {
            let u_select = s.next_1d();
            let u_point = s.next_2d();
            let c = match scene.sample_light(&from, u_select, u_point) {
                Some(LightSample::Surface(ls)) => {
                    let wo = (v.si.p - ls.p).normalize_or_zero();
                    let si = scene.interaction_at(ls.tri, ls.p, wo);
                    let at = Vertex::new(scene, &si, wo);
                    let place = At::Point {
                        tri: ls.tri,
                        p: ls.p,
                        wo,
                    };
                    Some(Candidate {
                        y: surface(&si, at),
                        at: reflecting(at, place),
                        from_bsdf: false,
                    })
                }
                Some(ls) => Some(Candidate {
                    y: DdgiSample::Light(ls),
                    at: None,
                    from_bsdf: false,
                }),
                None => None,
            };
            t.candidates.extend(c);
        }
        for k in 0..set.bsdf_candidates {
            let u_lobe = s.next_1d();
            let u_dir = s.next_2d();
            let Some(bs) = v.bsdf.sample(v.wo, u_dir, u_lobe) else {
                continue;
            };
            let c = match walk.as_mut().filter(|_| k == 0) {
                // The path's BSDF sample: the emission it finds, weighed against NEE, is
                // direct light; the surface it finds a candidate.
                Some(w) => {
                    w.follow(v, &bs);
                    match w.arrive(scene, &mut t.stats) {
                        Arrival::Escaped { le, mis } => {
                            t.direct += bs.weight * le * mis;
                            None
                        }
                        Arrival::Hit(h) => {
                            t.direct += bs.weight * h.le * h.mis;
                            Some(Candidate {
                                y: surface(&h.vertex.si, h.vertex),
                                at: reflecting(h.vertex, At::point(&h.vertex.si)),
                                from_bsdf: true,
                            })
                        }
                    }
                }
                None => {
                    let ray = spawn_ray(v.si.p, v.si.ng, v.frame.to_world(bs.wi));
                    t.stats.closest_rays += 1;
                    match scene.intersect(&ray) {
                Some(hit) => {
                    let si = scene.interaction(&ray, &hit);
                    let at = Vertex::new(scene, &si, si.wo);
                    Some(Candidate {
                        y: surface(&si, at),
                        at: reflecting(at, At::Hit { ray, hit }),
                        from_bsdf: true,
                    })
                }
                // With `direct_nee` the environment is direct light, which this ray does not estimate.
                None if set.direct_nee => None,
                None => scene
                    .environment_sample(&from, ray.d.normalize())
                    .map(|ls| Candidate {
                        y: DdgiSample::Light(ls),
                        at: None,
                        from_bsdf: true,
                    }),
                    }
                }
            };
            let Some(c) = c else { continue };
            if bs.delta {
                // A delta lobe's sample cannot enter the reservoir (no density to weigh it):
                // the first BSDF candidate's estimates it whole, the others are dropped.
                if k == 0 {
                    t.aux = Some(Aux {
                        candidate: t.candidates.len(),
                        weight: bs.weight,
                        delta: true,
                    });
                    t.candidates.push(Candidate {
                        from_bsdf: false,
                        ..c
                    });
                }
                continue;
            }
            if k == 0 && set.residual {
                t.aux = Some(Aux {
                    candidate: t.candidates.len(),
                    weight: bs.weight,
                    delta: false,
                });
            }
            t.candidates.push(c);
        }
        t
    }

    /// A smooth primary `v`'s path ([`DdgiRestirSettings::smooth_ends_in_source`]): NEE and
    /// BSDF sampling (MIS, the tracer's glossy samples at `v`) at each vertex, Russian
    /// roulette and the depth limit as the path tracer's, up to the first vertex that is not
    /// a delta and has roughness at least `smooth`, where it ends (no NEE there: the source's
    /// answer holds all the light leaving it); with a depth limit only if that vertex is the
    /// second (the source answers with its own depth). A vertex whose BSDF is black ends the
    /// path unasked: the light it reflects is exactly zero.
    fn smooth_path(
        &self,
        scene: &Scene,
        v: &Vertex,
        s: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> SmoothPath {
        let mut out = SmoothPath::default();
        let mut walk = PathWalk::from_vertex(scene, &self.tracer, 1);
        let unlimited = self.tracer.segment_limit() == u32::MAX;
        let mut v = *v;
        let mut vertex = 1;
        loop {
            if walk.at_depth_limit() {
                return out;
            }
            out.prefix += walk.throughput() * walk.next_event(scene, &v, s, stats);
            if walk.scatter(&v, s).is_none() {
                return out;
            }
            match walk.arrive(scene, stats) {
                Arrival::Escaped { le, mis } => {
                    out.prefix += walk.throughput() * le * mis;
                    return out;
                }
                Arrival::Hit(h) => {
                    vertex += 1;
                    out.prefix += walk.throughput() * h.le * h.mis;
                    if h.vertex.bsdf.is_black() {
                        return out;
                    }
                    if !h.vertex.bsdf.is_delta()
                        && h.vertex.bsdf.roughness() >= self.settings.smooth
                        && (unlimited || vertex == 2)
                    {
                        out.throughput = walk.throughput();
                        out.end = Some(At::point(&h.vertex.si));
                        return out;
                    }
                    v = h.vertex;
                }
            }
        }
    }

    /// `L_DDGI+` (eq. 6) leaving `at` toward its `wo`: `ρ/π E(x, n)` plus one sample of the
    /// glossy integral `∫ E(x, ω) / π · f_g cos dω`, drawn from the whole BSDF with
    /// `f_g = max(0, f − ρ/π)` (zero for a Lambertian surface). The paper divides `E(x, ω)` by
    /// `2π`; `π` is the cosine lobe's mass over the hemisphere (a uniform field of radiance
    /// `L` has `E = πL`), so `1/π` is what makes a glossy surface in a uniform field reflect
    /// its albedo.
    ///
    /// With `spread` (eqs. 7–8, the path's footprint from the primary vertex up to `at`, in
    /// the project's convention, [`crate::spread`]), while the footprint is below the
    /// threshold the glossy sample is traced instead: the radiance arriving along it (the
    /// emission at its hit and that hit's own `L_DDGI+`, recursively) replaces `E(x, ω)/π`.
    fn ddgi_plus(
        vol: &ProbeVolume,
        scene: &Scene,
        at: &Vertex,
        spread: Option<Spread>,
        s: &mut PixelSampler,
        stats: &mut PathStats,
        depth: u32,
    ) -> Vec3 {
        let rho = at.bsdf.diffuse_reflectance();
        let l = rho / PI * vol.irradiance(at.si.p, at.si.ns, at.wo_world);
        if matches!(at.bsdf, nrc_scene::bsdf::Bsdf::Diffuse { .. }) {
            return l;
        }
        let (u_lobe, u_dir) = (s.next_1d(), s.next_2d());
        let Some(bs) = at.bsdf.sample(at.wo, u_dir, u_lobe) else {
            return l;
        };
        let w = if bs.delta {
            bs.weight
        } else {
            let f = (at.bsdf.eval(at.wo, bs.wi) - rho / PI).max(Vec3::ZERO);
            f * bs.wi.z.abs() / bs.pdf
        };
        if !(w.is_finite() && w != Vec3::ZERO) {
            return l;
        }
        let wi = at.frame.to_world(bs.wi);
        let Some(mut spread) = spread else {
            return l + w / PI * vol.irradiance(at.si.p, wi, at.wo_world);
        };
        let ray = spawn_ray(at.si.p, at.si.ng, wi);
        stats.closest_rays += 1;
        let Some(hit) = scene.intersect(&ray) else {
            return l + w * scene.environment().radiance(wi);
        };
        let si = scene.interaction(&ray, &hit);
        let next = Vertex::new(scene, &si, si.wo);
        let ends = depth + 1 >= MAX_RECURSION
            || spread.arrive(hit.t * hit.t, (!bs.delta).then_some(bs.pdf), si.ng.dot(wi));
        let li = scene.emission(&si)
            + Self::ddgi_plus(
                vol,
                scene,
                &next,
                (!ends).then_some(spread),
                s,
                stats,
                depth + 1,
            );
        l + w * li
    }

    /// The radiance a surface sample point `y` reflects toward the primary vertex `x1` (seen
    /// from `eye`) in the probe modes: `L_DDGI+` of `vol` at `y` (eq. 6), through the
    /// near-specular recursion of eqs. 7–8 while the footprint allows; and the rays it traced.
    pub fn probe_radiance(
        &self,
        scene: &Scene,
        vol: &ProbeVolume,
        eye: Vec3,
        x1: Option<&Vertex>,
        y: &Vertex,
        s: &mut PixelSampler,
    ) -> (Vec3, u64) {
        let spread = x1.and_then(|x1| self.spread_to(eye, x1, y));
        let mut st = PathStats::default();
        let l = Self::ddgi_plus(vol, scene, y, spread, s, &mut st, 0);
        (l, st.closest_rays)
    }

    /// The chosen surface sample `y` with its radiance toward `x1` found again through the
    /// near-specular recursion (unchanged where `y` is Lambertian: nothing to follow).
    #[allow(clippy::too_many_arguments)]
    fn recursed(
        &self,
        scene: &Scene,
        vol: &ProbeVolume,
        eye: Vec3,
        x1: &Vertex,
        y: SurfacePoint,
        s: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> SurfacePoint {
        let wo = (x1.si.p - y.x).normalize_or_zero();
        let si = scene.interaction_at(y.tri, y.x, wo);
        let at = Vertex::new(scene, &si, wo);
        if matches!(at.bsdf, nrc_scene::bsdf::Bsdf::Diffuse { .. }) {
            return y;
        }
        let (l, rays) = self.probe_radiance(scene, vol, eye, Some(x1), &at, s);
        stats.closest_rays += rays;
        SurfacePoint {
            l,
            side: y.ng.dot(wo).signum(),
            ..y
        }
    }

    /// Eqs. 7–8 at a sample point `y` found from primary vertex `x1` (seen from `eye`): the
    /// spread of the path `eye → x1 → y`, `p₁` the primary BSDF's density toward `y` (the
    /// paper: proportional to the whole BSDF at the primary vertex); `None` once it is above
    /// the threshold already, or off.
    fn spread_to(&self, eye: Vec3, x1: &Vertex, y: &Vertex) -> Option<Spread> {
        // The paper's a0 = 4π d²/cos against the project's d²/(4π cos): c × 16π².
        let c = self.settings.footprint * 16.0 * PI * PI;
        if c <= 0.0 {
            return None;
        }
        let mut spread = Spread::new(c);
        let to_x1 = x1.si.p - eye;
        spread.arrive(
            to_x1.length_squared(),
            None,
            x1.si.ns.dot(to_x1.normalize_or_zero()),
        );
        let d = y.si.p - x1.si.p;
        let wi = d.normalize_or_zero();
        let pdf = x1.bsdf.pdf(x1.wo, x1.frame.to_local(wi));
        let pdf = (!x1.bsdf.is_delta()).then_some(pdf);
        (!spread.arrive(d.length_squared(), pdf, y.si.ng.dot(wi))).then_some(spread)
    }
}

impl RenderPass for DdgiRestirPass {
    fn name(&self) -> String {
        self.settings.name()
    }

    fn reset(&mut self) {
        self.history = None;
        self.volume = None;
    }

    fn debug_views(&self) -> Vec<super::frame::PassView> {
        let Some(h) = &self.history else {
            return Vec::new();
        };
        let mut views = h.views();
        if let Some(v) = &self.volume {
            views.push(super::ddgi_terminated::probe_view(v, &h.g.camera, h.g.width, h.g.height));
        }
        views
    }

    fn prepare(&mut self, input: &FrameInput) {
        if !self.settings.uses_probes() {
            return;
        }
        let t = Instant::now();
        let pixels = u64::from(input.width) * u64::from(input.height);
        if self.volume.is_none() {
            let mut ddgi = self.settings.ddgi;
            if self.settings.light == SurfaceLight::CacheProbes {
                ddgi.radiance = ProbeRadiance::Source;
            }
            self.volume = ProbeVolume::for_frame(&input.scene.bounds(), ddgi, pixels).ok();
        }
        if let Some(v) = &mut self.volume {
            v.fit_rays_to_frame(pixels);
        }
        // Probes fed by the cache blend in `resolve`, once the source has answered.
        if self.settings.light == SurfaceLight::Probes
            && let Some(v) = &mut self.volume
        {
            v.update(input.scene, Stream::ProbeRays.seed(input.seed));
        }
        self.update_ms = t.elapsed().as_secs_f64() * 1e3;
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let scene = input.scene;
        let seed = input.seed;
        let t = Instant::now();
        let g = GBuffer::trace(input, self.settings.jitter);
        let traced: Vec<Traced> = par_map(g.len(), |i| {
            match (usable(&g.primary[i], self.settings.smooth), &g.primary[i]) {
                (Some(p), _) => {
                    self.candidates(scene, &p.v, &mut stream(seed, i, Phase::Candidates))
                }
                (None, Some(p)) if self.settings.smooth_ends_in_source => {
                    let mut t = Traced::default();
                    let mut s = stream(seed, i, Phase::Path);
                    t.smooth = Some(self.smooth_path(scene, &p.v, &mut s, &mut t.stats));
                    t
                }
                _ => Traced::default(),
            }
        });
        let mut queries = Vec::new();
        let mut rays = None;
        // The probes' share of this phase, counted as theirs and not the candidates'.
        let mut probe_ms = 0.0;
        match self.settings.light {
            SurfaceLight::Probes => {}
            SurfaceLight::Cache => {
                for t in &traced {
                    queries.extend(
                        t.candidates
                            .iter()
                            .filter_map(|c| c.at.map(|a| a.vertex(scene).query())),
                    );
                    if let Some(at) = t.smooth.and_then(|sp| sp.end) {
                        queries.push(at.vertex(scene).query());
                    }
                }
            }
            SurfaceLight::CacheProbes => {
                let t = Instant::now();
                if let Some(v) = &self.volume {
                    let r = v.trace_rays(scene, Stream::ProbeRays.seed(seed));
                    queries = r.queries.clone();
                    rays = Some(r);
                }
                probe_ms = t.elapsed().as_secs_f64() * 1e3;
                self.update_ms += probe_ms;
            }
        }
        // The history's samples carry the radiance their finders stored, possibly frames ago;
        // the source has changed since (probes blend, the cache trains), so each is asked
        // again toward its owner. (The paper's §3.7 reuse assumes a static source: without
        // this, a converging source leaves the image dark by the stale values, -1.7 % in the
        // enclosure test.)
        let refresh: Vec<(usize, At)> =
            match self.history.as_ref().filter(|_| self.settings.temporal) {
                Some(h) => h
                    .res
                    .par_iter()
                    .enumerate()
                    .filter_map(|(j, r)| {
                        let Some(DdgiSample::Surface(y)) = r.sample else {
                            return None;
                        };
                        let owner = h.g.primary[j].as_ref()?.v.si.p;
                        let wo = (owner - y.x).normalize_or_zero();
                        Some((j, At::Point { tri: y.tri, p: y.x, wo }))
                    })
                    .collect(),
                None => Vec::new(),
            };
        if self.settings.light == SurfaceLight::Cache {
            queries.extend(refresh.iter().map(|(_, at)| at.vertex(scene).query()));
        }
        self.frame = Some(Frame {
            g,
            traced,
            rays,
            refresh,
            trace_ms: t.elapsed().as_secs_f64() * 1e3 - probe_ms,
        });
        queries
    }

    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput {
        if self.frame.is_none() {
            let q = self.trace(input);
            assert!(
                q.is_empty(),
                "resolve without trace needs a pass that asks no source"
            );
        }
        let Frame {
            g,
            mut traced,
            rays,
            refresh,
            trace_ms,
        } = self.frame.take().expect("just traced");
        let mut history = self
            .history
            .take()
            .filter(|h| self.settings.temporal && h.g.same_shape(&g));
        let scene = input.scene;
        let seed = input.seed;
        let set = self.settings;
        let n = g.len();
        let mut times = PhaseTimes {
            candidates_ms: trace_ms,
            ..Default::default()
        };

        // The surface candidates' source radiance.
        let t = Instant::now();
        let mut blend_ms = 0.0;
        match set.light {
            SurfaceLight::Cache => {
                let mut k = 0;
                for tr in &mut traced {
                    for c in &mut tr.candidates {
                        if let (DdgiSample::Surface(y), Some(_)) = (&mut c.y, c.at) {
                            let a = answers[k];
                            y.l = usable_answer(a);
                            k += 1;
                        }
                    }
                    if let Some(sp) = tr.smooth.as_mut().filter(|sp| sp.end.is_some()) {
                        sp.l = usable_answer(answers[k]);
                        k += 1;
                    }
                }
                let fresh: Vec<Vec3> = answers[k..].to_vec();
                if let Some(h) = &mut history {
                    refresh_history(h, &refresh, &fresh);
                }
            }
            SurfaceLight::CacheProbes => {
                let tu = Instant::now();
                if let (Some(v), Some(r)) = (&mut self.volume, rays) {
                    v.blend(r, answers);
                }
                blend_ms = tu.elapsed().as_secs_f64() * 1e3;
                self.update_ms += blend_ms;
            }
            SurfaceLight::Probes => {}
        }
        if let Some(vol) = self.volume.as_ref().filter(|_| set.uses_probes()) {
            let eye = input.camera.position;
            traced.par_iter_mut().enumerate().for_each(|(i, tr)| {
                let mut s = stream(seed, i, Phase::SourceLookup);
                for c in &mut tr.candidates {
                    if let (DdgiSample::Surface(y), Some(at)) = (&mut c.y, &c.at) {
                        let at = at.vertex(scene);
                        y.l = self.probe_radiance(scene, vol, eye, None, &at, &mut s).0;
                    }
                }
                if let Some(sp) = tr.smooth.as_mut()
                    && let Some(at) = sp.end
                {
                    let at = at.vertex(scene);
                    sp.l = self.probe_radiance(scene, vol, eye, None, &at, &mut s).0;
                }
            });
            if let Some(h) = &mut history {
                let hg = &h.g;
                let fresh: Vec<Vec3> = refresh
                    .par_iter()
                    .map(|(j, at)| {
                        let mut s = stream(seed, *j, Phase::HistoryRefresh);
                        let at = at.vertex(scene);
                        self.probe_radiance(scene, vol, hg.camera.position, None, &at, &mut s)
                            .0
                    })
                    .collect();
                refresh_history(h, &refresh, &fresh);
            }
        }
        times.candidates_ms += t.elapsed().as_secs_f64() * 1e3 - blend_ms;

        let b = scene.bounds();
        let diag = (b.max - b.min).length();
        let ctx = Ctx {
            g_max: if set.clamp > 0.0 {
                1.0 / (set.clamp * diag).powi(2)
            } else {
                f32::INFINITY
            },
            requery: self.volume.as_ref().filter(|_| set.requery),
        };
        let (ml, mb) = (set.light_candidates_used() as f32, set.bsdf_candidates as f32);

        // 1. Initial reservoirs (RIS, visibility reuse) and the aux estimates.
        let t = Instant::now();
        let initial: Vec<(DdgiReservoir, Vec3, PathStats)> = par_map(n, |i| {
            let tr = &traced[i];
            let mut stats = tr.stats;
            let mut r = DdgiReservoir::new();
            let mut aux = Vec3::ZERO;
            let Some(p) = usable(&g.primary[i], set.smooth) else {
                return (r, aux, stats);
            };
            let v = &p.v;
            let mut s = stream(seed, i, Phase::Resample);
            let mut chosen_bsdf = false;
            for (k, c) in tr.candidates.iter().enumerate() {
                if tr.aux.is_some_and(|a| a.delta && a.candidate == k) {
                    continue;
                }
                let u = s.next_1d();
                if let Some(con) = contribution(&ctx, v, &c.y) {
                    let w = con.target / (ml * con.p_light + mb * con.p_bsdf);
                    if r.update(c.y, w, con.target, u) {
                        chosen_bsdf = c.from_bsdf;
                    }
                }
            }
            // Unsampled candidates (missed lights, absorbed BSDF samples) are in M's counts.
            r.m = ml + mb;
            r.finish_normalised();
            if let Some(y) = r.sample
                && !chosen_bsdf
                && !sees(scene, v, &y, &mut stats)
            {
                r.clear_sample();
            }
            if let Some(a) = tr.aux {
                let y = &tr.candidates[a.candidate].y;
                aux = match y {
                    // The ray found y (no shadow ray): its own estimate f cos / p · L, of which
                    // the residual keeps the part the clamp took away.
                    DdgiSample::Surface(sp) => {
                        arriving(&ctx, sp, v.si.p).map_or(Vec3::ZERO, |arr| {
                            let frac = if a.delta {
                                1.0
                            } else {
                                let cos_x = v.si.ns.dot(arr.wi).abs();
                                let g = cos_x * arr.cos_y / arr.dist2;
                                (1.0 - ctx.g_max / g).max(0.0)
                            };
                            a.weight * arr.li * frac
                        })
                    }
                    DdgiSample::Light(LightSample::Environment { le, .. }) if a.delta => {
                        a.weight * *le
                    }
                    DdgiSample::Light(_) => Vec3::ZERO,
                };
            }
            (r, aux, stats)
        });

        // 2. Spatial reuse from the initial buffer.
        let frame = DdgiFrame {
            scene,
            g: &g,
            ctx,
            smooth: set.smooth,
            merge: Merge::of(false, set.pairwise),
        };
        let slots: Vec<Slot<DdgiSample>> = initial
            .iter()
            .map(|(r, _, _)| (*r, PathStats::default()))
            .collect();
        let (k, radius) = (set.spatial_neighbours, set.spatial_radius);
        let spatial = reuse::spatial(&frame, &g, seed, k, radius, &slots);
        times.spatial_ms = t.elapsed().as_secs_f64() * 1e3;

        // 3. Temporal reuse (last: the shading's shadow ray tests what it keeps).
        let t = Instant::now();
        let cap = set.m_cap * (ml + mb);
        let temporal = reuse::temporal(&frame, seed, history.as_ref(), cap, false, &spatial);
        times.temporal_ms = t.elapsed().as_secs_f64() * 1e3;

        // 4. Shading: one shadow ray, where reuse replaced the pixel's own sample (which was
        // shadow-tested, or found by its BSDF ray).
        let t = Instant::now();
        let eye = input.camera.position;
        let recursion = self.volume.as_ref().filter(|_| set.footprint > 0.0);
        let shaded: Vec<(Vec3, DdgiReservoir, PathStats)> = par_map(n, |i| {
            let (mut r, mut stats) = temporal[i];
            let (own, aux, st0) = initial[i];
            stats.add(&st0);
            let mut l = g.emitted[i];
            if let Some(p) = &g.primary[i] {
                if usable(&g.primary[i], set.smooth).is_some() {
                    l += aux + traced[i].direct;
                    if let Some(y) = r.sample {
                        let seen = |stats: &mut PathStats| {
                            own.sample == Some(y) || sees(scene, &p.v, &y, stats)
                        };
                        match contribution(&ctx, &p.v, &y) {
                            Some(c) if seen(&mut stats) => {
                                // Eqs. 7–8 at shading (the paper's use (iii)): the chosen
                                // point's radiance through the near-specular recursion.
                                let c = match (y, recursion) {
                                    (DdgiSample::Surface(sp), Some(vol)) => {
                                        let mut s = stream(seed, i, Phase::Footprint);
                                        let y = DdgiSample::Surface(self.recursed(
                                            scene, vol, eye, &p.v, sp, &mut s, &mut stats,
                                        ));
                                        contribution(&ctx, &p.v, &y).map_or(Vec3::ZERO, |c| c.c)
                                    }
                                    _ => c.c,
                                };
                                l += c * r.w;
                            }
                            _ => r.clear_sample(),
                        }
                    }
                } else if let Some(sp) = &traced[i].smooth {
                    l += sp.prefix + sp.throughput * sp.l;
                } else {
                    let mut s = stream(seed, i, Phase::Path);
                    l += self
                        .tracer
                        .reflected(scene, &p.v.si, p.v.wo_world, 1, &mut s, &mut stats);
                }
            }
            (l, r, stats)
        });
        times.shading_ms = t.elapsed().as_secs_f64() * 1e3;
        times.probes_ms = self.update_ms;

        let (out, res) = super::screen::assemble(&g, input, shaded, times);
        self.history = Some(History { g, res });
        out
    }
}

/// A frame of DDGI resampling as the reuse driver sees it: light and surface samples at the
/// usable primary vertices, in the samples' own measures (the same at every vertex); always
/// unbiased.
struct DdgiFrame<'a> {
    scene: &'a Scene,
    g: &'a GBuffer,
    ctx: Ctx<'a>,
    smooth: f32,
    merge: Merge,
}

impl Resampling for DdgiFrame<'_> {
    type Sample = DdgiSample;

    fn receiver(&self, i: usize) -> Option<&Vertex> {
        usable(&self.g.primary[i], self.smooth).map(|p| &p.v)
    }

    fn donor(&self, q: usize) -> Option<&Vertex> {
        self.g.primary[q].as_ref().map(|p| &p.v)
    }

    fn target(&self, v: &Vertex, y: &DdgiSample) -> f32 {
        contribution(&self.ctx, v, y).map_or(0.0, |c| c.target)
    }

    fn visible(&self, v: &Vertex, y: &DdgiSample, stats: &mut PathStats) -> bool {
        sees(self.scene, v, y, stats)
    }

    fn merge(&self) -> Merge {
        self.merge
    }
}

/// Puts the source's current radiance `fresh` into the history's surface samples listed in
/// `refresh` (reservoir index, the sample asked toward the reservoir's owner).
fn refresh_history(h: &mut History<DdgiSample>, refresh: &[(usize, At)], fresh: &[Vec3]) {
    for (&(j, at), l) in refresh.iter().zip(fresh) {
        if let Some(DdgiSample::Surface(y)) = &mut h.res[j].sample {
            y.l = usable_answer(*l);
            y.side = y.ng.dot(at.wo()).signum();
        }
    }
}

/// Vertices the near-specular recursion of one sample follows at most.
const MAX_RECURSION: u32 = 8;

/// The primary vertex where the resampling applies: not a delta, roughness at least `smooth`.
fn usable(p: &Option<Primary>, smooth: f32) -> Option<&Primary> {
    p.as_ref()
        .filter(|p| !p.v.bsdf.is_delta() && p.v.bsdf.roughness() >= smooth)
}
