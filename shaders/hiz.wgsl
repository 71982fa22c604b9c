// `occlusion_cull`: after the first phase of the G-buffer raster, each view's depth
// pyramid — at level k = 0..=HIZ_LEVELS the farthest view depth of every 2^k × 2^k
// pixels (level 0 each pixel's), a pixel without a surface counting as 3e38 — which shaders/triangle_cull.wgsl's
// `occlude` tests the kept triangles against. One invocation per 16 × 16 pixels (a tile
// of the top level) reads them once and writes every level's tiles in it; z runs over
// the set's views.

// RasterView: shaders/raster_view.wgsl; the set's views, from its first.
@group(0) @binding(0) var<storage, read> views: array<RasterView>;
// The packed G-buffer (shaders/gbuffer_surface.wgsl).
@group(0) @binding(1) var gbuf: texture_2d_array<u32>;
@group(0) @binding(2) var<storage, read_write> hiz: array<f32>;

const NO_SURFACE: f32 = 3.0e38;

// Writes tile (x, y) of level k if the view has it.
fn put(v: RasterView, k: u32, xy: vec2u, depth: f32) {
    let d = hiz_dims(v, k);
    if all(xy < d) {
        hiz[hiz_offset(v, k) + xy.x + d.x * xy.y] = depth;
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    let v = views[gid.z];
    let size = vec2u(v.size);
    if any(gid.xy >= hiz_dims(v, HIZ_LEVELS)) {
        return;
    }
    // Levels 0 and 1 (8 × 8 tiles of 2 × 2 pixels), then each level from the one below.
    var level: array<f32, 64>;
    for (var t = 0u; t < 64u; t++) {
        let tile = vec2u(t % 8u, t / 8u);
        var farthest = 0.0;
        for (var q = 0u; q < 4u; q++) {
            let px = (gid.xy * 8u + tile) * 2u + vec2u(q % 2u, q / 2u);
            if all(px < size) {
                let d = surface_depth(textureLoad(gbuf, px, gid.z, 0));
                let here = select(NO_SURFACE, d, d > 0.0);
                put(v, 0u, px, here);
                farthest = max(farthest, here);
            }
        }
        level[t] = farthest;
        put(v, 1u, gid.xy * 8u + tile, farthest);
    }
    var side = 8u;
    for (var k = 2u; k <= HIZ_LEVELS; k++) {
        side /= 2u;
        for (var t = 0u; t < side * side; t++) {
            let tile = vec2u(t % side, t / side);
            let below = tile * 2u;
            let farthest = max(
                max(level[below.x + 2u * side * below.y], level[below.x + 1u + 2u * side * below.y]),
                max(level[below.x + 2u * side * (below.y + 1u)], level[below.x + 1u + 2u * side * (below.y + 1u)]),
            );
            // In place: tile t lies at or before the tiles it was made of.
            level[t] = farthest;
            put(v, k, gid.xy * side + tile, farthest);
        }
    }
}
