//! The ray-query acceleration structure: an eight-wide compressed BVH (CWBVH, Ylitie et al.
//! 2017) built by `obvhs` (PLOC + reinsertion), traversed on the CPU with SIMD node tests.
//!
//! Triangles are stored in BVH leaf order, so the leaf's primitive index is the triangle's
//! index directly (no indirection, neighbouring leaves are neighbours in memory). The
//! [`Accel::build`] caller receives that permutation and reorders its per-triangle data.

use std::time::Duration;

use glam::{UVec2, Vec3, Vec3A};
use obvhs::{
    BvhBuildParams, cwbvh::CwBvh, cwbvh::builder::build_cwbvh_from_tris, triangle::Triangle,
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

/// `obvhs`' box-culling distance floor (its `cwbvh::node::EPSILON`, crate-private): boxes
/// left before this `t`, in units of the (scaled) direction, are not entered.
const NODE_T_MIN: f32 = 1e-4;

/// The hit mask of a compressed 8-wide node's children for the traversal (`obvhs`'
/// `CwBvhNode::intersect_ray`, same slab arithmetic and the same mask): with AVX2 the eight
/// quantized boxes are tested at once, each axis's eight bytes widened to floats by one
/// instruction, where `obvhs`' SSE version converts them one by one in two halves of four.
#[inline(always)]
fn node_hits(node: &obvhs::cwbvh::node::CwBvhNode, ray: &obvhs::ray::Ray, oct_inv4: u32) -> u32 {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        use std::arch::x86_64::*;
        let scale = node.compute_extent() * ray.inv_direction;
        let origin = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
        // SAFETY: AVX2 is enabled for this build (checked at start-up by `crate::cpu`); each
        // load reads exactly the 8 bytes of one `[u8; 8]` field.
        let inside = unsafe {
            let widen = |q: &[u8; 8]| {
                _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(
                    q.as_ptr().cast::<__m128i>(),
                )))
            };
            // Near and far planes per axis: the far side first where the ray runs backwards.
            let slab = |lo: &[u8; 8], hi: &[u8; 8], negative: bool, s: f32, o: f32| {
                let (near, far) = if negative { (hi, lo) } else { (lo, hi) };
                let (s, o) = (_mm256_set1_ps(s), _mm256_set1_ps(o));
                (
                    _mm256_add_ps(_mm256_mul_ps(widen(near), s), o),
                    _mm256_add_ps(_mm256_mul_ps(widen(far), s), o),
                )
            };
            let [(x0, x1), (y0, y1), (z0, z1)] = [
                (&node.child_min_x, &node.child_max_x, 0),
                (&node.child_min_y, &node.child_max_y, 1),
                (&node.child_min_z, &node.child_max_z, 2),
            ]
            .map(|(lo, hi, k)| slab(lo, hi, ray.direction[k] < 0.0, scale[k], origin[k]));
            let t0 = _mm256_max_ps(x0, _mm256_max_ps(y0, z0));
            let t1 = _mm256_min_ps(x1, _mm256_min_ps(y1, z1));
            let t0 = _mm256_max_ps(t0, _mm256_set1_ps(NODE_T_MIN));
            let t1 = _mm256_min_ps(t1, _mm256_set1_ps(ray.tmax));
            _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(t0, t1)) as u32
        };
        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let mut mask = inside;
        let mut hits = 0u32;
        while mask != 0 {
            let child = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let bits = ((child_bits8 >> (8 * child)) as u32) & 0xff;
            let index = ((bit_index8 >> (8 * child)) as u32) & 0xff;
            hits |= bits << index;
        }
        hits
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    {
        node.intersect_ray(ray, oct_inv4)
    }
}

/// What [`Accel::stats`] reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AccelStats {
    /// 8-wide compressed nodes.
    pub nodes: usize,
    /// Bytes of the nodes and the prepared triangles.
    pub bytes: usize,
    /// Wall-clock seconds of the build.
    pub build_seconds: f32,
}

/// The BVH over all scene triangles, with the triangles in BVH order.
pub struct Accel {
    bvh: CwBvh,
    tris: Vec<IsectTriangle>,
    /// Wall-clock seconds the build took.
    build_seconds: f32,
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
    /// empty and must hold only finite coordinates. It is taken by value and freed before the
    /// build, whose scratch memory is the peak of a scene's loading. `sphere`: a bounding
    /// sphere of the triangles (centre, radius; the scene's), for the traversal's slack.
    pub fn build(tris: Vec<[Vec3; 3]>, sphere: (Vec3, f32)) -> (Self, Vec<u32>) {
        let input: Vec<Triangle> = tris
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        drop(tris);
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
        let start = std::time::Instant::now();
        let mut bvh = build_cwbvh_from_tris(&input, params, &mut Duration::default());
        // Triangles are stored in leaf order, so the traversal's primitive index is the
        // triangle's: the BVH's own index list becomes the caller's permutation, and the
        // exact node boxes (kept by `obvhs` for refitting, which nothing here does) go.
        let order = std::mem::take(&mut bvh.primitive_indices);
        bvh.exact_node_aabbs = None;
        bvh.nodes.shrink_to_fit();
        let bvh_tris = order
            .iter()
            .map(|&i| {
                let t = &input[i as usize];
                IsectTriangle::new(t.v0.into(), t.v1.into(), t.v2.into())
            })
            .collect();
        let accel = Self {
            bvh,
            tris: bvh_tris,
            build_seconds: start.elapsed().as_secs_f32(),
            center: sphere.0,
            radius: sphere.1,
        };
        (accel, order)
    }

    /// What the structure holds and cost: its nodes, its bytes (nodes and prepared triangles)
    /// and the build's wall-clock seconds.
    pub fn stats(&self) -> AccelStats {
        AccelStats {
            nodes: self.bvh.nodes.len(),
            bytes: std::mem::size_of_val(self.bvh.nodes.as_slice())
                + std::mem::size_of_val(self.tris.as_slice()),
            build_seconds: self.build_seconds,
        }
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

    /// Walks the BVH along `r`, calling `triangle(index, r)` for each triangle in a leaf the
    /// ray enters (it may lower `r.tmax` to cull farther boxes) until it returns true. Through
    /// `obvhs`' `traverse!` macro rather than its `ray_traverse`, whose per-triangle callback
    /// stayed an out-of-line call (measured: 5 % of a Cornell-box render in the call alone).
    #[inline(always)]
    fn traverse(
        &self,
        r: &mut obvhs::ray::Ray,
        mut triangle: impl FnMut(usize, &mut obvhs::ray::Ray) -> bool,
    ) {
        let mut state = self.bvh.new_traversal(r.direction);
        let mut node;
        'walk: {
            obvhs::traverse!(self.bvh, node, state, node_hits(node, r, state.oct_inv4), {
                if triangle(state.primitive_id as usize, r) {
                    break 'walk;
                }
            });
        }
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
        // The closest hit is tracked here, exactly; the traversal only sees a slightly
        // enlarged distance to cull boxes with (see `slack`).
        self.traverse(&mut r, |id, r| {
            if let Some((t, u, v)) = self.tris[id].intersect(r.origin, r.direction, best)
                && t < best
                && accept(id as u32, u, v)
            {
                best = t;
                tri = id as u32;
                b1 = u;
                b2 = v;
                r.tmax = slack(t);
            }
            false
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
        let mut blocked = false;
        self.traverse(&mut r, |id, r| {
            blocked = matches!(
                self.tris[id].intersect(r.origin, r.direction, t_max),
                Some((t, u, v)) if t < t_max && accept(id as u32, u, v)
            );
            blocked
        });
        blocked
    }
}
