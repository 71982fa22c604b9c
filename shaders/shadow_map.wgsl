// Surface shadow maps (beyond paper 000; DESIGN.md §1's optional light-space stage):
// depth-only raster of the scene from each directional light, shared by every viewer.

struct LightView {
    view_proj: mat4x4f,
}

@group(0) @binding(0) var<uniform> light: LightView;

@vertex
fn vs_main(@location(0) position: vec3f) -> @builtin(position) vec4f {
    return light.view_proj * vec4f(position, 1.0);
}
