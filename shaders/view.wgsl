// The live viewer's display pass (crates/nrc-view/src/display.rs): one full-screen triangle
// drawn into the viewport texture (Rgba8Unorm, one texel per image pixel), which egui then
// shows. Every debug view of `nrc view` is one mode of this shader:
//
//   0  tone mapping: radiance scaled by 2^exposure, then ACES filmic (Narkowicz 2015, as
//      `nrc render --png` and `nrc compare`'s previews), a clamp, or Reinhard; sRGB encoded;
//   1  relative error against a reference: the per-pixel relMSE of `nrc compare`'s error images
//      (channel mean of (x − r)² / (r² + 0.01)) on a log scale from 1e-4 to 10, through viridis;
//   2  heat map: a count per pixel (this frame's training records) on a log scale, through magma;
//   3  a scalar per pixel (a pass's statistic, e.g. a reservoir's M) on a linear scale, viridis.
//
// The colour maps are nrc-eval's (d3's viridis and magma, via `colorous`), sampled at 1,024
// points into `lut` (sRGB-encoded values in [0, 1]): the views show the colours `nrc compare`
// writes. Images arrive with non-finite values already zeroed (the CPU does that on upload).

struct Params {
    mode: u32,
    tonemap: u32,
    // 2^exposure (mode 0).
    scale: f32,
    // The scale's range: mode 1 log10 of its ends, mode 2 the largest count, mode 3 min and max.
    lo: f32,
    hi: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
};

@group(0) @binding(0) var<uniform> params: Params;
// Linear radiance (or the scalar in .r), Rgba32Float.
@group(0) @binding(1) var image: texture_2d<f32>;
// The reference (mode 1), or the counts (mode 2, in .r).
@group(0) @binding(2) var aux: texture_2d<f32>;
// viridis at [0, LUT), magma at [LUT, 2 LUT).
@group(0) @binding(3) var<storage, read> lut: array<vec4<f32>>;

const LUT: u32 = 1024u;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // A triangle covering the viewport: (-1,-1), (3,-1), (-1,3).
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    return vec4<f32>(x * 2.0 - 1.0, y * 2.0 - 1.0, 0.0, 1.0);
}

fn aces(x: vec3<f32>) -> vec3<f32> {
    let a = 2.51;
    let b = 0.03;
    let c = 2.43;
    let d = 0.59;
    let e = 0.14;
    return clamp((x * (a * x + b)) / (x * (c * x + d) + e), vec3<f32>(0.0), vec3<f32>(1.0));
}

fn srgb_encode(c: vec3<f32>) -> vec3<f32> {
    let lower = 12.92 * c;
    let higher = 1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(higher, lower, c <= vec3<f32>(0.0031308));
}

// `t` in [0, 1] through the map starting at `base`.
fn colour(t: f32, base: u32) -> vec3<f32> {
    let i = u32(clamp(t, 0.0, 1.0) * f32(LUT - 1u) + 0.5);
    return lut[base + i].rgb;
}

@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let p = vec2<i32>(pos.xy);
    let x = textureLoad(image, p, 0).rgb;
    switch params.mode {
        case 1u: {
            let r = textureLoad(aux, p, 0).rgb;
            let d = x - r;
            let e = dot(d * d / (r * r + vec3<f32>(0.01)), vec3<f32>(1.0 / 3.0));
            var t = 0.0;
            if e > 0.0 {
                t = (log(e) / log(10.0) - params.lo) / (params.hi - params.lo);
            }
            return vec4<f32>(colour(t, 0u), 1.0);
        }
        case 2u: {
            let n = textureLoad(aux, p, 0).r;
            let t = log(1.0 + max(n, 0.0)) / log(1.0 + max(params.hi, 1.0));
            return vec4<f32>(colour(t, LUT), 1.0);
        }
        case 3u: {
            let t = (x.r - params.lo) / max(params.hi - params.lo, 1e-30);
            return vec4<f32>(colour(t, 0u), 1.0);
        }
        default: {
            let v = max(x * params.scale, vec3<f32>(0.0));
            var mapped: vec3<f32>;
            switch params.tonemap {
                case 1u: {
                    mapped = clamp(v, vec3<f32>(0.0), vec3<f32>(1.0));
                }
                case 2u: {
                    mapped = v / (vec3<f32>(1.0) + v);
                }
                default: {
                    mapped = aces(v);
                }
            }
            return vec4<f32>(srgb_encode(mapped), 1.0);
        }
    }
}
