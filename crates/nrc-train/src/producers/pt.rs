//! Path-traced training (Müller et al. 2021, §3.4; the NRC thesis, chapter 5).
//!
//! A training path starts at a predicted query (a camera primary hit, or a previous
//! termination point) and is traced with next-event estimation and BSDF sampling combined by
//! MIS, and Russian roulette, exactly as the reference path tracer. Every vertex becomes a
//! training record: its target is the radiance transported back along the path to it,
//! `L_i = D_i + w_i ⊙ L_{i+1}`, where `D_i` is the direct light NEE found at vertex `i` plus
//! the MIS-weighted emission the next segment found, `w_i = f|cos|/p` (divided by the Russian
//! roulette probability when it applied) and the vertex's own emission is left out (the caller
//! of the cache adds it).
//!
//! **Self-learning**: a training path ends in the cache. Its first part is the rendering
//! path (it ends where the area-spread heuristic would end an inference path); its *suffix*
//! continues from there until the heuristic, measured afresh from the suffix's start, fires
//! again, and the cache's prediction at that vertex closes the sum (`L_{n} = cache(x_n)`),
//! carrying light from long paths at the cost of one query. One path in
//! [`PathProducer::unbiased_every`] ignores the heuristic and ends only by Russian roulette or
//! the maximum depth, so that the cache's own bias cannot feed back on itself unchecked.

use glam::Vec3;
use nrc_cache::{CacheQuery, TrainingBatch};
use nrc_render::spread::Spread;
use nrc_render::transport::{Arrival, PathWalk};
use nrc_render::{LightStrategy, PathStats, PathTracer, PixelSampler, RadianceQuery};
use rayon::prelude::*;

use crate::producer::{Produced, Producer, ProducerContext, ProducerStats, ROUND};
use crate::starts::StartRay;

/// The path-tracing producer.
#[derive(Clone, Debug)]
pub struct PathProducer {
    name: String,
    /// End training suffixes in the cache.
    pub self_learning: bool,
    /// With self-learning, one path in this many is unbiased (ends by Russian roulette only);
    /// 16 in the paper.
    pub unbiased_every: u32,
    /// Threshold `c` of the area-spread heuristic (0.01 in the paper).
    pub spread_c: f32,
}

impl PathProducer {
    pub fn new(self_learning: bool) -> Self {
        Self {
            name: if self_learning { "pt-sl" } else { "pt" }.into(),
            self_learning,
            unbiased_every: 16,
            spread_c: 0.01,
        }
    }
}

/// One vertex of a training path: its query, the radiance found directly from it, and the
/// weight of the radiance arriving from the next vertex.
#[derive(Clone, Copy, Debug)]
struct Vertex {
    query: CacheQuery,
    direct: Vec3,
    weight: Vec3,
}

/// A traced training path: its vertices and, with self-learning, the query that closes it.
#[derive(Clone, Debug, Default)]
struct TracedPath {
    vertices: Vec<Vertex>,
    tail: Option<RadianceQuery>,
    rays: u64,
}

impl PathProducer {
    /// Traces one training path from `start`, through the path-vertex step of
    /// [`nrc_render::transport`] (NEE and BSDF sampling by MIS, Russian roulette on the
    /// throughput, the tracer's depth limit).
    fn trace(
        &self,
        ctx: &ProducerContext,
        start: &StartRay,
        sampler: &mut PixelSampler,
        unbiased: bool,
    ) -> TracedPath {
        let scene = ctx.scene;
        let tracer = PathTracer {
            strategy: LightStrategy::Mis,
            ..ctx.tracer
        };
        let heuristic = self.self_learning && !unbiased;
        let mut out = TracedPath::default();
        let mut stats = PathStats::default();
        let mut walk = PathWalk::from_ray(scene, &tracer, start.ray).for_records();
        let mut spread = Spread::new(self.spread_c);
        let mut in_suffix = false;
        let mut fired = false;
        loop {
            let h = match walk.arrive(scene, &mut stats) {
                Arrival::Escaped { le, mis } => {
                    if let Some(last) = out.vertices.last_mut() {
                        last.direct += last.weight * le * mis;
                    }
                    break;
                }
                Arrival::Hit(h) => h,
            };
            // Emission found by the segment belongs to the previous vertex's radiance.
            if let Some(last) = out.vertices.last_mut()
                && h.le != Vec3::ZERO
            {
                last.direct += last.weight * h.le * h.mis;
            }
            let v = &h.vertex;
            let query = v.query();
            if heuristic {
                // `fired` stays set once the spread exceeds the threshold: a suffix never
                // closes at a delta vertex (the cache cannot hold its radiance), it goes on to
                // the next one.
                fired |= spread.arrive(h.dist * h.dist, h.prev_pdf, v.si.ng.dot(v.si.wo));
                if fired && !v.bsdf.is_delta() {
                    fired = false;
                    if in_suffix {
                        out.tail = Some(query);
                        break;
                    }
                    // The rendering path would end here: the suffix starts.
                    in_suffix = true;
                    // Measured afresh: the suffix's first segment is its reference footprint.
                    spread.restart();
                }
            }
            if walk.at_depth_limit() {
                // The depth limit: self-learning paths close in the cache, others are cut.
                if heuristic {
                    out.tail = Some(query);
                }
                break;
            }
            let direct = walk.next_event(scene, v, sampler, &mut stats);
            out.vertices.push(Vertex {
                query: ctx.queries.cache_query(&query),
                direct,
                weight: Vec3::ZERO,
            });
            let Some(s) = walk.scatter(v, sampler) else {
                break;
            };
            out.vertices.last_mut().expect("just pushed").weight = s.weight;
            if s.weight == Vec3::ZERO {
                break;
            }
        }
        out.rays = stats.rays();
        out
    }
}

impl Producer for PathProducer {
    fn name(&self) -> &str {
        &self.name
    }

    fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced {
        let mut stats = ProducerStats::default();
        if budget == 0 || ctx.starts.is_empty() {
            return Produced::default();
        }
        let mut paths: Vec<TracedPath> = Vec::new();
        let mut records = 0usize;
        // Rounds of paths until the budget is met (deterministic: path i uses stream i).
        while records < budget {
            let first = paths.len();
            let round: Vec<TracedPath> = (first..first + ROUND)
                .into_par_iter()
                .map(|i| {
                    let mut sampler = PixelSampler::new(seed, i as u64, 0);
                    let unbiased = !self.self_learning
                        || (i as u32).is_multiple_of(self.unbiased_every.max(1));
                    self.trace(
                        ctx,
                        &ctx.starts[i % ctx.starts.len()],
                        &mut sampler,
                        unbiased,
                    )
                })
                .collect();
            let before = records;
            records += round.iter().map(|p| p.vertices.len()).sum::<usize>();
            paths.extend(round);
            stats.paths += ROUND as u64;
            if records == before && paths.len() >= 4 * ROUND {
                break; // Nothing to hit: the starts miss the scene.
            }
        }
        stats.rays = paths.iter().map(|p| p.rays).sum();
        // Self-learning: every path's closing query in one cache call.
        let tails: Vec<RadianceQuery> = paths.iter().filter_map(|p| p.tail).collect();
        let predicted = if tails.is_empty() {
            Vec::new()
        } else {
            ctx.cache.radiance(&tails)
        };
        let mut predicted = predicted.into_iter();
        let mut batch = TrainingBatch::default();
        for p in &paths {
            let mut radiance = match p.tail {
                Some(_) => predicted.next().expect("one prediction per tail"),
                None => Vec3::ZERO,
            };
            let start = batch.queries.len();
            for v in p.vertices.iter().rev() {
                radiance = v.direct + v.weight * radiance;
                batch.queries.push(v.query);
                batch.targets.push(radiance.to_array());
            }
            batch.queries[start..].reverse();
            batch.targets[start..].reverse();
            if batch.queries.len() >= budget {
                break;
            }
        }
        batch.queries.truncate(budget);
        batch.targets.truncate(budget);
        Produced { batch, stats }
    }
}
