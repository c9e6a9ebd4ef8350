//! Cache-terminated rendering: camera paths traced with BSDF sampling (optionally NEE with
//! MIS) that end at a vertex chosen by a [`Termination`] strategy, where the cache's
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
use std::time::Instant;

use glam::{Vec2, Vec3};
use nrc_cache::CacheQuery;
use nrc_render::path_tracer::{emission_mis_weight, next_event};
use nrc_render::{PathStats, PathTracer, PixelSampler};
use nrc_scene::{Camera, Image, Scene, bsdf::Bsdf, sampling::Frame, spawn_ray};
use rayon::prelude::*;

use crate::query::{QueryMaker, v3};
use crate::spread::Spread;
use crate::starts::TerminationPoint;
use crate::view::RadianceView;

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
}

impl Default for Termination {
    fn default() -> Self {
        Self::SpreadAngle { c: 0.01 }
    }
}

/// The grammar of termination names.
pub const TERMINATION_NAMES: &str =
    "first, diffuse[:ROUGHNESS] (default 0.3), spread[:C] (default 0.01), bth[:K] (default 4)";

impl FromStr for Termination {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (name, param) = match s.trim().split_once(':') {
            Some((n, p)) => (n, Some(p)),
            None => (s.trim(), None),
        };
        let value = |default: f32| -> Result<f32, String> {
            match param {
                None => Ok(default),
                Some(p) => match p.parse::<f32>() {
                    Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
                    _ => Err(format!(
                        "termination `{s}`: the parameter must be a positive number, got `{p}`"
                    )),
                },
            }
        };
        Ok(match name {
            "first" if param.is_none() => Self::FirstVertex,
            "diffuse" => Self::FirstDiffuse {
                roughness: value(0.3)?,
            },
            "spread" => Self::SpreadAngle { c: value(0.01)? },
            "bth" => Self::Balanced { k: value(4.0)? },
            _ => {
                return Err(format!(
                    "unknown termination `{s}`; known: {TERMINATION_NAMES}"
                ));
            }
        })
    }
}

impl fmt::Display for Termination {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::FirstVertex => write!(f, "first"),
            Self::FirstDiffuse { roughness: 0.3 } => write!(f, "diffuse"),
            Self::FirstDiffuse { roughness } => write!(f, "diffuse:{roughness}"),
            Self::SpreadAngle { c: 0.01 } => write!(f, "spread"),
            Self::SpreadAngle { c } => write!(f, "spread:{c}"),
            Self::Balanced { k: 4.0 } => write!(f, "bth"),
            Self::Balanced { k } => write!(f, "bth:{k}"),
        }
    }
}

/// The settings of the inference pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheRenderer {
    pub termination: Termination,
    /// Next-event estimation at the vertices before termination (MIS with BSDF sampling).
    pub nee: bool,
    /// Depth limit and Russian roulette of paths that have not ended in the cache.
    pub tracer: PathTracer,
    pub queries: QueryMaker,
}

/// What an inference pass counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct InferenceStats {
    /// Camera paths traced (pixels × samples).
    pub paths: u64,
    /// Rays traced.
    pub rays: u64,
    /// Paths that ended in the cache (queries sent to it).
    pub queries: u64,
    /// Samples whose value was NaN or infinite (counted as black).
    pub invalid_samples: u64,
    /// Milliseconds tracing paths.
    pub trace_ms: f64,
    /// Milliseconds in the cache call.
    pub cache_ms: f64,
}

/// A rendered inference pass.
#[derive(Clone, Debug)]
pub struct InferenceOutput {
    /// Per-pixel mean radiance.
    pub image: Image,
    /// Where paths ended in the cache (for the next frame's query prediction).
    pub terminations: Vec<TerminationPoint>,
    pub stats: InferenceStats,
}

/// One camera sample before the cache is asked.
#[derive(Clone, Copy, Debug)]
struct SamplePath {
    prefix: Vec3,
    throughput: Vec3,
    end: Option<(CacheQuery, TerminationPoint)>,
    rays: u64,
}

impl CacheRenderer {
    /// Whether the path ends in the cache at a vertex with `bsdf`, given the spread so far.
    fn ends_here(
        &self,
        bsdf: &Bsdf,
        wo: Vec3,
        arrival: Option<bool>,
        sampler: &mut PixelSampler,
    ) -> bool {
        match self.termination {
            Termination::FirstVertex => true,
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

    /// Traces one camera sample until it ends in the cache or otherwise.
    fn trace(
        &self,
        scene: &Scene,
        camera_pos: Vec3,
        mut ray: nrc_scene::Ray,
        sampler: &mut PixelSampler,
    ) -> SamplePath {
        let limit = if self.tracer.max_depth <= 0 {
            u32::MAX
        } else {
            self.tracer.max_depth as u32
        };
        let use_nee = self.nee && scene.light_count() > 0;
        let mut stats = PathStats::default();
        let mut out = SamplePath {
            prefix: Vec3::ZERO,
            throughput: Vec3::ONE,
            end: None,
            rays: 0,
        };
        let (mut prev_pdf, mut prev_delta) = (0.0f32, true);
        let mut prev_point = camera_pos;
        let mut spread = match self.termination {
            Termination::SpreadAngle { c } => Some(Spread::new(c)),
            _ => None,
        };
        let mut depth = 0u32;
        loop {
            stats.closest_rays += 1;
            let Some(hit) = scene.intersect(&ray) else {
                out.prefix += out.throughput * scene.background;
                break;
            };
            let si = scene.interaction(&ray, &hit);
            let dist = hit.t * ray.d.length();
            let le = scene.emission(&si);
            if le != Vec3::ZERO {
                out.prefix += out.throughput
                    * le
                    * emission_mis_weight(scene, &si, dist, prev_pdf, prev_delta || !use_nee);
            }
            let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
            let frame = Frame::from_normal(si.ns);
            let wo = frame.to_local(si.wo);
            let arrival = spread.as_mut().map(|s| {
                s.arrive(
                    dist * dist,
                    (!prev_delta).then_some(prev_pdf),
                    si.ng.dot(si.wo),
                )
            });
            if self.ends_here(&bsdf, wo, arrival, sampler) {
                out.end = Some((
                    self.queries.query(&si, &bsdf),
                    TerminationPoint {
                        from: prev_point,
                        to: si.p,
                    },
                ));
                break;
            }
            if depth + 1 >= limit {
                break;
            }
            if use_nee && !bsdf.is_delta() {
                out.prefix += out.throughput
                    * next_event(scene, &si, &bsdf, &frame, wo, true, sampler, &mut stats);
            }
            let u_lobe = sampler.next_1d();
            let u_dir = sampler.next_2d();
            let Some(bs) = bsdf.sample(wo, u_dir, u_lobe) else {
                break;
            };
            out.throughput *= bs.weight;
            prev_pdf = bs.pdf;
            prev_delta = bs.delta;
            prev_point = si.p;
            ray = spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
            depth += 1;
            if out.throughput == Vec3::ZERO {
                break;
            }
            if depth >= self.tracer.rr_depth {
                let q = out.throughput.max_element().min(0.95);
                if sampler.next_1d() >= q {
                    out.throughput = Vec3::ZERO;
                    break;
                }
                out.throughput /= q;
            }
        }
        out.rays = stats.rays();
        out
    }

    /// Renders `spp` cache-terminated samples per pixel; `seed` chooses the random streams.
    pub fn render(
        &self,
        scene: &Scene,
        camera: &Camera,
        cache: &dyn RadianceView,
        width: u32,
        height: u32,
        spp: u32,
        seed: u64,
    ) -> InferenceOutput {
        let spp = spp.max(1);
        let t0 = Instant::now();
        let samples: Vec<SamplePath> = (0..height)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..width).flat_map(move |x| {
                    let index = y as u64 * width as u64 + x as u64;
                    (0..spp).map(move |s| {
                        let mut sampler = PixelSampler::new(seed, index, s as u64);
                        let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                        let ray = camera.generate_ray(film, width, height);
                        self.trace(scene, camera.position, ray, &mut sampler)
                    })
                })
            })
            .collect();
        let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        let queries: Vec<CacheQuery> = samples.iter().filter_map(|s| s.end.map(|e| e.0)).collect();
        let predicted = if queries.is_empty() {
            Vec::new()
        } else {
            cache.predict(&queries)
        };
        let cache_ms = t1.elapsed().as_secs_f64() * 1e3;
        let mut predicted = predicted.into_iter();
        let mut stats = InferenceStats {
            paths: samples.len() as u64,
            queries: queries.len() as u64,
            trace_ms,
            cache_ms,
            ..Default::default()
        };
        let mut terminations = Vec::with_capacity(queries.len());
        let mut data = vec![Vec3::ZERO; width as usize * height as usize];
        let inv = 1.0 / spp as f32;
        for (i, s) in samples.iter().enumerate() {
            stats.rays += s.rays;
            let mut l = s.prefix;
            if let Some((_, point)) = s.end {
                l += s.throughput * v3(predicted.next().expect("one prediction per query"));
                terminations.push(point);
            }
            if !l.is_finite() {
                stats.invalid_samples += 1;
                l = Vec3::ZERO;
            }
            data[i / spp as usize] += l * inv;
        }
        InferenceOutput {
            image: Image::from_data(width as usize, height as usize, data)
                .expect("one value per pixel"),
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
