// Stage 2 (000 §3.1.2): per-viewer shadow frustums, all viewers in one dispatch.
// Froxels of `frustum_px` pixels over the first `frustum_slices` depth slices (which
// share their depth boundaries with the lighting volume); one light bitmask each.

@group(1) @binding(0) var<storage, read_write> frustum: array<u32>;

var<workgroup> wg_rays: atomic<u32>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_index) lid: u32) {
    if lid == 0u {
        atomicStore(&wg_rays, 0u);
    }
    workgroupBarrier();
    let view_index = gid.z / frame.frustum_slices;
    let slice = gid.z % frame.frustum_slices;
    if view_index < frame.view_count {
        let v = views[view_index];
        if gid.x < v.frustum_dims.x && gid.y < v.frustum_dims.y {
            let pix = (vec2f(gid.xy) + 0.5) * f32(v.frustum_px);
            // A froxel centre past the image edge takes the last pixel centre (a 1×1
            // viewer's only pixel), not the image corner.
            let dir = view_ray(v, min(pix, vec2f(v.size) - 0.5));
            let z = slice_depth(v, f32(slice) + 0.5 + v.jitter);
            let p = v.position + dir * (z / dot(dir, v.forward));
            var mask = 0u;
            var rays = 0u;
            for (var li = 0u; li < frame.light_count; li++) {
                let l = lights[li];
                if all(light_radiance(l, p) == vec3f(0.0)) {
                    continue;
                }
                rays += 1u;
                if light_visible(l, p) {
                    mask |= 1u << li;
                }
            }
            frustum[v.frustum_base + gid.x + v.frustum_dims.x * (gid.y + v.frustum_dims.y * slice)] = mask;
            atomicAdd(&wg_rays, rays);
        }
    }
    workgroupBarrier();
    if lid == 0u {
        atomicAdd(&counters[C_FRUSTUM_RAYS], atomicLoad(&wg_rays));
    }
}
