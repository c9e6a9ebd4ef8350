// Multiresolution hash-grid encoding: the parts shared by the forward and backward kernels
// (Müller et al. 2022, "Instant Neural Graphics Primitives"; tiny-cuda-nn conventions).
//
// Appended to hashgrid_forward.wgsl / hashgrid_backward.wgsl by the Rust glue
// (crates/nrc-cache/src/gpu/hashgrid.rs), which also fills the `info` buffer:
//
//   info[0]          number of samples n
//   info[1]          number of levels L
//   info[2 + 5l + 0] level l scale s_l = base · b^l − 1, as the bits of an f32 (the host computes
//                    it once, so both backends use the very same float)
//   info[2 + 5l + 1] level l resolution r_l = ceil(s_l) + 1
//   info[2 + 5l + 2] level l table entries: min(T, r_l³ rounded up to a multiple of 8)
//   info[2 + 5l + 3] level l offset of its first parameter (in floats) in the level-major table
//   info[2 + 5l + 4] 1 when level l is hashed (r_l³ > T), 0 when it is indexed densely

struct Level {
    scale: f32,
    resolution: u32,
    entries: u32,
    offset: u32,
    hashed: bool,
}

fn load_level(l: u32) -> Level {
    let b = 2u + 5u * l;
    return Level(bitcast<f32>(info[b]), info[b + 1u], info[b + 2u], info[b + 3u], info[b + 4u] != 0u);
}

// Table entry of integer grid vertex `c`: dense row-major index on coarse levels that fit, the
// spatial hash with primes (1, 2654435761, 805459861) on fine ones. u32 arithmetic wraps, which
// is the hash's definition.
fn grid_index(lv: Level, c: vec3<u32>) -> u32 {
    if lv.hashed {
        return (c.x ^ (c.y * 2654435761u) ^ (c.z * 805459861u)) & (lv.entries - 1u);
    }
    return (c.x + c.y * lv.resolution + c.z * lv.resolution * lv.resolution) % lv.entries;
}

// Cell and trilinear weight of a position: pos = x·s + 0.5, cell = floor(pos), w = pos − cell.
// Positions are clamped to the unit cube first (the cache normalises them to the scene box).
struct Cell {
    cell: vec3<u32>,
    w: vec3<f32>,
}

fn locate(lv: Level, sample: u32) -> Cell {
    let x = clamp(vec3<f32>(positions[3u * sample], positions[3u * sample + 1u], positions[3u * sample + 2u]), vec3<f32>(0.0), vec3<f32>(1.0));
    let pos = x * lv.scale + vec3<f32>(0.5);
    let cell = floor(pos);
    return Cell(vec3<u32>(cell), pos - cell);
}

// Weight of corner `corner` (bit 0: +x, bit 1: +y, bit 2: +z) of the trilinear stencil.
fn corner_weight(w: vec3<f32>, corner: u32) -> f32 {
    var weight = 1.0;
    if (corner & 1u) != 0u { weight *= w.x; } else { weight *= 1.0 - w.x; }
    if (corner & 2u) != 0u { weight *= w.y; } else { weight *= 1.0 - w.y; }
    if (corner & 4u) != 0u { weight *= w.z; } else { weight *= 1.0 - w.z; }
    return weight;
}

fn corner_vertex(cell: vec3<u32>, corner: u32) -> vec3<u32> {
    return cell + vec3<u32>(corner & 1u, (corner >> 1u) & 1u, (corner >> 2u) & 1u);
}

// A thread's work: one (level, sample), level-major so that neighbouring threads read the same
// level's table, with the level's constants and the sample's cell. `valid` is false for the
// threads past n · L in the last workgroup.
struct Task {
    valid: bool,
    levels: u32,
    level: u32,
    sample: u32,
    lv: Level,
    c: Cell,
}

// The dispatch grid is 2-D because one dimension holds at most 65535 workgroups.
fn task(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> Task {
    var t: Task;
    let n = info[0];
    t.levels = info[1];
    let thread = (wid.y * nwg.x + wid.x) * WORKGROUP + lid;
    t.valid = thread < n * t.levels;
    if !t.valid {
        return t;
    }
    t.level = thread / n;
    t.sample = thread - t.level * n;
    t.lv = load_level(t.level);
    t.c = locate(t.lv, t.sample);
    return t;
}
