// Stage 4 (000 §3.1.4): front-to-back integration of every froxel column, all viewers
// in one dispatch. Energy-conserving form (Hillaire 2015):
//   S_int = (S − S·exp(−σt·d)) / σt, with the σt → 0 limit S·d taken explicitly.
// Froxels hold src = S / max(σt, SIGMA_EPS), so S_int = src·(1 − exp(−σt·d)).
// integrated[s] holds (in-scattered rgb, transmittance) from the eye to the far
// boundary of slice s.

@group(1) @binding(0) var<storage, read> froxels: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> integrated: array<vec2u>;
// The last slice each column must integrate (FLAG_CULL; shaders/froxel_cull.wgsl): no
// pixel reads past it, and the froxels past it were not lit.
@group(1) @binding(2) var<storage, read> column_limit: array<u32>;

// Pixel coordinate, along one axis of `size` pixels, of froxel column `i`'s ray
// (`froxel_ray`: the column's centre, the last pixel's centre past the view's edge).
fn column_pixel(i: f32, froxel_px: f32, size: f32) -> f32 {
    return min((i + 0.5) * froxel_px, size - 0.5);
}

// The two columns along one axis whose rays bracket pixel coordinate `pix`, and the
// weight of the second; within 10⁻³ of a column's ray it is that column alone.
fn bracket(pix: f32, froxel_px: f32, size: f32, count: f32) -> vec3f {
    let c0 = clamp(floor(pix / froxel_px - 0.5), 0.0, count - 1.0);
    let c1 = min(c0 + 1.0, count - 1.0);
    let a = column_pixel(c0, froxel_px, size);
    let b = column_pixel(c1, froxel_px, size);
    var f = select(0.0, clamp((pix - a) / (b - a), 0.0, 1.0), b > a);
    f = select(f, 0.0, f < 1e-3);
    f = select(f, 1.0, f > 1.0 - 1e-3);
    return vec3f(c0, c1, f);
}

// Where a column's froxels project in its partner's view `o`, slice by slice. The eyes
// look the same way with the same projection, so a point at view depth z on the column's
// ray, pixel `pix` in its own view, lies at pixel c + (z·(pix − c) + k) / (z + dz) in
// `o`'s (c the views' centre; k, dz from the offset between the eyes): one reciprocal a
// slice, where projecting the world point costs a vector's worth of dot products.
struct PartnerProjection {
    centred: vec2f, // pix − c
    k: vec2f,
    dz: f32,
}

fn partner_projection(v: View, o: View, pix: vec2f) -> PartnerProjection {
    let d = v.position - o.position;
    let c = 0.5 * vec2f(o.size);
    let k = c * vec2f(dot(d, o.right) / o.tan_x, -dot(d, o.up) / o.tan_y);
    return PartnerProjection(pix - c, k, dot(d, o.forward));
}

// `pixel_of(o, p)` for the column's point at view depth `z`.
fn partner_pixel(o: View, pp: PartnerProjection, z: f32) -> vec2f {
    return 0.5 * vec2f(o.size) + (z * pp.centred + pp.k) / max(z + pp.dz, o.near);
}

// Froxel (src rgb, σt) of slice `s` at pixel `pix` of view `o`'s froxels: a
// coupled stereo eye's far slice, read from its partner (the eyes look the same way with
// the same slices, so both froxels lie on one depth plane), bilinear between the four
// columns whose rays bracket `pix`. S = src·σt and σt are interpolated, not
// src, so a froxel half in a medium takes half of its in-scattering. On a column's ray
// (zero disparity) it is that froxel, exactly.
fn partner_froxel(o: View, pix: vec2f, s: u32) -> vec4f {
    let fp = f32(o.froxel_px);
    let bx = bracket(pix.x, fp, f32(o.size.x), f32(o.froxel_dims.x));
    let by = bracket(pix.y, fp, f32(o.size.y), f32(o.froxel_dims.y));
    let cols = Columns(vec2f(bx.x, by.x), vec2f(bx.y, by.y), vec2f(bx.z, by.z));
    let slice = o.froxel_base + o.froxel_dims.x * o.froxel_dims.y * s;
    if all(fract(cols.f) == vec2f(0.0)) {
        let c = column_corner(cols, select(0u, 1u, cols.f.x > 0.5) | select(0u, 2u, cols.f.y > 0.5));
        return unpack_rgba16(froxels[slice + c.x + o.froxel_dims.x * c.y]);
    }
    var scattering = vec3f(0.0);
    var sigma_t = 0.0;
    for (var k = 0u; k < 4u; k++) {
        let w = column_weight(cols, k);
        // A stereo pair's eyes lie on one row: its rows' weights are 0 and 1, so only
        // two of the four columns are read.
        if w == 0.0 {
            continue;
        }
        let c = column_corner(cols, k);
        let f = unpack_rgba16(froxels[slice + c.x + o.froxel_dims.x * c.y]);
        scattering += w * f.rgb * max(f.w, SIGMA_EPS);
        sigma_t += w * f.w;
    }
    return vec4f(scattering / max(sigma_t, SIGMA_EPS), sigma_t);
}

// Every view integrates its own columns: its own froxels for the slices it lit
// (v.light_slices: all of them but for a coupled stereo eye) and, beyond, its partner's
// (v.volume_view) where its froxels' points project, so that both eyes' fog is
// integrated along their own rays while the far froxels are lit once. With culling, a
// column stops at its limit; the slices past it keep what an earlier frame left there.
@compute @workgroup_size(8, 8, 1)
fn main(
    @builtin(global_invocation_id) invocation: vec3u,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) n: vec3u,
) {
    let gid = column_slot(invocation, wg, n);
    let view_index = gid.z;
    if view_index >= frame.view_count {
        return;
    }
    let v = views[view_index];
    if gid.x >= v.froxel_dims.x || gid.y >= v.froxel_dims.y {
        return;
    }
    let o = volume_of(views[v.volume_view]);
    // A stereo head's first eye lit the head's volume: it reads it as its partner would.
    let own = select(0u, v.light_slices, volume_on_own_rays(v));
    let pix = froxel_pixel(v, gid.xy);
    let dir = view_ray(v, pix);
    let pp = partner_projection(v, o, pix);
    let inv_cos = 1.0 / dot(dir, v.forward);
    var scattered = vec3f(0.0);
    var transmittance = 1.0;
    var z0 = v.near;
    var end = frame.slices;
    if (frame.flags & FLAG_CULL) != 0u {
        // A coupled eye without a near field has no limit of its own: its partner's
        // covers the eye's tiles ±2 (shaders/froxel_cull.wgsl), so the eye's pixels too.
        let limit_view = select(view_index, v.volume_view, v.light_slices == 0u);
        end = min(end, column_limit[column_index(v, limit_view, gid.x, gid.y)] + 1u);
    }
    for (var s = 0u; s < end; s++) {
        let index = v.froxel_base + gid.x + v.froxel_dims.x * (gid.y + v.froxel_dims.y * s);
        let z1 = slice_depth(v, f32(s + 1u));
        let d = (z1 - z0) * inv_cos;
        z0 = z1;
        var f: vec4f;
        if s < own {
            f = unpack_rgba16(froxels[index]);
        } else {
            f = partner_froxel(o, partner_pixel(o, pp, froxel_depth(v, s)), s);
        }
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
