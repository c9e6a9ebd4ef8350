//! Cache snapshots: one safetensors file holding the whole training state.
//!
//! # Format (version 1)
//!
//! A [safetensors](https://github.com/huggingface/safetensors) file with eight 1-D f32 tensors:
//! `grid`, `grid_adam_m`, `grid_adam_v`, `grid_ema`, `mlp`, `mlp_adam_m`, `mlp_adam_v`, `mlp_ema`
//! (weights, Adam moments and raw — not bias-corrected — EMA of the hash table and the MLP, in
//! the layout of [`crate::model`]; the table may be empty). The safetensors header's
//! `__metadata__` map has one key, `nrc_cache`, whose value is a JSON document:
//!
//! ```json
//! { "magic": "nrc-cache-snapshot", "version": 1, "step": 1200,
//!   "config": { ...the cache configuration... },
//!   "scene_box": { "min": [..], "max": [..] },
//!   "scene_content": "1a2b3c4d5e6f...",
//!   "param_count": 12345, "checksum": "fnv1a64:0123456789abcdef" }
//! ```
//!
//! `lr_start` is optional (absent in older files, and where the learning rate's decay never
//! restarted: 0): the step the decay counts from. `scene_content` is optional (absent in older files, and when the caller gave none): a hex
//! content hash of the scene the cache was trained on, computed by the caller (this crate knows
//! nothing of scenes); [`check_scene`] compares it and the scene box with another scene's.
//! `checksum` is FNV-1a (64-bit) over the little-endian 64-bit words of the eight tensors'
//! bytes in the order above (a final partial word zero-padded); it does not cover the metadata.
//! The EMA tensors hold the raw EMA at `step`. Files are written to a temporary file in the same
//! directory (`tempfile`), synced, and renamed into place.
//!
//! The spatial-hash cache's snapshots use the same envelope with their own `magic`
//! ([`crate::hash_cache::SNAPSHOT_MAGIC`]) and tensors; [`crate::Cache::load`] tells the two
//! apart.

use std::io::Write;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};

use crate::config::{CacheConfig, SceneBox};
use crate::error::CacheError;
use crate::model::ModelLayout;
use crate::state::HostState;

/// Value of the `magic` field.
pub const MAGIC: &str = "nrc-cache-snapshot";
/// Current format version.
pub const VERSION: u32 = 1;
const METADATA_KEY: &str = "nrc_cache";
const NAMES: [&str; 8] = [
    "grid",
    "grid_adam_m",
    "grid_adam_v",
    "grid_ema",
    "mlp",
    "mlp_adam_m",
    "mlp_adam_v",
    "mlp_ema",
];

#[derive(Serialize, Deserialize)]
struct Metadata {
    magic: String,
    version: u32,
    step: u32,
    config: serde_json::Value,
    scene_box: SceneBox,
    /// Hex content hash of the scene, given by the caller; absent in older files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scene_content: Option<String>,
    /// The step the learning rate's decay counts from (its last restart); absent (0) in older
    /// files and where it never restarted.
    #[serde(default, skip_serializing_if = "is_zero")]
    lr_start: u32,
    param_count: usize,
    checksum: String,
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

/// A snapshot read back.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The configuration it was made with.
    pub config: CacheConfig,
    /// Its scene box.
    pub scene_box: SceneBox,
    /// The content hash of its scene (hex, computed by whoever saved it); `None` when the file
    /// has none (older snapshots, or saved without one).
    pub scene_content: Option<String>,
    /// Steps taken.
    pub step: u32,
    /// The step the learning rate's decay counts from
    /// ([`crate::RadianceCache::restart_learning_rate`]; 0 in files without it).
    pub lr_start: u32,
    /// The training state.
    pub state: HostState,
}

fn arrays(s: &HostState) -> [&[f32]; 8] {
    [
        &s.grid,
        &s.grid_m,
        &s.grid_v,
        &s.grid_ema,
        &s.mlp,
        &s.mlp_m,
        &s.mlp_v,
        &s.mlp_ema,
    ]
}

/// FNV-1a over 64-bit words.
pub(crate) fn checksum(parts: &[&[u8]]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in parts {
        let mut chunks = p.chunks_exact(8);
        for c in &mut chunks {
            h ^= u64::from_le_bytes(c.try_into().expect("8 bytes"));
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        let rest = chunks.remainder();
        if !rest.is_empty() {
            let mut w = [0u8; 8];
            w[..rest.len()].copy_from_slice(rest);
            h ^= u64::from_le_bytes(w);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    format!("fnv1a64:{h:016x}")
}

pub(crate) fn io_err(path: &Path, e: impl std::fmt::Display) -> CacheError {
    CacheError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

pub(crate) fn bad(path: &Path, message: impl Into<String>) -> CacheError {
    CacheError::Snapshot {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// Writes a snapshot atomically (temporary file in the same directory, synced, then renamed
/// over `path`). `scene_content` is the scene's content hash, stored as given.
pub fn write(
    path: &Path,
    config: &CacheConfig,
    scene_box: &SceneBox,
    scene_content: Option<&str>,
    (step, lr_start): (u32, u32),
    state: &HostState,
) -> Result<(), CacheError> {
    let bytes: Vec<&[u8]> = arrays(state)
        .iter()
        .map(|a| bytemuck::cast_slice::<f32, u8>(a))
        .collect();
    let meta = Metadata {
        magic: MAGIC.into(),
        version: VERSION,
        step,
        config: serde_json::to_value(config).expect("config serialises"),
        scene_box: *scene_box,
        scene_content: scene_content.map(str::to_owned),
        lr_start,
        param_count: state.grid.len() + state.mlp.len(),
        checksum: checksum(&bytes),
    };
    let tensors: Vec<(&str, Dtype, Vec<usize>, &[u8])> = NAMES
        .iter()
        .zip(bytes.iter().zip(arrays(state)))
        .map(|(name, (b, a))| (*name, Dtype::F32, vec![a.len()], *b))
        .collect();
    let json = serde_json::to_string(&meta).expect("metadata serialises");
    write_envelope(path, &tensors, json)
}

/// Writes named tensors and the metadata JSON (under the `nrc_cache` key) as a safetensors file,
/// atomically: a temporary file in the same directory, synced, then renamed over `path`.
pub(crate) fn write_envelope(
    path: &Path,
    tensors: &[(&str, Dtype, Vec<usize>, &[u8])],
    metadata_json: String,
) -> Result<(), CacheError> {
    let mut views = Vec::with_capacity(tensors.len());
    for (name, dtype, shape, b) in tensors {
        let view = TensorView::new(*dtype, shape.clone(), b)
            .map_err(|e| bad(path, format!("cannot encode tensor {name}: {e}")))?;
        views.push((name.to_string(), view));
    }
    let metadata = std::collections::HashMap::from([(METADATA_KEY.to_string(), metadata_json)]);
    let data = safetensors::tensor::serialize(views, Some(metadata))
        .map_err(|e| bad(path, format!("cannot encode: {e}")))?;
    write_atomically(path, &data)
}

/// Writes `data` to `path` atomically: a temporary file in the same directory, synced, then
/// renamed over `path` (a failure leaves `path` as it was).
pub(crate) fn write_atomically(path: &Path, data: &[u8]) -> Result<(), CacheError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| io_err(path, "not a file path"))?;
    // Named after the target so that a leftover (after a crash) says what it was.
    let prefix = format!(".{}.", name.to_string_lossy());
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    // The default of tempfile is 0o600; a snapshot gets the permissions `File::create` gives
    // (0o666 less the umask).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir).map_err(|e| {
        io_err(
            path,
            format!("cannot create a temporary file in {}: {e}", dir.display()),
        )
    })?;
    // On any error below, dropping `tmp` removes the temporary file.
    let written = (|| {
        tmp.write_all(data)?;
        tmp.flush()?;
        tmp.as_file().sync_all()
    })();
    written.map_err(|e| io_err(path, format!("cannot write: {e}")))?;
    tmp.persist(path).map_err(|e| {
        io_err(
            path,
            format!("cannot move the temporary file into place: {}", e.error),
        )
    })?;
    Ok(())
}

/// The `magic` of a snapshot file (which kind of cache it holds), read from its header alone.
pub(crate) fn magic_of(path: &Path) -> Result<String, CacheError> {
    use std::io::Read;
    let mut file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    let mut len = [0u8; 8];
    file.read_exact(&mut len)
        .map_err(|_| bad(path, "not a safetensors file or truncated header"))?;
    let len = u64::from_le_bytes(len);
    // The header is a JSON object of tensor entries; a larger one is not a snapshot of ours.
    if len > 100_000_000 {
        return Err(bad(path, format!("header of {len} bytes: not a snapshot")));
    }
    let mut header = Vec::new();
    file.take(len)
        .read_to_end(&mut header)
        .map_err(|e| io_err(path, e))?;
    #[derive(Deserialize)]
    struct Header {
        #[serde(rename = "__metadata__")]
        metadata: Option<std::collections::HashMap<String, String>>,
    }
    #[derive(Deserialize)]
    struct Magic {
        magic: String,
    }
    let h: Header = serde_json::from_slice(&header).map_err(|e| {
        bad(
            path,
            format!("not a safetensors file or truncated header ({e})"),
        )
    })?;
    let json = h
        .metadata
        .and_then(|mut m| m.remove(METADATA_KEY))
        .ok_or_else(|| bad(path, format!("not an nrc-cache snapshot: the safetensors metadata has no {METADATA_KEY:?} entry")))?;
    let magic: Magic =
        serde_json::from_str(&json).map_err(|e| bad(path, format!("malformed metadata: {e}")))?;
    Ok(magic.magic)
}

/// A snapshot file's bytes and its metadata JSON (the `nrc_cache` entry of the safetensors
/// header), with its `magic` field: the kind of snapshot it is.
pub(crate) fn read_envelope(path: &Path) -> Result<(Vec<u8>, String, String), CacheError> {
    let data = std::fs::read(path).map_err(|e| io_err(path, e))?;
    let (_, header) = SafeTensors::read_metadata(&data).map_err(|e| {
        bad(
            path,
            format!("not a safetensors file or truncated header ({e})"),
        )
    })?;
    let json = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(METADATA_KEY))
        .ok_or_else(|| bad(path, format!("not an nrc-cache snapshot: the safetensors metadata has no {METADATA_KEY:?} entry")))?
        .clone();
    #[derive(Deserialize)]
    struct Magic {
        magic: String,
    }
    let magic: Magic =
        serde_json::from_str(&json).map_err(|e| bad(path, format!("malformed metadata: {e}")))?;
    Ok((data, json, magic.magic))
}

/// Reads and checks a snapshot: truncated, corrupted, foreign or inconsistent files are errors
/// that say what is wrong.
pub fn read(path: &Path) -> Result<Snapshot, CacheError> {
    let (data, json, _) = read_envelope(path)?;
    let meta: Metadata =
        serde_json::from_str(&json).map_err(|e| bad(path, format!("malformed metadata: {e}")))?;
    if meta.magic != MAGIC {
        return Err(bad(
            path,
            format!("not an nrc-cache snapshot (magic {:?})", meta.magic),
        ));
    }
    if meta.version != VERSION {
        return Err(bad(
            path,
            format!(
                "format version {} is not supported (this build reads version {VERSION})",
                meta.version
            ),
        ));
    }
    let tensors = SafeTensors::deserialize(&data)
        .map_err(|e| bad(path, format!("truncated or corrupted tensor data ({e})")))?;
    let config: CacheConfig = serde_json::from_value(meta.config.clone())
        .map_err(|e| bad(path, format!("stored configuration is malformed: {e}")))?;
    config
        .validate()
        .map_err(|e| bad(path, format!("stored configuration is invalid: {e}")))?;
    let layout = ModelLayout::new(&config);
    let mut values: Vec<Vec<f32>> = Vec::with_capacity(8);
    let mut raw: Vec<Vec<u8>> = Vec::with_capacity(8);
    for (i, name) in NAMES.iter().enumerate() {
        let t = tensors
            .tensor(name)
            .map_err(|_| bad(path, format!("tensor {name:?} is missing")))?;
        if t.dtype() != Dtype::F32 {
            return Err(bad(
                path,
                format!("tensor {name:?} has dtype {:?}, expected F32", t.dtype()),
            ));
        }
        let expected = if i < 4 {
            layout.grid_params
        } else {
            layout.mlp_params()
        };
        if t.shape() != [expected] {
            return Err(bad(
                path,
                format!(
                    "tensor {name:?} has shape {:?}, but the stored configuration needs [{expected}]",
                    t.shape()
                ),
            ));
        }
        let v: Vec<f32> = t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        raw.push(t.data().to_vec());
        values.push(v);
    }
    let parts: Vec<&[u8]> = raw.iter().map(Vec::as_slice).collect();
    let sum = checksum(&parts);
    if sum != meta.checksum {
        return Err(bad(
            path,
            format!(
                "checksum mismatch (stored {}, computed {sum}): the tensor data is corrupted",
                meta.checksum
            ),
        ));
    }
    if meta.param_count != layout.param_count() {
        return Err(bad(
            path,
            format!(
                "parameter count {} does not match the configuration's {}",
                meta.param_count,
                layout.param_count()
            ),
        ));
    }
    let mut it = values.into_iter();
    let mut next = || it.next().expect("eight tensors");
    let state = HostState {
        grid: next(),
        grid_m: next(),
        grid_v: next(),
        grid_ema: next(),
        mlp: next(),
        mlp_m: next(),
        mlp_v: next(),
        mlp_ema: next(),
    };
    Ok(Snapshot {
        config,
        scene_box: meta.scene_box,
        scene_content: meta.scene_content,
        step: meta.step,
        lr_start: meta.lr_start.min(meta.step),
        state,
    })
}

/// Error unless the snapshot's configuration equals `expected`, naming the first differing section.
pub fn check_config(
    path: &Path,
    stored: &CacheConfig,
    expected: &CacheConfig,
) -> Result<(), CacheError> {
    let sections = [
        (
            "encoding",
            serde_json::to_value(&stored.encoding),
            serde_json::to_value(&expected.encoding),
        ),
        (
            "network",
            serde_json::to_value(&stored.network),
            serde_json::to_value(&expected.network),
        ),
        (
            "loss",
            serde_json::to_value(&stored.loss),
            serde_json::to_value(&expected.loss),
        ),
        (
            "optimizer",
            serde_json::to_value(&stored.optimizer),
            serde_json::to_value(&expected.optimizer),
        ),
        (
            "seed",
            serde_json::to_value(stored.seed),
            serde_json::to_value(expected.seed),
        ),
    ];
    for (name, a, b) in sections {
        if a.ok() != b.ok() {
            return Err(bad(
                path,
                format!(
                    "made with a different configuration: the {name:?} section differs from the expected one"
                ),
            ));
        }
    }
    Ok(())
}

/// Abbreviates a content hash to its first 12 characters for messages.
fn abbreviate(hash: &str) -> String {
    let mut chars = hash.chars();
    let head: String = chars.by_ref().take(12).collect();
    if chars.next().is_some() {
        format!("{head}…")
    } else {
        head
    }
}

/// Whether two boxes agree to 1e-4 of the larger box diagonal, corner by corner.
fn same_box(a: SceneBox, b: SceneBox) -> bool {
    let diagonal = |s: SceneBox| {
        s.extent()
            .iter()
            .map(|&e| f64::from(e) * f64::from(e))
            .sum::<f64>()
            .sqrt()
    };
    let tolerance = 1e-4 * diagonal(a).max(diagonal(b));
    let close = |x: &[f32; 3], y: &[f32; 3]| {
        x.iter()
            .zip(y)
            .all(|(&p, &q)| (f64::from(p) - f64::from(q)).abs() <= tolerance)
    };
    close(&a.min, &b.min) && close(&a.max, &b.max)
}

/// Error unless a snapshot belongs to a scene: its content hash (when it has one) must equal
/// `scene_content` (hex, compared ignoring ASCII case) and its box must equal `scene_box` to
/// 1e-4 of the box diagonal. A snapshot without a content hash is checked by its box only.
/// The message names both hashes (abbreviated to 12 characters) or both boxes.
pub fn check_scene(
    snapshot_content: Option<&str>,
    snapshot_box: SceneBox,
    scene_content: &str,
    scene_box: SceneBox,
) -> Result<(), String> {
    if let Some(stored) = snapshot_content.filter(|s| !s.eq_ignore_ascii_case(scene_content)) {
        return Err(format!(
            "the snapshot was trained on another scene (content {}, this scene {}); pass --allow-other-scene to use it anyway",
            abbreviate(stored),
            abbreviate(scene_content)
        ));
    }
    if !same_box(snapshot_box, scene_box) {
        return Err(format!(
            "the snapshot was trained on another scene box (min {:?} max {:?}, this scene min {:?} max {:?}); pass --allow-other-scene to use it anyway",
            snapshot_box.min, snapshot_box.max, scene_box.min, scene_box.max
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene_box(min: [f32; 3], max: [f32; 3]) -> SceneBox {
        SceneBox { min, max }
    }

    const HASH_A: &str = "1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d";
    const HASH_B: &str = "9f8e7d6c5b4a39281706f5e4d3c2b1a0";

    #[test]
    fn check_scene_accepts_the_same_scene() {
        let b = scene_box([-1.0, -2.0, -3.0], [4.0, 5.0, 6.0]);
        assert_eq!(check_scene(Some(HASH_A), b, HASH_A, b), Ok(()));
        // Case of the hex digits does not matter.
        assert_eq!(
            check_scene(Some(HASH_A.to_ascii_uppercase().as_str()), b, HASH_A, b),
            Ok(())
        );
        // A snapshot without a hash is checked by its box only.
        assert_eq!(check_scene(None, b, HASH_B, b), Ok(()));
        // Rounding-level differences of the box are accepted.
        let nudged = scene_box([-1.0 + 1e-6, -2.0, -3.0], [4.0, 5.0, 6.0 - 1e-6]);
        assert_eq!(check_scene(Some(HASH_A), b, HASH_A, nudged), Ok(()));
    }

    #[test]
    fn check_scene_rejects_another_content_hash() {
        let b = SceneBox::default();
        let e = check_scene(Some(HASH_A), b, HASH_B, b).unwrap_err();
        assert!(e.contains("another scene"), "{e}");
        assert!(e.contains("1a2b3c4d5e6f…"), "{e}");
        assert!(e.contains("9f8e7d6c5b4a…"), "{e}");
        assert!(!e.contains(HASH_A) && !e.contains(HASH_B), "{e}");
        assert!(e.contains("--allow-other-scene"), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }

    #[test]
    fn check_scene_rejects_another_box() {
        let a = scene_box([-1.0, -2.0, -3.0], [4.0, 5.0, 6.0]);
        let b = scene_box([-1.0, -2.0, -3.0], [4.0, 5.0, 6.1]);
        for content in [Some(HASH_A), None] {
            let e = check_scene(content, a, HASH_A, b).unwrap_err();
            assert!(e.contains("box"), "{e}");
            assert!(e.contains("6.1"), "{e}");
            assert!(e.contains("--allow-other-scene"), "{e}");
        }
    }

    #[test]
    fn abbreviation_keeps_short_hashes_whole() {
        assert_eq!(abbreviate("abc"), "abc");
        assert_eq!(abbreviate("0123456789ab"), "0123456789ab");
        assert_eq!(abbreviate("0123456789abc"), "0123456789ab…");
    }
}
