// Lookups in the shared shadow maps (src/render/shadow_maps.rs): per directional light
// one orthographic map of the static scene and one of the movers alone; per spot light
// one perspective map, per point light a cube of six perspective faces (both in
// `local_maps`, with the movers drawn in). Group 1, bindings 10–14, in every stage that
// reads them (composite: surfaces; shadow frustum: the fog near each eye; froxel
// lighting in `maps` mode: every froxel).

@group(1) @binding(10) var scene_maps: texture_depth_2d_array;
@group(1) @binding(11) var shadow_sampler: sampler_comparison;
@group(1) @binding(12) var<storage, read> map_info: array<LightMaps>;
@group(1) @binding(13) var mover_maps: texture_depth_2d_array;
@group(1) @binding(14) var local_maps: texture_depth_2d_array;

// ShadowMap.kind
const MAP_ORTHO: u32 = 0u;
const MAP_PERSPECTIVE: u32 = 1u;
const MAP_CUBE: u32 = 2u;

struct ShadowMap {
    view_proj: mat4x4f,
    layer: i32,       // −1: no map; a cube's first face
    texel_m: f32,     // texel size, metres (perspective and cube: at 1 m from the light)
    kind: u32,
    _pad: f32,
}
struct LightMaps {
    scene: ShadowMap,
    movers: ShadowMap,
    faces: array<mat4x4f, 6>,  // a cube's faces: +x, −x, +y, −y, +z, −z
}

// Whether light `li` has a map (else its shadows are traced).
fn has_map(li: u32) -> bool {
    return map_info[li].scene.layer >= 0;
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

// A point's place in a spot or cube map: (uv, depth) and its layer.
struct LocalCoord {
    c: vec3f,
    layer: i32,
}

// As map_coord for spot light or point light `li` at `pos`; the offset grows with the
// distance to the light as the texels do. Behind a spot's map: outside it.
fn local_coord(li: u32, pos: vec3f, p: vec3f, away: vec3f, texels: f32) -> LocalCoord {
    let m = map_info[li].scene;
    let q = p + away * (texels * m.texel_m * distance(p, pos));
    var vp = m.view_proj;
    var layer = m.layer;
    if m.kind == MAP_CUBE {
        let f = cube_face(q - pos);
        vp = map_info[li].faces[f];
        layer += i32(f);
    }
    let c = vp * vec4f(q, 1.0);
    if c.w <= 0.0 {
        return LocalCoord(vec3f(-1.0), layer);
    }
    let ndc = c.xyz / c.w;
    return LocalCoord(vec3f(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5, ndc.z), layer);
}

// Visibility (0..1, 2×2 PCF) of light `l` (scene light `li`, with a map) at `p` from its
// maps; `away` and `texels` as in map_coord.
fn map_visibility(li: u32, l: Light, p: vec3f, away: vec3f, texels: f32) -> f32 {
    let m = map_info[li];
    if m.scene.kind != MAP_ORTHO {
        let lc = local_coord(li, l.position, p, away, texels);
        if !inside(lc.c) {
            return 1.0;
        }
        return textureSampleCompareLevel(local_maps, shadow_sampler, lc.c.xy, lc.layer, min(lc.c.z, 1.0));
    }
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

// Whether the nearest texel of layer `layer` of depth array `maps` lets the light reach `c`.
fn texel_lit(maps: texture_depth_2d_array, layer: i32, c: vec3f) -> bool {
    if !inside(c) {
        return true;
    }
    let size = vec2f(textureDimensions(maps));
    let t = vec2i(clamp(c.xy * size, vec2f(0.0), size - 1.0));
    return min(c.z, 1.0) <= textureLoad(maps, t, layer, 0);
}

// Whether light `l` (scene light `li`, with a map) reaches a point in the fog, from the
// nearest texel of each of its maps (a froxel needs one bit, not a filtered edge);
// `away`, `texels` as above.
fn map_lit(li: u32, l: Light, p: vec3f, away: vec3f, texels: f32) -> bool {
    let m = map_info[li];
    if m.scene.kind != MAP_ORTHO {
        let lc = local_coord(li, l.position, p, away, texels);
        return texel_lit(local_maps, lc.layer, lc.c);
    }
    if !texel_lit(scene_maps, m.scene.layer, map_coord(m.scene, p, away, texels)) {
        return false;
    }
    return m.movers.layer < 0 || texel_lit(mover_maps, m.movers.layer, map_coord(m.movers, p, away, texels));
}
