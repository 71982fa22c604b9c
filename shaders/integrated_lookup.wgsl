// Reads of a viewer's integrated froxel volume (in-scattered rgb, transmittance from the
// eye), shared by the composite and the smoke raster; each declares `integrated`.

fn fetch_integrated(v: View, x: u32, y: u32, s: i32) -> vec4f {
    if s < 0 {
        return vec4f(0.0, 0.0, 0.0, 1.0);
    }
    let i = v.froxel_base + x + v.froxel_dims.x * (y + v.froxel_dims.y * u32(s));
    return unpack_rgba16(integrated[i]);
}

// The four froxel columns around pixel-space point `pix` of view `v` (clamped to the
// view's columns) and the bilinear weights between their centres.
fn columns_at(v: View, pix: vec2f) -> Columns {
    let c = pix / f32(v.froxel_px) - 0.5;
    let cmax = vec2f(v.froxel_dims) - 1.0;
    let c0 = clamp(floor(c), vec2f(0.0), cmax);
    return Columns(c0, min(c0 + 1.0, cmax), clamp(c - c0, vec2f(0.0), vec2f(1.0)));
}

// Trilinear lookup of view `v`'s integrated volume at pixel `pix` and view depth
// `depth`: bilinear between the four columns' centres around the pixel, linear between slice boundaries (boundary b holds integrated[b − 1];
// boundary 0 is the eye). Every view reads its own volume: a coupled stereo eye
// integrated its partner's froxels beyond its near field (volume_integration.wgsl).
fn sample_integrated(v: View, pix: vec2f, depth: f32) -> vec4f {
    let cols = columns_at(v, pix);
    let w = clamp(depth_to_slice(v, depth), 0.0, f32(frame.slices));
    let s0 = min(floor(w), f32(frame.slices) - 1.0);
    let fs = w - s0;
    var acc = vec4f(0.0);
    for (var k = 0u; k < 4u; k++) {
        let c = column_corner(cols, k);
        let a = fetch_integrated(v, c.x, c.y, i32(s0) - 1);
        let b = fetch_integrated(v, c.x, c.y, i32(s0));
        acc += column_weight(cols, k) * mix(a, b, fs);
    }
    return acc;
}
