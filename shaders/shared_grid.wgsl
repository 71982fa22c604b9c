// Stage 1 (000 §3.1.1): the shared world-space shadow grid.
// One invocation owns one u32 word = 4 voxels along x, each an 8-bit light bitmask.
// A voxel is traced only if its bounding sphere touches at least one viewer's frustum;
// with parity on, only voxels whose z parity matches the frame's parity are updated.

@group(1) @binding(0) var<storage, read_write> grid: array<u32>;
@group(1) @binding(1) var<storage, read_write> touched: array<atomic<u32>>;

// Sphere (centre c, radius r) against the frustum of view v, exact plane distances.
fn sphere_in_view(v: View, c: vec3f, r: f32) -> bool {
    let d = c - v.position;
    let z = dot(d, v.forward);
    if z < v.near - r || z > v.far + r {
        return false;
    }
    let x = abs(dot(d, v.right));
    let y = abs(dot(d, v.up));
    // Distance to a side plane through the eye: (x − z·tan) / sqrt(1 + tan²).
    return x - z * v.tan_x <= r * sqrt(1.0 + v.tan_x * v.tan_x)
        && y - z * v.tan_y <= r * sqrt(1.0 + v.tan_y * v.tan_y);
}

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    var rays = 0u;
    var traced = 0u;
    let dims = frame.grid_dims;
    let in_grid = gid.x < frame.grid_words_x && gid.y < dims.y && gid.z < dims.z
        && ((frame.flags & FLAG_PARITY) == 0u || (gid.z & 1u) == (frame.frame_index & 1u));
    if in_grid {
        let word_index = gid.x + frame.grid_words_x * (gid.y + dims.y * gid.z);
        var word = grid[word_index];
        // Trilinear lookups read the 8 voxels around a sample, so a voxel one voxel
        // outside a frustum may be read: widen the test by a voxel diagonal.
        var radius = 0.866 * frame.voxel_size;
        if (frame.flags & FLAG_TRILINEAR) != 0u {
            radius = 1.732 * frame.voxel_size;
        }
        for (var i = 0u; i < 4u; i++) {
            let x = gid.x * 4u + i;
            if x >= dims.x {
                break;
            }
            let centre = frame.grid_min + (vec3f(f32(x), f32(gid.y), f32(gid.z)) + 0.5) * frame.voxel_size;
            var seen = false;
            for (var vi = 0u; vi < frame.view_count; vi++) {
                if sphere_in_view(views[vi], centre, radius) {
                    seen = true;
                    break;
                }
            }
            if !seen {
                continue;
            }
            var mask = 0u;
            for (var li = 0u; li < frame.light_count; li++) {
                let l = lights[li];
                if all(light_radiance(l, centre) == vec3f(0.0)) {
                    continue; // outside a spot cone: no ray needed
                }
                rays += 1u;
                if light_visible(l, centre) {
                    mask |= 1u << li;
                }
            }
            word = (word & ~(0xffu << (8u * i))) | (mask << (8u * i));
            traced |= 1u << i;
        }
        if traced != 0u {
            grid[word_index] = word;
            atomicOr(&touched[word_index / 8u], traced << (4u * (word_index % 8u)));
        }
    }
    count(C_GRID_RAYS, rays);
    count(C_VOXELS_TRACED, countOneBits(traced));
}
