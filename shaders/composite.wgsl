// Composite + tone map, all viewers in one dispatch: surface shading (lights from the
// shared shadow maps when there are any, else by a shadow ray; every light dimmed by
// the media between it and the surface), then
// `surface × transmittance + in-scattered` from the integrated volume at the pixel's
// depth (000 §3.1.4), the smoke layer over it (issue 15), ACES-fitted tone curve, sRGB, RGBA8 out.
//
// Stereo shading (`stereo_shading`): a coupled stereo eye's surfaces take the irradiance
// its partner eye found at the same surface point (diffuse light does not depend on the
// eye), so the partner's views run first (`main`), writing it, and the coupled eyes
// after them (`coupled`). Where the partner does not see the point, or saw a light there
// only in part (a penumbra), the eye shades it itself.

@group(1) @binding(0) var<storage, read> integrated: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> output: array<u32>;
// The packed G-buffer (shaders/gbuffer_surface.wgsl).
@group(1) @binding(2) var gbuf: texture_2d_array<u32>;
// This set's smoke layers (premultiplied, fog around the particles included), read when
// the frame has particles; a 1×1 stub otherwise (shaders/smoke_raster.wgsl).
@group(1) @binding(5) var smoke: texture_2d_array<f32>;
// Per pixel of the views coupled eyes read, from each one's `lights_base`, a row of
// `size.x` after another, SHARED_WORDS u32s: the surface's irradiance (rgb, f16), its
// view depth (f16; −1 without a surface, or where a light was seen in part) and its
// normal (octahedral, 2 × snorm16); a stub when no view is coupled.
@group(1) @binding(6) var<storage, read_write> partner_light: array<u32>;
// The slots each entry point shades: [count of `main`'s, count of `coupled`'s, `main`'s
// slots…, `coupled`'s slots…].
@group(1) @binding(7) var<storage, read> order: array<u32>;
// Bindings 10–14: the shadow maps (shaders/shadow_lookup.wgsl).

// fetch_integrated / sample_integrated: shaders/integrated_lookup.wgsl.

fn aces(x: vec3f) -> vec3f {
    return clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), vec3f(0.0), vec3f(1.0));
}

fn srgb(c: vec3f) -> vec3f {
    return select(1.055 * pow(c, vec3f(1.0 / 2.4)) - 0.055, c * 12.92, c <= vec3f(0.0031308));
}

// A pixel's visible surface: its world point, the normal facing the eye, and its depth.
struct Surface {
    p: vec3f,
    n: vec3f,
    depth: f32,
}

// The surface of G-buffer texel `g` seen through pixel centre `pix` of view `v`.
fn surface_at(v: View, g: vec4u, pix: vec2f) -> Surface {
    let dir = view_ray(v, pix);
    let depth = surface_depth(g);
    var n = surface_normal(g);
    if dot(n, dir) > 0.0 {
        n = -n;
    }
    // The pixel centre's ray at the surface's view depth.
    return Surface(point_at_depth(v, dir, depth), n, depth);
}

// Irradiance at surface `s` (xyz): the ambient and every light, through its shadow map
// or a shadow ray (counted in `rays`), dimmed by the media on the way; w = 1 where some
// light is seen only in part (a penumbra, or a map's moiré), where it changes from pixel
// to pixel.
fn surface_irradiance(s: Surface, rays: ptr<function, u32>) -> vec4f {
    let p = s.p;
    let n = s.n;
    var irradiance = ambient_irradiance(p, n);
    var partial = 0.0;
    // Offset along the normal, scaled with distance (depth precision).
    let origin = p + n * (2e-3 + s.depth * 2e-4);
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
        if vis > 0.0 && vis < 1.0 {
            partial = 1.0;
        }
        // The light crossed the media on its way to the surface.
        if vis > 0.0 {
            irradiance += radiance * (ndl * vis * surface_transmittance(li, origin));
        }
    }
    return vec4f(irradiance, partial);
}

// Below this cosine between a surface and the partner's ray the surface turns away
// within a pixel (a column's silhouette): the eye shades it itself.
const GRAZING: f32 = 0.3;

// u32s a pixel in `partner_light`.
const SHARED_WORDS: u32 = 3u;

// The irradiance partner view `w` (slot `v.volume_view`) found for view `v`'s surface
// `s` (w = 1), if the partner's nearest pixel to it sees the same surface and saw every
// light wholly or not at all there: its surface's view depth is the depth of `s` in the
// partner, within 1 % and what the surface's slope spans in a pixel and a half, and its
// normal is s's within 11°. Else w = 0.
fn partner_irradiance(v: View, w: View, s: Surface) -> vec4f {
    let q = pixel_of(w, s.p);
    if any(q < vec2f(0.0)) || any(q >= vec2f(w.size)) {
        return vec4f(0.0);
    }
    let qi = vec2u(q);
    let at = (w.lights_base + qi.x + qi.y * w.size.x) * SHARED_WORDS;
    let e = vec3u(partner_light[at], partner_light[at + 1u], partner_light[at + 2u]);
    let b = unpack2x16float(e.y);
    let depth = dot(s.p - w.position, w.forward);
    // One pixel's width at the surface, and how far in depth the surface runs over it.
    let footprint = s.depth * 2.0 * v.tan_y / f32(v.size.y);
    let c = abs(dot(s.n, normalize(s.p - w.position)));
    let slope = footprint * sqrt(1.0 - c * c) / max(c, GRAZING);
    let n = oct_decode(unpack2x16snorm(e.z));
    if c < GRAZING || abs(b.y - depth) > 0.01 * depth + 1.5 * slope || dot(n, s.n) < 0.98 {
        return vec4f(0.0);
    }
    return vec4f(unpack2x16float(e.x), b.x, 1.0);
}

// The tone-mapped colour of pixel `xy` of view `v` (layer `layer` of the G-buffer);
// adds the shadow rays it traced to `rays`. A `coupled` eye takes its partner's
// irradiance where it can (counted in `reused`); a view a coupled eye reads writes its
// own.
fn shade_pixel(v: View, partner: View, layer: i32, xy: vec2u, coupled: bool, rays: ptr<function, u32>, reused: ptr<function, u32>) -> u32 {
    let texel = vec2i(xy);
    let g = textureLoad(gbuf, texel, layer, 0);
    let pix = vec2f(xy) + 0.5;
    var color = frame.sky;
    var depth = v.far;
    // What a coupled eye reads: irradiance, depth (−1: do not take it), normal.
    var handoff = vec3u(0u, pack2x16float(vec2f(0.0, -1.0)), 0u);
    if surface_depth(g) > 0.0 {
        let s = surface_at(v, g, pix);
        depth = s.depth;
        var irr = vec4f(0.0);
        if coupled {
            irr = partner_irradiance(v, partner, s);
            *reused += u32(irr.w);
        }
        if irr.w == 0.0 {
            irr = surface_irradiance(s, rays);
            handoff = vec3u(
                pack2x16float(irr.xy),
                pack2x16float(vec2f(irr.z, select(s.depth, -1.0, irr.w > 0.0))),
                pack2x16snorm(oct_encode(s.n)),
            );
        }
        color = surface_albedo(g) / PI * irr.xyz;
    }
    if v.lights_base != NO_LIGHTS {
        let at = (v.lights_base + xy.x + xy.y * v.size.x) * SHARED_WORDS;
        partner_light[at] = handoff.x;
        partner_light[at + 1u] = handoff.y;
        partner_light[at + 2u] = handoff.z;
    }
    if (frame.flags & FLAG_MEDIA) != 0u {
        let fog = sample_integrated(v, pix, depth);
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

// Shades the row `gid.y` strip of workgroup `wg` of the view in slot `slot`; returns
// the shadow rays it traced and the pixels that took the partner's irradiance.
fn shade_strip(slot: u32, coupled: bool, gid: vec3u, wg: vec3u, lid: vec3u) -> vec2u {
    var rays = 0u;
    var reused = 0u;
    let v = views[slot];
    // Read once per strip (a coupled eye's partner; else never read).
    let partner = views[select(slot, v.volume_view, coupled)];
    if gid.y < v.size.y {
        for (var k = 0u; k < STRIP; k++) {
            let x = (wg.x * STRIP + k) * 8u + lid.x;
            if x < v.size.x {
                output[v.pixel_base + x + gid.y * v.row_stride] = shade_pixel(v, partner, i32(slot), vec2u(x, gid.y), coupled, &rays, &reused);
            }
        }
    }
    return vec2u(rays, reused);
}

// z runs over `main`'s slots in `order`.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(workgroup_id) wg: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    var done = vec2u(0u);
    if gid.z < order[0] {
        done = shade_strip(order[2u + gid.z], false, gid, wg, lid);
    }
    count(C_SURFACE_RAYS, done.x);
}

// z runs over the coupled eyes' slots in `order` (after `main`).
@compute @workgroup_size(8, 8, 1)
fn coupled(@builtin(global_invocation_id) gid: vec3u, @builtin(workgroup_id) wg: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    var done = vec2u(0u);
    if gid.z < order[1] {
        done = shade_strip(order[2u + order[0] + gid.z], true, gid, wg, lid);
    }
    count(C_SURFACE_RAYS, done.x);
    count(C_STEREO_SHADED_PIXELS, done.y);
}
