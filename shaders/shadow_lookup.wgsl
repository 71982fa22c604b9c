// Lookups in the shared shadow maps of directional lights (src/render/shadow_maps.rs):
// per light one map of the static scene and one of the movers alone. Group 1, bindings
// 5–8, in every stage that reads them (composite: surfaces; shadow frustum: the fog
// near each eye).

@group(1) @binding(5) var scene_maps: texture_depth_2d_array;
@group(1) @binding(6) var shadow_sampler: sampler_comparison;
@group(1) @binding(7) var<storage, read> map_info: array<LightMaps>;
@group(1) @binding(8) var mover_maps: texture_depth_2d_array;

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

// Shadow-map coordinates (uv, depth) of point `p` pushed `texels` of this map's texels
// along the unit vector `away` (a surface's normal, or towards the light for a point in
// the fog) to clear the map's depth steps. Surfaces use 3/4 of a texel, measured best on
// Sponza among 0.4, 0.75, 1 and slope-scaled offsets (docs/decisions.md).
fn map_coord(m: ShadowMap, p: vec3f, away: vec3f, texels: f32) -> vec3f {
    let c = m.view_proj * vec4f(p + away * (texels * m.texel_m), 1.0);
    return vec3f(c.x * 0.5 + 0.5, 0.5 - c.y * 0.5, c.z);
}

// Inside the map's footprint. A receiver past the map's far plane is behind every caster
// in it: its depth is clamped to 1 (shadowed where the map holds a caster).
fn inside(c: vec3f) -> bool {
    return all(c.xy >= vec2f(0.0)) && all(c.xy <= vec2f(1.0));
}

// Visibility (0..1, 2×2 PCF) of a directional light at `p` from its maps; `away` and
// `texels` as in map_coord.
fn map_visibility(m: LightMaps, p: vec3f, away: vec3f, texels: f32) -> f32 {
    var vis = 1.0;
    let cs = map_coord(m.scene, p, away, texels);
    if inside(cs) {
        vis = textureSampleCompareLevel(scene_maps, shadow_sampler, cs.xy, m.scene.layer, min(cs.z, 1.0));
    }
    if m.movers.layer >= 0 {
        let cm = map_coord(m.movers, p, away, texels);
        if inside(cm) {
            vis *= textureSampleCompareLevel(mover_maps, shadow_sampler, cm.xy, m.movers.layer, min(cm.z, 1.0));
        }
    }
    return vis;
}

// Whether the nearest texel of map `m` in depth array `maps` lets the light reach `c`.
fn texel_lit(maps: texture_depth_2d_array, m: ShadowMap, c: vec3f) -> bool {
    if !inside(c) {
        return true;
    }
    let size = vec2f(textureDimensions(maps));
    let t = vec2i(clamp(c.xy * size, vec2f(0.0), size - 1.0));
    return min(c.z, 1.0) <= textureLoad(maps, t, m.layer, 0);
}

// Whether a directional light reaches a point in the fog, from the nearest texel of each
// of its maps (a froxel needs one bit, not a filtered edge); `away`, `texels` as above.
fn map_lit(m: LightMaps, p: vec3f, away: vec3f, texels: f32) -> bool {
    if !texel_lit(scene_maps, m.scene, map_coord(m.scene, p, away, texels)) {
        return false;
    }
    return m.movers.layer < 0 || texel_lit(mover_maps, m.movers, map_coord(m.movers, p, away, texels));
}
