//! Instant radiosity: the primary vertex's indirect light from a set of virtual point lights
//! (VPLs), its direct light by next-event estimation, its emission as seen. Three ways to keep
//! the VPLs (Hedman, Karras, Lehtinen, "Sequential Monte Carlo Instant Radiosity"):
//!
//! - **`ir`** (the baseline, Keller's instant radiosity): each frame, light paths traced from the
//!   lights with a new seed until `I` VPLs are made (whole paths), a VPL at every non-delta
//!   vertex carrying the flux weight `β` that arrived there; a VPL at `y` lights `x` by `f_x · G(x, y) · V · f_y(ω_in, y→x) · β / N`
//!   (`N` light paths). Unbiased but for the clamp, and a new set every frame: it flickers.
//! - **`smc-ir`** (the paper's Algorithm 1): VPLs on surfaces indirectly visible to the camera,
//!   carrying a radiosity `L(y)` (16 path-traced samples with a seed of the VPL's own, §3.2.3,
//!   the surfaces treated as diffuse, §3.1) and a density `p(y)` by k nearest neighbours
//!   (eq. 7, `k` from eq. 8); `y` lights `x` by `f_x · G · V · L(y) / (I p(y))` (eq. 5). Each
//!   frame: VPLs whose associated camera-visible point is no longer seen and cannot be seen again
//!   by `V` = 16 rays from visible points in two rounds are invalid (§3.2.2); `rate · I`
//!   intersection points of rays from visible points are resampled without replacement toward
//!   uniform area density into `I` candidates (§3.2.1; density by kNN among the points),
//!   their radiosities estimated and their densities against the current VPLs with `k = 1`
//!   (§3.2.4); `M_min = min(M_max, M_strong)` (eq. 9, `M_strong` the candidates stronger than 95 %
//!   of the VPLs) weakest VPLs invalidated; at most `M_max` invalid VPLs removed, the strongest
//!   candidates put in their place; radiosities and densities re-estimated for the frame
//!   (Algorithm 1, lines 18–19). The first frame runs the algorithm `warmup` times (100 in
//!   the paper) from candidates alone.
//! - **`smc-ir-nrc`**: as `smc-ir`, each VPL's radiosity one query of the radiance source (the
//!   cache trained online) instead of traced paths; the warm-up iterations of the first frame
//!   use traced radiosities (the source answers once per frame).
//!
//! Shading: every pixel sample's primary vertex (delta primaries are path traced instead)
//! connects to the VPLs of its interleaving group (`per_pixel` of the `I`, the group chosen by
//! the pixel's position in a tile; the sum scaled by the number of groups), with the geometry
//! term clamped at `G_max = 1/(clamp · diagonal)²`; with `residual` the clamped-away part is
//! estimated by one BSDF-sampled ray and the path-traced radiance where it lands, weighted by
//! `max(0, 1 − G_max/G)` (Kollig and Keller 2006): clamped plus residual is unbiased.
//! `indirect=1` renders the VPLs' (and the residual's) light alone (the paper's error measure).

use glam::{Vec2, Vec3};
use nrc_scene::{Scene, SurfaceInteraction};
use rayon::prelude::*;

use crate::error::SettingsError;
use super::screen::{GBuffer, Phase, stream, visible_between};
use super::params::{Key, Params, Value};
use super::spec::{PassConfig, PassKind, parse_variant};
use super::frame::{FrameInput, PassOutput, RenderPass};
use crate::knn::PointGrid;
use crate::light_path::trace_light_path;
use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::{PixelSampler, Stream};
use crate::source::RadianceQuery;
use crate::transport::Vertex;

/// Which VPLs the pass keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VplMode {
    /// `ir`: traced from the lights every frame.
    Classic,
    /// `smc-ir`: Algorithm 1, radiosities path traced.
    Smc,
    /// `smc-ir-nrc`: Algorithm 1, radiosities from the radiance source.
    SmcSource,
}

/// Settings of the instant-radiosity passes (the paper's defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IrSettings {
    pub mode: VplMode,
    /// `I`, the VPL budget.
    pub vpls: u32,
    /// `M_max`, the most VPLs replaced per frame (`smc-ir`).
    pub m_max: u32,
    /// VPLs each pixel sample connects to (interleaved sampling); 0: all.
    pub per_pixel: u32,
    /// `G_max = 1/(clamp · scene diagonal)²`.
    pub clamp: f32,
    /// Estimate the clamped-away part by one BSDF-sampled ray.
    pub residual: bool,
    /// Path-traced samples per VPL radiosity (`smc-ir`).
    pub radiosity_spp: u32,
    /// Intersection points per candidate (`rate · I` points resampled into `I` candidates).
    pub rate: u32,
    /// Algorithm 1 iterations before the first frame.
    pub warmup: u32,
    /// Points visible to the camera sampled per frame (a square grid of this many rays).
    pub visible_points: u32,
    /// Only the VPLs' (and the residual's) light: no emission, no direct light.
    pub indirect: bool,
}

impl Default for IrSettings {
    fn default() -> Self {
        Self {
            mode: VplMode::Smc,
            vpls: 2048,
            m_max: 16,
            per_pixel: 64,
            clamp: 0.1,
            residual: false,
            radiosity_spp: 16,
            rate: 16,
            warmup: 100,
            visible_points: 1024,
            indirect: false,
        }
    }
}

impl IrSettings {
    pub fn validate(&self) -> Result<(), SettingsError> {
        if self.vpls == 0 {
            return Err(SettingsError::bounds("vpls", "be at least 1", self.vpls));
        }
        // Absurd counts would be absurd allocations (`rate · vpls` candidate points) or loops.
        for (name, value, max) in [
            ("vpls", self.vpls, 1 << 20),
            ("rate", self.rate, 64),
            ("spp", self.radiosity_spp, 4096),
            ("warmup", self.warmup, 10_000),
            ("points", self.visible_points, 1 << 20),
            ("mmax", self.m_max, 1 << 20),
        ] {
            if value > max {
                return Err(SettingsError::bounds(name, format!("be at most {max}"), value));
            }
        }
        if self.per_pixel > self.vpls {
            return Err(SettingsError::bounds(
                "per_pixel",
                format!("not exceed vpls ({})", self.vpls),
                self.per_pixel,
            ));
        }
        if !(self.clamp.is_finite() && self.clamp > 0.0) {
            return Err(SettingsError::bounds("clamp", "be finite and > 0", self.clamp));
        }
        if self.rate == 0 || self.radiosity_spp == 0 || self.visible_points == 0 {
            return Err(SettingsError::Combination(
                "rate, radiosity_spp and visible points must be at least 1",
            ));
        }
        Ok(())
    }

}

pub const KIND: PassKind = PassKind {
    grammar: "ir, smc-ir, smc-ir-nrc",
    about: "instant radiosity: VPLs traced from the lights each frame (ir), sequential Monte \
            Carlo VPLs kept across frames with path-traced (smc-ir) or cache (smc-ir-nrc) \
            radiosities",
    method: true,
    variants: || variants().into_iter().map(|(_, s)| s.into()).collect(),
    parse: |name| parse_variant(name, &variants(), IrSettings::validate),
};

fn variants() -> [(&'static str, IrSettings); 3] {
    let d = IrSettings::default();
    [
        ("ir", IrSettings { mode: VplMode::Classic, ..d }),
        ("smc-ir", IrSettings { mode: VplMode::Smc, ..d }),
        ("smc-ir-nrc", IrSettings { mode: VplMode::SmcSource, ..d }),
    ]
}

impl Params for IrSettings {
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
        let at_most = |key: &'static str, help, max: f64| Key::new(key, help).range(0.0, max);
        let count = |key: &'static str, help, max: f64| Key::new(key, help).range(1.0, max);
        f(&count("vpls", "I, the VPL budget", 1048576.0), &mut self.vpls);
        let m_max = at_most("mmax", "M_max, the most VPLs replaced per frame", 1048576.0);
        f(&m_max, &mut self.m_max);
        let per_pixel = at_most("per_pixel", "VPLs per pixel sample (0: all)", 1048576.0);
        f(&per_pixel, &mut self.per_pixel);
        let clamp = Key::new("clamp", "G_max = 1/(clamp · scene diagonal)²");
        f(&clamp.positive(f64::INFINITY), &mut self.clamp);
        let residual = Key::new("residual", "the clamped-away part by one BSDF-sampled ray");
        f(&residual, &mut self.residual);
        let spp = count("spp", "path-traced samples per VPL radiosity", 4096.0);
        f(&spp, &mut self.radiosity_spp);
        f(&count("rate", "points per candidate", 64.0), &mut self.rate);
        let warmup = at_most("warmup", "Algorithm 1 iterations before the first frame", 1e4);
        f(&warmup, &mut self.warmup);
        let points = count("points", "camera-visible points sampled per frame", 1048576.0);
        f(&points, &mut self.visible_points);
        let indirect = Key::new("indirect", "only the VPLs' light: no emission, no direct light");
        f(&indirect, &mut self.indirect);
    }
}

impl PassConfig for IrSettings {
    /// (measured 392 (`ir`).)
    fn state_bytes_per_sample(&self) -> u64 {
        450
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let (base, defaults) = variants()[self.mode as usize];
        super::params::name(base, self, &defaults)
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(InstantRadiosityPass::new(*self, *tracer))
    }

    fn is_stateful(&self) -> bool {
        self.mode != VplMode::Classic
    }

    fn uses_source(&self) -> bool {
        self.mode == VplMode::SmcSource
    }

    fn params(&self) -> Vec<super::params::Param> {
        super::params::list(self)
    }
}

/// A virtual point light.
#[derive(Clone, Copy, Debug)]
pub struct Vpl {
    pub position: Vec3,
    /// Geometric normal, on the side the light leaves from.
    pub normal: Vec3,
    /// `smc-ir`: radiosity `L(y)` (radiance leaving the diffuse surface); `ir`: flux weight
    /// `β / N` arrived at `y`.
    pub power: Vec3,
    /// Diffuse albedo at `y` (`ir`'s `f_y = albedo/π` for diffuse surfaces; glossy ones use
    /// their diffuse part, as the paper's diffuse assumption does).
    pub albedo: Vec3,
    /// `p(y)` per unit area (`smc-ir`).
    pub density: f32,
    /// The camera-visible point it is associated with (§3.2.2) and that point's normal.
    pub anchor: Vec3,
    pub anchor_normal: Vec3,
    /// Seed of its radiosity estimate, fixed for its lifetime (§3.2.3).
    pub seed: u64,
}

impl Vpl {
    /// `I(y) = lum(L(y)) / p(y)` (eq. 6). Without a density (no VPLs yet to measure it
    /// against, at initialisation) candidates rank by their radiosity alone.
    pub fn intensity(&self) -> f32 {
        let l = luminance(self.power);
        if self.density > 0.0 {
            l / self.density
        } else {
            f32::INFINITY.min(l * 1e30)
        }
    }
}

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Counts of the last frame's VPL upkeep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VplFrameStats {
    /// VPLs found invalid (not indirectly visible), before eq. 9's additions.
    pub invalid: u32,
    /// VPLs replaced this frame.
    pub replaced: u32,
    /// `M_strong` of eq. 9.
    pub strong: u32,
}

/// A point the camera sees this frame (for candidates and the visibility checks).
#[derive(Clone, Copy)]
struct Visible {
    p: Vec3,
    ng: Vec3,
}

/// Candidates waiting for their radiosities (`smc-ir-nrc` asks the source between trace and
/// resolve).
struct Pending {
    candidates: Vec<Vpl>,
    invalid: Vec<bool>,
}

/// The instant-radiosity pass state.
pub struct InstantRadiosityPass {
    pub settings: IrSettings,
    pub tracer: PathTracer,
    vpls: Vec<Vpl>,
    next_seed: u64,
    pending: Option<Pending>,
    gbuffer: Option<GBuffer>,
    pub last: VplFrameStats,
    /// The last frame's camera and size (the VPL view).
    view: Option<(nrc_scene::Camera, u32, u32)>,
}

impl InstantRadiosityPass {
    pub fn new(settings: IrSettings, tracer: PathTracer) -> Self {
        Self {
            settings,
            tracer,
            vpls: Vec::new(),
            next_seed: 1,
            pending: None,
            gbuffer: None,
            last: VplFrameStats::default(),
            view: None,
        }
    }

    /// The current VPLs.
    pub fn vpls(&self) -> &[Vpl] {
        &self.vpls
    }

    /// `G_max` for `scene`.
    fn g_max(&self, scene: &Scene) -> f32 {
        let b = scene.bounds();
        let d = (b.max - b.min).length().max(1e-6);
        1.0 / (self.settings.clamp * d).powi(2)
    }

    /// `k` of eq. 8.
    fn render_k(&self) -> usize {
        ((self.settings.vpls as f32).sqrt() / 32.0).floor().max(1.0) as usize
    }

    /// Points the camera sees: rays through a jittered square grid.
    fn visible_points(&self, input: &FrameInput, seed: u64) -> Vec<Visible> {
        let n = (self.settings.visible_points as f32).sqrt().ceil().max(1.0) as u32;
        (0..n * n)
            .into_par_iter()
            .filter_map(|i| {
                let mut s = PixelSampler::new(seed, i as u64, 11);
                let film = Vec2::new((i % n) as f32, (i / n) as f32) + s.next_2d();
                let ray = input.camera.generate_ray(film, n, n);
                let hit = input.scene.intersect(&ray)?;
                let si = input.scene.interaction(&ray, &hit);
                let ng = if si.ng.dot(si.wo) >= 0.0 {
                    si.ng
                } else {
                    -si.ng
                };
                Some(Visible { p: si.p, ng })
            })
            .collect()
    }

    /// `ir`: the frame's VPLs traced from the lights (flux weights over the paths traced).
    fn classic_vpls(&self, scene: &Scene, seed: u64) -> Vec<Vpl> {
        let want = self.settings.vpls as usize;
        let max_vertices = self.tracer.max_depth.max(0) as u32;
        let max_vertices = if self.tracer.max_depth < 0 {
            64
        } else {
            max_vertices.max(1)
        };
        let mut out: Vec<Vpl> = Vec::with_capacity(want);
        let mut paths = 0u64;
        // Paths in parallel chunks, consumed in order until the budget is met.
        while out.len() < want && paths < 64 * want as u64 + 64 {
            let chunk: Vec<Vec<Vpl>> = (paths..paths + 256)
                .into_par_iter()
                .map(|i| {
                    let mut s = PixelSampler::new(seed, i, 12);
                    let mut ps = PathStats::default();
                    let path = trace_light_path(scene, &self.tracer, max_vertices, &mut s, &mut ps);
                    path.vertices
                        .iter()
                        .filter(|v| !v.bsdf.is_delta())
                        .map(|v| {
                            let ng = if v.si.ng.dot(v.si.wo) >= 0.0 {
                                v.si.ng
                            } else {
                                -v.si.ng
                            };
                            Vpl {
                                position: v.si.p,
                                normal: ng,
                                power: v.beta,
                                albedo: v.bsdf.diffuse_reflectance(),
                                density: 0.0,
                                anchor: v.si.p,
                                anchor_normal: ng,
                                seed: i,
                            }
                        })
                        .collect()
                })
                .collect();
            // Whole paths only (a path cut short would leave its flux uncounted): the set
            // may exceed the budget by the last path's vertices.
            for vs in chunk {
                if out.len() >= want {
                    break;
                }
                paths += 1;
                out.extend(vs);
            }
        }
        let n = paths.max(1) as f32;
        for v in &mut out {
            v.power /= n;
        }
        out
    }

    /// `rate · I` intersection points of cosine-distributed rays from the visible points,
    /// resampled without replacement toward uniform area density into (up to) `I` candidates
    /// (§3.2.1). Their radiosities are not yet estimated.
    fn candidates(&mut self, scene: &Scene, visible: &[Visible], seed: u64) -> Vec<Vpl> {
        if visible.is_empty() {
            return Vec::new();
        }
        let want = self.settings.vpls as usize;
        let n = want * self.settings.rate as usize;
        let points: Vec<Option<(SurfaceInteraction, Visible)>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut s = PixelSampler::new(seed, i as u64, 13);
                let from = visible[(s.next_1d() * visible.len() as f32) as usize % visible.len()];
                let local = nrc_scene::sampling::sample_cosine_hemisphere(s.next_2d());
                let frame = nrc_scene::sampling::Frame::from_normal(from.ng);
                let d = frame.to_world(local);
                let ray = nrc_scene::spawn_ray(from.p, from.ng, d);
                let hit = scene.intersect(&ray)?;
                let si = scene.interaction(&ray, &hit);
                let bsdf = nrc_scene::bsdf::Bsdf::from_pbr(&scene.pbr(&si));
                (!bsdf.is_delta()).then_some((si, from))
            })
            .collect();
        let points: Vec<(SurfaceInteraction, Visible)> = points.into_iter().flatten().collect();
        if points.is_empty() {
            return Vec::new();
        }
        let grid = PointGrid::new(&points.iter().map(|(si, _)| si.p).collect::<Vec<_>>());
        let k = 8.min(points.len().saturating_sub(1)).max(1);
        // Weighted sampling without replacement (Efraimidis–Spirakis keys u^(1/w)), w ∝ 1/p.
        let mut keyed: Vec<(f32, usize)> = (0..points.len())
            .into_par_iter()
            .map(|i| {
                let p = grid.density(points[i].0.p, k, points.len(), Some(i));
                let w = if p > 0.0 && p.is_finite() {
                    1.0 / p
                } else {
                    0.0
                };
                let u = PixelSampler::new(seed, i as u64, 14).next_1d().max(1e-12);
                (
                    if w > 0.0 {
                        u.ln() / w
                    } else {
                        f32::NEG_INFINITY
                    },
                    i,
                )
            })
            .collect();
        keyed.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        keyed
            .into_iter()
            .take(want)
            .filter(|(key, _)| key.is_finite())
            .map(|(_, i)| {
                let (si, from) = points[i];
                let ng = if si.ng.dot(si.wo) >= 0.0 {
                    si.ng
                } else {
                    -si.ng
                };
                let bsdf = nrc_scene::bsdf::Bsdf::from_pbr(&scene.pbr(&si));
                self.next_seed += 1;
                Vpl {
                    position: si.p,
                    normal: ng,
                    power: Vec3::ZERO,
                    albedo: bsdf.diffuse_reflectance(),
                    density: 0.0,
                    anchor: from.p,
                    anchor_normal: from.ng,
                    seed: self.next_seed,
                }
            })
            .collect()
    }

    /// Path-traced radiosities (§3.2.3): the radiance leaving each VPL's point along its
    /// normal, `radiosity_spp` samples from its own seed.
    fn trace_radiosities(&self, scene: &Scene, vpls: &mut [Vpl]) {
        let spp = self.settings.radiosity_spp;
        let tracer = self.tracer;
        vpls.par_iter_mut().for_each(|v| {
            let Some(si) = surface_at(scene, v.position, v.normal) else {
                v.power = Vec3::ZERO;
                return;
            };
            let mut sum = Vec3::ZERO;
            let mut ps = PathStats::default();
            for j in 0..spp {
                let mut s = PixelSampler::new(v.seed, j as u64, 15);
                sum += tracer.reflected(scene, &si, v.normal, 1, &mut s, &mut ps);
            }
            v.power = sum / spp as f32;
        });
    }

    /// Radiosity queries of `vpls` for the radiance source.
    fn radiosity_queries(scene: &Scene, vpls: &[Vpl]) -> Vec<RadianceQuery> {
        vpls.iter()
            .map(|v| match surface_at(scene, v.position, v.normal) {
                Some(si) => {
                    let bsdf = nrc_scene::bsdf::Bsdf::from_pbr(&scene.pbr(&si));
                    RadianceQuery::at(&si, &bsdf, v.normal)
                }
                None => RadianceQuery {
                    position: v.position,
                    direction: v.normal,
                    normal: v.normal,
                    roughness: 1.0,
                    diffuse: Vec3::ZERO,
                    specular: Vec3::ZERO,
                },
            })
            .collect()
    }

    /// §3.2.2: whether each VPL is indirectly visible: its anchor still seen by the camera and
    /// still seeing it, else found again by `V` = 16 rays from visible points, two rounds (a
    /// VPL found again takes the point that found it as its anchor).
    fn validate(&mut self, input: &FrameInput, visible: &[Visible], seed: u64) -> Vec<bool> {
        let scene = input.scene;
        let cam = input.camera.position;
        let mut stats = PathStats::default();
        let mut valid: Vec<bool> = self
            .vpls
            .iter()
            .map(|v| {
                let seen = {
                    let ray = nrc_scene::spawn_ray_to(v.anchor, v.anchor_normal, cam);
                    !scene.occluded(&ray) && input.camera.project(v.anchor, 1, 1).is_some()
                };
                seen && visible_between(
                    scene,
                    v.anchor,
                    v.anchor_normal,
                    v.position,
                    v.normal,
                    &mut PathStats::default(),
                )
            })
            .collect();
        if visible.is_empty() {
            return valid;
        }
        let mut s = PixelSampler::new(seed, 0, 16);
        for _round in 0..2 {
            let invalid: Vec<usize> = (0..valid.len()).filter(|&i| !valid[i]).collect();
            if invalid.is_empty() {
                break;
            }
            for _ in 0..16 {
                let i = invalid[(s.next_1d() * invalid.len() as f32) as usize % invalid.len()];
                if valid[i] {
                    continue;
                }
                let from = visible[(s.next_1d() * visible.len() as f32) as usize % visible.len()];
                let v = self.vpls[i];
                let facing = (v.position - from.p).dot(from.ng) > 0.0
                    && (from.p - v.position).dot(v.normal) > 0.0;
                if facing
                    && visible_between(scene, from.p, from.ng, v.position, v.normal, &mut stats)
                {
                    valid[i] = true;
                    self.vpls[i].anchor = from.p;
                    self.vpls[i].anchor_normal = from.ng;
                }
            }
        }
        valid
    }

    /// Candidates' densities against the current VPLs with `k = 1` (§3.2.4).
    fn candidate_densities(&self, candidates: &mut [Vpl]) {
        if self.vpls.is_empty() {
            candidates.iter_mut().for_each(|c| c.density = 0.0);
            return;
        }
        let grid = PointGrid::new(&self.vpls.iter().map(|v| v.position).collect::<Vec<_>>());
        // Eq. 7's I is the number of VPLs there are (the budget once the set is full), the same
        // I as eq. 5's in `vpl_light`.
        let n = self.vpls.len();
        candidates
            .par_iter_mut()
            .for_each(|c| c.density = grid.density(c.position, 1, n, None));
    }

    /// The current VPLs' densities among themselves, `k` from eq. 8.
    fn vpl_densities(&mut self) {
        if self.vpls.is_empty() {
            return;
        }
        let grid = PointGrid::new(&self.vpls.iter().map(|v| v.position).collect::<Vec<_>>());
        let k = self
            .render_k()
            .min(self.vpls.len().saturating_sub(1))
            .max(1);
        let n = self.vpls.len();
        self.vpls.par_iter_mut().enumerate().for_each(|(i, v)| {
            v.density = grid.density(v.position, k, n, Some(i));
        });
    }

    /// Lines 9–17 of Algorithm 1 on candidates with radiosities and densities, given which
    /// VPLs are valid.
    fn replace(&mut self, mut candidates: Vec<Vpl>, mut invalid: Vec<bool>) {
        let budget = self.settings.vpls as usize;
        let m_max = self.settings.m_max as usize;
        let mut stats = VplFrameStats {
            invalid: invalid.iter().filter(|x| **x).count() as u32,
            ..Default::default()
        };
        if self.vpls.is_empty() {
            // Initialisation: the strongest candidates.
            candidates.sort_by(|a, b| b.intensity().total_cmp(&a.intensity()));
            candidates.truncate(budget);
            stats.replaced = candidates.len() as u32;
            self.vpls = candidates;
            self.last = stats;
            return;
        }
        // Eq. 9: candidates stronger than 95 % of the current VPLs.
        let mut current: Vec<f32> = self.vpls.iter().map(Vpl::intensity).collect();
        current.sort_by(f32::total_cmp);
        let p95 = current[((current.len() as f32 * 0.95) as usize).min(current.len() - 1)];
        let strong = candidates.iter().filter(|c| c.intensity() > p95).count();
        stats.strong = strong as u32;
        let m_min = m_max.min(strong);
        // Invalidate the weakest valid VPLs until M_min are invalid.
        let mut order: Vec<usize> = (0..self.vpls.len()).collect();
        order.sort_by(|&a, &b| {
            self.vpls[a]
                .intensity()
                .total_cmp(&self.vpls[b].intensity())
        });
        let mut n_invalid = invalid.iter().filter(|x| **x).count();
        for &i in &order {
            if n_invalid >= m_min {
                break;
            }
            if !invalid[i] {
                invalid[i] = true;
                n_invalid += 1;
            }
        }
        // CLAMPSIZE: remove at most M_max invalid VPLs, the weakest first.
        let mut removed = 0;
        let mut remove = vec![false; self.vpls.len()];
        for &i in &order {
            if removed >= m_max {
                break;
            }
            if invalid[i] {
                remove[i] = true;
                removed += 1;
            }
        }
        // Replace in place (survivors keep their slots), strongest candidates first.
        candidates.sort_by(|a, b| b.intensity().total_cmp(&a.intensity()));
        let mut next = candidates.into_iter();
        let mut replaced = 0;
        for (i, r) in remove.iter().enumerate() {
            if *r && let Some(c) = next.next() {
                self.vpls[i] = c;
                replaced += 1;
            }
        }
        // Slots removed without a candidate to fill them go away.
        let mut keep = remove.iter();
        let filled = replaced;
        let mut extra = removed - filled;
        self.vpls.retain(|_| {
            let r = *keep.next().unwrap_or(&false);
            if r && extra > 0 {
                extra -= 1;
                false
            } else {
                true
            }
        });
        // While room remains in the budget, more candidates.
        for c in next {
            if self.vpls.len() >= budget {
                break;
            }
            self.vpls.push(c);
            replaced += 1;
        }
        stats.replaced = replaced as u32;
        self.last = stats;
    }

    /// One iteration of Algorithm 1 with traced radiosities (the warm-up, and `smc-ir`).
    fn iterate_traced(&mut self, input: &FrameInput, visible: &[Visible], seed: u64) {
        let invalid: Vec<bool> = self
            .validate(input, visible, seed)
            .iter()
            .map(|v| !v)
            .collect();
        let mut cands = self.candidates(input.scene, visible, seed);
        self.trace_radiosities(input.scene, &mut cands);
        self.candidate_densities(&mut cands);
        self.replace(cands, invalid);
    }

    /// The indirect light at vertex `v` from the VPLs of group `group` of `groups`.
    fn vpl_light(
        &self,
        scene: &Scene,
        v: &Vertex,
        (group, groups): (usize, usize),
        g_max: f32,
        stats: &mut PathStats,
    ) -> Vec3 {
        let mut sum = Vec3::ZERO;
        let n_vpl = self.vpls.len();
        // Eq. 5's I: the VPLs there are, as their densities (eq. 7) count them.
        let budget = n_vpl.max(1) as f32;
        for j in (group..n_vpl).step_by(groups.max(1)) {
            let y = &self.vpls[j];
            let d = y.position - v.si.p;
            let dist2 = d.length_squared();
            if dist2 <= 0.0 {
                continue;
            }
            let wi = d / dist2.sqrt();
            let cos_y = (-wi).dot(y.normal);
            if cos_y <= 0.0 {
                continue;
            }
            let wi_local = v.frame.to_local(wi);
            let f = v.bsdf.eval(v.wo, wi_local);
            if f == Vec3::ZERO {
                continue;
            }
            let g = (wi_local.z.abs() * cos_y / dist2).min(g_max);
            let emitted = match self.settings.mode {
                VplMode::Classic => {
                    // f_y(ω_in, y→x): the diffuse lobe (the paper's diffuse assumption).
                    y.albedo / std::f32::consts::PI * y.power
                }
                _ => {
                    if y.density > 0.0 {
                        y.power / (budget * y.density)
                    } else {
                        Vec3::ZERO
                    }
                }
            };
            if emitted == Vec3::ZERO {
                continue;
            }
            if !visible_between(scene, v.si.p, v.si.ng, y.position, y.normal, stats) {
                continue;
            }
            sum += f * g * emitted;
        }
        sum * groups.max(1) as f32
    }

    /// Kollig–Keller residual: the clamped-away part by one BSDF-sampled ray.
    fn residual(
        &self,
        scene: &Scene,
        v: &Vertex,
        g_max: f32,
        sampler: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let Some(bs) = v.bsdf.sample(v.wo, sampler.next_2d(), sampler.next_1d()) else {
            return Vec3::ZERO;
        };
        if bs.delta || bs.weight == Vec3::ZERO {
            return Vec3::ZERO;
        }
        let wi = v.frame.to_world(bs.wi);
        let ray = nrc_scene::spawn_ray(v.si.p, v.si.ng, wi);
        stats.closest_rays += 1;
        let Some(hit) = scene.intersect(&ray) else {
            return Vec3::ZERO;
        };
        let si = scene.interaction(&ray, &hit);
        let dist2 = (si.p - v.si.p).length_squared();
        let g = bs.wi.z.abs() * si.ng.dot(-wi).abs() / dist2.max(1e-30);
        if g <= g_max {
            return Vec3::ZERO;
        }
        let l = self.tracer.reflected(scene, &si, si.wo, 2, sampler, stats);
        bs.weight * l * (1.0 - g_max / g)
    }
}

/// The surface point at `p` (normal `n`), found again by a short ray back along `n`.
fn surface_at(scene: &Scene, p: Vec3, n: Vec3) -> Option<SurfaceInteraction> {
    let b = scene.bounds();
    let eps = 1e-4 * (b.max - b.min).length().max(1e-6);
    let ray = nrc_scene::Ray::new(p + n * eps, -n);
    let hit = scene.intersect(&ray)?;
    (hit.t <= 3.0 * eps).then(|| scene.interaction(&ray, &hit))
}

impl RenderPass for InstantRadiosityPass {
    fn name(&self) -> String {
        self.settings.name()
    }

    fn reset(&mut self) {
        self.vpls.clear();
        self.next_seed = 1;
        self.pending = None;
        self.gbuffer = None;
    }

    fn debug_views(&self) -> Vec<super::frame::PassView> {
        let Some((camera, w, h)) = &self.view else {
            return Vec::new();
        };
        // Each VPL in its power's colour, the brightest at 1.
        let brightest = self
            .vpls
            .iter()
            .map(|v| v.power.max_element())
            .filter(|p| p.is_finite())
            .fold(0.0f32, f32::max);
        let scale = if brightest > 0.0 { 1.0 / brightest } else { 0.0 };
        let radius = (*w.max(h) as f32 / 200.0).max(1.0);
        vec![super::frame::PassView::points(
            "vpls",
            camera,
            *w,
            *h,
            self.vpls.iter().map(|v| (v.position, v.power * scale)),
            radius,
        )]
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        self.view = Some((*input.camera, input.width, input.height));
        let seed = Stream::Vpls.seed(input.seed);
        // `indirect=1` leaves the emission out: no extra camera rays for it.
        let input = &FrameInput {
            emitter_samples: if self.settings.indirect {
                0
            } else {
                input.emitter_samples
            },
            ..*input
        };
        self.gbuffer = Some(GBuffer::trace(input, true));
        let mut queries = Vec::new();
        match self.settings.mode {
            VplMode::Classic => {
                self.vpls = self.classic_vpls(input.scene, seed);
                self.last = VplFrameStats {
                    replaced: self.vpls.len() as u32,
                    ..Default::default()
                };
            }
            VplMode::Smc | VplMode::SmcSource => {
                let visible = self.visible_points(input, seed);
                if self.vpls.is_empty() {
                    // Each iteration its own stream: the frame's own iteration below uses
                    // `seed`, which the first warm-up iteration used to repeat.
                    for w in 0..self.settings.warmup.max(1) {
                        let stream = Stream::VplWarmup(w).seed(input.seed);
                        self.iterate_traced(input, &visible, stream);
                        self.vpl_densities();
                    }
                }
                if self.settings.mode == VplMode::Smc {
                    self.iterate_traced(input, &visible, seed);
                    let mut v = std::mem::take(&mut self.vpls);
                    self.trace_radiosities(input.scene, &mut v);
                    self.vpls = v;
                } else {
                    let invalid: Vec<bool> = self
                        .validate(input, &visible, seed)
                        .iter()
                        .map(|v| !v)
                        .collect();
                    let candidates = self.candidates(input.scene, &visible, seed);
                    queries = Self::radiosity_queries(input.scene, &candidates);
                    queries.extend(Self::radiosity_queries(input.scene, &self.vpls));
                    self.pending = Some(Pending {
                        candidates,
                        invalid,
                    });
                }
            }
        }
        queries
    }

    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput {
        if let Some(Pending {
            mut candidates,
            invalid,
        }) = self.pending.take()
        {
            let nc = candidates.len();
            for (c, a) in candidates.iter_mut().zip(answers) {
                c.power = a.max(Vec3::ZERO);
            }
            for (v, a) in self.vpls.iter_mut().zip(&answers[nc.min(answers.len())..]) {
                v.power = a.max(Vec3::ZERO);
            }
            self.candidate_densities(&mut candidates);
            self.replace(candidates, invalid);
        }
        if self.settings.mode != VplMode::Classic {
            self.vpl_densities();
        }
        let g = self.gbuffer.take().expect("trace before resolve");
        let scene = input.scene;
        let g_max = self.g_max(scene);
        let groups = if self.settings.per_pixel == 0 {
            1
        } else {
            (self.vpls.len() / self.settings.per_pixel as usize).max(1)
        };
        // Interleaving: groups tile the image in a square pattern.
        let side = (groups as f32).sqrt().ceil() as usize;
        let spp = g.spp as usize;
        let width = g.width as usize;
        let results: Vec<(Vec3, (), PathStats)> = (0..g.len())
            .into_par_iter()
            .map(|i| {
                let mut stats = PathStats::default();
                let Some(p) = &g.primary[i] else {
                    let e = if self.settings.indirect {
                        Vec3::ZERO
                    } else {
                        g.emitted[i]
                    };
                    return (e, (), stats);
                };
                let mut sampler = stream(input.seed, i, Phase::Shading);
                let v = &p.v;
                let mut out = if self.settings.indirect {
                    Vec3::ZERO
                } else {
                    g.emitted[i]
                };
                if v.bsdf.is_delta() {
                    if !self.settings.indirect {
                        out += self.tracer.reflected(
                            scene,
                            &v.si,
                            v.wo_world,
                            1,
                            &mut sampler,
                            &mut stats,
                        );
                    }
                    return (out, (), stats);
                }
                if !self.settings.indirect {
                    out += crate::nee::next_event(
                        scene,
                        &v.si,
                        &v.bsdf,
                        &v.frame,
                        v.wo,
                        false,
                        crate::nee::Counts::ONE,
                        sampler.next_1d(),
                        sampler.next_2d(),
                        &mut stats,
                    );
                }
                let pixel = i / spp;
                let (x, y) = (pixel % width, pixel / width);
                let group = ((y % side) * side + (x % side)) % groups;
                out += self.vpl_light(scene, v, (group, groups), g_max, &mut stats);
                if self.settings.residual {
                    out += self.residual(scene, v, g_max, &mut sampler, &mut stats);
                }
                (out, (), stats)
            })
            .collect();
        super::screen::assemble(&g, input, results, Default::default()).0
    }
}
