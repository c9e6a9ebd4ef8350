//! The cache's custom burn operations (backend extensions).
//!
//! * [`MlpOps`] — differentiable: the fused MLP, a forward op and a backward op. The `Autodiff`
//!   implementation (generic over the inner backend) registers the backward op as the node's
//!   backward step, so gradients flow through burn's autodiff graph. (The hash-grid encoding's
//!   op is [`crate::hash_grid_op::HashGridOps`], built the same way.)
//! * [`NrcFusedOps`] — the whole CPU training step (encode, MLP forward/backward, loss, sparse
//!   Adam + EMA) and fused inference, on tensors that live on the device.
//!
//! [`MlpOps`] is implemented for Flex (rayon kernels in [`crate::cpu`]); on wgpu the custom-ops
//! path multiplies with burn's matmuls. [`NrcFusedOps`] is implemented for Flex and for wgpu
//! (`CubeBackend`: the `nrc-gpu` crate's CubeCL kernels, [`crate::gpu::fused`]).

use std::borrow::Cow;
use std::sync::Arc;

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    AutodiffBackend, Backend, Dispatch, ExtensionType, Flex, TensorMetadata, backend_extension,
};
use burn::tensor::{DType, Tensor, TensorData, f16};
use rayon::prelude::*;

use crate::config::MlpPrecision;
use crate::cpu;
use crate::cpu::mlp::{
    MlpGrad, OUT_PAD, PreparedMlp, TILE, TileScratch, backward_tile, forward_tile,
};
use crate::encoding::hash_grid::TablePrecision;
use crate::model::{LayerShape, ModelLayout};
use crate::profile::{InferClock, TrainClock};

/// Which gradients a backward op must produce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Needs {
    /// Gradient of the parameters (table or weights).
    pub params: bool,
    /// Gradient of the input (positions or network input).
    pub input: bool,
}

/// The fused MLP as a differentiable custom op (rayon tiles on Flex).
#[backend_extension(Flex, Autodiff)]
pub trait MlpOps: burn::backend::Backend {
    /// Fused MLP (ReLU hidden layers, no biases, linear output): `weights` is the MLP parameter
    /// group `[W]` (layout of [`LayerShape`]), `input` `[N, in]` → raw outputs `[N, 3]`.
    fn mlp_forward(
        weights: FloatTensor<Self>,
        input: FloatTensor<Self>,
        layers: Arc<Vec<LayerShape>>,
    ) -> FloatTensor<Self>;

    /// Backward of [`MlpOps::mlp_forward`]: `(∂L/∂weights [W], ∂L/∂input [N, in])`, recomputing
    /// each tile's activations in cache instead of storing them.
    fn mlp_backward(
        weights: FloatTensor<Self>,
        input: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        layers: Arc<Vec<LayerShape>>,
        needs: Needs,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

/// The complete training state on the device: the two parameter groups with their Adam
/// moments and EMA. The fused ops on Flex keep the table as per-entry records `[w | m | v | q]`
/// in `grid` (`q`: the EMA gap, see [`crate::cpu::optim`]), with `grid_m`, `grid_v`, `grid_ema`
/// empty; on the Cube backend as four arrays (`grid_ema` holding the gap).
#[derive(ExtensionType)]
pub struct TrainState<B: Backend> {
    /// Hash table records `[entries·4F]` (empty without a hash grid).
    pub grid: FloatTensor<B>,
    /// Unused by the fused ops (empty).
    pub grid_m: FloatTensor<B>,
    /// Unused by the fused ops (empty).
    pub grid_v: FloatTensor<B>,
    /// Unused by the fused ops (empty).
    pub grid_ema: FloatTensor<B>,
    /// The table's weights in half precision `[entries·F]`, which the fused training forward
    /// reads with `"training_precision": "f16"` (kept equal to the records' weights, rounded, by
    /// every update); empty otherwise, and rebuilt from the records when empty.
    pub grid_half: FloatTensor<B>,
    /// MLP weights `[W]`.
    pub mlp: FloatTensor<B>,
    /// Adam first moment of the MLP.
    pub mlp_m: FloatTensor<B>,
    /// Adam second moment of the MLP.
    pub mlp_v: FloatTensor<B>,
    /// Raw EMA of the MLP.
    pub mlp_ema: FloatTensor<B>,
}

/// Result of [`NrcFusedOps::fused_train_steps`].
#[derive(ExtensionType)]
pub struct TrainOutcome<B: Backend> {
    /// The updated state.
    #[extension_type]
    pub state: TrainState<B>,
    /// Mean loss of each step (before its update), `[steps]`, left on the device: reading it
    /// waits for the steps, so the caller reads it when it needs it (the online loop traces the
    /// next work on the CPU meanwhile).
    pub losses: FloatTensor<B>,
    /// The base step of the table's EMA gap after the steps (see [`crate::cpu::optim`]).
    pub ema_base: u32,
}

/// Result of [`NrcFusedOps::fused_gradients`].
#[derive(ExtensionType)]
pub struct GradientOutcome<B: Backend> {
    /// The state, unchanged.
    #[extension_type]
    pub state: TrainState<B>,
    /// Mean loss over samples and channels.
    pub loss: f64,
    /// ∂L/∂table, dense (`[entries · F]`; empty without a hash grid).
    pub grid: Vec<f32>,
    /// ∂L/∂(MLP weights).
    pub mlp: Vec<f32>,
}

/// Constants of a run of training steps.
#[derive(Clone, Debug)]
pub struct StepSpec {
    /// The model.
    pub layout: Arc<ModelLayout>,
    /// Adam parameters.
    pub adam: crate::config::AdamParams,
    /// EMA decay.
    pub ema: Option<f32>,
    /// Loss settings.
    pub loss: cpu::train::LossSettings,
    /// Step count before the first step of this run.
    pub first_step: u32,
    /// The base step of the table's EMA gap (at most `first_step`).
    pub ema_base: u32,
    /// Steps to take.
    pub steps: u32,
    /// Where the steps' time goes.
    pub clock: Arc<TrainClock>,
}

/// Inference weights derived from a [`TrainState`].
#[derive(ExtensionType)]
pub struct InferenceWeights<B: Backend> {
    /// Hash table (bias-corrected EMA, or the weights without EMA).
    pub grid: FloatTensor<B>,
    /// MLP weights (likewise).
    pub mlp: FloatTensor<B>,
}

/// A conversion of the table's EMA in the fused path's records (see [`crate::cpu::optim`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EmaConversion {
    /// Gap → raw EMA `shift` steps after the gap's base: `e = w + α^shift·q`.
    ToRaw {
        /// EMA decay.
        alpha: f32,
        /// Steps since the base.
        shift: u32,
    },
    /// Raw EMA → gap based at the current step: `q = e − w`.
    ToGap,
    /// The EMA slot (raw EMA or gap, whichever the records hold) set to `scale·w`: how the
    /// average is restarted at the weights ([`crate::RadianceCache::set_follow`]).
    ScaledWeights {
        /// The factor of the weights.
        scale: f32,
    },
}

/// Fused, non-differentiable custom ops of the training loop: rayon kernels on Flex
/// ([`crate::cpu`]), CubeCL kernels on the Cube backend ([`crate::gpu::fused`], the `nrc-gpu`
/// crate).
#[backend_extension(Cube, Flex)]
pub trait NrcFusedOps: burn::backend::Backend {
    /// Runs `spec.steps` fused training steps on the packed rows `batch` `[N, 21]`.
    fn fused_train_steps(
        #[extension_type] state: TrainState<Self>,
        batch: FloatTensor<Self>,
        spec: StepSpec,
    ) -> TrainOutcome<Self>;

    /// The loss and gradients one step of [`NrcFusedOps::fused_train_steps`] would feed to
    /// Adam (no update): how the backends' kernels are checked against each other.
    fn fused_gradients(
        #[extension_type] state: TrainState<Self>,
        batch: FloatTensor<Self>,
        spec: StepSpec,
    ) -> GradientOutcome<Self>;

    /// The inference weights at step `step`: bias-corrected EMA (the table's from its EMA gap
    /// based at `ema_base`, or from the raw EMA where that is `None`) or, with `ema = None`, the
    /// weights. Reads the state only.
    fn inference_weights(
        #[extension_type] state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        ema: Option<f32>,
        step: u32,
        ema_base: Option<u32>,
    ) -> InferenceWeights<Self>;

    /// Converts the table's EMA between the raw form (hosts, snapshots) and the gap form of the
    /// fused step.
    fn convert_ema(
        #[extension_type] state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        conversion: EmaConversion,
    ) -> TrainState<Self>;

    /// Fused inference on packed query rows `[N, 17]` → radiance `[N, 3]`.
    fn fused_infer(
        grid: FloatTensor<Self>,
        mlp: FloatTensor<Self>,
        queries: FloatTensor<Self>,
        layout: Arc<ModelLayout>,
        clock: Arc<InferClock>,
    ) -> FloatTensor<Self>;
}

// ---------------------------------------------------------------------------------------------
// Flex implementations.

/// Contiguous f32 view of a Flex tensor (copies only when strided or of another dtype).
fn flex_f32(t: &FlexTensor) -> Cow<'_, [f32]> {
    if t.dtype() == DType::F32
        && let Some(s) = t.as_slice::<f32>()
    {
        return Cow::Borrowed(s);
    }
    Cow::Owned(
        t.clone()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 data"),
    )
}

/// A uniquely owned, contiguous f32 Flex tensor whose storage can be mutated in place.
fn flex_owned_f32(t: FlexTensor) -> FlexTensor {
    if t.dtype() == DType::F32 && t.is_contiguous() && t.layout().start_offset() == 0 {
        t
    } else {
        FlexTensor::from_data(t.into_data().convert::<f32>())
    }
}

fn flex_mut_f32(t: &mut FlexTensor) -> &mut [f32] {
    let n = t.shape().num_elements();
    &mut t.storage_mut::<f32>()[..n]
}

fn flex_from(values: Vec<f32>, shape: &[usize]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape.to_vec()))
}

impl MlpOps for Flex {
    fn mlp_forward(
        weights: FlexTensor,
        input: FlexTensor,
        layers: Arc<Vec<LayerShape>>,
    ) -> FlexTensor {
        let k = layers[0].inputs;
        let x = flex_f32(&input);
        let n = x.len() / k;
        let prepared = PreparedMlp::new(&layers, &flex_f32(&weights), MlpPrecision::F32);
        let mut out = vec![0f32; n * 3];
        out.par_chunks_mut(TILE * 3)
            .zip(x.par_chunks(TILE * k))
            .for_each_init(
                || TileScratch::new(k, prepared.hidden()),
                |s, (o, xt)| {
                    let m = xt.len() / k;
                    s.x[..xt.len()].copy_from_slice(xt);
                    forward_tile(&prepared, m, s);
                    for i in 0..m {
                        o[i * 3..i * 3 + 3].copy_from_slice(&s.out[i * OUT_PAD..i * OUT_PAD + 3]);
                    }
                },
            );
        flex_from(out, &[n, 3])
    }

    fn mlp_backward(
        weights: FlexTensor,
        input: FlexTensor,
        grad_out: FlexTensor,
        layers: Arc<Vec<LayerShape>>,
        needs: Needs,
    ) -> (FlexTensor, FlexTensor) {
        let k = layers[0].inputs;
        let x = flex_f32(&input);
        let dy = flex_f32(&grad_out);
        let n = x.len() / k;
        let w = flex_f32(&weights);
        let prepared = PreparedMlp::new(&layers, &w, MlpPrecision::F32);
        let mut dx = vec![0f32; if needs.input { n * k } else { k }];
        let dx_chunk = if needs.input { TILE * k } else { k };
        let grad = x
            .par_chunks(TILE * k)
            .zip(dy.par_chunks(TILE * 3))
            .zip(dx.par_chunks_mut(dx_chunk))
            .fold(
                || {
                    (
                        MlpGrad::zeros(&prepared),
                        TileScratch::new(k, prepared.hidden()),
                    )
                },
                |(mut g, mut s), ((xt, dyt), dxt)| {
                    let m = xt.len() / k;
                    s.x[..xt.len()].copy_from_slice(xt);
                    forward_tile(&prepared, m, &mut s);
                    for i in 0..m {
                        let d = &mut s.dout[i * OUT_PAD..(i + 1) * OUT_PAD];
                        d[..3].copy_from_slice(&dyt[i * 3..i * 3 + 3]);
                        d[3..].fill(0.0);
                    }
                    let mut write =
                        |i: usize, row: &[f32]| dxt[i * k..(i + 1) * k].copy_from_slice(row);
                    let dx = needs.input.then_some((0, k, &mut write as _));
                    backward_tile(&prepared, m, &mut s, &mut g, dx);
                    (g, s)
                },
            )
            .map(|(g, _)| g)
            .reduce(
                || MlpGrad::zeros(&prepared),
                |mut a, b| {
                    a.add(&b);
                    a
                },
            );
        let gw = if needs.params {
            let mut flat = vec![0f32; w.len()];
            grad.write_flat(&layers, &mut flat);
            flex_from(flat, &[w.len()])
        } else {
            flex_from(Vec::new(), &[0])
        };
        let gx = if needs.input {
            flex_from(dx, &[n, k])
        } else {
            flex_from(Vec::new(), &[0])
        };
        (gw, gx)
    }
}

/// Unpacks a Flex training state into mutable slices (`[records, mlp, mlp_m, mlp_v, mlp_ema]`)
/// and the half-precision weights tensor, runs `f`, and packs it again.
fn with_flex_state<R>(
    state: TrainState<Flex>,
    f: impl FnOnce(&mut [&mut [f32]; 5], &mut FlexTensor) -> R,
) -> (TrainState<Flex>, R) {
    let TrainState {
        grid,
        grid_m,
        grid_v,
        grid_ema,
        mut grid_half,
        mlp,
        mlp_m,
        mlp_v,
        mlp_ema,
    } = state;
    let mut tensors = [grid, mlp, mlp_m, mlp_v, mlp_ema].map(flex_owned_f32);
    let r = {
        let [a, c, d, e, g] = &mut tensors;
        let mut slices = [
            flex_mut_f32(a),
            flex_mut_f32(c),
            flex_mut_f32(d),
            flex_mut_f32(e),
            flex_mut_f32(g),
        ];
        f(&mut slices, &mut grid_half)
    };
    let [grid, mlp, mlp_m, mlp_v, mlp_ema] = tensors;
    (
        TrainState {
            grid,
            grid_m,
            grid_v,
            grid_ema,
            grid_half,
            mlp,
            mlp_m,
            mlp_v,
            mlp_ema,
        },
        r,
    )
}

/// The half-precision weights of the records (`f` features per entry) in `t`: `t` itself when it
/// already holds them (every update keeps it equal), else built from the records.
fn flex_half_weights<'a>(t: &'a mut FlexTensor, records: &[f32], f: usize) -> &'a mut [f16] {
    let n = records.len() / cpu::optim::RECORD;
    if t.dtype() != DType::F16 || t.shape().num_elements() != n {
        *t = FlexTensor::from_data(TensorData::new(cpu::optim::half_weights(f, records), [n]));
    }
    &mut t.storage_mut::<f16>()[..n]
}

/// The inference table, as `T`, of the records `records` (EMA gap based at `ema_base`, or the
/// raw EMA where that is `None`): the bias-corrected EMA at `step` (or the weights without
/// EMA), level by level in parallel.
fn materialize_table<T: cpu::optim::TableValue>(
    layout: &ModelLayout,
    records: &[f32],
    ema: Option<f32>,
    step: u32,
    ema_base: Option<u32>,
) -> Vec<T> {
    let n = layout.grid_params;
    let mut g: Vec<T> = cpu::huge::huge_empty(n);
    if let Some((hg, _)) = layout.encoding.grid() {
        let f = hg.features();
        assert_eq!(hg.total_entries * f, n, "the levels partition the table");
        let rec = cpu::optim::RECORD * f;
        let outs = cpu::grid::split_levels(hg, f, &mut g.spare_capacity_mut()[..n]);
        outs.into_par_iter().enumerate().for_each(|(l, o)| {
            let level = &hg.levels[l];
            let (a, b) = (level.offset, level.offset + level.entries as usize);
            cpu::optim::materialize_grid_into(
                ema,
                step,
                ema_base,
                f,
                &records[a * rec..b * rec],
                o,
            );
        });
    } else {
        assert_eq!(n, 0, "a table without a hash grid");
    }
    // SAFETY: the levels partition the `n` elements and `materialize_grid_into` wrote each of
    // them (checked above and inside).
    unsafe { g.set_len(n) };
    g
}

impl NrcFusedOps for Flex {
    fn fused_train_steps(
        state: TrainState<Self>,
        batch: FlexTensor,
        spec: StepSpec,
    ) -> TrainOutcome<Self> {
        let rows = flex_f32(&batch);
        let half_features = spec.layout.encoding.grid().and_then(|(hg, _)| {
            (hg.params.training_precision == TablePrecision::F16).then_some(hg.features())
        });
        let features = spec.layout.encoding.grid().map(|(hg, _)| hg.features());
        let mut ema_base = spec.ema_base;
        let (state, losses) = with_flex_state(state, |s, half| {
            let [records, mlp, mlp_m, mlp_v, mlp_ema] = s;
            let mut half = half_features.map(|f| flex_half_weights(half, records, f));
            let mut losses = Vec::with_capacity(spec.steps as usize);
            for k in 1..=spec.steps {
                let done = spec.first_step + k - 1;
                if let (Some(alpha), Some(f)) = (spec.ema, features)
                    && done - ema_base >= cpu::optim::ema_rebase_interval(alpha)
                {
                    cpu::optim::rebase_ema_gap(alpha, done - ema_base, f, records);
                    ema_base = done;
                }
                let c = cpu::optim::StepConstants::new(spec.adam, spec.ema, done + 1, ema_base);
                let grid_state = (spec.layout.grid_params > 0).then_some(cpu::train::GridState {
                    records,
                    half: half.as_deref_mut(),
                });
                let mlp_state = cpu::train::GroupState {
                    w: mlp,
                    m: mlp_m,
                    v: mlp_v,
                    ema: mlp_ema,
                };
                losses.push(cpu::train::train_step(
                    &spec.layout,
                    grid_state,
                    mlp_state,
                    &rows,
                    &c,
                    spec.loss,
                    &spec.clock,
                ));
            }
            losses
        });
        let steps = losses.len();
        TrainOutcome {
            state,
            losses: FlexTensor::from_data(TensorData::new(losses, [steps])),
            ema_base,
        }
    }

    fn fused_gradients(
        state: TrainState<Self>,
        batch: FlexTensor,
        spec: StepSpec,
    ) -> GradientOutcome<Self> {
        let rows = flex_f32(&batch);
        let records = flex_f32(&state.grid);
        let grid_w = match spec.layout.encoding.grid() {
            Some((hg, _)) => {
                let [w, ..] = cpu::optim::unpack_records(hg.features(), &records);
                w
            }
            None => Vec::new(),
        };
        let (loss, grid, mlp) = cpu::train::gradients(
            &spec.layout,
            &grid_w,
            &flex_f32(&state.mlp),
            &rows,
            spec.loss,
        );
        GradientOutcome {
            state,
            loss,
            grid,
            mlp,
        }
    }

    fn inference_weights(
        state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        ema: Option<f32>,
        step: u32,
        ema_base: Option<u32>,
    ) -> InferenceWeights<Self> {
        let records = flex_f32(&state.grid);
        let mlp = flex_f32(&state.mlp);
        let half = layout
            .encoding
            .grid()
            .is_some_and(|(hg, _)| hg.params.inference_precision == TablePrecision::F16);
        let grid = if half {
            let g = materialize_table::<f16>(&layout, &records, ema, step, ema_base);
            let n = g.len();
            FlexTensor::from_data(TensorData::new(g, [n]))
        } else {
            let g = materialize_table::<f32>(&layout, &records, ema, step, ema_base);
            let n = g.len();
            flex_from(g, &[n])
        };
        let m = match ema {
            Some(alpha) => {
                let mut m = vec![0f32; mlp.len()];
                cpu::optim::materialize_dense(alpha, step, &mlp, &flex_f32(&state.mlp_ema), &mut m);
                m
            }
            None => mlp.to_vec(),
        };
        let ml = m.len();
        InferenceWeights {
            grid,
            mlp: flex_from(m, &[ml]),
        }
    }

    fn convert_ema(
        state: TrainState<Self>,
        layout: Arc<ModelLayout>,
        conversion: EmaConversion,
    ) -> TrainState<Self> {
        with_flex_state(state, |s, _| {
            if let Some((hg, _)) = layout.encoding.grid() {
                let (f, records) = (hg.features(), &mut *s[0]);
                match conversion {
                    EmaConversion::ToRaw { alpha, shift } => {
                        cpu::optim::ema_raw_from_gap(alpha, shift, f, records)
                    }
                    EmaConversion::ToGap => cpu::optim::ema_gap_from_raw(f, records),
                    EmaConversion::ScaledWeights { scale } => {
                        cpu::optim::ema_scaled_weights(scale, f, records)
                    }
                }
            }
        })
        .0
    }

    fn fused_infer(
        grid: FlexTensor,
        mlp: FlexTensor,
        queries: FlexTensor,
        layout: Arc<ModelLayout>,
        clock: Arc<InferClock>,
    ) -> FlexTensor {
        let rows = flex_f32(&queries);
        let n = rows.len() / crate::batch::QUERY_ROW;
        let mut out = vec![0f32; n * 3];
        let f = layout.encoding.grid().map_or(1, |(g, _)| g.features());
        let floats;
        let table = match grid.as_slice::<f16>() {
            Some(h) => cpu::grid::Table::F16(h),
            None => {
                floats = flex_f32(&grid);
                cpu::grid::Table::F32(&floats, f)
            }
        };
        cpu::infer::infer(&layout, table, &flex_f32(&mlp), &rows, &mut out, &clock);
        flex_from(out, &[n, 3])
    }
}

// ---------------------------------------------------------------------------------------------
// Autodiff: the backward ops become the nodes' backward steps.

impl<B: MlpOps, C: CheckpointStrategy> MlpOps for Autodiff<B, C> {
    fn mlp_forward(
        weights: FloatTensor<Self>,
        input: FloatTensor<Self>,
        layers: Arc<Vec<LayerShape>>,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct MlpBackward;

        impl<B: MlpOps> Backward<B, 2> for MlpBackward {
            type State = (FloatTensor<B>, FloatTensor<B>, Arc<Vec<LayerShape>>);

            fn backward(
                self,
                ops: Ops<Self::State, 2>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let [node_w, node_x] = ops.parents;
                let grad = grads.consume::<B>(&ops.node);
                let (w, x, layers) = ops.state;
                let needs = Needs {
                    params: node_w.is_some(),
                    input: node_x.is_some(),
                };
                let (gw, gx) = B::mlp_backward(w, x, grad, layers, needs);
                if let Some(node) = node_w {
                    grads.register::<B>(node.id, gw);
                }
                if let Some(node) = node_x {
                    grads.register::<B>(node.id, gx);
                }
            }
        }

        match MlpBackward
            .prepare::<C>([weights.node(), input.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let w = weights.primitive().clone();
                let x = input.primitive().clone();
                let out = B::mlp_forward(w.clone(), x.clone(), layers.clone());
                prep.finish((w, x, layers), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::mlp_forward(
                weights.into_primitive(),
                input.into_primitive(),
                layers,
            )),
        }
    }

    fn mlp_backward(
        weights: FloatTensor<Self>,
        input: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        layers: Arc<Vec<LayerShape>>,
        needs: Needs,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (gw, gx) = B::mlp_backward(
            weights.into_primitive(),
            input.into_primitive(),
            grad_out.into_primitive(),
            layers,
            needs,
        );
        (
            <Self as AutodiffBackend>::from_inner(gw),
            <Self as AutodiffBackend>::from_inner(gx),
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Tensor-level entry points.

/// The fused MLP on tensors: raw network outputs `[N, 3]` of `input` `[N, in]` with the MLP
/// parameter group `weights` `[W]`; differentiable in both on an autodiff device.
pub fn mlp(weights: Tensor<1>, input: Tensor<2>, layers: &Arc<Vec<LayerShape>>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as MlpOps>::mlp_forward(
        weights.into_dispatch(),
        input.into_dispatch(),
        layers.clone(),
    ))
}
