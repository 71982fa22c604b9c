// Stage 1 (000 §3.1.1): the shared world-space shadow grid.
// One invocation owns one u32 word = 4 voxels along x, each an 8-bit light bitmask.
// A voxel is needed if its bounding sphere touches at least one viewer's frustum (the
// paper), or, with FLAG_DEMAND, if a froxel requested it (grid_requests.wgsl). With
// parity on, only voxels whose z parity matches the frame's parity are updated. With
// FLAG_CACHE, `valid` keeps which light bits of each voxel are current (same layout as
// the grid); a needed voxel traces only its stale lights, and a light that changed
// (frame.dirty_lights) makes its bit stale in every voxel. With FLAG_FROXEL_REQUESTS the
// requests are last frame's froxels' (what they found unfilled), and a filled voxel
// whose bits went stale is needed too: every filled voxel stays current.

@group(1) @binding(0) var<storage, read_write> grid: array<u32>;
@group(1) @binding(1) var<storage, read_write> touched: array<atomic<u32>>;
@group(1) @binding(2) var<storage, read> requests: array<u32>;
@group(1) @binding(3) var<storage, read_write> valid: array<u32>;
@group(1) @binding(4) var<storage, read> slot_brick: array<u32>;
// FLAG_GRID_MEDIA: the grid's media density at each needed voxel's centre, an 8-bit
// code per voxel in the grid's layout (4 voxels per word): 0 not filled yet, c > 0 a
// density of (c − 1)·frame.grid_media_unit. Static media fill a needed voxel once;
// moving ones (FLAG_GRID_MEDIA_MOVES) every frame it is needed, whatever its light bits.
@group(1) @binding(5) var<storage, read_write> grid_density: array<u32>;

// Request bits x0 ..= x0 + 4 of the request row (y, z), as bits 0..4 (request_bit).
fn request_bits5(x0: u32, y: u32, z: u32) -> u32 {
    let bit = request_bit(vec3u(x0, y, z));
    var w = requests[bit.x] >> (x0 % 32u);
    // Bit x0 + 4 is the next word's first when x0 % 32 = 28 (if the row has it).
    if x0 % 32u == 28u && x0 + 4u <= frame.grid_dims.x {
        w |= requests[bit.x + 1u] << 4u;
    }
    return w & 0x1fu;
}

// Which of the 4 voxels of the word at (x0, y, z) (x0 a multiple of 4) some froxel's
// lookup reads (FLAG_DEMAND, dense grid), as bits 0..3. Request coordinates are voxel
// coordinates + 1 (grid_requests.wgsl); a trilinear lookup sets the bit of the lowest of
// its 8 voxels, so voxel q is read when request q + 1 − (i, j, k) is set for some i, j,
// k in {0, 1}: bits x0 ..= x0 + 4 of the request rows (y, z) ..= (y + 1, z + 1).
fn requested_voxels(x0: u32, y: u32, z: u32) -> u32 {
    if (frame.flags & FLAG_TRILINEAR) == 0u {
        return request_bits5(x0, y + 1u, z + 1u) >> 1u;
    }
    var m = 0u; // bit j: request x0 + j, the lowest corner of voxel x0 + j − 1's lookups
    for (var k = 0u; k < 4u; k++) {
        m |= request_bits5(x0, y + (k & 1u), z + (k >> 1u));
    }
    return (m | (m >> 1u)) & 0xfu;
}

// Whether the shadow ray from `centre` to light `li` crosses the bounds the movers swept
// since the last frame (then a cached bit of that light may be stale).
fn crosses_moved(centre: vec3f, li: u32) -> bool {
    let tl = to_light(lights[li], centre);
    let inv_d = 1.0 / select(tl.xyz, vec3f(1e-30), abs(tl.xyz) < vec3f(1e-30));
    return ray_box(centre, inv_d, tl.w, frame.moved_min, frame.moved_max);
}

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

// FLAG_DEMAND on a dense grid: `scan` lists the workgroups of `main_listed` (4 × 4 × 4
// words, as `main`'s, numbered x + gx·(y + gy·z)) that have work this frame, and
// `main_listed` runs over those alone (an indirect dispatch; src/render/shared_grid.rs).
@group(1) @binding(6) var<storage, read_write> listed: array<u32>;
// The indirect dispatch's (x, y, z): x counts the listed workgroups.
@group(1) @binding(7) var<storage, read_write> listed_args: array<atomic<u32>>;

// What one word does this frame: which of its 4 voxels trace which lights, its light
// and valid bits after the stale ones are dropped, and its media codes.
struct WordPlan {
    // The grid word with the bits about to be traced cleared.
    word: u32,
    valid_bits: u32,
    old_valid: u32,
    // FLAG_GRID_MEDIA: the codes to write (with `fill_codes`) where `coded` is set.
    codes: u32,
    coded: u32,
    old_codes: u32,
    needed: u32,
    // Bits 0..3: the voxels that trace; `stale`: their lights, 8 bits per voxel.
    traced: u32,
    stale: u32,
}

// The plan of the word at `gid` (inside the grid). `main` and `main_listed` fill the
// media codes it finds missing; `scan` only asks whether there are any.
fn plan_word(gid: vec3u, fill_codes: bool) -> WordPlan {
    var plan: WordPlan;
    let dims = frame.grid_dims;
    let word_index = gid.x + frame.grid_words_x * (gid.y + dims.y * gid.z);
    let cache = (frame.flags & FLAG_CACHE) != 0u;
    // Stale bits are dropped in every word, whether or not it is updated this frame.
    let dirty = frame.dirty_lights & 0xffu;
    plan.old_valid = select(0u, valid[word_index], cache);
    plan.valid_bits = plan.old_valid & ~(dirty * 0x01010101u);
    if plan.valid_bits != 0u && all(frame.moved_min <= frame.moved_max) {
        for (var i = 0u; i < 4u && gid.x * 4u + i < dims.x; i++) {
            let centre = frame.grid_min + (vec3f(f32(gid.x * 4u + i), f32(gid.y), f32(gid.z)) + 0.5) * frame.voxel_size;
            for (var li = 0u; li < light_count(); li++) {
                let bit = 1u << (8u * i + li);
                if (plan.valid_bits & bit) != 0u && crosses_moved(centre, li) {
                    plan.valid_bits &= ~bit;
                }
            }
        }
    }
    let may_trace = (frame.flags & FLAG_PARITY) == 0u || (gid.z & 1u) == (frame.frame_index & 1u);
    let all_lights = (1u << light_count()) - 1u;
    plan.word = grid[word_index];
    // Trilinear lookups read the 8 voxels around a sample, so a voxel one voxel
    // outside a frustum may be read: widen the test by a voxel diagonal.
    var radius = 0.866 * frame.voxel_size;
    if (frame.flags & FLAG_TRILINEAR) != 0u {
        radius = 1.732 * frame.voxel_size;
    }
    let media = (frame.flags & FLAG_GRID_MEDIA) != 0u;
    let refill = (frame.flags & FLAG_GRID_MEDIA_MOVES) != 0u;
    let fine = (frame.flags & FLAG_GRID_MEDIA_FINE) != 0u;
    // FLAG_GRID_MEDIA_FINE: the codes of the 8 fine words this word owns (fine_row in
    // common.wgsl), 2 per row of cells, and which of their bytes were filled.
    var fine_codes: array<u32, 8>;
    var fine_coded: array<u32, 8>;
    if media {
        plan.old_codes = grid_density[word_index];
    }
    var requested = 0u;
    if (frame.flags & FLAG_DEMAND) != 0u && (may_trace || media) {
        requested = requested_voxels(gid.x * 4u, gid.y, gid.z);
    }
    for (var i = 0u; i < 4u; i++) {
        let x = gid.x * 4u + i;
        if x >= dims.x || !(may_trace || media) {
            break;
        }
        var seen = false;
        if (frame.flags & FLAG_DEMAND) != 0u {
            seen = ((requested >> i) & 1u) != 0u;
            // FLAG_FROXEL_REQUESTS: froxels read a filled voxel without asking, so
            // one whose light bits a mover made stale is traced again unasked.
            if !seen && (frame.flags & FLAG_FROXEL_REQUESTS) != 0u {
                let filled = ((plan.old_codes >> (8u * i)) & 0xffu) != 0u;
                seen = filled && ((plan.valid_bits >> (8u * i)) & all_lights) != all_lights;
            }
        } else {
            let centre = frame.grid_min + (vec3f(f32(x), f32(gid.y), f32(gid.z)) + 0.5) * frame.voxel_size;
            for (var vi = 0u; vi < frame.view_count; vi++) {
                if sphere_in_view(views[vi], centre, radius) {
                    seen = true;
                    break;
                }
            }
        }
        if !seen {
            continue;
        }
        let shift = 8u * i;
        if media && (refill || ((plan.old_codes >> shift) & 0xffu) == 0u) {
            if fill_codes {
                let q = vec3u(x, gid.y, gid.z);
                if fine {
                    // Its 8 cells: row r = y + 2z of the owned rows, word i / 2, byte
                    // 2 (i % 2) + x; the coarse code is their mean's.
                    var sum = 0.0;
                    for (var k = 0u; k < 8u; k++) {
                        let c = vec3u(k & 1u, (k >> 1u) & 1u, k >> 2u);
                        let d = grid_media_density(fine_cell_centre(2u * q + c));
                        sum += d;
                        let slot = 2u * (k >> 1u) + i / 2u;
                        let byte = 8u * (2u * (i % 2u) + c.x);
                        fine_codes[slot] |= code_of_density(d) << byte;
                        fine_coded[slot] |= 0xffu << byte;
                    }
                    plan.codes |= code_of_density(sum / 8.0) << shift;
                } else {
                    plan.codes |= density_code(voxel_centre(q)) << shift;
                }
            }
            plan.coded |= 0xffu << shift;
        }
        if !may_trace {
            continue;
        }
        plan.needed += 1u;
        let current = (plan.valid_bits >> shift) & 0xffu;
        let stale = all_lights & ~current;
        if stale == 0u {
            continue; // every light bit is cached and current
        }
        // Keep the current bits; the stale ones are traced below.
        plan.word = (plan.word & ~(0xffu << shift)) | (((plan.word >> shift) & current) << shift);
        plan.valid_bits |= stale << shift;
        plan.traced |= 1u << i;
        plan.stale |= stale << shift;
    }
    if fine && fill_codes && plan.coded != 0u {
        for (var slot = 0u; slot < 8u; slot++) {
            if fine_coded[slot] != 0u {
                let r = slot / 2u;
                let at = fine_row(2u * gid.y + (r & 1u), 2u * gid.z + (r >> 1u)) + 2u * gid.x + slot % 2u;
                grid_density[at] = fine_codes[slot] | (grid_density[at] & ~fine_coded[slot]);
            }
        }
    }
    return plan;
}

// The voxels of this workgroup's 64 words that trace this frame, compacted so that every
// invocation traces from the same list (voxels needed are sparse with the demand-driven
// update: tracing word by word would leave most SIMD lanes idle). An entry is
// local word << 2 | voxel in word, with the voxel's stale lights << 8.
var<workgroup> todo: array<u32, 256>;
var<workgroup> todo_count: atomic<u32>;
// Light bits traced this frame, per local word (4 voxels × 8 bits).
var<workgroup> traced_bits: array<atomic<u32>, 64>;

// One workgroup of `main`'s: local word `lid` at `gid` of the 4 × 4 × 4 words of
// workgroup `wg`. `count_needed`: false where `scan` counted the needed voxels.
fn update_words(gid: vec3u, lid: u32, wg: vec3u, count_needed: bool) {
    var rays = 0u;
    var filled = 0u;
    let dims = frame.grid_dims;
    let in_grid = gid.x < frame.grid_words_x && gid.y < dims.y && gid.z < dims.z;
    let word_index = gid.x + frame.grid_words_x * (gid.y + dims.y * gid.z);
    if lid == 0u {
        atomicStore(&todo_count, 0u);
    }
    atomicStore(&traced_bits[lid], 0u);
    workgroupBarrier();
    var plan: WordPlan;
    if in_grid {
        plan = plan_word(gid, true);
        for (var i = 0u; i < 4u; i++) {
            if ((plan.traced >> i) & 1u) != 0u {
                let stale = (plan.stale >> (8u * i)) & 0xffu;
                todo[atomicAdd(&todo_count, 1u)] = (lid << 2u) | i | (stale << 8u);
            }
        }
        if plan.coded != 0u {
            grid_density[word_index] = plan.codes | (plan.old_codes & ~plan.coded);
            filled = countOneBits(plan.coded) / 8u;
        }
    }
    workgroupBarrier();
    let n = atomicLoad(&todo_count);
    for (var k = lid; k < n; k += 64u) {
        let e = todo[k];
        let w = e >> 2u & 63u;
        let i = e & 3u;
        let stale = (e >> 8u) & 0xffu;
        // Local word w of this workgroup: (w % 4, w / 4 % 4, w / 16) in words.
        let q = vec3u((wg.x * 4u + w % 4u) * 4u + i, wg.y * 4u + (w / 4u) % 4u, wg.z * 4u + w / 16u);
        atomicOr(&traced_bits[w], trace_voxel(q, stale, &rays) << (8u * i));
    }
    workgroupBarrier();
    if in_grid {
        if plan.traced != 0u {
            grid[word_index] = plan.word | atomicLoad(&traced_bits[lid]);
            atomicOr(&touched[word_index / 8u], plan.traced << (4u * (word_index % 8u)));
        }
        if (frame.flags & FLAG_CACHE) != 0u && plan.valid_bits != plan.old_valid {
            valid[word_index] = plan.valid_bits;
        }
    }
    count(C_GRID_RAYS, rays);
    count(C_VOXELS_TRACED, countOneBits(plan.traced));
    if count_needed {
        count(C_VOXELS_NEEDED, plan.needed);
    }
    count(C_GRID_MEDIA_VOXELS, filled);
}

@compute @workgroup_size(4, 4, 4)
fn main(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3u,
) {
    update_words(gid, lid, wg, true);
}

// `main`'s workgroups per axis.
fn word_groups() -> vec3u {
    return (vec3u(frame.grid_words_x, frame.grid_dims.y, frame.grid_dims.z) + 3u) / 4u;
}

// Workgroup number `id` of `main` (x + gx·(y + gy·z), `word_groups`) as (x, y, z).
fn word_group(id: u32) -> vec3u {
    let groups = word_groups();
    return vec3u(id % groups.x, (id / groups.x) % groups.y, id / (groups.x * groups.y));
}

// One invocation per workgroup of `main`: whether any of its 64 words traces, fills a
// media code or drops a stale bit this frame; such workgroups are listed for
// `main_listed`. Without workgroup barriers, so llvmpipe runs it as straight SIMD code
// (`main`'s barriers make it run invocation by invocation): with a cached grid most
// workgroups have nothing to do. Counts every word's needed voxels. 2-D dispatch: x +
// y·64·workgroups_x.
@compute @workgroup_size(64, 1, 1)
fn scan(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) nw: vec3u) {
    let id = gid.x + gid.y * nw.x * 64u;
    if id == 0u {
        atomicStore(&listed_args[1], 1u);
        atomicStore(&listed_args[2], 1u);
    }
    let groups = word_groups();
    var needed = 0u;
    if id < groups.x * groups.y * groups.z {
        let wg = word_group(id);
        var work = false;
        for (var w = 0u; w < 64u; w++) {
            let g = wg * 4u + vec3u(w % 4u, (w / 4u) % 4u, w / 16u);
            if g.x < frame.grid_words_x && g.y < frame.grid_dims.y && g.z < frame.grid_dims.z {
                let plan = plan_word(g, false);
                needed += plan.needed;
                work = work || plan.traced != 0u || plan.coded != 0u || plan.valid_bits != plan.old_valid;
            }
        }
        if work {
            listed[atomicAdd(&listed_args[0], 1u)] = id;
        }
    }
    count(C_VOXELS_NEEDED, needed);
}

// `main` over the workgroups `scan` listed (one dispatched workgroup per entry).
@compute @workgroup_size(4, 4, 4)
fn main_listed(
    @builtin(local_invocation_id) local: vec3u,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) slot: vec3u,
) {
    let wg = word_group(listed[slot.x]);
    update_words(wg * 4u + local, lid, wg, false);
}

// Sparse grid update: one invocation per pool word (2D dispatch: x + y·64·workgroups_x);
// words of allocated bricks trace their requested voxels (the request bits set by
// grid_requests.wgsl's `mark_voxels`). Bricks are allocated afresh every frame; the
// allocation cursor (bricks requested) is `counters[C_BRICKS]`.
@compute @workgroup_size(64, 1, 1)
fn update_sparse(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) n: vec3u) {
    var rays = 0u;
    var traced = 0u;
    let id = gid.x + gid.y * n.x * 64u;
    let slot = id / BRICK_WORDS;
    let allocated = min(atomicLoad(&counters[C_BRICKS]), frame.pool_capacity);
    if slot < allocated {
        let d = brick_dims();
        let b = slot_brick[slot];
        let origin = vec3u(b % d.x, (b / d.x) % d.y, b / (d.x * d.y)) * BRICK;
        var word = 0u;
        for (var i = 0u; i < 4u; i++) {
            let li = (id % BRICK_WORDS) * 4u + i;
            let q = origin + vec3u(li % BRICK, (li / BRICK) % BRICK, li / (BRICK * BRICK));
            let bit = slot * BRICK_VOXELS + li;
            if any(q >= frame.grid_dims) || ((requests[bit / 32u] >> (bit % 32u)) & 1u) == 0u {
                continue;
            }
            word |= trace_voxel(q, 0xffu, &rays) << (8u * i);
            traced += 1u;
        }
        grid[id] = word;
    }
    count(C_GRID_RAYS, rays);
    count(C_VOXELS_TRACED, traced);
    count(C_VOXELS_NEEDED, traced);
}
