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
        Packed::new(self).importance(p, n)
    }
}

/// A node's bounds as the traversal reads them: centre, squared bounding radius and the
/// cone's sine precomputed (pbrt-v4's `CompactLightBounds`, not quantised).
#[derive(Clone, Copy, Debug)]
struct Packed {
    pc: Vec3,
    r2: f32,
    w: Vec3,
    phi: f32,
    cos_o: f32,
    sin_o: f32,
    cos_e: f32,
    two_sided: bool,
}

impl Packed {
    fn new(b: &LightBounds) -> Self {
        Self {
            pc: b.centroid(),
            r2: 0.25 * (b.hi - b.lo).length_squared(),
            w: b.w,
            phi: b.phi,
            cos_o: b.cos_o,
            sin_o: safe_sqrt(1.0 - b.cos_o * b.cos_o),
            cos_e: b.cos_e,
            two_sided: b.two_sided,
        }
    }

    /// [`LightBounds::importance`].
    #[inline]
    fn importance(&self, p: Vec3, n: Vec3) -> f32 {
        let d = p - self.pc;
        let dist2 = d.length_squared();
        let inside = dist2 <= self.r2;
        let wi = if dist2 > 0.0 {
            d * dist2.sqrt().recip()
        } else {
            Vec3::ZERO
        };
        let mut cos_w = self.w.dot(wi);
        if self.two_sided {
            cos_w = cos_w.abs();
        }
        let sin_w = safe_sqrt(1.0 - cos_w * cos_w);
        // The half-angle of the cone of directions from `p` that the box's bounding sphere
        // subtends (every direction when `p` is inside it).
        let (cos_b, sin_b) = if inside {
            (-1.0, 0.0)
        } else {
            let sin2 = self.r2 / dist2;
            (safe_sqrt(1.0 - sin2), sin2.sqrt())
        };
        // θ′ = max(0, θw − θo − θb): the smallest angle between an emitting normal and the
        // direction to `p`.
        let cos_x = cos_sub_clamped(sin_w, cos_w, self.sin_o, self.cos_o);
        let sin_x = sin_sub_clamped(sin_w, cos_w, self.sin_o, self.cos_o);
        let cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
        if cos_p <= self.cos_e {
            return 0.0;
        }
        let mut importance = self.phi * cos_p / dist2.max(self.r2);
        if n != Vec3::ZERO {
            let cos_i = wi.dot(n).abs();
            let sin_i = safe_sqrt(1.0 - cos_i * cos_i);
            importance *= cos_sub_clamped(sin_i, cos_i, sin_b, cos_b);
        }
        if importance.is_finite() {
            importance.max(0.0)
        } else {
            0.0
        }
    }
}

fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// `cos(max(0, a − b))` from the angles' sines and cosines.
fn cos_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        1.0
    } else {
        cos_a * cos_b + sin_a * sin_b
    }
}

/// `sin(max(0, a − b))` from the angles' sines and cosines.
fn sin_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        0.0
    } else {
        sin_a * cos_b - cos_a * sin_b
    }
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
/// eq. 2; pbrt-v4's `EvaluateCost`): power × the orientation cone's measure × the box's area,
/// stretched by how thin the parent is along the split axis.
fn cost(b: &LightBounds, parent: (Vec3, Vec3), dim: usize) -> f32 {
    let theta_o = b.cos_o.clamp(-1.0, 1.0).acos();
    let theta_e = b.cos_e.clamp(-1.0, 1.0).acos();
    let theta_w = (theta_o + theta_e).min(PI);
    let sin_o = safe_sqrt(1.0 - b.cos_o * b.cos_o);
    let m_omega = 2.0 * PI * (1.0 - b.cos_o)
        + PI / 2.0
            * (2.0 * theta_w * sin_o - (theta_o - 2.0 * theta_w).cos() - 2.0 * theta_o * sin_o
                + b.cos_o);
    let d = parent.1 - parent.0;
    let kr = if d[dim] > 0.0 {
        d.max_element() / d[dim]
    } else {
        1.0
    };
    b.phi * m_omega * kr * b.surface_area()
}

#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Packed,
    /// Interior: the second child's index (the first is the next node). Leaf: the light's.
    index: u32,
    leaf: bool,
}

/// The tree over a scene's bounded lights, and its lights at infinity.
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    nodes: Vec<Node>,
    /// Each node's parent (the root's is itself).
    parents: Vec<u32>,
    lights: Vec<LightSource>,
    /// Each bounded light's leaf, sorted by [`key`].
    leaf_of: Vec<(u64, u32)>,
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
    /// the lights at `infinity`.
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
            tree.build(&mut lights, 0);
            tree.lights = lights.iter().map(|l| l.0).collect();
            tree.parents = vec![0; tree.nodes.len()];
            for (i, node) in tree.nodes.iter().enumerate() {
                if node.leaf {
                    tree.leaf_of
                        .push((key(tree.lights[node.index as usize]), i as u32));
                } else {
                    tree.parents[i + 1] = i as u32;
                    tree.parents[node.index as usize] = i as u32;
                }
            }
            tree.leaf_of.sort_unstable();
        }
        tree
    }

    /// Builds the subtree over `lights` (whose first entry is light `offset`), returning its
    /// root's index; reorders `lights`.
    fn build(&mut self, lights: &mut [(LightSource, LightBounds)], offset: usize) -> u32 {
        let at = self.nodes.len() as u32;
        let bounds = lights[1..]
            .iter()
            .fold(lights[0].1, |acc, l| acc.union(&l.1));
        if lights.len() == 1 {
            self.nodes.push(Node {
                bounds: Packed::new(&bounds),
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
                let c =
                    cost(&a, (bounds.lo, bounds.hi), dim) + cost(&b, (bounds.lo, bounds.hi), dim);
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
        self.nodes.push(Node {
            bounds: Packed::new(&bounds),
            index: 0,
            leaf: false,
        });
        let (left, right) = lights.split_at_mut(mid);
        self.build(left, offset);
        let second = self.build(right, offset + mid);
        self.nodes[at as usize].index = second;
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

    /// Nodes of the tree.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// The longest path from the root to a leaf, in edges.
    pub fn depth(&self) -> usize {
        (0..self.nodes.len())
            .filter(|&i| self.nodes[i].leaf)
            .map(|mut i| {
                let mut d = 0;
                while i != 0 {
                    i = self.parents[i] as usize;
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
        let mut u = ((u - p_inf) / (1.0 - p_inf)).clamp(0.0, 1.0 - f32::EPSILON / 2.0);
        let mut pmf = 1.0 - p_inf;
        let mut i = 0usize;
        loop {
            let node = &self.nodes[i];
            if node.leaf {
                if i > 0 || node.bounds.importance(p, n) > 0.0 {
                    return Some((self.lights[node.index as usize], pmf));
                }
                return None;
            }
            let (a, b) = (i + 1, node.index as usize);
            let ia = self.nodes[a].bounds.importance(p, n);
            let ib = self.nodes[b].bounds.importance(p, n);
            if ia + ib <= 0.0 {
                return None;
            }
            let pa = ia / (ia + ib);
            if u < pa {
                u = (u / pa).min(1.0 - f32::EPSILON / 2.0);
                pmf *= pa;
                i = a;
            } else {
                u = ((u - pa) / (1.0 - pa)).clamp(0.0, 1.0 - f32::EPSILON / 2.0);
                pmf *= 1.0 - pa;
                i = b;
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
        let leaf = self.leaf_of[at].1;
        let mut pmf = 1.0 - self.p_infinite();
        let mut i = leaf as usize;
        if i == 0 {
            return if self.nodes[0].bounds.importance(p, n) > 0.0 {
                pmf
            } else {
                0.0
            };
        }
        while i != 0 {
            let parent = self.parents[i] as usize;
            let (a, b) = (parent + 1, self.nodes[parent].index as usize);
            let ia = self.nodes[a].bounds.importance(p, n);
            let ib = self.nodes[b].bounds.importance(p, n);
            let mine = if i == a { ia } else { ib };
            if mine <= 0.0 {
                return 0.0;
            }
            pmf *= mine / (ia + ib);
            i = parent;
        }
        pmf
    }
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

    /// Every light's probability at a point and the share of draws that find none sum to 1,
    /// and sampling hits each light as often as `pmf` says (exactly: the choices are a partition of
    /// `[0, 1)`, walked here on a fine grid of `u`).
    #[test]
    fn probabilities_sum_to_one_and_match_sampling() {
        let mut lights = Vec::new();
        for i in 0..40u32 {
            let f = i as f32;
            let c = Vec3::new((f * 0.37).sin() * 3.0, (f * 0.71).cos() * 2.0, f * 0.1);
            let n = Vec3::new((f * 1.3).cos(), (f * 0.4).sin(), 0.5).normalize();
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
