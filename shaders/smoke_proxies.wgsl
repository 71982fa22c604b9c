// Smoke proxies, one dispatch per viewer set (x: particles, z: the set's viewers): each
// invocation finds its particle's rank back to front for its viewer — the number of
// particles farther from the eye, ties broken by particle slot (a rank sort over tiles of
// 64 keys in workgroup memory: one pass, deterministic, no padding) — and writes the
// particle's proxy record at that rank in the viewer's list, with the visibility of every
// light at the centre (shared shadow maps where the light has one, else a shadow ray); the
// raster uses it for lights without a map and tests the maps per node itself.

@group(1) @binding(0) var<storage, read_write> proxies: array<SmokeProxy>;
// Bindings 10–14: the shadow maps (shaders/shadow_lookup.wgsl).

const SORT_TILE: u32 = 64u;
var<workgroup> tile_keys: array<u32, 64>;

// Distance from the eye to particle i's centre as ordered bits (non-negative floats sort
// as their bit patterns); inf or NaN sort as the farthest.
fn sort_key(v: View, i: u32) -> u32 {
    let d = length(particles[i].centre - v.position);
    if !(d <= 3.0e38) {
        return 0x7f800000u;
    }
    return bitcast<u32>(d);
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    let n = frame.particle_count;
    let view_index = gid.z;
    let v = views[min(view_index, frame.view_count - 1u)];
    let i = gid.x;
    let mine = sort_key(v, min(i, max(n, 1u) - 1u));
    var rank = 0u;
    for (var base = 0u; base < n; base += SORT_TILE) {
        let j = base + lid.x;
        tile_keys[lid.x] = sort_key(v, min(j, n - 1u));
        workgroupBarrier();
        let m = min(SORT_TILE, n - base);
        for (var k = 0u; k < m; k++) {
            let kj = tile_keys[k];
            let before = kj > mine || (kj == mine && base + k < i);
            rank += select(0u, 1u, before);
        }
        workgroupBarrier();
    }
    if i >= n || view_index >= frame.view_count {
        return;
    }
    let p = particles[i];
    var vis = vec2u(0u);
    for (var li = 0u; li < light_count(); li++) {
        let l = lights[li];
        var lit = 1.0;
        if has_map(li) {
            lit = map_visibility(li, l, p.centre, to_light(l, p.centre).xyz, 1.0);
        } else {
            lit = select(0.0, 1.0, light_visible(l, p.centre));
        }
        let bits = u32(round(clamp(lit, 0.0, 1.0) * 255.0)) << (8u * (li & 3u));
        if li < 4u {
            vis.x |= bits;
        } else {
            vis.y |= bits;
        }
    }
    let stride = arrayLength(&proxies) / frame.view_count;
    var q: SmokeProxy;
    q.centre = p.centre;
    q.radius = select(0.0, PROXY_INRADIUS * p.falloff_u, p.falloff_u > 0.0 && p.falloff_u <= 3.0e37);
    q.scattering = p.scattering;
    q.absorption = p.absorption;
    q.vis = vis;
    q.falloff_u = p.falloff_u;
    q.g = p.g;
    q.key = bitcast<f32>(mine);
    q.index = i;
    proxies[view_index * stride + rank] = q;
}
