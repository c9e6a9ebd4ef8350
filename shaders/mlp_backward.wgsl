// Fully fused MLP backward, activation part (after tiny-cuda-nn's FullyFusedMLP): a workgroup
// takes a tile of TILE samples from the output gradient back to the input gradient while the
// activation gradients stay in workgroup memory. It reads the hidden activations the forward
// kernel stored (for the ReLU masks) and writes each hidden layer's pre-activation gradient
// dY_l, from which the host forms the weight gradients A_{l−1}ᵀ·dY_l as batched matrix
// products; with INPUT_GRAD it also writes the gradient of the network input.
//
// Thread t of the 256 owns sample row t / 4 of the tile and the columns ≡ t (mod 4) of the
// layer it produces.

// Every binding is read_write, inputs too: CubeCL packs tensors into shared wgpu buffers and
// wgpu refuses one buffer bound both read-only and read-write in a dispatch.
@group(0) @binding(0) var<storage, read_write> weights: array<f32>;
@group(0) @binding(1) var<storage, read_write> grad_output: array<f32>;    // [n, 3]
@group(0) @binding(2) var<storage, read_write> hidden: array<f32>;         // [HIDDEN, n, 64]
@group(0) @binding(3) var<storage, read_write> grad_hidden: array<f32>; // [HIDDEN, n, 64]
@group(0) @binding(4) var<storage, read_write> grad_input: array<f32>;  // [n, IN] when INPUT_GRAD
@group(0) @binding(5) var<storage, read_write> info: array<u32>;           // n, then each layer's offset

const IN: u32 = {{ inputs }}u;
const HIDDEN: u32 = {{ hidden }}u;
const INPUT_GRAD: bool = {{ input_grad }};
const WIDTH: u32 = 64u;
const TILE: u32 = 64u;

// 16 KiB: WebGPU's minimum maxComputeWorkgroupStorageSize.
var<workgroup> grad: array<f32, TILE * WIDTH>;

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
    let row = t / 4u;
    let q = t % 4u;
    let valid = first + row < n;
    var grad_out = vec3<f32>(0.0);
    if valid {
        let o = (first + row) * 3u;
        grad_out = vec3<f32>(grad_output[o], grad_output[o + 1u], grad_output[o + 2u]);
    }

    // Last hidden layer: dY = (dOut · W_outᵀ) ⊙ [A > 0].
    let out_offset = info[1u + HIDDEN];
    for (var j = q; j < WIDTH; j += 4u) {
        var d = 0.0;
        for (var c = 0u; c < 3u; c++) {
            d += grad_out[c] * weights[out_offset + j * 3u + c];
        }
        var dy = 0.0;
        if valid {
            let at = ((HIDDEN - 1u) * n + first + row) * WIDTH + j;
            dy = select(0.0, d, hidden[at] > 0.0);
            grad_hidden[at] = dy;
        }
        grad[row * WIDTH + j] = dy;
    }
    workgroupBarrier();

    // Hidden layers l = HIDDEN−1 … 1: dY_{l−1} = (dY_l · W_lᵀ) ⊙ [A_{l−1} > 0].
    for (var l = HIDDEN - 1u; l >= 1u; l--) {
        let offset = info[1u + l];
        var d: array<f32, 16>;
        for (var m = 0u; m < 16u; m++) {
            let k = q + 4u * m;
            var s = 0.0;
            for (var j = 0u; j < WIDTH; j++) {
                s += grad[row * WIDTH + j] * weights[offset + k * WIDTH + j];
            }
            d[m] = s;
        }
        workgroupBarrier(); // every thread has read dY_l
        for (var m = 0u; m < 16u; m++) {
            let k = q + 4u * m;
            var dy = 0.0;
            if valid {
                let at = ((l - 1u) * n + first + row) * WIDTH + k;
                dy = select(0.0, d[m], hidden[at] > 0.0);
                grad_hidden[at] = dy;
            }
            grad[row * WIDTH + k] = dy;
        }
        workgroupBarrier();
    }

    // Network input: dX = dY_0 · W_0ᵀ.
    if INPUT_GRAD && valid {
        let offset = info[1u];
        for (var i = q; i < IN; i += 4u) {
            var s = 0.0;
            for (var j = 0u; j < WIDTH; j++) {
                s += grad[row * WIDTH + j] * weights[offset + i * WIDTH + j];
            }
            grad_input[(first + row) * IN + i] = s;
        }
    }
}
