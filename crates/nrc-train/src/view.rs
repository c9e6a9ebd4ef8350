//! The read-only face of a radiance cache.

use nrc_cache::{CacheQuery, RadianceCache};

/// Answers batches of queries with outgoing radiance (emission excluded). Producers read the
/// cache through it for self-learning, inference passes for termination; tests substitute
/// exact radiance fields.
pub trait RadianceView: Sync {
    /// Radiance leaving each query's point toward its direction, emission excluded.
    fn predict(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]>;
}

impl RadianceView for RadianceCache {
    fn predict(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        self.infer(queries)
    }
}

/// A cache that knows nothing: zero everywhere (self-learning off, or before training).
#[derive(Clone, Copy, Debug, Default)]
pub struct ZeroView;

impl RadianceView for ZeroView {
    fn predict(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        vec![[0.0; 3]; queries.len()]
    }
}

/// A cache that answers by path tracing: each query's reflected radiance is the mean of
/// `samples` independent path-traced estimates (emission at the query point excluded). It is
/// unbiased wherever the reference path tracer is, so rendering or training against it checks
/// a consumer's bookkeeping statistically; it is far too slow for anything else.
///
/// The query's point is found again by a ray cast back along its direction from a point
/// `offset` (relative to the scene box's diagonal) in front of it.
#[derive(Clone, Copy, Debug)]
pub struct PathTracedView<'a> {
    pub scene: &'a nrc_scene::Scene,
    pub queries: crate::query::QueryMaker,
    pub tracer: nrc_render::PathTracer,
    pub samples: u32,
    pub seed: u64,
}

impl RadianceView for PathTracedView<'_> {
    fn predict(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        use glam::Vec3;
        use rayon::prelude::*;
        let b = self.queries.scene_box;
        let (min, max) = (Vec3::from_array(b.min), Vec3::from_array(b.max));
        let offset = 1e-4 * (max - min).length();
        queries
            .par_iter()
            .enumerate()
            .map(|(i, q)| {
                let p = min + Vec3::from_array(q.position) * (max - min);
                let wo = Vec3::from_array(q.direction).normalize_or_zero();
                let ray = nrc_scene::Ray::new(p + wo * offset, -wo);
                let mut stats = nrc_render::PathStats::default();
                // Emission at the point the ray finds is subtracted (the cache's targets exclude it).
                let le = self.scene.intersect(&ray).map_or(Vec3::ZERO, |hit| {
                    self.scene.emission(&self.scene.interaction(&ray, &hit))
                });
                let mut sum = Vec3::ZERO;
                for s in 0..self.samples {
                    let mut sampler = nrc_render::PixelSampler::new(self.seed, i as u64, s as u64);
                    sum += self
                        .tracer
                        .radiance(self.scene, ray, &mut sampler, &mut stats)
                        - le;
                }
                (sum / self.samples.max(1) as f32).to_array()
            })
            .collect()
    }
}
