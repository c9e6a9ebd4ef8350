//! The training loss and the output mapping, per sample (CPU kernels) and as tensor ops.
//!
//! Prediction `y_c = act(o_c) · (α_c + β_c)` (network output `o`, output activation `act`,
//! diffuse α and specular β: the reflectance factorisation; the emission is never learned).
//! Loss of a sample: `w · Σ_c (y_c − t_c)² / (lum(y)² + ε)` with `lum(y)` the Rec. 709 luminance
//! of the *detached* prediction; the batch loss is the mean over used samples and channels.

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
/// `scale` (1 / (3 · used samples)). Computed in f64 so extreme targets cannot overflow.
#[inline(always)]
pub fn sample_loss(
    act: OutputActivation,
    o: [f32; 3],
    factor: [f32; 3],
    target: [f32; 3],
    weight: f32,
    epsilon: f32,
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
    let w = f64::from(weight);
    let mut loss = 0.0;
    let mut grad = [0f32; 3];
    for c in 0..3 {
        let d = y[c] - f64::from(target[c]);
        loss += w * d * d / denom;
        grad[c] = (2.0 * w * d / denom * dy_do[c] * f64::from(scale)) as f32;
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

/// Mean relative L2 loss as tensor ops: `y`, `target`: `[N, 3]`, `weight`: `[N, 1]`.
pub fn loss_tensor(y: Tensor<2>, target: Tensor<2>, weight: Tensor<2>, epsilon: f32) -> Tensor<1> {
    let [n, _] = y.dims();
    let device = y.device();
    let lum_w = Tensor::<2>::from_data(
        TensorData::new(vec![0.2126f32, 0.7152, 0.0722], [3, 1]),
        &device,
    );
    let lum = y.clone().detach().matmul(lum_w); // [N, 1]
    let denom = (lum.clone() * lum).add_scalar(epsilon);
    let d = y - target;
    ((d.clone() * d) * weight / denom)
        .sum()
        .div_scalar((3 * n.max(1)) as f32)
}
