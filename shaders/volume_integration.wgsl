// Stage 4 (000 §3.1.4): front-to-back integration of every froxel column, all viewers
// in one dispatch. Energy-conserving form (Hillaire 2015):
//   S_int = (S − S·exp(−σt·d)) / σt, with the σt → 0 limit S·d taken explicitly.
// Froxels hold src = S / max(σt, SIGMA_EPS), so S_int = src·(1 − exp(−σt·d)).
// integrated[s] holds (in-scattered rgb, transmittance) from the eye to the far
// boundary of slice s.

@group(1) @binding(0) var<storage, read> froxels: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> integrated: array<vec2u>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    let view_index = gid.z;
    if view_index >= frame.view_count {
        return;
    }
    let v = views[view_index];
    // A coupled stereo eye integrates its near field only, or nothing (v.light_slices).
    if gid.x >= v.froxel_dims.x || gid.y >= v.froxel_dims.y || v.light_slices == 0u {
        return;
    }
    let pix = (vec2f(gid.xy) + 0.5) * f32(v.froxel_px);
    let dir = view_ray(v, min(pix, vec2f(v.size) - 0.5)); // past the edge: the last pixel centre
    let inv_cos = 1.0 / dot(dir, v.forward);
    var scattered = vec3f(0.0);
    var transmittance = 1.0;
    var z0 = v.near;
    for (var s = 0u; s < v.light_slices; s++) {
        let index = v.froxel_base + gid.x + v.froxel_dims.x * (gid.y + v.froxel_dims.y * s);
        let z1 = slice_depth(v, f32(s + 1u));
        let d = (z1 - z0) * inv_cos;
        z0 = z1;
        let f = unpack_rgba16(froxels[index]);
        let sigma_t = f.w;
        let tau = sigma_t * d;
        // 1 − exp(−τ) without cancellation for small τ.
        let absorbed = select(1.0 - exp(-tau), tau * (1.0 - 0.5 * tau), tau < 1e-4);
        var s_int = f.rgb * absorbed;
        if sigma_t < SIGMA_EPS {
            s_int = f.rgb * (SIGMA_EPS * d); // = S·d, the σt → 0 limit
        }
        scattered += transmittance * s_int;
        transmittance *= 1.0 - absorbed;
        integrated[index] = pack_rgba16(vec4f(min(scattered, vec3f(6.0e4)), transmittance));
    }
}
