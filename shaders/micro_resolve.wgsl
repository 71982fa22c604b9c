// `micro_raster`'s resolve, after a set's G-buffer raster: where the culling pass
// (shaders/triangle_cull.wgsl) rasterised a small triangle at a pixel nearer than the
// raster's depth there, that triangle's surface is written into the packed G-buffer
// texel (shaders/gbuffer_surface.wgsl) as the raster would have: the view depth and
// albedo interpolated perspective-correctly at the pixel centre, the flat normal. The
// pixel's word is cleared for the next frame. z runs over the set's views.

// RasterView: shaders/raster_view.wgsl; the set's views, from its first.
@group(0) @binding(0) var<storage, read> views: array<RasterView>;
// Raster vertices: position bits and packed albedo (src/render/scene_gpu.rs).
@group(0) @binding(1) var<storage, read> vertices: array<vec4u>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;
// The 64-bit words of shaders/micro_atomic.wgsl as (low, high) halves: x the inverted
// triangle, y the inverted depth; (0, 0) none.
@group(0) @binding(3) var<storage, read_write> micro: array<vec2u>;
@group(0) @binding(4) var depth: texture_depth_2d_array;
@group(0) @binding(5) var gbuf: texture_storage_2d_array<rgba32uint, write>;

fn cross2(u: vec2f, v: vec2f) -> f32 {
    return u.x * v.y - u.y * v.x;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    // The view's fields one by one: most pixels need only two of them.
    let size = vec2u(views[gid.z].size);
    if any(gid.xy >= size) {
        return;
    }
    let i = views[gid.z].micro_base + gid.x + size.x * gid.y;
    let word = micro[i];
    if word.y == 0u {
        return;
    }
    micro[i] = vec2u(0u);
    // Nearer than the raster's own triangles here (clip depth; cleared to 1).
    if bitcast<f32>(~word.y) >= textureLoad(depth, gid.xy, gid.z, 0) {
        return;
    }
    let t = 3u * ~word.x;
    let va = vertices[indices[t]];
    let vb = vertices[indices[t + 1u]];
    let vc = vertices[indices[t + 2u]];
    let pa = bitcast<vec3f>(va.xyz);
    let pb = bitcast<vec3f>(vb.xyz);
    let pc = bitcast<vec3f>(vc.xyz);
    let view_proj = views[gid.z].view_proj;
    let ca = view_proj * vec4f(pa, 1.0);
    let cb = view_proj * vec4f(pb, 1.0);
    let cc = view_proj * vec4f(pc, 1.0);
    let sa = (vec2f(ca.x, -ca.y) / ca.w * 0.5 + 0.5) * vec2f(size);
    let sb = (vec2f(cb.x, -cb.y) / cb.w * 0.5 + 0.5) * vec2f(size);
    let sc = (vec2f(cc.x, -cc.y) / cc.w * 0.5 + 0.5) * vec2f(size);
    let q = vec2f(gid.xy) + 0.5;
    // Screen-space barycentrics, then perspective-correct ones (clip w is the view depth).
    let l = vec3f(cross2(sc - sb, q - sb), cross2(sa - sc, q - sc), cross2(sb - sa, q - sa)) / cross2(sb - sa, sc - sa);
    let h = l / vec3f(ca.w, cb.w, cc.w);
    let sum = h.x + h.y + h.z;
    if !(sum > 0.0) {
        return;
    }
    let mu = h / sum;
    let n = normalize(cross(pb - pa, pc - pa));
    let albedo = mu.x * unpack4x8unorm(va.w).rgb + mu.y * unpack4x8unorm(vb.w).rgb + mu.z * unpack4x8unorm(vc.w).rgb;
    let texel = pack_surface(max(1.0 / sum, 1e-6), select(n, vec3f(0.0, 1.0, 0.0), any(n != n)), clamp(albedo, vec3f(0.0), vec3f(1.0)));
    textureStore(gbuf, gid.xy, gid.z, texel);
}
