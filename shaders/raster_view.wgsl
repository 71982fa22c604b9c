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
    _pad2: vec2f,
    _pad3: array<vec4f, 9>,
}
