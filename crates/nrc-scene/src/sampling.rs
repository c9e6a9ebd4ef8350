//! Monte Carlo sampling routines: local shading frames, warps from the unit square to
//! triangles, disks, hemispheres and spheres with their densities, the power heuristic for
//! multiple importance sampling, and luminance.
//!
//! Every warp takes uniform numbers in `[0, 1)²` and every `*_pdf` is a density with respect
//! to the measure of the target domain (solid angle for directions).

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, FRAC_PI_2, FRAC_PI_4, PI};

/// An orthonormal basis `(s, t, n)` around a unit normal `n`; local coordinates have `z`
/// along `n` (the shading frame of the BSDFs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// Builds the frame of a unit normal with the branchless construction of Duff et al.
    /// 2017, "Building an Orthonormal Basis, Revisited" (glam's `any_orthonormal_pair`
    /// implements exactly that construction). `n` must be unit length.
    pub fn from_normal(n: Vec3) -> Self {
        let (s, t) = n.any_orthonormal_pair();
        Self { s, t, n }
    }

    /// World direction to local coordinates (`z` along the normal).
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local coordinates back to a world direction.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// Uniform point on a triangle as barycentrics `(b1, b2)` of its second and third vertices
/// (`b0 = 1 − b1 − b2`), by the low-distortion square-to-triangle mapping of Heitz 2019,
/// "A Low-Distortion Map Between Triangle and Square". Density: 1 / area.
#[inline]
pub fn sample_uniform_triangle(u: Vec2) -> (f32, f32) {
    let (b0, b1) = if u.x < u.y {
        let b0 = 0.5 * u.x;
        (b0, u.y - b0)
    } else {
        let b1 = 0.5 * u.y;
        (u.x - b1, b1)
    };
    (b1, (1.0 - b0 - b1).max(0.0))
}

/// Uniform point on the unit disk by the concentric mapping of Shirley and Chiu 1997.
#[inline]
pub fn sample_concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y))
    };
    let (sin, cos) = theta.sin_cos();
    r * Vec2::new(cos, sin)
}

/// Cosine-weighted direction on the upper (`z > 0`) hemisphere (Malley's method: a
/// concentric-disk point lifted to the hemisphere). Density [`cosine_hemisphere_pdf`].
#[inline]
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Solid-angle density of [`sample_cosine_hemisphere`]: `cos θ / π` (0 below the horizon).
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * FRAC_1_PI
}

/// Uniform direction on the unit sphere. Density [`uniform_sphere_pdf`].
#[inline]
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (sin, cos) = (2.0 * PI * u.y).sin_cos();
    Vec3::new(r * cos, r * sin, z)
}

/// Solid-angle density of [`sample_uniform_sphere`]: `1 / 4π`.
#[inline]
pub fn uniform_sphere_pdf() -> f32 {
    0.25 * FRAC_1_PI
}

/// Uniform direction on the upper (`z ≥ 0`) hemisphere. Density [`uniform_hemisphere_pdf`].
#[inline]
pub fn sample_uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (sin, cos) = (2.0 * PI * u.y).sin_cos();
    Vec3::new(r * cos, r * sin, z)
}

/// Solid-angle density of [`sample_uniform_hemisphere`]: `1 / 2π`.
#[inline]
pub fn uniform_hemisphere_pdf() -> f32 {
    0.5 * FRAC_1_PI
}

/// Veach's power heuristic (β = 2) weight of strategy `f` taking `nf` samples of density
/// `f_pdf`, combined with strategy `g` taking `ng` samples of density `g_pdf`.
/// An infinite `f_pdf` (a delta strategy) gets weight 1; two zero densities give 0.
#[inline]
pub fn power_heuristic(nf: f32, f_pdf: f32, ng: f32, g_pdf: f32) -> f32 {
    let f = nf * f_pdf;
    let g = ng * g_pdf;
    if f.is_infinite() {
        return if g.is_infinite() { 0.5 } else { 1.0 };
    }
    let (f2, g2) = (f * f, g * g);
    if f2 + g2 > 0.0 && (f2 + g2).is_finite() {
        f2 / (f2 + g2)
    } else if g.is_infinite() {
        0.0
    } else if f2 > 0.0 {
        // Overflow of the squares with both finite: compare the ratio instead.
        let r = g / f;
        1.0 / (1.0 + r * r)
    } else {
        0.0
    }
}

/// Luminance of a linear RGB colour with the Rec. 709 / sRGB primaries' Y weights.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_and_round_trips() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(1.0, -2.0, 0.5).normalize(),
            Vec3::new(0.0, 0.0, -0.0),
        ] {
            let n = if n.length_squared() == 0.0 {
                -Vec3::Z
            } else {
                n
            };
            let f = Frame::from_normal(n);
            assert!(f.s.dot(f.t).abs() < 1e-6 && f.s.dot(f.n).abs() < 1e-6);
            assert!((f.s.length() - 1.0).abs() < 1e-6 && (f.t.length() - 1.0).abs() < 1e-6);
            assert!((f.s.cross(f.t) - f.n).length() < 1e-5, "right-handed");
            let v = Vec3::new(0.3, -0.4, 0.866);
            assert!((f.to_local(f.to_world(v)) - v).length() < 1e-5);
            assert!((f.to_local(n) - Vec3::Z).length() < 1e-5);
        }
    }

    #[test]
    fn power_heuristic_edge_cases() {
        assert_eq!(power_heuristic(1.0, f32::INFINITY, 1.0, 3.0), 1.0);
        assert_eq!(power_heuristic(1.0, 0.0, 1.0, 0.0), 0.0);
        assert!((power_heuristic(1.0, 1.0, 1.0, 1.0) - 0.5).abs() < 1e-6);
        assert!((power_heuristic(1.0, 1e30, 1.0, 1e30) - 0.5).abs() < 1e-6);
        assert!((power_heuristic(1.0, 2.0, 1.0, 1.0) - 0.8).abs() < 1e-6);
    }
}
