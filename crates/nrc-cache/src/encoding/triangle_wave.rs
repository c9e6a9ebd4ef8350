//! Triangle-wave frequency encoding (tiny-cuda-nn's `TriangleWave`): each input dimension `x`
//! becomes `n` values `tri(2^j · x)`, `j = 0..n`, where `tri(t) = 2·|2·frac(t) − 1| − 1` is a
//! triangle wave of period 1 with range [−1, 1]; a cheap stand-in for sin/cos frequencies.
//! Output layout: `out[d·n + j]`.

/// The triangle wave `tri(t)`.
#[inline(always)]
pub fn tri(t: f32) -> f32 {
    2.0 * (2.0 * (t - t.floor()) - 1.0).abs() - 1.0
}

/// Derivative of `tri` (±4; the kinks at multiples of 1/2 take the right-hand value).
#[inline(always)]
pub fn tri_derivative(t: f32) -> f32 {
    if t - t.floor() < 0.5 { -4.0 } else { 4.0 }
}

/// Encodes one scalar into `out` (length `n`).
#[inline]
pub fn forward(x: f32, out: &mut [f32]) {
    let mut freq = 1.0f32;
    for o in out.iter_mut() {
        *o = tri(freq * x);
        freq *= 2.0;
    }
}

/// Derivative of `⟨dout, forward(x)⟩` with respect to `x`.
#[inline]
pub fn backward_input(x: f32, dout: &[f32]) -> f32 {
    let mut freq = 1.0f32;
    let mut g = 0.0;
    for d in dout {
        g += d * freq * tri_derivative(freq * x);
        freq *= 2.0;
    }
    g
}
