// Stage 3 (000 §3.1.3): in-scattered light and extinction per froxel, all viewers in
// one dispatch. `reference` traces a shadow ray per light per froxel (Hillaire 2015 with
// ray-traced shadows); `shared` reads the shared grid (nearest voxel, or trilinear over
// 8 voxels), where its voxels disagree (a shadow edge) the light's shared shadow map,
// and for lights without a map the shadow frustum in the near slices; `maps` reads the
// shared shadow maps (shaders/shadow_lookup.wgsl, bindings 10–14) for every froxel.

@group(1) @binding(0) var<storage, read> grid: array<u32>;
@group(1) @binding(1) var<storage, read> frustum: array<u32>;
@group(1) @binding(2) var<storage, read_write> froxels: array<vec2u>;
@group(1) @binding(3) var<storage, read> history: array<vec2u>;
@group(1) @binding(4) var<storage, read> brick_table: array<u32>;
@group(1) @binding(5) var<storage, read> column_limit: array<u32>;
// FLAG_GRID_MEDIA: the grid's media density, 8 bits per voxel in the grid's layout
// (shaders/shared_grid.wgsl fills it).
@group(1) @binding(6) var<storage, read> grid_density: array<u32>;
// FLAG_GRID_MEDIA_FINE as a pipeline constant (`grid_media_fine`): off, the fine cells'
// code is compiled out (it cost lavapipe 4 % of this stage where no froxel ran it).
override GRID_MEDIA_FINE: bool = false;
// FLAG_FROXEL_REQUESTS: the grid's requests (grid_requests.wgsl's dense layout), made
// here for the next frame's grid pass instead of by a request pass before it.
@group(1) @binding(7) var<storage, read_write> requests: array<atomic<u32>>;

// A voxel of a sparse grid whose brick was not allocated (pool full).
const MASK_MISSING: u32 = 0x100u;

fn grid_mask(c: vec3i) -> u32 {
    let q = vec3u(clamp(c, vec3i(0), vec3i(frame.grid_dims) - 1));
    if (frame.flags & FLAG_SPARSE) != 0u {
        let t = brick_table[brick_of(q)];
        if t == 0u || t == BRICK_MISSING {
            return MASK_MISSING;
        }
        let li = in_brick(q);
        return (grid[(t - 1u) * BRICK_WORDS + li / 4u] >> (8u * (li % 4u))) & 0xffu;
    }
    let word = grid[q.x / 4u + frame.grid_words_x * (q.y + frame.grid_dims.y * q.z)];
    return (word >> (8u * (q.x % 4u))) & 0xffu;
}

// grid_visibility's trilinear read of the dense grid: four voxels share a word along x,
// so the two x-neighbours of each (y, z) corner pair come from one word three times in
// four (5 reads instead of 8 on average). Same sums, in the same order, as the
// voxel-by-voxel read. With `codes`, the voxels' codes from the same words of
// `grid_density`: the density at their centres (without FLAG_GRID_MEDIA_FINE), and
// whether one of the 8 voxels is not filled yet (`missing`; code 0: never requested;
// only without a request pass, FLAG_FROXEL_REQUESTS).
fn dense_trilinear(base: vec3i, f: vec3f, codes: bool) -> GridVisibility {
    var vis: array<f32, 8>;
    var density = 0.0;
    var unfilled = false;
    let top = vec3i(frame.grid_dims) - 1;
    let x0 = u32(clamp(base.x, 0, top.x));
    let x1 = u32(clamp(base.x + 1, 0, top.x));
    for (var yz = 0u; yz < 4u; yz++) {
        let oy = yz & 1u;
        let oz = yz >> 1u;
        let y = u32(clamp(base.y + i32(oy), 0, top.y));
        let z = u32(clamp(base.z + i32(oz), 0, top.z));
        let row = frame.grid_words_x * (y + frame.grid_dims.y * z);
        let w0 = grid[x0 / 4u + row];
        var w1 = w0;
        if x1 / 4u != x0 / 4u {
            w1 = grid[x1 / 4u + row];
        }
        let m0 = (w0 >> (8u * (x0 % 4u))) & 0xffu;
        let m1 = (w1 >> (8u * (x1 % 4u))) & 0xffu;
        let wy = select(1.0 - f.y, f.y, oy == 1u);
        let wz = select(1.0 - f.z, f.z, oz == 1u);
        let a = (1.0 - f.x) * wy * wz;
        let b = f.x * wy * wz;
        for (var li = 0u; li < light_slots(); li++) {
            vis[li] += a * f32((m0 >> li) & 1u);
            vis[li] += b * f32((m1 >> li) & 1u);
        }
        if codes {
            let d0 = grid_density[x0 / 4u + row];
            var d1 = d0;
            if x1 / 4u != x0 / 4u {
                d1 = grid_density[x1 / 4u + row];
            }
            // Code c holds (c − 1) steps; 0: not filled.
            let k0 = (d0 >> (8u * (x0 % 4u))) & 0xffu;
            let k1 = (d1 >> (8u * (x1 % 4u))) & 0xffu;
            unfilled = unfilled || k0 == 0u || k1 == 0u;
            density += a * (max(f32(k0), 1.0) - 1.0) + b * (max(f32(k1), 1.0) - 1.0);
        }
    }
    return GridVisibility(vis, unfilled, density * frame.grid_media_unit);
}

// The grid's media density at the point whose coarse trilinear lookup is (base, f),
// from the fine cells (fine_row in common.wgsl), trilinearly: the cells' coordinates
// are g = 2 (coarse coordinate) + 0.5. Those cells lie in the lookup's 8 voxels.
struct FineLookup {
    // The lowest of the 8 cells, the weights towards the others, the last cell a side.
    base: vec3i,
    w: vec3f,
    top: vec3i,
}

fn fine_lookup(base: vec3i, f: vec3f) -> FineLookup {
    let g = 2.0 * (vec3f(base) + f) + 0.5;
    return FineLookup(vec3i(floor(g)), g - floor(g), 2 * vec3i(frame.grid_dims) - 1);
}

fn fine_density(base: vec3i, f: vec3f) -> f32 {
    let l = fine_lookup(base, f);
    let b = l.base;
    let w = l.w;
    let top = l.top;
    let x0 = u32(clamp(b.x, 0, top.x));
    let x1 = u32(clamp(b.x + 1, 0, top.x));
    var density = 0.0;
    for (var yz = 0u; yz < 4u; yz++) {
        let oy = yz & 1u;
        let oz = yz >> 1u;
        let row = fine_row(u32(clamp(b.y + i32(oy), 0, top.y)), u32(clamp(b.z + i32(oz), 0, top.z)));
        let w0 = grid_density[row + x0 / 4u];
        var w1 = w0;
        if x1 / 4u != x0 / 4u {
            w1 = grid_density[row + x1 / 4u];
        }
        let k0 = (w0 >> (8u * (x0 % 4u))) & 0xffu;
        let k1 = (w1 >> (8u * (x1 % 4u))) & 0xffu;
        let wy = select(1.0 - w.y, w.y, oy == 1u);
        let wz = select(1.0 - w.z, w.z, oz == 1u);
        density += (1.0 - w.x) * wy * wz * (max(f32(k0), 1.0) - 1.0) + w.x * wy * wz * (max(f32(k1), 1.0) - 1.0);
    }
    return density * frame.grid_media_unit;
}

// fine_density where some of the lookup's voxels are not filled yet (made_trilinear):
// a cell not filled (code 0) is evaluated here as the grid pass fills it. One loop
// over the cells, so that the media's code is compiled once.
fn made_fine_density(base: vec3i, f: vec3f) -> f32 {
    let l = fine_lookup(base, f);
    let b = l.base;
    let w = l.w;
    let top = l.top;
    var density = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let o = vec3u(k & 1u, (k >> 1u) & 1u, k >> 2u);
        let c = vec3u(clamp(b + vec3i(o), vec3i(0), top));
        var code = (grid_density[fine_row(c.y, c.z) + c.x / 4u] >> (8u * (c.x % 4u))) & 0xffu;
        if code == 0u {
            code = density_code(fine_cell_centre(c));
        }
        let wk = select(1.0 - w, w, o == vec3u(1u));
        density += wk.x * wk.y * wk.z * (max(f32(code), 1.0) - 1.0);
    }
    return density * frame.grid_media_unit;
}

// dense_trilinear where some of the 8 voxels are not filled yet: those are made here as
// the grid pass makes them (trace_voxel, density_code; their rays added to `rays`), so
// the froxel gets the value it will read once the grid has them. The same sums in the
// same order; one loop over the voxels first, so the tracing code is compiled once.
fn made_trilinear(base: vec3i, f: vec3f, rays: ptr<function, u32>) -> GridVisibility {
    var masks: array<u32, 8>;
    var codes: array<u32, 8>;
    let top = vec3i(frame.grid_dims) - 1;
    for (var k = 0u; k < 8u; k++) {
        let o = vec3i(i32(k & 1u), i32((k >> 1u) & 1u), i32(k >> 2u));
        let q = vec3u(clamp(base + o, vec3i(0), top));
        let word = q.x / 4u + frame.grid_words_x * (q.y + frame.grid_dims.y * q.z);
        var m = (grid[word] >> (8u * (q.x % 4u))) & 0xffu;
        var c = (grid_density[word] >> (8u * (q.x % 4u))) & 0xffu;
        if c == 0u {
            m = trace_voxel(q, 0xffu, rays);
            if !GRID_MEDIA_FINE {
                c = density_code(voxel_centre(q));
            }
        }
        masks[k] = m;
        codes[k] = c;
    }
    var vis: array<f32, 8>;
    var density = 0.0;
    for (var yz = 0u; yz < 4u; yz++) {
        let oy = yz & 1u;
        let oz = yz >> 1u;
        let wy = select(1.0 - f.y, f.y, oy == 1u);
        let wz = select(1.0 - f.z, f.z, oz == 1u);
        let a = (1.0 - f.x) * wy * wz;
        let b = f.x * wy * wz;
        let m0 = masks[2u * yz];
        let m1 = masks[2u * yz + 1u];
        for (var li = 0u; li < light_slots(); li++) {
            vis[li] += a * f32((m0 >> li) & 1u);
            vis[li] += b * f32((m1 >> li) & 1u);
        }
        density += a * (max(f32(codes[2u * yz]), 1.0) - 1.0) + b * (max(f32(codes[2u * yz + 1u]), 1.0) - 1.0);
    }
    return GridVisibility(vis, false, density * frame.grid_media_unit);
}

// The dense grid's trilinear lookup at `p` (with `media`, its density too). Without a
// request pass (FLAG_FROXEL_REQUESTS) a lookup that meets a voxel not filled yet
// requests it for the next frame's grid pass — the bit grid_requests.wgsl would set —
// and makes the voxels it lacks itself (made_trilinear): the same value, only slower.
fn dense_lookup(p: vec3f, media: bool, rays: ptr<function, u32>) -> GridVisibility {
    let g = grid_coord(p);
    let base = vec3i(floor(g));
    let f = g - floor(g);
    let requests_here = (frame.flags & FLAG_FROXEL_REQUESTS) != 0u;
    let fine = GRID_MEDIA_FINE;
    var gv = dense_trilinear(base, f, requests_here || (media && !fine));
    let made = gv.missing;
    if made {
        if requests_here {
            let bit = lookup_request_bit(base, true);
            atomicOr(&requests[bit.x], bit.y);
        }
        gv = made_trilinear(base, f, rays);
    }
    if media && fine {
        if made {
            gv.density = made_fine_density(base, f);
        } else {
            gv.density = fine_density(base, f);
        }
    }
    return gv;
}

struct GridVisibility {
    vis: array<f32, 8>,
    // Some voxel read was not in the (sparse) grid: trace rays instead (dense grids make
    // such voxels in place, dense_lookup).
    missing: bool,
    // The grid's media density at the point (dense_trilinear with `media`; else 0).
    density: f32,
}

// Visibility of each light at p from the shared grid.
fn grid_visibility(p: vec3f, rays: ptr<function, u32>) -> GridVisibility {
    var vis: array<f32, 8>;
    let g = grid_coord(p);
    if (frame.flags & FLAG_TRILINEAR) == 0u {
        let m = grid_mask(vec3i(floor(g + 0.5)));
        for (var li = 0u; li < light_slots(); li++) {
            vis[li] = f32((m >> li) & 1u);
        }
        return GridVisibility(vis, m == MASK_MISSING, 0.0);
    }
    var missing = false;
    let base = vec3i(floor(g));
    let f = g - floor(g);
    if (frame.flags & FLAG_SPARSE) == 0u {
        return dense_lookup(p, false, rays);
    }
    for (var k = 0u; k < 8u; k++) {
        let o = vec3i(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
        let w3 = select(1.0 - f, f, vec3<bool>(o == vec3i(1)));
        let w = w3.x * w3.y * w3.z;
        let m = grid_mask(base + o);
        missing = missing || m == MASK_MISSING;
        for (var li = 0u; li < light_slots(); li++) {
            vis[li] += w * f32((m >> li) & 1u);
        }
    }
    return GridVisibility(vis, missing, 0.0);
}

// Light li's visibility at fog point p from its shared map (2×2 PCF, one texel towards
// the light): `maps`' lookup, and `shared`'s with `froxel_maps` or at a grid edge.
fn fog_map_visibility(li: u32, p: vec3f) -> f32 {
    let l = lights[li];
    return map_visibility(li, l, p, to_light(l, p).xyz, 1.0);
}

// The grid's media at density 1 (FLAG_GRID_MEDIA; else none), read once per column: a
// froxel scales it by the grid's density. Read per froxel, the medium's record (128
// bytes) cost lavapipe 12 % of the stage (docs/decisions.md, "Per-frame records read
// once per column").
fn grid_medium_unit() -> MediumSample {
    if (frame.flags & FLAG_GRID_MEDIA) == 0u {
        return MediumSample(vec3f(0.0), 0.0, vec3f(0.0), 0.0);
    }
    let gm = media[frame.grid_media_first];
    return MediumSample(gm.scattering, medium_extinction(gm), gm.emission, gm.g);
}

// The radiance source and extinction of froxel (xy, slice) of view `v` at `p`, seen
// along `dir` (the column's view ray), `grid_unit` the grid's media at density 1
// (`grid_medium_unit`); adds the shadow rays it traced to `rays`.
fn light_froxel(v: View, xy: vec2u, slice: u32, p: vec3f, dir: vec3f, grid_unit: MediumSample, rays: ptr<function, u32>) -> vec4f {
    // With the media's density in the grid, a froxel inside their box that reads the
    // grid takes light bits and density from the same words (the other media, if any,
    // analytically); the rest evaluate the media.
    let from_grid = (frame.flags & FLAG_GRID_MEDIA) != 0u && slice >= frame.frustum_slices
        && all(p >= frame.grid_media_min) && all(p <= frame.grid_media_max);
    var m: MediumSample;
    var gv: GridVisibility;
    if from_grid {
        gv = dense_lookup(p, true, rays);
        let d = gv.density;
        let grid_part = MediumSample(grid_unit.scattering * d, grid_unit.extinction * d, grid_unit.emission * d, grid_unit.g);
        m = combine_media(grid_part, sample_media_where(p, 0u));
    } else {
        m = media_at(p);
    }
    if m.extinction <= 0.0 && all(m.emission <= vec3f(0.0)) {
        return vec4f(0.0);
    }
    var vis: array<f32, 8>;
    var trace = (frame.flags & (FLAG_SHARED | FLAG_MAPS)) == 0u;
    if trace {
        // reference: traced below
    } else if (frame.flags & FLAG_MAPS) != 0u {
        // maps: every froxel reads the shared shadow maps (2×2 PCF, one texel towards
        // the light); a light without a map traces.
        for (var li = 0u; li < light_count(); li++) {
            let l = lights[li];
            vis[li] = 0.0;
            if all(light_radiance(l, p) == vec3f(0.0)) {
                continue;
            }
            if has_map(li) {
                vis[li] = fog_map_visibility(li, p);
            } else {
                *rays += 1u;
                vis[li] = select(0.0, 1.0, light_visible(l, p));
            }
        }
    } else {
        // shared: the lights with a map read it where FLAG_FROXEL_MAPS asks, the others
        // the shadow frustum (near slices) or the grid, whose shadow edges read the map
        // where FLAG_MAP_EDGES asks.
        var mapped = 0u;
        if (frame.flags & FLAG_FROXEL_MAPS) != 0u {
            for (var li = 0u; li < light_count(); li++) {
                if has_map(li) {
                    mapped |= 1u << li;
                    vis[li] = 0.0;
                    if any(light_radiance(lights[li], p) != vec3f(0.0)) {
                        vis[li] = fog_map_visibility(li, p);
                    }
                }
            }
        }
        if mapped != (1u << light_count()) - 1u {
            var other: array<f32, 8>;
            if slice < frame.frustum_slices {
                let fx = min(xy.x * v.froxel_px / v.frustum_px, v.frustum_dims.x - 1u);
                let fy = min(xy.y * v.froxel_px / v.frustum_px, v.frustum_dims.y - 1u);
                let mask = frustum[v.frustum_base + fx + v.frustum_dims.x * (fy + v.frustum_dims.y * slice)];
                for (var li = 0u; li < light_slots(); li++) {
                    other[li] = f32((mask >> li) & 1u);
                }
            } else {
                if !from_grid {
                    gv = grid_visibility(p, rays);
                }
                other = gv.vis;
                trace = gv.missing;
                // Where the voxels around p disagree, a shadow edge runs between them:
                // the map resolves it (FLAG_MAP_EDGES).
                if (frame.flags & FLAG_MAP_EDGES) != 0u {
                    for (var li = 0u; li < light_count(); li++) {
                        if other[li] > 0.0 && other[li] < 1.0 && has_map(li) {
                            other[li] = fog_map_visibility(li, p);
                        }
                    }
                }
            }
            for (var li = 0u; li < light_slots(); li++) {
                if ((mapped >> li) & 1u) == 0u {
                    vis[li] = other[li];
                }
            }
        }
    }
    if trace {
        for (var li = 0u; li < light_count(); li++) {
            let l = lights[li];
            vis[li] = 0.0;
            if all(light_radiance(l, p) == vec3f(0.0)) {
                continue;
            }
            *rays += 1u;
            vis[li] = select(0.0, 1.0, light_visible(l, p));
        }
    }
    // Stored as the source radiance S/σt (what an optically thick froxel converges to),
    // which stays within f16 range for σt up to 10⁴ m⁻¹.
    let s_rgb = in_scattering(m, p, dir, vis);
    return vec4f(min(s_rgb / max(m.extinction, SIGMA_EPS), vec3f(6.0e4)), m.extinction);
}

// Temporal reprojection: `out` blended with last frame's froxel at the same world point
// `p`; a non-finite history is discarded, never propagated.
fn blend_history(v: View, p: vec3f, out: vec4f) -> vec4f {
    let prev = v.prev_view_proj * vec4f(p, 1.0);
    if prev.w <= 0.0 {
        return out;
    }
    let ndc = prev.xyz / prev.w;
    let px = vec2f(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5) * vec2f(v.size) / f32(v.froxel_px);
    let s = depth_to_slice(v, prev.w);
    // A coupled eye's history holds its near field only (v.light_slices).
    if all(px >= vec2f(0.0)) && all(px < vec2f(v.froxel_dims)) && s >= 0.0 && s < f32(v.light_slices) {
        let hi = v.history_base + u32(px.x) + v.froxel_dims.x * (u32(px.y) + v.froxel_dims.y * u32(s));
        let h = unpack_rgba16(history[hi]);
        if all(abs(h) < vec4f(6.0e4)) {
            return mix(out, h, 0.9);
        }
    }
    return out;
}

// One invocation per froxel column (z runs over viewers), front to back: the view, its
// ray and the column's cull limit are read once, not once per froxel.
@compute @workgroup_size(8, 8, 1)
fn main(
    @builtin(global_invocation_id) invocation: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    var rays = 0u;
    var lit = 0u;
    let gid = column_slot(invocation, wg, n);
    let view_index = gid.z;
    if view_index < frame.view_count {
        let v = volume_of(views[view_index]);
        // A coupled stereo eye lights its near field only, or nothing (v.light_slices).
        if gid.x < v.froxel_dims.x && gid.y < v.froxel_dims.y && v.light_slices > 0u {
            // Slices behind every surface this column shows never reach the image: they
            // are neither lit nor written, and the integration stops there too
            // (FLAG_CULL, which no temporal history comes with).
            var last = v.light_slices - 1u;
            if (frame.flags & FLAG_CULL) != 0u {
                last = min(last, column_limit[column_index(v, view_index, gid.x, gid.y)]);
            }
            let dir = froxel_ray(v, gid.xy);
            let grid_unit = grid_medium_unit();
            for (var slice = 0u; slice <= last; slice++) {
                let p = froxel_point(v, dir, slice);
                var out = light_froxel(v, gid.xy, slice, p, dir, grid_unit, &rays);
                lit += select(0u, 1u, out.w > 0.0 || any(out.rgb > vec3f(0.0)));
                if v.history_base != NO_HISTORY {
                    out = blend_history(v, p, out);
                }
                froxels[v.froxel_base + gid.x + v.froxel_dims.x * (gid.y + v.froxel_dims.y * slice)] = pack_rgba16(out);
            }
        }
    }
    count(C_LIGHTING_RAYS, rays);
    count(C_FROXELS_WITH_MEDIA, lit);
}
