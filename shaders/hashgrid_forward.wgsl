// Hash-grid encoding, forward: encoded[n][l·F + f] = Σ_corners weight · table[l][index(corner)][f].
// Shared helpers (levels, hashing, trilinear weights) come from hashgrid_common.wgsl.

// Every binding is read_write, inputs too: CubeCL packs tensors into shared wgpu buffers and
// wgpu refuses one buffer bound both read-only and read-write in a dispatch.
@group(0) @binding(0) var<storage, read_write> positions: array<f32>;  // [n, 3], in [0, 1]³
@group(0) @binding(1) var<storage, read_write> params: array<f32>;     // [level][entry][feature]
@group(0) @binding(2) var<storage, read_write> encoded: array<f32>; // [n, L·F]
@group(0) @binding(3) var<storage, read_write> info: array<u32>;

const FEATURES: u32 = {{ features }}u;
const WORKGROUP: u32 = {{ workgroup_size }}u;

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

    var acc: array<f32, FEATURES>;
    for (var f = 0u; f < FEATURES; f++) {
        acc[f] = 0.0;
    }
    for (var corner = 0u; corner < 8u; corner++) {
        let weight = corner_weight(t.c.w, corner);
        let base = t.lv.offset + grid_index(t.lv, corner_vertex(t.c.cell, corner)) * FEATURES;
        for (var f = 0u; f < FEATURES; f++) {
            acc[f] += weight * params[base + f];
        }
    }
    let out = t.sample * t.levels * FEATURES + t.level * FEATURES;
    for (var f = 0u; f < FEATURES; f++) {
        encoded[out + f] = acc[f];
    }
}
