//! The ray-query acceleration structure: an eight-wide compressed BVH (CWBVH, Ylitie et al.
//! 2017) built by `obvhs` (PLOC + reinsertion), traversed on the CPU with SIMD node tests.
//!
//! Triangles are stored in BVH leaf order, so the leaf's primitive index is the triangle's
//! index directly (no indirection, neighbouring leaves are neighbours in memory). The
//! [`Accel::build`] caller receives that permutation and reorders its per-triangle data.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::{
    BvhBuildParams, cwbvh::CwBvh, cwbvh::builder::build_cwbvh_from_tris, ray::RayHit,
    triangle::Triangle,
};

use crate::geometry::Ray;

/// A closest hit: distance along the ray, triangle index (in scene order, which is BVH
/// order) and the barycentric coordinates of the triangle's second and third vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub tri: u32,
    pub b1: f32,
    pub b2: f32,
}

/// A triangle laid out for the Möller–Trumbore test (the layout of madmann91's `bvh`
/// library, also used by `obvhs::rt_triangle::RtTriangle`): `e1 = v0 − v1`, `e2 = v2 − v0`,
/// `n = e1 × e2`. 64 bytes, one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
pub struct IsectTriangle {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
    n: Vec3A,
}

impl IsectTriangle {
    /// Prepares the triangle `(v0, v1, v2)`.
    pub fn new(v0: Vec3, v1: Vec3, v2: Vec3) -> Self {
        let (v0, v1, v2) = (Vec3A::from(v0), Vec3A::from(v1), Vec3A::from(v2));
        let e1 = v0 - v1;
        let e2 = v2 - v0;
        Self {
            v0,
            e1,
            e2,
            n: e1.cross(e2),
        }
    }

    /// Möller–Trumbore intersection: `(t, b1, b2)` of a hit with `0 ≤ t ≤ t_max`, or `None`.
    /// Edges and vertices count as inside (a `-0.0` barycentric, from a ray exactly on an
    /// edge, counts as outside so that a shared edge is hit once).
    #[inline(always)]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, t_max: f32) -> Option<(f32, f32, f32)> {
        let c = self.v0 - o;
        let r = d.cross(c);
        let inv_det = 1.0 / self.n.dot(d);
        let u = r.dot(self.e2) * inv_det;
        let v = r.dot(self.e1) * inv_det;
        let w = 1.0 - u - v;
        // Sign bits of u, v, w at once: all three non-negative (and not NaN-signed).
        let inside = (u.to_bits() | v.to_bits() | w.to_bits()) & 0x8000_0000 == 0;
        if inside && inv_det != 0.0 {
            let t = self.n.dot(c) * inv_det;
            if t >= 0.0 && t <= t_max {
                return Some((t, u, v));
            }
        }
        None
    }
}

/// Scale of the ray direction handed to `obvhs` (a power of two, so that every `t` and
/// barycentric scales exactly). `obvhs`' CWBVH node test ignores boxes left before
/// `t = 1e-4` in units of the direction it is given; with unit directions that would lose
/// hits closer than 0.1 mm in metre-scale scenes (a ray leaving a wall next to the floor),
/// so the direction is shortened by 2⁻²⁴ and that limit becomes `6·10⁻¹²` units.
const DIRECTION_SCALE: f32 = 1.0 / 16_777_216.0;

/// Bound on the inverse direction components handed to `obvhs`. Exact for every unit
/// direction component above ~2·10⁻¹⁷ (smaller ones act as that: a drift of 10⁻¹⁴ over a
/// thousand units), and slab distances stay finite (no `0 × ∞`) while ray origins and
/// vertices stay within ~10¹⁴ units of each other (see [`crate::scene::MAX_COORDINATE`]).
const MAX_INVERSE: f32 = 1e24;

/// Relative slack of the traversal's box-culling distance (see `Accel::slack`): 2⁻¹⁸, a
/// few dozen ULPs, far above the slab test's rounding and far below any geometric scale.
const SLACK_ULPS: f32 = 1.0 / 262_144.0;

/// The BVH over all scene triangles, with the triangles in BVH order.
pub struct Accel {
    bvh: CwBvh,
    tris: Vec<IsectTriangle>,
    /// Bounding sphere of the triangles (for the traversal slack).
    center: Vec3,
    radius: f32,
}

impl std::fmt::Debug for Accel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Accel")
            .field("triangles", &self.tris.len())
            .field("nodes", &self.bvh.nodes.len())
            .finish()
    }
}

impl Accel {
    /// Builds the BVH over `tris` (each `[v0, v1, v2]`). Returns the structure and the
    /// permutation `order`: BVH triangle `i` is input triangle `order[i]`. `tris` must not be
    /// empty and must hold only finite coordinates.
    pub fn build(tris: &[[Vec3; 3]]) -> (Self, Vec<u32>) {
        let input: Vec<Triangle> = tris
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        // The "slow" preset (wider PLOC search, more reinsertion) without spatial splits:
        // every triangle is in exactly one leaf, so `primitive_indices` is a permutation and
        // triangles can be stored in leaf order. Measured against the medium preset (CPU
        // time, one thread, 512² camera rays then one diffuse bounce): caustics 6.4 → 8.0
        // primary and 5.9 → 6.3 incoherent Mrays/s, cornell-box 6.7 → 7.4 incoherent, for
        // 33 → 50 ms of build on caustics' 16k triangles. The "very slow" preset gained
        // nothing more.
        let params = BvhBuildParams {
            pre_split: false,
            ..BvhBuildParams::slow_build()
        };
        let bvh = build_cwbvh_from_tris(&input, params, &mut Duration::default());
        let order = bvh.primitive_indices.clone();
        let bvh_tris = order
            .iter()
            .map(|&i| {
                let t = &tris[i as usize];
                IsectTriangle::new(t[0], t[1], t[2])
            })
            .collect();
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for t in tris {
            for &v in t {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        let accel = Self {
            bvh,
            tris: bvh_tris,
            center: 0.5 * (lo + hi),
            radius: 0.5 * (hi - lo).length(),
        };
        (accel, order)
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// True when there is no triangle.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// The prepared triangle `i` (BVH order).
    pub fn triangle(&self, i: usize) -> &IsectTriangle {
        &self.tris[i]
    }

    /// The `obvhs` ray for `ray`, with the direction scaled by [`DIRECTION_SCALE`] (see
    /// there) and the inverse direction computed exactly (no epsilon clamping). Its `tmax`
    /// is the scaled `t_max`.
    #[inline(always)]
    fn to_obvhs(ray: &Ray) -> obvhs::ray::Ray {
        // `+ 0.0` turns −0.0 into +0.0: obvhs picks near/far slab planes by `d < 0` and
        // would otherwise pair them with a negative inverse (a ray straight down the −y axis
        // with d.x = −0.0 then misses every box).
        let d = Vec3A::from(ray.d + Vec3::ZERO) * DIRECTION_SCALE;
        let inv = |x: f32| {
            if x < 0.0 {
                (1.0 / x).max(-MAX_INVERSE)
            } else {
                (1.0 / x).min(MAX_INVERSE)
            }
        };
        obvhs::ray::Ray {
            origin: ray.o.into(),
            direction: d,
            inv_direction: Vec3A::new(inv(d.x), inv(d.y), inv(d.z)),
            tmin: 0.0,
            tmax: ray.t_max / DIRECTION_SCALE,
        }
    }

    /// Slack added to a distance before it bounds the traversal's box tests, so that
    /// rounding in the slab test cannot cull a box holding a triangle hit at (almost) that
    /// distance. The slab distances are differences of terms as large as the distance from
    /// the origin to the far side of the scene, so the slack is a few ULPs of that plus a
    /// few ULPs of `t` itself. Returns a function of the (scaled) distance.
    #[inline(always)]
    fn slack(&self, r: &obvhs::ray::Ray) -> impl Fn(f32) -> f32 + use<> {
        // Cheap upper bounds: the L1 norm bounds the distance to the centre, the largest
        // direction component bounds |d| from below.
        let reach = (Vec3A::from(self.center) - r.origin).abs().element_sum() + self.radius;
        let abs = SLACK_ULPS * reach / r.direction.abs().max_element();
        move |t: f32| t + (SLACK_ULPS * t + abs)
    }

    /// The closest hit along the ray with `0 ≤ t < ray.t_max` among the hits `accept(triangle,
    /// b1, b2)` lets through (alpha cut-outs; `|_, _, _| true` for all).
    #[inline]
    pub fn intersect(&self, ray: &Ray, accept: impl Fn(u32, f32, f32) -> bool) -> Option<Hit> {
        let mut r = Self::to_obvhs(ray);
        let slack = self.slack(&r);
        let mut best = r.tmax;
        r.tmax = slack(best);
        let (mut tri, mut b1, mut b2) = (u32::MAX, 0.0, 0.0);
        let tris = &self.tris;
        let mut hit = RayHit::none();
        // The closest hit is tracked here, exactly; the traversal only sees a slightly
        // enlarged distance to cull boxes with (see `slack`).
        self.bvh.ray_traverse(r, &mut hit, |r, id| {
            match tris[id].intersect(r.origin, r.direction, best) {
                Some((t, u, v)) if t < best && accept(id as u32, u, v) => {
                    best = t;
                    tri = id as u32;
                    b1 = u;
                    b2 = v;
                    slack(t)
                }
                _ => f32::INFINITY,
            }
        });
        (tri != u32::MAX).then_some(Hit {
            t: best * DIRECTION_SCALE,
            tri,
            b1,
            b2,
        })
    }

    /// Whether any triangle lies along the ray with `0 ≤ t < ray.t_max` (any-hit traversal
    /// that stops at the first intersection `accept` lets through).
    #[inline]
    pub fn occluded(&self, ray: &Ray, accept: impl Fn(u32, f32, f32) -> bool) -> bool {
        let mut r = Self::to_obvhs(ray);
        let t_max = r.tmax;
        r.tmax = self.slack(&r)(t_max);
        let tris = &self.tris;
        !self.bvh.ray_traverse_miss(r, |r, id| {
            match tris[id].intersect(r.origin, r.direction, t_max) {
                Some((t, u, v)) if t < t_max && accept(id as u32, u, v) => t,
                _ => f32::INFINITY,
            }
        })
    }
}
