//! Radiance sources: far-field radiance `L(y, ω)` at points a pass does not want to path
//! trace from. Every pass that ends paths early asks a source for a whole batch of queries at
//! once; the neural cache (an adapter in `nrc-train`, which knows burn), a DDGI probe volume
//! and the exact sources here all answer the same call, so every pass runs on every source.

use glam::Vec3;
use nrc_scene::{Ray, Scene};
use rayon::prelude::*;

use crate::path_tracer::{PathStats, PathTracer};
pub use crate::query::RadianceQuery;
use crate::sampler::PixelSampler;

/// Answers batches of queries with outgoing radiance, the query point's own emission excluded.
pub trait RadianceSource: Sync {
    /// Radiance leaving each query's point toward its direction, emission excluded; one
    /// answer per query, in order.
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3>;
}

/// A source's answer as a pass may use it: finite and non-negative, else zero (a cache still
/// learning can answer anything).
#[inline]
pub fn usable_answer(l: Vec3) -> Vec3 {
    if l.is_finite() {
        l.max(Vec3::ZERO)
    } else {
        Vec3::ZERO
    }
}

/// A source that knows nothing: zero everywhere (self-learning off, or no source at all).
#[derive(Clone, Copy, Debug, Default)]
pub struct ZeroSource;

impl RadianceSource for ZeroSource {
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3> {
        vec![Vec3::ZERO; queries.len()]
    }
}

/// An exact source by path tracing: each query's reflected radiance is the mean of `samples`
/// independent path-traced estimates (emission at the query point excluded). It is unbiased
/// wherever the reference path tracer is, so rendering or training against it checks a
/// consumer's bookkeeping statistically; it is far too slow for anything else.
///
/// The query's point is found again by a ray cast back along its direction from a point
/// `1e-4` of the scene box's diagonal in front of it.
#[derive(Clone, Copy, Debug)]
pub struct PathTracedSource<'a> {
    pub scene: &'a Scene,
    pub tracer: PathTracer,
    pub samples: u32,
    pub seed: u64,
}

impl RadianceSource for PathTracedSource<'_> {
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3> {
        let b = self.scene.bounds();
        let offset = 1e-4 * (b.max - b.min).length();
        queries
            .par_iter()
            .enumerate()
            .map(|(i, q)| {
                let wo = q.direction.normalize_or_zero();
                let ray = Ray::new(q.position + wo * offset, -wo);
                let mut stats = PathStats::default();
                // Emission at the point the ray finds is subtracted (sources exclude it).
                let le = self.scene.intersect(&ray).map_or(Vec3::ZERO, |hit| {
                    self.scene.emission(&self.scene.interaction(&ray, &hit))
                });
                let mut sum = Vec3::ZERO;
                for s in 0..self.samples {
                    let mut sampler = PixelSampler::new(self.seed, i as u64, s as u64);
                    sum += self
                        .tracer
                        .radiance(self.scene, ray, &mut sampler, &mut stats)
                        - le;
                }
                sum / self.samples.max(1) as f32
            })
            .collect()
    }
}
