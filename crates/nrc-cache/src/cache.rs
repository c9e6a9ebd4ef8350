//! [`RadianceCache`]: the public face of the crate — train on [`TrainingBatch`]es, answer
//! [`CacheQuery`]s with the EMA weights, save and load snapshots.

use std::path::Path;
use std::sync::{Arc, Mutex};

use burn::backend::Dispatch;
use burn::tensor::{Device, Tensor, TensorData};

use crate::batch::{QUERY_ROW, TRAIN_ROW, pack_queries, pack_training};
use crate::config::{AdamParams, CacheConfig, LrDecay, MlpPrecision, SceneBox, Sizing};
use crate::cpu::train::LossSettings;
use crate::device::{CacheDevice, ComputePath};
use crate::error::CacheError;
use crate::model::ModelLayout;
use crate::ops::{EmaConversion, NrcFusedOps, StepSpec};
use crate::profile::{InferClock, InferProfile, TrainClock, TrainProfile};
use crate::record::{CacheQuery, TrainingBatch};
use crate::snapshot;
use crate::state::{HostState, TensorState, tensor_vec, vec_tensor};

/// What a call to [`RadianceCache::train`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainStats {
    /// Mean loss (over samples and channels) of the last step, measured before its update;
    /// 0 when no step ran.
    pub loss: f32,
    /// Mean loss of the first step of this call.
    pub first_loss: f32,
    /// Steps taken by this call (0 when no sample survived the checks).
    pub steps: u32,
    /// Steps taken since the cache was created.
    pub total_steps: u32,
    /// Samples trained on.
    pub used: usize,
    /// Samples dropped: a NaN or infinite query field, target or weight.
    pub dropped_nonfinite: usize,
    /// Samples dropped: a negative or absurdly large target, or a negative weight.
    pub dropped_absurd: usize,
    /// Where the call's time went.
    pub profile: TrainProfile,
}

/// Training steps queued by [`RadianceCache::train_submit`]: their statistics, the losses still
/// on the device.
#[derive(Debug)]
#[must_use = "the steps' losses are read by `wait`"]
pub struct PendingTrain {
    stats: TrainStats,
    losses: Option<Tensor<1>>,
}

impl PendingTrain {
    /// Statistics complete already (no step queued, or a cache that trains synchronously).
    pub fn ready(stats: TrainStats) -> Self {
        Self {
            stats,
            losses: None,
        }
    }

    /// Waits for the steps and returns their statistics with the losses.
    pub fn wait(self) -> TrainStats {
        let mut stats = self.stats;
        if let Some(t) = self.losses {
            let losses = t
                .into_data()
                .convert::<f64>()
                .try_to_vec::<f64>()
                .expect("losses");
            stats.first_loss = losses.first().copied().unwrap_or(0.0) as f32;
            stats.loss = losses.last().copied().unwrap_or(0.0) as f32;
        }
        stats
    }
}

/// Inference weights, valid for one step count.
#[derive(Clone, Debug)]
struct InferenceWeights {
    step: u32,
    grid: Tensor<1>,
    mlp: Tensor<1>,
}

/// The neural radiance cache.
#[derive(Debug)]
pub struct RadianceCache {
    config: CacheConfig,
    layout: Arc<ModelLayout>,
    scene_box: SceneBox,
    /// Content hash of the scene (hex, given by the caller), stored in snapshots.
    scene_content: Option<String>,
    device: CacheDevice,
    burn_device: Device,
    path: ComputePath,
    /// Adam's parameters, the learning rate undecayed.
    adam: AdamParams,
    ema: Option<f32>,
    /// The learning rate's decay, and the step it counts from (0, or the last
    /// [`RadianceCache::restart_learning_rate`]; kept by snapshots and path changes).
    lr_decay: Option<LrDecay>,
    lr_start: u32,
    step: u32,
    /// On the fused path with EMA, the base step of the table's EMA gap in the records (see
    /// [`crate::cpu::optim`]); `None` while the records hold the raw EMA at the current step
    /// (after loading, and after a download until the next training step), and off that path.
    ema_base: Option<u32>,
    state: Option<TensorState>,
    inference: Mutex<Option<InferenceWeights>>,
    /// Inference from the training weights instead of their average (see
    /// [`RadianceCache::set_follow`]).
    follow: bool,
}

impl RadianceCache {
    /// A freshly initialised cache for `config` on `device` (its default [`ComputePath`]),
    /// positions normalised to the unit box.
    pub fn new(config: CacheConfig, device: CacheDevice) -> Result<Self, CacheError> {
        Self::with_path(config, SceneBox::default(), device, device.default_path())
    }

    /// A cache sized for a scene (see [`CacheConfig::sized_for_scene`]): the finest resolution
    /// and table size follow from the box and the smallest feature to resolve.
    pub fn for_scene_extent(
        config: &CacheConfig,
        scene_box: SceneBox,
        min_feature_size: f32,
        device: CacheDevice,
    ) -> Result<(Self, Sizing), CacheError> {
        let (config, sizing) = config.sized_for_scene(&scene_box, min_feature_size)?;
        Ok((
            Self::with_path(config, scene_box, device, device.default_path())?,
            sizing,
        ))
    }

    /// A freshly initialised cache computing along `path`.
    pub fn with_path(
        config: CacheConfig,
        scene_box: SceneBox,
        device: CacheDevice,
        path: ComputePath,
    ) -> Result<Self, CacheError> {
        config.validate()?;
        let layout = ModelLayout::new(&config);
        let (grid, mlp) = layout.init_params(config.seed);
        let host = HostState {
            grid_m: vec![0.0; grid.len()],
            grid_v: vec![0.0; grid.len()],
            grid_ema: vec![0.0; grid.len()],
            mlp_m: vec![0.0; mlp.len()],
            mlp_v: vec![0.0; mlp.len()],
            mlp_ema: vec![0.0; mlp.len()],
            grid,
            mlp,
        };
        Self::from_host(config, scene_box, device, path, host, 0)
    }

    pub(crate) fn from_host(
        config: CacheConfig,
        scene_box: SceneBox,
        device: CacheDevice,
        path: ComputePath,
        host: HostState,
        step: u32,
    ) -> Result<Self, CacheError> {
        let layout = Arc::new(ModelLayout::new(&config));
        let burn_device = device.burn_device()?;
        if device == CacheDevice::Wgpu && path == ComputePath::Fused {
            crate::gpu::fused::check(&burn_device, &layout).map_err(CacheError::Device)?;
        }
        if path == ComputePath::CustomOps
            && layout.encoding.grid().is_some()
            && crate::gpu::fused::compiles_spirv(&burn_device)
        {
            return Err(CacheError::Device(
                "the custom-ops path's hash-grid kernels are WGSL source, which a SPIR-V \
                 build (cargo feature `vulkan`) cannot load on this adapter: use the fused path"
                    .into(),
            ));
        }
        let (adam, ema) = config.optimizer.resolve();
        let lr_decay = config.optimizer.lr_decay();
        // The fused CPU step keeps the table as per-entry records; the GPU's as four arrays.
        let packed = (path == ComputePath::Fused && device == CacheDevice::Cpu)
            .then(|| layout.encoding.grid().map(|(g, _)| g.features()))
            .flatten();
        let state = TensorState::from_host(host, packed, &burn_device);
        Ok(Self {
            config,
            layout,
            scene_box,
            scene_content: None,
            device,
            burn_device,
            path,
            adam,
            ema,
            lr_decay,
            lr_start: 0,
            step,
            ema_base: None,
            state: Some(state),
            inference: Mutex::new(None),
            follow: false,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CacheConfig {
        &self.config
    }

    /// The model layout derived from the configuration.
    pub fn layout(&self) -> &ModelLayout {
        &self.layout
    }

    /// The scene box positions are normalised to.
    pub fn scene_box(&self) -> SceneBox {
        self.scene_box
    }

    /// The content hash of the scene the cache is trained on (hex, as given to
    /// [`RadianceCache::set_scene_content`] or read from a snapshot); `None` when unknown.
    pub fn scene_content(&self) -> Option<&str> {
        self.scene_content.as_deref()
    }

    /// Sets the scene's content hash (a hex digest computed by the caller: the cache knows
    /// nothing of scenes), stored in snapshots; see [`snapshot::check_scene`].
    pub fn set_scene_content(&mut self, content: Option<String>) {
        self.scene_content = content;
    }

    /// The compute device.
    pub fn device(&self) -> CacheDevice {
        self.device
    }

    /// How training and inference are computed.
    pub fn path(&self) -> ComputePath {
        self.path
    }

    /// The arithmetic of the MLP's products as this cache computes them: `"bf16"` on the fused
    /// CPU path with `"precision": "bf16"` (and an even input width), `"f16"` on the fused wgpu
    /// path with `"precision": "f16"` on an adapter with `shader-f16`, else `"f32"`.
    pub fn mlp_arithmetic(&self) -> &'static str {
        if self.path != ComputePath::Fused {
            return "f32";
        }
        match (self.device, self.layout.mlp_precision) {
            (CacheDevice::Cpu, MlpPrecision::Bf16)
                if self.layout.layers[0].inputs.is_multiple_of(2) =>
            {
                "bf16"
            }
            (CacheDevice::Wgpu, MlpPrecision::F16)
                if crate::gpu::fused::client(&self.burn_device)
                    .is_some_and(|c| crate::gpu::fused::half_mlp(&c, &self.layout)) =>
            {
                "f16"
            }
            _ => "f32",
        }
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u32 {
        self.step
    }

    /// Trainable parameters.
    pub fn param_count(&self) -> usize {
        self.layout.param_count()
    }

    /// Bytes of training state (see [`ModelLayout::training_memory_bytes`]).
    pub fn memory_bytes(&self) -> usize {
        self.layout.training_memory_bytes()
    }

    /// Adam's learning rate, before its decay (the configured one).
    pub fn learning_rate(&self) -> f32 {
        self.adam.learning_rate
    }

    /// The learning rate the next step takes: [`Self::learning_rate`] decayed by the
    /// configuration's `ExponentialDecay`, if any.
    pub fn current_learning_rate(&self) -> f32 {
        self.scheduled_adam().learning_rate
    }

    /// Adam's parameters for the next step, the learning rate decayed.
    fn scheduled_adam(&self) -> AdamParams {
        let factor = self
            .lr_decay
            .map_or(1.0, |d| d.factor(self.step - self.lr_start));
        AdamParams {
            learning_rate: self.adam.learning_rate * factor,
            ..self.adam
        }
    }

    /// Restarts the learning rate's decay: it counts its steps from the next one again (which
    /// takes the full rate unless `decay_start` is 0). The online loop calls this when a change
    /// in the scene is confirmed ([`crate::Cache::confirm_change`]), so that the cache learns
    /// the change at the full rate and settles again; no effect without a decay.
    pub fn restart_learning_rate(&mut self) {
        self.lr_start = self.step;
    }

    /// Sets Adam's learning rate from the next step on (the config, and so the snapshot's
    /// description, follow); an error outside (0, 1], the range a config accepts.
    pub fn set_learning_rate(&mut self, lr: f32) -> Result<(), CacheError> {
        if !(lr.is_finite() && lr > 0.0 && lr <= 1.0) {
            return Err(CacheError::Config {
                field: "optimizer.learning_rate".into(),
                message: format!("must be in (0, 1], got {lr}"),
            });
        }
        self.config.optimizer.set_learning_rate(lr);
        self.adam.learning_rate = lr;
        Ok(())
    }

    /// A human-readable summary: encoding, network, sizes, device and path.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        let enc = &self.layout.encoding;
        let parts: Vec<String> = enc
            .parts
            .iter()
            .map(|p| match &p.kind {
                crate::encoding::EncodingKind::HashGrid(g) => format!(
                    "HashGrid(L={}, F={}, log2T={}, N_min={}, b={:.4}, finest={}, {} dense levels)",
                    g.levels.len(),
                    g.features(),
                    g.params.log2_hashmap_size,
                    g.params.base_resolution,
                    g.params.per_level_scale,
                    g.finest_resolution(),
                    g.levels.iter().filter(|l| l.dense).count()
                ),
                crate::encoding::EncodingKind::OneBlob { bins, wrap } => format!(
                    "OneBlob({}×{bins}{})",
                    p.in_dims,
                    if *wrap { ", wrapped" } else { "" }
                ),
                crate::encoding::EncodingKind::TriangleWave { frequencies } => {
                    format!("TriangleWave({}×{frequencies})", p.in_dims)
                }
                crate::encoding::EncodingKind::Identity { .. } => {
                    format!("Identity({})", p.in_dims)
                }
            })
            .collect();
        s.push_str(&format!(
            "encoding: {} → {} inputs ({} padded)\n",
            parts.join(" + "),
            enc.unpadded_dims,
            enc.padded_dims
        ));
        let products = mlp_products(
            self.device,
            self.layout.mlp_precision,
            crate::cpu::bf16::PairKernel::best(),
            self.mlp_arithmetic() == "f16",
        );
        s.push_str(&format!(
            "network: {} hidden layers × 64, ReLU, no biases, {products}, output {:?} × (diffuse + specular)\n",
            self.layout.layers.len() - 1,
            self.layout.output_activation
        ));
        s.push_str(&format!(
            "parameters: {} (hash table {}, MLP {}), memory {:.1} MiB (training state and inference copy)\n",
            self.param_count(),
            self.layout.grid_params,
            self.layout.mlp_params(),
            self.memory_bytes() as f64 / (1024.0 * 1024.0)
        ));
        let decay = self.lr_decay.map_or(String::new(), |d| {
            format!(
                " × {} every {} steps from step {} to {} (floor × {:.3}, restarted by a confirmed change; \
                 now {:.2e})",
                d.base,
                d.interval,
                d.start,
                d.end,
                d.floor(),
                self.current_learning_rate()
            )
        });
        s.push_str(&format!(
            "optimizer: Adam lr {}{decay} β1 {} β2 {} ε {:e} L2 {}, EMA {}\n",
            self.adam.learning_rate,
            self.adam.beta1,
            self.adam.beta2,
            self.adam.epsilon,
            self.adam.l2_reg,
            self.ema.map_or("off".into(), |a| format!("α {a}"))
        ));
        let loss = &self.config.loss;
        let returned = loss.return_clipped.as_ref().map_or(String::new(), |r| {
            format!(
                "; the online loop returns the clipped light per bin of a {g}³ grid × 6 normals over {} frames, gain ≤ {}, surfaces of roughness ≥ {} or without a specular part",
                r.frames,
                r.max_gain,
                r.min_roughness,
                g = r.grid
            )
        });
        s.push_str(&format!(
            "loss: {:?} ε {} (Huber beyond a relative residual of {}{returned}), targets above {:e} dropped\n",
            loss.otype, loss.epsilon, loss.max_relative_error, loss.max_target
        ));
        s.push_str(&format!(
            "device: {} ({} path), step {}",
            self.device, self.path, self.step
        ));
        if self.device == CacheDevice::Wgpu && self.path == ComputePath::Fused {
            s.push_str(&format!(
                "; {}",
                crate::gpu::fused::describe(&self.burn_device, &self.layout)
            ));
        }
        s
    }

    /// Runs `steps` optimisation steps on the batch (each over all of its usable samples).
    /// Bad samples are dropped and counted, never trained on.
    pub fn train(&mut self, batch: &TrainingBatch, steps: u32) -> Result<TrainStats, CacheError> {
        Ok(self.train_submit(batch, steps)?.wait())
    }

    /// [`Self::train`] without waiting for the steps where the device runs them asynchronously
    /// (wgpu): the steps are queued, and [`PendingTrain::wait`] reads their losses. Work queued
    /// on the cache afterwards (inference) runs after them; the CPU is free meanwhile. On the
    /// CPU the steps have run when this returns.
    pub fn train_submit(
        &mut self,
        batch: &TrainingBatch,
        steps: u32,
    ) -> Result<PendingTrain, CacheError> {
        let t_pack = std::time::Instant::now();
        let packed = pack_training(batch, self.config.loss.max_target)?;
        self.check_batch(packed.len)?;
        let mut stats = TrainStats {
            used: packed.len,
            dropped_nonfinite: packed.dropped_nonfinite,
            dropped_absurd: packed.dropped_absurd,
            total_steps: self.step,
            ..TrainStats::default()
        };
        if packed.len == 0 || steps == 0 {
            return Ok(PendingTrain::ready(stats));
        }
        // Drop cached inference weights first: they may share storage with the weights, which
        // would make the in-place update copy them.
        *self.inference.lock().expect("inference lock") = None;
        let rows = Tensor::<2>::from_data(
            TensorData::new(packed.rows, [packed.len, TRAIN_ROW]),
            &self.burn_device,
        );
        let clock = Arc::new(TrainClock::default());
        clock.packing.since(t_pack);
        if self.path == ComputePath::Fused && self.ema.is_some() && self.ema_base.is_none() {
            // The fused step keeps the table's EMA as a gap, based here at the current step.
            self.convert_ema(EmaConversion::ToGap);
            self.ema_base = Some(self.step);
        }
        // The decayed rate of this call's first step (a call is one step in the online loop).
        let adam = self.scheduled_adam();
        let state = self.state.take().expect("state present between calls");
        let state_packed = state.packed;
        let losses: Tensor<1> = match self.path {
            ComputePath::Fused => {
                let spec = StepSpec {
                    adam,
                    ..self.step_spec(steps, clock.clone())
                };
                let out = <Dispatch as NrcFusedOps>::fused_train_steps(
                    state.into_dispatch(),
                    rows.into_dispatch(),
                    spec,
                );
                self.state = Some(TensorState::from_dispatch(out.state, state_packed));
                self.ema_base = self.ema.map(|_| out.ema_base);
                Tensor::from_dispatch(out.losses)
            }
            ComputePath::CustomOps | ComputePath::Unfused => {
                let mut state = state;
                let mut losses = Vec::with_capacity(steps as usize);
                for k in 1..=steps {
                    losses.push(crate::tensor_path::train_step_tensor(
                        &self.layout,
                        self.path,
                        &mut state,
                        &rows,
                        adam,
                        self.ema,
                        (
                            self.config.loss.epsilon,
                            self.config.loss.max_relative_error,
                        ),
                        self.step + k,
                    ));
                }
                self.state = Some(state);
                Tensor::cat(losses, 0)
            }
        };
        self.step += steps;
        stats.steps = steps;
        stats.total_steps = self.step;
        stats.profile = clock.profile();
        Ok(PendingTrain {
            stats,
            losses: Some(losses),
        })
    }

    /// Refuses a batch the fused GPU step cannot index (an error, not a panic in a kernel).
    fn check_batch(&self, rows: usize) -> Result<(), CacheError> {
        if self.device == CacheDevice::Wgpu && self.path == ComputePath::Fused {
            crate::gpu::fused::check_batch(&self.layout, rows).map_err(CacheError::Input)?;
        }
        Ok(())
    }

    /// The constants of `steps` fused steps from the current one.
    fn step_spec(&self, steps: u32, clock: Arc<TrainClock>) -> StepSpec {
        StepSpec {
            layout: self.layout.clone(),
            adam: self.adam,
            ema: self.ema,
            loss: LossSettings {
                activation: self.layout.output_activation,
                epsilon: self.config.loss.epsilon,
                max_relative_error: self.config.loss.max_relative_error,
            },
            first_step: self.step,
            ema_base: self.ema_base.unwrap_or(self.step),
            steps,
            clock,
        }
    }

    /// The mean loss and the gradients (the table's dense, the MLP's) that one training step on
    /// `batch` would feed to Adam, without updating anything: how the fused kernels of the CPU
    /// and of the GPU are checked against each other. Fused path only; bad samples are dropped
    /// as [`Self::train`] drops them.
    pub fn gradients(
        &mut self,
        batch: &TrainingBatch,
    ) -> Result<(f64, Vec<f32>, Vec<f32>), CacheError> {
        if self.path != ComputePath::Fused {
            return Err(CacheError::Device(format!(
                "gradients are read on the fused path only, not the {} path",
                self.path
            )));
        }
        let packed = pack_training(batch, self.config.loss.max_target)?;
        self.check_batch(packed.len)?;
        let rows = Tensor::<2>::from_data(
            TensorData::new(packed.rows, [packed.len, TRAIN_ROW]),
            &self.burn_device,
        );
        let spec = self.step_spec(1, Arc::new(TrainClock::default()));
        let state = self.state.take().expect("state present between calls");
        let state_packed = state.packed;
        let out = <Dispatch as NrcFusedOps>::fused_gradients(
            state.into_dispatch(),
            rows.into_dispatch(),
            spec,
        );
        self.state = Some(TensorState::from_dispatch(out.state, state_packed));
        Ok((out.loss, out.grid, out.mlp))
    }

    /// Outgoing radiance (emission excluded) at each query, from the EMA weights.
    pub fn infer(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        self.infer_profiled(queries).0
    }

    /// [`Self::infer`], with where the call's time went.
    pub fn infer_profiled(&self, queries: &[CacheQuery]) -> (Vec<[f32; 3]>, InferProfile) {
        if queries.is_empty() {
            return (Vec::new(), InferProfile::default());
        }
        let clock = Arc::new(InferClock::default());
        let t_call = std::time::Instant::now();
        let rows = Tensor::<2>::from_data(
            TensorData::new(pack_queries(queries), [queries.len(), QUERY_ROW]),
            &self.burn_device,
        );
        let (grid, mlp) = self.inference_weights();
        let out = match self.path {
            ComputePath::Fused => {
                Tensor::<2>::from_dispatch(<Dispatch as NrcFusedOps>::fused_infer(
                    grid.into_dispatch(),
                    mlp.into_dispatch(),
                    rows.into_dispatch(),
                    self.layout.clone(),
                    clock.clone(),
                ))
            }
            _ => crate::tensor_path::infer_tensor(
                &self.layout,
                self.path,
                (self.layout.grid_params > 0).then_some(grid),
                mlp,
                rows,
            ),
        };
        let flat: Vec<f32> = out
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 output");
        let out = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        clock.call.since(t_call);
        (out, clock.profile())
    }

    /// The bias-corrected EMA weights (the weights without EMA), computed once per step count.
    pub fn inference_weights(&self) -> (Tensor<1>, Tensor<1>) {
        let mut guard = self.inference.lock().expect("inference lock");
        if let Some(w) = guard.as_ref().filter(|w| w.step == self.step) {
            return (w.grid.clone(), w.mlp.clone());
        }
        let state = self.state.as_ref().expect("state present");
        let ema = self.ema.filter(|_| !self.follow);
        let (grid, mlp) = match (self.path, ema) {
            (ComputePath::Fused, ema) => {
                // The op takes the state by value; the clones share storage and the kernel only
                // reads it.
                let w = <Dispatch as NrcFusedOps>::inference_weights(
                    state.clone().into_dispatch(),
                    self.layout.clone(),
                    ema,
                    self.step,
                    self.ema_base,
                );
                (Tensor::from_dispatch(w.grid), Tensor::from_dispatch(w.mlp))
            }
            (_, None) => (state.grid.clone(), state.mlp.clone()),
            (_, Some(alpha)) => {
                if self.step == 0 {
                    (state.grid.clone(), state.mlp.clone())
                } else {
                    let inv = 1.0 / (1.0 - alpha.powi(self.step.min(i32::MAX as u32) as i32));
                    (
                        state.grid_ema.clone().mul_scalar(inv),
                        state.mlp_ema.clone().mul_scalar(inv),
                    )
                }
            }
        };
        *guard = Some(InferenceWeights {
            step: self.step,
            grid: grid.clone(),
            mlp: mlp.clone(),
        });
        (grid, mlp)
    }

    /// [`Self::inference_weights`] on the host as f32 (a half-precision table widened): the
    /// values inference reads (hash table, MLP).
    pub fn inference_weights_host(&self) -> (Vec<f32>, Vec<f32>) {
        let (grid, mlp) = self.inference_weights();
        (tensor_vec(grid), tensor_vec(mlp))
    }

    /// Whether inference reads the training weights instead of their average.
    pub fn follows(&self) -> bool {
        self.follow
    }

    /// Switches inference between the weights' EMA (the default: the average of the recent
    /// steps, calmer than the last step's weights) and the training weights themselves
    /// ("follow"). After the scene changes the average lags the training weights by about
    /// `1/(1 − α)` steps (100 at the preset's α = 0.99: on `cornell-box-jump` the first-vertex
    /// render has not recovered 60 frames after the light jumps); following, inference sees
    /// each step's progress at once. Leaving follow mode restarts the average at the
    /// weights (the bias-corrected EMA equals them), so that inference goes on from where it
    /// is instead of jumping back to the stale average. No effect without an EMA.
    pub fn set_follow(&mut self, follow: bool) {
        if self.follow == follow || self.ema.is_none() {
            return;
        }
        self.follow = follow;
        *self.inference.lock().expect("inference lock") = None;
        if !follow {
            self.restart_average();
        }
    }

    /// Sets the EMA so that its bias-corrected value `e_t / (1 − α^t)` equals the weights at
    /// the current step `t`: `e_t = (1 − α^t)·w`, or in the fused records' gap form based at
    /// `b` (`e_t = w + α^(t−b)·q`) `q = −α^b·w`.
    fn restart_average(&mut self) {
        let (Some(alpha), t) = (self.ema, self.step) else {
            return;
        };
        if t == 0 {
            return;
        }
        let keep = 1.0 - crate::cpu::optim::decay_pow(alpha, t);
        if self.path == ComputePath::Fused {
            let scale = match self.ema_base {
                Some(b) => -crate::cpu::optim::decay_pow(alpha, b),
                None => keep,
            };
            self.convert_ema(EmaConversion::ScaledWeights { scale });
        } else {
            let s = self.state.as_mut().expect("state present");
            s.grid_ema = s.grid.clone().mul_scalar(keep);
        }
        let s = self.state.as_mut().expect("state present");
        s.mlp_ema = s.mlp.clone().mul_scalar(keep);
        *self.inference.lock().expect("inference lock") = None;
    }

    /// The state on the host with the raw EMA (the form snapshots store).
    ///
    /// On the fused path the records' table EMA gap is turned into the raw EMA first, and stays
    /// so until the next training step, as in a cache loaded from the snapshot: the two hold the
    /// same bits and go on identically.
    pub fn host_state(&mut self) -> HostState {
        self.ema_to_raw();
        self.state.as_ref().expect("state present").to_host()
    }

    /// Puts the fused records' table EMA into raw form (see [`RadianceCache::host_state`]).
    fn ema_to_raw(&mut self) {
        if let (Some(alpha), Some(base)) = (self.ema, self.ema_base.take()) {
            let shift = self.step - base;
            self.convert_ema(EmaConversion::ToRaw { alpha, shift });
            *self.inference.lock().expect("inference lock") = None;
        }
    }

    /// Applies an EMA conversion to the fused state.
    fn convert_ema(&mut self, conversion: EmaConversion) {
        let state = self.state.take().expect("state present");
        let packed = state.packed;
        let s = <Dispatch as NrcFusedOps>::convert_ema(
            state.into_dispatch(),
            self.layout.clone(),
            conversion,
        );
        self.state = Some(TensorState::from_dispatch(s, packed));
    }

    /// The current weights (hash table, MLP), not averaged.
    pub fn weights(&self) -> (Vec<f32>, Vec<f32>) {
        let s = self.state.as_ref().expect("state present");
        let grid = match s.packed {
            Some(f) => crate::cpu::optim::unpack_records(f, &tensor_vec(s.grid.clone()))[0].clone(),
            None => tensor_vec(s.grid.clone()),
        };
        (grid, tensor_vec(s.mlp.clone()))
    }

    /// Replaces the current weights (moments and EMA untouched); lengths must match the layout.
    pub fn set_weights(&mut self, grid: Vec<f32>, mlp: Vec<f32>) -> Result<(), CacheError> {
        if grid.len() != self.layout.grid_params || mlp.len() != self.layout.mlp_params() {
            return Err(CacheError::Input(format!(
                "weights of length {} + {} do not match the layout's {} + {}",
                grid.len(),
                mlp.len(),
                self.layout.grid_params,
                self.layout.mlp_params()
            )));
        }
        *self.inference.lock().expect("inference lock") = None;
        // A gap to the old weights would move the EMA with them.
        self.ema_to_raw();
        let s = self.state.as_mut().expect("state present");
        s.grid = match s.packed {
            Some(f) => {
                let [_, m, v, e] =
                    crate::cpu::optim::unpack_records(f, &tensor_vec(s.grid.clone()));
                vec_tensor(
                    crate::cpu::optim::pack_records(f, &grid, &m, &v, &e),
                    &self.burn_device,
                )
            }
            None => vec_tensor(grid, &self.burn_device),
        };
        // The half-precision copy of the old weights (if any) is stale: the next fused step
        // builds a new one.
        s.grid_half = vec_tensor(Vec::new(), &self.burn_device);
        s.mlp = vec_tensor(mlp, &self.burn_device);
        *self.inference.lock().expect("inference lock") = None;
        Ok(())
    }

    /// Writes a snapshot (see [`crate::snapshot`] for the format), atomically.
    pub fn save(&mut self, path: &Path) -> Result<(), CacheError> {
        if self.follow {
            // Inference reads the weights: the snapshot's average is restarted at them, so
            // that a loaded cache answers as this one does.
            self.restart_average();
        }
        let host = self.host_state();
        snapshot::write(
            path,
            &self.config,
            &self.scene_box,
            self.scene_content.as_deref(),
            (self.step, self.lr_start),
            &host,
        )
    }

    /// Loads a snapshot onto `device` (its default path).
    pub fn load(path: &Path, device: CacheDevice) -> Result<Self, CacheError> {
        Self::from_snapshot(snapshot::read(path)?, device)
    }

    /// A cache on `device` (its default path) holding what a snapshot held.
    fn from_snapshot(s: snapshot::Snapshot, device: CacheDevice) -> Result<Self, CacheError> {
        let mut cache = Self::from_host(
            s.config,
            s.scene_box,
            device,
            device.default_path(),
            s.state,
            s.step,
        )?;
        cache.scene_content = s.scene_content;
        cache.lr_start = s.lr_start;
        Ok(cache)
    }

    /// Loads a snapshot and checks that it was made with `expected` (otherwise an error naming
    /// the first differing section).
    pub fn load_matching(
        path: &Path,
        expected: &CacheConfig,
        device: CacheDevice,
    ) -> Result<Self, CacheError> {
        let s = snapshot::read(path)?;
        snapshot::check_config(path, &s.config, expected)?;
        Self::from_snapshot(s, device)
    }

    /// Changes the compute path (the state moves over; the fused path requires the CPU).
    pub fn set_path(&mut self, path: ComputePath) -> Result<(), CacheError> {
        if path == self.path {
            return Ok(());
        }
        let host = self.host_state();
        let scene_content = self.scene_content.take();
        let moved = Self::from_host(
            self.config.clone(),
            self.scene_box,
            self.device,
            path,
            host,
            self.step,
        );
        match moved {
            Ok(mut cache) => {
                cache.scene_content = scene_content;
                cache.lr_start = self.lr_start;
                *self = cache;
                Ok(())
            }
            Err(e) => {
                self.scene_content = scene_content;
                Err(e)
            }
        }
    }
}

/// The MLP products part of [`RadianceCache::describe`]'s network line: the bf16 kernels exist
/// on the fused CPU (Flex) path only, the f16 kernels on the fused wgpu path only (`gpu_half`:
/// taken here, on an adapter with `shader-f16`); elsewhere the products are f32 whatever the
/// configuration says.
fn mlp_products(
    device: CacheDevice,
    precision: crate::config::MlpPrecision,
    kernel: crate::cpu::bf16::PairKernel,
    gpu_half: bool,
) -> &'static str {
    use crate::cpu::bf16::PairKernel;
    match (device, precision) {
        (CacheDevice::Wgpu, MlpPrecision::F32) => "MLP products f32 on wgpu",
        (CacheDevice::Wgpu, MlpPrecision::Bf16) => {
            "MLP products f32 on wgpu (the bf16 precision applies to the fused CPU path only)"
        }
        (CacheDevice::Wgpu, MlpPrecision::F16) if gpu_half => {
            "f16 products on the fused wgpu path (f16 weights and activations, f32 sums)"
        }
        (CacheDevice::Wgpu, MlpPrecision::F16) => {
            "MLP products f32 on wgpu (the f16 precision needs the fused path on an adapter with shader-f16)"
        }
        (CacheDevice::Cpu, MlpPrecision::F16) => {
            "f32 products (the f16 precision applies to the fused wgpu path only)"
        }
        (CacheDevice::Cpu, MlpPrecision::F32) => "f32 products",
        (CacheDevice::Cpu, MlpPrecision::Bf16) => match kernel {
            PairKernel::Avx512Bf16 => "bf16 products on the fused CPU path (AVX-512 BF16)",
            PairKernel::Avx2 => {
                "bf16 products on the fused CPU path (no AVX-512 BF16 here: AVX2 emulation, the same bits, slower than f32)"
            }
            PairKernel::Expanded => {
                "bf16 products on the fused CPU path (no AVX-512 BF16 here: portable emulation, the same bits, slower than f32)"
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::bf16::PairKernel;

    #[test]
    fn wgpu_description_claims_no_cpu_kernels() {
        for precision in [MlpPrecision::F32, MlpPrecision::Bf16, MlpPrecision::F16] {
            for kernel in [
                PairKernel::Expanded,
                PairKernel::Avx2,
                PairKernel::Avx512Bf16,
            ] {
                let text = mlp_products(CacheDevice::Wgpu, precision, kernel, false);
                assert!(text.starts_with("MLP products f32 on wgpu"), "{text}");
                assert!(!text.contains("AVX"), "{text}");
                assert!(!text.contains("bf16 products"), "{text}");
            }
        }
    }

    #[test]
    fn cpu_description_names_its_kernel() {
        assert_eq!(
            mlp_products(
                CacheDevice::Cpu,
                MlpPrecision::F32,
                PairKernel::Avx512Bf16,
                false
            ),
            "f32 products"
        );
        let text = mlp_products(
            CacheDevice::Cpu,
            MlpPrecision::Bf16,
            PairKernel::Avx512Bf16,
            false,
        );
        assert!(text.contains("AVX-512 BF16"), "{text}");
        let text = mlp_products(
            CacheDevice::Cpu,
            MlpPrecision::Bf16,
            PairKernel::Avx2,
            false,
        );
        assert!(text.contains("AVX2 emulation"), "{text}");
        // The f16 precision is the wgpu path's: the CPU says it computes in f32, even when the
        // caller (wrongly) says a GPU takes it.
        let text = mlp_products(CacheDevice::Cpu, MlpPrecision::F16, PairKernel::Avx2, true);
        assert!(text.starts_with("f32 products"), "{text}");
        let text = mlp_products(CacheDevice::Wgpu, MlpPrecision::F16, PairKernel::Avx2, true);
        assert!(text.starts_with("f16 products"), "{text}");
    }

    /// A small hash-grid cache on the CPU, with a few steps of training.
    fn small_cache() -> RadianceCache {
        use crate::config::NestedEncoding;
        let mut config = CacheConfig::hash_grid_preset();
        if let Some(NestedEncoding::HashGrid {
            log2_hashmap_size, ..
        }) = config.encoding.nested.first_mut()
        {
            *log2_hashmap_size = 12;
        }
        let scene_box = SceneBox {
            min: [-1.0, -2.0, -3.0],
            max: [4.0, 5.0, 6.0],
        };
        let mut cache =
            RadianceCache::with_path(config, scene_box, CacheDevice::Cpu, ComputePath::Fused)
                .expect("cache");
        let q = CacheQuery {
            position: [0.25, 0.5, 0.75],
            normal: [0.0, 0.0, 1.0],
            direction: [0.0, 0.0, 1.0],
            diffuse: [0.5; 3],
            ..Default::default()
        };
        let batch = TrainingBatch {
            queries: vec![q; 256],
            targets: vec![[1.0, 0.5, 0.25]; 256],
            weights: None,
        };
        cache.train(&batch, 2).expect("train");
        cache
    }

    /// Each call returns its own profile: the fused step's phases are measured, and a call's
    /// figures are its own (a second cache's calls in between change nothing).
    #[test]
    fn each_call_returns_its_own_profile() {
        let mut a = small_cache();
        let mut b = small_cache();
        let batch = crate::bench::synthetic_batch(4096, 7);
        let first = a.train(&batch, 1).expect("train").profile;
        for p in [
            first.encode,
            first.mlp,
            first.grid_wall,
            first.mlp_adam,
            first.packing,
        ] {
            assert!(p > std::time::Duration::ZERO, "{first:?}");
        }
        // Many of b's steps between two of a's one-step calls: a cumulative (process-wide)
        // clock would hand a's second call all of b's time too.
        let b_stats = b.train(&batch, 8).expect("train");
        let second = a.train(&batch, 1).expect("train").profile;
        assert!(
            second.mlp < b_stats.profile.mlp,
            "a's second call {second:?} holds more than its own step (b: {:?})",
            b_stats.profile
        );
        let (answers, infer) = a.infer_profiled(&batch.queries);
        assert_eq!(answers.len(), batch.queries.len());
        assert!(infer.call >= infer.kernel && infer.kernel > std::time::Duration::ZERO);
        assert!(infer.encode >= infer.hash_grid && infer.mlp > std::time::Duration::ZERO);
    }

    #[test]
    fn scene_content_round_trips_through_save_and_load() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("cache.nrc");
        let mut cache = small_cache();
        assert_eq!(cache.scene_content(), None);
        let hash = "1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d7e8f9a0b1c2d3e4f5a6b7c8d9e0f1a2b";
        cache.set_scene_content(Some(hash.to_string()));
        assert_eq!(cache.scene_content(), Some(hash));
        // Changing the compute path keeps it.
        cache.set_path(ComputePath::CustomOps).expect("set_path");
        assert_eq!(cache.scene_content(), Some(hash));
        cache.save(&file).expect("save");
        let loaded = RadianceCache::load(&file, CacheDevice::Cpu).expect("load");
        assert_eq!(loaded.scene_content(), Some(hash));
        assert_eq!(loaded.scene_box(), cache.scene_box());
        let s = snapshot::read(&file).expect("read");
        assert_eq!(s.scene_content.as_deref(), Some(hash));
        assert_eq!(
            snapshot::check_scene(
                s.scene_content.as_deref(),
                s.scene_box,
                hash,
                cache.scene_box()
            ),
            Ok(())
        );
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 1);
    }

    #[test]
    fn snapshot_without_scene_content_loads_as_none() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("cache.nrc");
        let mut cache = small_cache();
        cache.save(&file).expect("save");
        // Saved without a content hash, the metadata has no such key at all (as older files).
        let bytes = std::fs::read(&file).expect("read");
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).expect("header");
        let json = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("nrc_cache"))
            .expect("metadata")
            .clone();
        assert!(!json.contains("scene_content"), "{json}");
        let loaded = RadianceCache::load(&file, CacheDevice::Cpu).expect("load");
        assert_eq!(loaded.scene_content(), None);
        assert_eq!(loaded.step_count(), cache.step_count());
        // Checked by its box only.
        assert!(snapshot::check_scene(None, loaded.scene_box(), "00ff", cache.scene_box()).is_ok());
    }
}
