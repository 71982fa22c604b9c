// Hidden-froxel culling for the demand-driven grid (beyond paper 000): a froxel behind
// every surface its column's pixels show can never reach the image, so it is not lit and
// requests no voxels. Two passes, all viewers in one dispatch each (z = viewer):
//   `tile_max`: the farthest G-buffer depth of each 8 × 8 pixel tile (sky: the far plane);
//   `column_limit`: the last slice each froxel column must light.
// Composite reads column X bilinearly from pixels [8X − 4, 8X + 12), all inside tiles
// X − 1 ..= X + 1, and reads integrated slices up to floor(depth_to_slice(depth)); the
// limit is that over the 3 × 3 tiles around the column, plus one slice of slack.

@group(1) @binding(0) var<storage, read_write> tile_depth: array<f32>;
@group(1) @binding(1) var<storage, read_write> column_limit: array<u32>;
@group(1) @binding(2) var gbuf: texture_2d_array<u32>;

@compute @workgroup_size(8, 8, 1)
fn tile_max(@builtin(global_invocation_id) gid: vec3u) {
    if gid.z >= frame.view_count {
        return;
    }
    let v = views[gid.z];
    if gid.x >= v.froxel_dims.x || gid.y >= v.froxel_dims.y {
        return;
    }
    var far = 0.0;
    let origin = gid.xy * v.froxel_px;
    let end = min(origin + v.froxel_px, v.size);
    for (var y = origin.y; y < end.y; y++) {
        for (var x = origin.x; x < end.x; x++) {
            let w = surface_depth(textureLoad(gbuf, vec2i(vec2u(x, y)), i32(gid.z), 0));
            // No surface (w = 0): the ray runs to the far plane.
            far = max(far, select(v.far, w, w > 0.0));
        }
    }
    tile_depth[column_index(v, gid.z, gid.x, gid.y)] = far;
}

@compute @workgroup_size(8, 8, 1)
fn column_limit_pass(@builtin(global_invocation_id) gid: vec3u) {
    if gid.z >= frame.view_count {
        return;
    }
    let v = views[gid.z];
    if gid.x >= v.froxel_dims.x || gid.y >= v.froxel_dims.y {
        return;
    }
    var far = 0.0;
    // Froxels that a coupled stereo eye integrates too (its volume_view is this view)
    // are lit for what either eye's tiles show (and a stereo head's volume, lit from
    // between the eyes, for what both eyes' tiles show, each as a coupled eye's). Beyond
    // its near field the eyes' disparity is under a froxel (stereo_near_px), so the
    // coupled eye's column reads this view's columns ±1 and needs the depth of its own
    // 3 × 3 tiles: its tiles ±2 cover that (viewer_set.rs, `stereo_pairs`).
    for (var w = 0u; w < frame.view_count; w++) {
        if w != gid.z && views[w].volume_view != gid.z {
            continue;
        }
        let reach = select(1, 2, w != gid.z || !volume_on_own_rays(views[w]));
        let lo = max(vec2i(gid.xy) - reach, vec2i(0));
        let hi = min(vec2i(gid.xy) + reach, vec2i(v.froxel_dims) - 1);
        for (var y = lo.y; y <= hi.y; y++) {
            for (var x = lo.x; x <= hi.x; x++) {
                far = max(far, tile_depth[column_index(v, w, u32(x), u32(y))]);
            }
        }
    }
    // Froxel centres sit at slice + 0.5 + jitter; culling runs without jitter (temporal off).
    let s = floor(depth_to_slice(v, far)) + 1.0;
    column_limit[column_index(v, gid.z, gid.x, gid.y)] = u32(clamp(s, 0.0, f32(frame.slices - 1u)));
}
