//! The fused training step and inference on burn's Cube backend: [`NrcFusedOps`] for
//! `CubeBackend`, by the CubeCL kernels of the `nrc-gpu` crate.
//!
//! The table is read in f16 where the configuration asks for it and the device has f16
//! arithmetic (the training forward from an f16 copy of the weights that every update keeps,
//! as on the CPU); so is the MLP with `"precision": "f16"` (its weights from an f16 copy that
//! each call makes and every update keeps, its activations in f16, f32 sums); everything else
//! is f32 (bf16 MLP products are the CPU path's; the description line says which). The state is the CPU fused path's but for the table's
//! layout: weights, moments and the EMA gap (see [`crate::cpu::optim`]) as four arrays in
//! `grid`, `grid_m`, `grid_v`, `grid_ema` instead of per-entry records (each one binding: a
//! 2^19-entry table's records would exceed WebGPU's 128 MiB per binding), so EMA conversions
//! and the cache's bookkeeping are shared.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use burn::backend::wgpu::{CubeBackend, CubeTensor, into_contiguous};
use burn::tensor::DType;
use nrc_gpu::{AdamStep, Atomics, Layout, Loss, PartKind, State, TableState, Trainer};

use crate::config::{MlpPrecision, OutputActivation};
use crate::cpu::optim::{StepConstants, decay_pow, ema_rebase_interval};
use crate::encoding::EncodingKind;
use crate::encoding::hash_grid::TablePrecision;
use crate::model::ModelLayout;
use crate::ops::{
    EmaConversion, GradientOutcome, InferenceWeights, NrcFusedOps, StepSpec, TrainOutcome,
    TrainState,
};
use crate::profile::InferClock;
use crate::record::RAW_INPUT_DIMS;

/// 0: the adapter's best; 1: native float atomics; 2: compare-and-swap.
static FORCED_ATOMICS: AtomicU8 = AtomicU8::new(0);

/// Forces the gradient scatter's atomics (`None`: the best the adapter has), for tests and
/// benchmarks of both paths.
pub fn force_atomics(atomics: Option<Atomics>) {
    let code = match atomics {
        None => 0,
        Some(Atomics::Native) => 1,
        Some(Atomics::CompareSwap) => 2,
    };
    FORCED_ATOMICS.store(code, Ordering::Relaxed);
}

/// The atomics the scatter uses on `client`'s device.
pub fn atomics(client: &burn::cubecl::prelude::Client) -> Atomics {
    match FORCED_ATOMICS.load(Ordering::Relaxed) {
        1 => Atomics::Native,
        2 => Atomics::CompareSwap,
        _ => Atomics::best(client),
    }
}

/// The CubeCL client behind a burn device (`None` for the CPU's Flex device).
pub fn client(device: &burn::tensor::Device) -> Option<burn::cubecl::prelude::Client> {
    match device.as_dispatch() {
        burn::backend::DispatchDevice::Cube(d) => Some(d.client()),
        #[allow(unreachable_patterns)]
        _ => None,
    }
}

/// Whether CubeCL compiles kernels for `device` to SPIR-V (a build with the cargo feature
/// `vulkan`, on a Vulkan adapter): raw WGSL source kernels cannot load there.
pub fn compiles_spirv(device: &burn::tensor::Device) -> bool {
    client(device).is_some_and(|c| c.name().contains("spirv"))
}

/// Whether the fused path can run `layout` on `device` (the table within 32-bit indexing, a
/// tile within the adapter's workgroup memory): the error names what stands in the way.
pub fn check(device: &burn::tensor::Device, layout: &ModelLayout) -> Result<(), String> {
    let client = client(device);
    let half = client.as_ref().is_some_and(|c| half_mlp(c, layout));
    let l = gpu_layout(layout, half);
    l.check()?;
    if let Some(client) = client {
        nrc_gpu::tile_rows(&client, &l)?;
    }
    Ok(())
}

/// Whether the MLP computes in half precision on `client`'s device: `"precision": "f16"` and
/// f16 arithmetic there (wgpu's `shader-f16`).
pub fn half_mlp(client: &burn::cubecl::prelude::Client, layout: &ModelLayout) -> bool {
    layout.mlp_precision == MlpPrecision::F16 && nrc_gpu::supports_f16(client)
}

/// How the fused path runs on `device` (for the cache's description line): the runtime, the
/// precision, the atomics and the rows per tile.
pub fn describe(device: &burn::tensor::Device, layout: &ModelLayout) -> String {
    let Some(client) = client(device) else {
        return "not a CubeCL device".into();
    };
    let half = half_mlp(&client, layout);
    let l = gpu_layout(layout, half);
    let tile = match nrc_gpu::tile_rows(&client, &l) {
        Ok((r, _)) => format!("{r} rows a tile"),
        Err(e) => e,
    };
    let precision = |training: bool| {
        if half_table(&client, layout, training) {
            "f16"
        } else {
            "f32"
        }
    };
    format!(
        "fused CubeCL kernels on {}: table read in {} by the training forward and {} by \
         inference, {}, {}, {tile}, {} dispatches a step{}",
        client.name(),
        precision(true),
        precision(false),
        if half {
            "f16 MLP (f16 weights and activations, f32 sums and backward)"
        } else if layout.mlp_precision == MlpPrecision::F16 {
            "f32 MLP (the configured f16 needs shader-f16, which this adapter lacks)"
        } else {
            "f32 MLP (bf16 products are the CPU path's)"
        },
        atomics(&client).name(),
        if l.grid.is_some() {
            nrc_gpu::STEP_DISPATCHES
        } else {
            nrc_gpu::STEP_DISPATCHES - 2
        },
        if half {
            " and 1 a call (the MLP's f16 copy)"
        } else {
            ""
        }
    )
}

/// The model as the kernels read it, the MLP in half precision with `half_mlp`.
pub fn gpu_layout(layout: &ModelLayout, half_mlp: bool) -> Layout {
    let enc = &layout.encoding;
    let mut grid = None;
    let mut parts = Vec::new();
    for part in &enc.parts {
        let kind = match &part.kind {
            EncodingKind::HashGrid(g) => {
                grid = Some(nrc_gpu::Grid {
                    features: g.features(),
                    levels: g
                        .levels
                        .iter()
                        .map(|l| nrc_gpu::Level {
                            scale: l.scale,
                            resolution: l.resolution,
                            entries: l.entries,
                            offset: l.offset as u32,
                            dense: l.dense,
                        })
                        .collect(),
                    in_offset: part.in_offset,
                    out_offset: part.out_offset,
                });
                continue;
            }
            EncodingKind::OneBlob { bins, wrap } => PartKind::OneBlob {
                bins: *bins as u32,
                wrap: *wrap,
            },
            EncodingKind::TriangleWave { frequencies } => PartKind::TriangleWave {
                frequencies: *frequencies as u32,
            },
            EncodingKind::Identity { scale, offset } => PartKind::Identity {
                scale: *scale,
                offset: *offset,
            },
        };
        parts.push(nrc_gpu::Part {
            kind,
            in_offset: part.in_offset,
            in_dims: part.in_dims,
            out_offset: part.out_offset,
        });
    }
    Layout {
        inputs: enc.padded_dims,
        unpadded: enc.unpadded_dims,
        hidden: layout.layers.len() - 1,
        activation: match layout.output_activation {
            OutputActivation::Exponential => nrc_gpu::Activation::Exponential,
            OutputActivation::Softplus => nrc_gpu::Activation::Softplus,
            OutputActivation::ReLU => nrc_gpu::Activation::ReLU,
        },
        grid,
        parts,
        raw_dims: RAW_INPUT_DIMS,
        half_mlp,
    }
}

/// `t` contiguous and not shared with another tensor, so a kernel may update it in place.
fn owned(t: CubeTensor) -> CubeTensor {
    let t = into_contiguous(t);
    if t.can_mut() {
        t
    } else {
        nrc_gpu::combine(&t, &t, 1.0, 0.0, 1.0)
    }
}

fn owned_state(s: TrainState<CubeBackend>) -> TrainState<CubeBackend> {
    TrainState {
        grid: owned(s.grid),
        grid_m: owned(s.grid_m),
        grid_v: owned(s.grid_v),
        grid_ema: owned(s.grid_ema),
        grid_half: s.grid_half,
        mlp: owned(s.mlp),
        mlp_m: owned(s.mlp_m),
        mlp_v: owned(s.mlp_v),
        mlp_ema: owned(s.mlp_ema),
    }
}

/// The table's state; with `half`, the forward reads `grid_half` (an f16 copy).
fn table(s: &TrainState<CubeBackend>, half: bool) -> TableState<'_> {
    TableState {
        w: &s.grid,
        m: &s.grid_m,
        v: &s.grid_v,
        q: &s.grid_ema,
        half: half.then_some(&s.grid_half),
    }
}

/// The state as the kernels take it (the table only with a grid; its f16 copy with `half`;
/// the MLP's f16 copy `mlp_half`, if any).
fn kernel_state<'a>(
    s: &'a TrainState<CubeBackend>,
    grid: bool,
    half: bool,
    mlp_half: Option<&'a CubeTensor>,
) -> State<'a> {
    State {
        table: grid.then(|| table(s, half)),
        mlp: &s.mlp,
        mlp_m: &s.mlp_m,
        mlp_v: &s.mlp_v,
        mlp_ema: &s.mlp_ema,
        mlp_half,
    }
}

/// The MLP's weights rounded to f16 (the copy a half-precision MLP's tile pass reads; the
/// MLP update keeps it), or `None` for an f32 MLP: one dispatch per call, a few thousand values.
fn mlp_copy(s: &TrainState<CubeBackend>, half_mlp: bool) -> Option<CubeTensor> {
    half_mlp.then(|| nrc_gpu::combine_as(&s.mlp, &s.mlp, 1.0, 0.0, 1.0, true))
}

fn loss(spec: &StepSpec) -> Loss {
    Loss {
        epsilon: spec.loss.epsilon,
        huber: spec.loss.max_relative_error,
    }
}

/// Whether a batch of `n` rows can go through the fused GPU step (32-bit indexing).
pub fn check_batch(layout: &ModelLayout, n: usize) -> Result<(), String> {
    gpu_layout(layout, false).check_rows(n)
}

/// Whether `layout`'s table is read in half precision by the training forward
/// (`"training_precision": "f16"`) or by inference on `client`'s device: where it has f16
/// arithmetic (wgpu's `shader-f16`), else in f32.
fn half_table(
    client: &burn::cubecl::prelude::Client,
    layout: &ModelLayout,
    training: bool,
) -> bool {
    layout.encoding.grid().is_some_and(|(hg, _)| {
        let p = if training {
            hg.params.training_precision
        } else {
            hg.params.inference_precision
        };
        p == TablePrecision::F16 && nrc_gpu::supports_f16(client)
    })
}

fn elements(t: &CubeTensor) -> usize {
    t.meta.shape().num_elements()
}

impl NrcFusedOps for CubeBackend {
    fn fused_train_steps(
        state: TrainState<Self>,
        batch: CubeTensor,
        spec: StepSpec,
    ) -> TrainOutcome<Self> {
        let state = owned_state(state);
        let batch = into_contiguous(batch);
        let client = batch.client.clone();
        let half_mlp = half_mlp(&client, &spec.layout);
        let layout = gpu_layout(&spec.layout, half_mlp);
        let n = elements(&batch) / layout.train_row();
        let trainer = Trainer::new(&layout, batch, n, spec.steps as usize, atomics(&client))
            .unwrap_or_else(|e| panic!("the fused GPU step cannot run: {e}"));
        let has_grid = spec.layout.grid_params > 0;
        // The f16 copy the forward reads: kept from the last call when it is one (every update
        // keeps it equal to the weights rounded), else made from the weights.
        let half = half_table(&client, &spec.layout, true);
        let state = if half
            && !(state.grid_half.dtype == DType::F16
                && elements(&state.grid_half) == elements(&state.grid)
                && state.grid_half.can_mut()
                && state.grid_half.is_contiguous())
        {
            TrainState {
                grid_half: nrc_gpu::combine_as(&state.grid, &state.grid, 1.0, 0.0, 1.0, true),
                ..state
            }
        } else {
            state
        };
        let mlp_half = mlp_copy(&state, half_mlp);
        let mut ema_base = spec.ema_base;
        for k in 1..=spec.steps {
            let done = spec.first_step + k - 1;
            if let Some(alpha) = spec.ema
                && has_grid
                && done - ema_base >= ema_rebase_interval(alpha)
            {
                let shift = decay_pow(alpha, done - ema_base);
                nrc_gpu::combine_into(&state.grid, &state.grid_ema, 0.0, shift, 1.0);
                ema_base = done;
            }
            let c = StepConstants::new(spec.adam, spec.ema, done + 1, ema_base);
            let adam = AdamStep {
                beta1: spec.adam.beta1,
                beta2: spec.adam.beta2,
                epsilon: spec.adam.epsilon,
                l2: spec.adam.l2_reg,
                step_size: c.step_size,
                inv_bc2: c.inv_bc2,
                ema: spec.ema,
                gap_growth: c.gap_growth,
            };
            trainer.step(
                k as usize - 1,
                &kernel_state(&state, has_grid, half, mlp_half.as_ref()),
                &adam,
                loss(&spec),
            );
        }
        TrainOutcome {
            state,
            losses: trainer.loss_tensor(),
            ema_base,
        }
    }

    fn fused_gradients(
        state: TrainState<Self>,
        batch: CubeTensor,
        spec: StepSpec,
    ) -> GradientOutcome<Self> {
        let batch = into_contiguous(batch);
        let client = batch.client.clone();
        let half_mlp = half_mlp(&client, &spec.layout);
        let layout = gpu_layout(&spec.layout, half_mlp);
        let n = elements(&batch) / layout.train_row();
        let mut trainer = Trainer::new(&layout, batch, n, 1, atomics(&client))
            .unwrap_or_else(|e| panic!("the fused GPU step cannot run: {e}"));
        let state = TrainState {
            grid: into_contiguous(state.grid),
            mlp: into_contiguous(state.mlp),
            ..state
        };
        let mlp_half = mlp_copy(&state, half_mlp);
        let s = kernel_state(
            &state,
            spec.layout.grid_params > 0,
            false,
            mlp_half.as_ref(),
        );
        let g = trainer
            .gradients(&s, loss(&spec))
            .unwrap_or_else(|e| panic!("the fused GPU step failed: {e}"));
        GradientOutcome {
            state,
            loss: f64::from(g.loss),
            grid: g.table,
            mlp: g.mlp,
        }
    }

    fn inference_weights(
        state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        ema: Option<f32>,
        step: u32,
        ema_base: Option<u32>,
    ) -> InferenceWeights<Self> {
        let average = ema.filter(|_| step > 0);
        let grid = match layout.encoding.grid() {
            Some(_) => {
                let w = into_contiguous(state.grid);
                let q = into_contiguous(state.grid_ema);
                let (cw, cq, cs) = match average {
                    Some(alpha) => {
                        let inv = 1.0 / (1.0 - decay_pow(alpha, step));
                        match ema_base {
                            Some(b) => (1.0, decay_pow(alpha, step - b), inv),
                            None => (0.0, 1.0, inv),
                        }
                    }
                    None => (1.0, 0.0, 1.0),
                };
                let half = half_table(&w.client, &layout, false);
                nrc_gpu::combine_as(&w, &q, cw, cq, cs, half)
            }
            None => state.grid,
        };
        let mlp = into_contiguous(state.mlp);
        let half = half_mlp(&mlp.client, &layout);
        let mlp = match average {
            Some(alpha) => {
                let inv = 1.0 / (1.0 - decay_pow(alpha, step));
                nrc_gpu::combine_as(&mlp, &into_contiguous(state.mlp_ema), 0.0, inv, 1.0, half)
            }
            None => nrc_gpu::combine_as(&mlp, &mlp, 1.0, 0.0, 1.0, half),
        };
        InferenceWeights { grid, mlp }
    }

    fn convert_ema(
        state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        conversion: EmaConversion,
    ) -> TrainState<Self> {
        if layout.encoding.grid().is_none() {
            return state;
        }
        let state = TrainState {
            grid: into_contiguous(state.grid),
            grid_ema: owned(state.grid_ema),
            ..state
        };
        let (cw, cq) = match conversion {
            EmaConversion::ToRaw { alpha, shift } => (1.0, decay_pow(alpha, shift)),
            EmaConversion::ToGap => (-1.0, 1.0),
            EmaConversion::ScaledWeights { scale } => (scale, 0.0),
        };
        nrc_gpu::combine_into(&state.grid, &state.grid_ema, cw, cq, 1.0);
        state
    }

    fn fused_infer(
        grid: CubeTensor,
        mlp: CubeTensor,
        queries: CubeTensor,
        layout: Arc<ModelLayout>,
        clock: Arc<InferClock>,
    ) -> CubeTensor {
        let _ = clock;
        let l = gpu_layout(&layout, mlp.dtype == DType::F16);
        let queries = into_contiguous(queries);
        let n = elements(&queries) / l.query_row();
        let grid = into_contiguous(grid);
        let mlp = into_contiguous(mlp);
        nrc_gpu::infer(&l, &grid, &mlp, &queries, n)
            .unwrap_or_else(|e| panic!("fused GPU inference cannot run: {e}"))
    }
}
