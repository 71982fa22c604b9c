// Shared media transmittance toward each light (world / light space, once per frame for
// every viewer; src/render/media_transmittance.rs). Opaque visibility stays in the shadow
// grid and maps: this volume holds only the optical depth τ = ∫σt of the media along the
// way to the light (T = exp(−τ) at lookup), so wind moving the media refills it without a
// single opaque shadow ray.
//
// One invocation per column of a light's volume (z runs over lights), propagating the
// optical depth node to node away from the light, τ(k) = τ(k−1) + ∫σt over one spacing
// (004's light propagation down light-aligned columns, with Beer-Lambert exp(−τ), not the
// article's 1/(1 + ρ)). A directional light's columns are parallel, their first node
// upstream of every medium; a point or spot light's columns are rays from the light,
// their first node before any medium.
// Only lights marked in `frame.transmittance_dirty` are refilled; the others keep the
// nodes of an earlier frame.

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    var filled = 0u;
    let li = gid.z;
    if li < light_count() && ((frame.transmittance_dirty >> li) & 1u) != 0u {
        let v = light_media[li];
        if v.nodes > 0u && gid.x < v.dims.x && gid.y < v.dims.y {
            let l = lights[li];
            let c = media_column(l, v, gid.xy);
            let first = v.offset + gid.x + v.dims.x * gid.y;
            let stride = v.dims.x * v.dims.y;
            // Outside a spot's cone no light arrives: nothing to dim, nothing to march.
            let dark = l.kind == LIGHT_SPOT && dot(c.dir, l.direction) < l.cos_outer;
            var tau = 0.0;
            media_t[first] = 0.0;
            for (var k = 1u; k < v.dims.z; k++) {
                if !dark {
                    tau += media_optical_depth(c.start + c.dir * (v.spacing * f32(k - 1u)), c.dir, v.spacing);
                }
                media_t[first + k * stride] = tau;
            }
            filled = v.dims.z;
        }
    }
    count(C_TRANSMITTANCE_NODES, filled);
}
