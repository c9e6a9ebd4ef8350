//! ReSTIR DI: direct light at each pixel's primary vertex by spatiotemporal reservoir
//! resampling (Bitterli et al. 2020, "Spatiotemporal reservoir resampling for real-time ray
//! tracing with dynamic direct lighting"; the seed paper `world-space-restir-gi.txt` §3 recalls
//! its equations 3–6). The rest of the path is traced as the path tracer traces it.
//!
//! Per frame and pixel sample (see [`super::screen`] for buffers and streams):
//!
//! 1. **Candidates**: `light_candidates` samples of the scene's light sampler (by power: points
//!    on emissive triangles, punctual lights, environment directions; shading-point
//!    independent, so they can be reused elsewhere), or `tree_light_candidates` where the scene
//!    samples lights by its light tree (each costs a descent of the tree and already favours
//!    the lights that matter at the point: on `many-lights` 4 measured as good as 32 at an
//!    eighth of the cost, and with the eight-wide tree 2 no worse than 4 at 100 and 200 ms a
//!    frame, RESULTS.md), and `bsdf_candidates` BSDF samples whose
//!    ray reaches an emitter or the environment. Each enters with the balance-heuristic RIS
//!    weight `p̂(y) / (M_l p_l(y) + M_b p_b(y))`, densities in the light's own measure (area for
//!    triangles, solid angle for the environment, counting for punctual lights), target `p̂`
//!    the luminance of the unshadowed contribution `f · L · |cos θ| · G`. The chosen sample is
//!    shadow-tested and dropped if occluded (visibility reuse, Bitterli et al. §6.1).
//! 2. **Temporal reuse**: the previous frame's final reservoir at the reprojected pixel (if its
//!    vertex is similar: normals within 25°, depth within 10 %), its `M` capped at `m_cap`
//!    times the candidate count.
//! 3. **Spatial reuse**: `spatial_neighbours` pixels in a disc of `spatial_radius` pixels,
//!    read from the temporal step's buffer (never from one being written: deterministic
//!    whatever the thread count).
//! 4. **Shading**: one shadow ray for the chosen sample where spatial reuse brought it (the
//!    temporal step's sample was shadow-tested); `f · L · G · V · W`.
//!
//! Merging (steps 2–3), [`reuse::Merge`]: **unbiased** (default) by generalised pairwise MIS,
//! each reused reservoir weighed against the pixel's own by how likely its domain (target and
//! visibility: visibility is part of each reservoir's domain after visibility reuse) was to
//! produce the sample, one shadow ray per reused reservoir; `pairwise=0`: `W = w_sum / (Z p̂(y))`
//! with `Z` the `M` of the reservoirs whose owner could have produced `y` (Bitterli Alg. 6),
//! whose equal shares made the kitchen's glossy table a field of fireflies (MSE 11.0 against
//! 0.46 with pairwise MIS, RESULTS.md). **Biased** (`-biased`): `Z = Σ M` (Alg. 4), no extra
//! rays, darker where neighbours see the light differently.

use std::time::Instant;

use glam::Vec3;
use nrc_scene::{LightSample, Scene, light::Incident, sampling::luminance, spawn_ray};

use crate::error::SettingsError;
use super::reuse::{self, History, Merge, Resampling, Slot};
use super::screen::{GBuffer, MAX, Phase, Primary, par_map, stream};
use super::params::{Key, Params, Value};
use super::spec::{PassConfig, PassKind, parse_variant};
use super::frame::{FrameInput, PassOutput, PhaseTimes, RenderPass};
use crate::path_tracer::{PathStats, PathTracer};
use crate::reservoir::Reservoir;
use crate::sampler::PixelSampler;
use crate::source::RadianceQuery;
use crate::transport::Vertex;

pub const KIND: PassKind = PassKind {
    grammar: "restir-di[-biased]",
    about: "ReSTIR DI at the primary vertex (light-sampler and BSDF candidates by RIS, temporal \
            and spatial reuse, unbiased pairwise MIS with a visibility ray per reused \
            reservoir, or -biased 1/M); the rest of the path traced",
    method: true,
    variants: || variants().into_iter().map(|(_, s)| s.into()).collect(),
    parse: |name| parse_variant(name, &variants(), RestirDiSettings::validate),
};

fn variants() -> [(&'static str, RestirDiSettings); 2] {
    let d = RestirDiSettings::default();
    [("restir-di", d), ("restir-di-biased", RestirDiSettings { biased: true, ..d })]
}

/// ReSTIR DI's parameters (defaults: Bitterli et al. 2020's interactive settings).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestirDiSettings {
    /// Light-sampler candidates per pixel sample and frame.
    pub light_candidates: u32,
    /// The same where the scene samples lights by its light tree.
    pub tree_light_candidates: u32,
    /// BSDF-sampled candidates (a ray each).
    pub bsdf_candidates: u32,
    /// Reuse the previous frame's reservoirs.
    pub temporal: bool,
    /// Spatial neighbours per pixel (0: no spatial reuse).
    pub spatial_neighbours: u32,
    /// Radius of the spatial neighbourhood, pixels.
    pub spatial_radius: f32,
    /// The history's `M` is capped at this multiple of the candidate count.
    pub m_cap: f32,
    /// `Z = Σ M` (no visibility rays for the merge): biased.
    pub biased: bool,
    /// Unbiased merges by pairwise MIS (off: 1/Z), [`reuse::Merge`].
    pub pairwise: bool,
    /// Jitter camera rays in the pixel (off: through pixel centres, for tests against a
    /// reference at fixed primary rays).
    pub jitter: bool,
}

impl Default for RestirDiSettings {
    fn default() -> Self {
        Self {
            light_candidates: 32,
            tree_light_candidates: 2,
            bsdf_candidates: 1,
            temporal: true,
            spatial_neighbours: 5,
            spatial_radius: 30.0,
            m_cap: 20.0,
            biased: false,
            pairwise: true,
            jitter: true,
        }
    }
}

impl RestirDiSettings {
    /// Errors for settings that cannot work.
    pub fn validate(&self) -> Result<(), SettingsError> {
        reuse::validate_reuse(
            &[
                self.light_candidates,
                self.tree_light_candidates,
                self.bsdf_candidates,
                self.spatial_neighbours,
            ],
            self.spatial_radius,
            self.m_cap,
        )?;
        if self.light_candidates.min(self.tree_light_candidates) + self.bsdf_candidates == 0 {
            return Err(SettingsError::Combination(
                "at least one candidate (light or BSDF) is needed",
            ));
        }
        Ok(())
    }
}

impl RestirDiSettings {
    /// Light-sampler candidates per pixel sample with `scene`'s light sampler.
    pub fn light_candidates_for(&self, scene: &Scene) -> u32 {
        match scene.light_sampler() {
            nrc_scene::LightSamplerKind::Power => self.light_candidates,
            nrc_scene::LightSamplerKind::Tree => self.tree_light_candidates,
        }
    }
}

impl Params for RestirDiSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        let light = Key::new("light", "light-sampler candidates per pixel sample");
        f(&light.range(0.0, MAX), &mut self.light_candidates);
        let tree = Key::new(
            "tree-light",
            "light-sampler candidates per pixel sample where lights are sampled by the light tree",
        );
        f(&tree.range(0.0, MAX), &mut self.tree_light_candidates);
        let bsdf = Key::new("bsdf", "BSDF-sampled candidates (a ray each)");
        f(&bsdf.range(0.0, MAX), &mut self.bsdf_candidates);
        let (k, radius) = (&mut self.spatial_neighbours, &mut self.spatial_radius);
        let (m_cap, temporal, pairwise) = (&mut self.m_cap, &mut self.temporal, &mut self.pairwise);
        reuse::visit_reuse(f, k, radius, m_cap, temporal, pairwise);
        f(&Key::new("jitter", "jitter camera rays in the pixel"), &mut self.jitter);
    }
}

impl PassConfig for RestirDiSettings {
    /// (measured 676.)
    fn state_bytes_per_sample(&self) -> u64 {
        700
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let (base, defaults) = variants()[self.biased as usize];
        super::params::name(base, self, &defaults)
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(RestirDiPass::new(*self, tracer))
    }

    fn is_stateful(&self) -> bool {
        true
    }

    fn params(&self) -> Vec<super::params::Param> {
        super::params::list(self)
    }
}

/// A direct-light reservoir.
pub type DiReservoir = Reservoir<LightSample>;

/// The ReSTIR DI pass and its history.
pub struct RestirDiPass {
    pub settings: RestirDiSettings,
    tracer: PathTracer,
    history: Option<History<LightSample>>,
    frame: Option<PassOutput>,
}

impl RestirDiPass {
    pub fn new(settings: RestirDiSettings, tracer: &PathTracer) -> Self {
        Self {
            settings,
            tracer: *tracer,
            history: None,
            frame: None,
        }
    }
}

/// A light sample's density in its own measure (what the light sampler drew it with).
#[inline]
fn own_pdf(y: &LightSample) -> f32 {
    match *y {
        LightSample::Surface(s) => s.pdf_area,
        LightSample::Punctual { pmf, .. } => pmf,
        LightSample::Environment { pdf, .. } => pdf,
    }
}

/// What light sample `y` brings to vertex `v`, unshadowed.
#[derive(Clone, Copy, Debug)]
pub(super) struct Contribution {
    /// `f · L · |cos θ|` per unit of the sample's own measure (`G` included for area lights).
    pub c: Vec3,
    /// `p̂`: the luminance of `c`.
    pub target: f32,
    /// Density of the light sampler drawing `y`, own measure.
    pub p_light: f32,
    /// Density of BSDF sampling at `v` reaching `y`, own measure (0 for delta lights).
    pub p_bsdf: f32,
    pub inc: Incident,
}

#[inline]
pub(super) fn contribution(v: &Vertex, y: &LightSample) -> Option<Contribution> {
    let inc = y.incident(v.si.p)?;
    let wi = v.frame.to_local(inc.wi);
    let f = v.bsdf.eval(v.wo, wi) * wi.z.abs();
    let p_light = own_pdf(y);
    // Own measure per solid angle at v: cos θ_l / d² for area lights, 1 otherwise.
    let g = p_light / inc.pdf;
    let c = f * inc.li * g;
    let target = luminance(c);
    if !(target > 0.0 && target.is_finite()) {
        return None;
    }
    let p_bsdf = if inc.delta {
        0.0
    } else {
        v.bsdf.pdf(v.wo, wi) * g
    };
    Some(Contribution {
        c,
        target,
        p_light,
        p_bsdf,
        inc,
    })
}

/// `p̂` of `y` at `v` (0 where it brings nothing).
#[inline]
fn target_at(v: &Vertex, y: &LightSample) -> f32 {
    contribution(v, y).map_or(0.0, |c| c.target)
}

/// Whether `v` sees the light of `y` (arriving as `inc`); counts the ray.
#[inline]
pub(super) fn sees(
    scene: &Scene,
    v: &Vertex,
    y: &LightSample,
    inc: &Incident,
    stats: &mut PathStats,
) -> bool {
    stats.shadow_rays += 1;
    !scene.occluded(&y.shadow_ray(v.si.p, v.si.ng, inc))
}

impl RestirDiPass {
    /// Step 1: RIS over the candidates, then visibility reuse.
    fn candidates(
        &self,
        scene: &Scene,
        v: &Vertex,
        s: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> DiReservoir {
        let set = &self.settings;
        let n_light = set.light_candidates_for(scene);
        let (ml, mb) = (n_light as f32, set.bsdf_candidates as f32);
        let mut r = DiReservoir::new();
        let at = nrc_scene::LightContext::new(v.si.p, v.si.ns);
        let offer = |r: &mut DiReservoir, y: Option<LightSample>, u: f32| match y
            .and_then(|y| contribution(v, &y).map(|c| (y, c)))
        {
            Some((y, c)) => {
                r.update(y, c.target / (ml * c.p_light + mb * c.p_bsdf), c.target, u);
            }
            None => r.m += 1.0,
        };
        for _ in 0..n_light {
            let u_select = s.next_1d();
            let u_point = s.next_2d();
            let u = s.next_1d();
            offer(&mut r, scene.sample_light(&at, u_select, u_point), u);
        }
        for _ in 0..set.bsdf_candidates {
            let u_lobe = s.next_1d();
            let u_dir = s.next_2d();
            let u = s.next_1d();
            let y = v
                .bsdf
                .sample(v.wo, u_dir, u_lobe)
                .filter(|bs| !bs.delta)
                .and_then(|bs| {
                    let ray = spawn_ray(v.si.p, v.si.ng, v.frame.to_world(bs.wi));
                    stats.closest_rays += 1;
                    match scene.intersect(&ray) {
                        Some(hit) => scene.light_sample_at(&at, &scene.interaction(&ray, &hit)),
                        None => scene.environment_sample(&at, ray.d.normalize()),
                    }
                });
            offer(&mut r, y, u);
        }
        r.finish_normalised();
        if let Some(y) = r.sample {
            let inc = y
                .incident(v.si.p)
                .expect("a selected sample lights its owner");
            if !sees(scene, v, &y, &inc, stats) {
                r.clear_sample();
            }
        }
        r
    }
}

/// A frame of ReSTIR DI as the reuse driver sees it: light samples at the usable primary
/// vertices, in area (or the light's own) measure, which is the same at every vertex.
struct DiFrame<'a> {
    scene: &'a Scene,
    g: &'a GBuffer,
    direct: bool,
    merge: Merge,
}

impl DiFrame<'_> {
    /// The primary vertex of pixel sample `i` where resampling applies: non-delta, with direct
    /// light to resample.
    fn usable(&self, i: usize) -> Option<&Primary> {
        self.g.primary[i]
            .as_ref()
            .filter(|p| self.direct && !p.v.bsdf.is_delta())
    }
}

impl Resampling for DiFrame<'_> {
    type Sample = LightSample;

    fn receiver(&self, i: usize) -> Option<&Vertex> {
        self.usable(i).map(|p| &p.v)
    }

    fn donor(&self, q: usize) -> Option<&Vertex> {
        self.g.primary[q].as_ref().map(|p| &p.v)
    }

    fn target(&self, v: &Vertex, y: &LightSample) -> f32 {
        target_at(v, y)
    }

    fn visible(&self, v: &Vertex, y: &LightSample, stats: &mut PathStats) -> bool {
        contribution(v, y).is_some_and(|c| sees(self.scene, v, y, &c.inc, stats))
    }

    fn merge(&self) -> Merge {
        self.merge
    }
}

impl RenderPass for RestirDiPass {
    fn name(&self) -> String {
        self.settings.name()
    }

    fn reset(&mut self) {
        self.history = None;
    }

    fn debug_views(&self) -> Vec<super::frame::PassView> {
        self.history.iter().flat_map(|h| h.views()).collect()
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let scene = input.scene;
        let seed = input.seed;
        let mut times = PhaseTimes::default();
        let t = Instant::now();
        let g = GBuffer::trace(input, self.settings.jitter);
        let n = g.len();
        let frame = DiFrame {
            scene,
            g: &g,
            direct: self.tracer.segment_limit() >= 2 && scene.light_count() > 0,
            merge: Merge::of(self.settings.biased, self.settings.pairwise),
        };

        // 1. Candidates.
        let initial: Vec<Slot<LightSample>> = par_map(n, |i| {
            let mut stats = PathStats::default();
            let r = match frame.usable(i) {
                Some(p) => self.candidates(
                    scene,
                    &p.v,
                    &mut stream(seed, i, Phase::Candidates),
                    &mut stats,
                ),
                None => DiReservoir::new(),
            };
            (r, stats)
        });
        times.candidates_ms = t.elapsed().as_secs_f64() * 1e3;

        // 2. Temporal reuse (history samples shadow-tested, as they feed spatial reuse).
        let t = Instant::now();
        let cap = self.settings.m_cap
            * (self.settings.light_candidates_for(scene) + self.settings.bsdf_candidates) as f32;
        let history = self
            .history
            .take()
            .filter(|h| self.settings.temporal && h.g.same_shape(&g));
        let temporal = reuse::temporal(&frame, seed, history.as_ref(), cap, true, &initial);
        times.temporal_ms = t.elapsed().as_secs_f64() * 1e3;

        // 3. Spatial reuse, reading only the temporal buffer.
        let t = Instant::now();
        let (k, radius) = (self.settings.spatial_neighbours, self.settings.spatial_radius);
        let spatial = reuse::spatial(&frame, &g, seed, k, radius, &temporal);
        times.spatial_ms = t.elapsed().as_secs_f64() * 1e3;

        // 4. Shading, and the rest of the path. The shadow ray only where spatial reuse took
        // the sample from a neighbour: the temporal step's was shadow-tested.
        let t = Instant::now();
        let shaded: Vec<(Vec3, DiReservoir, PathStats)> = par_map(n, |i| {
            let (mut r, mut stats) = spatial[i];
            let mut l = g.emitted[i];
            if let Some(p) = &g.primary[i] {
                let mut s = stream(seed, i, Phase::Path);
                if frame.usable(i).is_some() {
                    if let Some(y) = r.sample {
                        let c = contribution(&p.v, &y).expect("a selected sample lights its owner");
                        if temporal[i].0.sample == Some(y)
                            || sees(scene, &p.v, &y, &c.inc, &mut stats)
                        {
                            l += c.c * r.w;
                        } else {
                            r.clear_sample();
                        }
                    }
                    l += self.tracer.indirect(scene, &p.v, 1, &mut s, &mut stats);
                } else {
                    // Delta vertices (and depth 1): the path tracer's own estimate.
                    l += self
                        .tracer
                        .reflected(scene, &p.v.si, p.v.wo_world, 1, &mut s, &mut stats);
                }
            }
            (l, r, stats)
        });
        times.shading_ms = t.elapsed().as_secs_f64() * 1e3;

        let (out, res) = super::screen::assemble(&g, input, shaded, times);
        self.history = Some(History { g, res });
        self.frame = Some(out);
        Vec::new()
    }

    fn resolve(&mut self, input: &FrameInput, _answers: &[Vec3]) -> PassOutput {
        if self.frame.is_none() {
            self.trace(input);
        }
        self.frame.take().expect("just traced")
    }
}
