//! The cache-terminated pass: camera paths traced with BSDF sampling (optionally NEE with
//! MIS) that end at a vertex chosen by a [`Termination`] strategy, where the radiance source's
//! prediction of the outgoing radiance replaces the rest of the path.
//!
//! A sample's value is `prefix + throughput ⊙ cache(x_n)`: `prefix` holds the emission found
//! along the path (MIS-weighted against NEE when NEE is on, so the terminal vertex's own
//! emission is added back here, never learned) and the direct light NEE found at the
//! vertices before `x_n`; the cache returns `x_n`'s reflected radiance with the reflectance
//! factorisation applied. All termination queries of a frame go to the cache in one call, with
//! its EMA weights.
//!
//! With a cache that returns the exact reflected radiance, every strategy is unbiased: the
//! decision to end at `x_n` depends only on the path up to `x_n` (and for the balanced
//! heuristic on an independent random number), and both ending (the exact value) and going on
//! (an unbiased estimate of it) have the same expectation.

use std::fmt;
use std::str::FromStr;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::error::{PassError, TerminationError};
use super::params::{self, Params};
use super::spec::{PassConfig, PassKind};
use super::frame::{FrameInput, PassOutput, PassStats, RenderPass, TerminationPoint};
use crate::path_tracer::{LightStrategy, PathStats, PathTracer};
use crate::sampler::PixelSampler;
use crate::source::RadianceQuery;
use crate::spread::Spread;
use crate::transport::{Arrival, PathWalk};
use nrc_scene::{Image, bsdf::Bsdf};

/// Where a rendering path ends in the cache.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Termination {
    /// At the primary hit (the cache replaces all of the light transport).
    FirstVertex,
    /// At the first vertex whose BSDF is not a delta and whose perceptual roughness is at
    /// least `roughness` (0.3 by default): glossy and specular chains are traced through.
    FirstDiffuse { roughness: f32 },
    /// The area-spread heuristic of Müller et al. 2021 with threshold `c` (0.01 by default;
    /// see [`crate::spread`]), at the first non-delta vertex where it fires.
    SpreadAngle { c: f32 },
    /// The balanced termination heuristic: at a non-delta vertex, end with probability
    /// `t = (K·p_L)² / ((K·p_L)² + p_B²)`, the power heuristic of the Lambertian density
    /// `p_L = cos θ/π` against the BSDF's own density `p_B`, both evaluated at the mirror
    /// direction of `ωo` (the lobe's peak): a Lambertian vertex ends with probability
    /// `K²/(K²+1)`, a sharp glossy one almost never. `K` = 4 by default.
    Balanced { k: f32 },
    /// At the secondary vertex (the first bounce's hit) unless it is a delta: the primary
    /// vertex's direct light by NEE and BSDF sampling, the rest from the source (DDGI
    /// resampling's "+Secondary DDGI").
    Secondary,
}

impl Default for Termination {
    fn default() -> Self {
        Self::SpreadAngle { c: 0.01 }
    }
}

/// The grammar of termination names.
pub const TERMINATION_NAMES: &str = "first, secondary, diffuse[:ROUGHNESS] (default 0.3), spread[:C] (default 0.01), bth[:K] (default 4)";

impl FromStr for Termination {
    type Err = TerminationError;

    fn from_str(s: &str) -> Result<Self, TerminationError> {
        let (name, param) = match s.trim().split_once(':') {
            Some((n, p)) => (n, Some(p)),
            None => (s.trim(), None),
        };
        let value = |default: f32| -> Result<f32, TerminationError> {
            match param {
                None => Ok(default),
                Some(p) => match p.parse::<f32>() {
                    Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
                    _ => Err(TerminationError::BadParameter {
                        name: s.to_string(),
                        param: p.to_string(),
                    }),
                },
            }
        };
        Ok(match name {
            "first" if param.is_none() => Self::FirstVertex,
            "secondary" if param.is_none() => Self::Secondary,
            "diffuse" => Self::FirstDiffuse {
                roughness: value(0.3)?,
            },
            "spread" => Self::SpreadAngle { c: value(0.01)? },
            "bth" => Self::Balanced { k: value(4.0)? },
            _ => {
                return Err(TerminationError::Unknown {
                    name: s.to_string(),
                    known: TERMINATION_NAMES,
                });
            }
        })
    }
}

impl fmt::Display for Termination {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::FirstVertex => write!(f, "first"),
            Self::Secondary => write!(f, "secondary"),
            Self::FirstDiffuse { roughness: 0.3 } => write!(f, "diffuse"),
            Self::FirstDiffuse { roughness } => write!(f, "diffuse:{roughness}"),
            Self::SpreadAngle { c: 0.01 } => write!(f, "spread"),
            Self::SpreadAngle { c } => write!(f, "spread:{c}"),
            Self::Balanced { k: 4.0 } => write!(f, "bth"),
            Self::Balanced { k } => write!(f, "bth:{k}"),
        }
    }
}

pub const KIND: PassKind = PassKind {
    grammar: "cache[-TERMINATION][-nonee]",
    about: "camera paths ending in the radiance source where the termination says (default: \
            spread; first, secondary, diffuse[:ROUGHNESS] (default 0.3), spread[:C] (default \
            0.01), bth[:K] (default 4)); -nonee: BSDF sampling only before it",
    method: false,
    variants: || {
        let first = Termination::FirstVertex;
        [(Termination::default(), true), (first, true), (Termination::Secondary, true)]
            .into_iter()
            .chain([(Termination::default(), false)])
            .map(|(termination, nee)| CacheTerminatedSettings { termination, nee }.into())
            .collect()
    },
    parse: |name| {
        let rest = match name.strip_prefix("cache")? {
            "" => "",
            r if r.starts_with(':') || r.contains('=') => {
                return Some(Err(PassError::TerminationParameters {
                    pass: name.to_string(),
                }));
            }
            r => r.strip_prefix('-').filter(|t| !t.is_empty())?,
        };
        let (rest, nee) = match rest {
            "nonee" => ("", false),
            r => match r.strip_suffix("-nonee") {
                Some(t) if !t.is_empty() => (t, false),
                Some(_) => return None,
                None => (r, true),
            },
        };
        Some(
            match rest {
                "" => Ok(Termination::default()),
                t => t.parse().map_err(|source| PassError::Termination {
                    pass: name.to_string(),
                    source,
                }),
            }
            .map(|termination| CacheTerminatedSettings { termination, nee }.into()),
        )
    },
};

/// The cache-terminated pass's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheTerminatedSettings {
    pub termination: Termination,
    /// NEE (with MIS) at the vertices before the path ends; off: BSDF sampling only.
    pub nee: bool,
}

impl Default for CacheTerminatedSettings {
    fn default() -> Self {
        Self {
            termination: Termination::default(),
            nee: true,
        }
    }
}

impl Params for CacheTerminatedSettings {
    fn visit(&mut self, _: &mut dyn FnMut(&params::Key, &mut dyn params::Value)) {}
}

impl PassConfig for CacheTerminatedSettings {
    /// (measured 347 (`cache-first`).)
    fn state_bytes_per_sample(&self) -> u64 {
        400
    }

    fn kind(&self) -> &'static PassKind {
        &KIND
    }

    fn name(&self) -> String {
        let mut name = String::from("cache");
        if self.termination != Termination::default() {
            name += &format!("-{}", self.termination);
        }
        if !self.nee {
            name += "-nonee";
        }
        name
    }

    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        Box::new(CacheTerminatedPass::new(self.termination, self.nee, tracer))
    }

    fn uses_source(&self) -> bool {
        true
    }
}

/// One camera sample before the source is asked.
#[derive(Clone, Copy, Debug)]
struct SamplePath {
    prefix: Vec3,
    /// The part of `prefix` the camera ray saw directly (the emitters' anti-aliasing).
    seen: Vec3,
    throughput: Vec3,
    end: Option<(RadianceQuery, TerminationPoint)>,
    rays: u64,
}

/// The cache-terminated pass: its settings and the samples of the frame being traced.
#[derive(Clone, Debug)]
pub struct CacheTerminatedPass {
    pub termination: Termination,
    /// Depth limit, Russian roulette, and NEE at the vertices before termination (MIS with
    /// BSDF sampling) unless the strategy is BSDF sampling only.
    pub tracer: PathTracer,
    samples: Vec<SamplePath>,
}

impl CacheTerminatedPass {
    /// The pass ending paths by `termination`, with NEE (MIS) or without, and `tracer`'s depth
    /// limit and Russian roulette.
    pub fn new(termination: Termination, nee: bool, tracer: &PathTracer) -> Self {
        Self {
            termination,
            tracer: PathTracer {
                strategy: if nee {
                    LightStrategy::Mis
                } else {
                    LightStrategy::BsdfOnly
                },
                ..*tracer
            },
            samples: Vec::new(),
        }
    }

    /// Whether the path ends in the source at its `vertex`-th vertex (1: primary) with `bsdf`,
    /// given the spread so far.
    fn ends_here(
        &self,
        vertex: u32,
        bsdf: &Bsdf,
        wo: Vec3,
        arrival: Option<bool>,
        sampler: &mut PixelSampler,
    ) -> bool {
        match self.termination {
            Termination::FirstVertex => true,
            Termination::Secondary => vertex >= 2 && !bsdf.is_delta(),
            Termination::FirstDiffuse { roughness } => {
                !bsdf.is_delta() && bsdf.roughness() >= roughness
            }
            // Never at a delta vertex: its radiance is a view-dependent spike the cache cannot
            // hold; the path goes on to the next vertex, where the spread (which only grows)
            // still says stop.
            Termination::SpreadAngle { .. } => arrival.unwrap_or(false) && !bsdf.is_delta(),
            Termination::Balanced { k } => {
                // Always draw, so the stream does not depend on the BSDF.
                let u = sampler.next_1d();
                if bsdf.is_delta() || wo.z <= 0.0 {
                    return false;
                }
                let peak = Vec3::new(-wo.x, -wo.y, wo.z);
                let p_l = k * wo.z / std::f32::consts::PI;
                let p_b = bsdf.pdf(wo, peak);
                let t = if p_b.is_finite() {
                    p_l * p_l / (p_l * p_l + p_b * p_b)
                } else {
                    0.0
                };
                u < t
            }
        }
    }

    /// Traces one camera sample until it ends in the source or otherwise.
    fn trace_sample(
        &self,
        scene: &nrc_scene::Scene,
        camera_pos: Vec3,
        ray: nrc_scene::Ray,
        sampler: &mut PixelSampler,
    ) -> SamplePath {
        let mut stats = PathStats::default();
        let mut out = SamplePath {
            prefix: Vec3::ZERO,
            seen: Vec3::ZERO,
            throughput: Vec3::ONE,
            end: None,
            rays: 0,
        };
        let mut walk = PathWalk::from_ray(scene, &self.tracer, ray);
        let mut prev_point = camera_pos;
        let mut spread = match self.termination {
            Termination::SpreadAngle { c } => Some(Spread::new(c)),
            _ => None,
        };
        let mut vertex = 0;
        loop {
            vertex += 1;
            let h = match walk.arrive(scene, &mut stats) {
                Arrival::Escaped { le, mis } => {
                    out.prefix += walk.throughput() * le * mis;
                    if vertex == 1 {
                        out.seen = le * mis;
                    }
                    break;
                }
                Arrival::Hit(h) => h,
            };
            if h.le != Vec3::ZERO {
                out.prefix += walk.throughput() * h.le * h.mis;
                if vertex == 1 {
                    out.seen = h.le * h.mis;
                }
            }
            let v = &h.vertex;
            let arrival = spread
                .as_mut()
                .map(|s| s.arrive(h.dist * h.dist, h.prev_pdf, v.si.ng.dot(v.si.wo)));
            if self.ends_here(vertex, &v.bsdf, v.wo, arrival, sampler) {
                out.throughput = walk.throughput();
                out.end = Some((
                    v.query(),
                    TerminationPoint {
                        from: prev_point,
                        to: v.si.p,
                    },
                ));
                break;
            }
            if walk.at_depth_limit() {
                break;
            }
            out.prefix += walk.throughput() * walk.next_event(scene, v, sampler, &mut stats);
            if walk.scatter(v, sampler).is_none() {
                break;
            }
            prev_point = v.si.p;
        }
        out.rays = stats.rays();
        out
    }
}

impl RenderPass for CacheTerminatedPass {
    fn name(&self) -> String {
        CacheTerminatedSettings {
            termination: self.termination,
            nee: self.tracer.strategy != LightStrategy::BsdfOnly,
        }
        .name()
    }

    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery> {
        let (width, spp, seed) = (input.width, input.spp.max(1), input.seed);
        let (scene, camera) = (input.scene, input.camera);
        let this = &*self;
        let samples: Vec<SamplePath> = (0..input.height)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..width).flat_map(move |x| {
                    let index = y as u64 * width as u64 + x as u64;
                    (0..spp).map(move |s| {
                        let mut sampler = PixelSampler::new(seed, index, s as u64);
                        let offset = input.camera_offset(index, s, sampler.next_2d());
                        let film = Vec2::new(x as f32, y as f32) + offset;
                        let ray = camera.generate_ray(film, width, input.height);
                        this.trace_sample(scene, camera.position, ray, &mut sampler)
                    })
                })
            })
            .collect();
        let queries = samples.iter().filter_map(|s| s.end.map(|e| e.0)).collect();
        self.samples = samples;
        queries
    }

    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput {
        let (width, height, spp) = (input.width, input.height, input.spp.max(1));
        let samples = std::mem::take(&mut self.samples);
        let mut answers = answers.iter();
        let mut stats = PassStats {
            paths: samples.len() as u64,
            ..Default::default()
        };
        let mut terminations = Vec::new();
        let mut data = vec![Vec3::ZERO; width as usize * height as usize];
        let mut seen = data.clone();
        let inv = 1.0 / spp as f32;
        for (i, s) in samples.iter().enumerate() {
            stats.rays += s.rays;
            let mut l = s.prefix;
            if let Some((_, point)) = s.end {
                l += s.throughput * *answers.next().expect("one answer per query");
                terminations.push(point);
            }
            if l.is_finite() {
                seen[i / spp as usize] += s.seen * inv;
            } else {
                stats.invalid_samples += 1;
                l = Vec3::ZERO;
            }
            data[i / spp as usize] += l * inv;
        }
        let mut image =
            Image::from_data(width as usize, height as usize, data).expect("one value per pixel");
        if let Some(aa) = input.supersample_emitters(spp, &seen) {
            aa.apply(&mut image);
            stats.rays += aa.rays;
        }
        PassOutput {
            image,
            variance: None,
            terminations,
            stats,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn termination_names_parse_and_print() {
        for name in [
            "first",
            "diffuse",
            "diffuse:0.5",
            "spread",
            "spread:0.02",
            "bth",
            "bth:8",
        ] {
            assert_eq!(name.parse::<Termination>().unwrap().to_string(), name);
        }
        for bad in ["", "last", "spread:0", "spread:x", "bth:-1", "first:1"] {
            assert!(bad.parse::<Termination>().is_err(), "{bad}");
        }
    }
}
