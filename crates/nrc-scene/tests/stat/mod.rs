//! Statistics shared by the sampling and BSDF tests: Pearson's χ² goodness-of-fit test with
//! pooling of sparse cells, its p-value through the regularized upper incomplete gamma
//! function, the Šidák correction, and a (cos θ, φ) histogram of the sphere whose expected
//! counts come from 2-D adaptive Simpson integration of a density (in the manner of the χ²
//! tests of Mitsuba 3 and pbrt).
#![allow(dead_code)]

use glam::Vec3;
use std::f64::consts::PI;

/// `ln Γ(x)` for `x > 0` by the Lanczos approximation (g = 7, 9 terms; ~1e-15 relative).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    let t = x + G + 0.5;
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularized upper incomplete gamma function `Q(a, x) = Γ(a, x) / Γ(a)`: the series of
/// `P = 1 − Q` for `x < a + 1`, else Lentz's continued fraction for `Q`.
pub fn gamma_q(a: f64, x: f64) -> f64 {
    assert!(a > 0.0 && x >= 0.0, "gamma_q({a}, {x})");
    if x == 0.0 {
        return 1.0;
    }
    let prefactor = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del) = (a, 1.0 / a);
        let mut sum = del;
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * prefactor).max(0.0)
    } else {
        const TINY: f64 = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / TINY;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < TINY {
                d = TINY;
            }
            c = b + an / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (prefactor * h).clamp(0.0, 1.0)
    }
}

/// Upper-tail probability of the χ² distribution with `dof` degrees of freedom.
pub fn chi2_p_value(statistic: f64, dof: usize) -> f64 {
    gamma_q(0.5 * dof as f64, 0.5 * statistic)
}

/// Per-test significance level giving family-wise level `alpha` over `n` independent tests.
pub fn sidak(alpha: f64, n: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / n as f64)
}

#[derive(Clone, Copy, Debug)]
pub struct Chi2 {
    pub statistic: f64,
    pub dof: usize,
    pub p_value: f64,
}

/// Pearson's χ² of observed against expected counts. Cells are sorted by expected count and
/// those below 5 pooled together (the pooled cell joins the test if it reaches 5, else is
/// merged into the smallest regular cell). A cell with (numerically) zero expected count
/// but observed samples is an immediate failure: the sampler produced impossible values.
pub fn chi2_test(observed: &[f64], expected: &[f64]) -> Result<Chi2, String> {
    assert_eq!(observed.len(), expected.len());
    let total: f64 = expected.iter().sum();
    for (i, (&o, &e)) in observed.iter().zip(expected).enumerate() {
        if e <= 1e-9 * total.max(1.0) && o > 0.0 {
            return Err(format!(
                "cell {i}: {o} samples where the density integrates to {e:.3e}"
            ));
        }
    }
    let mut cells: Vec<(f64, f64)> = observed
        .iter()
        .copied()
        .zip(expected.iter().copied())
        .collect();
    cells.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    let mut kept: Vec<(f64, f64)> = Vec::new();
    for (o, e) in cells {
        if e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            kept.push((o, e));
        }
    }
    if pool_e >= 5.0 {
        kept.push((pool_o, pool_e));
    } else if pool_e > 0.0 || pool_o > 0.0 {
        match kept.first_mut() {
            Some(first) => {
                first.0 += pool_o;
                first.1 += pool_e;
            }
            None => kept.push((pool_o, pool_e)),
        }
    }
    if kept.len() < 2 {
        return Ok(Chi2 {
            statistic: 0.0,
            dof: 0,
            p_value: 1.0,
        });
    }
    let statistic: f64 = kept.iter().map(|&(o, e)| (o - e) * (o - e) / e).sum();
    let dof = kept.len() - 1;
    Ok(Chi2 {
        statistic,
        dof,
        p_value: chi2_p_value(statistic, dof),
    })
}

/// Histogram of directions over the sphere in equal-area cells of `(cos θ, φ)`.
#[derive(Clone, Copy, Debug)]
pub struct SphereBins {
    pub cos_bins: usize,
    pub phi_bins: usize,
}

/// Unit direction of `(cos θ, φ)`.
pub fn direction(cos: f64, phi: f64) -> Vec3 {
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    Vec3::new(
        (sin * phi.cos()) as f32,
        (sin * phi.sin()) as f32,
        cos as f32,
    )
}

impl SphereBins {
    pub fn len(&self) -> usize {
        self.cos_bins * self.phi_bins
    }

    pub fn index(&self, w: Vec3) -> usize {
        let cos = f64::from(w.z).clamp(-1.0, 1.0);
        let phi = f64::from(w.y).atan2(f64::from(w.x)).rem_euclid(2.0 * PI);
        let i = (((cos + 1.0) * 0.5 * self.cos_bins as f64) as usize).min(self.cos_bins - 1);
        let j = ((phi / (2.0 * PI) * self.phi_bins as f64) as usize).min(self.phi_bins - 1);
        i * self.phi_bins + j
    }

    /// Bounds `(cos0, cos1, phi0, phi1)` of a cell.
    pub fn cell(&self, k: usize) -> (f64, f64, f64, f64) {
        let (i, j) = (k / self.phi_bins, k % self.phi_bins);
        let dc = 2.0 / self.cos_bins as f64;
        let dp = 2.0 * PI / self.phi_bins as f64;
        (
            -1.0 + i as f64 * dc,
            -1.0 + (i + 1) as f64 * dc,
            j as f64 * dp,
            (j + 1) as f64 * dp,
        )
    }

    /// Integral of a solid-angle density over each cell (`dω = d cos θ dφ`), by adaptive
    /// Simpson with tolerance `tol + rel_tol · |cell integral|` per cell. Each cell is first
    /// split `4^min_depth(k)` times so that narrow lobes are not stepped over.
    pub fn integrate(
        &self,
        pdf: &dyn Fn(Vec3) -> f64,
        tol: f64,
        rel_tol: f64,
        min_depth: &dyn Fn(usize) -> u32,
    ) -> Vec<f64> {
        let f = |c: f64, p: f64| pdf(direction(c, p));
        (0..self.len())
            .map(|k| {
                let (c0, c1, p0, p1) = self.cell(k);
                let whole = simpson(&f, c0, c1, p0, p1);
                let tol = tol + rel_tol * whole.abs();
                adaptive_simpson(&f, c0, c1, p0, p1, whole, tol, 10, min_depth(k)).max(0.0)
            })
            .collect()
    }
}

/// 3 × 3-point Simpson rule on a rectangle.
fn simpson(f: &dyn Fn(f64, f64) -> f64, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    const W: [f64; 3] = [1.0, 4.0, 1.0];
    let (xm, ym) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let xs = [x0, xm, x1];
    let ys = [y0, ym, y1];
    let mut s = 0.0;
    for (wx, &x) in W.iter().zip(&xs) {
        for (wy, &y) in W.iter().zip(&ys) {
            s += wx * wy * f(x, y);
        }
    }
    s * (x1 - x0) * (y1 - y0) / 36.0
}

/// Adaptive Simpson on a rectangle: compare the rule on the rectangle with the sum over
/// its four quarters and recurse where they disagree by more than `15 tol`, adding the
/// Richardson correction when accepting. Children get `tol / 2` (not `/ 4`), so that
/// refinement along a discontinuity of the density (horizon, total internal reflection)
/// terminates; the total error stays a small multiple of `tol`.
fn adaptive_simpson(
    f: &dyn Fn(f64, f64) -> f64,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    whole: f64,
    tol: f64,
    depth_left: u32,
    min_depth: u32,
) -> f64 {
    let (xm, ym) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let quarters = [
        (x0, xm, y0, ym),
        (xm, x1, y0, ym),
        (x0, xm, ym, y1),
        (xm, x1, ym, y1),
    ];
    let parts = quarters.map(|(a, b, c, d)| simpson(f, a, b, c, d));
    let sum: f64 = parts.iter().sum();
    if min_depth == 0 && (depth_left == 0 || (sum - whole).abs() <= 15.0 * tol) {
        return sum + (sum - whole) / 15.0;
    }
    quarters
        .iter()
        .zip(parts)
        .map(|(&(a, b, c, d), part)| {
            adaptive_simpson(
                f,
                a,
                b,
                c,
                d,
                part,
                0.5 * tol,
                depth_left.saturating_sub(1),
                min_depth.saturating_sub(1),
            )
        })
        .sum()
}
