//! Portable exports of a neural cache: the inference weights as plain safetensors and a
//! tiny-cuda-nn–style JSON description of everything needed to evaluate them without this
//! project (`docs/export.md` is the format's documentation; the Python test
//! `crates/nrc-py/tests/test_export.py` re-implements it in NumPy and is its specification).
//!
//! A snapshot ([`crate::snapshot`]) holds the whole training state (weights, Adam moments,
//! raw EMA) to resume training; an export holds only what inference reads: the bias-corrected
//! EMA weights (or the weights while the cache follows them), with the table at its inference
//! precision widened to f32.
//!
//! `DIR/config.json` and `DIR/weights.safetensors` are each written atomically (temporary file,
//! synced, renamed), the weights first; the weights' safetensors header holds the same
//! description, so the weights file alone is complete.

use std::path::{Path, PathBuf};

use safetensors::tensor::Dtype;
use serde_json::{Value, json};

use crate::cache::RadianceCache;
use crate::encoding::EncodingKind;
use crate::encoding::hash_grid::PRIMES;
use crate::error::CacheError;
use crate::loss::EXP_CLAMP;
use crate::record::RAW_INPUT_DIMS;

/// Value of the export's `format` field.
pub const FORMAT: &str = "nrc-cache-export";
/// Current export version.
pub const VERSION: u32 = 1;
/// File names inside the export folder.
pub const CONFIG_FILE: &str = "config.json";
pub const WEIGHTS_FILE: &str = "weights.safetensors";

/// What [`export`] wrote.
#[derive(Clone, Debug)]
pub struct Exported {
    pub config: PathBuf,
    pub weights: PathBuf,
    /// Bytes of the two files together.
    pub bytes: u64,
}

/// The export's description (the contents of `config.json`).
pub fn describe(cache: &RadianceCache) -> Value {
    let layout = cache.layout();
    let mut nested = Vec::new();
    for part in &layout.encoding.parts {
        let mut e = match &part.kind {
            EncodingKind::HashGrid(g) => {
                let p = &g.params;
                let levels: Vec<Value> = g
                    .levels
                    .iter()
                    .map(|l| {
                        json!({
                            "scale": l.scale,
                            "resolution": l.resolution,
                            "dense": l.dense,
                            "entries": l.entries,
                            "offset": l.offset,
                        })
                    })
                    .collect();
                json!({
                    "otype": "HashGrid",
                    "n_levels": p.n_levels,
                    "n_features_per_level": p.n_features_per_level,
                    "log2_hashmap_size": p.log2_hashmap_size,
                    "base_resolution": p.base_resolution,
                    "per_level_scale": p.per_level_scale,
                    "hash_primes": PRIMES,
                    "levels": levels,
                    "table": "hash_grid",
                })
            }
            EncodingKind::OneBlob { bins, wrap } => {
                json!({ "otype": "OneBlob", "n_bins": bins, "wrap": wrap })
            }
            EncodingKind::TriangleWave { frequencies } => {
                json!({ "otype": "TriangleWave", "n_frequencies": frequencies })
            }
            EncodingKind::Identity { scale, offset } => {
                json!({ "otype": "Identity", "scale": scale, "offset": offset })
            }
        };
        let fields = e.as_object_mut().expect("an object");
        fields.insert("input_offset".into(), json!(part.in_offset));
        fields.insert("n_dims_to_encode".into(), json!(part.in_dims));
        fields.insert("output_offset".into(), json!(part.out_offset));
        fields.insert("n_output_dims".into(), json!(part.out_dims));
        nested.push(e);
    }
    let layers: Vec<Value> = layout
        .layers
        .iter()
        .enumerate()
        .map(|(i, l)| json!({ "tensor": format!("mlp.{i}"), "shape": [l.inputs, l.outputs] }))
        .collect();
    let output_activation = match layout.output_activation {
        crate::config::OutputActivation::Exponential => "Exponential",
        crate::config::OutputActivation::Softplus => "Softplus",
        crate::config::OutputActivation::ReLU => "ReLU",
    };
    let scene_box = cache.scene_box();
    // The products inference takes (bfloat16 only on the fused CPU path with an even input
    // width, f16 only on the fused wgpu path with shader-f16, f32 elsewhere).
    let mlp_precision = cache.mlp_arithmetic();
    json!({
        "format": FORMAT,
        "version": VERSION,
        "step": cache.step_count(),
        "scene_box": { "min": scene_box.min, "max": scene_box.max },
        "scene_content": cache.scene_content(),
        "query": {
            "fields": [
                ["position", 3], ["direction", 3], ["normal", 3], ["roughness", 1],
                ["diffuse", 3], ["specular", 3]
            ],
            "n_dims": 16,
            "position": "world position mapped into [0,1]^3 by scene_box: (p - min) / (max - min), clamped",
        },
        "raw_inputs": {
            "n_dims": RAW_INPUT_DIMS,
            "fields": [
                ["position", 3], ["direction_spherical", 2], ["normal_spherical", 2],
                ["roughness_encoded", 1], ["diffuse", 3], ["specular", 3]
            ],
        },
        "encoding": {
            "otype": "Composite",
            "nested": nested,
            "n_output_dims_unpadded": layout.encoding.unpadded_dims,
            "n_output_dims": layout.encoding.padded_dims,
            "padding_value": 1.0,
        },
        "network": {
            "otype": "FullyFusedMLP",
            "activation": "ReLU",
            "output_activation": output_activation,
            "exp_clamp": EXP_CLAMP,
            "n_neurons": crate::model::WIDTH,
            "n_hidden_layers": layout.layers.len() - 1,
            "n_output_dims": crate::model::OUTPUTS,
            "biases": false,
            "layers": layers,
            "mlp_precision": mlp_precision,
        },
        "output": "radiance[c] = output_activation(y[c]) * max(diffuse[c] + specular[c], 0)",
        "weights": WEIGHTS_FILE,
    })
}

/// Writes the export of `cache` into the folder `dir` (created if missing).
pub fn export(cache: &RadianceCache, dir: &Path) -> Result<Exported, CacheError> {
    let io = |e: std::io::Error| CacheError::Io {
        path: dir.display().to_string(),
        message: e.to_string(),
    };
    if cfg!(target_endian = "big") {
        return Err(CacheError::Input(
            "exports are written on little-endian machines only (safetensors is little-endian)"
                .into(),
        ));
    }
    std::fs::create_dir_all(dir).map_err(io)?;
    let layout = cache.layout();
    let (grid, mlp) = cache.inference_weights_host();
    let mut tensors: Vec<(String, Vec<usize>, &[f32])> = Vec::new();
    if let Some((g, _)) = layout.encoding.grid() {
        tensors.push((
            "hash_grid".into(),
            vec![g.total_entries, g.features()],
            &grid[..],
        ));
    }
    for (i, l) in layout.layers.iter().enumerate() {
        tensors.push((
            format!("mlp.{i}"),
            vec![l.inputs, l.outputs],
            &mlp[l.offset..l.offset + l.len()],
        ));
    }
    let description = describe(cache);
    let views: Vec<(&str, Dtype, Vec<usize>, &[u8])> = tensors
        .iter()
        .map(|(name, shape, data)| {
            (
                name.as_str(),
                Dtype::F32,
                shape.clone(),
                bytemuck::cast_slice::<f32, u8>(data),
            )
        })
        .collect();
    let weights = dir.join(WEIGHTS_FILE);
    crate::snapshot::write_envelope(&weights, &views, description.to_string())?;
    let config = dir.join(CONFIG_FILE);
    let text = serde_json::to_string_pretty(&description).expect("JSON serialises");
    crate::snapshot::write_atomically(&config, text.as_bytes())?;
    let size = |p: &Path| std::fs::metadata(p).map(|m| m.len()).map_err(io);
    Ok(Exported {
        bytes: size(&weights)? + size(&config)?,
        config,
        weights,
    })
}
