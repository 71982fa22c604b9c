// Stage 3 (000 §3.1.3): in-scattered light and extinction per froxel, all viewers in
// one dispatch. `reference` traces a shadow ray per light per froxel (Hillaire 2015 with
// ray-traced shadows); `shared` reads the shadow frustum for the near slices and the
// shared grid (nearest voxel, or trilinear over 8 voxels) beyond.

@group(1) @binding(0) var<storage, read> grid: array<u32>;
@group(1) @binding(1) var<storage, read> frustum: array<u32>;
@group(1) @binding(2) var<storage, read_write> froxels: array<vec2u>;
@group(1) @binding(3) var<storage, read> history: array<vec2u>;

var<workgroup> wg_rays: atomic<u32>;
var<workgroup> wg_froxels: atomic<u32>;

fn grid_mask(c: vec3i) -> u32 {
    let d = vec3i(frame.grid_dims);
    let q = clamp(c, vec3i(0), d - 1);
    let x = u32(q.x);
    let word = grid[x / 4u + frame.grid_words_x * (u32(q.y) + frame.grid_dims.y * u32(q.z))];
    return (word >> (8u * (x % 4u))) & 0xffu;
}

// Visibility of each light at p from the shared grid.
fn grid_visibility(p: vec3f) -> array<f32, 8> {
    var vis: array<f32, 8>;
    let g = (p - frame.grid_min) / frame.voxel_size - 0.5;
    if (frame.flags & FLAG_TRILINEAR) == 0u {
        let m = grid_mask(vec3i(floor(g + 0.5)));
        for (var li = 0u; li < 8u; li++) {
            vis[li] = f32((m >> li) & 1u);
        }
        return vis;
    }
    let base = vec3i(floor(g));
    let f = g - floor(g);
    for (var k = 0u; k < 8u; k++) {
        let o = vec3i(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
        let w3 = select(1.0 - f, f, vec3<bool>(o == vec3i(1)));
        let w = w3.x * w3.y * w3.z;
        let m = grid_mask(base + o);
        for (var li = 0u; li < 8u; li++) {
            vis[li] += w * f32((m >> li) & 1u);
        }
    }
    return vis;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_index) lid: u32) {
    if lid == 0u {
        atomicStore(&wg_rays, 0u);
        atomicStore(&wg_froxels, 0u);
    }
    workgroupBarrier();
    let view_index = gid.z / frame.slices;
    let slice = gid.z % frame.slices;
    if view_index < frame.view_count {
        let v = views[view_index];
        if gid.x < v.froxel_dims.x && gid.y < v.froxel_dims.y {
            let index = v.froxel_base + gid.x + v.froxel_dims.x * (gid.y + v.froxel_dims.y * slice);
            let pix = (vec2f(gid.xy) + 0.5) * f32(v.froxel_px);
            // A froxel centre past the image edge takes the last pixel centre (a 1×1
            // viewer's only pixel), not the image corner.
            let dir = view_ray(v, min(pix, vec2f(v.size) - 0.5));
            let z = slice_depth(v, f32(slice) + 0.5 + v.jitter);
            let p = v.position + dir * (z / dot(dir, v.forward));
            let m = sample_media(p);
            var out = vec4f(0.0);
            if m.extinction > 0.0 || any(m.emission > vec3f(0.0)) {
                var vis: array<f32, 8>;
                var rays = 0u;
                if (frame.flags & FLAG_SHARED) == 0u {
                    for (var li = 0u; li < frame.light_count; li++) {
                        let l = lights[li];
                        if all(light_radiance(l, p) == vec3f(0.0)) {
                            continue;
                        }
                        rays += 1u;
                        vis[li] = select(0.0, 1.0, light_visible(l, p));
                    }
                } else if slice < frame.frustum_slices {
                    let fx = min(gid.x * v.froxel_px / v.frustum_px, v.frustum_dims.x - 1u);
                    let fy = min(gid.y * v.froxel_px / v.frustum_px, v.frustum_dims.y - 1u);
                    let mask = frustum[v.frustum_base + fx + v.frustum_dims.x * (fy + v.frustum_dims.y * slice)];
                    for (var li = 0u; li < 8u; li++) {
                        vis[li] = f32((mask >> li) & 1u);
                    }
                } else {
                    vis = grid_visibility(p);
                }
                // Stored as the source radiance S/σt (what an optically thick froxel converges
                // to), which stays within f16 range for σt up to 10⁴ m⁻¹.
                let s_rgb = in_scattering(m, p, dir, vis);
                out = vec4f(min(s_rgb / max(m.extinction, SIGMA_EPS), vec3f(6.0e4)), m.extinction);
                atomicAdd(&wg_rays, rays);
                atomicAdd(&wg_froxels, 1u);
            }
            if (frame.flags & FLAG_HISTORY) != 0u {
                // Temporal reprojection: blend with last frame's froxel at the same
                // world point; a non-finite history is discarded, never propagated.
                let prev = v.prev_view_proj * vec4f(p, 1.0);
                if prev.w > 0.0 {
                    let ndc = prev.xyz / prev.w;
                    let px = vec2f(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5) * vec2f(v.size) / f32(v.froxel_px);
                    let zprev = prev.w;
                    let s = depth_to_slice(v, zprev);
                    if all(px >= vec2f(0.0)) && all(px < vec2f(v.froxel_dims)) && s >= 0.0 && s < f32(frame.slices) {
                        let hi = v.froxel_base + u32(px.x) + v.froxel_dims.x * (u32(px.y) + v.froxel_dims.y * u32(s));
                        let h = unpack_rgba16(history[hi]);
                        let finite = all(abs(h) < vec4f(6.0e4));
                        if finite {
                            out = mix(out, h, 0.9);
                        }
                    }
                }
            }
            froxels[index] = pack_rgba16(out);
        }
    }
    workgroupBarrier();
    if lid == 0u {
        atomicAdd(&counters[C_LIGHTING_RAYS], atomicLoad(&wg_rays));
        atomicAdd(&counters[C_FROXELS_WITH_MEDIA], atomicLoad(&wg_froxels));
    }
}
