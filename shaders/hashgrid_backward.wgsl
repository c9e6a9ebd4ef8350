// Hash-grid encoding, backward: the gradient of the loss w.r.t. the table is the scatter-add
//   grad_params[l][index(corner)][f] += weight · grad_encoded[n][l·F + f]
// over samples and corners. Many samples hit the same entry (hash collisions, shared cells), so
// the adds are atomic. WGSL core has no float atomics: each add is emulated by a
// compare-and-swap loop on the entry's bits held as atomic<u32>. The order of the adds differs
// from a sequential CPU sum, so results agree to rounding, not bit for bit.
// The gradient w.r.t. positions is not computed: positions are inputs, never trained.
// Shared helpers (levels, hashing, trilinear weights) come from hashgrid_common.wgsl.

// Every binding is read_write, inputs too: CubeCL packs tensors into shared wgpu buffers and
// wgpu refuses one buffer bound both read-only and read-write in a dispatch.
@group(0) @binding(0) var<storage, read_write> positions: array<f32>;        // [n, 3]
@group(0) @binding(1) var<storage, read_write> grad_encoded: array<f32>;     // [n, L·F]
@group(0) @binding(2) var<storage, read_write> grad_params: array<atomic<u32>>; // f32 bits, zeroed by the host
@group(0) @binding(3) var<storage, read_write> info: array<u32>;

const FEATURES: u32 = {{ features }}u;
const WORKGROUP: u32 = {{ workgroup_size }}u;

// grad_params[i] += value, atomically (compare-and-swap on the float's bits).
fn atomic_add_f32(i: u32, value: f32) {
    var old = atomicLoad(&grad_params[i]);
    loop {
        let sum = bitcast<u32>(bitcast<f32>(old) + value);
        let result = atomicCompareExchangeWeak(&grad_params[i], old, sum);
        if result.exchanged {
            break;
        }
        old = result.old_value;
    }
}

@compute @workgroup_size({{ workgroup_size }}, 1, 1)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let t = task(wid, nwg, lid);
    if !t.valid {
        return;
    }

    var g: array<f32, FEATURES>;
    var any_nonzero = false;
    let src = t.sample * t.levels * FEATURES + t.level * FEATURES;
    for (var f = 0u; f < FEATURES; f++) {
        g[f] = grad_encoded[src + f];
        any_nonzero = any_nonzero || g[f] != 0.0;
    }
    // A zero upstream gradient (e.g. a ReLU that is off everywhere) adds nothing: skip the atomics.
    if !any_nonzero {
        return;
    }
    for (var corner = 0u; corner < 8u; corner++) {
        let weight = corner_weight(t.c.w, corner);
        let base = t.lv.offset + grid_index(t.lv, corner_vertex(t.c.cell, corner)) * FEATURES;
        for (var f = 0u; f < FEATURES; f++) {
            atomic_add_f32(base + f, weight * g[f]);
        }
    }
}
