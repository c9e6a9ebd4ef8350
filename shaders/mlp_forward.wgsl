// Fully fused MLP forward (after tiny-cuda-nn's FullyFusedMLP): a workgroup takes a tile of
// TILE samples through every layer while their activations stay in workgroup memory; only the
// network input is read from and the 3 raw outputs written to global memory. With STORE = 1
// (training), each hidden layer's activation is also written out for the backward kernel.
//
// Network: 64-wide, no biases, ReLU on hidden layers, linear 3 outputs. Weights are the MLP
// parameter group, input-major per layer: layer l's M[k][j] at info offset_l + k·outputs + j.
//
// Thread t of the 256 owns sample row t / 4 of the tile and the 16 output columns
// 16·(t % 4) .. 16·(t % 4) + 16 of every hidden layer.

// Every binding is read_write, inputs too: CubeCL packs tensors into shared wgpu buffers and
// wgpu refuses one buffer bound both read-only and read-write in a dispatch.
@group(0) @binding(0) var<storage, read_write> weights: array<f32>;
@group(0) @binding(1) var<storage, read_write> input: array<f32>;          // [n, IN]
@group(0) @binding(2) var<storage, read_write> output: array<f32>;   // [n, 3]
@group(0) @binding(3) var<storage, read_write> hidden: array<f32>;   // [HIDDEN, n, 64] when STORE
@group(0) @binding(4) var<storage, read_write> info: array<u32>;           // n, then each layer's offset

const IN: u32 = {{ inputs }}u;
const HIDDEN: u32 = {{ hidden }}u;
const STORE: bool = {{ store }};
const WIDTH: u32 = 64u;
const TILE: u32 = 64u;
const COLS: u32 = 16u;
// Row stride of the activation tile: the wider of the input and the hidden layers.
const STRIDE: u32 = max(IN, WIDTH);

var<workgroup> act: array<f32, TILE * STRIDE>;

@compute @workgroup_size(256, 1, 1)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let n = info[0];
    let first = (wid.y * nwg.x + wid.x) * TILE;
    if first >= n {
        return; // uniform: the whole workgroup leaves together
    }

    // The tile's network input (rows past the batch read as zero).
    for (var i = t; i < TILE * IN; i += 256u) {
        let row = i / IN;
        let col = i - row * IN;
        var v = 0.0;
        if first + row < n {
            v = input[(first + row) * IN + col];
        }
        act[row * STRIDE + col] = v;
    }
    workgroupBarrier();

    let row = t / 4u;
    let col0 = (t % 4u) * COLS;
    for (var l = 0u; l < HIDDEN; l++) {
        let fan_in = select(WIDTH, IN, l == 0u);
        let offset = info[1u + l];
        var acc: array<f32, COLS>;
        for (var m = 0u; m < COLS; m++) {
            acc[m] = 0.0;
        }
        for (var k = 0u; k < fan_in; k++) {
            let a = act[row * STRIDE + k];
            let w = offset + k * WIDTH + col0;
            for (var m = 0u; m < COLS; m++) {
                acc[m] += a * weights[w + m];
            }
        }
        workgroupBarrier(); // every thread has read this layer's input
        for (var m = 0u; m < COLS; m++) {
            let y = max(acc[m], 0.0);
            act[row * STRIDE + col0 + m] = y;
            if STORE && first + row < n {
                hidden[(l * n + first + row) * WIDTH + col0 + m] = y;
            }
        }
        workgroupBarrier();
    }

    // Linear output layer: threads 0 .. 3·TILE each produce one output.
    if t < 3u * TILE {
        let r = t / 3u;
        let c = t - r * 3u;
        let offset = info[1u + HIDDEN];
        var y = 0.0;
        for (var k = 0u; k < WIDTH; k++) {
            y += act[r * STRIDE + k] * weights[offset + k * 3u + c];
        }
        if first + r < n {
            output[(first + r) * 3u + c] = y;
        }
    }
}
