// Composite + tone map, all viewers in one dispatch: surface shading (lights from the
// shared shadow maps when there are any, else by a shadow ray; every light dimmed by
// the media between it and the surface), then
// `surface × transmittance + in-scattered` from the integrated volume at the pixel's
// depth (000 §3.1.4), the smoke layer over it (issue 15), ACES-fitted tone curve, sRGB, RGBA8 out.

@group(1) @binding(0) var<storage, read> integrated: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> output: array<u32>;
@group(1) @binding(2) var gbuf_position: texture_2d_array<f32>;
@group(1) @binding(3) var gbuf_normal: texture_2d_array<f32>;
@group(1) @binding(4) var gbuf_albedo: texture_2d_array<f32>;
// This set's smoke layers (premultiplied, fog around the particles included), read when
// the frame has particles; a 1×1 stub otherwise (shaders/smoke_raster.wgsl).
@group(1) @binding(5) var smoke: texture_2d_array<f32>;
// Coupled stereo: each view's surface radiance (rgb, f32), written by the views that
// shade their own surfaces and read by the eyes that share their volume (one per pixel
// of every slot; a stub without coupled pairs).
@group(1) @binding(6) var<storage, read_write> surface: array<vec4f>;
// Bindings 10–14: the shadow maps (shaders/shadow_lookup.wgsl).

// fetch_integrated / sample_integrated / fog_to: shaders/integrated_lookup.wgsl.

fn aces(x: vec3f) -> vec3f {
    return clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), vec3f(0.0), vec3f(1.0));
}

fn srgb(c: vec3f) -> vec3f {
    return select(1.055 * pow(c, vec3f(1.0 / 2.4)) - 0.055, c * 12.92, c <= vec3f(0.0031308));
}

// Linear radiance leaving the surface a view's pixel shows (position `pos`, layer
// `layer` of the G-buffer, seen along `dir`): diffuse, so the same from every eye.
// Adds the shadow rays it traced to `rays`.
fn surface_radiance(pos: vec4f, dir: vec3f, layer: i32, texel: vec2i, rays: ptr<function, u32>) -> vec3f {
    let depth = pos.w;
    let p = pos.xyz;
    var n = textureLoad(gbuf_normal, texel, layer, 0).xyz;
    if dot(n, dir) > 0.0 {
        n = -n;
    }
    let albedo = textureLoad(gbuf_albedo, texel, layer, 0).rgb;
    var irradiance = ambient_irradiance(p, n);
    // Offset along the normal, scaled with distance (depth precision).
    let origin = p + n * (2e-3 + depth * 2e-4);
    for (var li = 0u; li < frame.light_count; li++) {
        let l = lights[li];
        let tl = to_light(l, origin);
        let ndl = dot(n, tl.xyz);
        if ndl <= 0.0 {
            continue;
        }
        let radiance = light_radiance(l, origin);
        if all(radiance == vec3f(0.0)) {
            continue;
        }
        var vis = 0.0;
        if has_map(li) {
            vis = map_visibility(li, l, p, n, 0.75);
        } else {
            *rays += 1u;
            vis = select(0.0, 1.0, light_visible(l, origin));
        }
        // The light crossed the media on its way to the surface.
        if vis > 0.0 {
            irradiance += radiance * (ndl * vis * surface_transmittance(li, origin));
        }
    }
    return albedo / PI * irradiance;
}

// Index of pixel `xy` of the view in slot `slot` in `surface` (one image per slot).
fn surface_index(v: View, slot: u32, xy: vec2u) -> u32 {
    return (slot * v.size.y + xy.y) * v.size.x + xy.x;
}

// A coupled stereo eye's surface radiance at `p`, interpolated bilinearly between the
// partner's four pixel centres around `p`'s projection. Only where all of them lie on
// the surface through `p` with normal `n` (within 1 cm + 0.5 % of the depth of its
// plane, normals within 25°) and agree within 4 % (no shadow edge or depth edge between
// them); w = 0 otherwise (disoccluded, outside the partner's view, an edge): the eye
// then shades the pixel itself.
fn partner_surface(v: View, p: vec3f, n: vec3f) -> vec4f {
    let o = views[v.volume_view];
    let d = p - o.position;
    let z = dot(d, o.forward);
    if z <= o.near {
        return vec4f(0.0);
    }
    let ndc = vec2f(dot(d, o.right) / (z * o.tan_x), dot(d, o.up) / (z * o.tan_y));
    let c = vec2f(ndc.x + 1.0, 1.0 - ndc.y) * 0.5 * vec2f(o.size) - 0.5;
    let c0 = floor(c);
    // Snapped to a centre within 1/1000 of a pixel: coincident eyes read one pixel.
    let f = select(c - c0, vec2f(0.0), c - c0 < vec2f(1e-3));
    let tolerance = 0.01 + 0.005 * z;
    var acc = vec3f(0.0);
    var lo = vec3f(3.0e38);
    var hi = vec3f(0.0);
    for (var k = 0u; k < 4u; k++) {
        let q = c0 + vec2f(f32(k & 1u), f32(k >> 1u));
        let w = select(1.0 - f.x, f.x, (k & 1u) != 0u) * select(1.0 - f.y, f.y, (k & 2u) != 0u);
        if w <= 0.0 {
            continue;
        }
        if any(q < vec2f(0.0)) || any(q >= vec2f(o.size)) {
            return vec4f(0.0);
        }
        let seen = textureLoad(gbuf_position, vec2i(q), i32(v.volume_view), 0);
        let seen_n = textureLoad(gbuf_normal, vec2i(q), i32(v.volume_view), 0).xyz;
        if !(seen.w > 0.0 && abs(dot(seen.xyz - p, n)) <= tolerance && abs(dot(seen_n, n)) > 0.9) {
            return vec4f(0.0);
        }
        let s = surface[surface_index(o, v.volume_view, vec2u(q))].rgb;
        acc += w * s;
        lo = min(lo, s);
        hi = max(hi, s);
    }
    if any(hi - lo > 0.04 * hi + 1e-6) {
        return vec4f(0.0);
    }
    return vec4f(acc, 1.0);
}

// The tone-mapped colour of pixel `xy` of view `v` (slot `slot`, also its G-buffer
// layer). `coupled`: a coupled stereo eye, which takes the surface's radiance from its
// partner where the partner shows the same point; otherwise the view shades it and,
// when some eye reads it (FLAG_COUPLED), stores it in `surface`. Adds the shadow rays
// it traced to `rays`.
fn shade_pixel(v: View, slot: u32, xy: vec2u, coupled: bool, rays: ptr<function, u32>, reused: ptr<function, u32>) -> u32 {
    let layer = i32(slot);
    let texel = vec2i(xy);
    let pos = textureLoad(gbuf_position, texel, layer, 0);
    let pix = vec2f(xy) + 0.5;
    let dir = view_ray(v, pix);
    var color = frame.sky;
    var depth = v.far;
    var point = v.position + dir * (v.far / dot(dir, v.forward));
    if pos.w > 0.0 {
        depth = pos.w;
        point = pos.xyz;
        var from_partner = vec4f(0.0);
        if coupled {
            from_partner = partner_surface(v, point, textureLoad(gbuf_normal, texel, layer, 0).xyz);
        }
        if from_partner.w > 0.0 {
            color = from_partner.rgb;
            *reused += 1u;
        } else {
            color = surface_radiance(pos, dir, layer, texel, rays);
        }
        if !coupled && (frame.flags & FLAG_COUPLED) != 0u {
            surface[surface_index(v, slot, xy)] = vec4f(color, 1.0);
        }
    }
    if (frame.flags & FLAG_MEDIA) != 0u {
        let fog = fog_to(v, slot, pix, depth, point);
        color = color * fog.w + fog.rgb;
    }
    // The smoke over what lies behind it: S + (1 − S.a)·base, S premultiplied.
    if frame.particle_count > 0u {
        let s = textureLoad(smoke, texel, layer, 0);
        color = s.rgb + (1.0 - s.a) * color;
    }
    let ldr = srgb(aces(color * frame.exposure));
    let q = vec4u(vec3u(round(clamp(ldr, vec3f(0.0), vec3f(1.0)) * 255.0)), 255u);
    return q.x | (q.y << 8u) | (q.z << 16u) | (q.w << 24u);
}

// Pixels per invocation, along x: the view is read once for all of them. Lane i of a
// workgroup row shades pixels i, i + 8, i + 16, … of the row's 8·STRIP, so the lanes
// work on 8 neighbouring pixels at a time (coherent shadow rays in `reference`).
const STRIP: u32 = 4u;

// The pixels of the views that shade their own surfaces (slots below
// frame.volume_views), or with `coupled` of the coupled stereo eyes (the slots from
// there on); z runs over those views.
fn composite_views(gid: vec3u, wg: vec3u, lid: vec3u, coupled: bool) {
    var rays = 0u;
    var reused = 0u;
    let slot = gid.z + select(0u, frame.volume_views, coupled);
    if slot < frame.view_count {
        let v = views[slot];
        if gid.y < v.size.y {
            for (var k = 0u; k < STRIP; k++) {
                let x = (wg.x * STRIP + k) * 8u + lid.x;
                if x < v.size.x {
                    output[v.pixel_base + x + gid.y * v.row_stride] = shade_pixel(v, slot, vec2u(x, gid.y), coupled, &rays, &reused);
                }
            }
        }
    }
    count(C_SURFACE_RAYS, rays);
    count(C_SURFACES_REUSED, reused);
}

// Every view that shades its own surfaces (all of them without coupled stereo).
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(workgroup_id) wg: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    composite_views(gid, wg, lid, false);
}

// After `main`: the coupled stereo eyes, which read their partners' surfaces.
@compute @workgroup_size(8, 8, 1)
fn coupled(@builtin(global_invocation_id) gid: vec3u, @builtin(workgroup_id) wg: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    composite_views(gid, wg, lid, true);
}
