//! Input encodings: hash grid, one-blob (plain and wrapped), triangle wave, identity, and their
//! composition into the padded network input.
//!
//! Each encoding exists twice, with the same definition:
//! * per-sample CPU kernels (`forward_one` / backward) used by the Flex custom ops and the fused
//!   CPU training step;
//! * a burn-tensor version ([`InputEncoding::encode_tensor`]) built from generic tensor ops, which
//!   runs on every backend with autodiff. It is the unfused reference the custom ops are tested
//!   and measured against, and the path used on devices without custom kernels.

pub mod hash_grid;
pub mod identity;
pub mod one_blob;
pub mod triangle_wave;

use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::config::{CompositeConfig, NestedEncoding};
use crate::record::RAW_INPUT_DIMS;
use hash_grid::{HashGrid, PRIMES};

/// One encoding of the composite and where it reads and writes.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodingPart {
    /// What it computes.
    pub kind: EncodingKind,
    /// First raw input dimension read.
    pub in_offset: usize,
    /// Raw input dimensions read.
    pub in_dims: usize,
    /// First output column written.
    pub out_offset: usize,
    /// Output columns written.
    pub out_dims: usize,
}

/// The closed set of encodings.
#[derive(Clone, Debug, PartialEq)]
pub enum EncodingKind {
    /// Multiresolution hash grid (trainable parameters).
    HashGrid(HashGrid),
    /// One-blob with `bins` bins per dimension.
    OneBlob {
        /// Bins per dimension.
        bins: usize,
        /// Periodic.
        wrap: bool,
    },
    /// Triangle wave with `frequencies` octaves per dimension.
    TriangleWave {
        /// Octaves per dimension.
        frequencies: usize,
    },
    /// `x·scale + offset`.
    Identity {
        /// Multiplier.
        scale: f32,
        /// Offset.
        offset: f32,
    },
}

/// The composite encoding: raw inputs (14) → padded network input.
#[derive(Clone, Debug, PartialEq)]
pub struct InputEncoding {
    /// The nested encodings in order.
    pub parts: Vec<EncodingPart>,
    /// Output width before padding.
    pub unpadded_dims: usize,
    /// Output width after padding with ones.
    pub padded_dims: usize,
}

impl InputEncoding {
    /// Builds the composite from a (validated) config.
    pub fn new(config: &CompositeConfig) -> Self {
        let mut parts = Vec::new();
        let (mut i, mut o) = (0usize, 0usize);
        for n in &config.nested {
            let in_dims = n.n_dims_to_encode() as usize;
            let (kind, out_dims) = match n {
                NestedEncoding::HashGrid {
                    n_levels,
                    n_features_per_level,
                    log2_hashmap_size,
                    base_resolution,
                    per_level_scale,
                    inference_precision,
                    training_precision,
                    ..
                } => {
                    let g = HashGrid::new(hash_grid::HashGridParams {
                        n_levels: *n_levels,
                        n_features_per_level: *n_features_per_level,
                        log2_hashmap_size: *log2_hashmap_size,
                        base_resolution: *base_resolution,
                        per_level_scale: *per_level_scale,
                        inference_precision: *inference_precision,
                        training_precision: *training_precision,
                    });
                    let d = g.output_dims();
                    (EncodingKind::HashGrid(g), d)
                }
                NestedEncoding::OneBlob { n_bins, wrap, .. } => (
                    EncodingKind::OneBlob {
                        bins: *n_bins as usize,
                        wrap: *wrap,
                    },
                    in_dims * *n_bins as usize,
                ),
                NestedEncoding::TriangleWave { n_frequencies, .. } => (
                    EncodingKind::TriangleWave {
                        frequencies: *n_frequencies as usize,
                    },
                    in_dims * *n_frequencies as usize,
                ),
                NestedEncoding::Identity { scale, offset, .. } => (
                    EncodingKind::Identity {
                        scale: *scale,
                        offset: *offset,
                    },
                    in_dims,
                ),
            };
            parts.push(EncodingPart {
                kind,
                in_offset: i,
                in_dims,
                out_offset: o,
                out_dims,
            });
            i += in_dims;
            o += out_dims;
        }
        let pad = config.pad_to_multiple as usize;
        Self {
            parts,
            unpadded_dims: o,
            padded_dims: o.div_ceil(pad) * pad,
        }
    }

    /// The hash grid and its output column offset, if any.
    pub fn grid(&self) -> Option<(&HashGrid, &EncodingPart)> {
        self.parts.iter().find_map(|p| match &p.kind {
            EncodingKind::HashGrid(g) => Some((g, p)),
            _ => None,
        })
    }

    /// Trainable parameters of the encoding (the hash table).
    pub fn param_count(&self) -> usize {
        self.grid().map_or(0, |(g, _)| g.param_count())
    }

    /// Encodes one sample's raw inputs into `out` (length `padded_dims`). `grid` is the hash
    /// table (may be empty without a hash grid).
    #[inline]
    pub fn forward_one(&self, grid: &[f32], raw: &[f32], out: &mut [f32]) {
        for part in &self.parts {
            let x = &raw[part.in_offset..part.in_offset + part.in_dims];
            let o = &mut out[part.out_offset..part.out_offset + part.out_dims];
            match &part.kind {
                EncodingKind::HashGrid(g) => g.forward_one(grid, [x[0], x[1], x[2]], o),
                EncodingKind::OneBlob { bins, wrap } => {
                    for (d, xd) in x.iter().enumerate() {
                        one_blob::forward(*xd, *wrap, &mut o[d * bins..(d + 1) * bins]);
                    }
                }
                EncodingKind::TriangleWave { frequencies } => {
                    for (d, xd) in x.iter().enumerate() {
                        triangle_wave::forward(*xd, &mut o[d * frequencies..(d + 1) * frequencies]);
                    }
                }
                EncodingKind::Identity { scale, offset } => {
                    for (oj, xj) in o.iter_mut().zip(x) {
                        *oj = identity::forward(*xj, *scale, *offset);
                    }
                }
            }
        }
        out[self.unpadded_dims..self.padded_dims].fill(1.0);
    }

    /// The non-grid columns (everything but the hash grid, plus padding) of [`Self::forward_one`]
    /// for the `m` rows of `raw` (`row_len` floats each, raw inputs first), into the rows of
    /// `out` (`stride` floats each): the one-blob parts are encoded a column at a time over all
    /// rows (vectorised, the same bits), the rest row by row.
    pub fn forward_rows_without_grid(
        &self,
        raw: &[f32],
        row_len: usize,
        out: &mut [f32],
        stride: usize,
    ) {
        let m = raw.len() / row_len;
        let mut column = vec![0f32; m];
        for part in &self.parts {
            match &part.kind {
                EncodingKind::HashGrid(_) => {}
                EncodingKind::OneBlob { bins, wrap } => {
                    for d in 0..part.in_dims {
                        for (c, row) in column.iter_mut().zip(raw.chunks_exact(row_len)) {
                            *c = row[part.in_offset + d];
                        }
                        one_blob::forward_many(
                            &column,
                            *wrap,
                            *bins,
                            out,
                            stride,
                            part.out_offset + d * bins,
                        );
                    }
                }
                EncodingKind::TriangleWave { frequencies } => {
                    for (row, o) in raw.chunks_exact(row_len).zip(out.chunks_mut(stride)) {
                        let x = &row[part.in_offset..part.in_offset + part.in_dims];
                        for (d, xd) in x.iter().enumerate() {
                            let at = part.out_offset + d * frequencies;
                            triangle_wave::forward(*xd, &mut o[at..at + frequencies]);
                        }
                    }
                }
                EncodingKind::Identity { scale, offset } => {
                    for (row, o) in raw.chunks_exact(row_len).zip(out.chunks_mut(stride)) {
                        let x = &row[part.in_offset..part.in_offset + part.in_dims];
                        let o = &mut o[part.out_offset..part.out_offset + part.out_dims];
                        for (oj, xj) in o.iter_mut().zip(x) {
                            *oj = identity::forward(*xj, *scale, *offset);
                        }
                    }
                }
            }
        }
        for o in out.chunks_mut(stride).take(m) {
            o[self.unpadded_dims..self.padded_dims].fill(1.0);
        }
    }

    /// Gradient of `⟨dout, encode(raw)⟩` with respect to the raw inputs (for gradient checks).
    pub fn backward_input_one(
        &self,
        grid: &[f32],
        raw: &[f32],
        dout: &[f32],
    ) -> [f32; RAW_INPUT_DIMS] {
        let mut g = [0f32; RAW_INPUT_DIMS];
        for part in &self.parts {
            let x = &raw[part.in_offset..part.in_offset + part.in_dims];
            let d = &dout[part.out_offset..part.out_offset + part.out_dims];
            let gi = &mut g[part.in_offset..part.in_offset + part.in_dims];
            match &part.kind {
                EncodingKind::HashGrid(h) => {
                    gi.copy_from_slice(&h.backward_input_one(grid, [x[0], x[1], x[2]], d))
                }
                EncodingKind::OneBlob { bins, wrap } => {
                    for (k, xd) in x.iter().enumerate() {
                        gi[k] = one_blob::backward_input(*xd, *wrap, &d[k * bins..(k + 1) * bins]);
                    }
                }
                EncodingKind::TriangleWave { frequencies } => {
                    for (k, xd) in x.iter().enumerate() {
                        gi[k] = triangle_wave::backward_input(
                            *xd,
                            &d[k * frequencies..(k + 1) * frequencies],
                        );
                    }
                }
                EncodingKind::Identity { scale, .. } => {
                    for (gk, dk) in gi.iter_mut().zip(d) {
                        *gk = dk * scale;
                    }
                }
            }
        }
        g
    }

    /// The encoding on tensors: `raw` is `[N, 14]`, `grid` the hash table `[P]` (ignored
    /// without a hash grid). The hash grid runs as its custom op
    /// ([`crate::hash_grid_op::hash_grid`]: WGSL on wgpu, rayon on Flex, explicit backward), the
    /// other encodings as tensor ops. Differentiable in the table (and, except through the
    /// hash grid, in the inputs) on an autodiff device.
    pub fn encode_tensor(&self, grid: Option<Tensor<1>>, raw: Tensor<2>) -> Tensor<2> {
        self.encode_tensor_with(grid, raw, true)
    }

    /// As [`InputEncoding::encode_tensor`], with the hash grid composed of generic tensor ops
    /// ([`hash_grid_tensor`]): the unfused reference, differentiable in the table and positions.
    pub fn encode_tensor_reference(&self, grid: Option<Tensor<1>>, raw: Tensor<2>) -> Tensor<2> {
        self.encode_tensor_with(grid, raw, false)
    }

    fn encode_tensor_with(
        &self,
        grid: Option<Tensor<1>>,
        raw: Tensor<2>,
        custom_op: bool,
    ) -> Tensor<2> {
        let [n, _] = raw.dims();
        let device = raw.device();
        let mut cols = Vec::with_capacity(self.parts.len() + 1);
        for part in &self.parts {
            let x = raw.clone().narrow(1, part.in_offset, part.in_dims);
            cols.push(match &part.kind {
                EncodingKind::HashGrid(g) => {
                    let table = grid.clone().expect("a hash-grid encoding needs its table");
                    if custom_op {
                        crate::hash_grid_op::hash_grid(g, table, x)
                    } else {
                        hash_grid_tensor(g, table, x)
                    }
                }
                EncodingKind::OneBlob { bins, wrap } => one_blob_tensor(x, *bins, *wrap),
                EncodingKind::TriangleWave { frequencies } => triangle_wave_tensor(x, *frequencies),
                EncodingKind::Identity { scale, offset } => {
                    x.mul_scalar(*scale).add_scalar(*offset)
                }
            });
        }
        if self.padded_dims > self.unpadded_dims {
            cols.push(Tensor::ones(
                [n, self.padded_dims - self.unpadded_dims],
                &device,
            ));
        }
        Tensor::cat(cols, 1)
    }
}

/// Column vector of constants `[1, k]`.
fn row(values: Vec<f32>, device: &Device) -> Tensor<2> {
    let k = values.len();
    Tensor::from_data(TensorData::new(values, [1, k]), device)
}

/// One-blob as tensor ops: `x` is `[N, D]`, output `[N, D·bins]` (dimension-major).
pub fn one_blob_tensor(x: Tensor<2>, bins: usize, wrap: bool) -> Tensor<2> {
    let [n, d] = x.dims();
    let device = x.device();
    let nb = bins as f32;
    let boundaries = row((0..=bins).map(|i| i as f32 / nb).collect(), &device);
    let cdf = |u: Tensor<2>| {
        let u = u.clamp(-1.0, 1.0);
        let u2 = u.clone() * u.clone();
        let poly =
            u2.clone().mul_scalar(-2.0 / 3.0).add_scalar(1.0) + u2.clone() * u2.mul_scalar(0.2);
        (u * poly).mul_scalar(15.0 / 16.0).add_scalar(0.5)
    };
    let mut outs = Vec::with_capacity(d);
    for k in 0..d {
        let xk = x.clone().narrow(1, k, 1); // [N,1]
        let diff = boundaries.clone() - xk; // [N, bins+1]
        let mut c = cdf(diff.clone().mul_scalar(nb));
        if wrap {
            c = c
                + cdf(diff.clone().sub_scalar(1.0).mul_scalar(nb))
                + cdf(diff.add_scalar(1.0).mul_scalar(nb));
        }
        outs.push(c.clone().narrow(1, 1, bins) - c.narrow(1, 0, bins));
    }
    let out = Tensor::cat(outs, 1);
    debug_assert_eq!(out.dims(), [n, d * bins]);
    out
}

/// Triangle wave as tensor ops: `x` is `[N, D]`, output `[N, D·n]` (dimension-major).
pub fn triangle_wave_tensor(x: Tensor<2>, frequencies: usize) -> Tensor<2> {
    let [_, d] = x.dims();
    let device = x.device();
    let freqs = row(
        (0..frequencies).map(|j| (1u32 << j) as f32).collect(),
        &device,
    );
    let mut outs = Vec::with_capacity(d);
    for k in 0..d {
        let u = (x.clone().narrow(1, k, 1) * freqs.clone()).sub_scalar(0.25); // [N, n]
        let frac = u.clone() - u.detach().floor();
        outs.push(frac.sub_scalar(0.5).abs().mul_scalar(4.0).sub_scalar(1.0));
    }
    Tensor::cat(outs, 1)
}

/// The hash grid as generic tensor ops (gather + weighted sum per level and vertex). Slow, but
/// runs on every backend and differentiates through `select` (scatter-add) automatically.
/// `p` is `[N, 3]`, `table` `[entries·F]`; output `[N, L·F]`.
pub fn hash_grid_tensor(grid: &HashGrid, table: Tensor<1>, p: Tensor<2>) -> Tensor<2> {
    let f = grid.features();
    let [n, _] = p.dims();
    let table = table.reshape([grid.total_entries, f]);
    let p = p.clamp(0.0, 1.0);
    let mut levels = Vec::with_capacity(grid.levels.len());
    for level in &grid.levels {
        let pos = p.clone().mul_scalar(level.scale).add_scalar(0.5);
        let cell = pos.clone().detach().floor();
        let frac = pos - cell.clone();
        let cell_i: Tensor<2, Int> = cell.int();
        let mut acc: Option<Tensor<2>> = None;
        for c in 0..8usize {
            let mut w: Option<Tensor<2>> = None;
            let mut coords = Vec::with_capacity(3);
            for d in 0..3 {
                let bit = (c >> d) & 1;
                let fd = frac.clone().narrow(1, d, 1);
                let wd = if bit == 1 {
                    fd
                } else {
                    fd.neg().add_scalar(1.0)
                };
                w = Some(match w {
                    None => wd,
                    Some(w) => w * wd,
                });
                coords.push(
                    cell_i
                        .clone()
                        .narrow(1, d, 1)
                        .add_scalar(bit as i64)
                        .reshape([n]),
                );
            }
            // All products are taken modulo 2^32 in the kernels; only the low log2(T) bits
            // matter for hashed levels, and dense indices stay far below 2^31, so the same
            // expression is exact in i32 and i64. The second prime is written as its
            // two's-complement i32 value so it is representable on i32 backends.
            let [x, y, z] = [coords[0].clone(), coords[1].clone(), coords[2].clone()];
            let index = if level.dense {
                let r = i64::from(level.resolution);
                (x + y.mul_scalar(r) + z.mul_scalar(r * r))
                    .remainder_scalar(i64::from(level.entries))
            } else {
                let p1 = i64::from(PRIMES[1] as i32);
                let p2 = i64::from(PRIMES[2] as i32);
                x.bitwise_xor(y.mul_scalar(p1))
                    .bitwise_xor(z.mul_scalar(p2))
                    .bitwise_and_scalar(i64::from(level.entries - 1))
            };
            let index = index.add_scalar(level.offset as i64);
            let feats = table.clone().select(0, index); // [N, F]
            let term = feats * w.expect("3 dimensions");
            acc = Some(match acc {
                None => term,
                Some(a) => a + term,
            });
        }
        levels.push(acc.expect("8 vertices"));
    }
    Tensor::cat(levels, 1)
}
