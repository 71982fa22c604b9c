// The world media layer (src/render/media_layer.rs): the media filled once per frame
// into sparse bricks for every viewer (paper 004's metavoxels), so that froxels, surfaces
// and the transmittance columns read density with one trilinear lookup instead of
// evaluating noise. Two passes, one invocation per brick, then one workgroup per slot:
//
// `mark`: a brick of 8³ voxels gets a pool slot when some medium in the layer covers it
// and some viewer's frustum (of any viewer set) reaches it — 004's eye culling, over the
// union of all viewers. Bricks already in the pool keep their slot (static media are
// filled once; while media move, the table is cleared every frame and refilled).
// `fill`: the bricks given a slot this frame get their 9³ nodes evaluated analytically.

// Whether some in-layer medium may be non-zero in the box [lo, hi] at the frame's time.
fn layer_covered(lo: vec3f, hi: vec3f) -> bool {
    for (var i = 0u; i < frame.medium_count; i++) {
        let m = media[i];
        if m.in_layer == 0u {
            continue;
        }
        var mlo = m.min;
        var mhi = m.max;
        if m.kind == MEDIUM_VOLUME {
            // Where the volume is now: its sphere of outer radius (the box bounds its path).
            let r = m.radius_or_falloff * (1.0 + m.disp_amplitude);
            let c = volume_center(m);
            let d = max(max(lo - c, c - hi), vec3f(0.0));
            if dot(d, d) > r * r {
                continue;
            }
            mlo = max(mlo, c - r);
            mhi = min(mhi, c + r);
        }
        if all(lo <= mhi) && all(hi >= mlo) {
            return true;
        }
    }
    return false;
}

// Whether some viewer's frustum reaches the sphere (c, r).
fn layer_seen(c: vec3f, r: f32) -> bool {
    for (var i = 0u; i < frame.view_count; i++) {
        let v = views[i];
        let d = c - v.position;
        let z = dot(d, v.forward);
        if z < v.near - r || z > v.far + r {
            continue;
        }
        let x = abs(dot(d, v.right));
        let y = abs(dot(d, v.up));
        // Distance past the side planes |x| = z·tan, along their normals.
        if (x - z * v.tan_x) * inverseSqrt(1.0 + v.tan_x * v.tan_x) > r {
            continue;
        }
        if (y - z * v.tan_y) * inverseSqrt(1.0 + v.tan_y * v.tan_y) > r {
            continue;
        }
        return true;
    }
    return false;
}

@compute @workgroup_size(64, 1, 1)
fn mark(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    var requested = 0u;
    let nb = frame.layer_bricks;
    let b = gid.x + gid.y * groups.x * 64u;
    if b < nb.x * nb.y * nb.z && layer_table[b] == 0u {
        let bc = vec3u(b % nb.x, (b / nb.x) % nb.y, b / (nb.x * nb.y));
        let edge = 8.0 * frame.layer_voxel;
        let lo = frame.layer_min + vec3f(bc) * edge;
        let hi = lo + vec3f(edge);
        if layer_covered(lo, hi) && layer_seen((lo + hi) * 0.5, 0.8660254 * edge) {
            let slot = atomicAdd(&layer_slots[0], 1u);
            // A full pool leaves the brick out: its media are evaluated where read (and
            // the pool grows for the next frame: every request is counted).
            requested = 1u;
            if slot < frame.layer_capacity {
                layer_table[b] = slot + 1u;
                atomicStore(&layer_slots[1u + 2u * slot], b);
                atomicStore(&layer_slots[2u + 2u * slot], frame.layer_stamp);
            }
        }
    }
    count(C_LAYER_BRICKS, requested);
}

// The summed density of the layer's media at p (they share their coefficients).
fn layer_density(p: vec3f) -> f32 {
    var d = 0.0;
    for (var i = 0u; i < frame.medium_count; i++) {
        if media[i].in_layer == 1u {
            d += medium_density(media[i], p);
        }
    }
    return d;
}

// f16 holds up to 65504: denser media saturate there (σt 6·10⁴ m⁻¹ is opaque in 0.1 mm).
fn f16_safe(v: vec2f) -> vec2f {
    return clamp(v, vec2f(-6.0e4), vec2f(6.0e4));
}

@compute @workgroup_size(64, 1, 1)
fn fill(@builtin(workgroup_id) wg: vec3u, @builtin(num_workgroups) groups: vec3u, @builtin(local_invocation_index) lane: u32) {
    var filled = 0u;
    let slot = wg.x + wg.y * groups.x;
    let handed = min(atomicLoad(&layer_slots[0]), frame.layer_capacity);
    if slot < handed && atomicLoad(&layer_slots[2u + 2u * slot]) == frame.layer_stamp {
        let nb = frame.layer_bricks;
        let b = atomicLoad(&layer_slots[1u + 2u * slot]);
        let bc = vec3u(b % nb.x, (b / nb.x) % nb.y, b / (nb.x * nb.y));
        for (var i = lane; i < LAYER_NODES; i += 64u) {
            let n = vec3u(i % 9u, (i / 9u) % 9u, i / 81u);
            let p = frame.layer_min + vec3f(bc * 8u + n) * frame.layer_voxel;
            let at = (slot * LAYER_NODES + i) * frame.layer_node_words;
            if (frame.flags & FLAG_LAYER_FULL) == 0u {
                layer_pool[at] = bitcast<u32>(layer_density(p));
            } else {
                let s = sample_media_where(p, 1u);
                let w = (s.scattering.x + s.scattering.y + s.scattering.z) / 3.0;
                layer_pool[at] = pack2x16float(f16_safe(s.scattering.xy));
                layer_pool[at + 1u] = pack2x16float(f16_safe(vec2f(s.scattering.z, s.extinction)));
                layer_pool[at + 2u] = pack2x16float(f16_safe(s.emission.xy));
                layer_pool[at + 3u] = pack2x16float(f16_safe(vec2f(s.emission.z, s.g * w)));
            }
            filled += 1u;
        }
    }
    count(C_LAYER_NODES, filled);
}
