// Reads of a viewer's integrated froxel volume (in-scattered rgb, transmittance from the
// eye), shared by the composite and the smoke raster; each declares `integrated`.

fn fetch_integrated(v: View, x: u32, y: u32, s: i32) -> vec4f {
    if s < 0 {
        return vec4f(0.0, 0.0, 0.0, 1.0);
    }
    let i = v.froxel_base + x + v.froxel_dims.x * (y + v.froxel_dims.y * u32(s));
    return unpack_rgba16(integrated[i]);
}

// The four froxel columns around pixel `pix` and their bilinear weights.
struct Columns {
    c0: vec2f,
    c1: vec2f,
    f: vec2f,
}

fn columns_at(v: View, pix: vec2f) -> Columns {
    let c = pix / f32(v.froxel_px) - 0.5;
    let cmax = vec2f(v.froxel_dims) - 1.0;
    let c0 = clamp(floor(c), vec2f(0.0), cmax);
    return Columns(c0, min(c0 + 1.0, cmax), clamp(c - c0, vec2f(0.0), vec2f(1.0)));
}

// Trilinear lookup: bilinear between the columns' centres, linear between slice
// boundaries (boundary b holds integrated[b − 1]; boundary 0 is the eye). Depths past
// the last slice the view lit (v.light_slices: a coupled eye's near field) read that
// boundary.
fn sample_columns(v: View, cols: Columns, depth: f32) -> vec4f {
    let w = clamp(depth_to_slice(v, depth), 0.0, f32(v.light_slices));
    let s0 = min(floor(w), f32(v.light_slices) - 1.0);
    let fs = w - s0;
    var acc = vec4f(0.0);
    for (var k = 0u; k < 4u; k++) {
        let sx = select(cols.c0.x, cols.c1.x, (k & 1u) != 0u);
        let sy = select(cols.c0.y, cols.c1.y, (k & 2u) != 0u);
        let wx = select(1.0 - cols.f.x, cols.f.x, (k & 1u) != 0u);
        let wy = select(1.0 - cols.f.y, cols.f.y, (k & 2u) != 0u);
        let a = fetch_integrated(v, u32(sx), u32(sy), i32(s0) - 1);
        let b = fetch_integrated(v, u32(sx), u32(sy), i32(s0));
        acc += wx * wy * mix(a, b, fs);
    }
    return acc;
}

fn sample_integrated(v: View, pix: vec2f, depth: f32) -> vec4f {
    return sample_columns(v, columns_at(v, pix), depth);
}

// The fog between view `v`'s eye (slot `slot`) and the world point `p` its pixel `pix`
// shows at `depth` along its forward axis. A coupled stereo eye (v.volume_view ≠ slot)
// lit only its near field, the slices up to where the eyes' disparity falls under
// `stereo_near_px` (maybe none), and reads its partner's volume beyond, where `p`
// projects into it: the partner's integral along its own ray, which differs from this
// eye's by their parallax (viewer_set.rs, `stereo_pairs`, `near_slices`). The eyes look
// the same way, so the split is one depth for both.
fn fog_to(v: View, slot: u32, pix: vec2f, depth: f32, p: vec3f) -> vec4f {
    if v.volume_view == slot {
        return sample_integrated(v, pix, depth);
    }
    let split = slice_depth(v, f32(v.light_slices));
    var near = vec4f(0.0, 0.0, 0.0, 1.0);
    if v.light_slices > 0u {
        near = sample_integrated(v, pix, min(depth, split));
        if depth <= split {
            return near;
        }
    }
    let o = views[v.volume_view];
    let d = p - o.position;
    let z = max(dot(d, o.forward), o.near);
    let ndc = vec2f(dot(d, o.right) / (z * o.tan_x), dot(d, o.up) / (z * o.tan_y));
    let opix = vec2f(ndc.x + 1.0, 1.0 - ndc.y) * 0.5 * vec2f(o.size);
    let cols = columns_at(o, opix);
    let far = sample_columns(o, cols, z);
    if v.light_slices == 0u {
        return far;
    }
    // The partner's fog from the split on: its integral to p less that to the split,
    // seen through its transmittance at the split (un-composited), then put behind this
    // eye's own near field. Where the partner's fog is all but opaque before the split
    // (T < 1e-3) what lies beyond it is lost in the f16 differences; the floor keeps
    // their amplification bounded.
    let at_split = sample_columns(o, cols, split);
    let inv = near.a / max(at_split.a, 1e-3);
    return vec4f(
        near.rgb + inv * max(far.rgb - at_split.rgb, vec3f(0.0)),
        min(inv * far.a, near.a),
    );
}
