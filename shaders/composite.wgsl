// Composite + tone map, all viewers in one dispatch: surface shading with ray-traced
// shadows, then `surface × transmittance + in-scattered` from the integrated volume
// at the pixel's depth (000 §3.1.4), ACES-fitted tone curve, sRGB, RGBA8 out.

@group(1) @binding(0) var<storage, read> integrated: array<vec2u>;
@group(1) @binding(1) var<storage, read_write> output: array<u32>;
@group(1) @binding(2) var gbuf_position: texture_2d_array<f32>;
@group(1) @binding(3) var gbuf_normal: texture_2d_array<f32>;
@group(1) @binding(4) var gbuf_albedo: texture_2d_array<f32>;
@group(1) @binding(5) var scene_maps: texture_depth_2d_array;
@group(1) @binding(6) var shadow_sampler: sampler_comparison;
@group(1) @binding(8) var mover_maps: texture_depth_2d_array;

// Shared surface shadow maps of a directional light (src/render/shadow_maps.rs): one of
// the static scene, one of the movers alone.
struct ShadowMap {
    view_proj: mat4x4f,
    layer: i32,       // −1: no map
    texel_m: f32,
    _pad: vec2f,
}
struct LightMaps {
    scene: ShadowMap,
    movers: ShadowMap,
}
@group(1) @binding(7) var<storage, read> map_info: array<LightMaps>;

// Shadow-map coordinates (uv, depth) of surface point `p` with normal `n`, pushed along
// the normal by 3/4 of a texel to clear the map's depth steps (measured best on Sponza
// among 0.4, 0.75, 1 and slope-scaled offsets: docs/decisions.md).
fn map_coord(m: ShadowMap, p: vec3f, n: vec3f) -> vec3f {
    let offset = 0.75 * m.texel_m;
    let c = m.view_proj * vec4f(p + n * offset, 1.0);
    return vec3f(c.x * 0.5 + 0.5, 0.5 - c.y * 0.5, c.z);
}

// Inside the map's footprint. A receiver past the map's far plane is behind every caster
// in it: its depth is clamped to 1 (shadowed where the map holds a caster).
fn inside(c: vec3f) -> bool {
    return all(c.xy >= vec2f(0.0)) && all(c.xy <= vec2f(1.0));
}

// Visibility (0..1, 2×2 PCF) of a directional light at a lit surface point from its maps.
fn map_visibility(m: LightMaps, p: vec3f, n: vec3f) -> f32 {
    var vis = 1.0;
    let cs = map_coord(m.scene, p, n);
    if inside(cs) {
        vis = textureSampleCompareLevel(scene_maps, shadow_sampler, cs.xy, m.scene.layer, min(cs.z, 1.0));
    }
    if m.movers.layer >= 0 {
        let cm = map_coord(m.movers, p, n);
        if inside(cm) {
            vis *= textureSampleCompareLevel(mover_maps, shadow_sampler, cm.xy, m.movers.layer, min(cm.z, 1.0));
        }
    }
    return vis;
}

fn fetch_integrated(v: View, x: u32, y: u32, s: i32) -> vec4f {
    if s < 0 {
        return vec4f(0.0, 0.0, 0.0, 1.0);
    }
    let i = v.froxel_base + x + v.froxel_dims.x * (y + v.froxel_dims.y * u32(s));
    return unpack_rgba16(integrated[i]);
}

// Trilinear lookup: bilinear between froxel column centres, linear between slice
// boundaries (boundary b holds integrated[b − 1]; boundary 0 is the eye).
fn sample_integrated(v: View, pix: vec2f, depth: f32) -> vec4f {
    let w = clamp(depth_to_slice(v, depth), 0.0, f32(frame.slices));
    let s0 = min(floor(w), f32(frame.slices) - 1.0);
    let fs = w - s0;
    let c = pix / f32(v.froxel_px) - 0.5;
    let cmax = vec2f(v.froxel_dims) - 1.0;
    let c0 = clamp(floor(c), vec2f(0.0), cmax);
    let c1 = min(c0 + 1.0, cmax);
    let f = clamp(c - c0, vec2f(0.0), vec2f(1.0));
    var acc = vec4f(0.0);
    for (var k = 0u; k < 4u; k++) {
        let sx = select(c0.x, c1.x, (k & 1u) != 0u);
        let sy = select(c0.y, c1.y, (k & 2u) != 0u);
        let wx = select(1.0 - f.x, f.x, (k & 1u) != 0u);
        let wy = select(1.0 - f.y, f.y, (k & 2u) != 0u);
        let a = fetch_integrated(v, u32(sx), u32(sy), i32(s0) - 1);
        let b = fetch_integrated(v, u32(sx), u32(sy), i32(s0));
        acc += wx * wy * mix(a, b, fs);
    }
    return acc;
}

fn aces(x: vec3f) -> vec3f {
    return clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), vec3f(0.0), vec3f(1.0));
}

fn srgb(c: vec3f) -> vec3f {
    return select(1.055 * pow(c, vec3f(1.0 / 2.4)) - 0.055, c * 12.92, c <= vec3f(0.0031308));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    var rays = 0u;
    if gid.z < frame.view_count {
        let v = views[gid.z];
        if gid.x < v.size.x && gid.y < v.size.y {
            let texel = vec2i(gid.xy);
            let layer = i32(gid.z);
            let pos = textureLoad(gbuf_position, texel, layer, 0);
            let pix = vec2f(gid.xy) + 0.5;
            let dir = view_ray(v, pix);
            var color = frame.sky;
            var depth = v.far;
            if pos.w > 0.0 {
                depth = pos.w;
                let p = pos.xyz;
                var n = textureLoad(gbuf_normal, texel, layer, 0).xyz;
                if dot(n, dir) > 0.0 {
                    n = -n;
                }
                let albedo = textureLoad(gbuf_albedo, texel, layer, 0).rgb;
                var irradiance = frame.ambient * PI;
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
                    let m = map_info[li];
                    if m.scene.layer >= 0 {
                        irradiance += radiance * ndl * map_visibility(m, p, n);
                        continue;
                    }
                    rays += 1u;
                    if light_visible(l, origin) {
                        irradiance += radiance * ndl;
                    }
                }
                color = albedo / PI * irradiance;
            }
            if (frame.flags & FLAG_MEDIA) != 0u {
                let fog = sample_integrated(v, pix, depth);
                color = color * fog.w + fog.rgb;
            }
            let ldr = srgb(aces(color * frame.exposure));
            let q = vec4u(vec3u(round(clamp(ldr, vec3f(0.0), vec3f(1.0)) * 255.0)), 255u);
            output[v.pixel_base + gid.x + gid.y * v.size.x] = q.x | (q.y << 8u) | (q.z << 16u) | (q.w << 24u);
        }
    }
    count(C_SURFACE_RAYS, rays);
}
