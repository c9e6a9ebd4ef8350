//! A light-sampling tree: a bounding-volume hierarchy over the emitters, each node bounding its
//! lights' power, positions and emission directions, traversed for each shading point by a
//! conservative estimate of how much each subtree can light it (Conty Estevez and Kulla 2018,
//! "Importance Sampling of Many Lights with Adaptive Tree Splitting"; pbrt-v4 §12.6.3, its
//! `BVHLightSampler` and `LightBounds`).
//!
//! **Sampling.** Lights at infinity (the environment, directional lights) have no position to
//! bound: one of them is chosen with probability `n∞ / (n∞ + 1)`, uniformly, and otherwise
//! the tree is descended from the root, choosing each child in proportion to its importance at
//! the point ([`LightBounds::importance`]); the probability of a light is the product of the
//! choices on its path. [`LightTree::pmf`] recomputes that product from the leaf up, so a
//! light found by a BSDF-sampled ray gets the same probability multiple importance sampling
//! needs.
//!
//! **Unbiasedness.** A light gets probability zero only where its bound says it cannot light
//! the point: the point is behind every emitting side of the node (`cos θ′ ≤ cos θe`) or sees
//! it exactly edge-on. Everything else keeps a non-zero probability, however small.

use std::f32::consts::PI;

use glam::{Quat, Vec3};
use wide::f32x8;

use crate::light::LightSource;

/// Bounds on a set of emitters (pbrt-v4's `LightBounds`): their box, total power `phi`, and
/// the cone of directions they emit in, as a cone of normals (axis `w`, half-angle `θo`)
/// widened by how far from its normal each emits (`θe`: π/2 for a Lambertian surface).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightBounds {
    pub lo: Vec3,
    pub hi: Vec3,
    pub phi: f32,
    /// Unit axis of the normals' cone.
    pub w: Vec3,
    /// `cos θo` (−1: every direction).
    pub cos_o: f32,
    /// `cos θe`.
    pub cos_e: f32,
    /// Emits on both sides of each normal.
    pub two_sided: bool,
}

impl LightBounds {
    /// A one-sided or two-sided Lambertian emitter of power `phi` with geometric normal `n`
    /// (the side it emits toward) over the box `lo..hi`.
    pub fn surface(lo: Vec3, hi: Vec3, n: Vec3, phi: f32, two_sided: bool) -> Self {
        Self {
            lo,
            hi,
            phi,
            w: n.normalize_or(Vec3::Z),
            cos_o: 1.0,
            cos_e: 0.0,
            two_sided,
        }
    }

    /// A point light of power `phi` at `p` (emitting everywhere).
    pub fn point(p: Vec3, phi: f32) -> Self {
        Self {
            lo: p,
            hi: p,
            phi,
            w: Vec3::Z,
            cos_o: -1.0,
            cos_e: 0.0,
            two_sided: false,
        }
    }

    /// A spot light of power `phi` at `p` shining along unit `axis`, full intensity within
    /// `cos_inner` of it and none beyond `cos_outer`.
    pub fn spot(p: Vec3, axis: Vec3, phi: f32, cos_inner: f32, cos_outer: f32) -> Self {
        let (inner, outer) = (cos_inner.clamp(-1.0, 1.0), cos_outer.clamp(-1.0, 1.0));
        Self {
            lo: p,
            hi: p,
            phi,
            w: axis.normalize_or(Vec3::Z),
            cos_o: inner,
            cos_e: (outer.acos() - inner.acos()).cos(),
            two_sided: false,
        }
    }

    fn centroid(&self) -> Vec3 {
        0.5 * (self.lo + self.hi)
    }

    fn surface_area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// The bounds of both sets: the boxes' union, the powers' sum, a cone holding both cones.
    pub fn union(&self, b: &Self) -> Self {
        let (w, cos_o) = cone_union((self.w, self.cos_o), (b.w, b.cos_o));
        Self {
            lo: self.lo.min(b.lo),
            hi: self.hi.max(b.hi),
            phi: self.phi + b.phi,
            w,
            cos_o,
            cos_e: self.cos_e.min(b.cos_e),
            two_sided: self.two_sided || b.two_sided,
        }
    }

    /// An upper bound, up to a common factor, of the light these emitters can send to a point
    /// `p` whose shading normal is `n` (unit, or zero: no surface, every direction counts):
    /// power × the largest emission cosine toward `p` over the cone and box, × the largest
    /// receiving cosine over the directions the box subtends, over the squared distance to the
    /// box's centre (at least its bounding radius, squared).
    pub fn importance(&self, p: Vec3, n: Vec3) -> f32 {
        Wide::new(&[(*self, 0)]).importance(p, n).to_array()[0]
    }
}

/// How many children a node of the tree holds: one AVX register's lanes, so that a node's
/// children are weighed in one pass ([`Wide::importance`]).
pub const WIDTH: usize = 8;

/// Marks a lane of [`Wide::child`] that holds a light (its index in [`LightTree::lights`])
/// rather than a node.
const LEAF: u32 = 1 << 31;

/// A node of the tree as the traversal reads it: up to [`WIDTH`] children's bounds, lane by
/// lane (centre, squared bounding radius, the cone's sine precomputed: pbrt-v4's
/// `CompactLightBounds`, not quantised), and what each child is.
#[derive(Clone, Copy, Debug)]
struct Wide {
    pc: [f32x8; 3],
    r2: f32x8,
    w: [f32x8; 3],
    phi: f32x8,
    cos_o: f32x8,
    sin_o: f32x8,
    cos_e: f32x8,
    /// All bits set in the lanes of two-sided emitters.
    two_sided: f32x8,
    /// Each lane's child: a node's index, or [`LEAF`] | a light's.
    child: [u32; WIDTH],
    len: u8,
}

impl Wide {
    /// A node over `children` (at most [`WIDTH`]; the lanes beyond have no power).
    fn new(children: &[(LightBounds, u32)]) -> Self {
        let mut lanes = [[0f32; WIDTH]; 12];
        let mut child = [0; WIDTH];
        for (i, (b, c)) in children.iter().enumerate() {
            let pc = b.centroid();
            let values = [
                pc.x,
                pc.y,
                pc.z,
                0.25 * (b.hi - b.lo).length_squared(),
                b.w.x,
                b.w.y,
                b.w.z,
                b.phi,
                b.cos_o,
                safe_sqrt(1.0 - b.cos_o * b.cos_o),
                b.cos_e,
                if b.two_sided {
                    f32::from_bits(u32::MAX)
                } else {
                    0.0
                },
            ];
            for (lane, v) in lanes.iter_mut().zip(values) {
                lane[i] = v;
            }
            child[i] = *c;
        }
        let v = |k: usize| f32x8::new(lanes[k]);
        Self {
            pc: [v(0), v(1), v(2)],
            r2: v(3),
            w: [v(4), v(5), v(6)],
            phi: v(7),
            cos_o: v(8),
            sin_o: v(9),
            cos_e: v(10),
            two_sided: v(11),
            child,
            len: children.len() as u8,
        }
    }

    /// [`LightBounds::importance`] of every child at once.
    #[inline]
    fn importance(&self, p: Vec3, n: Vec3) -> f32x8 {
        let zero = f32x8::ZERO;
        let one = f32x8::ONE;
        let safe_sqrt = |x: f32x8| x.max(zero).sqrt();
        // `cos(max(0, a − b))` and `sin(max(0, a − b))` from the angles' sines and cosines.
        let cos_sub = |sin_a: f32x8, cos_a: f32x8, sin_b: f32x8, cos_b: f32x8| {
            cos_a
                .simd_gt(cos_b)
                .select(one, cos_a * cos_b + sin_a * sin_b)
        };
        let sin_sub = |sin_a: f32x8, cos_a: f32x8, sin_b: f32x8, cos_b: f32x8| {
            cos_a
                .simd_gt(cos_b)
                .select(zero, sin_a * cos_b - cos_a * sin_b)
        };
        let d = [
            f32x8::splat(p.x) - self.pc[0],
            f32x8::splat(p.y) - self.pc[1],
            f32x8::splat(p.z) - self.pc[2],
        ];
        let dist2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let inside = dist2.simd_le(self.r2);
        let inv = dist2.simd_gt(zero).select(one / dist2.sqrt(), zero);
        let wi = [d[0] * inv, d[1] * inv, d[2] * inv];
        let cos_w = self.w[0] * wi[0] + self.w[1] * wi[1] + self.w[2] * wi[2];
        let cos_w = self.two_sided.select(cos_w.abs(), cos_w);
        let sin_w = safe_sqrt(one - cos_w * cos_w);
        // The half-angle of the cone of directions from `p` that the box's bounding sphere
        // subtends (every direction when `p` is inside it).
        let sin2 = self.r2 / dist2;
        let cos_b = inside.select(-one, safe_sqrt(one - sin2));
        let sin_b = inside.select(zero, sin2.sqrt());
        // θ′ = max(0, θw − θo − θb): the smallest angle between an emitting normal and the
        // direction to `p`.
        let cos_x = cos_sub(sin_w, cos_w, self.sin_o, self.cos_o);
        let sin_x = sin_sub(sin_w, cos_w, self.sin_o, self.cos_o);
        let cos_p = cos_sub(sin_x, cos_x, sin_b, cos_b);
        let mut importance = self.phi * cos_p / dist2.max(self.r2);
        if n != Vec3::ZERO {
            let cos_i = (wi[0] * n.x + wi[1] * n.y + wi[2] * n.z).abs();
            let sin_i = safe_sqrt(one - cos_i * cos_i);
            importance *= cos_sub(sin_i, cos_i, sin_b, cos_b);
        }
        let lit = cos_p.simd_gt(self.cos_e) & importance.is_finite();
        lit.select(importance.max(zero), zero)
    }

    /// Each child's importance at `p` (0 in the lanes past [`Wide::len`]) and their sum, each
    /// at most `f32::MAX / WIDTH` so that the sum stays finite.
    #[inline]
    fn weights(&self, p: Vec3, n: Vec3) -> ([f32; WIDTH], f32) {
        let cap = f32x8::splat(f32::MAX / WIDTH as f32);
        let mut w = self.importance(p, n).min(cap).to_array();
        w[self.len as usize..].fill(0.0);
        (w, w.iter().sum())
    }
}

fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// The smallest cone (axis, cos half-angle) holding both cones (pbrt-v4's
/// `DirectionCone::Union`).
fn cone_union(a: (Vec3, f32), b: (Vec3, f32)) -> (Vec3, f32) {
    let theta_a = a.1.clamp(-1.0, 1.0).acos();
    let theta_b = b.1.clamp(-1.0, 1.0).acos();
    let theta_d = a.0.dot(b.0).clamp(-1.0, 1.0).acos();
    if (theta_d + theta_b).min(PI) <= theta_a {
        return a;
    }
    if (theta_d + theta_a).min(PI) <= theta_b {
        return b;
    }
    let theta_o = 0.5 * (theta_a + theta_d + theta_b);
    if theta_o >= PI {
        return (a.0, -1.0);
    }
    let axis = a.0.cross(b.0);
    if axis.length_squared() < 1e-12 {
        return (a.0, -1.0);
    }
    let w = Quat::from_axis_angle(axis.normalize(), theta_o - theta_a) * a.0;
    (w.normalize(), theta_o.cos())
}

/// The Surface Area Orientation Heuristic's cost of a node (Conty Estevez and Kulla 2018,
/// eq. 2; pbrt-v4's `EvaluateCost`): its [`spread`], stretched by how thin the parent is
/// along the split axis.
fn cost(b: &LightBounds, parent: (Vec3, Vec3), dim: usize) -> f32 {
    let d = parent.1 - parent.0;
    let kr = if d[dim] > 0.0 {
        d.max_element() / d[dim]
    } else {
        1.0
    };
    spread(b) * kr
}

/// How much light a node spreads over how much of space and direction: power × the
/// orientation cone's measure × the box's area (the heuristic's measure of a node).
fn spread(b: &LightBounds) -> f32 {
    let theta_o = b.cos_o.clamp(-1.0, 1.0).acos();
    let theta_e = b.cos_e.clamp(-1.0, 1.0).acos();
    let theta_w = (theta_o + theta_e).min(PI);
    let sin_o = safe_sqrt(1.0 - b.cos_o * b.cos_o);
    let m_omega = 2.0 * PI * (1.0 - b.cos_o)
        + PI / 2.0
            * (2.0 * theta_w * sin_o - (theta_o - 2.0 * theta_w).cos() - 2.0 * theta_o * sin_o
                + b.cos_o);
    b.phi * m_omega * b.surface_area()
}

/// A node of the binary tree the build makes before it is collapsed into [`Wide`] nodes.
struct Binary {
    bounds: LightBounds,
    /// Interior: the second child's index (the first is the next node). Leaf: the light's.
    index: u32,
    leaf: bool,
}

/// The tree over a scene's bounded lights, and its lights at infinity.
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    /// The root first.
    nodes: Vec<Wide>,
    /// Each node's parent and the lane it is in there (the root's: `u32::MAX`).
    parents: Vec<(u32, u8)>,
    lights: Vec<LightSource>,
    /// Each bounded light's node and lane, sorted by [`key`].
    leaf_of: Vec<(u64, u32, u8)>,
    infinite: Vec<LightSource>,
}

/// A light's place in [`LightTree::leaf_of`]'s order.
fn key(light: LightSource) -> u64 {
    match light {
        LightSource::Triangle(t) => u64::from(t),
        LightSource::Punctual(i) => (1 << 32) | u64::from(i),
        LightSource::Environment => 2 << 32,
    }
}

/// Buckets per axis the build tries splits at.
const BUCKETS: usize = 12;

impl LightTree {
    /// A tree over `bounded` lights (entries with zero or non-finite power are left out) and
    /// the lights at `infinity`: a binary tree built by the surface area orientation heuristic,
    /// then collapsed into nodes of [`WIDTH`] children, each node taking in turn the children
    /// of its interior child of the largest [`spread`] until it is full (as wide BVHs are made
    /// from binary ones: the loosest bound is replaced by its children's tighter ones first).
    /// The probabilities are those of a descent over the wide nodes.
    pub fn new(bounded: Vec<(LightSource, LightBounds)>, infinity: Vec<LightSource>) -> Self {
        let mut lights: Vec<(LightSource, LightBounds)> = bounded
            .into_iter()
            .filter(|(_, b)| b.phi > 0.0 && b.phi.is_finite())
            .collect();
        let mut tree = Self {
            infinite: infinity,
            ..Self::default()
        };
        if !lights.is_empty() {
            debug_assert!(
                lights.len() < LEAF as usize,
                "a light's index would take the leaf bit"
            );
            let mut binary = Vec::with_capacity(2 * lights.len());
            build(&mut binary, &mut lights, 0);
            tree.lights = lights.iter().map(|l| l.0).collect();
            tree.collapse(&binary, 0, (u32::MAX, 0));
            tree.leaf_of.sort_unstable();
        }
        tree
    }

    /// Makes the wide node over binary node `b`'s subtree (`b` itself a lane when it is a
    /// leaf), child of `parent`; returns its index.
    fn collapse(&mut self, binary: &[Binary], b: usize, parent: (u32, u8)) -> u32 {
        let children = |i: usize| [i + 1, binary[i].index as usize];
        let mut lanes: Vec<usize> = if binary[b].leaf {
            vec![b]
        } else {
            children(b).to_vec()
        };
        while lanes.len() < WIDTH {
            let Some(k) = (0..lanes.len())
                .filter(|&k| !binary[lanes[k]].leaf)
                .max_by(|&x, &y| {
                    let m = |k: usize| spread(&binary[lanes[k]].bounds);
                    m(x).total_cmp(&m(y))
                })
            else {
                break;
            };
            let [first, second] = children(lanes[k]);
            lanes[k] = first;
            lanes.insert(k + 1, second);
        }
        let at = self.nodes.len() as u32;
        self.nodes.push(Wide::new(&[]));
        self.parents.push(parent);
        let mut kids = Vec::with_capacity(lanes.len());
        for (lane, &c) in lanes.iter().enumerate() {
            let node = &binary[c];
            let child = if node.leaf {
                let light = node.index;
                self.leaf_of
                    .push((key(self.lights[light as usize]), at, lane as u8));
                LEAF | light
            } else {
                self.collapse(binary, c, (at, lane as u8))
            };
            kids.push((node.bounds, child));
        }
        self.nodes[at as usize] = Wide::new(&kids);
        at
    }

    /// Lights in the tree (bounded) and at infinity.
    pub fn len(&self) -> usize {
        self.lights.len() + self.infinite.len()
    }

    /// True when the tree holds no light.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every light the tree can choose: its bounded lights, then those at infinity.
    pub fn lights(&self) -> impl Iterator<Item = LightSource> + '_ {
        self.lights.iter().chain(&self.infinite).copied()
    }

    /// Nodes of the tree (each of up to [`WIDTH`] children).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// The most nodes a descent passes through to reach a light: the choices it makes (0
    /// without bounded lights, 1 for a single one).
    pub fn depth(&self) -> usize {
        self.leaf_of
            .iter()
            .map(|&(_, mut node, _)| {
                let mut d = 1;
                while self.parents[node as usize].0 != u32::MAX {
                    node = self.parents[node as usize].0;
                    d += 1;
                }
                d
            })
            .max()
            .unwrap_or(0)
    }

    /// The probability of choosing a light at infinity.
    fn p_infinite(&self) -> f32 {
        let n = self.infinite.len() as f32;
        if self.nodes.is_empty() {
            if n > 0.0 { 1.0 } else { 0.0 }
        } else {
            n / (n + 1.0)
        }
    }

    /// Chooses a light for a point `p` with shading normal `n` (zero: none) with `u` uniform
    /// in `[0, 1)`: `(light, probability)`. `None` when no light can reach `p`.
    pub fn sample(&self, p: Vec3, n: Vec3, u: f32) -> Option<(LightSource, f32)> {
        let p_inf = self.p_infinite();
        if u < p_inf {
            let k = self.infinite.len();
            let i = ((u / p_inf * k as f32) as usize).min(k - 1);
            return Some((self.infinite[i], p_inf / k as f32));
        }
        if self.nodes.is_empty() {
            return None;
        }
        let below_one = 1.0 - f32::EPSILON / 2.0;
        let mut u = ((u - p_inf) / (1.0 - p_inf)).clamp(0.0, below_one);
        let mut pmf = 1.0 - p_inf;
        let mut node = &self.nodes[0];
        loop {
            let (w, total) = node.weights(p, n);
            if !(total > 0.0) {
                return None;
            }
            // The lane whose share of `[0, total)` holds `u · total` (the last lit lane where
            // rounding leaves it past the end).
            let target = u * total;
            let mut below = 0.0;
            let mut lane = None;
            for (k, &wk) in w.iter().enumerate().take(node.len as usize) {
                if wk <= 0.0 {
                    continue;
                }
                lane = Some((k, below));
                if target < below + wk {
                    break;
                }
                below += wk;
            }
            // `total > 0`, so some lane is lit.
            let (k, below) = lane?;
            pmf *= w[k] / total;
            u = ((target - below) / w[k]).clamp(0.0, below_one);
            match node.child[k] {
                c if c & LEAF != 0 => return Some((self.lights[(c & !LEAF) as usize], pmf)),
                c => node = &self.nodes[c as usize],
            }
        }
    }

    /// The probability that [`LightTree::sample`] chooses `light` for `p` and `n` (0 for
    /// lights it does not hold).
    pub fn pmf(&self, p: Vec3, n: Vec3, light: LightSource) -> f32 {
        if self.infinite.contains(&light) {
            return self.p_infinite() / self.infinite.len() as f32;
        }
        let Ok(at) = self.leaf_of.binary_search_by_key(&key(light), |e| e.0) else {
            return 0.0;
        };
        let (_, mut node, mut lane) = self.leaf_of[at];
        let mut pmf = 1.0 - self.p_infinite();
        while node != u32::MAX {
            let (w, total) = self.nodes[node as usize].weights(p, n);
            let mine = w[lane as usize];
            if mine <= 0.0 {
                return 0.0;
            }
            pmf *= mine / total;
            (node, lane) = self.parents[node as usize];
        }
        pmf
    }
}

/// Builds the binary subtree over `lights` (whose first entry is light `offset`) into
/// `nodes`, returning its root's index; reorders `lights`.
fn build(nodes: &mut Vec<Binary>, lights: &mut [(LightSource, LightBounds)], offset: usize) -> u32 {
    let at = nodes.len() as u32;
    let bounds = lights[1..]
        .iter()
        .fold(lights[0].1, |acc, l| acc.union(&l.1));
    if lights.len() == 1 {
        nodes.push(Binary {
            bounds,
            index: offset as u32,
            leaf: true,
        });
        return at;
    }
    let (clo, chi) = lights.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), l| (lo.min(l.1.centroid()), hi.max(l.1.centroid())),
    );
    let bucket_of = |c: Vec3, dim: usize| {
        let t = (c[dim] - clo[dim]) / (chi[dim] - clo[dim]);
        ((t * BUCKETS as f32) as usize).min(BUCKETS - 1)
    };
    let mut best: Option<(f32, usize, usize)> = None;
    for dim in 0..3 {
        if chi[dim] <= clo[dim] {
            continue;
        }
        let mut buckets: [Option<LightBounds>; BUCKETS] = [None; BUCKETS];
        for l in lights.iter() {
            let b = &mut buckets[bucket_of(l.1.centroid(), dim)];
            *b = Some(b.map_or(l.1, |b| b.union(&l.1)));
        }
        let merge = |range: &[Option<LightBounds>]| {
            range
                .iter()
                .flatten()
                .fold(None, |acc: Option<LightBounds>, b| {
                    Some(acc.map_or(*b, |a| a.union(b)))
                })
        };
        for split in 0..BUCKETS - 1 {
            let (Some(a), Some(b)) = (merge(&buckets[..=split]), merge(&buckets[split + 1..]))
            else {
                continue;
            };
            let c = cost(&a, (bounds.lo, bounds.hi), dim) + cost(&b, (bounds.lo, bounds.hi), dim);
            if c.is_finite() && best.is_none_or(|(bc, _, _)| c < bc) {
                best = Some((c, dim, split));
            }
        }
    }
    let mid = match best {
        Some((_, dim, split)) => {
            let mut mid = 0;
            for i in 0..lights.len() {
                if bucket_of(lights[i].1.centroid(), dim) <= split {
                    lights.swap(i, mid);
                    mid += 1;
                }
            }
            mid
        }
        None => 0,
    };
    let mid = if mid == 0 || mid == lights.len() {
        // No useful split (coincident centroids): halve along the widest axis.
        let dim = (chi - clo).max_position();
        lights.sort_by(|a, b| a.1.centroid()[dim].total_cmp(&b.1.centroid()[dim]));
        lights.len() / 2
    } else {
        mid
    };
    nodes.push(Binary {
        bounds,
        index: 0,
        leaf: false,
    });
    let (left, right) = lights.split_at_mut(mid);
    build(nodes, left, offset);
    let second = build(nodes, right, offset + mid);
    nodes[at as usize].index = second;
    at
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn tri_light(i: u32, c: Vec3, n: Vec3, phi: f32) -> (LightSource, LightBounds) {
        (
            LightSource::Triangle(i),
            LightBounds::surface(c - 0.05, c + 0.05, n, phi, false),
        )
    }

    /// The `i`-th of the tests' scattered emitters: `i` as a number, a centre and a unit
    /// normal.
    fn scattered(i: u32) -> (f32, Vec3, Vec3) {
        let f = i as f32;
        let c = Vec3::new((f * 0.37).sin() * 3.0, (f * 0.71).cos() * 2.0, f * 0.1);
        let n = Vec3::new((f * 1.3).cos(), (f * 0.4).sin(), 0.5).normalize();
        (f, c, n)
    }

    /// Every light's probability at a point and the share of draws that find none sum to 1,
    /// and sampling hits each light as often as `pmf` says (exactly: the choices are a partition of
    /// `[0, 1)`, walked here on a fine grid of `u`).
    #[test]
    fn probabilities_sum_to_one_and_match_sampling() {
        let mut lights = Vec::new();
        for i in 0..40u32 {
            let (f, c, n) = scattered(i);
            lights.push(tri_light(i, c, n, 1.0 + (f * 0.9).sin().abs() * 5.0));
        }
        lights.push((LightSource::Punctual(0), LightBounds::point(Vec3::ONE, 3.0)));
        let tree = LightTree::new(lights.clone(), vec![LightSource::Environment]);
        assert_eq!(tree.len(), 42);
        for (p, n) in [
            (Vec3::new(0.3, -0.2, 1.0), Vec3::Y),
            (Vec3::new(5.0, 5.0, 5.0), Vec3::ZERO),
            (Vec3::new(-1.0, 0.5, 2.0), Vec3::new(0.0, 0.6, -0.8)),
        ] {
            let total: f32 = lights.iter().map(|l| tree.pmf(p, n, l.0)).sum::<f32>()
                + tree.pmf(p, n, LightSource::Environment);
            let steps = 200_000;
            let mut counts: HashMap<LightSource, u32> = HashMap::new();
            let mut none = 0;
            for k in 0..steps {
                let u = (k as f32 + 0.5) / steps as f32;
                if let Some((l, pmf)) = tree.sample(p, n, u) {
                    *counts.entry(l).or_default() += 1;
                    assert!(
                        (pmf - tree.pmf(p, n, l)).abs() <= 1e-4 * pmf.max(1e-3),
                        "{l:?}"
                    );
                } else {
                    none += 1;
                }
            }
            // The probabilities and the draws that find no light (a node whose children both
            // face away) make up 1.
            let missed = none as f32 / steps as f32;
            assert!((total + missed - 1.0).abs() < 1e-3, "{total} + {missed}");
            for (l, c) in counts {
                let expect = tree.pmf(p, n, l) * steps as f32;
                assert!(
                    (c as f32 - expect).abs() <= 2.0 + 1e-3 * expect,
                    "{l:?}: {c} {expect}"
                );
            }
        }
    }

    /// The bound for one node, one light at a time: pbrt-v4's `LightBounds::Importance` as
    /// the binary tree computed it before the nodes were widened, the oracle of the test below.
    fn importance_one(b: &LightBounds, p: Vec3, n: Vec3) -> f32 {
        let sqrt0 = |x: f32| x.max(0.0).sqrt();
        let cos_sub = |sa: f32, ca: f32, sb: f32, cb: f32| {
            if ca > cb { 1.0 } else { ca * cb + sa * sb }
        };
        let sin_sub = |sa: f32, ca: f32, sb: f32, cb: f32| {
            if ca > cb { 0.0 } else { sa * cb - ca * sb }
        };
        let (pc, r2) = (b.centroid(), 0.25 * (b.hi - b.lo).length_squared());
        let d = p - pc;
        let dist2 = d.length_squared();
        let wi = if dist2 > 0.0 {
            d * dist2.sqrt().recip()
        } else {
            Vec3::ZERO
        };
        let mut cos_w = b.w.dot(wi);
        if b.two_sided {
            cos_w = cos_w.abs();
        }
        let sin_w = sqrt0(1.0 - cos_w * cos_w);
        let (cos_b, sin_b) = if dist2 <= r2 {
            (-1.0, 0.0)
        } else {
            (sqrt0(1.0 - r2 / dist2), (r2 / dist2).sqrt())
        };
        let sin_o = sqrt0(1.0 - b.cos_o * b.cos_o);
        let cos_x = cos_sub(sin_w, cos_w, sin_o, b.cos_o);
        let sin_x = sin_sub(sin_w, cos_w, sin_o, b.cos_o);
        let cos_p = cos_sub(sin_x, cos_x, sin_b, cos_b);
        if cos_p <= b.cos_e {
            return 0.0;
        }
        let mut importance = b.phi * cos_p / dist2.max(r2);
        if n != Vec3::ZERO {
            let cos_i = wi.dot(n).abs();
            importance *= cos_sub(sqrt0(1.0 - cos_i * cos_i), cos_i, sin_b, cos_b);
        }
        if importance.is_finite() {
            importance.max(0.0)
        } else {
            0.0
        }
    }

    /// A node of eight weighs each lane as the one-light bound does, bit for bit: one- and
    /// two-sided surfaces, point and spot lights, a point inside a box and one on a point
    /// light, with a shading normal and without, in full and partly filled nodes.
    #[test]
    fn a_wide_node_weighs_each_child_as_the_one_light_bound() {
        let mut bounds = Vec::new();
        for i in 0..24u32 {
            let (f, c, n) = scattered(i);
            let half = Vec3::splat(0.05 + 0.3 * (f * 0.5).sin().abs());
            bounds.push(match i % 4 {
                0 => LightBounds::surface(c - half, c + half, n, 1.0 + f, false),
                1 => LightBounds::surface(c - half, c + half, n, 2.0, true),
                2 => LightBounds::point(c, 3.0),
                _ => LightBounds::spot(c, n, 5.0, 0.9, 0.7),
            });
        }
        let points = [
            (Vec3::new(0.3, -0.2, 1.0), Vec3::Y),
            (Vec3::new(5.0, 5.0, 5.0), Vec3::ZERO),
            (Vec3::new(-1.0, 0.5, 2.0), Vec3::new(0.0, 0.6, -0.8)),
            (bounds[0].centroid(), Vec3::X),
            (bounds[2].centroid(), Vec3::Z),
        ];
        let mut lit = 0;
        for chunk in [&bounds[..8], &bounds[8..16], &bounds[16..19]] {
            let lanes: Vec<(LightBounds, u32)> = chunk.iter().map(|b| (*b, 0)).collect();
            let node = Wide::new(&lanes);
            for (p, n) in points {
                let (w, total) = node.weights(p, n);
                for (k, b) in chunk.iter().enumerate() {
                    let one = importance_one(b, p, n);
                    assert_eq!(
                        w[k].to_bits(),
                        one.to_bits(),
                        "lane {k} at {p}: {} against {one}",
                        w[k]
                    );
                    lit += usize::from(one > 0.0);
                }
                assert!(w[chunk.len()..].iter().all(|&x| x == 0.0));
                assert_eq!(total, w.iter().sum::<f32>());
            }
        }
        // Lit and unlit lanes both occur.
        assert!((20..95).contains(&lit), "{lit} of 95 lit");
    }

    /// A one-sided emitter facing away from the point gets probability zero; one facing it,
    /// non-zero; a two-sided one, non-zero either way.
    #[test]
    fn importance_is_zero_only_behind_one_sided_emitters() {
        let b = LightBounds::surface(Vec3::splat(-0.1), Vec3::splat(0.1), Vec3::Z, 1.0, false);
        assert_eq!(b.importance(Vec3::new(0.0, 0.0, -2.0), Vec3::ZERO), 0.0);
        assert!(b.importance(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO) > 0.0);
        let two = LightBounds {
            two_sided: true,
            ..b
        };
        assert!(two.importance(Vec3::new(0.0, 0.0, -2.0), Vec3::ZERO) > 0.0);
    }

    /// The union of two cones holds both.
    #[test]
    fn cone_union_holds_both_cones() {
        for (a, b) in [
            ((Vec3::Z, 0.9f32), (Vec3::X, 0.95f32)),
            ((Vec3::Z, 1.0), (Vec3::new(0.0, 0.6, 0.8), 1.0)),
            ((Vec3::Z, 0.0), (-Vec3::Z, 0.0)),
        ] {
            let (w, c) = cone_union(a, b);
            if c <= -1.0 {
                continue; // every direction
            }
            for (axis, cos) in [a, b] {
                // The cone's farthest direction from `w` is within the union's angle.
                let angle = w.dot(axis).clamp(-1.0, 1.0).acos() + cos.acos();
                assert!(
                    angle <= c.clamp(-1.0, 1.0).acos() + 1e-4,
                    "{a:?} {b:?} -> {w} {c}"
                );
            }
        }
    }
}
