// Demand-driven grid update, step 1 (beyond paper 000; its §4.2 notes the frustum-gated
// update "is overestimating the voxels required for sampling"): every froxel that will
// read the shared grid marks the voxels its lookup reads — the nearest voxel, or the 8
// trilinear neighbours — and only marked voxels are traced. Froxels outside every
// medium mark nothing. All viewers in one dispatch; z runs over viewers × grid slices.

@group(1) @binding(0) var<storage, read_write> requests: array<u32>;

// Whether any medium can have density at `p`: its shape contains `p`. Noise scales the
// density by max(1 + a·(2·fbm − 1), 0) with fbm in [0, 1], which is zero only for
// amplitudes a ≥ 1; those media are sampled exactly.
fn may_have_media(p: vec3f) -> bool {
    for (var i = 0u; i < frame.medium_count; i++) {
        let m = media[i];
        if m.noise_frequency > 0.0 && m.noise_amplitude >= 1.0 {
            if medium_density(m, p) > 0.0 {
                return true;
            }
            continue;
        }
        let inside_box = all(p >= m.min) && all(p <= m.max);
        if m.kind == 3u {
            let q = p - (m.min + m.max) * 0.5;
            if dot(q, q) <= m.radius_or_falloff * m.radius_or_falloff {
                return true;
            }
        } else if inside_box {
            return true;
        }
    }
    return false;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    let grid_slices = frame.slices - frame.frustum_slices;
    let view_index = gid.z / grid_slices;
    let slice = frame.frustum_slices + gid.z % grid_slices;
    if view_index < frame.view_count {
        let v = views[view_index];
        if gid.x < v.froxel_dims.x && gid.y < v.froxel_dims.y {
            let p = froxel_sample(v, gid.xy, slice).p;
            if may_have_media(p) {
                let g = grid_coord(p);
                if (frame.flags & FLAG_TRILINEAR) == 0u {
                    requests[voxel_index(vec3i(floor(g + 0.5)))] = 1u;
                } else {
                    let base = vec3i(floor(g));
                    for (var k = 0u; k < 8u; k++) {
                        let o = vec3i(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
                        requests[voxel_index(base + o)] = 1u;
                    }
                }
            }
        }
    }
}
