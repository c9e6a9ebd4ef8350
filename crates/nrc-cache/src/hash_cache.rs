//! The non-neural baseline: a spatially hashed radiance cache, the way NVIDIA's SHaRC and
//! bevy_solari's world cache build one (and the kind of cache the NRC thesis compares against,
//! §7.3). It learns from the same training records as the neural cache and answers the same
//! queries, so that "what does the network buy" is one switch.
//!
//! - **Cells**: a record's position quantised to a grid whose cell is `cell` times the scene
//!   box's largest extent, doubled per level of detail: a point at distance `d` from the camera
//!   uses level `⌊log2(max(d / (lod_cells · cell), 1))⌋` (clamped to `levels − 1`), so that a
//!   cell covers about the same number of pixels near and far (SHaRC's distance-based
//!   levels). The key also holds the normal's dominant axis and sign (6 bins: the two sides of
//!   a wall never share a cell) and, with `direction_bins`, the outgoing direction's (6 more).
//! - **Table**: open addressing over a fixed number of slots (`2^log2_capacity`, a fixed memory
//!   budget), linear probing of at most [`MAX_PROBES`] slots, the full 64-bit key stored as the
//!   checksum; a record or lookup that finds neither its key nor a free slot is counted as a
//!   collision (and dropped, or answered by a coarser level).
//! - **Averaging**: a frame's records are summed per cell, then blended into the cell's value
//!   as a count-limited running mean: `v ← (v·n + Σ) / (n + k)`, `n ← min(n + k, max_samples)`
//!   (an exponential average of time constant `max_samples` samples once the count saturates,
//!   so the cache follows a changing scene). Each record also accumulates into the coarser
//!   levels of its point, so that a lookup whose own cell is empty falls back to a coarser
//!   one.
//! - **Eviction**: a cell not updated for `stale_frames` frames is removed by backward-shift
//!   deletion (the probe runs stay whole), as SHaRC evicts stale entries; the sweep runs every
//!   eighth of that age (a frame's own update touches only the cells its records reached).
//! - **Lookups**: the cell of the query's level, or the first non-empty coarser one; with
//!   `jitter`, the position is offset by up to half a cell per axis first (a hash of the query,
//!   so answers are deterministic), which hides cell borders at the cost of noise.

use rayon::prelude::*;

use crate::batch::check_record;
use crate::record::luminance;
use crate::{CacheQuery, SceneBox, TrainingBatch};

/// Slots probed before a key counts as a collision.
pub const MAX_PROBES: usize = 16;

/// The hash cache's settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HashCacheConfig {
    /// Cell edge at the finest level, as a fraction of the scene box's largest extent.
    pub cell: f32,
    /// Levels of detail (1: one cell size everywhere).
    pub levels: u32,
    /// A point within this many finest cells of the camera uses the finest level.
    pub lod_cells: f32,
    /// Also key cells by the outgoing direction's dominant axis (for glossy surfaces).
    pub direction_bins: bool,
    /// The table holds `2^log2_capacity` cells.
    pub log2_capacity: u32,
    /// The running mean's sample count saturates here (its time constant, in samples).
    pub max_samples: f32,
    /// Cells not updated for this many frames are evicted.
    pub stale_frames: u32,
    /// Jitter lookups by up to half a cell.
    pub jitter: bool,
}

impl Default for HashCacheConfig {
    fn default() -> Self {
        Self {
            cell: 1.0 / 128.0,
            levels: 6,
            lod_cells: 64.0,
            direction_bins: false,
            log2_capacity: 20,
            max_samples: 256.0,
            stale_frames: 64,
            jitter: false,
        }
    }
}

impl HashCacheConfig {
    /// Refuses settings that cannot work, naming the field.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.cell > 0.0 && self.cell <= 1.0) {
            return Err(format!(
                "hash cache: cell must be in (0, 1], got {}",
                self.cell
            ));
        }
        if !(1..=16).contains(&self.levels) {
            return Err(format!(
                "hash cache: levels must be in 1..=16, got {}",
                self.levels
            ));
        }
        if !(self.lod_cells > 0.0 && self.lod_cells.is_finite()) {
            return Err(format!(
                "hash cache: lod_cells must be positive, got {}",
                self.lod_cells
            ));
        }
        // 2^26 cells are 3.2 GB; beyond that an allocation failure would abort the program.
        if !(8..=26).contains(&self.log2_capacity) {
            return Err(format!(
                "hash cache: log2_capacity must be in 8..=26, got {}",
                self.log2_capacity
            ));
        }
        if !(self.max_samples >= 1.0 && self.max_samples.is_finite()) {
            return Err(format!(
                "hash cache: max_samples must be ≥ 1, got {}",
                self.max_samples
            ));
        }
        if self.stale_frames == 0 {
            return Err("hash cache: stale_frames must be at least 1".into());
        }
        Ok(())
    }
}

/// One cell of the table. `key == 0` is a free slot.
#[derive(Clone, Copy, Debug, Default)]
struct Slot {
    key: u64,
    /// The running mean and its sample count.
    value: [f32; 3],
    count: f32,
    /// This frame's sum and weight, not yet blended.
    sum: [f32; 3],
    weight: f32,
    /// The last frame that updated the cell.
    frame: u32,
}

/// What a training call did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HashTrainStats {
    pub used: usize,
    pub dropped_nonfinite: usize,
    pub dropped_absurd: usize,
    /// Records (one per level) that found neither their cell nor a free slot.
    pub collisions: usize,
    /// Cells evicted as stale after this call.
    pub evicted: usize,
    /// Relative L2 error of the cells' values before the update against the records.
    pub loss: f32,
}

/// The spatially hashed radiance cache.
#[derive(Debug)]
pub struct HashCache {
    config: HashCacheConfig,
    scene_box: SceneBox,
    /// Finest cell edge in world units.
    cell: f32,
    /// The camera position (world) the levels of detail are measured from.
    camera: [f32; 3],
    slots: Vec<Slot>,
    frame: u32,
    /// Lookups (since creation) that found no cell at any level.
    misses: std::sync::atomic::AtomicU64,
    /// The content hash of the scene it was trained on (written into snapshots).
    scene_content: Option<String>,
}

impl HashCache {
    /// An empty cache over `scene_box`.
    pub fn new(config: HashCacheConfig, scene_box: SceneBox) -> Result<Self, String> {
        config.validate()?;
        let extent = scene_box.extent().into_iter().fold(0.0f32, f32::max);
        if !(extent > 0.0 && extent.is_finite()) {
            return Err(format!(
                "hash cache: the scene box {scene_box:?} is degenerate"
            ));
        }
        let center = std::array::from_fn(|k| 0.5 * (scene_box.min[k] + scene_box.max[k]));
        Ok(Self {
            config,
            scene_box,
            cell: config.cell * extent,
            camera: center,
            slots: vec![Slot::default(); 1 << config.log2_capacity],
            frame: 0,
            misses: Default::default(),
            scene_content: None,
        })
    }

    pub fn config(&self) -> &HashCacheConfig {
        &self.config
    }

    pub fn scene_box(&self) -> SceneBox {
        self.scene_box
    }

    /// The camera the levels of detail are measured from (world units). The online loop sets it
    /// every frame; a snapshot keeps the last one, so a render from it looks cells up at the
    /// levels they were trained at (a level with no cell falls back to a coarser one).
    pub fn set_camera(&mut self, position: [f32; 3]) {
        self.camera = position;
    }

    pub fn scene_content(&self) -> Option<&str> {
        self.scene_content.as_deref()
    }

    pub fn set_scene_content(&mut self, content: Option<String>) {
        self.scene_content = content;
    }

    /// Cells in use.
    pub fn cells(&self) -> usize {
        self.slots.iter().filter(|s| s.key != 0).count()
    }

    /// Bytes of the table.
    pub fn memory_bytes(&self) -> usize {
        self.slots.len() * std::mem::size_of::<Slot>()
    }

    /// Lookups that found nothing at any level, since creation.
    pub fn misses(&self) -> u64 {
        self.misses.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// One line on what the cache is.
    pub fn describe(&self) -> String {
        let c = &self.config;
        format!(
            "hash cache: {} slots ({:.1} MB), finest cell {:.4} ({} of the box), {} levels, normal{} bins, running mean of up to {} samples, stale after {} frames{}",
            self.slots.len(),
            self.memory_bytes() as f64 / 1e6,
            self.cell,
            c.cell,
            c.levels,
            if c.direction_bins {
                " and direction"
            } else {
                ""
            },
            c.max_samples,
            c.stale_frames,
            if c.jitter { ", jittered lookups" } else { "" }
        )
    }

    fn world(&self, p: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|k| {
            self.scene_box.min[k] + p[k] * (self.scene_box.max[k] - self.scene_box.min[k])
        })
    }

    /// The level of detail of a world point.
    fn level(&self, p: [f32; 3]) -> u32 {
        let d = (0..3)
            .map(|k| (p[k] - self.camera[k]).powi(2))
            .sum::<f32>()
            .sqrt();
        let r = d / (self.config.lod_cells * self.cell);
        if r > 1.0 {
            (r.log2().floor() as u32).min(self.config.levels - 1)
        } else {
            0
        }
    }

    /// The key of world point `p` at `level` (never 0).
    fn key(&self, p: [f32; 3], q: &CacheQuery, level: u32) -> u64 {
        let size = self.cell * (1u32 << level) as f32;
        let mut h = 0xcbf2_9ce4_8422_2325u64 ^ u64::from(level);
        for &x in &p {
            h = mix(h ^ ((x / size).floor() as i64 as u64));
        }
        h = mix(h ^ axis_bin(q.normal));
        if self.config.direction_bins {
            h = mix(h ^ (axis_bin(q.direction) << 8));
        }
        h.max(1)
    }

    /// The slot holding `key`, or a free one to put it in (`None`: a collision).
    fn find(&self, key: u64) -> Option<usize> {
        let mask = self.slots.len() - 1;
        let start = (key as usize) & mask;
        (0..MAX_PROBES)
            .map(|k| (start + k) & mask)
            .find(|&i| self.slots[i].key == key || self.slots[i].key == 0)
    }

    /// The world point of a lookup: the query's, jittered by a hash of it when asked.
    fn lookup_point(&self, q: &CacheQuery, level: u32) -> [f32; 3] {
        let mut p = self.world(q.position);
        if self.config.jitter {
            let size = self.cell * (1u32 << level) as f32;
            let mut h = q.position.iter().fold(0x9e37_79b9_7f4a_7c15u64, |h, x| {
                mix(h ^ u64::from(x.to_bits()))
            });
            for x in &mut p {
                h = mix(h);
                *x += ((h >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * size;
            }
        }
        p
    }

    /// The radiance of a query's cell, or of the first non-empty coarser one.
    fn answer(&self, q: &CacheQuery) -> Option<[f32; 3]> {
        let start = self.level(self.world(q.position));
        (start..self.config.levels).find_map(|level| {
            let key = self.key(self.lookup_point(q, level), q, level);
            let i = self.find(key)?;
            let s = &self.slots[i];
            (s.key == key && s.count > 0.0).then_some(s.value)
        })
    }

    /// Radiance for each query: its cell's mean, or the first non-empty coarser cell's; 0
    /// (a counted miss) where none holds data.
    pub fn infer(&self, queries: &[CacheQuery]) -> Vec<[f32; 3]> {
        queries
            .par_iter()
            .map(|q| {
                self.answer(q).unwrap_or_else(|| {
                    self.misses
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    [0.0; 3]
                })
            })
            .collect()
    }

    /// Lets every cell's running mean weigh at most `keep` samples (`keep` ≥ 0): after a change
    /// in the scene the next records move the cells by `k/(keep + k)` instead of
    /// `k/(max_samples + k)`, the hash cache's way to follow a change quickly (its values stay:
    /// a cell nobody trains again still answers as before).
    pub fn forget(&mut self, keep: f32) {
        let keep = keep.max(0.0);
        for s in &mut self.slots {
            s.count = s.count.min(keep);
        }
    }

    /// Learns one frame's records: each (checked as the neural cache checks them) adds to its
    /// cell at its level and every coarser one; then the frame's sums are blended into the
    /// cells' running means and stale cells evicted.
    pub fn train(&mut self, batch: &TrainingBatch) -> Result<HashTrainStats, String> {
        let n = batch.queries.len();
        let weights = batch.weights.as_ref().map_or(n, Vec::len);
        if batch.targets.len() != n || weights != n {
            return Err(format!(
                "training batch has {n} queries but {} targets and {weights} weights",
                batch.targets.len()
            ));
        }
        let mut stats = HashTrainStats::default();
        let (mut loss, mut loss_n) = (0.0f64, 0usize);
        let mut touched = Vec::new();
        let before: Vec<[f32; 3]> = batch
            .queries
            .par_iter()
            .map(|q| self.answer(q).unwrap_or([0.0; 3]))
            .collect();
        for i in 0..n {
            let (q, t) = (&batch.queries[i], batch.targets[i]);
            let w = batch.weights.as_ref().map_or(1.0, |w| w[i]);
            match check_record(q, &t, w, f32::MAX) {
                Err(crate::batch::Dropped::NonFinite) => {
                    stats.dropped_nonfinite += 1;
                    continue;
                }
                Err(crate::batch::Dropped::Absurd) => {
                    stats.dropped_absurd += 1;
                    continue;
                }
                Ok(()) => {}
            }
            stats.used += 1;
            let (b, tl) = (luminance(before[i]), luminance(t));
            loss += f64::from((b - tl).powi(2) / (b * b + 0.01));
            loss_n += 1;
            let p = self.world(q.position);
            for level in self.level(p)..self.config.levels {
                let key = self.key(p, q, level);
                let Some(s) = self.find(key) else {
                    stats.collisions += 1;
                    continue;
                };
                let slot = &mut self.slots[s];
                if slot.weight == 0.0 {
                    touched.push(s);
                }
                slot.key = key;
                for k in 0..3 {
                    slot.sum[k] += w * t[k];
                }
                slot.weight += w;
            }
        }
        self.frame += 1;
        let (frame, max) = (self.frame, self.config.max_samples);
        for &i in &touched {
            let s = &mut self.slots[i];
            if s.weight <= 0.0 {
                continue;
            }
            let total = s.count + s.weight;
            for k in 0..3 {
                s.value[k] = (s.value[k] * s.count + s.sum[k]) / total;
            }
            s.count = total.min(max);
            s.sum = [0.0; 3];
            s.weight = 0.0;
            s.frame = frame;
        }
        // The sweep for stale cells reads the whole table: every eighth of the stale age.
        if self.frame % (self.config.stale_frames / 8).max(1) == 0 {
            stats.evicted = self.evict();
        }
        stats.loss = (loss / loss_n.max(1) as f64) as f32;
        Ok(stats)
    }

    /// Removes the cells not updated for `stale_frames` frames; returns how many.
    fn evict(&mut self) -> usize {
        let cutoff = self.frame.saturating_sub(self.config.stale_frames);
        let mut evicted = 0;
        let mut i = 0;
        while i < self.slots.len() {
            let s = &self.slots[i];
            if s.key != 0 && s.frame < cutoff {
                self.remove(i);
                evicted += 1;
                // The cell shifted into slot `i`, if any, is looked at next.
            } else {
                i += 1;
            }
        }
        evicted
    }

    /// Empties slot `i` by backward-shift deletion: each later cell of the probe run moves into
    /// the hole when that brings it no farther from its home slot, so every cell stays within
    /// its probe distance and no run is broken (no tombstones, no rebuild).
    fn remove(&mut self, mut hole: usize) {
        let mask = self.slots.len() - 1;
        self.slots[hole] = Slot::default();
        let mut j = hole;
        loop {
            j = (j + 1) & mask;
            let key = self.slots[j].key;
            if key == 0 {
                return;
            }
            let home = key as usize & mask;
            if j.wrapping_sub(home) & mask >= j.wrapping_sub(hole) & mask {
                self.slots[hole] = self.slots[j];
                self.slots[j] = Slot::default();
                hole = j;
            }
        }
    }
}

/// The `i`-th `w`-byte word of `b`.
fn word(b: &[u8], i: usize, w: usize) -> &[u8] {
    &b[i * w..(i + 1) * w]
}

/// Value of a hash-cache snapshot's `magic` field.
pub const SNAPSHOT_MAGIC: &str = "nrc-hash-cache-snapshot";
/// The hash-cache snapshot format's version.
pub const SNAPSHOT_VERSION: u32 = 1;

/// A hash-cache snapshot's metadata (the `nrc_cache` entry of the safetensors header; the
/// envelope is the neural cache's, [`crate::snapshot`]). Tensors: `keys` (U64), `values`
/// (F32, three per cell), `counts` (F32), `frames` (U32), one entry per cell in use, in slot
/// order from just after a free slot (so that loading reinserts each cell in its own slot); `checksum` is FNV-1a over the settings' JSON and the four tensors' bytes in that
/// order (the settings size the table, so a corrupted one is refused before it is allocated).
#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct SnapshotMeta {
    magic: String,
    version: u32,
    config: HashCacheConfig,
    scene_box: SceneBox,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scene_content: Option<String>,
    camera: [f32; 3],
    frame: u32,
    cells: usize,
    checksum: String,
}

impl HashCache {
    /// Writes the cells in use, the settings and the scene's identity, atomically.
    pub fn save(&self, path: &std::path::Path) -> Result<(), crate::CacheError> {
        // Cells in slot order from just after a free slot: no probe run then wraps past the
        // start, so inserting them in this order on load puts each back in its own slot.
        let mask = self.slots.len() - 1;
        let start = self.slots.iter().position(|s| s.key == 0).unwrap_or(0);
        let live: Vec<&Slot> = (start..start + self.slots.len())
            .map(|k| &self.slots[k & mask])
            .filter(|s| s.key != 0)
            .collect();
        let keys: Vec<u64> = live.iter().map(|s| s.key).collect();
        let values: Vec<f32> = live.iter().flat_map(|s| s.value).collect();
        let counts: Vec<f32> = live.iter().map(|s| s.count).collect();
        let frames: Vec<u32> = live.iter().map(|s| s.frame).collect();
        let bytes: [&[u8]; 4] = [
            bytemuck::cast_slice(&keys),
            bytemuck::cast_slice(&values),
            bytemuck::cast_slice(&counts),
            bytemuck::cast_slice(&frames),
        ];
        let settings = serde_json::to_string(&self.config).expect("settings serialise");
        let summed: [&[u8]; 5] = [settings.as_bytes(), bytes[0], bytes[1], bytes[2], bytes[3]];
        let meta = SnapshotMeta {
            magic: SNAPSHOT_MAGIC.into(),
            version: SNAPSHOT_VERSION,
            config: self.config,
            scene_box: self.scene_box,
            scene_content: self.scene_content.clone(),
            camera: self.camera,
            frame: self.frame,
            cells: live.len(),
            checksum: crate::snapshot::checksum(&summed),
        };
        use safetensors::tensor::Dtype;
        let n = live.len();
        let tensors = [
            ("keys", Dtype::U64, vec![n], bytes[0]),
            ("values", Dtype::F32, vec![n * 3], bytes[1]),
            ("counts", Dtype::F32, vec![n], bytes[2]),
            ("frames", Dtype::U32, vec![n], bytes[3]),
        ];
        let json = serde_json::to_string(&meta).expect("metadata serialises");
        crate::snapshot::write_envelope(path, &tensors, json)
    }

    /// Reads a snapshot [`HashCache::save`] wrote; a truncated, corrupted or foreign file is an
    /// error that says what is wrong.
    pub fn load(path: &std::path::Path) -> Result<Self, crate::CacheError> {
        use crate::snapshot::bad;
        use safetensors::tensor::{Dtype, SafeTensors};
        let (data, json, magic) = crate::snapshot::read_envelope(path)?;
        if magic != SNAPSHOT_MAGIC {
            return Err(bad(
                path,
                format!("not a hash-cache snapshot (magic {magic:?})"),
            ));
        }
        let meta: SnapshotMeta = serde_json::from_str(&json)
            .map_err(|e| bad(path, format!("malformed metadata: {e}")))?;
        if meta.version != SNAPSHOT_VERSION {
            return Err(bad(
                path,
                format!(
                    "format version {} is not supported (this build reads version {SNAPSHOT_VERSION})",
                    meta.version
                ),
            ));
        }
        let n = meta.cells;
        let tensors = SafeTensors::deserialize(&data)
            .map_err(|e| bad(path, format!("truncated or corrupted tensor data ({e})")))?;
        let mut raw: Vec<&[u8]> = Vec::with_capacity(4);
        for (name, dtype, len) in [
            ("keys", Dtype::U64, n),
            ("values", Dtype::F32, n.saturating_mul(3)),
            ("counts", Dtype::F32, n),
            ("frames", Dtype::U32, n),
        ] {
            let t = tensors
                .tensor(name)
                .map_err(|_| bad(path, format!("tensor {name:?} is missing")))?;
            if t.dtype() != dtype || t.shape() != [len] {
                return Err(bad(
                    path,
                    format!(
                        "tensor {name:?} is {:?} of shape {:?}, expected {dtype:?} of [{len}]",
                        t.dtype(),
                        t.shape()
                    ),
                ));
            }
            raw.push(t.data());
        }
        let settings = serde_json::to_string(&meta.config).expect("settings serialise");
        let mut summed = vec![settings.as_bytes()];
        summed.extend(&raw);
        let sum = crate::snapshot::checksum(&summed);
        if sum != meta.checksum {
            return Err(bad(
                path,
                format!(
                    "checksum mismatch (stored {}, computed {sum}): the data is corrupted",
                    meta.checksum
                ),
            ));
        }
        let mut cache = Self::new(meta.config, meta.scene_box)
            .map_err(|e| bad(path, format!("stored settings: {e}")))?;
        if n > cache.slots.len() {
            return Err(bad(
                path,
                format!(
                    "{n} cells, more than the table's {} slots",
                    cache.slots.len()
                ),
            ));
        }
        for i in 0..n {
            let key = u64::from_le_bytes(word(raw[0], i, 8).try_into().expect("8 bytes"));
            let f32_at =
                |b: &[u8], k: usize| f32::from_le_bytes(word(b, k, 4).try_into().expect("4 bytes"));
            let slot = Slot {
                key,
                value: [
                    f32_at(raw[1], 3 * i),
                    f32_at(raw[1], 3 * i + 1),
                    f32_at(raw[1], 3 * i + 2),
                ],
                count: f32_at(raw[2], i),
                sum: [0.0; 3],
                weight: 0.0,
                frame: u32::from_le_bytes(word(raw[3], i, 4).try_into().expect("4 bytes")),
            };
            let sane = slot.value.iter().all(|v| v.is_finite() && *v >= 0.0)
                && slot.count.is_finite()
                && slot.count >= 0.0;
            if key == 0 || !sane {
                return Err(bad(
                    path,
                    format!(
                        "cell {i} is malformed (key {key}, value {:?}, count {})",
                        slot.value, slot.count
                    ),
                ));
            }
            match cache.find(key) {
                Some(at) if cache.slots[at].key == 0 => cache.slots[at] = slot,
                Some(_) => return Err(bad(path, format!("cell {i}: key {key} appears twice"))),
                None => {
                    return Err(bad(
                        path,
                        format!("cell {i} finds no slot: the table is corrupted"),
                    ));
                }
            }
        }
        cache.camera = meta.camera;
        cache.frame = meta.frame;
        cache.scene_content = meta.scene_content;
        Ok(cache)
    }
}

/// The dominant axis of `v` and its sign, 0..6 (a zero or non-finite vector: +z).
fn axis_bin(v: [f32; 3]) -> u64 {
    let a = v.map(|x| if x.is_finite() { x } else { 0.0 });
    let k = (0..3)
        .max_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs()))
        .unwrap_or(2);
    if a == [0.0; 3] {
        return 4;
    }
    2 * k as u64 + u64::from(a[k] < 0.0)
}

/// A 64-bit finaliser (splitmix64's).
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn query(p: [f32; 3], n: [f32; 3]) -> CacheQuery {
        CacheQuery {
            position: p,
            direction: n,
            normal: n,
            roughness: 1.0,
            diffuse: [0.5; 3],
            specular: [0.0; 3],
        }
    }

    fn cache(config: HashCacheConfig) -> HashCache {
        HashCache::new(config, SceneBox::default()).unwrap()
    }

    /// A 256-slot table of fine cells at one level that evicts after 2 frames.
    fn crowded() -> HashCacheConfig {
        HashCacheConfig {
            log2_capacity: 8,
            levels: 1,
            stale_frames: 2,
            cell: 1.0 / 1024.0,
            ..Default::default()
        }
    }

    fn batch(records: Vec<(CacheQuery, [f32; 3])>) -> TrainingBatch {
        let (queries, targets) = records.into_iter().unzip();
        TrainingBatch {
            queries,
            targets,
            weights: None,
        }
    }

    /// A cell's answer is the mean of its records (within the running mean's exactness), the
    /// two sides of a wall do not mix, and a point never trained falls back to a coarser level.
    #[test]
    fn a_cell_answers_the_mean_of_its_records_and_sides_do_not_mix() {
        let mut c = cache(HashCacheConfig::default());
        let up = [0.0, 0.0, 1.0];
        let down = [0.0, 0.0, -1.0];
        let p = [0.501, 0.502, 0.5];
        let targets = [1.0f32, 3.0, 2.0, 6.0];
        let recs: Vec<_> = targets
            .iter()
            .map(|&t| (query(p, up), [t; 3]))
            .chain([(query(p, down), [100.0; 3])])
            .collect();
        c.train(&batch(recs)).unwrap();
        let a = c.infer(&[query(p, up), query(p, down)]);
        assert!((a[0][0] - 3.0).abs() < 1e-5, "{:?}", a[0]);
        assert!((a[1][0] - 100.0).abs() < 1e-3, "{:?}", a[1]);
        // A nearby point in an untrained finest cell answers from a coarser cell.
        let near = [0.505 + c.config.cell, 0.502, 0.5];
        assert!(c.infer(&[query(near, up)])[0][0] > 0.0);
        // Far away, nothing: a counted miss.
        assert_eq!(c.infer(&[query([0.05, 0.9, 0.1], up)])[0], [0.0; 3]);
        assert_eq!(c.misses(), 1);
    }

    /// After `forget`, a cell follows the next frame's records by `k/(keep + k)`; without it, by
    /// `k/(max_samples + k)` (the control).
    #[test]
    fn forgetting_lets_the_next_records_move_the_cells() {
        let p = [0.5, 0.5, 0.5];
        let up = [0.0, 1.0, 0.0];
        let frame = |c: &mut HashCache, v: f32| {
            c.train(&batch((0..4).map(|_| (query(p, up), [v; 3])).collect()))
                .unwrap();
        };
        let after_change = |forget: bool| {
            let mut c = cache(HashCacheConfig::default());
            for _ in 0..100 {
                frame(&mut c, 1.0);
            }
            if forget {
                c.forget(4.0);
            }
            frame(&mut c, 2.0);
            c.infer(&[query(p, up)])[0][0]
        };
        // 4 records against 4 kept samples: halfway to the new value.
        assert!(
            (after_change(true) - 1.5).abs() < 1e-4,
            "{}",
            after_change(true)
        );
        // 4 records against a saturated count of 256: 4/260 of the way.
        let slow = after_change(false);
        assert!((slow - (1.0 + 4.0 / 260.0)).abs() < 1e-4, "{slow}");
    }

    /// Statistical check of the running mean over 32 cells: noisy records of a constant
    /// converge to it, and once the count saturates a cell follows a change within a few time
    /// constants. Negative control: a cell that keeps only its last frame (`max_samples` 1)
    /// fails the same bound.
    #[test]
    fn the_running_mean_converges_and_follows_a_change() {
        let run = |max_samples: f32| {
            let config = HashCacheConfig {
                max_samples,
                ..Default::default()
            };
            let mut c = cache(config);
            let qs: Vec<_> = (0..32)
                .map(|i| query([0.1 + 0.025 * i as f32, 0.3, 0.3], [1.0, 0.0, 0.0]))
                .collect();
            let mut rng = 0x1234_5678u64;
            let mut uniform = || {
                rng = mix(rng);
                (rng >> 40) as f32 / (1u64 << 24) as f32
            };
            let mut frame = |c: &mut HashCache, scale: f32| {
                let recs = qs
                    .iter()
                    .flat_map(|q| {
                        (0..16)
                            .map(|_| (*q, [scale * uniform(); 3]))
                            .collect::<Vec<_>>()
                    })
                    .collect();
                c.train(&batch(recs)).unwrap();
            };
            let rms = |c: &HashCache, mean: f32| {
                let a = c.infer(&qs);
                (a.iter().map(|v| (v[0] - mean).powi(2)).sum::<f32>() / a.len() as f32).sqrt()
            };
            // Targets uniform in [0, 2): mean 1, standard deviation 0.577.
            for _ in 0..64 {
                frame(&mut c, 2.0);
            }
            let settled = rms(&c, 1.0);
            // The light doubles: targets uniform in [0, 4).
            for _ in 0..96 {
                frame(&mut c, 4.0);
            }
            (settled, rms(&c, 2.0))
        };
        // 256 samples of σ 0.577: the mean's σ is 0.036. After the change (96 frames of 16
        // samples at a time constant of 272 samples: e^-5.6 of the gap left) the EMA's σ is
        // about 1.155 / √544 = 0.05.
        let (settled, changed) = run(256.0);
        assert!(settled < 0.07, "settled RMS error {settled}");
        assert!(changed < 0.1, "RMS error after the change {changed}");
        // Without averaging, the last frame's 16 samples: σ 0.144.
        let (control, _) = run(1.0);
        assert!(
            control > 0.07,
            "a cell without averaging passes: the test cannot tell ({control})"
        );
    }

    /// A full table counts collisions instead of losing the cells it holds, and stale cells
    /// are evicted, freeing their slots.
    #[test]
    fn collisions_are_counted_and_stale_cells_evicted() {
        let mut c = cache(crowded());
        let up = [0.0, 0.0, 1.0];
        let recs: Vec<_> = (0..400)
            .map(|i| (query([i as f32 / 400.0, 0.5, 0.5], up), [1.0; 3]))
            .collect();
        let s = c.train(&batch(recs)).unwrap();
        assert_eq!(c.cells(), 256, "the table fills");
        assert_eq!(
            s.collisions,
            400 - 256,
            "every record that found no slot is counted"
        );
        let empty = batch(Vec::new());
        for _ in 0..3 {
            c.train(&empty).unwrap();
        }
        assert_eq!(c.cells(), 0, "stale cells are evicted");
    }

    /// A saved cache loads back answering identically; a flipped byte of its data, a
    /// truncated file and a neural snapshot's magic are refused with a message.
    #[test]
    fn snapshots_round_trip_and_corruption_is_refused() {
        let mut c = cache(HashCacheConfig::default());
        c.set_scene_content(Some("abc123".into()));
        let qs: Vec<_> = (0..50)
            .map(|i| query([0.02 * i as f32, 0.4, 0.6], [0.0, 1.0, 0.0]))
            .collect();
        let recs = qs.iter().map(|q| (*q, [q.position[0], 1.0, 2.0])).collect();
        c.train(&batch(recs)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.nrc");
        c.save(&path).unwrap();
        let back = HashCache::load(&path).unwrap();
        assert_eq!(back.infer(&qs), c.infer(&qs));
        assert_eq!(back.cells(), c.cells());
        assert_eq!(back.scene_content(), Some("abc123"));
        let bytes = std::fs::read(&path).unwrap();
        let mut flipped = bytes.clone();
        let last = flipped.len() - 5;
        flipped[last] ^= 0x40;
        std::fs::write(&path, &flipped).unwrap();
        let e = HashCache::load(&path).unwrap_err().to_string();
        assert!(e.contains("checksum") || e.contains("malformed"), "{e}");
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        let e = HashCache::load(&path).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
        let json = r#"{"magic": "nrc-cache-snapshot", "version": 1}"#.to_string();
        crate::snapshot::write_envelope(&path, &[], json).unwrap();
        let e = HashCache::load(&path).unwrap_err().to_string();
        assert!(e.contains("not a hash-cache snapshot"), "{e}");
    }

    /// Evicting part of a crowded table leaves every live cell findable (backward-shift
    /// deletion keeps the probe runs whole), and a crowded table (150 cells in 256 slots) saves
    /// and loads back with every cell in place.
    #[test]
    fn eviction_and_snapshots_keep_every_cell_of_a_crowded_table() {
        let mut c = cache(crowded());
        let up = [0.0, 0.0, 1.0];
        let qs: Vec<_> = (0..150)
            .map(|i| query([i as f32 / 150.0, 0.5, 0.5], up))
            .collect();
        let recs =
            |qs: &[CacheQuery]| batch(qs.iter().map(|q| (*q, [q.position[0] + 1.0; 3])).collect());
        assert_eq!(c.train(&recs(&qs)).unwrap().collisions, 0);
        assert_eq!(c.cells(), 150);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("full.nrc");
        c.save(&path).unwrap();
        let back = HashCache::load(&path).unwrap();
        assert_eq!(back.infer(&qs), c.infer(&qs), "every cell loads back");
        // Every other cell kept alive while the rest go stale.
        let kept: Vec<_> = qs.iter().step_by(2).copied().collect();
        for _ in 0..4 {
            c.train(&recs(&kept)).unwrap();
        }
        assert_eq!(c.cells(), kept.len(), "the stale half is evicted");
        let answers = c.infer(&kept);
        for (q, a) in kept.iter().zip(&answers) {
            let want = q.position[0] + 1.0;
            assert!(
                (a[0] - want).abs() < 1e-5,
                "a kept cell is lost or wrong: {a:?}"
            );
        }
    }

    #[test]
    fn bad_settings_and_records_are_refused_or_counted() {
        let bad = HashCacheConfig {
            log2_capacity: 40,
            ..Default::default()
        };
        assert!(
            HashCache::new(bad, SceneBox::default())
                .unwrap_err()
                .contains("log2_capacity")
        );
        let flat = SceneBox {
            min: [0.0; 3],
            max: [0.0; 3],
        };
        assert!(
            HashCache::new(HashCacheConfig::default(), flat)
                .unwrap_err()
                .contains("degenerate")
        );
        let mut c = cache(HashCacheConfig::default());
        let q = query([0.5; 3], [0.0, 1.0, 0.0]);
        let s = c
            .train(&batch(vec![
                (q, [f32::NAN; 3]),
                (q, [-1.0; 3]),
                (q, [1.0; 3]),
            ]))
            .unwrap();
        assert_eq!((s.dropped_nonfinite, s.dropped_absurd, s.used), (1, 1, 1));
    }
}
