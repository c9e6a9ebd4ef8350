//! Bidirectional training (BT, the NRC thesis eq. 5.10).
//!
//! The training query `x` is a camera primary hit (the context's start rays, in order,
//! cycling), asking for the radiance leaving `x` toward the camera, `ωo = si.wo`. One light
//! path `y_0, y_1, ...` is traced per query ([`super::lt::trace_light_path`]: `y_0` on a light
//! chosen by power, a cosine-distributed emission direction, BSDF sampling, Russian roulette)
//! and every light vertex is connected to `x` by a shadow ray:
//!
//! - `j = 0`, the light sample itself (next-event estimation of direct light):
//!   `f_x(ωo, ω) |ω·n_s(x)| · Le(y_0 → x) |cos θ_{y_0}| / d² / p_A(y_0)` for a point on an
//!   emitter, `f_x · I(ω)/d² / P(light)` for a point or spot light, `f_x · E / P(light)` for a
//!   directional one, `f_x · L_env(ω) / p_ω(ω)` for an environment direction;
//! - `j ≥ 1`, a non-delta surface vertex with flux weight `β_j`:
//!   `f_x(ωo, ω) |ω·n_s(x)| · f_{y_j}(ω_{y_j→x}, ω_{y_j→y_{j−1}}) |cos_g θ_{y_j}| / d² · β_j`,
//!
//! `ω` the unit direction from `x` to the vertex and `d` their distance. The connection through
//! `y_j` is the only strategy in this estimator that produces paths with `j + 1` light vertices,
//! so the sum of the connections is an unbiased estimate of the radiance reflected at `x` over
//! all paths whose vertex next to `x` is a light point or a non-delta surface vertex. Not
//! covered: light reaching `x` through a delta (mirror or smooth glass) vertex next to it, and
//! the delta lobes of `x` itself. A query whose BSDF is entirely delta is skipped (no
//! connection can reach it); mixed BSDFs get only their non-delta part.
//!
//! The depth limit counts segments from the camera: camera → `x` → `y_j` → ... → `y_0` has
//! `j + 2` of them, so vertices with `j + 2 > max_depth` are not connected.
//!
//! The geometry term `1/d²` is unbounded where a light vertex lands near `x` (close to an edge
//! between two surfaces, for instance). The estimate stays unbiased, nothing is clamped, but its
//! variance grows without bound for queries near such edges; the regression's loss sees the
//! occasional large target.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use nrc_render::{PathStats, PixelSampler};
use nrc_scene::{SurfaceInteraction, bsdf::Bsdf, sampling::Frame, spawn_ray_between};

use nrc_render::light_path::{LightPath, light_vertex_limit, trace_light_path};

use crate::error::TrainError;
use crate::producer::{
    Produced, Producer, ProducerContext, ProducerStats, fill_rounds, push_records,
};

/// The bidirectional-training producer: one record per camera primary hit. It has no
/// settings (depth and Russian roulette come from the context's tracer).
#[derive(Clone, Debug, Default)]
pub struct BidirectionalProducer {}

/// The query point of a connection.
struct QueryPoint<'a> {
    si: &'a SurfaceInteraction,
    bsdf: &'a Bsdf,
    frame: Frame,
    wo: Vec3,
}

impl QueryPoint<'_> {
    /// `f_x(ωo, ω) |ω·n_s|` toward the world point `p`, with the unit direction `ω` and the
    /// squared distance.
    fn toward(&self, p: Vec3) -> (Vec3, Vec3, f32) {
        let d = p - self.si.p;
        let dist2 = d.length_squared();
        let w = d / dist2.sqrt();
        let wi = self.frame.to_local(w);
        (self.bsdf.eval(self.wo, wi) * wi.z.abs(), w, dist2)
    }
}

/// The sum of the connections of every vertex of `path` to `x` (see the module
/// documentation). `max_j`: the largest vertex index that may be connected.
fn connect(
    ctx: &ProducerContext,
    x: &QueryPoint,
    path: &LightPath,
    max_j: u32,
    stats: &mut PathStats,
    skipped: &AtomicU64,
) -> Vec3 {
    let scene = ctx.scene;
    let mut sum = Vec3::ZERO;
    // j = 0: the light sample itself (a point on an emitter, a punctual light, or an
    // environment direction), connected as next-event estimation connects it.
    if let Some(ls) = path.origin
        && let Some(inc) = ls.incident(x.si.p)
    {
        let wi = x.frame.to_local(inc.wi);
        let fx = x.bsdf.eval(x.wo, wi) * wi.z.abs();
        let c = fx * inc.li / inc.pdf;
        if !c.is_finite() {
            skipped.fetch_add(1, Ordering::Relaxed);
        } else if c.max_element() > 0.0 {
            stats.shadow_rays += 1;
            if !scene.occluded(&ls.shadow_ray(x.si.p, x.si.ng, &inc)) {
                sum += c;
            }
        }
    }
    // j ≥ 1: the surface vertices.
    for (k, y) in path.vertices.iter().enumerate() {
        if k as u32 + 1 > max_j {
            break;
        }
        if y.bsdf.is_delta() {
            continue;
        }
        let (fx, w, dist2) = x.toward(y.si.p);
        if fx == Vec3::ZERO {
            continue;
        }
        // At y the viewer is x (wo) and the light came from the previous vertex (wi).
        let fy = y.bsdf.eval(y.frame.to_local(-w), y.wo_local);
        let cos_y = y.si.ng.dot(w).abs();
        let c = fx * fy * y.beta * (cos_y / dist2);
        if !c.is_finite() {
            skipped.fetch_add(1, Ordering::Relaxed);
        } else if c.max_element() > 0.0 {
            stats.shadow_rays += 1;
            if !scene.occluded(&spawn_ray_between(x.si.p, x.si.ng, y.si.p, y.si.ng)) {
                sum += c;
            }
        }
    }
    sum
}

impl Producer for BidirectionalProducer {
    fn name(&self) -> &str {
        "bt"
    }

    fn check(&self, scene: &nrc_scene::Scene) -> Result<(), TrainError> {
        crate::producer::check_light_paths(self.name(), scene)
    }

    fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced {
        let mut stats = ProducerStats::default();
        if budget == 0 || ctx.starts.is_empty() {
            return Produced::default();
        }
        let scene = ctx.scene;
        // Connected vertex y_j: j + 2 segments from the camera.
        let max_j = light_vertex_limit(&ctx.tracer, 2);
        let max_j = if ctx.tracer.segment_limit() < 2 {
            None
        } else {
            Some(max_j)
        };
        // Query i: start i mod len, light path from stream (i, 0).
        let skipped = AtomicU64::new(0);
        let rounds = fill_rounds(budget, |i| {
            let mut ps = PathStats::default();
            ps.closest_rays += 1;
            let ray = ctx.starts[i % ctx.starts.len()].ray;
            let Some(hit) = scene.intersect(&ray) else {
                return (Vec::new(), ps.rays());
            };
            let si = scene.interaction(&ray, &hit);
            let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
            if bsdf.is_delta() {
                return (Vec::new(), ps.rays());
            }
            let frame = Frame::from_normal(si.ns);
            let x = QueryPoint {
                si: &si,
                bsdf: &bsdf,
                frame,
                wo: frame.to_local(si.wo),
            };
            let target = match max_j {
                None => Vec3::ZERO,
                Some(max_j) => {
                    let mut sampler = PixelSampler::new(seed, i as u64, 0);
                    let path = trace_light_path(scene, &ctx.tracer, max_j, &mut sampler, &mut ps);
                    connect(ctx, &x, &path, max_j, &mut ps, &skipped)
                }
            };
            (vec![(ctx.queries.query(&si, &bsdf), target)], ps.rays())
        });
        stats.paths = rounds.tried as u64;
        stats.rays = rounds.rays;
        stats.skipped = skipped.into_inner();
        let mut out = Produced::default();
        push_records(
            &mut out.batch,
            &mut stats,
            rounds.items.into_iter().take(budget),
        );
        out.stats = stats;
        out
    }
}
