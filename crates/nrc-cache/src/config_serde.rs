//! JSON form of the `"otype"`-tagged components ([`NestedEncoding`], [`OptimizerConfig`]).
//!
//! serde's derived internally-tagged enums buffer their content, which loses the path of a bad
//! field (`encoding.nested[0]` instead of `encoding.nested[0].n_levels`). These hand-written
//! impls read the tag, then deserialize the remaining fields into a per-variant struct with
//! path tracking, and pass the inner path up inside the error message as `@path@ message`;
//! [`split_error`] joins it to the outer path.

use serde::de::{DeserializeOwned, Error as _};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Map, Value};

use std::path::Path;

use crate::config::{
    CacheConfig, NestedEncoding, OptimizerConfig, adam_eps, beta1, beta2, ema_decay, lr, one,
};
use crate::encoding::hash_grid::TablePrecision;
use crate::error::CacheError;

/// Splits a path-tracked error into (field path, message), joining an inner `@path@` prefix.
pub(crate) fn split_error(outer: &str, message: &str) -> (String, String) {
    let (inner, rest) = parse_inner(message);
    let outer = if outer == "." { "" } else { outer };
    let field = match (outer.is_empty(), inner.is_empty()) {
        (true, true) => "(document)".to_string(),
        (true, false) => inner.to_string(),
        (false, true) => outer.to_string(),
        (false, false) => format!("{outer}.{inner}"),
    };
    (field, rest.to_string())
}

fn parse_inner(message: &str) -> (&str, &str) {
    if let Some(rest) = message.strip_prefix('@')
        && let Some(end) = rest.find('@')
    {
        return (&rest[..end], rest[end + 1..].trim_start());
    }
    ("", message)
}

/// Deserializes the fields of one variant, reporting a bad field's path as `@path@ message`.
fn fields<T: DeserializeOwned, E: serde::de::Error>(value: Value) -> Result<T, E> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let (field, message) = split_error(&e.path().to_string(), &e.inner().to_string());
        let field = if field == "(document)" {
            String::new()
        } else {
            field
        };
        E::custom(format!("@{field}@ {message}"))
    })
}

/// Removes and returns the `"otype"` tag.
fn take_otype<E: serde::de::Error>(map: &mut Map<String, Value>) -> Result<String, E> {
    match map.remove("otype") {
        Some(Value::String(s)) => Ok(s),
        Some(other) => Err(E::custom(format!("@otype@ must be a string, got {other}"))),
        None => Err(E::custom("@otype@ missing field `otype`")),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct HashGridFields {
    n_dims_to_encode: u32,
    n_levels: u32,
    n_features_per_level: u32,
    log2_hashmap_size: u32,
    base_resolution: f32,
    per_level_scale: f32,
    #[serde(default)]
    inference_precision: TablePrecision,
    #[serde(default)]
    training_precision: TablePrecision,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OneBlobFields {
    n_dims_to_encode: u32,
    n_bins: u32,
    #[serde(default)]
    wrap: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TriangleWaveFields {
    n_dims_to_encode: u32,
    n_frequencies: u32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct IdentityFields {
    n_dims_to_encode: u32,
    #[serde(default = "one")]
    scale: f32,
    #[serde(default)]
    offset: f32,
}

impl<'de> Deserialize<'de> for NestedEncoding {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let mut map = Map::<String, Value>::deserialize(d)?;
        let otype = take_otype::<D::Error>(&mut map)?;
        let v = Value::Object(map);
        Ok(match otype.as_str() {
            "HashGrid" => {
                let f: HashGridFields = fields(v)?;
                Self::HashGrid {
                    n_dims_to_encode: f.n_dims_to_encode,
                    n_levels: f.n_levels,
                    n_features_per_level: f.n_features_per_level,
                    log2_hashmap_size: f.log2_hashmap_size,
                    base_resolution: f.base_resolution,
                    per_level_scale: f.per_level_scale,
                    inference_precision: f.inference_precision,
                    training_precision: f.training_precision,
                }
            }
            "OneBlob" => {
                let f: OneBlobFields = fields(v)?;
                Self::OneBlob {
                    n_dims_to_encode: f.n_dims_to_encode,
                    n_bins: f.n_bins,
                    wrap: f.wrap,
                }
            }
            "TriangleWave" => {
                let f: TriangleWaveFields = fields(v)?;
                Self::TriangleWave {
                    n_dims_to_encode: f.n_dims_to_encode,
                    n_frequencies: f.n_frequencies,
                }
            }
            "Identity" => {
                let f: IdentityFields = fields(v)?;
                Self::Identity {
                    n_dims_to_encode: f.n_dims_to_encode,
                    scale: f.scale,
                    offset: f.offset,
                }
            }
            other => {
                return Err(D::Error::custom(format!(
                    "@otype@ unknown encoding {other:?} (expected HashGrid, OneBlob, TriangleWave or Identity)"
                )));
            }
        })
    }
}

impl Serialize for NestedEncoding {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        match self {
            Self::HashGrid {
                n_dims_to_encode,
                n_levels,
                n_features_per_level,
                log2_hashmap_size,
                base_resolution,
                per_level_scale,
                inference_precision,
                training_precision,
            } => {
                m.serialize_entry("otype", "HashGrid")?;
                m.serialize_entry("n_dims_to_encode", n_dims_to_encode)?;
                m.serialize_entry("n_levels", n_levels)?;
                m.serialize_entry("n_features_per_level", n_features_per_level)?;
                m.serialize_entry("log2_hashmap_size", log2_hashmap_size)?;
                m.serialize_entry("base_resolution", base_resolution)?;
                m.serialize_entry("per_level_scale", per_level_scale)?;
                m.serialize_entry("inference_precision", inference_precision)?;
                m.serialize_entry("training_precision", training_precision)?;
            }
            Self::OneBlob {
                n_dims_to_encode,
                n_bins,
                wrap,
            } => {
                m.serialize_entry("otype", "OneBlob")?;
                m.serialize_entry("n_dims_to_encode", n_dims_to_encode)?;
                m.serialize_entry("n_bins", n_bins)?;
                m.serialize_entry("wrap", wrap)?;
            }
            Self::TriangleWave {
                n_dims_to_encode,
                n_frequencies,
            } => {
                m.serialize_entry("otype", "TriangleWave")?;
                m.serialize_entry("n_dims_to_encode", n_dims_to_encode)?;
                m.serialize_entry("n_frequencies", n_frequencies)?;
            }
            Self::Identity {
                n_dims_to_encode,
                scale,
                offset,
            } => {
                m.serialize_entry("otype", "Identity")?;
                m.serialize_entry("n_dims_to_encode", n_dims_to_encode)?;
                m.serialize_entry("scale", scale)?;
                m.serialize_entry("offset", offset)?;
            }
        }
        m.end()
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EmaFields {
    #[serde(default = "ema_decay")]
    decay: f32,
    nested: OptimizerConfig,
}

/// tiny-cuda-nn's defaults.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DecayFields {
    #[serde(default = "decay_start")]
    decay_start: u32,
    #[serde(default = "decay_interval")]
    decay_interval: u32,
    #[serde(default = "decay_base")]
    decay_base: f32,
    #[serde(default = "decay_end")]
    decay_end: u32,
    nested: OptimizerConfig,
}

fn decay_start() -> u32 {
    10_000
}
fn decay_interval() -> u32 {
    10_000
}
fn decay_base() -> f32 {
    0.1
}
fn decay_end() -> u32 {
    10_000_000
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AdamFields {
    #[serde(default = "lr")]
    learning_rate: f32,
    #[serde(default = "beta1")]
    beta1: f32,
    #[serde(default = "beta2")]
    beta2: f32,
    #[serde(default = "adam_eps")]
    epsilon: f32,
    #[serde(default)]
    l2_reg: f32,
}

impl<'de> Deserialize<'de> for OptimizerConfig {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let mut map = Map::<String, Value>::deserialize(d)?;
        let otype = take_otype::<D::Error>(&mut map)?;
        let v = Value::Object(map);
        Ok(match otype.as_str() {
            "EMA" => {
                let f: EmaFields = fields(v)?;
                Self::EMA {
                    decay: f.decay,
                    nested: Box::new(f.nested),
                }
            }
            "ExponentialDecay" => {
                let f: DecayFields = fields(v)?;
                Self::ExponentialDecay {
                    decay_start: f.decay_start,
                    decay_interval: f.decay_interval,
                    decay_base: f.decay_base,
                    decay_end: f.decay_end,
                    nested: Box::new(f.nested),
                }
            }
            "Adam" => {
                let f: AdamFields = fields(v)?;
                Self::Adam {
                    learning_rate: f.learning_rate,
                    beta1: f.beta1,
                    beta2: f.beta2,
                    epsilon: f.epsilon,
                    l2_reg: f.l2_reg,
                }
            }
            other => {
                return Err(D::Error::custom(format!(
                    "@otype@ unknown optimizer {other:?} (expected EMA, ExponentialDecay or Adam)"
                )));
            }
        })
    }
}

impl Serialize for OptimizerConfig {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        match self {
            Self::EMA { decay, nested } => {
                m.serialize_entry("otype", "EMA")?;
                m.serialize_entry("decay", decay)?;
                m.serialize_entry("nested", nested)?;
            }
            Self::ExponentialDecay {
                decay_start,
                decay_interval,
                decay_base,
                decay_end,
                nested,
            } => {
                m.serialize_entry("otype", "ExponentialDecay")?;
                m.serialize_entry("decay_start", decay_start)?;
                m.serialize_entry("decay_interval", decay_interval)?;
                m.serialize_entry("decay_base", decay_base)?;
                m.serialize_entry("decay_end", decay_end)?;
                m.serialize_entry("nested", nested)?;
            }
            Self::Adam {
                learning_rate,
                beta1,
                beta2,
                epsilon,
                l2_reg,
            } => {
                m.serialize_entry("otype", "Adam")?;
                m.serialize_entry("learning_rate", learning_rate)?;
                m.serialize_entry("beta1", beta1)?;
                m.serialize_entry("beta2", beta2)?;
                m.serialize_entry("epsilon", epsilon)?;
                m.serialize_entry("l2_reg", l2_reg)?;
            }
        }
        m.end()
    }
}

impl CacheConfig {
    /// Parses and validates a JSON document.
    pub fn from_json_str(json: &str) -> Result<Self, CacheError> {
        let de = &mut serde_json::Deserializer::from_str(json);
        let config: Self = serde_path_to_error::deserialize(de).map_err(|e| {
            let (field, message) = split_error(&e.path().to_string(), &e.inner().to_string());
            CacheError::Config { field, message }
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Reads, parses and validates a JSON file.
    pub fn from_file(path: &Path) -> Result<Self, CacheError> {
        let text = std::fs::read_to_string(path).map_err(|e| CacheError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_json_str(&text)
    }
}
