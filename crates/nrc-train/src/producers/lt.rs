//! Light training (LT, the NRC thesis §5.4): training queries where light actually arrives.
//!
//! Light paths are traced from the lights (a point chosen by power, a cosine-distributed
//! direction on the emitting side or sides). At every non-delta vertex `y_j` (`j ≥ 1`) the
//! producer makes a query: the radiance leaving `y_j` toward `ωo`, where `ωo` is the direction
//! in which the light path continues, sampled by the BSDF at `y_j` given the direction the light
//! came from (adjoint sampling: the directions into which `y_j` scatters most of the light it
//! receives, so the queries sit where the reflected radiance is large). Its target is an
//! independent path-traced estimate of `L_o(y_j, ωo)` ([`outgoing_radiance`]: next-event
//! estimation and BSDF sampling combined by MIS, Russian roulette; the emission of `y_j` itself
//! left out), so every target is an unbiased estimate of the radiance the cache must learn.
//!
//! **Balancing.** Light paths leave most of the scene without queries (the shadowed parts, the
//! surfaces far from lights). The thesis (eq. 5.11) balances this by adding samples at uniformly
//! chosen surface points and at camera primary hits whose targets are *zero radiance*. This
//! implementation adds samples at the same places ([`LightProducer::surface_balance`],
//! [`LightProducer::camera_balance`]: fractions of the budget) but gives them *estimated*
//! targets, computed exactly like the light-vertex targets. A regression on unbiased targets
//! learns the true radiance; zero targets would pull the cache toward zero wherever balance
//! samples fall, a bias that only vanishes where light vertices outnumber them. Both balances
//! default to 0.
//!
//! The light paths come from [`nrc_render::light_path`].

use glam::Vec3;
use nrc_cache::TrainingBatch;
use nrc_render::light_path::{light_vertex_limit, trace_light_path};
use nrc_render::{LightStrategy, PathStats, PathTracer, PixelSampler};
use nrc_scene::{
    Ray, Scene, SurfaceInteraction,
    accel::Hit,
    bsdf::Bsdf,
    sampling::{Frame, sample_cosine_hemisphere, sample_uniform_triangle},
};

use crate::error::TrainError;
use crate::producer::{
    Produced, Producer, ProducerContext, ProducerStats, Rounds, fill_rounds, push_records,
};

/// The light-training producer.
#[derive(Clone, Debug)]
pub struct LightProducer {
    /// Fraction of the budget spent on queries at uniformly area-sampled surface points (a
    /// triangle chosen in proportion to its area, a uniform point on it, `ωo` cosine-distributed
    /// on its front side). In `[0, 1]`; default 0.
    pub surface_balance: f32,
    /// Fraction of the budget spent on queries at camera primary hits (the context's start
    /// rays, `ωo` toward the camera). In `[0, 1]`; default 0.
    pub camera_balance: f32,
}

impl Default for LightProducer {
    fn default() -> Self {
        Self {
            surface_balance: 0.0,
            camera_balance: 0.0,
        }
    }
}

impl LightProducer {
    /// Checks the settings: each balance finite in `[0, 1]`, their sum at most 1.
    pub fn validate(&self) -> Result<(), TrainError> {
        for (name, v) in [
            ("surface_balance", self.surface_balance),
            ("camera_balance", self.camera_balance),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(TrainError::bounds(
                    format!("light training: {name}"),
                    "lie in [0, 1]",
                    v,
                ));
            }
        }
        if self.surface_balance + self.camera_balance > 1.0 {
            return Err(TrainError::bounds(
                "light training: surface_balance + camera_balance",
                "be at most 1",
                self.surface_balance + self.camera_balance,
            ));
        }
        Ok(())
    }

    /// The budget split `(light, surface, camera)`; out-of-range balances are clamped to
    /// `[0, 1]` (NaN counts as 0) and scaled down to sum at most 1 (see [`Self::validate`]).
    pub fn split(&self, budget: usize) -> (usize, usize, usize) {
        let clean = |v: f32| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        let (mut s, mut c) = (clean(self.surface_balance), clean(self.camera_balance));
        if s + c > 1.0 {
            let t = s + c;
            s /= t;
            c /= t;
        }
        let surface = ((budget as f32 * s).round() as usize).min(budget);
        let camera = ((budget as f32 * c).round() as usize).min(budget - surface);
        (budget - surface - camera, surface, camera)
    }
}

impl Producer for LightProducer {
    fn name(&self) -> &str {
        "lt"
    }

    fn check(&self, scene: &nrc_scene::Scene) -> Result<(), TrainError> {
        crate::producer::check_light_paths(self.name(), scene)
    }

    fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced {
        let mut stats = ProducerStats::default();
        if budget == 0 {
            return Produced::default();
        }
        let (n_light, n_surface, n_camera) = self.split(budget);
        let scene = ctx.scene;
        let max_vertices = light_vertex_limit(&ctx.tracer, 1);

        // Queries at light-path vertices: light path i uses stream (i, 0); the target of its
        // vertex j uses stream (i, 1 + j).
        let light = fill_rounds(n_light, |i| {
            let mut sampler = PixelSampler::new(seed, i as u64, 0);
            let mut ps = PathStats::default();
            let path = trace_light_path(scene, &ctx.tracer, max_vertices, &mut sampler, &mut ps);
            let mut out = Vec::new();
            for (j, v) in path.vertices.iter().enumerate() {
                let Some(wo) = v.next else { continue };
                if v.bsdf.is_delta() {
                    continue;
                }
                let mut s = PixelSampler::new(seed, i as u64, 1 + j as u64);
                let target = outgoing_radiance(ctx, &v.si, wo, &mut s, &mut ps);
                out.push((ctx.queries.query_toward(&v.si, &v.bsdf, wo), target));
            }
            (out, ps.rays())
        });
        stats.paths += light.tried as u64;
        stats.rays += light.rays;

        // Balance at uniformly area-sampled surface points (streams offset by 2⁶² so they
        // never coincide with the light paths').
        let surface = if n_surface > 0 {
            let areas = SurfaceSampler::new(scene);
            fill_rounds(n_surface, |i| {
                let mut s = PixelSampler::new(seed, (1u64 << 62) + i as u64, 0);
                let mut ps = PathStats::default();
                let mut out = Vec::new();
                if let Some((si, wo)) = areas.sample(scene, &mut s) {
                    let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
                    if !bsdf.is_delta() {
                        let target = outgoing_radiance(ctx, &si, wo, &mut s, &mut ps);
                        out.push((ctx.queries.query_toward(&si, &bsdf, wo), target));
                    }
                }
                (out, ps.rays())
            })
        } else {
            Rounds::default()
        };
        stats.paths += surface.tried as u64;
        stats.rays += surface.rays;

        // Balance at camera primary hits (streams offset by 2⁶³).
        let camera = if n_camera > 0 && !ctx.starts.is_empty() {
            fill_rounds(n_camera, |i| {
                let mut s = PixelSampler::new(seed, (1u64 << 63) + i as u64, 0);
                let mut ps = PathStats::default();
                let mut out = Vec::new();
                ps.closest_rays += 1;
                let ray = ctx.starts[i % ctx.starts.len()].ray;
                if let Some(hit) = scene.intersect(&ray) {
                    let si = scene.interaction(&ray, &hit);
                    let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
                    if !bsdf.is_delta() {
                        let target = outgoing_radiance(ctx, &si, si.wo, &mut s, &mut ps);
                        out.push((ctx.queries.query(&si, &bsdf), target));
                    }
                }
                (out, ps.rays())
            })
        } else {
            Rounds::default()
        };
        stats.paths += camera.tried as u64;
        stats.rays += camera.rays;

        let mut batch = TrainingBatch::default();
        for (records, n) in [
            (light.items, n_light),
            (surface.items, n_surface),
            (camera.items, n_camera),
        ] {
            push_records(&mut batch, &mut stats, records.into_iter().take(n));
        }
        Produced { batch, stats }
    }
}

/// A path-traced estimate of the radiance leaving the surface point `si` toward `wo` (unit,
/// world), the point's own emission excluded: the reference path tracer's estimate from a
/// vertex ([`nrc_render::PathTracer::reflected`], NEE and BSDF sampling combined by MIS,
/// Russian roulette), the point counting as a camera primary hit for the maximum depth.
pub fn outgoing_radiance(
    ctx: &ProducerContext,
    si: &SurfaceInteraction,
    wo: Vec3,
    sampler: &mut PixelSampler,
    stats: &mut PathStats,
) -> Vec3 {
    let tracer = PathTracer {
        strategy: LightStrategy::Mis,
        ..ctx.tracer
    };
    tracer.reflected(ctx.scene, si, wo, 1, sampler, stats)
}

/// Uniform points on the scene's surfaces: a triangle chosen in proportion to its area, a
/// uniform point on it.
#[derive(Clone, Debug)]
pub(crate) struct SurfaceSampler {
    /// Cumulative areas, normalised so the last is 1.
    cdf: Vec<f32>,
}

impl SurfaceSampler {
    pub fn new(scene: &Scene) -> Self {
        let mut acc = 0.0f64;
        let mut cdf: Vec<f64> = Vec::with_capacity(scene.triangle_count());
        for t in 0..scene.triangle_count() as u32 {
            acc += scene.triangle_area(t) as f64;
            cdf.push(acc);
        }
        let mut cdf: Vec<f32> = cdf.iter().map(|c| (c / acc) as f32).collect();
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        Self { cdf }
    }

    /// A uniform surface point with a direction cosine-distributed about the front side
    /// (the side the geometric normal points to: the visible side by glTF's winding rule) of
    /// its shading normal. Uses four numbers of `sampler`.
    pub fn sample(
        &self,
        scene: &Scene,
        sampler: &mut PixelSampler,
    ) -> Option<(SurfaceInteraction, Vec3)> {
        let u = sampler.next_1d();
        let u_tri = sampler.next_2d();
        let u_dir = sampler.next_2d();
        if self.cdf.is_empty() {
            return None;
        }
        let tri = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1) as u32;
        let (b1, b2) = sample_uniform_triangle(u_tri);
        let [a, b, c] = scene.triangle_vertices(tri);
        let p = a * (1.0 - b1 - b2) + b * b1 + c * b2;
        let ng = scene.triangle_normal(tri);
        // A ray arriving along −ng at the point: the interaction fills in the shading data.
        let ray = Ray::new(p + ng, -ng);
        let si = scene.interaction(
            &ray,
            &Hit {
                t: 1.0,
                tri,
                b1,
                b2,
            },
        );
        let wo = Frame::from_normal(si.ns).to_world(sample_cosine_hemisphere(u_dir));
        (wo.dot(si.ng) > 0.0).then_some((SurfaceInteraction { wo, ..si }, wo))
    }
}
