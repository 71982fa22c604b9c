// Demand-driven grid update, step 1 (beyond paper 000; its §4.2 notes the frustum-gated
// update "is overestimating the voxels required for sampling"): every froxel that will
// read the shared grid marks the voxels its lookup reads — the nearest voxel, or the 8
// trilinear neighbours — and only marked voxels are traced. Froxels outside every
// medium, or hidden behind the depth buffer (froxel_cull.wgsl), mark nothing. All viewers
// in one dispatch; an invocation walks one froxel column (z runs over viewers).
//
// Dense grid (`main`): one bit per voxel (`request_bit` in common.wgsl). A trilinear
// lookup sets only the bit of the lowest of the 8 voxels it reads, and the grid pass
// takes a voxel as requested when its bit or one of its 7 lower neighbours' is set
// (shared_grid.wgsl): one atomicOr per lookup, paid per viewer, instead of 8 stores.
// Sparse grid: `mark_bricks` flags the bricks the froxels read, `allocate` gives each
// flagged brick a pool slot, `mark_voxels` sets the read voxels' bits (512 per brick)
// in the slot's request words.

@group(1) @binding(0) var<storage, read_write> requests: array<atomic<u32>>;
@group(1) @binding(1) var<storage, read_write> brick_table: array<u32>;
@group(1) @binding(2) var<storage, read_write> slot_brick: array<u32>;
@group(1) @binding(3) var<storage, read> column_limit: array<u32>;

const PHASE_DENSE: u32 = 0u;
const PHASE_BRICKS: u32 = 1u;
const PHASE_VOXELS: u32 = 2u;

var<private> phase: u32;

// Requests voxel `c` (clamped into the grid), or on the dense grid with trilinear
// lookups the 2 × 2 × 2 voxels from `c` on (those inside the grid).
fn request(c: vec3i) {
    let last = vec3i(frame.grid_dims) - 1;
    if phase == PHASE_DENSE {
        let bit = lookup_request_bit(c, (frame.flags & FLAG_TRILINEAR) != 0u);
        atomicOr(&requests[bit.x], bit.y);
        return;
    }
    let q = vec3u(clamp(c, vec3i(0), last));
    if phase == PHASE_BRICKS {
        brick_table[brick_of(q)] = BRICK_MISSING;
    } else {
        let t = brick_table[brick_of(q)];
        if t != 0u && t != BRICK_MISSING {
            let bit = (t - 1u) * BRICK_VOXELS + in_brick(q);
            atomicOr(&requests[bit / 32u], 1u << (bit % 32u));
        }
    }
}

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
        if m.kind == MEDIUM_SPHERE {
            let q = p - (m.min + m.max) * 0.5;
            if dot(q, q) <= m.radius_or_falloff * m.radius_or_falloff {
                return true;
            }
        } else if m.kind == MEDIUM_VOLUME {
            // A volume: the sphere of its outer radius where it is now.
            let q = p - volume_center(m);
            let outer = m.radius_or_falloff * (1.0 + m.disp_amplitude);
            if dot(q, q) <= outer * outer {
                return true;
            }
        } else if inside_box {
            return true;
        }
    }
    return false;
}

// The requests of one froxel column (gid.xy) of viewer gid.z: its grid slices, front
// to back, up to the last one culling keeps. Consecutive slices whose lookups start at
// the same voxel mark it once (near the eye many slices share a voxel).
fn request_column(gid: vec3u) {
    if gid.z >= frame.view_count {
        return;
    }
    let v = volume_of(views[gid.z]);
    // A coupled stereo eye lights its near field only, or nothing (v.light_slices).
    if gid.x >= v.froxel_dims.x || gid.y >= v.froxel_dims.y || v.light_slices == 0u {
        return;
    }
    var last = v.light_slices - 1u;
    if (frame.flags & FLAG_CULL) != 0u {
        last = min(last, column_limit[column_index(v, gid.z, gid.x, gid.y)]);
    }
    let trilinear = (frame.flags & FLAG_TRILINEAR) != 0u;
    var prev = vec3i(-2147483647);
    // The column's ray once; froxel_point gives the lighting stage's points exactly.
    let dir = froxel_ray(v, gid.xy);
    for (var slice = frame.frustum_slices; slice <= last; slice++) {
        let p = froxel_point(v, dir, slice);
        // Inside the box of the grid's media (FLAG_GRID_MEDIA) froxel lighting reads
        // their density from the grid wherever the media are or are not.
        let grid_media = (frame.flags & FLAG_GRID_MEDIA) != 0u
            && all(p >= frame.grid_media_min) && all(p <= frame.grid_media_max);
        if !grid_media && !may_have_media(p) {
            continue;
        }
        let g = grid_coord(p);
        let base = select(vec3i(floor(g + 0.5)), vec3i(floor(g)), trilinear);
        if all(base == prev) {
            continue;
        }
        prev = base;
        if !trilinear || phase == PHASE_DENSE {
            request(base);
        } else {
            for (var k = 0u; k < 8u; k++) {
                request(base + vec3i(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u)));
            }
        }
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    phase = PHASE_DENSE;
    request_column(column_slot(gid, wg, n));
}

@compute @workgroup_size(8, 8, 1)
fn mark_bricks(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    phase = PHASE_BRICKS;
    request_column(column_slot(gid, wg, n));
}

@compute @workgroup_size(8, 8, 1)
fn mark_voxels(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    phase = PHASE_VOXELS;
    request_column(column_slot(gid, wg, n));
}

// One invocation per brick (2D dispatch: x + y·64·workgroups_x): a flagged brick takes
// the next pool slot; when the pool is full it stays BRICK_MISSING and the froxels that
// read it trace their own shadow rays (exact, only slower).
@compute @workgroup_size(64, 1, 1)
fn allocate(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) n: vec3u) {
    let d = brick_dims();
    let b = gid.x + gid.y * n.x * 64u;
    if b < d.x * d.y * d.z && brick_table[b] == BRICK_MISSING {
        let slot = atomicAdd(&counters[C_BRICKS], 1u);
        if slot < frame.pool_capacity {
            brick_table[b] = slot + 1u;
            slot_brick[slot] = b;
        }
    }
}
