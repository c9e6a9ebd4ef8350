//! Rays, bounding boxes and robust ray spawning.
//!
//! Secondary rays start at a point offset from the surface along the geometric normal by a
//! few units in the last place of the position's coordinates (Wächter and Binder 2019,
//! "A Fast and Robust Method for Avoiding Self-Intersection", Ray Tracing Gems ch. 6). The
//! offset scales with the magnitude of the position, so it works at any scene scale
//! without a user-tuned epsilon, and the ray's `t` range can start at 0.

use glam::Vec3;

/// A ray `o + t·d` for `t` in `[0, t_max]`. `d` need not be unit length (the `t` of a hit
/// is in units of `|d|`), but every ray this crate creates has a unit `d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub o: Vec3,
    pub d: Vec3,
    pub t_max: f32,
}

impl Ray {
    /// A ray of unbounded extent.
    #[inline]
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Self {
            o,
            d,
            t_max: f32::INFINITY,
        }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}

/// An axis-aligned bounding box. The empty box has `min = +∞`, `max = −∞`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    /// The empty box (the identity of [`Aabb::union`]).
    pub const EMPTY: Self = Self {
        min: Vec3::INFINITY,
        max: Vec3::NEG_INFINITY,
    };

    /// Grows the box to contain `p`.
    #[inline]
    pub fn extend(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// The smallest box containing both boxes.
    pub fn union(self, other: Self) -> Self {
        Self {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// True when the box contains no point.
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// Centre of the box.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// Edge lengths of the box.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// Whether `p` lies inside or on the box.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

/// Offsets a surface point `p` along the unit normal `n` (pointing to the side the new ray
/// leaves towards) so that a ray starting there cannot hit the surface it left
/// (Ray Tracing Gems ch. 6: an integer offset of the float bit patterns away from the
/// origin, and a small fixed offset for coordinates near zero, where ULPs are tiny).
#[inline]
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    #[inline(always)]
    fn axis(p: f32, n: f32) -> f32 {
        if p.abs() < ORIGIN {
            p + FLOAT_SCALE * n
        } else {
            let of_i = (INT_SCALE * n) as i32;
            let bits = p.to_bits() as i32;
            let moved = if p < 0.0 {
                bits.wrapping_sub(of_i)
            } else {
                bits.wrapping_add(of_i)
            };
            f32::from_bits(moved as u32)
        }
    }
    Vec3::new(axis(p.x, n.x), axis(p.y, n.y), axis(p.z, n.z))
}

/// A ray leaving the surface point `p` (geometric unit normal `ng`, either orientation) in
/// direction `dir` (unit), with its origin offset to the side of the surface `dir` points to.
#[inline]
pub fn spawn_ray(p: Vec3, ng: Vec3, dir: Vec3) -> Ray {
    let n = if dir.dot(ng) >= 0.0 { ng } else { -ng };
    Ray::new(offset_ray_origin(p, n), dir)
}

/// Relative shortening of shadow rays so that they stop just before their target point.
pub const SHADOW_EPSILON: f32 = 1e-4;

/// A shadow ray from the surface point `p` (geometric unit normal `ng`) towards `target`:
/// unit direction, and `t_max` stopping a relative [`SHADOW_EPSILON`] short of the target so
/// that the surface the target lies on is not reported as an occluder.
#[inline]
pub fn spawn_ray_to(p: Vec3, ng: Vec3, target: Vec3) -> Ray {
    let n = if (target - p).dot(ng) >= 0.0 { ng } else { -ng };
    let o = offset_ray_origin(p, n);
    let to = target - o;
    let dist = to.length();
    let d = if dist > 0.0 { to / dist } else { n };
    Ray {
        o,
        d,
        t_max: dist * (1.0 - SHADOW_EPSILON),
    }
}

/// A shadow ray between two surface points, each offset along its own geometric normal to
/// the side facing the other point; the most robust way to test mutual visibility.
#[inline]
pub fn spawn_ray_between(p0: Vec3, n0: Vec3, p1: Vec3, n1: Vec3) -> Ray {
    let w = p1 - p0;
    let n1 = if (-w).dot(n1) >= 0.0 { n1 } else { -n1 };
    spawn_ray_to(p0, n0, offset_ray_origin(p1, n1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_moves_to_the_requested_side_at_every_scale() {
        for scale in [1e-3f32, 0.5, 1.0, 37.0, 1e4] {
            for n in [Vec3::X, -Vec3::Y, Vec3::new(0.3, -0.5, 0.81).normalize()] {
                let p = Vec3::new(0.7, -1.3, 2.1) * scale;
                let q = offset_ray_origin(p, n);
                assert!((q - p).dot(n) > 0.0, "offset not along n at scale {scale}");
                assert!((q - p).length() < 1e-3 * scale.max(1.0));
            }
        }
    }

    #[test]
    fn shadow_ray_stops_before_target() {
        let r = spawn_ray_to(Vec3::ZERO, Vec3::Y, Vec3::new(0.0, 2.0, 0.0));
        assert!((r.d - Vec3::Y).length() < 1e-6);
        assert!(r.t_max < 2.0 && r.t_max > 1.99);
    }
}
