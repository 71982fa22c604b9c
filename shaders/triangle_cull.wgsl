// Per-view triangle culling before the G-buffer raster (`triangle_cull`): of every
// (view, cluster) pair whose cluster box the view's frustum touches, the triangles the
// raster would draw nothing of are dropped — outside one clip plane, back faces of
// one-sided meshes, and triangles whose screen box holds no pixel centre (they cover
// no sample, so the raster makes no fragment of them) — and the rest are written, in
// their order, into the view's own index list, drawn with one indirect draw. Two passes:
// `cull` marks and counts each pair's triangles, `compact` writes them after the counts
// of the view's earlier pairs. The order is the scene's, so the picture is the one the
// unculled draw gives, depth ties included.
//
// With `occlusion_cull` the raster runs in two phases (two-phase occlusion culling, as
// GPU-driven engines do it): `cull` puts in the first list only the kept triangles that
// were visible in this view last frame; after they are drawn, shaders/hiz.wgsl builds a
// pyramid of their farthest depths, and `occlude` tests every kept triangle against
// it: a triangle nearer than that somewhere in its screen box is visible (next frame's
// first list), and the visible ones not drawn yet make the second list. A triangle
// dropped there lies behind surfaces drawn this frame at every pixel centre it covers,
// so the picture is the one drawing it gives (up to depth ties between the two lists).
//
// With `micro_raster` (one phase only), `cull` rasterises the small triangles itself —
// those whose screen box holds at most 4 × 4 pixel centres, all corners in front of the
// eye — instead of listing them: each centre the triangle covers gets the nearest
// (depth, triangle) by a 64-bit atomicMax (`micro_put`, prepended: shaders/
// micro_atomic.wgsl), and shaders/micro_resolve.wgsl writes the G-buffer texels where
// such a triangle lies nearer than what the raster drew.

// RasterView: shaders/raster_view.wgsl.
@group(0) @binding(0) var<storage, read> views: array<RasterView>;
// Raster vertices: position bits and packed albedo (src/render/scene_gpu.rs).
@group(0) @binding(1) var<storage, read> vertices: array<vec4u>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;
// Per cluster: first index, index count, cull (0 none, 1 back faces, 2 front faces), 0.
@group(0) @binding(3) var<storage, read> clusters: array<vec4u>;
// Per pair: view, cluster, the view's first pair, 0. A view's pairs are consecutive.
@group(0) @binding(4) var<storage, read> pairs: array<vec4u>;
// Three regions of `params[0].y` words, each PAIR_WORDS words per pair (the count, then
// MASK_WORDS masks per lane): the triangles kept, those of the first list, those of
// the second (`occlusion_cull`).
@group(0) @binding(5) var<storage, read_write> kept: array<u32>;
@group(0) @binding(6) var<storage, read_write> out_indices: array<u32>;
// Per view: DrawIndexedIndirect (index count, instances, first index, base vertex,
// first instance) of the first list, then of every view's second list.
@group(0) @binding(7) var<storage, read_write> args: array<u32>;
// [0]: this frame's pairs (the pair buffer is longer), a region's words, the scene's
// clusters, the frame's views; [1].x: which list `compact` writes (0 first, 1 second),
// [1].y: 1 with `occlusion_cull`, [1].z: 1 with `micro_raster`.
@group(0) @binding(8) var<uniform> params: array<vec4u, 2>;
// The frame's counters (common.wgsl's C_*): the triangles kept, summed over views.
@group(0) @binding(9) var<storage, read_write> counters: array<atomic<u32>>;
const C_RASTER_TRIANGLES: u32 = 12u;
// Per view and cluster, 32 words: which of its triangles the view saw last frame (a
// triangle `occlude` found nearer than the depths drawn around it).
@group(0) @binding(10) var<storage, read_write> visible: array<u32>;
// Per view, from its RasterView.hiz_base: the pyramid of the farthest view depths drawn
// in the first phase (shaders/hiz.wgsl; no surface: 3e38).
@group(0) @binding(11) var<storage, read> hiz: array<f32>;

// One subgroup per pair, no workgroup barrier (llvmpipe runs barrier-free compute as
// straight SIMD loops): LANES lanes, each PER_LANE consecutive triangles of the pair's
// cluster (LANES × PER_LANE = the 1024 of a cluster). Needs subgroups of LANES or more.
const LANES: u32 = 8u;
const PER_LANE: u32 = 128u;
const MASK_WORDS: u32 = 4u; // PER_LANE / 32
const PAIR_WORDS: u32 = 33u; // the count, then MASK_WORDS per lane
const CULL_BACK: u32 = 1u;
const CULL_FRONT: u32 = 2u;

fn pair_index(wg: vec3u, n: vec3u) -> u32 {
    return wg.x + wg.y * n.x;
}

fn corner(view_proj: mat4x4f, i: u32) -> vec4f {
    return view_proj * vec4f(bitcast<vec3f>(vertices[i].xyz), 1.0);
}

// How far the raster may move a corner when it snaps it to its sub-pixel grid, in
// pixels: the tests below grow by it. Rasterisers with 8 sub-pixel bits (llvmpipe, and
// the minimum D3D12 requires) move a corner by at most 1/512 pixel; 1/64 is 8 times
// that. Vulkan's minimum, 4 bits, could move one by 1/32: an adapter that coarse could
// draw a pixel that these tests decide it does not.
const SNAP_PX: f32 = 1.0 / 64.0;

// Whether screen-space triangle (a, b, c) (pixels, y down), whose corners and the point
// `p` lie within distance `d` of each other, may cover `p` once the raster has snapped
// its corners: `p` on the inner side of each edge, or outside it by no more than a snap
// of SNAP_PX can move the edge at `p`. Moving a and b by at most δ changes the edge
// function (b − a) × (p − a) by at most δ·(2|p − a| + |b − a|) + 2δ² ≤ 3δd + 2δ², and
// the doubled area by as much. A triangle of (nearly) no area counts as covering.
fn may_cover(a: vec2f, b: vec2f, c: vec2f, p: vec2f, d: f32) -> bool {
    let slack = SNAP_PX * (3.0 * d + 2.0 * SNAP_PX);
    let area = cross2(b - a, c - a);
    if abs(area) <= slack {
        return true;
    }
    let e = sign(area) * vec3f(cross2(b - a, p - a), cross2(c - b, p - b), cross2(a - c, p - c));
    return all(e >= vec3f(-slack));
}

fn cross2(u: vec2f, v: vec2f) -> f32 {
    return u.x * v.y - u.y * v.x;
}

// Whether the screen-space triangle (a, b, c) may cover any pixel centre k + 0.5 with k
// in [lo, hi] (a box of at most 2 × 2 centres; larger boxes count as covered).
fn covers_a_centre(a: vec2f, b: vec2f, c: vec2f, lo: vec2f, hi: vec2f) -> bool {
    if any(hi - lo > vec2f(1.0)) {
        return true;
    }
    // Corners and centres lie within the box grown by SNAP_PX.
    let d = length(max(max(a, b), max(c, hi + 0.5)) - min(min(a, b), min(c, lo + 0.5)));
    for (var q = 0u; q < 4u; q++) {
        let k = lo + vec2f(f32(q & 1u), f32(q >> 1u));
        if all(k <= hi) && may_cover(a, b, c, k + 0.5, d) {
            return true;
        }
    }
    return false;
}

// What becomes of a triangle: dropped, listed for the raster, or rasterised here.
const DROPPED: u32 = 0u;
const LISTED: u32 = 1u;
const MICRO: u32 = 2u;

// Sub-pixel steps a pixel of the raster's grid (8 bits, as llvmpipe and D3D12 snap).
const SUBPIXELS: f32 = 256.0;

// Whether a pixel centre exactly on the edge from u to v (screen space, y down, the
// triangle wound so that its inside is on the edges' positive side) is covered: the
// top-left rule (a horizontal edge with the inside below it, or an edge going up).
fn top_left(u: vec2f, v: vec2f) -> bool {
    let d = v - u;
    return (d.y == 0.0 && d.x > 0.0) || d.y < 0.0;
}

// Whether the edge from u to v covers centre q (all relative to q, in sub-pixel steps).
fn edge_covers(u: vec2f, v: vec2f) -> bool {
    let e = cross2(v - u, -u);
    return e > 0.0 || (e == 0.0 && top_left(u, v));
}

// `micro_raster`: rasterises triangle `t` (screen corners sa, sb, sc in pixels; clip z
// over w `zw`, all w > 0) at the pixel centres k + 0.5 of view `v` for k in [k0, k1]:
// a centre is covered as the raster decides it, the corners snapped to 1/256 pixel
// and the top-left rule on edges through it; its depth is the clip depth interpolated
// there, kept where 0 ≤ z ≤ 1 (the raster clips the rest). Whether it covered one.
fn micro_raster(v: RasterView, t: u32, sa: vec2f, sb: vec2f, sc: vec2f, zw: vec3f, k0: vec2f, k1: vec2f) -> bool {
    let lo = max(k0, vec2f(0.0));
    let hi = min(k1, v.size - 1.0);
    let snapped_a = round(sa * SUBPIXELS);
    var snapped_b = round(sb * SUBPIXELS);
    var snapped_c = round(sc * SUBPIXELS);
    // Relative to a centre and in steps, every product below is an exact integer in f32
    // (a box of 4 × 4 centres plus snap: |coordinates| < 2^11, products < 2^23).
    let area = cross2(snapped_b - snapped_a, snapped_c - snapped_a);
    if area == 0.0 {
        return false;
    }
    if area < 0.0 {
        let s = snapped_b;
        snapped_b = snapped_c;
        snapped_c = s;
    }
    // Screen-space barycentrics of a, b, c (unsnapped, as the raster's interpolation).
    let inv = 1.0 / cross2(sb - sa, sc - sa);
    var covered = false;
    for (var y = lo.y; y <= hi.y; y += 1.0) {
        for (var x = lo.x; x <= hi.x; x += 1.0) {
            let q = vec2f(x, y) + 0.5;
            let qs = q * SUBPIXELS;
            let a = snapped_a - qs;
            let b = snapped_b - qs;
            let c = snapped_c - qs;
            if edge_covers(a, b) && edge_covers(b, c) && edge_covers(c, a) {
                let l = vec3f(cross2(sc - sb, q - sb), cross2(sa - sc, q - sc), cross2(sb - sa, q - sa)) * inv;
                let z = dot(l, zw);
                if z >= 0.0 && z <= 1.0 {
                    micro_put(v.micro_base + u32(x) + u32(v.size.x) * u32(y), max(z, 0.0), t);
                    covered = true;
                }
            }
        }
    }
    return covered;
}

// Whether the raster can draw any fragment of triangle `t` (vertices ia, ib, ic) in
// view `v` with cull mode `cull` (LISTED), or not (DROPPED); with `micro`, a small one
// is rasterised here instead (MICRO if it covered a pixel centre, else DROPPED).
// Conservative: a triangle reaching behind the eye plane skips the pixel-centre test
// (the raster clips it), and the screen box grows by 1/64 pixel for the raster's
// sub-pixel snapping.
fn drawn(v: RasterView, t: u32, ia: u32, ib: u32, ic: u32, cull: u32, micro: bool) -> u32 {
    let view_proj = v.view_proj;
    let size = v.size;
    let a = corner(view_proj, ia);
    let b = corner(view_proj, ib);
    let c = corner(view_proj, ic);
    let x = vec3f(a.x, b.x, c.x);
    let y = vec3f(a.y, b.y, c.y);
    let z = vec3f(a.z, b.z, c.z);
    let w = vec3f(a.w, b.w, c.w);
    if all(x < -w) || all(x > w) || all(y < -w) || all(y > w) || all(z < vec3f(0.0)) || all(z > w) {
        return DROPPED;
    }
    // The side the eye sees: the sign of det(x, y, w) (Olano and Greer's homogeneous
    // rasterisation), right for corners behind the eye too, which the raster clips away:
    // the part it keeps winds the same way. With every w > 0 it is the sign of the
    // projected area, counter-clockwise on screen (y up) the front.
    let det = dot(vec3f(a.x, a.y, a.w), cross(vec3f(b.x, b.y, b.w), vec3f(c.x, c.y, c.w)));
    if (cull == CULL_BACK && det < 0.0) || (cull == CULL_FRONT && det > 0.0) {
        return DROPPED;
    }
    if any(w <= vec3f(1e-6)) {
        return LISTED;
    }
    let sa = (vec2f(a.x, -a.y) / a.w * 0.5 + 0.5) * size;
    let sb = (vec2f(b.x, -b.y) / b.w * 0.5 + 0.5) * size;
    let sc = (vec2f(c.x, -c.y) / c.w * 0.5 + 0.5) * size;
    let lo = min(sa, min(sb, sc)) - SNAP_PX;
    let hi = max(sa, max(sb, sc)) + SNAP_PX;
    // The pixel centres k + 0.5 in [lo, hi], along each axis.
    let k0 = ceil(lo - 0.5);
    let k1 = floor(hi - 0.5);
    if any(k0 > k1) {
        return DROPPED;
    }
    if micro && all(k1 - k0 <= vec2f(3.0)) {
        return select(DROPPED, MICRO, micro_raster(v, t, sa, sb, sc, z / w, k0, k1));
    }
    // A small triangle's box may hold a centre the triangle misses.
    return select(DROPPED, LISTED, covers_a_centre(sa, sb, sc, k0, k1));
}

@compute @workgroup_size(8)
fn cull(@builtin(workgroup_id) wg: vec3u, @builtin(num_workgroups) n: vec3u, @builtin(local_invocation_index) lane: u32) {
    let p = pair_index(wg, n);
    if p >= params[0].x {
        return;
    }
    let pair = pairs[p];
    let v = views[pair.x];
    let c = clusters[pair.y];
    let triangles = c.y / 3u;
    let occlusion = params[1].y == 1u;
    let micro = params[1].z == 1u;
    var first_here = 0u;
    var micro_here = 0u;
    for (var w = 0u; w < MASK_WORDS; w++) {
        var bits = 0u;
        for (var k = 0u; k < 32u; k++) {
            let t = lane * PER_LANE + w * 32u + k;
            if t < triangles {
                let i = c.x + 3u * t;
                let fate = drawn(v, i / 3u, indices[i], indices[i + 1u], indices[i + 2u], c.z, micro);
                if fate == LISTED {
                    bits |= 1u << k;
                }
                micro_here += select(0u, 1u, fate == MICRO);
            }
        }
        let m = mask_word(p, lane, w);
        kept[m] = bits;
        // The first list: every kept triangle, or with occlusion culling those the view
        // saw last frame.
        var first = bits;
        if occlusion {
            first &= visible[visible_word(pair, lane, w)];
        }
        kept[params[0].y + m] = first;
        first_here += countOneBits(first);
    }
    let total = subgroupAdd(first_here);
    // The triangles rasterised here count as drawn.
    let micro_total = subgroupAdd(micro_here);
    if lane == 0u {
        kept[params[0].y + p * PAIR_WORDS] = total;
        atomicAdd(&counters[C_RASTER_TRIANGLES], total + micro_total);
    }
}

// Word `w` of lane `lane`'s mask of pair `p` in the first region.
fn mask_word(p: u32, lane: u32, w: u32) -> u32 {
    return p * PAIR_WORDS + 1u + lane * MASK_WORDS + w;
}

// The word of `visible` holding the same triangles as mask word (lane, w) of `pair`.
fn visible_word(pair: vec4u, lane: u32, w: u32) -> u32 {
    return (pair.x * params[0].z + pair.y) * (LANES * MASK_WORDS) + lane * MASK_WORDS + w;
}

// Whether the triangle (ia, ib, ic), which `drawn` keeps, lies behind the depths drawn
// in view `v`'s first phase at every pixel centre its screen box holds: its nearest
// corner farther than the farthest depth of the 2 × 2 tiles of the finest pyramid level
// whose tiles the box fits in; at the pixels' level (a box of at most 2 × 2 centres),
// than the depth of each centre the triangle may cover (`may_cover`). Boxes wider than
// two of the top level's tiles, and triangles reaching behind the eye, count as visible.
fn occluded(v: RasterView, ia: u32, ib: u32, ic: u32) -> bool {
    let a = corner(v.view_proj, ia);
    let b = corner(v.view_proj, ib);
    let c = corner(v.view_proj, ic);
    // Clip w is the view depth (what the G-buffer keeps).
    let near = min(a.w, min(b.w, c.w));
    if near <= 1e-6 {
        return false;
    }
    let sa = (vec2f(a.x, -a.y) / a.w * 0.5 + 0.5) * v.size;
    let sb = (vec2f(b.x, -b.y) / b.w * 0.5 + 0.5) * v.size;
    let sc = (vec2f(c.x, -c.y) / c.w * 0.5 + 0.5) * v.size;
    let lo_f = max(ceil(min(sa, min(sb, sc)) - SNAP_PX - 0.5), vec2f(0.0));
    let hi_f = min(floor(max(sa, max(sb, sc)) + SNAP_PX - 0.5), v.size - 1.0);
    if any(lo_f > hi_f) {
        return false;
    }
    let lo = vec2u(lo_f);
    let hi = vec2u(hi_f);
    var k = 0u;
    while k <= HIZ_LEVELS && any((hi >> vec2u(k)) - (lo >> vec2u(k)) > vec2u(1u)) {
        k++;
    }
    if k > HIZ_LEVELS {
        return false;
    }
    if k == 0u {
        // At most 2 × 2 centres: behind the depth drawn at each centre it may cover.
        let o = hiz_offset(v, 0u);
        let cols = hiz_dims(v, 0u).x;
        let d = length(max(max(sa, sb), max(sc, hi_f + 0.5)) - min(min(sa, sb), min(sc, lo_f + 0.5)));
        for (var q = 0u; q < 4u; q++) {
            let px = lo + vec2u(q & 1u, q >> 1u);
            if all(px <= hi) && may_cover(sa, sb, sc, vec2f(px) + 0.5, d) && near <= hiz[o + px.x + cols * px.y] * (1.0 + 1e-4) {
                return false;
            }
        }
        return true;
    }
    let t0 = lo >> vec2u(k);
    let t1 = hi >> vec2u(k);
    let o = hiz_offset(v, k);
    let cols = hiz_dims(v, k).x;
    let farthest = max(
        max(hiz[o + t0.x + cols * t0.y], hiz[o + t1.x + cols * t0.y]),
        max(hiz[o + t0.x + cols * t1.y], hiz[o + t1.x + cols * t1.y]),
    );
    return near > farthest * (1.0 + 1e-4);
}

// `occlusion_cull`'s second pass, after the first list is drawn and shaders/hiz.wgsl
// took its depths: every kept triangle of the pair is tested against them. The visible
// ones are the view's first list next frame; those of them not drawn yet are the second
// list (third region).
@compute @workgroup_size(8)
fn occlude(@builtin(workgroup_id) wg: vec3u, @builtin(num_workgroups) n: vec3u, @builtin(local_invocation_index) lane: u32) {
    let p = pair_index(wg, n);
    if p >= params[0].x {
        return;
    }
    let pair = pairs[p];
    let v = views[pair.x];
    let c = clusters[pair.y];
    var second_here = 0u;
    for (var w = 0u; w < MASK_WORDS; w++) {
        let m = mask_word(p, lane, w);
        let candidates = kept[m];
        let vw = visible_word(pair, lane, w);
        let drawn_first = kept[params[0].y + m];
        var seen = 0u;
        var bits = candidates;
        while bits != 0u {
            let k = firstTrailingBit(bits);
            bits &= bits - 1u;
            let i = c.x + 3u * (lane * PER_LANE + w * 32u + k);
            if !occluded(v, indices[i], indices[i + 1u], indices[i + 2u]) {
                seen |= 1u << k;
            }
        }
        visible[vw] = seen;
        let second = seen & ~drawn_first;
        kept[2u * params[0].y + m] = second;
        second_here += countOneBits(second);
    }
    let total = subgroupAdd(second_here);
    if lane == 0u {
        kept[2u * params[0].y + p * PAIR_WORDS] = total;
        atomicAdd(&counters[C_RASTER_TRIANGLES], total);
    }
}

@compute @workgroup_size(8)
fn compact(@builtin(workgroup_id) wg: vec3u, @builtin(num_workgroups) n: vec3u, @builtin(local_invocation_index) lane: u32) {
    let p = pair_index(wg, n);
    if p >= params[0].x {
        return;
    }
    let pair = pairs[p];
    let c = clusters[pair.y];
    // The list written: the first (second region), or the second (third region), which
    // follows the first in the view's part of the index buffer.
    let second = params[1].x == 1u;
    let region = select(1u, 2u, second) * params[0].y;
    // Triangles kept by the view's earlier pairs.
    var before = 0u;
    for (var q = pair.z + lane; q < p; q += LANES) {
        before += kept[region + q * PAIR_WORDS];
    }
    let earlier = subgroupAdd(before);
    var here = 0u;
    for (var w = 0u; w < MASK_WORDS; w++) {
        here += countOneBits(kept[region + mask_word(p, lane, w)]);
    }
    // This lane's first slot: after the earlier pairs and this pair's lower lanes.
    var at = earlier + subgroupExclusiveAdd(here);
    let end = earlier + subgroupAdd(here);
    var base = args[5u * pair.x + 2u];
    var draw = 5u * pair.x;
    if second {
        base += args[5u * pair.x];
        draw = 5u * (params[0].w + pair.x);
    }
    for (var w = 0u; w < MASK_WORDS; w++) {
        var bits = kept[region + mask_word(p, lane, w)];
        while bits != 0u {
            let k = firstTrailingBit(bits);
            bits &= bits - 1u;
            let i = c.x + 3u * (lane * PER_LANE + w * 32u + k);
            out_indices[base + 3u * at] = indices[i];
            out_indices[base + 3u * at + 1u] = indices[i + 1u];
            out_indices[base + 3u * at + 2u] = indices[i + 2u];
            at += 1u;
        }
    }
    // The view's last pair knows its total: the draw's index count.
    let last = p + 1u == params[0].x || pairs[p + 1u].x != pair.x;
    if lane == 0u && last {
        args[draw] = 3u * end;
        args[draw + 2u] = base;
    }
}
