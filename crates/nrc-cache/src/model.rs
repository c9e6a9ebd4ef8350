//! The model's parameter layout and initialisation.
//!
//! All trainable parameters live in one flat f32 vector (as in tiny-cuda-nn):
//!
//! ```text
//! [ hash table: [level][entry][feature] | layer 0: [in][64] | layer 1..H−1: [64][64] | output: [64][3] ]
//! ```
//!
//! Training keeps the two groups apart (the grid is updated sparsely, the MLP densely), so
//! [`LayerShape::offset`] counts from the start of the MLP group.
//!
//! Weight matrices are stored input-major (`M[k][j]` connects input `k` to output `j`), so a
//! layer computes `y = x · M`. There are no biases; the encoding's padding columns (ones) act
//! as the first layer's bias.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::config::SceneBox;
use crate::config::{CacheConfig, MlpPrecision, NestedEncoding, OutputActivation, Sizing};
use crate::encoding::InputEncoding;
use crate::encoding::hash_grid::TablePrecision;
use crate::error::CacheError;

/// Width of every hidden layer.
pub const WIDTH: usize = 64;
/// Network outputs (RGB).
pub const OUTPUTS: usize = 3;

/// Shape and position of one weight matrix in the flat parameter vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LayerShape {
    /// Inputs (rows).
    pub inputs: usize,
    /// Outputs (columns).
    pub outputs: usize,
    /// Offset of `M[0][0]` in the MLP parameter group.
    pub offset: usize,
}

impl LayerShape {
    /// Number of weights.
    pub fn len(&self) -> usize {
        self.inputs * self.outputs
    }

    /// Whether the layer has no weights.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Everything derived from a config that the kernels need: the encoding, the layers and the
/// parameter layout.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelLayout {
    /// The composite input encoding.
    pub encoding: InputEncoding,
    /// Weight matrices, input to output.
    pub layers: Vec<LayerShape>,
    /// Output mapping.
    pub output_activation: OutputActivation,
    /// Arithmetic of the fused CPU path's hidden-layer products.
    pub mlp_precision: MlpPrecision,
    /// Parameters of the hash table (they come first).
    pub grid_params: usize,
    /// Total parameters.
    pub total_params: usize,
}

impl ModelLayout {
    /// Derives the layout from a validated config.
    pub fn new(config: &CacheConfig) -> Self {
        let encoding = InputEncoding::new(&config.encoding);
        let grid_params = encoding.param_count();
        let hidden = config.network.n_hidden_layers as usize;
        let mut offset = 0;
        let mut layers = Vec::with_capacity(hidden + 1);
        let mut inputs = encoding.padded_dims;
        for l in 0..=hidden {
            let outputs = if l == hidden { OUTPUTS } else { WIDTH };
            layers.push(LayerShape {
                inputs,
                outputs,
                offset,
            });
            offset += inputs * outputs;
            inputs = outputs;
        }
        Self {
            encoding,
            layers,
            output_activation: config.network.output_activation,
            mlp_precision: config.network.precision,
            grid_params,
            total_params: grid_params + offset,
        }
    }

    /// Total trainable parameters.
    pub fn param_count(&self) -> usize {
        self.total_params
    }

    /// MLP parameters.
    pub fn mlp_params(&self) -> usize {
        self.total_params - self.grid_params
    }

    /// Bytes the cache holds: weights, two Adam moments and EMA (4 × 4 bytes per parameter),
    /// the half-precision copy of
    /// the table the training forward reads (2 bytes per parameter, with
    /// `"training_precision": "f16"`) and the inference weights (the table at its inference
    /// precision, 2 or 4 bytes per parameter, and the MLP's).
    pub fn training_memory_bytes(&self) -> usize {
        let params = self.encoding.grid().map(|(g, _)| &g.params);
        let inference_bytes = match params.map(|p| p.inference_precision) {
            Some(TablePrecision::F16) => 2,
            _ => 4,
        };
        let forward_copy_bytes = match params.map(|p| p.training_precision) {
            Some(TablePrecision::F16) => 2,
            _ => 0,
        };
        self.total_params * 4 * 4
            + self.grid_params * (inference_bytes + forward_copy_bytes)
            + self.mlp_params() * 4
    }

    /// Initial parameters: hash table uniform in ±1e-4, weight matrices Xavier-uniform
    /// (`±sqrt(6/(fan_in+fan_out))`), from a seeded PCG generator.
    /// Returns (hash table, MLP weights).
    pub fn init_params(&self, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let grid = (0..self.grid_params)
            .map(|_| rng.random_range(-1e-4f32..1e-4))
            .collect();
        let mut mlp = Vec::with_capacity(self.mlp_params());
        for l in &self.layers {
            let a = (6.0 / (l.inputs + l.outputs) as f32).sqrt();
            for _ in 0..l.len() {
                mlp.push(rng.random_range(-a..a));
            }
        }
        (grid, mlp)
    }
}

impl CacheConfig {
    /// Sizes the model for a scene: the finest resolvable feature is `min_feature_size` (world
    /// units) along the box's longest axis.
    ///
    /// * Hash grid: finest resolution `N_max = ceil(longest extent / min_feature_size)`, the
    ///   per-level scale spreads the configured levels from the base resolution to `N_max`
    ///   (`b = (N_max/N_min)^(1/(L−1))`), and the table holds the finest level's *surface* cells:
    ///   `T = next_pow2(2·(n_x n_y + n_y n_z + n_z n_x))` (the box's surface area in finest cells,
    ///   a proxy for the scene's surfaces), at least 2^14 and at most the configured
    ///   `log2_hashmap_size`, which acts as the memory budget.
    /// * Triangle wave: octaves so that the finest period is about `min_feature_size`
    ///   (`n = ceil(log2 N_max) + 1`, at most the configured count).
    pub fn sized_for_scene(
        &self,
        scene: &SceneBox,
        min_feature_size: f32,
    ) -> Result<(Self, Sizing), CacheError> {
        let ext = scene.extent();
        if !ext.iter().all(|e| e.is_finite() && *e >= 0.0) || ext.iter().all(|e| *e <= 0.0) {
            return Err(CacheError::Config {
                field: "scene_box".into(),
                message: format!("invalid extent {ext:?}"),
            });
        }
        if !(min_feature_size.is_finite() && min_feature_size > 0.0) {
            return Err(CacheError::Config {
                field: "min_feature_size".into(),
                message: format!("must be finite and > 0, got {min_feature_size}"),
            });
        }
        let longest = ext.iter().cloned().fold(0.0f32, f32::max);
        let n_max = (longest / min_feature_size).ceil().clamp(2.0, 1_048_576.0);
        let mut out = self.clone();
        let mut sizing = Sizing {
            finest_resolution: n_max as u32,
            per_level_scale: None,
            log2_hashmap_size: None,
            n_frequencies: None,
            param_count: 0,
            memory_bytes: 0,
        };
        for n in out.encoding.nested.iter_mut() {
            match n {
                NestedEncoding::HashGrid {
                    n_levels,
                    log2_hashmap_size,
                    base_resolution,
                    per_level_scale,
                    ..
                } => {
                    let n_max = n_max.max(*base_resolution);
                    *per_level_scale = if *n_levels > 1 {
                        (n_max / *base_resolution).powf(1.0 / (*n_levels - 1) as f32)
                    } else {
                        1.0
                    };
                    let cells: [f64; 3] = std::array::from_fn(|k| {
                        (f64::from(ext[k] / longest) * f64::from(n_max))
                            .ceil()
                            .max(1.0)
                    });
                    let surface =
                        2.0 * (cells[0] * cells[1] + cells[1] * cells[2] + cells[2] * cells[0]);
                    let log2 = (surface.log2().ceil() as u32).clamp(14, *log2_hashmap_size);
                    *log2_hashmap_size = log2;
                    sizing.per_level_scale = Some(*per_level_scale);
                    sizing.log2_hashmap_size = Some(log2);
                }
                NestedEncoding::TriangleWave { n_frequencies, .. } => {
                    let n = ((n_max.log2().ceil() as u32) + 1).clamp(1, *n_frequencies);
                    *n_frequencies = n;
                    sizing.n_frequencies = Some(n);
                }
                _ => {}
            }
        }
        out.validate()?;
        let layout = ModelLayout::new(&out);
        sizing.param_count = layout.param_count();
        sizing.memory_bytes = layout.training_memory_bytes();
        Ok((out, sizing))
    }
}
