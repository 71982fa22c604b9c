// Stage 2 (000 §3.1.2): per-viewer shadow frustums, all viewers in one dispatch.
// Froxels of `frustum_px` pixels over the first `frustum_slices` depth slices (which
// share their depth boundaries with the lighting volume); one light bitmask each.
// A light with a shared shadow map (shaders/shadow_lookup.wgsl: orthographic for the
// sun, perspective for spots, a cube for point lights) is looked up in it instead of
// traced: the map's texels (Sponza 1.8 cm at 4096²) resolve the near field as finely as
// the rays do, and it was rendered once for every viewer.

@group(1) @binding(0) var<storage, read_write> frustum: array<u32>;

// One invocation per frustum column (z runs over viewers), front to back.
@compute @workgroup_size(8, 8, 1)
fn main(
    @builtin(global_invocation_id) invocation: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    var rays = 0u;
    let gid = column_slot(invocation, wg, n);
    let view_index = gid.z;
    if view_index < frame.view_count {
        let v = volume_of(views[view_index]);
        // A coupled stereo eye lights its near field only, or nothing (v.light_slices).
        if gid.x < v.frustum_dims.x && gid.y < v.frustum_dims.y && v.light_slices > 0u {
            let pix = (vec2f(gid.xy) + 0.5) * f32(v.frustum_px);
            let dir = view_ray(v, min(pix, vec2f(v.size) - 0.5)); // past the edge: the last pixel centre
            for (var slice = 0u; slice < min(frame.frustum_slices, v.light_slices); slice++) {
                let p = froxel_point(v, dir, slice);
                var mask = 0u;
                for (var li = 0u; li < light_count(); li++) {
                    let l = lights[li];
                    if all(light_radiance(l, p) == vec3f(0.0)) {
                        continue;
                    }
                    var visible: bool;
                    if has_map(li) {
                        // One texel towards the light clears the map's depth steps.
                        visible = map_lit(li, l, p, to_light(l, p).xyz, 1.0);
                    } else {
                        rays += 1u;
                        visible = light_visible(l, p);
                    }
                    if visible {
                        mask |= 1u << li;
                    }
                }
                frustum[v.frustum_base + gid.x + v.frustum_dims.x * (gid.y + v.frustum_dims.y * slice)] = mask;
            }
        }
    }
    count(C_FRUSTUM_RAYS, rays);
}
