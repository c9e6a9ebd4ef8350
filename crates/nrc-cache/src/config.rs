//! The cache's configuration: one JSON document describing encoding, network, loss and optimizer,
//! in tiny-cuda-nn's style (an `"otype"` tag per component). See `models/nrc-hashgrid.json`.
//!
//! Parsing reports the JSON path of a malformed field (`encoding.nested[0].n_levels: ...`);
//! [`CacheConfig::validate`] rejects out-of-range values naming the field.

use serde::{Deserialize, Serialize};

use crate::encoding::hash_grid::{HashGrid, HashGridParams, TablePrecision};
use crate::error::CacheError;
use crate::record::RAW_INPUT_DIMS;

/// The whole cache configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CacheConfig {
    /// Input encoding (a `Composite` over the 14 raw inputs, see [`crate::record::raw_inputs`]).
    pub encoding: CompositeConfig,
    /// The MLP.
    pub network: NetworkConfig,
    /// Training loss.
    pub loss: LossConfig,
    /// Optimizer (`Adam`, optionally wrapped in an `EMA`).
    pub optimizer: OptimizerConfig,
    /// Seed of the parameter initialisation.
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_seed() -> u64 {
    1337
}

/// `Composite` encoding: nested encodings consume consecutive raw input dimensions; the
/// concatenated output is padded with ones to a multiple of `pad_to_multiple` (the padding acts
/// as a bias input of the bias-free first layer).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompositeConfig {
    pub otype: EncodingType,
    /// The nested encodings, in raw-input order.
    pub nested: Vec<NestedEncoding>,
    /// Output width is padded up to a multiple of this.
    #[serde(default = "default_pad")]
    pub pad_to_multiple: u32,
}

fn default_pad() -> u32 {
    16
}

/// The encoding's `"otype"`: `"Composite"`, the only one the cache takes (its 14 raw inputs go
/// through the nested encodings).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum EncodingType {
    #[default]
    Composite,
}

/// The network's `"otype"`: `"FullyFusedMLP"` (64 wide, no biases).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum NetworkType {
    #[default]
    FullyFusedMLP,
}

/// The hidden layers' activation: `"ReLU"`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Activation {
    #[default]
    ReLU,
}

/// The loss's `"otype"`: `"RelativeL2Luminance"`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum LossType {
    #[default]
    RelativeL2Luminance,
}

/// One nested encoding of the composite.
#[derive(Clone, Debug, PartialEq)]
pub enum NestedEncoding {
    /// Multiresolution hash grid over 3 dimensions (see [`crate::encoding::hash_grid`]).
    HashGrid {
        /// Must be 3.
        n_dims_to_encode: u32,
        /// Levels L.
        n_levels: u32,
        /// Features per level F (1, 2, 4 or 8).
        n_features_per_level: u32,
        /// log2 of the per-level table size.
        log2_hashmap_size: u32,
        /// Coarsest resolution.
        base_resolution: f32,
        /// Growth factor between levels.
        per_level_scale: f32,
        /// Precision of the inference table (`"f32"` when absent, `"f16"`).
        inference_precision: TablePrecision,
        /// Precision of the weights the training forward pass reads (`"f32"` when absent,
        /// `"f16"`).
        training_precision: TablePrecision,
    },
    /// One-blob encoding with `n_bins` bins per dimension; `wrap` for periodic inputs (azimuth).
    OneBlob {
        /// Dimensions consumed.
        n_dims_to_encode: u32,
        /// Bins per dimension.
        n_bins: u32,
        /// Periodic on [0,1).
        wrap: bool,
    },
    /// Triangle-wave frequency encoding with `n_frequencies` octaves per dimension.
    TriangleWave {
        /// Dimensions consumed.
        n_dims_to_encode: u32,
        /// Octaves per dimension.
        n_frequencies: u32,
    },
    /// Pass-through `x·scale + offset`.
    Identity {
        /// Dimensions consumed.
        n_dims_to_encode: u32,
        /// Multiplier.
        scale: f32,
        /// Offset.
        offset: f32,
    },
}

pub(crate) fn one() -> f32 {
    1.0
}

impl NestedEncoding {
    /// Raw input dimensions this encoding consumes.
    pub fn n_dims_to_encode(&self) -> u32 {
        match self {
            Self::HashGrid {
                n_dims_to_encode, ..
            }
            | Self::OneBlob {
                n_dims_to_encode, ..
            }
            | Self::TriangleWave {
                n_dims_to_encode, ..
            }
            | Self::Identity {
                n_dims_to_encode, ..
            } => *n_dims_to_encode,
        }
    }
}

/// Mapping of the network's 3 outputs to non-negative radiance (before the reflectance factor).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OutputActivation {
    /// `exp(y)` (default): the relative loss is scale-invariant, so learning log-radiance gives
    /// gradients of the same size for targets from 1e-6 to 1e6. The argument is clamped to
    /// [−80, 80] to stay finite.
    Exponential,
    /// `ln(1 + e^y)`: smooth, linear growth for large radiance.
    Softplus,
    /// `max(y, 0)`: cheapest; a unit stuck below zero gets no gradient.
    ReLU,
}

/// The MLP: `n_hidden_layers` hidden layers of 64 neurons, ReLU, no biases, 3 outputs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkConfig {
    pub otype: NetworkType,
    /// Width; must be 64.
    pub n_neurons: u32,
    /// Hidden layers (weight matrices = hidden layers + 1).
    pub n_hidden_layers: u32,
    /// Hidden activation.
    #[serde(default)]
    pub activation: Activation,
    /// Output mapping to non-negative radiance.
    #[serde(default = "exponential")]
    pub output_activation: OutputActivation,
    /// Must be 3 (RGB).
    #[serde(default = "three")]
    pub n_output_dims: u32,
    /// Arithmetic of the MLP's products (`"f32"` when absent; `"bf16"` on the fused CPU path,
    /// `"f16"` on the fused wgpu path).
    #[serde(default, skip_serializing_if = "MlpPrecision::is_f32")]
    pub precision: MlpPrecision,
}

/// Arithmetic of the MLP's products (training and inference): `f32`; `bf16`, on the fused CPU
/// path: operands rounded to bfloat16 with f32 sums, the weights rounded from f32 master
/// weights each step (mixed precision, as tiny-cuda-nn's half-precision MLP), twice the
/// multiply-adds per cycle on CPUs with AVX-512 BF16 (see [`crate::cpu::bf16`]), the output
/// layer f32; `f16`, on the fused wgpu path where the adapter has `shader-f16`: the weights
/// rounded to IEEE half from f32 master weights each step and the activations kept in half
/// precision in workgroup memory, every product summed in f32, the backward's deltas and
/// gradients f32 (see `nrc_gpu::Layout::half_mlp`). Each precision applies to its path only;
/// the others compute in f32 and the cache's description line says so. The optimizer is f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MlpPrecision {
    /// Single precision (the default).
    #[default]
    F32,
    /// bfloat16 operands, f32 sums (the fused CPU path).
    Bf16,
    /// IEEE half weights and activations, f32 sums (the fused wgpu path, with `shader-f16`).
    F16,
}

impl MlpPrecision {
    /// Whether this is the default, f32.
    pub fn is_f32(&self) -> bool {
        *self == Self::F32
    }
}

fn exponential() -> OutputActivation {
    OutputActivation::Exponential
}
fn three() -> u32 {
    3
}

/// Relative L2 loss normalised by the squared luminance of the detached prediction:
/// `w·(y − t)² / (lum(y)² + epsilon)`, averaged over samples and channels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    pub otype: LossType,
    /// ε of the denominator.
    #[serde(default = "loss_eps")]
    pub epsilon: f32,
    /// Targets with a channel above this (or below 0) are absurd: dropped and counted.
    #[serde(default = "max_target")]
    pub max_target: f32,
    /// The relative residual `|y − t| / √(lum(y)² + ε)` beyond which a sample's loss grows
    /// linearly instead of quadratically (Huber's loss; see `loss.rs`): one firefly target's
    /// gradient is bounded. `1e30` gives the plain relative L2 loss. 16 by default; 64 lets
    /// the cache carry more of the light that rare targets bring (better in long runs on the
    /// door scenes, worse on the kitchen: RESULTS.md, "The drift was the measure's").
    #[serde(default = "max_relative_error")]
    pub max_relative_error: f32,
    /// The light the bound clips, returned to the place it was clipped from (the online loop
    /// does it: `nrc_train::clipped`). Absent: the bound's light is lost, and the cache
    /// settles below its targets' mean where rare bright targets carry the light.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub return_clipped: Option<ReturnClipped>,
}

/// How the online loop returns the light the loss bound clips (`nrc_train::clipped`): each
/// record's target is clamped where the bound would clip its residual (at the cache's
/// prediction), the clipped luminance is summed per bin (a cell of a `grid`³ grid over the
/// scene box and the normal's dominant axis and sign), and every target of a bin is scaled by
/// its gain, `1 + clipped / kept` over the bin's remembered records, at most `max_gain`;
/// records on glossy surfaces are only clamped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReturnClipped {
    /// Cells per axis of the grid whose bins balance the light.
    pub grid: u32,
    /// Frames a bin remembers (its sums decay by `1 − 1/frames` a frame).
    pub frames: f32,
    /// The largest gain of a bin.
    pub max_gain: f32,
    /// Records on a surface with a specular part smoother than this (the BSDF's roughness,
    /// `√α`; 1 for a diffuse surface) are clamped but take no part in the bins: their radiance
    /// depends on the direction, which a bin does not hold.
    pub min_roughness: f32,
}

fn loss_eps() -> f32 {
    0.01
}
fn max_target() -> f32 {
    1e8
}
fn max_relative_error() -> f32 {
    16.0
}

/// Optimizer: `Adam`, or an `EMA` of the weights wrapping Adam (inference uses the average).
#[derive(Clone, Debug, PartialEq)]
pub enum OptimizerConfig {
    /// Exponential moving average of the weights, bias-corrected: `ê_t = e_t / (1 − decay^t)`.
    EMA {
        /// α.
        decay: f32,
        /// The optimizer whose weights are averaged (must be Adam).
        nested: Box<OptimizerConfig>,
    },
    /// Piecewise-constant exponential decay of the nested optimizer's learning rate, as
    /// tiny-cuda-nn's `ExponentialDecay`: at step `k` (counted from the cache's first step, or
    /// from the last [`crate::RadianceCache::restart_learning_rate`], where tiny-cuda-nn counts
    /// from its first) the rate is `learning_rate · decay_base^n`, `n` the number of steps
    /// `decay_start, decay_start + decay_interval, …` at most `min(k, decay_end)`. The rate
    /// stops falling at `decay_end`: that is its floor. A training call of several steps takes
    /// its first step's rate for all of them (the online loop makes one step a call); a
    /// snapshot stores the step of the last restart.
    ExponentialDecay {
        decay_start: u32,
        decay_interval: u32,
        decay_base: f32,
        decay_end: u32,
        /// The optimizer whose learning rate decays (Adam).
        nested: Box<OptimizerConfig>,
    },
    /// Adam.
    Adam {
        /// Learning rate.
        learning_rate: f32,
        /// β1.
        beta1: f32,
        /// β2.
        beta2: f32,
        /// ε.
        epsilon: f32,
        /// L2 regularisation added to the gradient (`g + l2_reg·w`).
        l2_reg: f32,
    },
}

pub(crate) fn ema_decay() -> f32 {
    0.99
}
pub(crate) fn lr() -> f32 {
    1e-2
}
pub(crate) fn beta1() -> f32 {
    0.9
}
pub(crate) fn beta2() -> f32 {
    0.99
}
pub(crate) fn adam_eps() -> f32 {
    1e-15
}

/// A learning-rate decay ([`OptimizerConfig::ExponentialDecay`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LrDecay {
    pub start: u32,
    pub interval: u32,
    pub base: f32,
    pub end: u32,
}

impl LrDecay {
    /// The factor of the learning rate at step `k` of the schedule (counted from 0).
    pub fn factor(&self, k: u32) -> f32 {
        if k < self.start {
            return 1.0;
        }
        let n =
            (k.min(self.end).saturating_sub(self.start) / self.interval.max(1)).saturating_add(1);
        self.base.powi(n.min(i32::MAX as u32) as i32)
    }

    /// The lowest factor (from step `end` on).
    pub fn floor(&self) -> f32 {
        self.factor(self.end)
    }
}

/// Adam hyper-parameters, resolved from the config.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamParams {
    /// Learning rate.
    pub learning_rate: f32,
    /// β1.
    pub beta1: f32,
    /// β2.
    pub beta2: f32,
    /// ε.
    pub epsilon: f32,
    /// L2 regularisation.
    pub l2_reg: f32,
}

impl OptimizerConfig {
    /// Sets Adam's learning rate (the nested optimizer's, under an EMA or a decay; a decay
    /// scales it from there).
    pub fn set_learning_rate(&mut self, lr: f32) {
        match self {
            Self::EMA { nested, .. } | Self::ExponentialDecay { nested, .. } => {
                nested.set_learning_rate(lr)
            }
            Self::Adam { learning_rate, .. } => *learning_rate = lr,
        }
    }

    /// The learning rate's decay, if any.
    pub fn lr_decay(&self) -> Option<LrDecay> {
        match self {
            Self::EMA { nested, .. } => nested.lr_decay(),
            &Self::ExponentialDecay {
                decay_start,
                decay_interval,
                decay_base,
                decay_end,
                ..
            } => Some(LrDecay {
                start: decay_start,
                interval: decay_interval,
                base: decay_base,
                end: decay_end,
            }),
            Self::Adam { .. } => None,
        }
    }

    /// The Adam parameters and the EMA decay (None without EMA); the learning rate is the
    /// undecayed one (see [`Self::lr_decay`]).
    pub fn resolve(&self) -> (AdamParams, Option<f32>) {
        match self {
            Self::EMA { decay, nested } => (nested.resolve().0, Some(*decay)),
            Self::ExponentialDecay { nested, .. } => nested.resolve(),
            Self::Adam {
                learning_rate,
                beta1,
                beta2,
                epsilon,
                l2_reg,
            } => (
                AdamParams {
                    learning_rate: *learning_rate,
                    beta1: *beta1,
                    beta2: *beta2,
                    epsilon: *epsilon,
                    l2_reg: *l2_reg,
                },
                None,
            ),
        }
    }
}

/// An axis-aligned scene box; query positions are normalised to it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneBox {
    /// Minimum corner.
    pub min: [f32; 3],
    /// Maximum corner.
    pub max: [f32; 3],
}

impl Default for SceneBox {
    fn default() -> Self {
        Self {
            min: [0.0; 3],
            max: [1.0; 3],
        }
    }
}

impl SceneBox {
    /// Extent per axis.
    pub fn extent(&self) -> [f32; 3] {
        std::array::from_fn(|k| self.max[k] - self.min[k])
    }

    /// Maps a world position into [0,1]³ (clamped).
    pub fn normalize(&self, p: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|k| {
            let e = self.max[k] - self.min[k];
            if e > 0.0 {
                ((p[k] - self.min[k]) / e).clamp(0.0, 1.0)
            } else {
                0.5
            }
        })
    }
}

/// What [`CacheConfig::sized_for_scene`] chose.
#[derive(Clone, Debug, PartialEq)]
pub struct Sizing {
    /// Finest grid resolution (or finest triangle-wave period, in cells of the longest axis).
    pub finest_resolution: u32,
    /// Chosen per-level scale of the hash grid (None without a hash grid).
    pub per_level_scale: Option<f32>,
    /// Chosen log2 table size (None without a hash grid).
    pub log2_hashmap_size: Option<u32>,
    /// Chosen triangle-wave octaves (None without a triangle-wave encoding).
    pub n_frequencies: Option<u32>,
    /// Trainable parameters.
    pub param_count: usize,
    /// Bytes of training state (weights, Adam moments, EMA, gradient scratch, bookkeeping).
    pub memory_bytes: usize,
}

impl CacheConfig {
    /// Serialises to pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("config serialises")
    }

    /// The `models/nrc-hashgrid.json` preset: hash grid 16×2, log2T 19, base 16, 3 hidden layers.
    pub fn hash_grid_preset() -> Self {
        Self::from_json_str(include_str!("../../../models/nrc-hashgrid.json"))
            .expect("preset is valid")
    }

    /// The `models/nrc-trianglewave.json` preset: 12 triangle-wave octaves + one-blob, 5 hidden layers.
    pub fn triangle_wave_preset() -> Self {
        Self::from_json_str(include_str!("../../../models/nrc-trianglewave.json"))
            .expect("preset is valid")
    }

    /// Checks every field's range; the error names the field.
    pub fn validate(&self) -> Result<(), CacheError> {
        let err = |field: String, message: String| Err(CacheError::Config { field, message });
        let e = &self.encoding;
        if e.nested.is_empty() {
            return err(
                "encoding.nested".into(),
                "must hold at least one encoding".into(),
            );
        }
        if !(1..=64).contains(&e.pad_to_multiple) {
            return err(
                "encoding.pad_to_multiple".into(),
                format!("must be in 1..=64, got {}", e.pad_to_multiple),
            );
        }
        let mut dims = 0u32;
        let mut grids = 0;
        for (i, n) in e.nested.iter().enumerate() {
            let f = |name: &str| format!("encoding.nested[{i}].{name}");
            let nd = n.n_dims_to_encode();
            if nd == 0 || nd > RAW_INPUT_DIMS as u32 {
                return err(
                    f("n_dims_to_encode"),
                    format!("must be in 1..={RAW_INPUT_DIMS}, got {nd}"),
                );
            }
            dims += nd;
            match n {
                NestedEncoding::HashGrid {
                    n_dims_to_encode,
                    n_levels,
                    n_features_per_level,
                    log2_hashmap_size,
                    base_resolution,
                    per_level_scale,
                    ..
                } => {
                    grids += 1;
                    if grids > 1 {
                        return err(
                            f("otype"),
                            "at most one HashGrid encoding is supported".into(),
                        );
                    }
                    if *n_dims_to_encode != 3 {
                        return err(
                            f("n_dims_to_encode"),
                            format!(
                                "a HashGrid encodes exactly 3 dimensions (the position), got {n_dims_to_encode}"
                            ),
                        );
                    }
                    if !(1..=32).contains(n_levels) {
                        return err(f("n_levels"), format!("must be in 1..=32, got {n_levels}"));
                    }
                    if ![1, 2, 4, 8].contains(n_features_per_level) {
                        return err(
                            f("n_features_per_level"),
                            format!("must be 1, 2, 4 or 8, got {n_features_per_level}"),
                        );
                    }
                    if !(10..=24).contains(log2_hashmap_size) {
                        return err(
                            f("log2_hashmap_size"),
                            format!("must be in 10..=24, got {log2_hashmap_size}"),
                        );
                    }
                    if !(base_resolution.is_finite()
                        && *base_resolution >= 2.0
                        && *base_resolution <= 4096.0)
                    {
                        return err(
                            f("base_resolution"),
                            format!("must be in [2, 4096], got {base_resolution}"),
                        );
                    }
                    if !(per_level_scale.is_finite()
                        && *per_level_scale >= 1.0
                        && *per_level_scale <= 4.0)
                    {
                        return err(
                            f("per_level_scale"),
                            format!("must be in [1, 4], got {per_level_scale}"),
                        );
                    }
                    let finest = base_resolution * per_level_scale.powi(*n_levels as i32 - 1);
                    if finest > 1_048_576.0 {
                        return err(
                            f("per_level_scale"),
                            format!("finest resolution {finest:.0} exceeds 2^20"),
                        );
                    }
                }
                NestedEncoding::OneBlob { n_bins, .. } => {
                    if !(1..=64).contains(n_bins) {
                        return err(f("n_bins"), format!("must be in 1..=64, got {n_bins}"));
                    }
                }
                NestedEncoding::TriangleWave { n_frequencies, .. } => {
                    if !(1..=24).contains(n_frequencies) {
                        return err(
                            f("n_frequencies"),
                            format!("must be in 1..=24, got {n_frequencies}"),
                        );
                    }
                }
                NestedEncoding::Identity { scale, offset, .. } => {
                    if !scale.is_finite() {
                        return err(f("scale"), format!("must be finite, got {scale}"));
                    }
                    if !offset.is_finite() {
                        return err(f("offset"), format!("must be finite, got {offset}"));
                    }
                }
            }
        }
        if dims != RAW_INPUT_DIMS as u32 {
            return err(
                "encoding.nested".into(),
                format!(
                    "the nested encodings consume {dims} dimensions; the cache provides {RAW_INPUT_DIMS} (position 3, direction 2, normal 2, roughness 1, diffuse 3, specular 3)"
                ),
            );
        }
        let n = &self.network;
        if n.n_neurons != 64 {
            return err(
                "network.n_neurons".into(),
                format!("only 64 neurons are supported, got {}", n.n_neurons),
            );
        }
        if !(1..=16).contains(&n.n_hidden_layers) {
            return err(
                "network.n_hidden_layers".into(),
                format!("must be in 1..=16, got {}", n.n_hidden_layers),
            );
        }
        if n.n_output_dims != 3 {
            return err(
                "network.n_output_dims".into(),
                format!("must be 3 (RGB), got {}", n.n_output_dims),
            );
        }
        let l = &self.loss;
        finite_above("loss.epsilon", l.epsilon, 0.0, true)?;
        finite_above("loss.max_target", l.max_target, 0.0, true)?;
        finite_above("loss.max_relative_error", l.max_relative_error, 0.0, true)?;
        if let Some(r) = &l.return_clipped {
            finite_above(
                "loss.return_clipped.min_roughness",
                r.min_roughness,
                0.0,
                false,
            )?;
            if !(1..=64).contains(&r.grid) {
                return err(
                    "loss.return_clipped.grid".into(),
                    format!("must be 1 to 64 cells, got {}", r.grid),
                );
            }
            finite_above("loss.return_clipped.frames", r.frames, 1.0, false)?;
            finite_above("loss.return_clipped.max_gain", r.max_gain, 1.0, false)?;
        }
        validate_optimizer(&self.optimizer, "optimizer", true)
    }

    /// The hash-grid parameters, if the encoding has a hash grid.
    pub fn hash_grid(&self) -> Option<HashGridParams> {
        self.encoding.nested.iter().find_map(|n| match n {
            NestedEncoding::HashGrid {
                n_levels,
                n_features_per_level,
                log2_hashmap_size,
                base_resolution,
                per_level_scale,
                inference_precision,
                training_precision,
                ..
            } => Some(HashGridParams {
                n_levels: *n_levels,
                n_features_per_level: *n_features_per_level,
                log2_hashmap_size: *log2_hashmap_size,
                base_resolution: *base_resolution,
                per_level_scale: *per_level_scale,
                inference_precision: *inference_precision,
                training_precision: *training_precision,
            }),
            _ => None,
        })
    }

    /// The derived hash-grid layout, if any.
    pub fn grid_layout(&self) -> Option<HashGrid> {
        self.hash_grid().map(HashGrid::new)
    }
}

fn validate_optimizer(o: &OptimizerConfig, field: &str, top: bool) -> Result<(), CacheError> {
    let err = |name: &str, message: String| {
        Err(CacheError::Config {
            field: format!("{field}.{name}"),
            message,
        })
    };
    match o {
        OptimizerConfig::EMA { decay, nested } => {
            if !top {
                return err("otype", "an EMA cannot be nested in an EMA".into());
            }
            if !(decay.is_finite() && (0.0..1.0).contains(decay)) {
                return err("decay", format!("must be in [0, 1), got {decay}"));
            }
            validate_optimizer(nested, &format!("{field}.nested"), false)
        }
        OptimizerConfig::ExponentialDecay { nested, .. } => {
            let d = o.lr_decay().expect("a decay");
            if d.interval == 0 {
                return err("decay_interval", "must be at least 1".into());
            }
            if !(d.base.is_finite() && d.base > 0.0 && d.base <= 1.0) {
                return err("decay_base", format!("must be in (0, 1], got {}", d.base));
            }
            if d.end < d.start {
                return err(
                    "decay_end",
                    format!("must be at least decay_start ({}), got {}", d.start, d.end),
                );
            }
            if !matches!(**nested, OptimizerConfig::Adam { .. }) {
                return err(
                    "nested.otype",
                    "the decay's nested optimizer must be Adam".into(),
                );
            }
            validate_optimizer(nested, &format!("{field}.nested"), false)
        }
        OptimizerConfig::Adam {
            learning_rate,
            beta1,
            beta2,
            epsilon,
            l2_reg,
        } => {
            // Above 1 a step moves every weight by about the learning rate: the mutation tests
            // found rates of 10^8 and 2^32 accepted, and the cache's weights non-finite after
            // one step.
            if !(learning_rate.is_finite() && *learning_rate > 0.0 && *learning_rate <= 1.0) {
                return err(
                    "learning_rate",
                    format!("must be in (0, 1], got {learning_rate}"),
                );
            }
            if !(beta1.is_finite() && (0.0..1.0).contains(beta1)) {
                return err("beta1", format!("must be in [0, 1), got {beta1}"));
            }
            if !(beta2.is_finite() && (0.0..1.0).contains(beta2)) {
                return err("beta2", format!("must be in [0, 1), got {beta2}"));
            }
            if !(epsilon.is_finite() && *epsilon >= 0.0) {
                return err("epsilon", format!("must be finite and ≥ 0, got {epsilon}"));
            }
            if !(l2_reg.is_finite() && *l2_reg >= 0.0) {
                return err("l2_reg", format!("must be finite and ≥ 0, got {l2_reg}"));
            }
            Ok(())
        }
    }
}

/// An error naming `field` unless `value` is finite and above `min` (`strict`) or at least
/// `min`: "must be finite and > 0, got …".
fn finite_above(field: &str, value: f32, min: f32, strict: bool) -> Result<(), CacheError> {
    let ok = value.is_finite() && if strict { value > min } else { value >= min };
    if ok {
        return Ok(());
    }
    Err(CacheError::Config {
        field: field.into(),
        message: format!(
            "must be finite and {} {min}, got {value}",
            if strict { ">" } else { ">=" }
        ),
    })
}
