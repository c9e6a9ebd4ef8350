//! The fused MLP on the CPU: forward and backward of one batch tile whose activations stay in
//! the core's L2 cache (a tile of 128 samples of a 3-hidden-layer network is ≈ 200 KiB with
//! its weights), in the spirit of tiny-cuda-nn's fully fused MLP keeping a tile in shared memory.
//! With `"precision": "bf16"` the hidden layers' products take bfloat16 operands and f32 sums
//! ([`super::bf16`]); the output layer (3 of 8 padded columns) stays f32.

use super::bf16::{Pairs, gemm_pairs, pairs_along_columns, pairs_along_rows};
use super::gemm::{Rows, Store, Strided, gemm};
use crate::config::MlpPrecision;
use crate::model::{LayerShape, OUTPUTS, WIDTH};

/// Columns of the padded output layer (the kernels work on multiples of 8 columns).
pub const OUT_PAD: usize = 8;

/// Samples per tile.
pub const TILE: usize = 128;

/// The weights arranged for the kernels: forward matrices (the output layer padded to 8
/// columns) and their transposes for the backward pass; with bfloat16 products, the hidden
/// layers' matrices also in bfloat16 pairs.
#[derive(Clone, Debug)]
pub struct PreparedMlp {
    /// Layer shapes (from the layout).
    pub layers: Vec<LayerShape>,
    /// Forward matrices `[in][out]`, the last one `[64][8]` zero-padded.
    forward: Vec<Vec<f32>>,
    /// Transposed matrices `[out][in_pad]` (rows padded to a multiple of 8).
    transposed: Vec<Vec<f32>>,
    /// With `"precision": "bf16"`, per hidden layer: the forward matrix in pairs along its
    /// inputs `[in/2][64]` and the transposed one in pairs along its outputs `[32][in_pad]`.
    pairs: Option<Vec<(Vec<u32>, Vec<u32>)>>,
}

/// Rounds up to a multiple of 8.
#[inline]
pub fn pad8(n: usize) -> usize {
    n.div_ceil(8) * 8
}

impl PreparedMlp {
    /// Arranges the MLP parameter group `params` (layout of [`LayerShape`]) for products in
    /// `precision` (bfloat16 needs an even number of inputs; otherwise f32 is used).
    pub fn new(layers: &[LayerShape], params: &[f32], precision: MlpPrecision) -> Self {
        let last = layers.len() - 1;
        let mut forward = Vec::with_capacity(layers.len());
        let mut transposed = Vec::with_capacity(layers.len());
        for (l, s) in layers.iter().enumerate() {
            let m = &params[s.offset..s.offset + s.len()];
            let cols = if l == last { OUT_PAD } else { s.outputs };
            let mut f = vec![0f32; s.inputs * cols];
            for k in 0..s.inputs {
                f[k * cols..k * cols + s.outputs]
                    .copy_from_slice(&m[k * s.outputs..(k + 1) * s.outputs]);
            }
            forward.push(f);
            let ip = pad8(s.inputs);
            let mut t = vec![0f32; s.outputs * ip];
            for k in 0..s.inputs {
                for j in 0..s.outputs {
                    t[j * ip + k] = m[k * s.outputs + j];
                }
            }
            transposed.push(t);
        }
        let bf16 = precision == MlpPrecision::Bf16 && layers[0].inputs.is_multiple_of(2);
        let pairs = bf16.then(|| {
            (0..last)
                .map(|l| {
                    let (k, ip) = (layers[l].inputs, pad8(layers[l].inputs));
                    let mut f = vec![0u32; k / 2 * WIDTH];
                    pairs_along_rows(&forward[l], k, WIDTH, WIDTH, &mut f);
                    let mut t = vec![0u32; WIDTH / 2 * ip];
                    pairs_along_rows(&transposed[l], WIDTH, ip, ip, &mut t);
                    (f, t)
                })
                .collect()
        });
        Self {
            layers: layers.to_vec(),
            forward,
            transposed,
            pairs,
        }
    }

    /// Network input width.
    pub fn inputs(&self) -> usize {
        self.layers[0].inputs
    }

    /// Hidden layers.
    pub fn hidden(&self) -> usize {
        self.layers.len() - 1
    }
}

/// Per-thread scratch for one tile.
#[derive(Clone, Debug)]
pub struct TileScratch {
    /// Encoded inputs `[TILE][in]`.
    pub x: Vec<f32>,
    /// Hidden activations (after ReLU), one `[TILE][64]` per hidden layer.
    pub h: Vec<Vec<f32>>,
    /// Network outputs before the output activation `[TILE][8]`.
    pub out: Vec<f32>,
    /// Loss gradient with respect to `out` `[TILE][8]`.
    pub dout: Vec<f32>,
    dh: [Vec<f32>; 2],
    /// bfloat16 pairs of a product's left operand (`[TILE][max(in, 64)/2]`, or
    /// `[TILE/2][max(in, 64)]` paired along the rows).
    pairs_a: Vec<u32>,
    /// bfloat16 pairs of the backward gradient paired along the rows `[TILE/2][64]`.
    pairs_b: Vec<u32>,
    /// ∂L/∂x of the first layer's requested columns, padded to whole groups of 8 `[TILE][≤ in]`.
    dx: Vec<f32>,
}

impl TileScratch {
    /// Scratch for a network with `inputs` inputs and `hidden` hidden layers.
    pub fn new(inputs: usize, hidden: usize) -> Self {
        Self {
            x: vec![0.0; TILE * inputs],
            h: vec![vec![0.0; TILE * WIDTH]; hidden],
            out: vec![0.0; TILE * OUT_PAD],
            dout: vec![0.0; TILE * OUT_PAD],
            dh: [vec![0.0; TILE * WIDTH], vec![0.0; TILE * WIDTH]],
            pairs_a: vec![0; TILE * inputs.max(WIDTH).div_ceil(2)],
            pairs_b: vec![0; TILE.div_ceil(2) * WIDTH],
            dx: vec![0.0; TILE * pad8(inputs)],
        }
    }
}

/// Weight gradients accumulated over tiles, laid out like the forward matrices (the output
/// layer padded to 8 columns).
#[derive(Clone, Debug)]
pub struct MlpGrad {
    /// One buffer per layer.
    pub layers: Vec<Vec<f32>>,
}

impl MlpGrad {
    /// Zeroed gradients for `mlp`.
    pub fn zeros(mlp: &PreparedMlp) -> Self {
        Self {
            layers: mlp.forward.iter().map(|f| vec![0.0; f.len()]).collect(),
        }
    }

    /// Adds another thread's gradients.
    pub fn add(&mut self, other: &Self) {
        for (a, b) in self.layers.iter_mut().zip(&other.layers) {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        }
    }

    /// Writes the gradients in the parameter group's layout.
    pub fn write_flat(&self, layers: &[LayerShape], out: &mut [f32]) {
        for (s, g) in layers.iter().zip(&self.layers) {
            let cols = g.len() / s.inputs;
            for k in 0..s.inputs {
                out[s.offset + k * s.outputs..s.offset + (k + 1) * s.outputs]
                    .copy_from_slice(&g[k * cols..k * cols + s.outputs]);
            }
        }
    }
}

/// Forward pass of `m ≤ TILE` samples whose inputs are in `scratch.x`: fills `scratch.h` and
/// `scratch.out` (first 3 of 8 columns meaningful).
pub fn forward_tile(mlp: &PreparedMlp, m: usize, s: &mut TileScratch) {
    let k_in = mlp.inputs();
    let hidden = mlp.hidden();
    for l in 0..hidden {
        let (prev, rest) = s.h.split_at_mut(l);
        let (a, k) = if l == 0 {
            (&s.x[..], k_in)
        } else {
            (&prev[l - 1][..], WIDTH)
        };
        let out = Rows {
            data: &mut rest[0][..],
            stride: WIDTH,
        };
        match &mlp.pairs {
            Some(p) => {
                pairs_along_columns(a, m, k, k, &mut s.pairs_a);
                gemm_pairs(
                    m,
                    WIDTH,
                    k / 2,
                    Pairs {
                        data: &s.pairs_a,
                        row_stride: k / 2,
                        col_stride: 1,
                    },
                    Rows {
                        data: &p[l].0,
                        stride: WIDTH,
                    },
                    out,
                    Store::Relu,
                );
            }
            None => gemm(
                m,
                WIDTH,
                k,
                Strided {
                    data: a,
                    row_stride: k,
                    col_stride: 1,
                },
                Rows {
                    data: &mlp.forward[l],
                    stride: WIDTH,
                },
                out,
                Store::Relu,
            ),
        }
    }
    gemm(
        m,
        OUT_PAD,
        WIDTH,
        Strided {
            data: &s.h[hidden - 1],
            row_stride: WIDTH,
            col_stride: 1,
        },
        Rows {
            data: &mlp.forward[hidden],
            stride: OUT_PAD,
        },
        Rows {
            data: &mut s.out[..],
            stride: OUT_PAD,
        },
        Store::Overwrite,
    );
}

/// `grad += aᵀ · d` over a tile's `m` rows (`a`: `[m][k]`, `d`: `[m][64]`, `grad`: `[k][64]`):
/// a hidden layer's weight gradient. `pa` and `pb` hold the bfloat16 pairs.
#[allow(clippy::too_many_arguments)]
fn weight_gradient(
    mlp: &PreparedMlp,
    m: usize,
    a: &[f32],
    k: usize,
    d: &[f32],
    grad: &mut [f32],
    pa: &mut [u32],
    pb: &mut [u32],
) {
    let grad = Rows {
        data: grad,
        stride: WIDTH,
    };
    if mlp.pairs.is_some() {
        pairs_along_rows(a, m, k, k, pa);
        pairs_along_rows(d, m, WIDTH, WIDTH, pb);
        let a = Pairs {
            data: pa,
            row_stride: 1,
            col_stride: k,
        };
        let d = Rows {
            data: &pb[..],
            stride: WIDTH,
        };
        gemm_pairs(k, WIDTH, m.div_ceil(2), a, d, grad, Store::Accumulate);
    } else {
        let a = Strided {
            data: a,
            row_stride: 1,
            col_stride: k,
        };
        let d = Rows {
            data: d,
            stride: WIDTH,
        };
        gemm(k, WIDTH, m, a, d, grad, Store::Accumulate);
    }
}

/// `out[m][n] = d · Mₗᵀ` restricted to columns `start..start + n` of `Mₗᵀ` (`d`: `[m][64]`): the
/// gradient with respect to hidden layer `l`'s inputs. `pa` holds the bfloat16 pairs.
fn input_gradient(
    mlp: &PreparedMlp,
    l: usize,
    m: usize,
    d: &[f32],
    (start, n): (usize, usize),
    out: &mut [f32],
    pa: &mut [u32],
) {
    let ip = pad8(mlp.layers[l].inputs);
    let out = Rows {
        data: out,
        stride: n,
    };
    match &mlp.pairs {
        Some(p) if n.is_multiple_of(16) => {
            pairs_along_columns(d, m, WIDTH, WIDTH, pa);
            let d = Pairs {
                data: pa,
                row_stride: WIDTH / 2,
                col_stride: 1,
            };
            let t = Rows {
                data: &p[l].1[start..],
                stride: ip,
            };
            gemm_pairs(m, n, WIDTH / 2, d, t, out, Store::Overwrite);
        }
        _ => {
            let d = Strided {
                data: d,
                row_stride: WIDTH,
                col_stride: 1,
            };
            let t = Rows {
                data: &mlp.transposed[l][start..],
                stride: ip,
            };
            gemm(m, n, WIDTH, d, t, out, Store::Overwrite);
        }
    }
}

/// Where [`backward_tile`] hands ∂L/∂x: `(first column, columns, sink)`; `sink(i, values)`
/// receives row `i`'s gradient for those input columns, once per row of the tile.
pub type InputGradient<'a> = (usize, usize, &'a mut dyn FnMut(usize, &[f32]));

/// Backward pass of a tile after [`forward_tile`], with `scratch.dout` holding ∂L/∂out (zero in
/// the padding columns): accumulates the weight gradients into `grad` and, when `dx` is given,
/// hands ∂L/∂x for the requested input columns to its sink, row by row.
pub fn backward_tile(
    mlp: &PreparedMlp,
    m: usize,
    s: &mut TileScratch,
    grad: &mut MlpGrad,
    dx: Option<InputGradient<'_>>,
) {
    let hidden = mlp.hidden();
    let k_in = mlp.inputs();
    // Output layer (f32): dM += h_lastᵀ · dout, dh = dout · Mᵀ ⊙ relu'.
    gemm(
        WIDTH,
        OUT_PAD,
        m,
        Strided {
            data: &s.h[hidden - 1],
            row_stride: 1,
            col_stride: WIDTH,
        },
        Rows {
            data: &s.dout,
            stride: OUT_PAD,
        },
        Rows {
            data: &mut grad.layers[hidden][..],
            stride: OUT_PAD,
        },
        Store::Accumulate,
    );
    let [dh_a, dh_b] = &mut s.dh;
    gemm(
        m,
        WIDTH,
        OUTPUTS,
        Strided {
            data: &s.dout,
            row_stride: OUT_PAD,
            col_stride: 1,
        },
        Rows {
            data: &mlp.transposed[hidden],
            stride: WIDTH,
        },
        Rows {
            data: &mut dh_a[..],
            stride: WIDTH,
        },
        Store::Overwrite,
    );
    relu_mask(&mut dh_a[..m * WIDTH], &s.h[hidden - 1][..m * WIDTH]);
    let (mut cur, mut next) = (dh_a, dh_b);
    let (pa, pb) = (&mut s.pairs_a[..], &mut s.pairs_b[..]);
    for l in (1..hidden).rev() {
        let h = &s.h[l - 1];
        weight_gradient(mlp, m, h, WIDTH, cur, &mut grad.layers[l], pa, pb);
        input_gradient(mlp, l, m, cur, (0, WIDTH), next, pa);
        relu_mask(&mut next[..m * WIDTH], &h[..m * WIDTH]);
        std::mem::swap(&mut cur, &mut next);
    }
    // First layer: dM0 += xᵀ · dh, dx = dh · M0ᵀ (only the requested columns).
    weight_gradient(mlp, m, &s.x, k_in, cur, &mut grad.layers[0], pa, pb);
    if let Some((first, cols, sink)) = dx {
        let start = first / 8 * 8;
        let n = pad8(first + cols) - start;
        debug_assert!(start + n <= pad8(k_in));
        let tmp = &mut s.dx[..m * n];
        input_gradient(mlp, 0, m, cur, (start, n), tmp, pa);
        let off = first - start;
        for i in 0..m {
            sink(i, &tmp[i * n + off..i * n + off + cols]);
        }
    }
}

/// `d ⊙= (h > 0)`: the ReLU derivative, from the activation after ReLU. Written as a select
/// so it vectorises: about half the activations are zero, and a branch per element
/// mispredicted often enough to cost a quarter of the MLP's time (measured with perf).
#[inline]
fn relu_mask(d: &mut [f32], h: &[f32]) {
    for (dv, hv) in d.iter_mut().zip(h) {
        *dv = if *hv > 0.0 { *dv } else { 0.0 };
    }
}
