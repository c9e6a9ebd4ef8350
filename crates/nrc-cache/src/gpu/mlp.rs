//! The fused MLP on wgpu: `shaders/mlp_forward.wgsl` and `shaders/mlp_backward.wgsl` keep a
//! tile of 64 samples' activations (forward) or activation gradients (backward) in workgroup
//! memory across all layers, as tiny-cuda-nn's FullyFusedMLP does; the weight gradients
//! `A_{l−1}ᵀ · dY_l` are batch-long reductions and run as matrix products on burn's kernels.
//!
//! Implements [`MlpOps`] for `CubeBackend`; the matmul + ReLU chain it replaces is
//! `tensor_path::mlp_tensor` ([`unfused_forward`] is the same chain on raw primitives).
//!
//! Measured (examples/gpu_bench.rs, 2 iterations, batch 2^14, on mesa lavapipe = llvmpipe, a
//! *software* Vulkan rasteriser on the 2-core CPU, machine shared with other builds): the fused
//! kernels LOSE, ×0.25–0.30 of the matmul chain's throughput forward (1.3e4 vs 5.3e4 samples/s,
//! hash-grid net) and ×0.20–0.25 forward + backward (3.5e3 vs 1.4e4/s). lavapipe emulates
//! workgroup barriers and turns the per-thread weight loads into gathers, where burn's matmul
//! is vectorised. So the cache does not route the MLP through this op on wgpu
//! (`tensor_path::has_mlp_op` is Flex-only); no hardware GPU was available to measure it there.

use burn::backend::ops::{ActivationOps, FloatTensorOps};
use burn::backend::wgpu::{
    CubeBackend, CubeTensor, KernelSource, SourceKernel, SourceTemplate, into_contiguous,
};
use burn::cubecl::prelude::KernelId;
use burn::cubecl::server::KernelArguments;
use burn::cubecl::{CubeCount, CubeDim};
use burn::tensor::{DType, FloatDType, Shape, Slice};
use std::sync::Arc;

use crate::model::{LayerShape, OUTPUTS, WIDTH};
use crate::ops::{MlpOps, Needs};

const FORWARD: &str = include_str!("../../../../shaders/mlp_forward.wgsl");
const BACKWARD: &str = include_str!("../../../../shaders/mlp_backward.wgsl");

/// Samples per workgroup (the `TILE` of both shaders) and threads per workgroup.
const TILE: usize = 64;
const THREADS: u32 = 256;
/// Most workgroups one dispatch dimension may hold (WebGPU's default limit).
const MAX_GROUPS_PER_DIM: u32 = 65_535;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Pass {
    /// Forward; `store` also writes the hidden activations for the backward kernel.
    Forward { store: bool },
    /// Backward of the activations; `input_grad` also writes the input gradient.
    Backward { input_grad: bool },
}

/// One pass of the fused MLP, specialised to the input width and the hidden-layer count.
#[derive(Debug)]
struct MlpKernel {
    pass: Pass,
    inputs: u32,
    hidden: u32,
}

impl KernelSource for MlpKernel {
    fn source(&self) -> SourceTemplate {
        let template = match self.pass {
            Pass::Forward { store } => {
                SourceTemplate::new(FORWARD).register("store", store.to_string())
            }
            Pass::Backward { input_grad } => {
                SourceTemplate::new(BACKWARD).register("input_grad", input_grad.to_string())
            }
        };
        template
            .register("inputs", self.inputs.to_string())
            .register("hidden", self.hidden.to_string())
    }

    fn id(&self) -> KernelId {
        KernelId::new::<Self>().info((self.pass, self.inputs, self.hidden))
    }

    fn lang(&self) -> &'static str {
        "wgsl"
    }
}

/// Checks the network has the shape the kernels assume: 64-wide hidden layers, 3 outputs,
/// weights of the f32 group in order. Returns (inputs, hidden layers).
fn shape_of(layers: &[LayerShape], weights: &CubeTensor) -> (usize, usize) {
    assert!(
        layers.len() >= 2,
        "fused MLP on wgpu: needs at least one hidden layer"
    );
    assert_eq!(
        weights.dtype,
        DType::F32,
        "fused MLP on wgpu: weights must be f32"
    );
    let hidden = layers.len() - 1;
    for (l, layer) in layers.iter().enumerate() {
        let outputs = if l == hidden { OUTPUTS } else { WIDTH };
        let inputs = if l == 0 { layer.inputs } else { WIDTH };
        assert!(
            layer.outputs == outputs && layer.inputs == inputs,
            "fused MLP on wgpu: layer {l} is {}×{}, expected {inputs}×{outputs}",
            layer.inputs,
            layer.outputs
        );
    }
    let total = layers.last().map_or(0, |l| l.offset + l.len());
    assert_eq!(
        weights.meta.shape().num_elements(),
        total,
        "fused MLP on wgpu: weight count"
    );
    (layers[0].inputs, hidden)
}

/// Whether the fused kernels fit this device's workgroup memory for `inputs` network inputs
/// (the forward tile holds 64 × max(inputs, 64) floats: 16 KiB, WebGPU's guaranteed minimum,
/// up to 64 inputs).
pub fn fits(tensor: &CubeTensor, inputs: usize) -> bool {
    let bytes = TILE * inputs.max(WIDTH) * size_of::<f32>();
    bytes <= tensor.client.properties().hardware.max_shared_memory_size
}

fn cube_count(samples: usize) -> CubeCount {
    let groups = samples.div_ceil(TILE) as u32;
    let x = groups.clamp(1, MAX_GROUPS_PER_DIM);
    CubeCount::Static(x, groups.div_ceil(x).max(1), 1)
}

fn info(samples: usize, layers: &[LayerShape]) -> Vec<u32> {
    std::iter::once(samples as u32)
        .chain(layers.iter().map(|l| l.offset as u32))
        .collect()
}

fn empty(like: &CubeTensor, shape: Shape) -> CubeTensor {
    let handle = like
        .client
        .empty(shape.num_elements().max(1) * size_of::<f32>());
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        shape,
        handle,
        DType::F32,
    )
}

/// Runs the forward kernel; with `store`, also returns the hidden activations [H·n·64].
fn forward_pass(
    weights: &CubeTensor,
    input: &CubeTensor,
    layers: &[LayerShape],
    store: bool,
) -> (CubeTensor, CubeTensor) {
    let (inputs, hidden) = shape_of(layers, weights);
    let samples = input.meta.shape()[0];
    assert_eq!(
        input.meta.shape().num_dims(),
        2,
        "fused MLP on wgpu: input must be [n, in]"
    );
    assert_eq!(
        input.meta.shape()[1],
        inputs,
        "fused MLP on wgpu: input width"
    );
    assert!(
        fits(input, inputs),
        "fused MLP on wgpu: {inputs} inputs need more workgroup memory than the device has"
    );
    let output = empty(input, Shape::new([samples, OUTPUTS]));
    let activations = empty(
        input,
        Shape::new([if store { hidden * samples * WIDTH } else { 1 }]),
    );
    if samples == 0 {
        return (output, activations);
    }
    let client = &input.client;
    let info = client.create_from_slice(bytemuck::cast_slice(&info(samples, layers)));
    let kernel = MlpKernel {
        pass: Pass::Forward { store },
        inputs: inputs as u32,
        hidden: hidden as u32,
    };
    client.launch(
        Box::new(SourceKernel::new(kernel, CubeDim::new_1d(THREADS))),
        cube_count(samples),
        KernelArguments::new().with_buffers(vec![
            weights.handle.clone().binding(),
            input.handle.clone().binding(),
            output.handle.clone().binding(),
            activations.handle.clone().binding(),
            info.binding(),
        ]),
    );
    (output, activations)
}

/// Raw outputs [n, 3] of the network with the MLP parameter group `weights` for `input` [n, in].
pub fn forward(weights: CubeTensor, input: CubeTensor, layers: &[LayerShape]) -> CubeTensor {
    let (weights, input) = (into_contiguous(weights), into_contiguous(input));
    forward_pass(&weights, &input, layers, false).0
}

/// `(∂L/∂weights [W], ∂L/∂input [n, in])` for `grad_output` = ∂L/∂outputs [n, 3]; a gradient
/// not asked for by `needs` comes back as an empty tensor, as on Flex.
pub fn backward(
    weights: CubeTensor,
    input: CubeTensor,
    grad_output: CubeTensor,
    layers: &[LayerShape],
    needs: Needs,
) -> (CubeTensor, CubeTensor) {
    let (weights, input) = (into_contiguous(weights), into_contiguous(input));
    let grad_output = into_contiguous(grad_output);
    let (inputs, hidden) = shape_of(layers, &weights);
    let samples = input.meta.shape()[0];
    let (_, activations) = forward_pass(&weights, &input, layers, true);

    let grad_hidden = empty(&input, Shape::new([hidden * samples * WIDTH]));
    let grad_input = empty(
        &input,
        Shape::new([if needs.input { samples } else { 0 }, inputs]),
    );
    if samples > 0 {
        let client = &input.client;
        let info = client.create_from_slice(bytemuck::cast_slice(&info(samples, layers)));
        let kernel = MlpKernel {
            pass: Pass::Backward {
                input_grad: needs.input,
            },
            inputs: inputs as u32,
            hidden: hidden as u32,
        };
        client.launch(
            Box::new(SourceKernel::new(kernel, CubeDim::new_1d(THREADS))),
            cube_count(samples),
            KernelArguments::new().with_buffers(vec![
                weights.handle.clone().binding(),
                grad_output.handle.clone().binding(),
                activations.handle.clone().binding(),
                grad_hidden.handle.clone().binding(),
                grad_input.handle.clone().binding(),
                info.binding(),
            ]),
        );
    }
    if !needs.params {
        return (empty(&input, Shape::new([0])), grad_input);
    }
    if samples == 0 {
        let total = layers.last().map_or(0, |l| l.offset + l.len());
        return (
            CubeBackend::float_zeros(Shape::new([total]), &input.device, FloatDType::F32),
            grad_input,
        );
    }

    // Layer l's activation (its input) and pre-activation gradient, both [n, ·].
    let layer_of = |t: &CubeTensor, l: usize| {
        let at = l * samples * WIDTH;
        let slice = CubeBackend::float_slice(t.clone(), &[Slice::from(at..at + samples * WIDTH)]);
        CubeBackend::float_reshape(slice, Shape::new([samples, WIDTH]))
    };
    let grads = layers
        .iter()
        .enumerate()
        .map(|(l, layer)| {
            let a = if l == 0 {
                input.clone()
            } else {
                layer_of(&activations, l - 1)
            };
            let dy = if l == hidden {
                grad_output.clone()
            } else {
                layer_of(&grad_hidden, l)
            };
            let g = CubeBackend::float_matmul(CubeBackend::float_transpose(a), dy);
            CubeBackend::float_reshape(g, Shape::new([layer.len()]))
        })
        .collect();
    (CubeBackend::float_cat(grads, 0), grad_input)
}

/// The chain of matrix products and ReLUs the fused forward replaces (burn's own kernels).
pub fn unfused_forward(
    weights: CubeTensor,
    input: CubeTensor,
    layers: &[LayerShape],
) -> CubeTensor {
    let last = layers.len() - 1;
    let mut h = input;
    for (l, layer) in layers.iter().enumerate() {
        let m = CubeBackend::float_slice(
            weights.clone(),
            &[Slice::from(layer.offset..layer.offset + layer.len())],
        );
        let m = CubeBackend::float_reshape(m, Shape::new([layer.inputs, layer.outputs]));
        h = CubeBackend::float_matmul(h, m);
        if l < last {
            h = CubeBackend::relu(h);
        }
    }
    h
}

impl MlpOps for CubeBackend {
    fn mlp_forward(
        weights: CubeTensor,
        input: CubeTensor,
        layers: Arc<Vec<LayerShape>>,
    ) -> CubeTensor {
        forward(weights, input, &layers)
    }

    fn mlp_backward(
        weights: CubeTensor,
        input: CubeTensor,
        grad_out: CubeTensor,
        layers: Arc<Vec<LayerShape>>,
        needs: Needs,
    ) -> (CubeTensor, CubeTensor) {
        backward(weights, input, grad_out, &layers, needs)
    }
}
