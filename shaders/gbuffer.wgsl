// G-buffer raster, one pass per viewer: world position + view depth, flat normal, albedo.

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

struct FsOut {
    @location(0) position: vec4f,
    @location(1) normal: vec4f,
    @location(2) albedo: vec4f,
}

@fragment
fn fs_main(i: VsOut) -> FsOut {
    var o: FsOut;
    let n = normalize(cross(dpdx(i.world), dpdy(i.world)));
    o.position = vec4f(i.world, max(dot(i.world - view.position, view.forward), 1e-6));
    o.normal = vec4f(select(n, vec3f(0.0, 1.0, 0.0), any(n != n)), 0.0);
    o.albedo = vec4f(i.albedo, 1.0);
    return o;
}
