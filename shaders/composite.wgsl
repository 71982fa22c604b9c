// Composite + tone map, all viewers in one dispatch: surface shading (lights from the
// shared shadow maps when there are any, else by a shadow ray; every light dimmed by
// the media between it and the surface), then
// `surface × transmittance + in-scattered` from the integrated volume at the pixel's
// depth (000 §3.1.4), the smoke layer over it (issue 15), ACES-fitted tone curve, sRGB, RGBA8 out.

@group(1) @binding(0) var<storage, read> integrated: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> output: array<u32>;
// The packed G-buffer (shaders/gbuffer_surface.wgsl).
@group(1) @binding(2) var gbuf: texture_2d_array<u32>;
// This set's smoke layers (premultiplied, fog around the particles included), read when
// the frame has particles; a 1×1 stub otherwise (shaders/smoke_raster.wgsl).
@group(1) @binding(5) var smoke: texture_2d_array<f32>;
// Bindings 10–14: the shadow maps (shaders/shadow_lookup.wgsl).

// fetch_integrated / sample_integrated: shaders/integrated_lookup.wgsl.

fn aces(x: vec3f) -> vec3f {
    return clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), vec3f(0.0), vec3f(1.0));
}

fn srgb(c: vec3f) -> vec3f {
    return select(1.055 * pow(c, vec3f(1.0 / 2.4)) - 0.055, c * 12.92, c <= vec3f(0.0031308));
}

// Irradiance from light `li` on the surface at `p` of normal `n` (shadow rays leave from
// `origin`); adds the shadow ray it traced to `rays`.
fn surface_light(li: u32, p: vec3f, n: vec3f, origin: vec3f, rays: ptr<function, u32>) -> vec3f {
    let l = lights[li];
    let tl = to_light(l, origin);
    let ndl = dot(n, tl.xyz);
    if ndl <= 0.0 {
        return vec3f(0.0);
    }
    let radiance = light_radiance(l, origin);
    if all(radiance == vec3f(0.0)) {
        return vec3f(0.0);
    }
    var vis = 0.0;
    if has_map(li) {
        vis = map_visibility(li, l, p, n, 0.75);
    } else {
        *rays += 1u;
        vis = select(0.0, 1.0, light_visible(l, origin));
    }
    if vis <= 0.0 {
        return vec3f(0.0);
    }
    // The light crossed the media on its way to the surface.
    return radiance * (ndl * vis * surface_transmittance(li, origin));
}

// The tone-mapped colour of pixel `xy` of view `v` (layer `layer` of the G-buffer);
// adds the shadow rays it traced to `rays`.
fn shade_pixel(v: View, layer: i32, xy: vec2u, rays: ptr<function, u32>) -> u32 {
    let texel = vec2i(xy);
    let surface = textureLoad(gbuf, texel, layer, 0);
    let pix = vec2f(xy) + 0.5;
    let dir = view_ray(v, pix);
    var color = frame.sky;
    var depth = v.far;
    if surface_depth(surface) > 0.0 {
        depth = surface_depth(surface);
        // The pixel centre's ray at the surface's view depth.
        let p = point_at_depth(v, dir, depth);
        var n = surface_normal(surface);
        if dot(n, dir) > 0.0 {
            n = -n;
        }
        let albedo = surface_albedo(surface);
        // Offset along the normal, scaled with distance (depth precision).
        let origin = p + n * (2e-3 + depth * 2e-4);
        // The ambient light, then each light's (`surface_light`; the sum is generated,
        // src/render/mod.rs `LightSum`).
        let irradiance = surface_lights(ambient_irradiance(p, n), p, n, origin, rays);
        color = albedo / PI * irradiance;
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

// z runs over viewers.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u, @builtin(workgroup_id) wg: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    var rays = 0u;
    if gid.z < frame.view_count {
        let v = views[gid.z];
        if gid.y < v.size.y {
            for (var k = 0u; k < STRIP; k++) {
                let x = (wg.x * STRIP + k) * 8u + lid.x;
                if x < v.size.x {
                    output[v.pixel_base + x + gid.y * v.row_stride] = shade_pixel(v, i32(gid.z), vec2u(x, gid.y), &rays);
                }
            }
        }
    }
    count(C_SURFACE_RAYS, rays);
}
