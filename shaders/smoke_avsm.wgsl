// The smoke's adaptive volumetric shadow maps (seed 002), built once per frame for every
// viewer (world / light space; src/render/smoke_shadows.rs). One invocation per texel of
// a light's map (z runs over map records: SMOKE_MAPS_PER_LIGHT per light, a cube's faces): the GPU twin of `TransmittanceCurve::from_crossings`
// in src/smoke/avsm.rs, node for node.
//
// 1. Every live particle whose proxy (a sphere of PROXY_RADIUS_PER_U·u) the texel's ray
//    crosses at depth > 0 (clipped there), with an optical depth along the whole line of
//    at least NEGLIGIBLE_TAU, goes into a private list sorted by the depth of its first inserted node, ties
//    by its place in `particles` (emitter by emitter, oldest first: the particle index).
//    At most MAX_CROSSINGS are kept: past that the farthest (by that key) are dropped, so
//    what lies behind the 64 nearest blobs of one ray casts no more shadow.
// 2. The particles are inserted in that order: nodes at b − 0.2u, b, b + 0.2u clamped to
//    the proxy interval (b: where the ray passes closest to the centre), each new node the
//    curve's value there times the particle's exact transmittance (closed form with erf);
//    existing nodes behind the entry multiplied by the same; then the interior node whose
//    removal changes the area under the curve least goes until `nodes` are left.
// 3. The curve is written to smoke_nodes (unused nodes at SMOKE_FAR_DEPTH, last value).
//
// A particle's scalar extinction at its centre is mean(σs) + σa (the media's grey
// extinction, `medium_extinction`): the map holds one transmittance for all channels
// (smoke is grey in practice; a coloured σs darkens by its mean).

const MAX_CROSSINGS: u32 = 64u;
// 16 nodes at most, plus the 3 a particle inserts before removal.
const MAX_CURVE: u32 = 19u;
// A particle's proxy radius in units of u: σt < σ e^−112 beyond it.
const PROXY_RADIUS_PER_U: f32 = 1.5;
// Half-width of the inserted segment in units of u (two standard deviations).
const INSERT_HALF_WIDTH_PER_U: f32 = 0.2;
const SQRT_50: f32 = 7.0710678;
// A crossing whose whole line integral σ√π/k·e^{−k²h²} is below this is not inserted: it
// changes no transmittance by more than 1e-4, and big overlapping proxies (a plume's
// older particles, 1.5 u ≈ 9 m) would otherwise fill the MAX_CROSSINGS slots with such
// grazing crossings and drop the ones that shadow.
const NEGLIGIBLE_TAU: f32 = 1e-4;

var<private> keys: array<f32, 64>;
var<private> ids: array<u32, 64>;
var<private> nd: array<f32, 19>;
var<private> nt: array<f32, 19>;
var<private> n_count: u32;

// Particle i along a light ray: proxy entry and exit depths, b (depth of the point
// closest to the centre), h² (squared distance of the ray from the centre), σ, u.
struct Crossing {
    hit: bool,
    entry: f32,
    exit: f32,
    b: f32,
    h2: f32,
    sigma: f32,
    u: f32,
}

fn crossing_of(ray: SmokeRay, i: u32) -> Crossing {
    let p = particles[i];
    let sigma = (p.scattering.x + p.scattering.y + p.scattering.z) / 3.0 + p.absorption;
    var c = Crossing(false, 0.0, 0.0, 0.0, 0.0, sigma, p.falloff_u);
    if p.falloff_u <= 0.0 || sigma <= 0.0 {
        return c;
    }
    let r = PROXY_RADIUS_PER_U * p.falloff_u;
    let to_centre = p.centre - ray.start;
    let b = dot(to_centre, ray.dir);
    let h2 = max(dot(to_centre, to_centre) - b * b, 0.0);
    if h2 >= r * r {
        return c;
    }
    let k = SQRT_50 / p.falloff_u;
    if sigma * sqrt(PI) / k * exp(-k * k * h2) < NEGLIGIBLE_TAU {
        return c;
    }
    let half_chord = sqrt(r * r - h2);
    // The ray starts at depth 0 (the light, or the orthographic map's plane upstream of
    // all the smoke): a proxy behind it is on no point's way to the light, and one around
    // it (a lamp inside the smoke) counts from the light on.
    if b + half_chord <= 0.0 {
        return c;
    }
    c.hit = true;
    c.entry = max(b - half_chord, 0.0);
    c.exit = b + half_chord;
    c.b = b;
    c.h2 = h2;
    return c;
}

// The crossing's insertion-order key: the depth of its first inserted node.
fn first_insert_depth(c: Crossing) -> f32 {
    return clamp(c.b - INSERT_HALF_WIDTH_PER_U * c.u, c.entry, c.exit);
}

// erf(x), Abramowitz & Stegun 7.1.26 (absolute error below 1.5e-7).
fn erf_approx(x: f32) -> f32 {
    let a = abs(x);
    let t = 1.0 / (1.0 + 0.3275911 * a);
    let poly = ((((1.061405429 * t - 1.453152027) * t + 1.421413741) * t - 0.284496736) * t + 0.254829592) * t;
    return sign(x) * (1.0 - poly * exp(-a * a));
}

// The particle's own transmittance from its entry to `depth` (1 before the entry, the
// whole crossing's behind the exit): 001 Eq. 10's closed form,
// τ = σ √π/(2k) e^{−k²h²} (erf(k(s1 − b)) − erf(k(s0 − b))), k = √50/u.
fn particle_t(c: Crossing, depth: f32) -> f32 {
    let s1 = min(depth, c.exit);
    if s1 <= c.entry {
        return 1.0;
    }
    let k = SQRT_50 / c.u;
    let scale = c.sigma * sqrt(PI) / (2.0 * k) * exp(-k * k * c.h2);
    let tau = scale * (erf_approx(k * (s1 - c.b)) - erf_approx(k * (c.entry - c.b)));
    return exp(-max(tau, 0.0));
}

// The private curve at `depth` (before the particle being inserted).
fn curve_at(depth: f32) -> f32 {
    if n_count == 0u || depth < nd[0] {
        return 1.0;
    }
    for (var k = 1u; k < n_count; k++) {
        if nd[k] > depth {
            return nt[k - 1u] + (depth - nd[k - 1u]) * (nt[k] - nt[k - 1u]) / (nd[k] - nd[k - 1u]);
        }
    }
    return nt[n_count - 1u];
}

fn curve_has(depth: f32) -> bool {
    for (var k = 0u; k < n_count; k++) {
        if nd[k] == depth {
            return true;
        }
    }
    return false;
}

// Removes the interior node spanning the smallest triangle (002 §3.2; ties: the nearest).
fn remove_least_area_node() {
    var best = 1u;
    var best_change = 3.0e38;
    for (var i = 1u; i + 1u < n_count; i++) {
        let change = abs((nd[i + 1u] - nd[i - 1u]) * (nt[i + 1u] - nt[i]) - (nd[i + 1u] - nd[i]) * (nt[i + 1u] - nt[i - 1u]));
        if change < best_change {
            best = i;
            best_change = change;
        }
    }
    for (var k = best; k + 1u < n_count; k++) {
        nd[k] = nd[k + 1u];
        nt[k] = nt[k + 1u];
    }
    n_count -= 1u;
}

// Composites one particle into the curve, then removes nodes down to `max_nodes`.
fn insert_crossing(c: Crossing, max_nodes: u32) {
    let half = INSERT_HALF_WIDTH_PER_U * c.u;
    let cand = array<f32, 3>(
        clamp(c.b - half, c.entry, c.exit),
        clamp(c.b, c.entry, c.exit),
        clamp(c.b + half, c.entry, c.exit),
    );
    // The new nodes (distinct, not already in the curve) with the curve's value there.
    var new_d: array<f32, 3>;
    var new_t: array<f32, 3>;
    var new_count = 0u;
    for (var j = 0u; j < 3u; j++) {
        let d = cand[j];
        if (j > 0u && d == cand[j - 1u]) || curve_has(d) {
            continue;
        }
        new_d[new_count] = d;
        new_t[new_count] = curve_at(d);
        new_count += 1u;
    }
    for (var k = 0u; k < n_count; k++) {
        if nd[k] > c.entry {
            nt[k] *= particle_t(c, nd[k]);
        }
    }
    for (var j = 0u; j < new_count; j++) {
        let d = new_d[j];
        var at = n_count;
        while at > 0u && nd[at - 1u] >= d {
            nd[at] = nd[at - 1u];
            nt[at] = nt[at - 1u];
            at -= 1u;
        }
        nd[at] = d;
        nt[at] = new_t[j] * particle_t(c, d);
        n_count += 1u;
    }
    while n_count > max_nodes {
        remove_least_area_node();
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    // One map record per z: light gid.z / SMOKE_MAPS_PER_LIGHT, face gid.z % it.
    if gid.z / SMOKE_MAPS_PER_LIGHT >= light_count() {
        return;
    }
    let m = smoke_maps[gid.z];
    if m.kind == SMOKE_MAP_NONE || gid.x >= m.px || gid.y >= m.px {
        return;
    }
    if m.kind == SMOKE_MAP_CUBE && (m.faces & 1u) == 0u {
        return;
    }
    let ray = smoke_texel_ray(m, gid.xy);
    // 1. The crossings in insertion order (particles arrive in index order, so a tie
    //    goes behind the earlier particle).
    var count = 0u;
    for (var i = 0u; i < frame.particle_count; i++) {
        let c = crossing_of(ray, i);
        if !c.hit {
            continue;
        }
        let key = first_insert_depth(c);
        if count == MAX_CROSSINGS && key >= keys[MAX_CROSSINGS - 1u] {
            continue;
        }
        var at = min(count, MAX_CROSSINGS - 1u);
        while at > 0u && keys[at - 1u] > key {
            keys[at] = keys[at - 1u];
            ids[at] = ids[at - 1u];
            at -= 1u;
        }
        keys[at] = key;
        ids[at] = i;
        count = min(count + 1u, MAX_CROSSINGS);
    }
    // 2. Insertion with removal.
    n_count = 0u;
    let max_nodes = min(m.nodes, MAX_CURVE - 3u);
    for (var k = 0u; k < count; k++) {
        insert_crossing(crossing_of(ray, ids[k]), max_nodes);
    }
    // 3. The curve.
    let first = m.offset + (gid.x + m.px * gid.y) * m.nodes;
    var last = 1.0;
    for (var k = 0u; k < m.nodes; k++) {
        if k < n_count {
            last = nt[k];
            smoke_nodes[first + k] = vec2f(nd[k], nt[k]);
        } else {
            smoke_nodes[first + k] = vec2f(SMOKE_FAR_DEPTH, last);
        }
    }
}

// Test probe (`Renderer::probe_smoke_transmittance`): the lookup every stage uses, at
// probe_points[i].xyz for light probe_points[i].w.
@group(1) @binding(0) var<storage, read> probe_points: array<vec4f>;
@group(1) @binding(1) var<storage, read_write> probe_out: array<f32>;

@compute @workgroup_size(64, 1, 1)
fn probe(@builtin(global_invocation_id) gid: vec3u) {
    let i = gid.x;
    if i >= arrayLength(&probe_points) {
        return;
    }
    let q = probe_points[i];
    probe_out[i] = smoke_transmittance(u32(q.w), q.xyz);
}
