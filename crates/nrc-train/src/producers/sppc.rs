//! Sparse progressive photon collection (SPPC, the NRC thesis §5.5): training targets from
//! progressive photon mapping (Hachisuka and Jensen 2009, "Stochastic Progressive Photon
//! Mapping") at a sparse, persistent set of query points.
//!
//! **Query balls.** The producer keeps a ring buffer of at most [`SppcProducer::capacity`]
//! balls across frames. Each ball sits at a camera primary hit (the context's start rays, in
//! order) on a non-delta surface and asks for the radiance leaving it toward the camera. A new
//! ball's radius is [`SppcProducer::initial_radius`] times the diagonal of the scene's bounds.
//! Each frame the buffer is first filled up, then the oldest `replace_fraction` of it is
//! replaced by new balls.
//!
//! **Photons.** Each frame `budget × photons_per_record` light paths are traced
//! ([`nrc_render::light_path::trace_light_path`]: a light point chosen by power, a cosine-distributed
//! emission direction, BSDF sampling, Russian roulette). At every non-delta photon hit `y_j`,
//! `j ≥ 1` (the first hit too, so direct illumination is collected), the photon's flux weight
//! `β_j` is gathered into every ball containing `y_j`: `Φ_M += f_ball(ωo, ω_{y_j→y_{j−1}}) β_j`
//! with the ball's own BSDF and direction, `M += 1`. With [`SppcProducer::normal_reject`],
//! hits whose shading normal deviates from the ball's (`n_ball · n_hit < 0.9`) are not
//! gathered (they lie on another surface crossing the ball). The balls are found through a
//! bounding-volume hierarchy over their bounding boxes (`obvhs`' `Bvh2`, PLOC build, rebuilt
//! each frame; a point query per photon hit, then the exact sphere test).
//!
//! **Progressive radius reduction** (SPPM, per ball, at the frame's end, α =
//! [`SppcProducer::alpha`]): `N' = N + αM`, `R'² = R² (N + αM)/(N + M)`,
//! `τ' = (τ + Φ_M) R'²/R²`. The ball's radiance estimate is `L = τ / (π R² N_e)`, `N_e` the
//! number of light paths emitted while the ball existed. Since `τ/(πR²)` is the sum over frames
//! of `Φ_k / (π R_k²)` with `R_k` fixed before frame `k`'s photons are traced, the estimate is
//! unbiased wherever the reflected radiance is uniform over the ball's disc; elsewhere its bias
//! shrinks with the radius. Emission at the ball is excluded by construction (photons carry only
//! light that arrived there).
//!
//! **Training records**: every ball that has seen at least one frame of photons, its estimate
//! as the target, at most `budget` of them, oldest first (ring order). Selecting by age rather
//! than by photon count keeps the choice independent of the photons' outcome (preferring balls
//! with many photons would prefer estimates that came out high).

use std::f32::consts::PI;
use std::time::Duration;

use glam::{Vec3, Vec3A};
use nrc_cache::CacheQuery;
use nrc_render::{PathStats, PixelSampler};
use nrc_scene::{bsdf::Bsdf, sampling::Frame};
use obvhs::{BvhBuildParams, aabb::Aabb as BoxA, bvh2::Bvh2, bvh2::builder::build_bvh2};
use rayon::prelude::*;

use nrc_render::light_path::{LightVertex, light_vertex_limit, trace_light_path};

use crate::error::TrainError;
use crate::producer::{Produced, Producer, ProducerContext, ProducerStats, push_records};

/// One persistent query of progressive photon collection.
#[derive(Clone, Copy, Debug)]
pub struct QueryBall {
    /// Centre: the surface point the query asks about.
    pub position: Vec3,
    /// Shading normal at the centre.
    pub normal: Vec3,
    /// Unit direction (world) the radiance is asked for.
    pub wo: Vec3,
    pub query: CacheQuery,
    /// Squared gathering radius.
    pub radius2: f32,
    /// Accumulated flux `τ` (scaled with the radius reductions).
    pub tau: Vec3,
    /// SPPM's photon count `N` (grows by `αM` per frame).
    pub photons: f32,
    /// Light paths emitted while the ball existed.
    pub emitted: u64,
    bsdf: Bsdf,
    frame: Frame,
    wo_local: Vec3,
}

impl QueryBall {
    /// The radiance estimate `τ / (π R² N_e)`; `None` before the ball's first frame of photons.
    pub fn radiance(&self) -> Option<Vec3> {
        (self.emitted > 0).then(|| {
            let s = (PI as f64 * self.radius2 as f64 * self.emitted as f64).recip();
            (self.tau.as_dvec3() * s).as_vec3()
        })
    }
}

/// The SPPC producer and its persistent query balls.
#[derive(Clone, Debug)]
pub struct SppcProducer {
    /// Size of the ring buffer of query balls (default 16384).
    pub capacity: usize,
    /// Fraction of the balls replaced by new ones each frame, oldest first (default 0.25).
    pub replace_fraction: f32,
    /// Initial radius of a ball as a fraction of the scene bounds' diagonal (default 0.01).
    pub initial_radius: f32,
    /// Light paths traced per training record of the budget (default 4).
    pub photons_per_record: f32,
    /// SPPM's α in (0, 1]: the fraction of new photons kept when shrinking (default 0.7).
    pub alpha: f32,
    /// Gather only photons whose hit normal is within `acos 0.9` of the ball's (default on).
    pub normal_reject: bool,
    balls: Vec<QueryBall>,
    /// Index of the oldest ball (the next to replace once the buffer is full).
    oldest: usize,
}

impl Default for SppcProducer {
    fn default() -> Self {
        Self {
            capacity: 16384,
            replace_fraction: 0.25,
            initial_radius: 0.01,
            photons_per_record: 4.0,
            alpha: 0.7,
            normal_reject: true,
            balls: Vec::new(),
            oldest: 0,
        }
    }
}

/// Normal-rejection threshold on `n_ball · n_hit`.
const NORMAL_COS: f32 = 0.9;

impl SppcProducer {
    /// Checks the settings, naming the first that is out of range.
    pub fn validate(&self) -> Result<(), TrainError> {
        if self.capacity == 0 {
            return Err(TrainError::bounds("sppc: capacity", "be at least 1", 0));
        }
        if !(0.0..=1.0).contains(&self.replace_fraction) {
            return Err(TrainError::bounds(
                "sppc: replace_fraction",
                "lie in [0, 1]",
                self.replace_fraction,
            ));
        }
        if !(self.initial_radius > 0.0 && self.initial_radius.is_finite()) {
            return Err(TrainError::bounds(
                "sppc: initial_radius",
                "be positive and finite",
                self.initial_radius,
            ));
        }
        if !(self.photons_per_record > 0.0 && self.photons_per_record.is_finite()) {
            return Err(TrainError::bounds(
                "sppc: photons_per_record",
                "be positive and finite",
                self.photons_per_record,
            ));
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(TrainError::bounds(
                "sppc: alpha",
                "lie in (0, 1]",
                self.alpha,
            ));
        }
        Ok(())
    }

    /// The query balls, oldest first.
    pub fn balls(&self) -> impl Iterator<Item = &QueryBall> {
        let (newer, older) = self.balls.split_at(self.oldest.min(self.balls.len()));
        older.iter().chain(newer)
    }

    /// Forgets every ball (a new scene, or a camera cut).
    pub fn reset(&mut self) {
        self.balls.clear();
        self.oldest = 0;
    }

    /// Makes up to `n` new balls at the start rays' hits and puts them in the ring. Returns the
    /// rays traced.
    fn replace(&mut self, ctx: &ProducerContext, n: usize, capacity: usize, radius2: f32) -> u64 {
        let scene = ctx.scene;
        let fresh: Vec<QueryBall> = ctx
            .starts
            .par_iter()
            .filter_map(|start| {
                let hit = scene.intersect(&start.ray)?;
                let si = scene.interaction(&start.ray, &hit);
                let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
                if bsdf.is_delta() {
                    return None;
                }
                let frame = Frame::from_normal(si.ns);
                Some(QueryBall {
                    position: si.p,
                    normal: si.ns,
                    wo: si.wo,
                    query: ctx.queries.query(&si, &bsdf),
                    radius2,
                    tau: Vec3::ZERO,
                    photons: 0.0,
                    emitted: 0,
                    bsdf,
                    frame,
                    wo_local: frame.to_local(si.wo),
                })
            })
            .collect();
        for ball in fresh.into_iter().take(n) {
            if self.balls.len() < capacity {
                self.balls.push(ball);
            } else {
                self.balls[self.oldest] = ball;
                self.oldest = (self.oldest + 1) % capacity;
            }
        }
        ctx.starts.len() as u64
    }

    /// The contributions `(ball, f β)` of one photon hit to the balls containing it.
    /// The balls `v` falls in, with its contributions; returns how many were NaN or infinite
    /// (left out).
    fn gather(
        &self,
        bvh: &Bvh2,
        v: &LightVertex,
        normal_reject: bool,
        out: &mut Vec<(u32, Vec3)>,
    ) -> u64 {
        let mut skipped = 0;
        let p = v.si.p;
        bvh.point_traverse(Vec3A::from(p), |bvh, node_index| {
            let node = &bvh.nodes[node_index as usize];
            for k in node.first_index..node.first_index + node.prim_count {
                let b = bvh.primitive_indices[k as usize];
                let ball = &self.balls[b as usize];
                if (ball.position - p).length_squared() > ball.radius2 {
                    continue;
                }
                if normal_reject && ball.normal.dot(v.si.ns) < NORMAL_COS {
                    continue;
                }
                let f = ball.bsdf.eval(ball.wo_local, ball.frame.to_local(v.si.wo));
                let c = f * v.beta;
                if !c.is_finite() {
                    skipped += 1;
                } else if c.max_element() > 0.0 {
                    out.push((b, c));
                }
            }
            true
        });
        skipped
    }
}

impl Producer for SppcProducer {
    fn name(&self) -> &str {
        "sppc"
    }

    fn check(&self, scene: &nrc_scene::Scene) -> Result<(), TrainError> {
        crate::producer::check_light_paths(self.name(), scene)
    }

    fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced {
        let mut stats = ProducerStats::default();
        if budget == 0 {
            return Produced::default();
        }
        // Out-of-range settings fall back to the defaults (see `validate`).
        let d = Self::default();
        let capacity = self.capacity.max(1);
        let fraction = if (0.0..=1.0).contains(&self.replace_fraction) {
            self.replace_fraction
        } else {
            d.replace_fraction
        };
        let initial = if self.initial_radius > 0.0 && self.initial_radius.is_finite() {
            self.initial_radius
        } else {
            d.initial_radius
        };
        let per_record = if self.photons_per_record > 0.0 && self.photons_per_record.is_finite() {
            self.photons_per_record
        } else {
            d.photons_per_record
        };
        let alpha = if self.alpha > 0.0 && self.alpha <= 1.0 {
            self.alpha
        } else {
            d.alpha
        };
        if self.balls.len() > capacity {
            self.reset();
        }

        // 1. New balls: fill the ring, then replace the oldest fraction.
        let bounds = ctx.scene.bounds();
        let diagonal = (bounds.max - bounds.min).length();
        let r0 = if diagonal.is_finite() && diagonal > 0.0 {
            initial * diagonal
        } else {
            initial
        };
        let n_new = ((capacity - self.balls.len()) + (capacity as f32 * fraction).round() as usize)
            .min(capacity);
        if n_new > 0 && !ctx.starts.is_empty() {
            stats.rays += self.replace(ctx, n_new, capacity, r0 * r0);
        }
        if self.balls.is_empty() {
            return Produced {
                batch: Default::default(),
                stats,
            };
        }

        // 2. The hierarchy over the balls' bounds.
        let boxes: Vec<BoxA> = self
            .balls
            .iter()
            .map(|b| {
                let r = Vec3A::splat(b.radius2.sqrt());
                let c = Vec3A::from(b.position);
                BoxA::new(c - r, c + r)
            })
            .collect();
        let mut build_time = Duration::ZERO;
        let bvh = build_bvh2(&boxes, BvhBuildParams::fastest_build(), &mut build_time);

        // 3. Photons: light path i uses stream (i, 0); its hits' contributions are summed into
        // the balls in path order, so the sums do not depend on the thread count.
        let n_photons = ((budget as f64 * per_record as f64).round() as usize).max(1);
        let max_vertices = light_vertex_limit(&ctx.tracer, 1);
        let normal_reject = self.normal_reject;
        let this = &*self;
        // Per photon: its (ball, contribution) pairs, its rays, its contributions skipped.
        type Gathered = (Vec<(u32, Vec3)>, u64, u64);
        let gathered: Vec<Gathered> = (0..n_photons)
            .into_par_iter()
            .map(|i| {
                let mut sampler = PixelSampler::new(seed, i as u64, 0);
                let mut ps = PathStats::default();
                let path =
                    trace_light_path(ctx.scene, &ctx.tracer, max_vertices, &mut sampler, &mut ps);
                let mut out = Vec::new();
                let mut skipped = 0;
                for v in path.vertices.iter().filter(|v| !v.bsdf.is_delta()) {
                    skipped += this.gather(&bvh, v, normal_reject, &mut out);
                }
                (out, ps.rays(), skipped)
            })
            .collect();
        stats.paths += n_photons as u64;
        let mut count = vec![0u32; self.balls.len()];
        let mut flux = vec![Vec3::ZERO; self.balls.len()];
        for (contributions, rays, skipped) in gathered {
            stats.rays += rays;
            stats.skipped += skipped;
            for (b, c) in contributions {
                count[b as usize] += 1;
                flux[b as usize] += c;
            }
        }

        // 4. Progressive radius reduction.
        for ((ball, &m), &phi) in self.balls.iter_mut().zip(&count).zip(&flux) {
            ball.emitted += n_photons as u64;
            if m > 0 {
                let m = m as f32;
                let ratio = (ball.photons + alpha * m) / (ball.photons + m);
                ball.photons += alpha * m;
                ball.radius2 *= ratio;
                ball.tau = (ball.tau + phi) * ratio;
            }
        }

        // 5. Records: the balls oldest first.
        let mut out = Produced::default();
        let records = self
            .balls()
            .filter_map(|b| b.radiance().map(|l| (b.query, l)))
            .take(budget);
        push_records(&mut out.batch, &mut stats, records);
        out.stats = stats;
        out
    }
}
