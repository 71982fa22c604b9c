// The packed G-buffer (rgba32uint, one texel a pixel): the G-buffer raster writes it,
// the composite, hidden-froxel culling and the smoke raster read it.
//   x: view depth along the view's forward axis (f32 bits; 0: no surface, the sky),
//   y: the surface normal, octahedral, 2 × snorm16,
//   z: albedo, rgba8 unorm,
//   w: spare (0).
// The world point is the pixel centre's view ray at that depth (view_ray in
// common.wgsl): 16 bytes a pixel instead of a position, a normal and an albedo target.

fn sign_not_zero(v: vec2f) -> vec2f {
    return select(vec2f(-1.0), vec2f(1.0), v >= vec2f(0.0));
}

// Octahedral map of unit directions onto [−1, 1]² and back (the lower hemisphere folded
// over the diagonals); also the media transmittance volumes' column directions
// (common.wgsl).
fn oct_encode(d: vec3f) -> vec2f {
    let n = d / (abs(d.x) + abs(d.y) + abs(d.z));
    if n.z < 0.0 {
        return (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    }
    return n.xy;
}

fn oct_decode(e: vec2f) -> vec3f {
    var n = vec3f(e, 1.0 - abs(e.x) - abs(e.y));
    if n.z < 0.0 {
        n = vec3f((1.0 - abs(n.yx)) * sign_not_zero(n.xy), n.z);
    }
    return normalize(n);
}

fn pack_surface(depth: f32, normal: vec3f, albedo: vec3f) -> vec4u {
    return vec4u(bitcast<u32>(depth), pack2x16snorm(oct_encode(normal)), pack4x8unorm(vec4f(albedo, 1.0)), 0u);
}

// The view depth of a packed surface (0: none).
fn surface_depth(g: vec4u) -> f32 {
    return bitcast<f32>(g.x);
}

fn surface_normal(g: vec4u) -> vec3f {
    return oct_decode(unpack2x16snorm(g.y));
}

fn surface_albedo(g: vec4u) -> vec3f {
    return unpack4x8unorm(g.z).rgb;
}
