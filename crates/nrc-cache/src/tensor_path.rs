//! Training and inference with burn autodiff over tensors (the `CustomOps` and `Unfused`
//! paths): encode, MLP, output mapping and loss as tensor ops, backward by burn, then Adam and
//! the EMA as tensor ops. Runs on every device.
//!
//! The hash table gets the same sparse semantics as the fused CPU step: an entry whose
//! gradient is exactly zero (not referenced by the batch) keeps its weights and moments. The
//! EMA is updated densely every step, so it is always current.

use std::sync::Arc;

use burn::tensor::activation::relu;
use burn::tensor::{Bool, Tensor};

use crate::batch::{FACTOR_AT, TARGET_AT, WEIGHT_AT};
use crate::config::AdamParams;
use crate::device::ComputePath;
use crate::loss::{loss_tensor, predict_tensor};
use crate::model::{LayerShape, ModelLayout};
use crate::record::RAW_INPUT_DIMS;
use crate::state::TensorState;

/// Rows per slice of the batch in [`mlp_tensor`]'s split products: at least this many, and at
/// most [`MAX_SLICES`] slices.
const MIN_SLICE_ROWS: usize = 512;
/// Most slices of the batch in [`mlp_tensor`].
const MAX_SLICES: usize = 256;

/// The MLP as generic tensor ops (matmul + ReLU), raw outputs `[N, 3]`.
///
/// On a GPU the batch is cut into slices of rows and each layer is one batched product over the
/// slices, with the layer's matrix expanded (a view) over them. The point is the backward pass:
/// a layer's weight gradient `xᵀ·δ` reduces over the whole batch into a 64 × 64 matrix, which
/// one plain product computes on a handful of workgroups (on an H200 the matmul held 93.5 % of
/// the GPU time of 3 s of training and inference at 2^16, and training ran at 0.67 M samples/s
/// at every batch size, BENCHMARKS.md); sliced, autodiff computes one 64 × 64 product per slice
/// in parallel and sums them (the expand's backward): a split-K product from generic ops. Flex
/// keeps one product (the CPU's default is the fused step; slicing was not measured there).
pub fn mlp_tensor(weights: Tensor<1>, x: Tensor<2>, layers: &[LayerShape]) -> Tensor<2> {
    let [n, _] = x.dims();
    let flex = matches!(
        x.device().inner().as_dispatch(),
        burn::backend::DispatchDevice::Flex(_)
    );
    let slices = if flex {
        1
    } else {
        (n / MIN_SLICE_ROWS).clamp(1, MAX_SLICES)
    };
    mlp_tensor_sliced(weights, x, layers, slices)
}

/// [`mlp_tensor`] with the batch cut into `slices` slices (1: one product per layer).
fn mlp_tensor_sliced(
    weights: Tensor<1>,
    x: Tensor<2>,
    layers: &[LayerShape],
    slices: usize,
) -> Tensor<2> {
    let [n, k] = x.dims();
    if slices < 2 {
        let last = layers.len() - 1;
        let mut h = x;
        for (l, s) in layers.iter().enumerate() {
            h = h.matmul(layer_matrix(&weights, s));
            if l < last {
                h = relu(h);
            }
        }
        return h;
    }
    let rows = n.div_ceil(slices);
    let padded = rows * slices;
    // Zero rows pad the batch to whole slices; their outputs are cut off below, so their
    // gradient is zero and they add nothing to the weight gradients.
    let x = if padded > n {
        let pad = Tensor::<2>::zeros([padded - n, k], &x.device());
        Tensor::cat(vec![x, pad], 0)
    } else {
        x
    };
    let last = layers.len() - 1;
    let mut h: Tensor<3> = x.reshape([slices, rows, k]);
    for (l, s) in layers.iter().enumerate() {
        let m = layer_matrix(&weights, s)
            .unsqueeze::<3>()
            .expand([slices, s.inputs, s.outputs]);
        h = h.matmul(m);
        if l < last {
            h = relu(h);
        }
    }
    let outputs = layers[last].outputs;
    h.reshape([padded, outputs]).narrow(0, 0, n)
}

/// Layer `s`'s weight matrix `[inputs, outputs]` from the flat MLP weights.
fn layer_matrix(weights: &Tensor<1>, s: &LayerShape) -> Tensor<2> {
    weights
        .clone()
        .narrow(0, s.offset, s.len())
        .reshape([s.inputs, s.outputs])
}

/// Raw network outputs `[N, 3]` for raw inputs `[N, 14]`.
pub fn network_tensor(
    layout: &ModelLayout,
    path: ComputePath,
    grid: Option<Tensor<1>>,
    mlp: Tensor<1>,
    raw: Tensor<2>,
) -> Tensor<2> {
    let x = match path {
        ComputePath::Unfused => layout.encoding.encode_tensor_reference(grid, raw),
        _ => layout.encoding.encode_tensor(grid, raw),
    };
    if path != ComputePath::Unfused && has_mlp_op(&mlp) {
        crate::ops::mlp(mlp, x, &Arc::new(layout.layers.clone()))
    } else {
        mlp_tensor(mlp, x, &layout.layers)
    }
}

/// Whether the tensor's backend implements the fused MLP op (Flex only so far).
fn has_mlp_op(t: &Tensor<1>) -> bool {
    matches!(
        t.device().inner().as_dispatch(),
        burn::backend::DispatchDevice::Flex(_)
    )
}

/// Radiance `[N, 3]` of packed query rows `[N, 17]`.
pub fn infer_tensor(
    layout: &ModelLayout,
    path: ComputePath,
    grid: Option<Tensor<1>>,
    mlp: Tensor<1>,
    rows: Tensor<2>,
) -> Tensor<2> {
    let raw = rows.clone().narrow(1, 0, RAW_INPUT_DIMS);
    let factor = rows.narrow(1, FACTOR_AT, 3);
    let o = network_tensor(layout, path, grid, mlp, raw);
    predict_tensor(layout.output_activation, o, factor)
}

/// One training step on packed rows `[N, 21]`; returns the loss tensor (a scalar, before the
/// update) so the caller can read all losses at the end without a sync per step.
pub fn train_step_tensor(
    layout: &ModelLayout,
    path: ComputePath,
    state: &mut TensorState,
    rows: &Tensor<2>,
    adam: AdamParams,
    ema: Option<f32>,
    (epsilon, max_relative_error): (f32, f32),
    step: u32,
) -> Tensor<1> {
    let has_grid = layout.grid_params > 0;
    let grid = has_grid.then(|| state.grid.clone().autodiff().require_grad());
    let mlp = state.mlp.clone().autodiff().require_grad();
    let rows_ad = rows.clone().autodiff();
    let raw = rows_ad.clone().narrow(1, 0, RAW_INPUT_DIMS);
    let factor = rows_ad.clone().narrow(1, FACTOR_AT, 3);
    let target = rows_ad.clone().narrow(1, TARGET_AT, 3);
    let weight = rows_ad.narrow(1, WEIGHT_AT, 1);
    let o = network_tensor(layout, path, grid.clone(), mlp.clone(), raw);
    let y = predict_tensor(layout.output_activation, o, factor);
    let loss = loss_tensor(y, target, weight, epsilon, max_relative_error);
    let grads = loss.backward();
    let t = step.min(i32::MAX as u32) as i32;
    let bc1 = 1.0 - adam.beta1.powi(t);
    let bc2 = 1.0 - adam.beta2.powi(t);
    if let Some(g) = grid.as_ref().and_then(|g| g.grad(&grads)) {
        let referenced = g.clone().not_equal_elem(0.0);
        adam_tensor(
            &mut state.grid,
            &mut state.grid_m,
            &mut state.grid_v,
            g,
            Some(referenced),
            adam,
            bc1,
            bc2,
        );
        if let Some(alpha) = ema {
            state.grid_ema = state.grid_ema.clone().mul_scalar(alpha)
                + state.grid.clone().mul_scalar(1.0 - alpha);
        }
    }
    if let Some(g) = mlp.grad(&grads) {
        adam_tensor(
            &mut state.mlp,
            &mut state.mlp_m,
            &mut state.mlp_v,
            g,
            None,
            adam,
            bc1,
            bc2,
        );
        if let Some(alpha) = ema {
            state.mlp_ema =
                state.mlp_ema.clone().mul_scalar(alpha) + state.mlp.clone().mul_scalar(1.0 - alpha);
        }
    }
    loss.without_autodiff()
}

/// Adam as tensor ops; with `mask`, only masked entries change (sparse semantics).
/// Non-finite gradients count as zero.
fn adam_tensor(
    w: &mut Tensor<1>,
    m: &mut Tensor<1>,
    v: &mut Tensor<1>,
    g: Tensor<1>,
    mask: Option<Tensor<1, Bool>>,
    a: AdamParams,
    bc1: f32,
    bc2: f32,
) {
    let g = g.clone().mask_fill(g.is_finite().bool_not(), 0.0);
    let g = if a.l2_reg > 0.0 {
        g + w.clone().mul_scalar(a.l2_reg)
    } else {
        g
    };
    let m_new = m.clone().mul_scalar(a.beta1) + g.clone().mul_scalar(1.0 - a.beta1);
    let v_new = v.clone().mul_scalar(a.beta2) + (g.clone() * g).mul_scalar(1.0 - a.beta2);
    let update =
        m_new.clone().div_scalar(bc1) / v_new.clone().div_scalar(bc2).sqrt().add_scalar(a.epsilon);
    let update = update.clone().mask_fill(update.is_finite().bool_not(), 0.0);
    let w_new = w.clone() - update.mul_scalar(a.learning_rate);
    match mask {
        Some(mask) => {
            *m = m.clone().mask_where(mask.clone(), m_new);
            *v = v.clone().mask_where(mask.clone(), v_new);
            *w = w.clone().mask_where(mask, w_new);
        }
        None => {
            *m = m_new;
            *v = v_new;
            *w = w_new;
        }
    }
}
