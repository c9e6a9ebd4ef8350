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

/// The BVH over all scene triangles, with the triangles in BVH order.
pub struct Accel {
    bvh: CwBvh,
    tris: Vec<IsectTriangle>,
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
        // Medium preset without spatial splits: every triangle is in exactly one leaf, so
        // `primitive_indices` is a permutation and triangles can be stored in leaf order.
        let params = BvhBuildParams::medium_build();
        debug_assert!(!params.pre_split);
        let bvh = build_cwbvh_from_tris(&input, params, &mut Duration::default());
        let order = bvh.primitive_indices.clone();
        let tris = order
            .iter()
            .map(|&i| {
                let t = &tris[i as usize];
                IsectTriangle::new(t[0], t[1], t[2])
            })
            .collect();
        (Self { bvh, tris }, order)
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

    #[inline(always)]
    fn to_obvhs(ray: &Ray) -> obvhs::ray::Ray {
        obvhs::ray::Ray::new(ray.o.into(), ray.d.into(), 0.0, ray.t_max)
    }

    /// The closest hit along the ray with `0 ≤ t < ray.t_max`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let mut hit = RayHit::none();
        let (mut b1, mut b2) = (0.0, 0.0);
        let tris = &self.tris;
        // The traversal shrinks `r.tmax` to the closest hit so far and records a hit when
        // the returned t is below it: the same test as here, so (b1, b2) belong to `hit`.
        let found = self.bvh.ray_traverse(Self::to_obvhs(ray), &mut hit, |r, id| {
            match tris[id].intersect(r.origin, r.direction, r.tmax) {
                Some((t, u, v)) if t < r.tmax => {
                    b1 = u;
                    b2 = v;
                    t
                }
                _ => f32::INFINITY,
            }
        });
        found.then_some(Hit {
            t: hit.t,
            tri: hit.primitive_id,
            b1,
            b2,
        })
    }

    /// Whether any triangle lies along the ray with `0 ≤ t < ray.t_max` (any-hit traversal
    /// that stops at the first intersection found).
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        let tris = &self.tris;
        !self.bvh.ray_traverse_miss(Self::to_obvhs(ray), |r, id| {
            match tris[id].intersect(r.origin, r.direction, r.tmax) {
                Some((t, _, _)) => t,
                None => f32::INFINITY,
            }
        })
    }
}
