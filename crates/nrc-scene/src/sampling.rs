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

/// A piecewise-constant density on `[0, 1)` with `n` equal cells, proportional to the
/// non-negative weights it was built from (uniform when they sum to zero or are not finite).
/// Sampling inverts the cumulative distribution exactly within a cell, so the sample's
/// density is `weight(cell) · n / Σ weights`.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    /// Density of each cell (integrates to 1 over `[0, 1)`).
    density: Vec<f32>,
    /// Cumulative probability at each cell's end (the last is 1).
    cdf: Vec<f32>,
    /// Sum of the weights (`0` when the distribution fell back to uniform).
    total: f64,
}

impl Distribution1D {
    /// The distribution of `weights` (at least one). Negative and non-finite weights count as 0.
    pub fn new(weights: &[f32]) -> Self {
        assert!(
            !weights.is_empty(),
            "a distribution needs at least one cell"
        );
        let clean = |w: f32| {
            if w.is_finite() && w > 0.0 {
                w as f64
            } else {
                0.0
            }
        };
        let mut total: f64 = weights.iter().map(|&w| clean(w)).sum();
        let n = weights.len();
        let uniform = !(total > 0.0 && total.is_finite());
        let weight = |w: f32| if uniform { 1.0 } else { clean(w) };
        let sum = if uniform { n as f64 } else { total };
        if uniform {
            total = 0.0;
        }
        let mut cdf = Vec::with_capacity(n);
        let mut acc = 0.0f64;
        let density = weights
            .iter()
            .map(|&w| {
                acc += weight(w);
                cdf.push((acc / sum) as f32);
                (weight(w) * n as f64 / sum) as f32
            })
            .collect();
        *cdf.last_mut().expect("non-empty") = 1.0;
        Self {
            density,
            cdf,
            total,
        }
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.density.len()
    }

    /// Always false (a distribution has at least one cell).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Sum of the weights it was built from (0 for the uniform fallback).
    pub fn total(&self) -> f64 {
        self.total
    }

    /// A point `x` in `[0, 1)` for `u` uniform in `[0, 1)`: `(x, density at x, cell)`.
    #[inline]
    pub fn sample(&self, u: f32) -> (f32, f32, usize) {
        let n = self.density.len();
        // First cell whose end lies above u, skipping zero-probability cells.
        let i = self.cdf.partition_point(|&c| c <= u).min(n - 1);
        let start = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let p = self.cdf[i] - start;
        let t = if p > 0.0 {
            ((u - start) / p).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let x = ((i as f32 + t) / n as f32).min(1.0 - f32::EPSILON / 2.0);
        (x, self.density[i], i)
    }

    /// Density at `x` in `[0, 1)` (clamped into the range).
    #[inline]
    pub fn pdf(&self, x: f32) -> f32 {
        self.density[self.cell(x)]
    }

    /// The cell holding `x`.
    #[inline]
    pub fn cell(&self, x: f32) -> usize {
        let n = self.density.len();
        ((x * n as f32) as isize).clamp(0, n as isize - 1) as usize
    }
}

/// A piecewise-constant density on `[0, 1)²` over a `width × height` grid of cells (row `y`,
/// column `x`), sampled as a marginal over rows and a conditional within the row (PBRT's
/// construction).
#[derive(Clone, Debug)]
pub struct Distribution2D {
    rows: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    /// The distribution of row-major `weights` (`width × height` of them, both at least 1).
    pub fn new(weights: &[f32], width: usize, height: usize) -> Self {
        assert!(width > 0 && height > 0 && weights.len() == width * height);
        let rows: Vec<Distribution1D> = weights
            .chunks_exact(width)
            .map(Distribution1D::new)
            .collect();
        let row_weights: Vec<f32> = rows.iter().map(|r| r.total() as f32).collect();
        Self {
            marginal: Distribution1D::new(&row_weights),
            rows,
        }
    }

    /// Sum of the weights.
    pub fn total(&self) -> f64 {
        self.marginal.total()
    }

    /// A point of `[0, 1)²` (`x` along a row, `y` across rows) and its density.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let (y, py, row) = self.marginal.sample(u.y);
        let (x, px, _) = self.rows[row].sample(u.x);
        (Vec2::new(x, y), px * py)
    }

    /// Density at `p` in `[0, 1)²`.
    #[inline]
    pub fn pdf(&self, p: Vec2) -> f32 {
        let row = self.marginal.cell(p.y);
        self.marginal.pdf(p.y) * self.rows[row].pdf(p.x)
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
