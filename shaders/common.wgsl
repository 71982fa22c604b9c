// Shared declarations for every fogcast compute stage (group 0), prepended to each stage.
// Mirrors `src/render/gpu_types.rs`; media and phase mirror `src/scene/media.rs`.

struct Frame {
    grid_min: vec3f,
    voxel_size: f32,
    grid_dims: vec3u,
    light_count: u32,
    sky: vec3f,
    medium_count: u32,
    ambient: vec3f,
    exposure: f32,
    view_count: u32,
    frame_index: u32,
    flags: u32,
    time_s: f32,
    grid_words_x: u32,
    max_ray_m: f32,
    frustum_slices: u32,
    slices: u32,
    depth_curve: f32,
    // Lights whose position, direction, cone or colour changed since the last frame
    // (bit per light): cached grid bits of these lights are stale.
    dirty_lights: u32,
    // Sparse grid: bricks in the pool.
    pool_capacity: u32,
    // First node of the movers' BVH (after the static tree), or 0xffffffff.
    mover_root: u32,
    // Bounds swept by the movers since the last frame (min > max: nothing moved); with
    // FLAG_CACHE, a voxel whose shadow ray to a light crosses them re-traces that light.
    moved_min: vec3f,
    // Lights whose shared media transmittance volume is refilled this frame (bit per
    // light): every light on the first frame, a light that changed, all of them while
    // wind moves the media (shaders/media_transmittance.wgsl).
    transmittance_dirty: u32,
    moved_max: vec3f,
    // Quadrature step of a shadow ray through height or noisy media, metres.
    media_step_m: f32,
    // The world media layer (shaders/media_layer.wgsl): origin, voxel edge, bricks a
    // side, pool slots, this frame's fill stamp, the g of every medium in it.
    layer_min: vec3f,
    layer_voxel: f32,
    layer_bricks: vec3u,
    layer_capacity: u32,
    layer_stamp: u32,
    // The first medium in the layer: with FLAG_LAYER_FULL off every medium in it has its
    // coefficients, and a node holds the summed density alone.
    layer_first: u32,
    // u32 words per node: 1 (density) or 4 (σs.rgb, σt, emission.rgb, g·mean(σs), f16).
    layer_node_words: u32,
    // Live smoke particles in `particles` this frame.
    particle_count: u32,
    // The shared ambient grid (shaders/ambient_grid.wgsl, FLAG_SH_AMBIENT): the first
    // probe's position, the probes' spacing, probes a side, and probes in all.
    sh_min: vec3f,
    sh_cell: f32,
    sh_dims: vec3u,
    sh_probes: u32,
    // The media whose density the shared grid carries (FLAG_GRID_MEDIA): the box they
    // fill, the density of one step of its 8-bit code (code c > 0 is (c − 1) steps; 0:
    // not filled yet), and the first of them (every one has its coefficients).
    grid_media_min: vec3f,
    grid_media_unit: f32,
    grid_media_max: vec3f,
    grid_media_first: u32,
}

// Frame.flags
const FLAG_PARITY: u32 = 1u;     // update only voxels whose z parity matches the frame's
const FLAG_TRILINEAR: u32 = 2u;  // 8-voxel trilinear grid lookup (000 §3.1.3)
const FLAG_SHARED: u32 = 4u;     // mode `shared` (else `reference`: a ray per froxel)
const FLAG_MEDIA: u32 = 8u;      // the scene has participating media
const FLAG_DEMAND: u32 = 32u;    // grid: trace only voxels that froxels requested
const FLAG_CACHE: u32 = 64u;     // grid: keep voxels' light bits until a light changes
const FLAG_SPARSE: u32 = 128u;   // grid: bricks allocated where froxels read (sparse)
const FLAG_CULL: u32 = 256u;     // demand: froxels behind the depth buffer are not lit (froxel_cull.wgsl)
const FLAG_MEDIA_T: u32 = 512u;  // transmittance toward lights from the shared volumes (else marched)
const FLAG_LAYER: u32 = 1024u;   // media marked `in_layer` are read from the world media layer
const FLAG_MAPS: u32 = 2048u;    // mode `maps`: froxels read the shared shadow maps (no grid, no rays)
const FLAG_LAYER_FULL: u32 = 4096u; // layer nodes hold σs, σt, emission and g (else one density)
const FLAG_SH_AMBIENT: u32 = 8192u; // ambient light from the shared SH grid (else the constant `ambient`)
const FLAG_FROXEL_MAPS: u32 = 16384u; // shared: froxels read the maps of the lights that have one
const FLAG_MAP_EDGES: u32 = 32768u; // shared: where the grid's voxels disagree, the map
const FLAG_GRID_MEDIA: u32 = 65536u; // shared: the grid carries the costly media's density (grid_density)
const FLAG_GRID_MEDIA_MOVES: u32 = 131072u; // grid_media: the media move (refill every needed voxel each frame)
const FLAG_FROXEL_REQUESTS: u32 = 262144u; // no request pass: froxels request the voxels they find unfilled
const FLAG_GRID_MEDIA_FINE: u32 = 524288u; // grid_media: the density on cells of half a voxel (fine_row)

struct View {
    view_proj: mat4x4f,
    prev_view_proj: mat4x4f,
    position: vec3f,
    near: f32,
    forward: vec3f,
    far: f32,
    right: vec3f,
    tan_x: f32,
    up: vec3f,
    tan_y: f32,
    size: vec2u,
    froxel_dims: vec2u,
    frustum_dims: vec2u,
    froxel_px: u32,
    frustum_px: u32,
    froxel_base: u32,
    frustum_base: u32,
    pixel_base: u32,
    jitter: f32,
    row_stride: u32,    // pixels per row of the frame this view's tile is written into
    history_base: u32,  // this viewer's froxels in last frame's volume; NO_HISTORY: none
    volume_view: u32,   // the slot whose froxels this view integrates beyond its own slices (coupled stereo)
    light_slices: u32,  // slices it lights itself: all, a coupled eye's near field, or 0
    origin: vec3f,      // where its froxel volume is lit from: its eye, or a stereo head's midpoint
    _pad_origin: u32,
}

// The view whose froxels view `v`'s slot holds: `v` itself, or, for the first eye of a
// stereo head (`stereo_head`), the same view from the midpoint between the eyes. The
// froxel stages light and read the volume through it; the eye's own rays (integration,
// composite) start at `v.position`.
fn volume_of(v: View) -> View {
    var o = v;
    o.position = v.origin;
    return o;
}

// Whether view `v`'s own froxel columns lie on its own rays (not a stereo head's volume).
fn volume_on_own_rays(v: View) -> bool {
    return all(v.origin == v.position);
}

const NO_HISTORY: u32 = 0xffffffffu;

// The scene's light count as a pipeline constant, 1..=8 (0: not given; then
// `frame.light_count`). The per-froxel and per-pixel stages get it (`light_constants` in
// src/render/mod.rs): their loops over the lights then run a count fixed when the pipeline
// is built, which the shader compiler unrolls, keeping the per-light values in registers
// (docs/decisions.md, "The light count as a pipeline constant").
override LIGHTS: u32 = 0u;

// How many lights the scene has.
fn light_count() -> u32 {
    return select(frame.light_count, LIGHTS, LIGHTS > 0u);
}

// How many of a grid mask's 8 light bits loops over them visit: the scene's lights where
// the pipeline knows them, else all 8.
fn light_slots() -> u32 {
    return select(8u, LIGHTS, LIGHTS > 0u);
}

// Light.kind (LightKind::gpu_code in src/scene/types.rs)
const LIGHT_DIRECTIONAL: u32 = 0u;
const LIGHT_POINT: u32 = 1u;
const LIGHT_SPOT: u32 = 2u;

struct Light {
    position: vec3f,
    kind: u32,        // LIGHT_DIRECTIONAL, LIGHT_POINT or LIGHT_SPOT
    direction: vec3f, // direction of travel
    cos_outer: f32,
    radiance: vec3f,
    cos_inner: f32,
}

// Medium.kind (the match on MediumKind in src/render/gpu_types.rs)
const MEDIUM_CONSTANT: u32 = 0u;
const MEDIUM_HEIGHT: u32 = 1u;
const MEDIUM_BOX: u32 = 2u;
const MEDIUM_SPHERE: u32 = 3u;
const MEDIUM_VOLUME: u32 = 4u;

struct Medium {
    min: vec3f,
    kind: u32,        // MEDIUM_CONSTANT, _HEIGHT, _BOX, _SPHERE or _VOLUME
    max: vec3f,
    absorption: f32,
    scattering: vec3f,
    g: f32,
    emission: vec3f,
    radius_or_falloff: f32,
    wind: vec3f,
    base_y: f32,
    noise_frequency: f32,
    noise_octaves: u32,
    noise_amplitude: f32,
    in_layer: u32,    // 1: read from the world media layer where it holds the point
    // Volume primitives (kind 4; `radius_or_falloff` is their radius).
    center: vec3f,
    period_s: f32,
    velocity: vec3f,
    disp_amplitude: f32,
    disp_offset: vec3f,
    disp_frequency: f32,
    disp_octaves: u32,
    _pad2: u32,
    _pad3: u32,
    _pad4: u32,
}

// One live smoke particle (issue 15; ParticleGpu in src/render/gpu_types.rs): 001 Eq. 9's
// Gaussian, σ(l) = σ_centre · exp(−50 l²/u²), with its emitter's coefficients at the centre.
struct Particle {
    centre: vec3f,
    falloff_u: f32,   // u, metres (0: zero size, extinguishes nothing)
    scattering: vec3f, // σs at the centre, per channel, m⁻¹
    absorption: f32,  // σa at the centre, m⁻¹
    g: f32,
    index: u32,       // birth order within its emitter
    emitter: u32,
    _pad: u32,
}

@group(0) @binding(0) var<storage, read> frame: Frame;
@group(0) @binding(1) var<storage, read> views: array<View>;
@group(0) @binding(2) var<storage, read> lights: array<Light>;
@group(0) @binding(3) var<storage, read> media: array<Medium>;
@group(0) @binding(4) var<storage, read> bvh_nodes: array<BvhNode>;
@group(0) @binding(5) var<storage, read> bvh_tris: array<BvhTriangle>;
@group(0) @binding(6) var<storage, read_write> counters: array<atomic<u32>>;
// Shared media transmittance toward each light (src/render/media_transmittance.rs): one
// volume of optical depths per light, filled once per frame for every viewer, read
// trilinearly.
@group(0) @binding(7) var<storage, read_write> media_t: array<f32>;
@group(0) @binding(8) var<storage, read> light_media: array<LightMedia>;
// The world media layer (shaders/media_layer.wgsl, src/render/media_layer.rs): bricks of
// 8³ voxels over the media's bounds, each in `layer_table` as its pool slot + 1 (0: not
// in the pool this frame — read the media analytically there). A slot holds the brick's
// 9³ nodes (corners of its voxels; faces are stored by both neighbours, so a trilinear
// read never leaves its brick) of `layer_node_words` words each: the summed density (f32)
// when the layer's media share their coefficients, else σs.rgb, σt, emission.rgb and
// g·mean(σs) as f16 (every word read is a gather on a CPU rasteriser: fewer is faster).
// `layer_slots`: [0] slots handed out, then per slot its brick and the stamp of the
// frame that filled it.
@group(0) @binding(9) var<storage, read_write> layer_table: array<u32>;
@group(0) @binding(10) var<storage, read_write> layer_pool: array<u32>;
@group(0) @binding(11) var<storage, read_write> layer_slots: array<atomic<u32>>;
// The live smoke particles of every emitter, `frame.particle_count` of them (issue 15).
@group(0) @binding(12) var<storage, read> particles: array<Particle>;
// The smoke's adaptive volumetric shadow maps (seed 002; src/render/smoke_shadows.rs,
// shaders/smoke_avsm.wgsl): per light a map of px² texels, each a curve of `nodes`
// (depth, transmittance) nodes at smoke_nodes[offset + (x + px·y)·nodes + k], filled once
// per frame for every viewer (`smoke_transmittance` reads them).
@group(0) @binding(13) var<storage, read_write> smoke_nodes: array<vec2f>;
@group(0) @binding(14) var<storage, read> smoke_maps: array<SmokeMap>;
// The shared ambient grid: per probe five vec4f (order-2 SH of the radiance arriving there,
// red, green, blue: (L00, L1−1, L10, L11) each; then (valid weight, free distance +x, −x,
// +y) and (−y, +z, −z, 0): how far the probe sees along each axis before geometry) for
// the accumulated grid every stage reads, then as many for this frame's estimate
// (ambient_grid.rs).
@group(0) @binding(15) var<storage, read_write> ambient_sh: array<vec4f>;

// Light i's transmittance volume: dims.x·dims.y columns of dims.z nodes `spacing` apart,
// node (x, y, k) at media_t[offset + x + dims.x·(y + dims.y·k)]. A directional light's
// columns run along its direction of travel through the media's bounding sphere (centre,
// radius), laid out on the plane across it (`light_basis`). A point or spot light's
// columns are rays from the light, starting `near` metres out: one per texel of an
// octahedral map of all directions (`tan_half` = 0: the light is in or near the media),
// or of a perspective map of the cone around the sphere (tangent of its half angle).
struct LightMedia {
    centre: vec3f,
    radius: f32,
    dims: vec3u,
    offset: u32,
    spacing: f32,
    nodes: u32,       // 0: no volume (transmittance is marched per sample)
    near: f32,
    tan_half: f32,
}

// SmokeMap.kind
const SMOKE_MAP_NONE: u32 = 0u;        // no map this frame: the smoke casts no shadow
const SMOKE_MAP_ORTHO: u32 = 1u;       // directional light: parallel rays along `axis`
const SMOKE_MAP_PERSPECTIVE: u32 = 2u; // point or spot light: rays from `origin`
const SMOKE_MAP_CUBE: u32 = 3u;        // a point or spot light close to the smoke: six faces
// Map records per light in smoke_maps (a cube's six faces; other maps use the first).
const SMOKE_MAPS_PER_LIGHT: u32 = 6u;

// One light's smoke shadow map (SmokeMapGpu in src/render/gpu_types.rs), fitted to the
// particles' bounding sphere. Orthographic: texel (x, y)'s ray starts at origin + (ex·e.x
// + ey·e.y)·extent, e ∈ (−1, 1)² the texel centre, and runs along `axis`; depth is the
// distance from the plane through `origin` across `axis`. Perspective: the ray from the
// light `origin` along normalize(axis + (ex·e.x + ey·e.y)·extent) (extent: tangent of the
// half angle); depth is the distance from the light. Light li's maps are records
// SMOKE_MAPS_PER_LIGHT·li + f: a cube (kind SMOKE_MAP_CUBE on record 0, which is also face
// 0) has 90° perspective faces f in `cube_face` order, those that can see the smoke
// flagged in `faces` (the others read 1).
struct SmokeMap {
    origin: vec3f,
    kind: u32,
    axis: vec3f,
    extent: f32,
    ex: vec3f,
    offset: u32,      // first node of the map in smoke_nodes
    ey: vec3f,
    px: u32,          // texels a side
    nodes: u32,       // nodes per texel (the `avsm_nodes` setting)
    faces: u32,       // SMOKE_MAP_CUBE: bit f set where face f holds a map
    _pad1: u32,
    _pad2: u32,
}

// counters[]
const C_GRID_RAYS: u32 = 0u;
const C_FRUSTUM_RAYS: u32 = 1u;
const C_LIGHTING_RAYS: u32 = 2u;
const C_SURFACE_RAYS: u32 = 3u;
const C_VOXELS_TRACED: u32 = 4u;
const C_FROXELS_WITH_MEDIA: u32 = 5u;
const C_VOXELS_NEEDED: u32 = 6u;
const C_BRICKS: u32 = 7u;        // sparse grid: bricks requested this frame (allocation cursor)
const C_TRANSMITTANCE_NODES: u32 = 8u; // shared media transmittance nodes filled
const C_LAYER_BRICKS: u32 = 9u;  // media layer: bricks asked for this frame (in the pool or not)
const C_LAYER_NODES: u32 = 10u;  // media layer: nodes filled this frame
const C_GRID_MEDIA_VOXELS: u32 = 11u; // grid_media: voxels whose density was filled this frame
const C_RASTER_TRIANGLES: u32 = 12u; // triangle_cull: static triangles kept for the G-buffer (shaders/triangle_cull.wgsl)

// Sparse grid (paper 000 §5.1's proposal): the grid is cut into bricks of 8³ voxels; a
// table over all bricks holds 0 (unused), slot + 1 (allocated in the pool) or
// BRICK_MISSING (requested but the pool was full). A brick is 128 words of 4 voxels.
const BRICK: u32 = 8u;
const BRICK_VOXELS: u32 = 512u;
const BRICK_WORDS: u32 = 128u;
const BRICK_MISSING: u32 = 0xffffffffu;

fn brick_dims() -> vec3u {
    return (frame.grid_dims + BRICK - 1u) / BRICK;
}

// Brick of voxel q (inside the grid).
fn brick_of(q: vec3u) -> u32 {
    let d = brick_dims();
    let b = q / BRICK;
    return b.x + d.x * (b.y + d.y * b.z);
}

// Voxel q's index inside its brick (x fastest, so 4 neighbours along x share a word).
fn in_brick(q: vec3u) -> u32 {
    let l = q % BRICK;
    return l.x + BRICK * (l.y + BRICK * l.z);
}

// The dense grid's request bit at request coordinate r: (word, mask). Request
// coordinates are voxel coordinates + 1, 0 ..= dims along each axis (0: a trilinear
// lookup clamped below the grid), one bit each, every row along x padded to whole words.
fn request_bit(r: vec3u) -> vec2u {
    let d = frame.grid_dims;
    let row_words = (d.x + 32u) / 32u;
    return vec2u(r.x / 32u + row_words * (r.y + (d.y + 1u) * r.z), 1u << (r.x % 32u));
}

// The dense grid's request bit of a lookup whose lowest voxel is `c` (the nearest voxel,
// or the lowest of the 8 trilinear ones): `c` clamped into the grid (from −1 with
// `trilinear`: such a lookup reads voxel 0 as its upper corner), as a request coordinate.
fn lookup_request_bit(c: vec3i, trilinear: bool) -> vec2u {
    let lowest = select(0, -1, trilinear);
    return request_bit(vec3u(clamp(c, vec3i(lowest), vec3i(frame.grid_dims) - 1) + 1));
}

// The centre of grid voxel q, where the grid pass traces and fills it.
fn voxel_centre(q: vec3u) -> vec3f {
    return frame.grid_min + (vec3f(q) + 0.5) * frame.voxel_size;
}

// Voxel q's light bits as the grid pass traces them: the lights of `which` (a bitmask)
// with radiance at its centre (a spot's cone), one ray each, added to `rays`.
fn trace_voxel(q: vec3u, which: u32, rays: ptr<function, u32>) -> u32 {
    let centre = voxel_centre(q);
    var mask = 0u;
    for (var li = 0u; li < light_count(); li++) {
        if ((which >> li) & 1u) == 0u {
            continue;
        }
        let l = lights[li];
        if all(light_radiance(l, centre) == vec3f(0.0)) {
            continue; // outside a spot cone: no ray needed
        }
        *rays += 1u;
        if light_visible(l, centre) {
            mask |= 1u << li;
        }
    }
    return mask;
}

// The summed density of the media the grid carries (in_layer with FLAG_GRID_MEDIA) at
// `p`, as its 8-bit code: 1 + the density in steps of frame.grid_media_unit (0: not
// filled yet). Evaluated at `p` clamped into the box froxels read the grid in
// (frame.grid_media_min..max, which holds the media): a voxel beyond one of its faces
// holds the density at the face, so a trilinear read just inside runs up to the face
// undimmed instead of mixing in empty voxels the froxels outside never read.
fn density_code(p: vec3f) -> u32 {
    return code_of_density(grid_media_density(p));
}

// The density of the media the grid carries at `p` clamped into their box (density_code).
fn grid_media_density(p: vec3f) -> f32 {
    let q = clamp(p, frame.grid_media_min, frame.grid_media_max);
    var d = 0.0;
    for (var i = 0u; i < frame.medium_count; i++) {
        if media[i].in_layer == 1u {
            d += medium_density(media[i], q);
        }
    }
    return d;
}

fn code_of_density(d: f32) -> u32 {
    return 1u + u32(clamp(round(d / frame.grid_media_unit), 0.0, 254.0));
}

// With FLAG_GRID_MEDIA_FINE the grid's media density lattice is twice as fine as its
// light bits: each voxel holds 2 × 2 × 2 cells of half its edge, cell (x, y, z) centred
// at grid_min + (x + 0.5, y + 0.5, z + 0.5) · voxel_size / 2. Their codes follow the
// coarse words in `grid_density`, laid out like the coarse words at twice the
// resolution (4 cells a word along x, 2 · grid_words_x words a row), so a trilinear
// read pairs x-neighbours in one word as the coarse one does, and the coarse word
// (x, y, z) owns fine words 2x and 2x + 1 of rows 2y, 2y + 1 in slices 2z, 2z + 1.
// A voxel's cells are filled together with its coarse code, which then holds their
// mean and marks the voxel filled (docs/decisions.md, "Density in the shared grid").
fn fine_cell_centre(c: vec3u) -> vec3f {
    return frame.grid_min + (vec3f(c) + 0.5) * (0.5 * frame.voxel_size);
}

// The first word of the fine cells' row (y, z) in `grid_density`.
fn fine_row(y: u32, z: u32) -> u32 {
    let dims = frame.grid_dims;
    return frame.grid_words_x * dims.y * dims.z + 2u * frame.grid_words_x * (y + 2u * dims.y * z);
}

const PI: f32 = 3.14159265358979;
// Froxels store S / max(σt, SIGMA_EPS); below it the σt → 0 limit S·d is used.
const SIGMA_EPS: f32 = 1e-4;

// Unit ray direction through pixel-space point `pix` (y down) of view `v`.
fn view_ray(v: View, pix: vec2f) -> vec3f {
    let ndc = vec2f(2.0 * pix.x / f32(v.size.x) - 1.0, 1.0 - 2.0 * pix.y / f32(v.size.y));
    return normalize(v.forward + v.right * (ndc.x * v.tan_x) + v.up * (ndc.y * v.tan_y));
}

// A froxel's sample is `froxel_point(v, froxel_ray(v, xy), slice)`: its world point on the
// view ray through the froxel's centre, at the slice's centre depth. The lighting and
// grid-request stages both build it so, so they see exactly the same points.

// The unit view ray of froxel column `xy`.
fn froxel_ray(v: View, xy: vec2u) -> vec3f {
    return view_ray(v, froxel_pixel(v, xy));
}

// The pixel-space point froxel column `xy`'s ray goes through: its centre, or past the
// view's edge the last pixel centre.
fn froxel_pixel(v: View, xy: vec2u) -> vec2f {
    return min((vec2f(xy) + 0.5) * f32(v.froxel_px), vec2f(v.size) - 0.5);
}

// The sample point of `slice` on the column's ray `dir`.
fn froxel_point(v: View, dir: vec3f, slice: u32) -> vec3f {
    return point_at_depth(v, dir, froxel_depth(v, slice));
}

// The point at view depth `z` on view `v`'s ray `dir` (unit, from the eye).
fn point_at_depth(v: View, dir: vec3f, z: f32) -> vec3f {
    return v.position + dir * (z / dot(dir, v.forward));
}

// The view depth of `slice`'s samples: its centre, moved by this frame's jitter.
fn froxel_depth(v: View, slice: u32) -> f32 {
    return slice_depth(v, f32(slice) + 0.5 + v.jitter);
}

// Pixel-space point (y down) where world point p projects in view `v` (p at least
// `near` in front of the eye).
fn pixel_of(v: View, p: vec3f) -> vec2f {
    let d = p - v.position;
    let z = max(dot(d, v.forward), v.near);
    let ndc = vec2f(dot(d, v.right) / (z * v.tan_x), dot(d, v.up) / (z * v.tan_y));
    return vec2f(ndc.x + 1.0, 1.0 - ndc.y) * 0.5 * vec2f(v.size);
}

// Four froxel columns, c0 and c1 along each axis (corner k: bit 0 picks x from c1, bit 1
// y), and the weight f of c1 along each axis: a bilinear read between their rays.
struct Columns {
    c0: vec2f,
    c1: vec2f,
    f: vec2f,
}

// Corner k (0..4) of `cols`, and its bilinear weight.
fn column_corner(cols: Columns, k: u32) -> vec2u {
    return vec2u(select(cols.c0, cols.c1, vec2<bool>((k & 1u) != 0u, (k & 2u) != 0u)));
}

fn column_weight(cols: Columns, k: u32) -> f32 {
    let w = select(1.0 - cols.f, cols.f, vec2<bool>((k & 1u) != 0u, (k & 2u) != 0u));
    return w.x * w.y;
}

// The slot and column of invocation `gid` of workgroup `wg` in a froxel-column stage's
// dispatch over `n` workgroups: workgroup (x, y, z) works for slot (z + x) mod n.z, so
// that every run of consecutive workgroups mixes the slots. Lavapipe hands each of its
// threads one contiguous range of workgroups; with z alone naming the slot, a coupled
// stereo eye's near field and its partner's whole volume went to different threads and
// the partner's thread did all of its work alone. The map is one-to-one for every x.
fn column_slot(gid: vec3u, wg: vec3u, n: vec3u) -> vec3u {
    return vec3u(gid.xy, (wg.z + wg.x) % n.z);
}

// Index of froxel column (x, y) of viewer `view_index` in per-column buffers (culling's
// tile depths and slice limits).
fn column_index(v: View, view_index: u32, x: u32, y: u32) -> u32 {
    return view_index * v.froxel_dims.x * v.froxel_dims.y + x + v.froxel_dims.x * y;
}

// Continuous grid coordinate of `p`: voxel centres sit at integers.
fn grid_coord(p: vec3f) -> vec3f {
    return (p - frame.grid_min) / frame.voxel_size - 0.5;
}

// Linear index of voxel `c`, clamped into the grid (lookups clamp the same way).
fn voxel_index(c: vec3i) -> u32 {
    let q = vec3u(clamp(c, vec3i(0), vec3i(frame.grid_dims) - 1));
    return q.x + frame.grid_dims.x * (q.y + frame.grid_dims.y * q.z);
}

// View depth of the boundary at (fractional) slice coordinate `s`: an exponential
// distribution between near and far, z = near + (far − near)·(e^{k·s/N} − 1)/(e^k − 1).
// k = depth_curve; k = ln(far/near) is close to Wronski's pure near·(far/near)^{s/N},
// smaller k moves slices away from the eye (see `Settings::depth_curve`).
fn slice_depth(v: View, s: f32) -> f32 {
    let k = frame.depth_curve;
    return v.near + (v.far - v.near) * (exp(k * s / f32(frame.slices)) - 1.0) / (exp(k) - 1.0);
}

// Fractional slice coordinate of view depth `z` (inverse of `slice_depth`).
fn depth_to_slice(v: View, z: f32) -> f32 {
    let k = frame.depth_curve;
    let u = max(z - v.near, 0.0) / (v.far - v.near);
    return f32(frame.slices) * log(1.0 + u * (exp(k) - 1.0)) / k;
}

// Direction from `p` towards light `l` (xyz) and the shadow-ray length (w).
fn to_light(l: Light, p: vec3f) -> vec4f {
    if l.kind == LIGHT_DIRECTIONAL {
        return vec4f(-l.direction, frame.max_ray_m);
    }
    let d = l.position - p;
    let dist = length(d);
    return vec4f(d / max(dist, 1e-6), dist);
}

// Radiance arriving at `p` from `l`, ignoring occlusion. Point and spot lights fall
// off with the inverse square of the distance, clamped at 0.1 m so that a light inside
// a voxel or at a froxel centre stays finite.
fn light_radiance(l: Light, p: vec3f) -> vec3f {
    if l.kind == LIGHT_DIRECTIONAL {
        return l.radiance;
    }
    let d = l.position - p;
    let dist2 = max(dot(d, d), 0.01);
    var r = l.radiance / dist2;
    if l.kind == LIGHT_SPOT {
        let c = dot(-d * inverseSqrt(max(dot(d, d), 1e-12)), l.direction);
        r *= smoothstep(l.cos_outer, l.cos_inner, c);
    }
    return r;
}

fn hash3(c: vec3i) -> u32 {
    var h = (bitcast<u32>(c.x) * 0x8da6b343u) ^ (bitcast<u32>(c.y) * 0xd8163841u) ^ (bitcast<u32>(c.z) * 0xcb1ab31fu);
    h ^= h >> 16u;
    h *= 0x7feb352du;
    h ^= h >> 15u;
    h *= 0x846ca68bu;
    h ^= h >> 16u;
    return h;
}

fn lattice(c: vec3i) -> f32 {
    return f32(hash3(c) >> 8u) * (1.0 / 16777216.0);
}

fn value_noise(p: vec3f) -> f32 {
    let i = floor(p);
    let f = p - i;
    let u = f * f * (vec3f(3.0) - 2.0 * f);
    let c = vec3i(i);
    let x00 = mix(lattice(c), lattice(c + vec3i(1, 0, 0)), u.x);
    let x10 = mix(lattice(c + vec3i(0, 1, 0)), lattice(c + vec3i(1, 1, 0)), u.x);
    let x01 = mix(lattice(c + vec3i(0, 0, 1)), lattice(c + vec3i(1, 0, 1)), u.x);
    let x11 = mix(lattice(c + vec3i(0, 1, 1)), lattice(c + vec3i(1, 1, 1)), u.x);
    return mix(mix(x00, x10, u.y), mix(x01, x11, u.y), u.z);
}

fn fbm(p: vec3f, octaves: u32) -> f32 {
    var sum = 0.0;
    var amp = 1.0;
    var norm = 0.0;
    var q = p;
    for (var i = 0u; i < octaves; i++) {
        sum += amp * value_noise(q);
        norm += amp;
        amp *= 0.5;
        q *= 2.0;
    }
    return sum / norm;
}

// Width of a volume's soft edge as a fraction of its radius (media.rs VOLUME_EDGE_FRACTION).
const VOLUME_EDGE_FRACTION: f32 = 0.05;

// A volume's centre at the frame's time: the motion wraps every period (types.rs
// `Volume::center_at`).
fn volume_center(m: Medium) -> vec3f {
    let x = frame.time_s / m.period_s + 0.5;
    return m.center + m.velocity * (m.period_s * (x - floor(x) - 0.5));
}

// Density of a displaced-sphere volume (paper 004 §5.3; media.rs `volume_density`):
// smoothstep((R(û) − ρ)/w), R(û) = r·(1 + a·(2·fbm(f·û + offset) − 1)), w = 0.05·r.
fn volume_density(m: Medium, p: vec3f) -> f32 {
    let q = p - volume_center(m);
    let rho_sq = dot(q, q);
    let r = m.radius_or_falloff;
    let outer = r * (1.0 + m.disp_amplitude);
    if rho_sq >= outer * outer {
        return 0.0;
    }
    let edge = VOLUME_EDGE_FRACTION * r;
    let inner = r * (1.0 - m.disp_amplitude) - edge;
    if rho_sq <= inner * inner {
        return 1.0;
    }
    let rho = sqrt(rho_sq);
    var surface = r;
    if m.disp_amplitude > 0.0 {
        let n = fbm(q / rho * m.disp_frequency + m.disp_offset, m.disp_octaves);
        surface = r * (1.0 + m.disp_amplitude * (2.0 * n - 1.0));
    }
    let x = clamp((surface - rho) / edge, 0.0, 1.0);
    return x * x * (3.0 - 2.0 * x);
}

fn medium_density(m: Medium, p: vec3f) -> f32 {
    let inside_box = all(p >= m.min) && all(p <= m.max);
    var d = 0.0;
    switch m.kind {
        case MEDIUM_CONSTANT, MEDIUM_BOX: { d = select(0.0, 1.0, inside_box); }
        case MEDIUM_HEIGHT: { d = select(0.0, exp(-max(p.y - m.base_y, 0.0) / m.radius_or_falloff), inside_box); }
        case MEDIUM_VOLUME: { d = volume_density(m, p); }
        default: {
            let c = (m.min + m.max) * 0.5;
            let q = p - c;
            d = select(0.0, 1.0, dot(q, q) <= m.radius_or_falloff * m.radius_or_falloff);
        }
    }
    if d > 0.0 && m.noise_frequency > 0.0 {
        let q = (p - m.min - m.wind * frame.time_s) * m.noise_frequency;
        d *= max(1.0 + m.noise_amplitude * (2.0 * fbm(q, m.noise_octaves) - 1.0), 0.0);
    }
    return d;
}

struct MediumSample {
    scattering: vec3f,
    extinction: f32,   // grey: mean(σs) + σa
    emission: vec3f,
    g: f32,
}

// Every medium at p (what `reference` and the analytic paths read).
fn sample_media(p: vec3f) -> MediumSample {
    return sample_media_where(p, ALL_MEDIA);
}

// `sample_media_where(p, layer)`: every medium.
const ALL_MEDIA: u32 = 2u;

// The media at p whose `in_layer` is `layer` (0 or 1), or all of them (`ALL_MEDIA`):
// σs and emission summed, σt grey, g weighted by scattering.
fn sample_media_where(p: vec3f, layer: u32) -> MediumSample {
    var s = MediumSample(vec3f(0.0), 0.0, vec3f(0.0), 0.0);
    var gw = 0.0;
    for (var i = 0u; i < frame.medium_count; i++) {
        if layer != ALL_MEDIA && media[i].in_layer != layer {
            continue;
        }
        let m = media[i];
        let d = medium_density(m, p);
        if d <= 0.0 {
            continue;
        }
        let ss = m.scattering * d;
        s.scattering += ss;
        s.extinction += (ss.x + ss.y + ss.z) / 3.0 + m.absorption * d;
        s.emission += m.emission * d;
        let w = ss.x + ss.y + ss.z;
        s.g += m.g * w;
        gw += w;
    }
    if gw > 0.0 {
        s.g /= gw;
    }
    return s;
}

const LAYER_NODES: u32 = 729u; // 9³ per brick

// Index of brick `b` (in bricks) of the layer.
fn layer_brick_index(b: vec3u) -> u32 {
    return b.x + frame.layer_bricks.x * (b.y + frame.layer_bricks.y * b.z);
}

struct LayerRead {
    // Whether the layer answered (else the caller evaluates the layer's media itself).
    found: bool,
    s: MediumSample,
}

// The layer's media at p, trilinear between the 8 nodes around it; points outside the
// layer's bounds hold none of its media.
fn layer_read(p: vec3f) -> LayerRead {
    var s = MediumSample(vec3f(0.0), 0.0, vec3f(0.0), 0.0);
    let g = (p - frame.layer_min) / frame.layer_voxel;
    let span = vec3f(frame.layer_bricks * 8u);
    if any(g < vec3f(0.0)) || any(g > span) {
        return LayerRead(true, s);
    }
    let b = min(vec3u(g / 8.0), frame.layer_bricks - 1u);
    let t = layer_table[layer_brick_index(b)];
    if t == 0u {
        return LayerRead(false, s);
    }
    let local = clamp(g - vec3f(b * 8u), vec3f(0.0), vec3f(8.0));
    let base = min(vec3u(floor(local)), vec3u(7u));
    let f = local - vec3f(base);
    let first = (t - 1u) * LAYER_NODES;
    let full = (frame.flags & FLAG_LAYER_FULL) != 0u;
    var a = vec4f(0.0);
    var e = vec4f(0.0);
    for (var k = 0u; k < 8u; k++) {
        let o = vec3<bool>((k & 1u) != 0u, (k & 2u) != 0u, (k & 4u) != 0u);
        let q = base + select(vec3u(0u), vec3u(1u), o);
        let w3 = select(1.0 - f, f, o);
        let w = w3.x * w3.y * w3.z;
        let i = (first + q.x + 9u * (q.y + 9u * q.z)) * frame.layer_node_words;
        if full {
            a += w * vec4f(unpack2x16float(layer_pool[i]), unpack2x16float(layer_pool[i + 1u]));
            e += w * vec4f(unpack2x16float(layer_pool[i + 2u]), unpack2x16float(layer_pool[i + 3u]));
        } else {
            a.w += w * bitcast<f32>(layer_pool[i]);
        }
    }
    if full {
        s.scattering = max(a.xyz, vec3f(0.0));
        s.extinction = max(a.w, 0.0);
        s.emission = max(e.xyz, vec3f(0.0));
        let w = (s.scattering.x + s.scattering.y + s.scattering.z) / 3.0;
        s.g = select(0.0, clamp(e.w / w, -0.999, 0.999), w > 0.0);
    } else {
        let m = media[frame.layer_first];
        let d = max(a.w, 0.0);
        s.scattering = m.scattering * d;
        s.extinction = medium_extinction(m) * d;
        s.emission = m.emission * d;
        s.g = m.g;
    }
    return LayerRead(true, s);
}

// The media at p as every stage reads them: with the layer on, the media in it from the
// layer (analytically where it has no brick) and the others analytically; else all
// analytically (`reference`).
fn media_at(p: vec3f) -> MediumSample {
    if (frame.flags & FLAG_LAYER) == 0u {
        return sample_media(p);
    }
    var l = layer_read(p);
    if !l.found {
        l.s = sample_media_where(p, 1u);
    }
    return combine_media(l.s, sample_media_where(p, 0u));
}

// Two sets of media at one point as one: σs, σt and emission summed, g weighted by
// scattering.
fn combine_media(a: MediumSample, b: MediumSample) -> MediumSample {
    var s = a;
    let wa = a.scattering.x + a.scattering.y + a.scattering.z;
    let wb = b.scattering.x + b.scattering.y + b.scattering.z;
    s.g = select(0.0, (a.g * wa + b.g * wb) / (wa + wb), wa + wb > 0.0);
    s.scattering += b.scattering;
    s.extinction += b.extinction;
    s.emission += b.emission;
    return s;
}

// Extinction at p of the layer's media only (from the layer where it has the brick).
fn layer_extinction(p: vec3f) -> f32 {
    let l = layer_read(p);
    if l.found {
        return l.s.extinction;
    }
    return sample_media_where(p, 1u).extinction;
}

// Extinction of medium `m` per unit density (grey: mean(σs) + σa, as `sample_media`).
fn medium_extinction(m: Medium) -> f32 {
    return (m.scattering.x + m.scattering.y + m.scattering.z) / 3.0 + m.absorption;
}

// The part [t0, t1] of the segment p + dir·[0, dist] inside medium m's extent (t1 <= t0:
// none). Constant and height media fill their box (the scene's media bounds).
fn medium_span(m: Medium, p: vec3f, dir: vec3f, dist: f32) -> vec2f {
    let inv = 1.0 / select(dir, vec3f(1e-30), abs(dir) < vec3f(1e-30));
    let a = (m.min - p) * inv;
    let b = (m.max - p) * inv;
    let lo = min(a, b);
    let hi = max(a, b);
    var t0 = max(max(lo.x, lo.y), max(lo.z, 0.0));
    var t1 = min(min(hi.x, hi.y), min(hi.z, dist));
    if m.kind == MEDIUM_SPHERE || m.kind == MEDIUM_VOLUME {
        // A volume: the sphere of its outer radius where it is now.
        var centre = (m.min + m.max) * 0.5;
        var radius = m.radius_or_falloff;
        if m.kind == MEDIUM_VOLUME {
            centre = volume_center(m);
            radius *= 1.0 + m.disp_amplitude;
        }
        let oc = p - centre;
        let b_half = dot(oc, dir);
        let disc = b_half * b_half - (dot(oc, oc) - radius * radius);
        if disc < 0.0 {
            return vec2f(1.0, 0.0);
        }
        let s = sqrt(disc);
        t0 = max(t0, -b_half - s);
        t1 = min(t1, -b_half + s);
    }
    return vec2f(t0, t1);
}

// Most quadrature steps per medium of one shadow-ray march.
const MAX_MARCH_STEPS: f32 = 32.0;

// Optical depth ∫σt ds along p + dir·[0, dist] (dir unit): exact for homogeneous boxes,
// spheres and constant media (σt × the length inside), midpoint quadrature with steps of
// about `frame.media_step_m` through height fog, noisy media and volumes. Zero extinction
// gives 0 exactly. With the media layer on, the media in it are marched through the layer
// (one lookup per step for all of them) over the stretch of the segment they span.
fn media_optical_depth(p: vec3f, dir: vec3f, dist: f32) -> f32 {
    var tau = 0.0;
    let layer = (frame.flags & FLAG_LAYER) != 0u;
    // With the layer on, the stretch of the segment that crosses its media is marched
    // through the layer once, whatever the number of media in it.
    var lspan = vec2f(1e30, -1e30);
    for (var i = 0u; i < frame.medium_count; i++) {
        let m = media[i];
        let sigma = medium_extinction(m);
        if sigma <= 0.0 {
            continue;
        }
        let span = medium_span(m, p, dir, dist);
        let len = span.y - span.x;
        if len <= 0.0 {
            continue;
        }
        if layer && m.in_layer == 1u {
            lspan = vec2f(min(lspan.x, span.x), max(lspan.y, span.y));
            continue;
        }
        if m.kind != MEDIUM_HEIGHT && m.kind != MEDIUM_VOLUME && m.noise_frequency <= 0.0 {
            tau += sigma * len;
            continue;
        }
        let n = clamp(ceil(len / frame.media_step_m), 1.0, MAX_MARCH_STEPS);
        let h = len / n;
        var sum = 0.0;
        for (var k = 0.0; k < n; k += 1.0) {
            sum += medium_density(m, p + dir * (span.x + (k + 0.5) * h));
        }
        tau += sigma * sum * h;
    }
    let len = lspan.y - lspan.x;
    if len > 0.0 {
        let n = clamp(ceil(len / frame.media_step_m), 1.0, MAX_MARCH_STEPS);
        let h = len / n;
        var sum = 0.0;
        for (var k = 0.0; k < n; k += 1.0) {
            sum += layer_extinction(p + dir * (lspan.x + (k + 0.5) * h));
        }
        tau += sum * h;
    }
    return tau;
}

// An orthonormal basis (ex, ey) across unit direction n (Duff et al. 2017): the same
// in the fill and in every lookup, so a directional light's columns need no storage.
fn light_basis(n: vec3f) -> mat2x3f {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return mat2x3f(vec3f(1.0 + s * n.x * n.x * a, s * b, -s * n.x), vec3f(b, s + n.y * n.y * a, -n.y));
}

// oct_encode / oct_decode (octahedral unit directions): shaders/gbuffer_surface.wgsl,
// compiled with this file into every stage.

// The first node of column (x, y) of light `l`'s volume `v`, and the column's unit
// direction (nodes k lie at start + dir·spacing·k).
struct MediaColumn {
    start: vec3f,
    dir: vec3f,
}

fn media_column(l: Light, v: LightMedia, xy: vec2u) -> MediaColumn {
    let e = (vec2f(xy) + 0.5) / vec2f(v.dims.xy) * 2.0 - 1.0;
    if l.kind == LIGHT_DIRECTIONAL {
        let b = light_basis(l.direction);
        let across = vec2f(xy) * v.spacing - v.radius;
        return MediaColumn(v.centre + b[0] * across.x + b[1] * across.y - l.direction * v.radius, l.direction);
    }
    var dir = oct_decode(e);
    if v.tan_half > 0.0 {
        let axis = normalize(v.centre - l.position);
        let b = light_basis(axis);
        dir = normalize(axis + (b[0] * e.x + b[1] * e.y) * v.tan_half);
    }
    return MediaColumn(l.position + dir * v.near, dir);
}

// Continuous node coordinate of p in light `l`'s volume `v` (nodes at integers).
fn media_coord(l: Light, v: LightMedia, p: vec3f) -> vec3f {
    if l.kind == LIGHT_DIRECTIONAL {
        let b = light_basis(l.direction);
        let d = p - v.centre;
        return (vec3f(dot(d, b[0]), dot(d, b[1]), dot(d, l.direction)) + v.radius) / v.spacing;
    }
    let d = p - l.position;
    let r = length(d);
    var e = oct_encode(d / max(r, 1e-6));
    if v.tan_half > 0.0 {
        let axis = normalize(v.centre - l.position);
        let b = light_basis(axis);
        // Behind the light (z <= 0) nothing lies in the media's cone: the edge clamps.
        let z = max(dot(d, axis), 1e-6 * r);
        e = vec2f(dot(d, b[0]), dot(d, b[1])) / (z * v.tan_half);
    }
    return vec3f((e * 0.5 + 0.5) * vec2f(v.dims.xy) - 0.5, (r - v.near) / v.spacing);
}

// Shared transmittance of light `l` at p: exp(−τ) of the optical depth interpolated
// trilinearly between the 8 nodes of its volume around p, clamped at the volume's faces
// (before a column's first node no medium has been crossed; past its last no medium is
// left). Interpolating τ, not T, keeps a homogeneous medium exact along a column and
// lets T fall to 0 right behind the face of a dense medium, as it does.
fn lookup_media_t(l: Light, v: LightMedia, p: vec3f) -> f32 {
    let g = clamp(media_coord(l, v, p), vec3f(0.0), vec3f(v.dims - 1u));
    let base = min(vec3u(floor(g)), v.dims - 1u);
    let f = g - vec3f(base);
    let top = min(base + 1u, v.dims - 1u);
    var acc = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let o = vec3<bool>((k & 1u) != 0u, (k & 2u) != 0u, (k & 4u) != 0u);
        let q = select(base, top, o);
        let w3 = select(1.0 - f, f, o);
        acc += w3.x * w3.y * w3.z * media_t[v.offset + q.x + v.dims.x * (q.y + v.dims.y * q.z)];
    }
    return exp(-acc);
}

// Transmittance between p and light `li`: the media's (`media_transmittance`) times the
// smoke's (`smoke_transmittance`). Froxel lighting (near field and beyond), the smoke's own
// shading and, through `surface_transmittance`, the surfaces all read it.
fn light_transmittance(li: u32, p: vec3f) -> f32 {
    return media_transmittance(li, p) * smoke_transmittance(li, p);
}

// Transmittance of the media between p and light `li`, T = exp(−∫σt): from the shared
// volume where there is one, else by marching the shadow ray (`reference`).
fn media_transmittance(li: u32, p: vec3f) -> f32 {
    if frame.medium_count == 0u {
        return 1.0;
    }
    if (frame.flags & FLAG_MEDIA_T) != 0u && light_media[li].nodes > 0u {
        return lookup_media_t(lights[li], light_media[li], p);
    }
    let tl = to_light(lights[li], p);
    return exp(-media_optical_depth(p, tl.xyz, tl.w));
}

// As `light_transmittance`, for a point on a surface. Media often end where geometry
// begins (fog filling a room down to its floor): beyond that face a column's optical
// depth stops growing, so the trilinear lookup of a point just inside the face mixes in
// nodes outside and comes out too low (the floor too bright by ~σt·spacing). The volume
// is read a few spacings towards the light instead, where every node around the point
// is inside, and the rest of the way, that short segment, is integrated exactly.
// The smoke's transmittance (`smoke_transmittance`) multiplies it as it does
// `light_transmittance`.
//
// Where no medium's face lies within 1.75 spacings of the point (a directional light's
// nodes are `spacing` apart on every axis, so the 8 around the point lie within √3
// spacings of it, all on its side of every face), the volume reads right at the point,
// as a froxel's does: the surfaces of a scene whose media reach past its floor and walls
// need no march (docs/decisions.md, "Surfaces away from the media's faces").
fn surface_transmittance(li: u32, p: vec3f) -> f32 {
    if frame.medium_count == 0u || (frame.flags & FLAG_MEDIA_T) == 0u || light_media[li].nodes == 0u {
        return light_transmittance(li, p);
    }
    let l = lights[li];
    if l.kind == LIGHT_DIRECTIONAL && media_faces_beyond(p, 1.75 * light_media[li].spacing) {
        return lookup_media_t(l, light_media[li], p) * smoke_transmittance(li, p);
    }
    let tl = to_light(l, p);
    let back = min(3.0 * light_media[li].spacing, tl.w);
    let q = p + tl.xyz * back;
    let media = lookup_media_t(l, light_media[li], q) * exp(-media_optical_depth(p, tl.xyz, back));
    return media * smoke_transmittance(li, p);
}

// Whether every medium's density is continuous within `r` of p: no face of a medium's
// box within `r` (inside it, the nearest face; outside, the box), and p not inside the
// box of a sphere or volume (their surfaces are not boxes: those points keep the march).
// A medium without extinction counts too (no need to tell it apart here).
fn media_faces_beyond(p: vec3f, r: f32) -> bool {
    // The fields it needs one by one (a medium is 128 bytes).
    for (var i = 0u; i < frame.medium_count; i++) {
        let lo = media[i].min;
        let hi = media[i].max;
        let kind = media[i].kind;
        let inside = min(p - lo, hi - p);
        let depth_in = min(min(inside.x, inside.y), inside.z);
        if depth_in >= 0.0 && (depth_in <= r || kind == MEDIUM_SPHERE || kind == MEDIUM_VOLUME) {
            return false;
        }
        if depth_in < 0.0 && length(max(max(lo - p, p - hi), vec3f(0.0))) <= r {
            return false;
        }
    }
    return true;
}

// Henyey-Greenstein; cos_theta between the light's travel direction and the scattered one.
fn hg_phase(g: f32, cos_theta: f32) -> f32 {
    // 1 + g² − 2g·cosθ as two non-negative terms (precise near g → ±1; see media.rs).
    let d_pos = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - cos_theta);
    let d_neg = (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 + cos_theta);
    let denom = max(select(d_neg, d_pos, g >= 0.0), 1e-12);
    return (1.0 - g) * (1.0 + g) / (4.0 * PI * denom * sqrt(denom));
}

// ---- Ambient light: the constant `ambient`, or the shared SH grid --------------------

const SH_Y0: f32 = 0.2820948; // Y00 = 1/(2√π)
const SH_Y1: f32 = 0.4886025; // Y1m = √(3/(4π))·(y, z, x)

const SH_STRIDE: u32 = 5u;

// The accumulated grid's probes around `p`, interpolated trilinearly over the valid ones
// (a probe inside geometry is not) that see `p`: `p` inside the probe's free box (its
// free distance along each axis), so light does not leak through a wall or floor between
// a probe and the point; where none does, over every valid probe.
fn sh_at(p: vec3f) -> array<vec4f, 3> {
    let dims = frame.sh_dims;
    let c = clamp((p - frame.sh_min) / frame.sh_cell, vec3f(0.0), vec3f(dims - 1u));
    let c0 = min(vec3u(floor(c)), dims - 1u);
    let f = c - vec3f(c0);
    var acc = array<vec4f, 3>(vec4f(0.0), vec4f(0.0), vec4f(0.0));
    var total = 0.0;
    for (var pass_all = 0u; pass_all < 2u && total <= 1e-6; pass_all++) {
        for (var k = 0u; k < 8u; k++) {
            let o = vec3u(k & 1u, (k >> 1u) & 1u, k >> 2u);
            let q = min(c0 + o, dims - 1u);
            let w3 = select(1.0 - f, f, vec3<bool>(o == vec3u(1u)));
            let probe = (q.z * dims.y + q.y) * dims.x + q.x;
            let m0 = ambient_sh[SH_STRIDE * probe + 3u];
            var w = w3.x * w3.y * w3.z * m0.x;
            if pass_all == 0u {
                let m1 = ambient_sh[SH_STRIDE * probe + 4u];
                let d = p - (frame.sh_min + vec3f(q) * frame.sh_cell);
                let free = select(vec3f(m0.z, m1.x, m1.z), vec3f(m0.y, m0.w, m1.y), d >= vec3f(0.0));
                w = select(0.0, w, all(abs(d) < free));
            }
            if w > 0.0 {
                acc[0] += w * ambient_sh[SH_STRIDE * probe];
                acc[1] += w * ambient_sh[SH_STRIDE * probe + 1u];
                acc[2] += w * ambient_sh[SH_STRIDE * probe + 2u];
                total += w;
            }
        }
    }
    let inv = select(0.0, 1.0 / total, total > 1e-6);
    return array<vec4f, 3>(acc[0] * inv, acc[1] * inv, acc[2] * inv);
}

// Σ_lm k_l·c_lm·Y_lm(d) per channel, zonal factors k = (k0, k1), never negative.
fn sh_eval(sh: array<vec4f, 3>, d: vec3f, k0: f32, k1: f32) -> vec3f {
    let y = vec4f(k0 * SH_Y0, k1 * SH_Y1 * d.y, k1 * SH_Y1 * d.z, k1 * SH_Y1 * d.x);
    return max(vec3f(dot(sh[0], y), dot(sh[1], y), dot(sh[2], y)), vec3f(0.0));
}

// Ambient radiance a medium of HG `g` at `p` scatters toward an eye looking along
// `view_dir`: ∫ L(ω)·p(ω·view_dir) dω = Σ g^l·c_lm·Y_lm(view_dir) (Funk–Hecke), or the
// constant `ambient` (isotropic: the phase integrates to 1).
fn ambient_radiance(p: vec3f, view_dir: vec3f, g: f32) -> vec3f {
    if (frame.flags & FLAG_SH_AMBIENT) == 0u {
        return frame.ambient;
    }
    return sh_eval(sh_at(p), view_dir, 1.0, g);
}

// Ambient irradiance on a surface at `p` of normal `n`: the clamped cosine's zonal factors
// (π, 2π/3), or π·`ambient`.
fn ambient_irradiance(p: vec3f, n: vec3f) -> vec3f {
    if (frame.flags & FLAG_SH_AMBIENT) == 0u {
        return frame.ambient * PI;
    }
    // Lifted off the surface by a tenth of the spacing: inside the free box of the probes
    // on its side, outside those of the probes behind it.
    return sh_eval(sh_at(p + n * (0.1 * frame.sh_cell)), n, PI, 2.0 * PI / 3.0);
}

// In-scattered radiance per metre at `p` seen along `view_dir`, given the visibility
// of each light by opaque geometry (0..1); the light is dimmed by the media it crossed
// on its way to p (`light_transmittance`). Ambient light as `ambient_radiance`.
fn in_scattering(m: MediumSample, p: vec3f, view_dir: vec3f, vis: array<f32, 8>) -> vec3f {
    // The ambient light, then each light's (`scattered_light`; the sum is generated,
    // src/render/mod.rs `LightSum`).
    let l_in = scattered_lights(ambient_radiance(p, view_dir, m.g), m.g, p, view_dir, vis);
    return m.scattering * l_in + m.emission;
}

// Radiance per unit scattering coefficient that light `i` (visibility `vis[i]`) scatters
// at `p` towards an eye looking along `view_dir`, HG `g`.
fn scattered_light(i: u32, g: f32, p: vec3f, view_dir: vec3f, vis: array<f32, 8>) -> vec3f {
    if vis[i] <= 0.0 {
        return vec3f(0.0);
    }
    let l = lights[i];
    let wl = -to_light(l, p).xyz;
    return light_radiance(l, p) * hg_phase(g, dot(wl, -view_dir)) * (vis[i] * light_transmittance(i, p));
}

fn pack_rgba16(v: vec4f) -> vec2u {
    return vec2u(pack2x16float(v.xy), pack2x16float(v.zw));
}

fn unpack_rgba16(p: vec2u) -> vec4f {
    return vec4f(unpack2x16float(p.x), unpack2x16float(p.y));
}

// The cube face a point at `d` from the light falls on (`cube_face` in shadow_maps.rs):
// the axis of d's largest component, + before −.
fn cube_face(d: vec3f) -> u32 {
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, d.x >= 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, d.y >= 0.0);
    }
    return select(5u, 4u, d.z >= 0.0);
}

// ---- Smoke shadows: adaptive volumetric shadow maps (seed 002) ----------------------

// Where p falls in smoke map m: texel-space coordinate (texel centres at integers), the
// depth along the light ray, and whether the point is in the map's frustum at all.
struct SmokeCoord {
    texel: vec2f,
    depth: f32,
    inside: bool,
}

fn smoke_map_coord(m: SmokeMap, p: vec3f) -> SmokeCoord {
    let d = p - m.origin;
    var e: vec2f;
    var depth: f32;
    if m.kind == SMOKE_MAP_ORTHO {
        e = vec2f(dot(d, m.ex), dot(d, m.ey)) / m.extent;
        depth = dot(d, m.axis);
    } else {
        let z = dot(d, m.axis);
        if z <= 0.0 {
            return SmokeCoord(vec2f(0.0), 0.0, false);
        }
        e = vec2f(dot(d, m.ex), dot(d, m.ey)) / (z * m.extent);
        depth = length(d);
    }
    let inside = all(abs(e) <= vec2f(1.0));
    return SmokeCoord((e * 0.5 + 0.5) * f32(m.px) - 0.5, depth, inside);
}

// Texel xy's light ray in map m: its start and unit direction (depth = distance along it).
struct SmokeRay {
    start: vec3f,
    dir: vec3f,
}

fn smoke_texel_ray(m: SmokeMap, xy: vec2u) -> SmokeRay {
    let e = (vec2f(xy) + 0.5) / f32(m.px) * 2.0 - 1.0;
    let across = m.ex * e.x + m.ey * e.y;
    if m.kind == SMOKE_MAP_ORTHO {
        return SmokeRay(m.origin + across * m.extent, m.axis);
    }
    return SmokeRay(m.origin, normalize(m.axis + across * m.extent));
}

// One texel's curve at `depth` (002 Eq. 2, as `TransmittanceCurve::transmittance_at`):
// 1 in front of the first node, linear between nodes, the last value behind the last.
// Unused nodes sit at SMOKE_FAR_DEPTH with the last node's value.
fn smoke_curve_at(first: u32, count: u32, depth: f32) -> f32 {
    let n0 = smoke_nodes[first];
    if depth < n0.x {
        return 1.0;
    }
    var l = n0;
    for (var k = 1u; k < count; k++) {
        let r = smoke_nodes[first + k];
        if r.x > depth {
            return l.y + (depth - l.x) * (r.y - l.y) / (r.x - l.x);
        }
        l = r;
    }
    return l.y;
}

// Depth of a curve's unused nodes.
const SMOKE_FAR_DEPTH: f32 = 3.0e38;

// Transmittance of the smoke between p and light `li` from its AVSM: the curves of the 4
// texels around p, bilinearly (texels clamped at the map's edge, where the fitted map
// holds no smoke); 1 outside the map, without particles, or for a light without a map.
fn smoke_transmittance(li: u32, p: vec3f) -> f32 {
    if frame.particle_count == 0u {
        return 1.0;
    }
    var m = smoke_maps[li * SMOKE_MAPS_PER_LIGHT];
    if m.kind == SMOKE_MAP_NONE {
        return 1.0;
    }
    if m.kind == SMOKE_MAP_CUBE {
        let f = cube_face(p - m.origin);
        if ((m.faces >> f) & 1u) == 0u {
            return 1.0;
        }
        if f != 0u {
            m = smoke_maps[li * SMOKE_MAPS_PER_LIGHT + f];
        }
    }
    let c = smoke_map_coord(m, p);
    if !c.inside {
        return 1.0;
    }
    let top = m.px - 1u;
    let g = clamp(c.texel, vec2f(0.0), vec2f(f32(top)));
    let base = min(vec2u(floor(g)), vec2u(top));
    let f = g - vec2f(base);
    let hi = min(base + 1u, vec2u(top));
    var acc = 0.0;
    for (var k = 0u; k < 4u; k++) {
        let o = vec2<bool>((k & 1u) != 0u, (k & 2u) != 0u);
        let q = select(base, hi, o);
        let w2 = select(1.0 - f, f, o);
        let w = w2.x * w2.y;
        if w > 0.0 {
            acc += w * smoke_curve_at(m.offset + (q.x + m.px * q.y) * m.nodes, m.nodes, c.depth);
        }
    }
    return acc;
}
