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

var<workgroup> wg_rays: atomic<u32>;
var<workgroup> wg_voxels: atomic<u32>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_index) lid: u32) {
    if lid == 0u {
        atomicStore(&wg_rays, 0u);
        atomicStore(&wg_voxels, 0u);
    }
    workgroupBarrier();
    let dims = frame.grid_dims;
    let in_grid = gid.x < frame.grid_words_x && gid.y < dims.y && gid.z < dims.z
        && ((frame.flags & FLAG_PARITY) == 0u || (gid.z & 1u) == (frame.frame_index & 1u));
    if in_grid {
        let word_index = gid.x + frame.grid_words_x * (gid.y + dims.y * gid.z);
        var word = grid[word_index];
        var traced = 0u;
        var rays = 0u;
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
            atomicAdd(&wg_rays, rays);
            atomicAdd(&wg_voxels, countOneBits(traced));
        }
    }
    workgroupBarrier();
    if lid == 0u {
        atomicAdd(&counters[C_GRID_RAYS], atomicLoad(&wg_rays));
        atomicAdd(&counters[C_VOXELS_TRACED], atomicLoad(&wg_voxels));
    }
}
