// G-buffer raster, one pass per viewer: view depth, flat normal and albedo, packed into
// one texel a pixel (shaders/gbuffer_surface.wgsl).

// RasterView: shaders/raster_view.wgsl.
@group(0) @binding(0) var<uniform> view: RasterView;

struct VsOut {
    @builtin(position) clip: vec4f,
    @location(0) world: vec3f,
    @location(1) albedo: vec3f,
}

@vertex
fn vs_main(@location(0) position: vec3f, @location(1) albedo: u32) -> VsOut {
    var o: VsOut;
    o.clip = view.view_proj * vec4f(position, 1.0);
    o.world = position;
    o.albedo = unpack4x8unorm(albedo).rgb;
    return o;
}

@fragment
fn fs_main(i: VsOut) -> @location(0) vec4u {
    let n = normalize(cross(dpdx(i.world), dpdy(i.world)));
    let depth = max(dot(i.world - view.position, view.forward), 1e-6);
    return pack_surface(depth, select(n, vec3f(0.0, 1.0, 0.0), any(n != n)), i.albedo);
}
