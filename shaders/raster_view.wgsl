// One view's raster uniforms (src/render/gbuffer.rs, `RasterView`): 256 bytes, the
// stride at which they lie in one buffer (read at a dynamic offset by the G-buffer raster,
// as an array by the triangle culling).
struct RasterView {
    view_proj: mat4x4f,
    position: vec3f,
    _pad0: f32,
    forward: vec3f,
    _pad1: f32,
    // Pixels.
    size: vec2f,
    // `occlusion_cull`: where the view's depth pyramid starts in shaders/hiz.wgsl's
    // buffer.
    hiz_base: u32,
    // `micro_raster`: where the view's pixels start in the small triangles' buffer
    // (shaders/triangle_cull.wgsl, shaders/micro_resolve.wgsl).
    micro_base: u32,
    _pad3: array<vec4f, 9>,
}

// `occlusion_cull`'s depth pyramid (shaders/hiz.wgsl): level k = 0..=HIZ_LEVELS holds the
// farthest view depth of every 2^k × 2^k pixels (level 0: each pixel's), the levels one
// after another.
const HIZ_LEVELS: u32 = 4u;

// Tiles of level k of view `v` per row and column.
fn hiz_dims(v: RasterView, k: u32) -> vec2u {
    let t = 1u << k;
    return (vec2u(v.size) + t - 1u) / t;
}

// Where level k of view `v`'s pyramid starts.
fn hiz_offset(v: RasterView, k: u32) -> u32 {
    var o = v.hiz_base;
    for (var j = 0u; j < k; j++) {
        let d = hiz_dims(v, j);
        o += d.x * d.y;
    }
    return o;
}
