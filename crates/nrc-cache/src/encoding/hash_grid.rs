//! Multiresolution hash-grid encoding (Müller et al. 2022), tiny-cuda-nn conventions.
//!
//! # Specification (the CPU kernels here and the WGSL kernels in `shaders/` implement exactly this)
//!
//! Parameters: `L` levels, `F` features per level, table size `T = 2^log2T` entries per level,
//! base resolution `N_min`, per-level scale `b`. For level `l`:
//!
//! * scale `s_l = N_min · b^l − 1`, resolution `r_l = ceil(s_l) + 1`;
//! * the level is **dense** when `r_l³ ≤ T`: it holds `E_l = min(T, round_up(r_l³, 8))` entries and
//!   a grid vertex `(x, y, z)` has index `(x + y·r_l + z·r_l²) mod E_l` (computed in u32; vertices at
//!   coordinate `r_l`, reached only for inputs next to 1, alias as in tiny-cuda-nn);
//! * otherwise it is **hashed**: `E_l = T` and the index is
//!   `(x·1 ⊕ y·2654435761 ⊕ z·805459861) & (T − 1)` with wrapping u32 products.
//!
//! For an input `p` (clamped to [0,1]³): `pos = p·s_l + 0.5`, `cell = floor(pos)`, `w = pos − cell`; the
//! level's `F` features are the trilinear interpolation of the 8 vertices `cell + c`,
//! `c ∈ {0,1}³`, with weight `Π_d (c_d ? w_d : 1 − w_d)`. The output is level-major:
//! `out[l·F + f]`.
//!
//! Parameters are laid out level-major `[level][entry][feature]`, level `l` starting at entry
//! offset `Σ_{k<l} E_k`; they are initialised uniformly in ±1e-4.
//!
//! The backward pass scatters `w_c · ∂L/∂out[l·F + f]` into the gradient of the 8 vertices'
//! features, and (for gradient checks) gives `∂L/∂p_d = Σ_l s_l Σ_c ∂w_c/∂pos_d · ⟨feature_c, ∂L/∂out_l⟩`.

use serde::{Deserialize, Serialize};

/// Hash primes of the spatial hash, one per dimension (tiny-cuda-nn).
pub const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// Hyper-parameters of a hash grid (the JSON fields of a `HashGrid` encoding).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HashGridParams {
    /// Number of levels L.
    pub n_levels: u32,
    /// Features per level F.
    pub n_features_per_level: u32,
    /// log2 of the table size T per level.
    pub log2_hashmap_size: u32,
    /// Resolution N_min of the coarsest level.
    pub base_resolution: f32,
    /// Growth factor b between levels.
    pub per_level_scale: f32,
    /// Precision of the table the fused CPU inference reads.
    pub inference_precision: TablePrecision,
    /// Precision of the weights the fused CPU training forward pass reads (Adam's master
    /// weights, moments and EMA stay f32).
    pub training_precision: TablePrecision,
}

/// Precision of a table the fused CPU path reads: the materialised inference table
/// (`inference_precision`) or the copy of the weights the training forward pass reads
/// (`training_precision`). Adam's master weights, moments and EMA are always f32, and snapshots
/// store f32.
///
/// `f16` rounds each feature to the nearest half (clamped to ±65504): half the bytes per entry
/// and an eighth of the bytes of a training record, so the table's random reads touch fewer
/// lines and hit the last-level cache more often. This is tiny-cuda-nn's mixed precision: its
/// hash grid is read in half precision while the optimizer keeps full-precision master
/// weights. Values move by about 2^-11 relative per feature. The other paths read f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TablePrecision {
    /// Single precision (the default): inference reads the values training produced.
    #[default]
    F32,
    /// Half precision, rounded to nearest even.
    F16,
}

/// One level of a hash grid, derived from [`HashGridParams`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridLevel {
    /// `s_l`.
    pub scale: f32,
    /// `r_l`.
    pub resolution: u32,
    /// Dense indexing (true) or spatial hash (false).
    pub dense: bool,
    /// Entries `E_l` of this level.
    pub entries: u32,
    /// First entry of this level in the parameter table.
    pub offset: usize,
}

/// A hash grid's derived layout: the per-level scale, resolution, indexing mode and offsets.
#[derive(Clone, Debug, PartialEq)]
pub struct HashGrid {
    /// The hyper-parameters.
    pub params: HashGridParams,
    /// Derived per-level layout.
    pub levels: Vec<GridLevel>,
    /// Total entries over all levels.
    pub total_entries: usize,
}

/// Vertex indices and trilinear weights of one level for one input.
#[derive(Clone, Copy, Debug, Default)]
pub struct Corners {
    /// Entry index (absolute, including the level offset) of each of the 8 vertices.
    pub index: [u32; 8],
    /// Trilinear weight of each vertex.
    pub weight: [f32; 8],
    /// Fractional position `w` within the cell, per dimension.
    pub frac: [f32; 3],
}

impl HashGrid {
    /// Derives the level layout from the hyper-parameters (assumed validated).
    pub fn new(params: HashGridParams) -> Self {
        let t = 1u64 << params.log2_hashmap_size;
        let mut offset = 0usize;
        let levels = (0..params.n_levels)
            .map(|l| {
                let scale = level_scale(params.base_resolution, params.per_level_scale, l);
                let resolution = scale.ceil() as u32 + 1;
                let r3 = u64::from(resolution).pow(3);
                let dense = r3 <= t;
                let entries = if dense { t.min(r3.div_ceil(8) * 8) } else { t } as u32;
                let level = GridLevel {
                    scale,
                    resolution,
                    dense,
                    entries,
                    offset,
                };
                offset += entries as usize;
                level
            })
            .collect();
        Self {
            params,
            levels,
            total_entries: offset,
        }
    }

    /// The batch kernels' per-level constants.
    pub fn fast_levels(&self) -> Vec<FastLevel> {
        self.levels.iter().map(FastLevel::new).collect()
    }

    /// Number of features F per level.
    pub fn features(&self) -> usize {
        self.params.n_features_per_level as usize
    }

    /// Output dimensions L·F.
    pub fn output_dims(&self) -> usize {
        self.levels.len() * self.features()
    }

    /// Number of parameters (entries · F).
    pub fn param_count(&self) -> usize {
        self.total_entries * self.features()
    }

    /// Resolution of the finest level.
    pub fn finest_resolution(&self) -> u32 {
        self.levels.last().map_or(0, |l| l.resolution)
    }

    /// Vertex indices and weights of level `l` for input `p` (components in [0,1]).
    #[inline(always)]
    pub fn corners(&self, level: &GridLevel, p: [f32; 3]) -> Corners {
        let (lower, frac) = cell(level.scale, p);
        let mut out = Corners {
            frac,
            ..Corners::default()
        };
        for c in 0..8u32 {
            let v = [
                lower[0] + (c & 1),
                lower[1] + ((c >> 1) & 1),
                lower[2] + ((c >> 2) & 1),
            ];
            let mut w = 1.0;
            for (d, fd) in frac.iter().enumerate() {
                w *= if (c >> d) & 1 == 1 { *fd } else { 1.0 - fd };
            }
            out.index[c as usize] = level.offset as u32 + vertex_index(level, v);
            out.weight[c as usize] = w;
        }
        out
    }

    /// Encodes one input: `out[l·F + f]` (length L·F) from the table `params` ([entry][feature]).
    #[inline]
    pub fn forward_one(&self, params: &[f32], p: [f32; 3], out: &mut [f32]) {
        let f = self.features();
        for (l, level) in self.levels.iter().enumerate() {
            let c = self.corners(level, p);
            let o = &mut out[l * f..(l + 1) * f];
            o.fill(0.0);
            for k in 0..8 {
                let base = c.index[k] as usize * f;
                let w = c.weight[k];
                for (j, oj) in o.iter_mut().enumerate() {
                    *oj += w * params[base + j];
                }
            }
        }
    }

    /// Scatters the gradient of one input's output `dout` (length L·F) into `grad` ([entry][feature]).
    #[inline]
    pub fn backward_params_one(&self, p: [f32; 3], dout: &[f32], grad: &mut [f32]) {
        let f = self.features();
        for (l, level) in self.levels.iter().enumerate() {
            let c = self.corners(level, p);
            let d = &dout[l * f..(l + 1) * f];
            for k in 0..8 {
                let base = c.index[k] as usize * f;
                for j in 0..f {
                    grad[base + j] += c.weight[k] * d[j];
                }
            }
        }
    }

    /// Gradient of `⟨dout, encode(p)⟩` with respect to the input position `p`.
    pub fn backward_input_one(&self, params: &[f32], p: [f32; 3], dout: &[f32]) -> [f32; 3] {
        let f = self.features();
        let mut g = [0f32; 3];
        for (l, level) in self.levels.iter().enumerate() {
            let c = self.corners(level, p);
            let d = &dout[l * f..(l + 1) * f];
            for k in 0..8u32 {
                let base = c.index[k as usize] as usize * f;
                let dot: f32 = (0..f).map(|j| params[base + j] * d[j]).sum();
                for (dim, gd) in g.iter_mut().enumerate() {
                    // ∂w_c/∂frac_dim: the factor of dimension `dim` becomes ±1.
                    let mut dw = if (k >> dim) & 1 == 1 { 1.0 } else { -1.0 };
                    for e in 0..3 {
                        if e != dim {
                            dw *= if (k >> e) & 1 == 1 {
                                c.frac[e]
                            } else {
                                1.0 - c.frac[e]
                            };
                        }
                    }
                    *gd += level.scale * dw * dot;
                }
            }
        }
        g
    }
}

/// One level's constants for the batch kernels: the same definition as [`HashGrid::corners`]
/// with the per-corner work hoisted (dense offsets `{0, 1, r, r+1, r², …}`, hash products per
/// axis) so a corner costs a few integer operations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FastLevel {
    scale: f32,
    res: u32,
    res2: u32,
    entries: u32,
    offset: u32,
    dense: bool,
    /// Offsets of the 8 corners from the first on a dense level.
    dense_offsets: [u32; 8],
}

impl FastLevel {
    /// Constants of `level`.
    pub fn new(level: &GridLevel) -> Self {
        Self {
            scale: level.scale,
            res: level.resolution,
            res2: level.resolution.wrapping_mul(level.resolution),
            entries: level.entries,
            offset: level.offset as u32,
            dense: level.dense,
            dense_offsets: {
                let (r, r2) = (
                    level.resolution,
                    level.resolution.wrapping_mul(level.resolution),
                );
                [0, 1, r, r + 1, r2, r2 + 1, r2 + r, r2 + r + 1]
            },
        }
    }

    /// Absolute entry indices and trilinear weights of the 8 vertices around `p`; identical,
    /// bit for bit, to [`HashGrid::corners`].
    #[inline(always)]
    pub fn corners(&self, p: [f32; 3]) -> ([u32; 8], [f32; 8]) {
        let (c, w1) = cell(self.scale, p);
        let wx = [1.0 - w1[0], w1[0]];
        let wy = [1.0 - w1[1], w1[1]];
        let wz = [1.0 - w1[2], w1[2]];
        let mut w = [0f32; 8];
        for (k, wk) in w.iter_mut().enumerate() {
            *wk = wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2];
        }
        let mut idx = [0u32; 8];
        if self.dense {
            let (r, r2) = (self.res, self.res2);
            let base = c[0]
                .wrapping_add(c[1].wrapping_mul(r))
                .wrapping_add(c[2].wrapping_mul(r2));
            let offs = [0, 1, r, r + 1, r2, r2 + 1, r2 + r, r2 + r + 1];
            if base < self.entries - (r2 + r + 1).min(self.entries) {
                for k in 0..8 {
                    idx[k] = self.offset + base + offs[k];
                }
            } else {
                for k in 0..8 {
                    idx[k] = self.offset + base.wrapping_add(offs[k]) % self.entries;
                }
            }
        } else {
            let hx = [c[0], c[0].wrapping_add(1)];
            let hy = [
                c[1].wrapping_mul(PRIMES[1]),
                c[1].wrapping_add(1).wrapping_mul(PRIMES[1]),
            ];
            let hz = [
                c[2].wrapping_mul(PRIMES[2]),
                c[2].wrapping_add(1).wrapping_mul(PRIMES[2]),
            ];
            let mask = self.entries - 1;
            for k in 0..8 {
                idx[k] = self.offset + ((hx[k & 1] ^ hy[(k >> 1) & 1] ^ hz[k >> 2]) & mask);
            }
        }
        (idx, w)
    }

    /// [`FastLevel::corners`] of eight samples at once, in AVX2 registers: lane `j` of
    /// `idx[k]` and `w[k]` is corner `k` of sample `j` (positions `x`, `y`, `z`, one sample per
    /// lane), the same bits as the scalar version; `None` where a dense level's corner wraps for
    /// some lane (the caller falls back to the scalar version for that group).
    ///
    /// # Safety
    /// Callable only where the CPU has AVX2 and FMA (a `target_feature` function).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn corners_x8(
        &self,
        x: std::arch::x86_64::__m256,
        y: std::arch::x86_64::__m256,
        z: std::arch::x86_64::__m256,
    ) -> Option<(
        [std::arch::x86_64::__m256i; 8],
        [std::arch::x86_64::__m256; 8],
    )> {
        use std::arch::x86_64::*;
        let one = _mm256_set1_ps(1.0);
        // `cell`: clamp01 (max with 0 maps NaN and −0 to +0, as the scalar test does), then
        // `pos = p·s + 0.5 ≥ 0.5`, whose truncation is the floor.
        let cell = |p: __m256| {
            let c = _mm256_min_ps(_mm256_max_ps(p, _mm256_setzero_ps()), one);
            let pos = _mm256_add_ps(
                _mm256_mul_ps(c, _mm256_set1_ps(self.scale)),
                _mm256_set1_ps(0.5),
            );
            // `fl = (pos as u32) as f32` and `c = fl as u32`, as in `cell` (the round trip
            // matters only past 2^24, where `fl` rounds).
            let fl = _mm256_cvtepi32_ps(_mm256_cvttps_epi32(pos));
            (_mm256_cvttps_epi32(fl), _mm256_sub_ps(pos, fl))
        };
        let (cx, fx) = cell(x);
        let (cy, fy) = cell(y);
        let (cz, fz) = cell(z);
        let wx = [_mm256_sub_ps(one, fx), fx];
        let wy = [_mm256_sub_ps(one, fy), fy];
        let wz = [_mm256_sub_ps(one, fz), fz];
        let wxy = [
            _mm256_mul_ps(wx[0], wy[0]),
            _mm256_mul_ps(wx[1], wy[0]),
            _mm256_mul_ps(wx[0], wy[1]),
            _mm256_mul_ps(wx[1], wy[1]),
        ];
        let w: [__m256; 8] = std::array::from_fn(|k| _mm256_mul_ps(wxy[k & 3], wz[k >> 2]));
        let offset = _mm256_set1_epi32(self.offset as i32);
        let idx: [__m256i; 8] = if self.dense {
            let base = _mm256_add_epi32(
                _mm256_add_epi32(
                    cx,
                    _mm256_mullo_epi32(cy, _mm256_set1_epi32(self.res as i32)),
                ),
                _mm256_mullo_epi32(cz, _mm256_set1_epi32(self.res2 as i32)),
            );
            // Every lane must satisfy base < entries − (r² + r + 1) (bases are far below 2³¹,
            // so the signed comparison is the unsigned one).
            let limit = self.entries - (self.res2 + self.res + 1).min(self.entries);
            let ok = _mm256_cmpgt_epi32(_mm256_set1_epi32(limit as i32), base);
            if _mm256_movemask_epi8(ok) != -1 {
                return None;
            }
            let first = _mm256_add_epi32(offset, base);
            std::array::from_fn(|k| {
                _mm256_add_epi32(first, _mm256_set1_epi32(self.dense_offsets[k] as i32))
            })
        } else {
            let ones = _mm256_set1_epi32(1);
            let (p1, p2) = (
                _mm256_set1_epi32(PRIMES[1] as i32),
                _mm256_set1_epi32(PRIMES[2] as i32),
            );
            let hx = [cx, _mm256_add_epi32(cx, ones)];
            let hy0 = _mm256_mullo_epi32(cy, p1);
            let hz0 = _mm256_mullo_epi32(cz, p2);
            // (c + 1)·P = c·P + P in wrapping arithmetic.
            let hy = [hy0, _mm256_add_epi32(hy0, p1)];
            let hz = [hz0, _mm256_add_epi32(hz0, p2)];
            let mask = _mm256_set1_epi32((self.entries - 1) as i32);
            std::array::from_fn(|k| {
                let h = _mm256_xor_si256(_mm256_xor_si256(hx[k & 1], hy[(k >> 1) & 1]), hz[k >> 2]);
                _mm256_add_epi32(offset, _mm256_and_si256(h, mask))
            })
        };
        Some((idx, w))
    }
}

/// The cell of a level with scale `scale` that holds `p` (components clamped to [0,1]): its
/// lower vertex and the fractional position inside it, per dimension.
#[inline(always)]
pub fn cell(scale: f32, p: [f32; 3]) -> ([u32; 3], [f32; 3]) {
    let mut c = [0u32; 3];
    let mut frac = [0f32; 3];
    for d in 0..3 {
        // pos ≥ 0.5 after the clamp, so truncation is the floor.
        let pos = clamp01(p[d]) * scale + 0.5;
        let fl = (pos as u32) as f32;
        c[d] = fl as u32;
        frac[d] = pos - fl;
    }
    (c, frac)
}

/// Clamps a coordinate to [0,1] (NaN becomes 0).
#[inline(always)]
pub fn clamp01(x: f32) -> f32 {
    if x > 0.0 { x.min(1.0) } else { 0.0 }
}

/// `s_l = N_min · b^l − 1`, computed as tiny-cuda-nn does (exp2 of l·log2 b).
#[inline]
pub fn level_scale(base_resolution: f32, per_level_scale: f32, level: u32) -> f32 {
    (level as f32 * per_level_scale.log2()).exp2() * base_resolution - 1.0
}

/// Index of vertex `v` within its level (without the level offset).
#[inline(always)]
pub fn vertex_index(level: &GridLevel, v: [u32; 3]) -> u32 {
    if level.dense {
        let r = level.resolution;
        let i = v[0]
            .wrapping_add(v[1].wrapping_mul(r))
            .wrapping_add(v[2].wrapping_mul(r.wrapping_mul(r)));
        i % level.entries
    } else {
        let h = v[0].wrapping_mul(PRIMES[0])
            ^ v[1].wrapping_mul(PRIMES[1])
            ^ v[2].wrapping_mul(PRIMES[2]);
        h & (level.entries - 1)
    }
}
