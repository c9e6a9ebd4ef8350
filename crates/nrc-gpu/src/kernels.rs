//! The kernels, in CubeCL (one source for wgpu's WGSL and SPIR-V, CUDA and the rest).
//!
//! A cube is [`WIDTH`] units, one per neuron of a hidden layer. The tile kernels
//! ([`train_tiles`], [`infer_tiles`]) walk tiles of `r_tile` rows (cube `c` takes tiles `c`,
//! `c + cubes`, …): each tile is encoded into workgroup memory, run through the MLP with every
//! layer's activations kept there, and (training) its loss gradient propagated back, the weight
//! gradients summed into the cube's own partial (no atomics, a fixed order: the same bits on
//! every run) and the gradient of the hash-grid columns written out for [`scatter_cas`] /
//! [`scatter_native`]. [`mlp_adam`] reduces the partials and updates the MLP; [`table_adam`]
//! updates the referenced table entries (sparse Adam, PyTorch `SparseAdam` semantics: an entry
//! no sample referenced keeps its moments) and clears the gradient for the next step.
//!
//! The arithmetic follows the CPU path (`nrc_cache::cpu`) operation by operation in f32 (the
//! CPU's loss is computed in f64; the GPU may contract multiply-adds), so the two agree to
//! rounding, not to the bit.

use burn::cubecl;
use burn::cubecl::prelude::*;

/// Units per cube: the hidden layers' width.
pub const WIDTH: usize = 64;

/// The largest finite half-precision value: tables are clamped to it before rounding.
pub const HALF_MAX: f32 = 65504.0;

/// Words per level in the info buffer: scale bits, resolution, entries, offset (entries),
/// dense flag.
pub const LEVEL_WORDS: usize = 5;
/// Words per encoding part in the info buffer (after the levels): kind, input offset, input
/// dimensions, output offset, bins or frequencies, wrap, scale bits, offset bits.
pub const PART_WORDS: usize = 8;

/// An activation stored as `M` (f32, or f16 for a half-precision MLP): clamped to `M`'s finite
/// range first (WGSL leaves an out-of-range conversion to f16 undefined), NaN kept.
#[cube]
fn to_act<M: Float>(v: f32) -> M {
    let hi = f32::cast_from(M::max_value());
    M::cast_from(select(v > hi, hi, select(v < -hi, -hi, v)))
}

/// `x` clamped to [0, 1], NaN to 0 (as `hash_grid::clamp01`).
#[cube]
fn clamp01(x: f32) -> f32 {
    let mut y = 0.0f32;
    if x > 0.0f32 {
        y = x.min(1.0f32);
    }
    y
}

/// The eight corners of `p`'s cell on level `l` (indices into the table, in entries, and
/// trilinear weights), as `HashGrid::corners`.
#[cube]
fn corners(
    info: &[u32],
    l: usize,
    px: f32,
    py: f32,
    pz: f32,
    index: &mut Array<u32>,
    weight: &mut Array<f32>,
) {
    let d = l * LEVEL_WORDS;
    let scale = f32::from_bits(info[d]);
    let res = info[d + 1];
    let entries = info[d + 2];
    let offset = info[d + 3];
    let dense = info[d + 4];
    let fx = clamp01(px) * scale + 0.5f32;
    let fy = clamp01(py) * scale + 0.5f32;
    let fz = clamp01(pz) * scale + 0.5f32;
    let cx = u32::cast_from(fx);
    let cy = u32::cast_from(fy);
    let cz = u32::cast_from(fz);
    let rx = fx - f32::cast_from(cx);
    let ry = fy - f32::cast_from(cy);
    let rz = fz - f32::cast_from(cz);
    #[unroll]
    for c in 0..8u32 {
        let bx = c & 1u32;
        let by = (c >> 1u32) & 1u32;
        let bz = (c >> 2u32) & 1u32;
        let vx = cx + bx;
        let vy = cy + by;
        let vz = cz + bz;
        let wx = if bx == 1u32 { rx } else { 1.0f32 - rx };
        let wy = if by == 1u32 { ry } else { 1.0f32 - ry };
        let wz = if bz == 1u32 { rz } else { 1.0f32 - rz };
        let at = if dense == 1u32 {
            (vx + vy * res + vz * (res * res)) % entries
        } else {
            (vx ^ (vy * 2_654_435_761u32) ^ (vz * 805_459_861u32)) & (entries - 1u32)
        };
        index[c as usize] = offset + at;
        weight[c as usize] = wx * wy * wz;
    }
}

/// The one-blob kernel's CDF (as `one_blob::cdf`).
#[cube]
fn blob_cdf(u: f32) -> f32 {
    let u = u.clamp(-1.0f32, 1.0f32);
    let u2 = u * u;
    (0.9375f32 * u * (1.0f32 - 0.666_666_7f32 * u2 + 0.2f32 * u2 * u2) + 0.5f32)
        .clamp(0.0f32, 1.0f32)
}

#[cube]
fn blob_cdf_sum(boundary: f32, x: f32, bins: f32, wrap: u32) -> f32 {
    let mut c = blob_cdf((boundary - x) * bins);
    if wrap == 1u32 {
        c = c + blob_cdf((boundary - x - 1.0f32) * bins) + blob_cdf((boundary - x + 1.0f32) * bins);
    }
    c
}

/// The triangle wave (as `triangle_wave::tri`).
#[cube]
fn tri(t: f32) -> f32 {
    let u = t - 0.25f32;
    4.0f32 * ((u - u.floor()) - 0.5f32).abs() - 1.0f32
}

/// Encodes the tile's rows `first..first + r_tile` into `act[..r_tile·k]` (row-major): the
/// non-grid parts one unit per row, the hash grid one unit per (row, level). Rows at or past
/// `n` encode as zeros.
#[cube]
fn encode_tile<T: Float, M: Float>(
    rows: &[f32],
    table: &[T],
    info: &[u32],
    act: &mut Shared<[M]>,
    first: usize,
    n: usize,
    n_parts: u32,
    #[comptime] r_tile: usize,
    #[comptime] k: usize,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] stride: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] grid_out: usize,
    #[comptime] unpadded: usize,
) {
    let u = UNIT_POS as usize;
    let grid_end = grid_out + levels * features;
    if u < r_tile {
        let i = first + u;
        let base = u * k;
        if i < n {
            let raw = i * row_len;
            for p in 0..n_parts as usize {
                let d = levels * LEVEL_WORDS + p * PART_WORDS;
                let kind = info[d];
                let in_off = info[d + 1] as usize;
                let in_dims = info[d + 2] as usize;
                let out_off = info[d + 3] as usize;
                let count = info[d + 4] as usize;
                let wrap = info[d + 5];
                let sc = f32::from_bits(info[d + 6]);
                let of = f32::from_bits(info[d + 7]);
                for dim in 0..in_dims {
                    let x = rows[raw + in_off + dim];
                    if kind == 1u32 {
                        let bins = f32::cast_from(count);
                        let at = base + out_off + dim * count;
                        let mut left = blob_cdf_sum(0.0f32, x, bins, wrap);
                        for b in 0..count {
                            let right = blob_cdf_sum(f32::cast_from(b + 1) / bins, x, bins, wrap);
                            act[at + b] = to_act::<M>(right - left);
                            left = right;
                        }
                    } else if kind == 2u32 {
                        let at = base + out_off + dim * count;
                        let mut freq = 1.0f32;
                        for b in 0..count {
                            act[at + b] = to_act::<M>(tri(freq * x));
                            freq *= 2.0f32;
                        }
                    } else {
                        act[base + out_off + dim] = to_act::<M>(x * sc + of);
                    }
                }
            }
            for c in unpadded..k {
                act[base + c] = M::cast_from(1.0f32);
            }
        } else {
            for c in 0..k {
                if c < grid_out || c >= grid_end {
                    act[base + c] = M::cast_from(0.0f32);
                }
            }
        }
    }
    if levels > 0 {
        let mut index = Array::<u32>::new(8usize);
        let mut weight = Array::<f32>::new(8usize);
        let mut acc = Array::<f32>::new(features);
        let mut p = u;
        while p < r_tile * levels {
            let r = p % r_tile;
            let l = p / r_tile;
            let i = first + r;
            let o = r * k + grid_out + l * features;
            if i < n {
                let at = i * row_len + grid_in;
                corners(
                    info,
                    l,
                    rows[at],
                    rows[at + 1],
                    rows[at + 2],
                    &mut index,
                    &mut weight,
                );
                #[unroll]
                for f in 0..features {
                    acc[f] = 0.0f32;
                }
                #[unroll]
                for c in 0..8usize {
                    let e = index[c] as usize * stride;
                    #[unroll]
                    for f in 0..features {
                        acc[f] += weight[c] * f32::cast_from(table[e + f]);
                    }
                }
                #[unroll]
                for f in 0..features {
                    act[o + f] = to_act::<M>(acc[f]);
                }
            } else {
                #[unroll]
                for f in 0..features {
                    act[o + f] = M::cast_from(0.0f32);
                }
            }
            p += WIDTH;
        }
    }
}

/// One hidden layer: `act[out_base + r·64 + j] = relu(Σ_k W[k][j] · act[in_base + r·in_dims + k])`
/// for unit `j` and every row `r` of the tile.
#[cube]
fn dense_forward<M: Float>(
    mlp: &[M],
    w_off: usize,
    act: &mut Shared<[M]>,
    in_base: usize,
    out_base: usize,
    #[comptime] in_dims: usize,
    #[comptime] r_tile: usize,
) {
    let j = UNIT_POS as usize;
    let mut acc = Array::<f32>::new(r_tile);
    #[unroll]
    for r in 0..r_tile {
        acc[r] = 0.0f32;
    }
    for kk in 0..in_dims {
        let w = f32::cast_from(mlp[w_off + kk * WIDTH + j]);
        #[unroll]
        for r in 0..r_tile {
            acc[r] += w * f32::cast_from(act[in_base + r * in_dims + kk]);
        }
    }
    #[unroll]
    for r in 0..r_tile {
        act[out_base + r * WIDTH + j] = to_act::<M>(acc[r].max(0.0f32));
    }
}

/// The whole forward of a tile: encoding, hidden layers, and the raw outputs in
/// `small[r·3 + c]`.
#[cube]
fn forward_tile<T: Float, M: Float>(
    rows: &[f32],
    table: &[T],
    info: &[u32],
    mlp: &[M],
    act: &mut Shared<[M]>,
    small: &mut Shared<[f32]>,
    first: usize,
    n: usize,
    n_parts: u32,
    #[comptime] r_tile: usize,
    #[comptime] k: usize,
    #[comptime] hidden: usize,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] stride: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] grid_out: usize,
    #[comptime] unpadded: usize,
) {
    encode_tile::<T, M>(
        rows, table, info, act, first, n, n_parts, r_tile, k, levels, features, stride, row_len,
        grid_in, grid_out, unpadded,
    );
    sync_cube();
    let xs_len = r_tile * k;
    dense_forward::<M>(mlp, 0usize, act, 0usize, xs_len, k, r_tile);
    sync_cube();
    #[unroll]
    for l in 1..hidden {
        dense_forward::<M>(
            mlp,
            k * WIDTH + (l - 1) * WIDTH * WIDTH,
            act,
            xs_len + (l - 1) * r_tile * WIDTH,
            xs_len + l * r_tile * WIDTH,
            WIDTH,
            r_tile,
        );
        sync_cube();
    }
    // The output layer (64 → 3), one unit per (row, channel).
    let out_off = k * WIDTH + (hidden - 1) * WIDTH * WIDTH;
    let last = xs_len + (hidden - 1) * r_tile * WIDTH;
    let mut t = UNIT_POS as usize;
    while t < r_tile * 3 {
        let r = t / 3;
        let c = t % 3;
        let mut o = 0.0f32;
        for kk in 0..WIDTH {
            o += f32::cast_from(mlp[out_off + kk * 3 + c])
                * f32::cast_from(act[last + r * WIDTH + kk]);
        }
        small[t] = o;
        t += WIDTH;
    }
    sync_cube();
}

/// The output activation (0 exponential, 1 softplus, 2 ReLU; as `loss::activate`).
#[cube]
fn activate(o: f32, #[comptime] activation: u32) -> f32 {
    let mut y = 0.0f32;
    if activation == 0 {
        y = o.clamp(-40.0f32, 40.0f32).exp();
    } else if activation == 1 {
        if o > 20.0f32 {
            y = o;
        } else {
            y = o.exp().log1p();
        }
    } else if o > 0.0f32 {
        y = o;
    }
    y
}

/// The derivative of [`activate`] (straight through the exponential's clamp).
#[cube]
fn activate_grad(o: f32, #[comptime] activation: u32) -> f32 {
    let mut d = 0.0f32;
    if activation == 0 {
        d = o.clamp(-40.0f32, 40.0f32).exp();
    } else if activation == 1 {
        d = 1.0f32 / (1.0f32 + (-o).exp());
    } else if o > 0.0f32 {
        d = 1.0f32;
    }
    d
}

/// Huber's loss of a relative residual and its derivative, as `loss::sample_loss`.
#[cube]
fn huber(r: f32, k: f32, deriv: &mut Array<f32>) -> f32 {
    let mut h = r * r;
    deriv[0] = 2.0f32 * r;
    if r.abs() > k {
        h = 2.0f32 * k * r.abs() - k * k;
        let mut s = 1.0f32;
        if r < 0.0f32 {
            s = -1.0f32;
        }
        deriv[0] = 2.0f32 * k * s;
    }
    h
}

/// Unit `u`'s column of a layer's weight gradient, `Σ_r in[r][kk] · δ[r][u]` for every input
/// `kk` (the layer's input rows at `in_base`, `in_dims` wide; δ at `d_base`), added to (or, on
/// the cube's first tile, written to) the cube's partial at `w_at + kk·64 + u`.
#[cube]
fn weight_gradient<M: Float>(
    act: &Shared<[M]>,
    delta: &Shared<[f32]>,
    wpart: &mut [f32],
    in_base: usize,
    d_base: usize,
    w_at: usize,
    first_tile: bool,
    #[comptime] in_dims: usize,
    #[comptime] r_tile: usize,
) {
    let u = UNIT_POS as usize;
    let mut own = Array::<f32>::new(r_tile);
    #[unroll]
    for r in 0..r_tile {
        own[r] = delta[d_base + r * WIDTH + u];
    }
    for kk in 0..in_dims {
        let mut g = 0.0f32;
        #[unroll]
        for r in 0..r_tile {
            g += f32::cast_from(act[in_base + r * in_dims + kk]) * own[r];
        }
        let at = w_at + kk * WIDTH + u;
        if first_tile {
            wpart[at] = g;
        } else {
            wpart[at] += g;
        }
    }
}

/// One training pass over the batch (see the module documentation): forward, loss, backward
/// per tile; the cube's weight-gradient partial in `wpart[CUBE_POS·w_total..]`, its loss sum in
/// `lpart[CUBE_POS]`, ∂L/∂(grid columns) in `dxg` (`[n][levels·features]`).
#[cube(launch_unchecked)]
pub fn train_tiles<T: Float, M: Float>(
    rows: &[f32],
    table: &[T],
    info: &[u32],
    mlp: &[M],
    dxg: &mut [f32],
    wpart: &mut [f32],
    lpart: &mut [f32],
    n: u32,
    n_parts: u32,
    epsilon: f32,
    huber_k: f32,
    scale: f32,
    #[comptime] r_tile: usize,
    #[comptime] k: usize,
    #[comptime] hidden: usize,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] stride: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] grid_out: usize,
    #[comptime] unpadded: usize,
    #[comptime] factor_at: usize,
    #[comptime] activation: u32,
    #[comptime] w_total: usize,
    #[comptime] act_len: usize,
) {
    let u = UNIT_POS as usize;
    let n = n as usize;
    let tiles = n.div_ceil(r_tile);
    let mut act = Shared::<[M]>::new_slice(act_len);
    let mut small = Shared::<[f32]>::new_slice(r_tile * 7);
    let mut delta = Shared::<[f32]>::new_slice(r_tile * WIDTH * 2);
    let xs_len = r_tile * k;
    let wp = CUBE_POS * w_total;
    let grid_dims = levels * features;
    let mut first_tile = true;
    let mut t = CUBE_POS;
    let mut deriv = Array::<f32>::new(1usize);
    while t < tiles {
        let first = t * r_tile;
        forward_tile::<T, M>(
            rows, table, info, mlp, &mut act, &mut small, first, n, n_parts, r_tile, k, hidden,
            levels, features, stride, row_len, grid_in, grid_out, unpadded,
        );
        // Loss and its gradient, one unit per row.
        if u < r_tile {
            let i = first + u;
            let mut loss = 0.0f32;
            let mut d0 = 0.0f32;
            let mut d1 = 0.0f32;
            let mut d2 = 0.0f32;
            if i < n {
                let row = i * row_len;
                let o0 = small[u * 3];
                let o1 = small[u * 3 + 1];
                let o2 = small[u * 3 + 2];
                let f0 = rows[row + factor_at];
                let f1 = rows[row + factor_at + 1];
                let f2 = rows[row + factor_at + 2];
                let y0 = activate(o0, activation) * f0;
                let y1 = activate(o1, activation) * f1;
                let y2 = activate(o2, activation) * f2;
                let lum = 0.2126f32 * y0 + 0.7152f32 * y1 + 0.0722f32 * y2;
                let norm = (lum * lum + epsilon).sqrt();
                let w = rows[row + factor_at + 6];
                let c = w / norm * scale;
                loss += w * huber((y0 - rows[row + factor_at + 3]) / norm, huber_k, &mut deriv);
                d0 = c * deriv[0] * activate_grad(o0, activation) * f0;
                loss += w * huber((y1 - rows[row + factor_at + 4]) / norm, huber_k, &mut deriv);
                d1 = c * deriv[0] * activate_grad(o1, activation) * f1;
                loss += w * huber((y2 - rows[row + factor_at + 5]) / norm, huber_k, &mut deriv);
                d2 = c * deriv[0] * activate_grad(o2, activation) * f2;
            }
            small[r_tile * 3 + u * 3] = d0;
            small[r_tile * 3 + u * 3 + 1] = d1;
            small[r_tile * 3 + u * 3 + 2] = d2;
            small[r_tile * 6 + u] = loss;
        }
        sync_cube();
        if u == 0 {
            let mut s = 0.0f32;
            for r in 0..r_tile {
                s += small[r_tile * 6 + r];
            }
            if first_tile {
                lpart[CUBE_POS] = s;
            } else {
                lpart[CUBE_POS] += s;
            }
        }
        // Output layer: its weight gradient and the last hidden layer's delta.
        let out_off = k * WIDTH + (hidden - 1) * WIDTH * WIDTH;
        let last = xs_len + (hidden - 1) * r_tile * WIDTH;
        #[unroll]
        for c in 0..3usize {
            let mut g = 0.0f32;
            #[unroll]
            for r in 0..r_tile {
                g += f32::cast_from(act[last + r * WIDTH + u]) * small[r_tile * 3 + r * 3 + c];
            }
            let at = wp + out_off + u * 3 + c;
            if first_tile {
                wpart[at] = g;
            } else {
                wpart[at] += g;
            }
        }
        let w0 = f32::cast_from(mlp[out_off + u * 3]);
        let w1 = f32::cast_from(mlp[out_off + u * 3 + 1]);
        let w2 = f32::cast_from(mlp[out_off + u * 3 + 2]);
        #[unroll]
        for r in 0..r_tile {
            let d = r_tile * 3 + r * 3;
            let s = w0 * small[d] + w1 * small[d + 1] + w2 * small[d + 2];
            let h = f32::cast_from(act[last + r * WIDTH + u]);
            delta[r * WIDTH + u] = select(h > 0.0f32, s, 0.0f32);
        }
        sync_cube();
        // Hidden layers from the last: weight gradient, then the delta of the layer below.
        let mut acc = Array::<f32>::new(r_tile);
        // Unrolled, with each layer's δ buffer half fixed by its parity: a runtime loop over the
        // layers here, with a mutable buffer index, trained wrongly on lavapipe as soon as a
        // cube took several tiles and the network had 4 or more hidden layers (the gradient
        // test with a cube cap of 3 catches it).
        #[unroll]
        for back in 1..hidden {
            // (A mutable local started from a comptime value fails CubeCL's verifier.)
            let l = hidden - back;
            let w_off = k * WIDTH + (l - 1) * WIDTH * WIDTH;
            let in_base = xs_len + (l - 1) * r_tile * WIDTH;
            let cb = ((back - 1) % 2) * r_tile * WIDTH;
            let nb = (back % 2) * r_tile * WIDTH;
            weight_gradient::<M>(
                &act,
                &delta,
                wpart,
                in_base,
                cb,
                wp + w_off,
                first_tile,
                WIDTH,
                r_tile,
            );
            // δ_below[r][u] = relu'(h[r][u]) · Σ_j W[u][j] · δ[r][j]
            #[unroll]
            for r in 0..r_tile {
                acc[r] = 0.0f32;
            }
            for j in 0..WIDTH {
                let w = f32::cast_from(mlp[w_off + u * WIDTH + j]);
                #[unroll]
                for r in 0..r_tile {
                    acc[r] += w * delta[cb + r * WIDTH + j];
                }
            }
            #[unroll]
            for r in 0..r_tile {
                let h = f32::cast_from(act[in_base + r * WIDTH + u]);
                delta[nb + r * WIDTH + u] = select(h > 0.0f32, acc[r], 0.0f32);
            }
            sync_cube();
        }
        // The first layer: its weight gradient, and ∂L/∂(grid columns) out.
        let cb = ((hidden - 1) % 2) * r_tile * WIDTH;
        weight_gradient::<M>(&act, &delta, wpart, 0usize, cb, wp, first_tile, k, r_tile);
        let mut col = u;
        while col < grid_dims {
            let kk = grid_out + col;
            #[unroll]
            for r in 0..r_tile {
                acc[r] = 0.0f32;
            }
            for j in 0..WIDTH {
                let w = f32::cast_from(mlp[kk * WIDTH + j]);
                #[unroll]
                for r in 0..r_tile {
                    acc[r] += w * delta[cb + r * WIDTH + j];
                }
            }
            #[unroll]
            for r in 0..r_tile {
                let i = first + r;
                if i < n {
                    dxg[i * grid_dims + col] = acc[r];
                }
            }
            col += WIDTH;
        }
        sync_cube();
        first_tile = false;
        t += CUBE_COUNT;
    }
}

/// Inference over packed query rows: radiance `act(o) · factor` into `out` (`[n][3]`).
#[cube(launch_unchecked)]
pub fn infer_tiles<T: Float, M: Float>(
    rows: &[f32],
    table: &[T],
    info: &[u32],
    mlp: &[M],
    out: &mut [f32],
    n: u32,
    n_parts: u32,
    #[comptime] r_tile: usize,
    #[comptime] k: usize,
    #[comptime] hidden: usize,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] stride: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] grid_out: usize,
    #[comptime] unpadded: usize,
    #[comptime] factor_at: usize,
    #[comptime] activation: u32,
    #[comptime] act_len: usize,
) {
    let u = UNIT_POS as usize;
    let n = n as usize;
    let tiles = n.div_ceil(r_tile);
    let mut act = Shared::<[M]>::new_slice(act_len);
    let mut small = Shared::<[f32]>::new_slice(r_tile * 7);
    let mut t = CUBE_POS;
    while t < tiles {
        let first = t * r_tile;
        forward_tile::<T, M>(
            rows, table, info, mlp, &mut act, &mut small, first, n, n_parts, r_tile, k, hidden,
            levels, features, stride, row_len, grid_in, grid_out, unpadded,
        );
        let mut q = u;
        while q < r_tile * 3 {
            let i = first + q / 3;
            if i < n {
                let c = q % 3;
                out[i * 3 + c] = activate(small[q], activation) * rows[i * row_len + factor_at + c];
            }
            q += WIDTH;
        }
        sync_cube();
        t += CUBE_COUNT;
    }
}

/// `value` added to the f32 whose bits `buf[at]` holds, by a compare-and-swap loop (WGSL has no
/// float atomics). CubeCL's weak exchange returns only the old value: a spurious failure that
/// still returns the expected value would end the loop without the add. SPIR-V's and CUDA's
/// exchanges are strong (WGSL's compiles to SPIR-V's on Vulkan); the native path
/// ([`scatter_native`]) is taken wherever the adapter has float atomics.
#[cube]
fn atomic_add_cas(buf: &[Atomic<u32>], at: usize, value: f32) {
    let mut v = buf[at].load();
    loop {
        let prev = v;
        let new = (f32::from_bits(v) + value).to_bits();
        v = buf[at].compare_exchange_weak(v, new);
        if prev == v {
            break;
        }
    }
}

/// Marks entry `e` referenced; with `with_list`, the first mark of an entry also appends it to
/// `list` (its length counted in `counter[parity]`), so that the table update visits only the
/// referenced entries.
#[cube]
fn mark(
    touched: &[Atomic<u32>],
    list: &mut [u32],
    counter: &[Atomic<u32>],
    parity: u32,
    e: usize,
    #[comptime] with_list: bool,
) {
    if with_list {
        let prev = touched[e].exchange(1u32);
        if prev == 0u32 {
            let slot = counter[parity as usize].fetch_add(1u32);
            list[slot as usize] = e as u32;
        }
    } else {
        touched[e].store(1u32);
    }
}

/// What unit `p` of a scatter adds (one unit per (sample, level)): the eight corners' entries
/// of its sample on its level in `index`, weight × upstream gradient in `value` (`features` per
/// corner); marks the entries referenced (and lists them, with `with_list`).
#[cube]
fn scatter_values(
    rows: &[f32],
    info: &[u32],
    dxg: &[f32],
    touched: &[Atomic<u32>],
    list: &mut [u32],
    counter: &[Atomic<u32>],
    parity: u32,
    p: usize,
    index: &mut Array<u32>,
    value: &mut Array<f32>,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] with_list: bool,
) {
    let i = p / levels;
    let l = p % levels;
    let mut weight = Array::<f32>::new(8usize);
    let at = i * row_len + grid_in;
    corners(
        info,
        l,
        rows[at],
        rows[at + 1],
        rows[at + 2],
        index,
        &mut weight,
    );
    let d = i * levels * features + l * features;
    #[unroll]
    for c in 0..8usize {
        mark(touched, list, counter, parity, index[c] as usize, with_list);
        #[unroll]
        for f in 0..features {
            value[c * features + f] = weight[c] * dxg[d + f];
        }
    }
}

/// The hash-grid gradient scatter ([`scatter_values`] per (sample, level)) with
/// compare-and-swap adds.
#[cube(launch)]
pub fn scatter_cas(
    rows: &[f32],
    info: &[u32],
    dxg: &[f32],
    grad: &[Atomic<u32>],
    touched: &[Atomic<u32>],
    list: &mut [u32],
    counter: &[Atomic<u32>],
    n: u32,
    parity: u32,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] with_list: bool,
) {
    let p = ABSOLUTE_POS;
    if p < n as usize * levels {
        let mut index = Array::<u32>::new(8usize);
        let mut value = Array::<f32>::new(8 * features);
        scatter_values(
            rows, info, dxg, touched, list, counter, parity, p, &mut index, &mut value, levels,
            features, row_len, grid_in, with_list,
        );
        #[unroll]
        for c in 0..8usize {
            #[unroll]
            for f in 0..features {
                let v = value[c * features + f];
                if v != 0.0f32 {
                    atomic_add_cas(grad, index[c] as usize * features + f, v);
                }
            }
        }
    }
}

/// [`scatter_cas`] with native float atomic adds (where the adapter has them).
#[cube(launch)]
pub fn scatter_native(
    rows: &[f32],
    info: &[u32],
    dxg: &[f32],
    grad: &[Atomic<f32>],
    touched: &[Atomic<u32>],
    list: &mut [u32],
    counter: &[Atomic<u32>],
    n: u32,
    parity: u32,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] row_len: usize,
    #[comptime] grid_in: usize,
    #[comptime] with_list: bool,
) {
    let p = ABSOLUTE_POS;
    if p < n as usize * levels {
        let mut index = Array::<u32>::new(8usize);
        let mut value = Array::<f32>::new(8 * features);
        scatter_values(
            rows, info, dxg, touched, list, counter, parity, p, &mut index, &mut value, levels,
            features, row_len, grid_in, with_list,
        );
        #[unroll]
        for c in 0..8usize {
            #[unroll]
            for f in 0..features {
                let v = value[c * features + f];
                if v != 0.0f32 {
                    grad[index[c] as usize * features + f].fetch_add(v);
                }
            }
        }
    }
}

/// Adam on one value (as `StepConstants::adam`: a non-finite gradient counts as zero, a
/// non-finite update is skipped); returns the new weight and writes the moments to `mv`.
#[cube]
fn adam(
    w: f32,
    m: f32,
    v: f32,
    g: f32,
    mv: &mut Array<f32>,
    beta1: f32,
    beta2: f32,
    epsilon: f32,
    l2: f32,
    step_size: f32,
    inv_bc2: f32,
) -> f32 {
    let mut gg = l2 * w;
    if !(g.is_nan() || g.is_inf()) {
        gg = g + l2 * w;
    }
    let m1 = beta1 * m + (1.0f32 - beta1) * gg;
    let v1 = beta2 * v + (1.0f32 - beta2) * gg * gg;
    let upd = step_size * m1 / ((v1 * inv_bc2).sqrt() + epsilon);
    mv[0] = m1;
    mv[1] = v1;
    let mut out = w;
    if !(upd.is_nan() || upd.is_inf()) {
        out = w - upd;
    }
    out
}

/// The MLP's update: the cubes' gradient partials summed (in cube order), Adam, the EMA; unit 0
/// also writes the step's mean loss to `losses[step_index]`.
#[cube(launch)]
pub fn mlp_adam<S: Float>(
    wpart: &[f32],
    lpart: &[f32],
    w: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    ema: &mut [f32],
    half: &mut [S],
    losses: &mut [f32],
    cubes: u32,
    w_total: u32,
    step_index: u32,
    loss_scale: f32,
    beta1: f32,
    beta2: f32,
    epsilon: f32,
    l2: f32,
    step_size: f32,
    inv_bc2: f32,
    alpha: f32,
    #[comptime] with_ema: bool,
    #[comptime] with_half: bool,
) {
    let i = ABSOLUTE_POS;
    if i == 0 {
        let mut s = 0.0f32;
        for c in 0..cubes as usize {
            s += lpart[c];
        }
        losses[step_index as usize] = s * loss_scale;
    }
    if i < w_total as usize {
        let mut g = 0.0f32;
        for c in 0..cubes as usize {
            g += wpart[c * w_total as usize + i];
        }
        let mut mv = Array::<f32>::new(2usize);
        let wn = adam(
            w[i], m[i], v[i], g, &mut mv, beta1, beta2, epsilon, l2, step_size, inv_bc2,
        );
        w[i] = wn;
        m[i] = mv[0];
        v[i] = mv[1];
        if with_ema {
            ema[i] = alpha * ema[i] + (1.0f32 - alpha) * wn;
        }
        if with_half {
            half[i] = S::cast_from(wn.clamp(-HALF_MAX, HALF_MAX));
        }
    }
}

/// Sparse Adam over the table (weights `w`, moments `m` and `v`, EMA gap `q`, `features` per
/// entry): every entry marked in `touched` is updated from `grad` (and its EMA gap moved by
/// `gap_growth·(w_old − w_new)`); its gradient and mark are cleared. One unit per entry, or with
/// `with_list` one per listed entry (the first `counter[parity]` of `list`; unit 0 also zeroes
/// the other parity's counter, which the next step's scatter counts in).
#[cube(launch)]
pub fn table_adam<S: Float>(
    w: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    q: &mut [f32],
    grad: &mut [f32],
    touched: &mut [u32],
    half: &mut [S],
    list: &[u32],
    counter: &[Atomic<u32>],
    parity: u32,
    entries: u32,
    beta1: f32,
    beta2: f32,
    epsilon: f32,
    l2: f32,
    step_size: f32,
    inv_bc2: f32,
    gap_growth: f32,
    #[comptime] features: usize,
    #[comptime] with_ema: bool,
    #[comptime] with_half: bool,
    #[comptime] with_list: bool,
) {
    let p = ABSOLUTE_POS;
    let mut e = p;
    let mut go = false;
    if with_list {
        if p == 0 {
            counter[1 - parity as usize].store(0u32);
        }
        if p < counter[parity as usize].load() as usize {
            e = list[p] as usize;
            go = true;
        }
    } else if p < entries as usize {
        go = touched[p] != 0u32;
    }
    {
        if go {
            touched[e] = 0u32;
            let mut mv = Array::<f32>::new(2usize);
            #[unroll]
            for f in 0..features {
                let i = e * features + f;
                let old = w[i];
                let wn = adam(
                    old, m[i], v[i], grad[i], &mut mv, beta1, beta2, epsilon, l2, step_size,
                    inv_bc2,
                );
                w[i] = wn;
                m[i] = mv[0];
                v[i] = mv[1];
                grad[i] = 0.0f32;
                if with_ema {
                    q[i] += gap_growth * (old - wn);
                }
                if with_half {
                    half[i] = S::cast_from(wn.clamp(-HALF_MAX, HALF_MAX));
                }
            }
        }
    }
}

/// `c·v`, exactly 0 for `c = 0` whatever `v` (a non-finite value left out, not turned into
/// NaN: the CPU's conversions overwrite).
#[cube]
fn term(c: f32, v: f32) -> f32 {
    let mut t = 0.0f32;
    if c != 0.0f32 {
        t = c * v;
    }
    t
}

/// `y ← (cx·x + cy·y)·cs`, element by element (the table's EMA conversions and rebases, `y`
/// the EMA slot and `x` the weights).
#[cube(launch)]
pub fn combine_into(x: &[f32], y: &mut [f32], len: u32, cx: f32, cy: f32, cs: f32) {
    let p = ABSOLUTE_POS;
    if p < len as usize {
        y[p] = (term(cx, x[p]) + term(cy, y[p])) * cs;
    }
}

/// `out = (cx·x + cy·y)·cs`, element by element, stored as `O` (clamped to ±65504 first with
/// `half`, as the CPU rounds its half-precision tables).
#[cube(launch)]
pub fn combine<O: Float>(
    x: &[f32],
    y: &[f32],
    out: &mut [O],
    len: u32,
    cx: f32,
    cy: f32,
    cs: f32,
    #[comptime] half: bool,
) {
    let p = ABSOLUTE_POS;
    if p < len as usize {
        let v = (term(cx, x[p]) + term(cy, y[p])) * cs;
        if half {
            out[p] = O::cast_from(v.clamp(-HALF_MAX, HALF_MAX));
        } else {
            out[p] = O::cast_from(v);
        }
    }
}
