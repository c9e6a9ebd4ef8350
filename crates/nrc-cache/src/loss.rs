//! The training loss and the output mapping, per sample (CPU kernels) and as tensor ops.
//!
//! Prediction `y_c = act(o_c) · (α_c + β_c)` (network output `o`, output activation `act`,
//! diffuse α and specular β: the reflectance factorisation; the emission is never learned).
//! Loss of a sample: `w · Σ_c h(r_c)` of the relative residuals `r_c = (y_c − t_c) / √(lum(y)² +
//! ε)`, with `lum(y)` the Rec. 709 luminance of the *detached* prediction and `h` the square up to
//! `|r| = k` (`max_relative_error`) and linear beyond (`2k|r| − k²`, Huber's loss): within `k` the
//! relative L2 loss of Müller et al., whose expected gradient vanishes at the targets' mean;
//! beyond it one sample's gradient is bounded by `2k`, so a firefly target (10⁴ × the prediction:
//! a caustic found by a path at 1 spp) cannot kick the network and inflate Adam's second moment
//! for thousands of steps (it did, in the long runs of `nrc-harness/tests/online.rs`). The price is
//! a bias toward lower values where targets beyond `k` times the prediction carry energy. The
//! batch loss is the mean over used samples and channels.

use burn::tensor::{Tensor, TensorData};

use crate::config::OutputActivation;

/// Pre-activations are clamped to ±this before `exp` so the prediction stays finite; the
/// gradient passes through the clamp (straight-through) so an output beyond it is pulled back.
pub const EXP_CLAMP: f32 = 40.0;

/// `act(o)` and `d act/d o`.
#[inline(always)]
pub fn activate(act: OutputActivation, o: f32) -> (f32, f32) {
    match act {
        OutputActivation::Exponential => {
            let y = o.clamp(-EXP_CLAMP, EXP_CLAMP).exp();
            (y, y)
        }
        OutputActivation::Softplus => {
            let y = if o > 20.0 { o } else { o.exp().ln_1p() };
            (y, 1.0 / (1.0 + (-o).exp()))
        }
        OutputActivation::ReLU => {
            if o > 0.0 {
                (o, 1.0)
            } else {
                (0.0, 0.0)
            }
        }
    }
}

/// Loss of one sample and its gradient with respect to the network outputs `o`, scaled by
/// `scale` (1 / (3 · used samples)); `k` the relative residual beyond which the loss is linear.
/// Computed in f64 so extreme targets cannot overflow.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn sample_loss(
    act: OutputActivation,
    o: [f32; 3],
    factor: [f32; 3],
    target: [f32; 3],
    weight: f32,
    epsilon: f32,
    k: f32,
    scale: f32,
) -> (f64, [f32; 3]) {
    let mut y = [0f64; 3];
    let mut dy_do = [0f64; 3];
    for c in 0..3 {
        let (a, da) = activate(act, o[c]);
        y[c] = f64::from(a) * f64::from(factor[c]);
        dy_do[c] = f64::from(da) * f64::from(factor[c]);
    }
    let lum = 0.2126 * y[0] + 0.7152 * y[1] + 0.0722 * y[2];
    let denom = lum * lum + f64::from(epsilon);
    let norm = denom.sqrt();
    let (w, k) = (f64::from(weight), f64::from(k));
    let mut loss = 0.0;
    let mut grad = [0f32; 3];
    for c in 0..3 {
        let r = (y[c] - f64::from(target[c])) / norm;
        let (h, dh) = if r.abs() <= k {
            (r * r, 2.0 * r)
        } else {
            (2.0 * k * r.abs() - k * k, 2.0 * k * r.signum())
        };
        loss += w * h;
        grad[c] = (w * dh / norm * dy_do[c] * f64::from(scale)) as f32;
    }
    (loss, grad)
}

/// `act(o) · factor` as tensor ops (`o`, `factor`: `[N, 3]`). The exponential's clamp passes
/// gradients straight through, as in the CPU kernel.
pub fn predict_tensor(act: OutputActivation, o: Tensor<2>, factor: Tensor<2>) -> Tensor<2> {
    let a = match act {
        OutputActivation::Exponential => {
            // exp(o + (clamp(o) − o).detach()): the value of exp(clamp(o)), the gradient of exp.
            let clamped = o.clone().detach().clamp(-EXP_CLAMP, EXP_CLAMP);
            let shift = clamped - o.clone().detach();
            (o + shift).exp()
        }
        OutputActivation::Softplus => burn::tensor::activation::softplus(o, 1.0),
        OutputActivation::ReLU => burn::tensor::activation::relu(o),
    };
    a * factor
}

/// Mean relative loss (Huber beyond `k`, as [`sample_loss`]) as tensor ops: `y`, `target`:
/// `[N, 3]`, `weight`: `[N, 1]`.
pub fn loss_tensor(
    y: Tensor<2>,
    target: Tensor<2>,
    weight: Tensor<2>,
    epsilon: f32,
    k: f32,
) -> Tensor<1> {
    let [n, _] = y.dims();
    let device = y.device();
    let lum_w = Tensor::<2>::from_data(
        TensorData::new(vec![0.2126f32, 0.7152, 0.0722], [3, 1]),
        &device,
    );
    let lum = y.clone().detach().matmul(lum_w); // [N, 1]
    let norm = (lum.clone() * lum).add_scalar(epsilon).sqrt();
    let r = (y - target) / norm;
    let abs = r.clone().abs();
    let beyond = abs.clone().greater_elem(k);
    let h = (r.clone() * r).mask_where(beyond, abs.mul_scalar(2.0 * k).sub_scalar(k * k));
    (h * weight).sum().div_scalar((3 * n.max(1)) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Huber part: the loss and its gradient are continuous at `|r| = k`, the gradient is the
    /// relative L2 loss's within `k` and bounded by `2k / √(lum² + ε)` beyond, whatever the target.
    #[test]
    fn the_loss_is_quadratic_within_k_and_linear_beyond() {
        let act = OutputActivation::ReLU;
        let (o, f) = ([0.5f32, 0.5, 0.5], [1.0f32; 3]);
        let norm = (0.25f64 + 0.01).sqrt();
        let at = |t: f32, k: f32| sample_loss(act, o, f, [t; 3], 1.0, 0.01, k, 1.0);
        // Residual r = (0.5 − t)/norm; k = 4 is reached at t = 0.5 + 4·norm.
        let edge = (0.5 + 4.0 * norm) as f32;
        let (below, above) = (at(edge - 1e-4, 4.0), at(edge + 1e-4, 4.0));
        assert!((below.0 - above.0).abs() < 1e-2, "{below:?} {above:?}");
        assert!(
            (below.1[0] - above.1[0]).abs() < 1e-2,
            "{below:?} {above:?}"
        );
        // Within k, the plain relative L2 loss.
        let (plain, huber) = (at(0.7, 1e30), at(0.7, 4.0));
        assert_eq!(plain, huber);
        // A firefly: the plain gradient grows with the target, the bounded one does not.
        let firefly = |k| at(1e4, k).1[0].abs() as f64;
        assert!(firefly(1e30) > 1e4);
        let bound = 2.0 * 4.0 / norm;
        assert!(
            (firefly(4.0) - bound).abs() < 1e-4 * bound,
            "{} vs {bound}",
            firefly(4.0)
        );
    }
}
