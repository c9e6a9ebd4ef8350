//! One-blob encoding (Müller et al. 2019): a scalar in [0,1] becomes `k` bins, each holding the
//! integral over the bin of a quartic kernel of radius 1/k centred on the input.
//!
//! The kernel is `K(u) = 15/16 (1 − u²)²` on `u ∈ [−1, 1]` (in units of the radius), with CDF
//! `C(u) = 15/16 (u − 2u³/3 + u⁵/5) + 1/2`, so bin `i` is `C(k·((i+1)/k − x)) − C(k·(i/k − x))`.
//! The **wrapped** variant (for an azimuth, periodic on [0,1)) adds the kernel's copies shifted
//! by ±1, as tiny-cuda-nn's `OneBlob` does; the plain variant uses the central copy only, so mass
//! falling outside [0,1] is lost.

/// Quartic kernel `K(u)`.
#[inline(always)]
pub fn kernel(u: f32) -> f32 {
    let t = (1.0 - u * u).max(0.0);
    (15.0 / 16.0) * t * t
}

/// CDF of the quartic kernel, `C(u)`, clamped to [0,1].
#[inline(always)]
pub fn cdf(u: f32) -> f32 {
    let u = u.clamp(-1.0, 1.0);
    let u2 = u * u;
    ((15.0 / 16.0) * u * (1.0 - (2.0 / 3.0) * u2 + 0.2 * u2 * u2) + 0.5).clamp(0.0, 1.0)
}

/// Sum of the CDF over the kernel copies (central, and ±1 when wrapping).
#[inline(always)]
fn cdf_sum(boundary: f32, x: f32, bins: f32, wrap: bool) -> f32 {
    let c = cdf((boundary - x) * bins);
    if wrap {
        c + cdf((boundary - x - 1.0) * bins) + cdf((boundary - x + 1.0) * bins)
    } else {
        c
    }
}

#[inline(always)]
fn kernel_sum(boundary: f32, x: f32, bins: f32, wrap: bool) -> f32 {
    let k = kernel((boundary - x) * bins);
    if wrap {
        k + kernel((boundary - x - 1.0) * bins) + kernel((boundary - x + 1.0) * bins)
    } else {
        k
    }
}

/// Encodes `x` into `out` (length = number of bins).
#[inline]
pub fn forward(x: f32, wrap: bool, out: &mut [f32]) {
    let n = out.len() as f32;
    let mut left = cdf_sum(0.0, x, n, wrap);
    for (i, o) in out.iter_mut().enumerate() {
        let right = cdf_sum((i + 1) as f32 / n, x, n, wrap);
        *o = right - left;
        left = right;
    }
}

/// [`forward`] of many inputs at once: `x[r]` is encoded into `out[r·stride + col..][..bins]`.
/// Each bin boundary's CDF is computed for all inputs in one loop (which the compiler
/// vectorises), with the same operations per input as [`forward`], so the same bits.
pub fn forward_many(
    x: &[f32],
    wrap: bool,
    bins: usize,
    out: &mut [f32],
    stride: usize,
    col: usize,
) {
    let n = bins as f32;
    let mut left: Vec<f32> = x.iter().map(|&xi| cdf_sum(0.0, xi, n, wrap)).collect();
    let mut right = vec![0f32; x.len()];
    for i in 0..bins {
        let boundary = (i + 1) as f32 / n;
        for (r, &xi) in right.iter_mut().zip(x) {
            *r = cdf_sum(boundary, xi, n, wrap);
        }
        for (row, (r, l)) in right.iter().zip(&left).enumerate() {
            out[row * stride + col + i] = r - l;
        }
        std::mem::swap(&mut left, &mut right);
    }
}

/// Derivative of `⟨dout, forward(x)⟩` with respect to `x`.
#[inline]
pub fn backward_input(x: f32, wrap: bool, dout: &[f32]) -> f32 {
    let n = dout.len() as f32;
    // d/dx C(n(b − x)) = −n K(n(b − x)).
    let mut left = -n * kernel_sum(0.0, x, n, wrap);
    let mut g = 0.0;
    for (i, d) in dout.iter().enumerate() {
        let right = -n * kernel_sum((i + 1) as f32 / n, x, n, wrap);
        g += d * (right - left);
        left = right;
    }
    g
}
