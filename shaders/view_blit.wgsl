// The viewer's viewport, copied into the UI's target (the window's surface, or a screenshot)
// before egui paints its panels around it (crates/nrc-view/src/canvas.rs). Each target pixel
// takes the viewport texel under it (nearest, no blending). Drawn by egui as a textured, blended
// quad instead, the viewport cost ~15 ms a UI frame on Mesa's software Vulkan at 1280 × 800;
// this pass ~1 ms.

struct Blit {
    // The viewport's top-left corner in target pixels.
    origin: vec2<f32>,
    // Target pixels per viewport texel.
    scale: f32,
    // 1: the target encodes sRGB itself, so the (already encoded) texel is decoded first.
    decode: u32,
};

@group(0) @binding(0) var<uniform> blit: Blit;
// The viewport (Rgba8Unorm, sRGB-encoded values) the display pass drew.
@group(0) @binding(1) var shown: texture_2d<f32>;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    return vec4<f32>(x * 2.0 - 1.0, y * 2.0 - 1.0, 0.0, 1.0);
}

fn srgb_decode(c: vec3<f32>) -> vec3<f32> {
    let lower = c / 12.92;
    let higher = pow((c + 0.055) / 1.055, vec3<f32>(2.4));
    return select(higher, lower, c <= vec3<f32>(0.04045));
}

@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let dims = vec2<i32>(textureDimensions(shown));
    let t = clamp(vec2<i32>(floor((pos.xy - blit.origin) / blit.scale)), vec2<i32>(0), dims - 1);
    let c = textureLoad(shown, t, 0).rgb;
    if blit.decode == 1u {
        return vec4<f32>(srgb_decode(c), 1.0);
    }
    return vec4<f32>(c, 1.0);
}
