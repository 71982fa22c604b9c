// The shared ambient grid (issue 16, seed 003 §4's SH irradiance volume): world space,
// once per frame for every viewer (src/render/ambient_grid.rs).
//
// Each probe holds order-2 spherical harmonics of the radiance arriving at it from every
// direction except the lights' own (those every stage adds exactly): the sky through the
// media and past the geometry, the lights' single scattering in the media along the way,
// the surfaces' reflection of the lights, and — read back from the grid itself — every
// further bounce. `trace` estimates it from `RAYS` stratified, randomly turned rays per
// probe into this frame's half of the buffer; `blend` folds that estimate into the grid
// every stage reads, as seed 003 accumulates its SH volume over frames: the history
// clamped to the range of this frame's estimates in the probe's 3×3×3 neighbourhood,
// then an exponential average (`alpha`). The first frame runs both passes `WARMUP` times
// over every probe without the clamp (ambient_grid.rs), so one frame starts converged;
// later frames update a share of the probes each (`stride`), the others keep theirs.

struct Pass {
    // Seeds this pass's ray directions (the frame index, or the warm-up iteration).
    seed: u32,
    // Weight of this pass's estimate; 1 replaces the history.
    alpha: f32,
    // 1: clamp the history to the neighbourhood's estimates first.
    clamp_history: u32,
    // This pass updates the probes i ≡ phase (mod stride): a share of the grid a frame.
    stride: u32,
    phase: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// The probe invocation `t` of this pass updates (or one past the last probe).
fn pass_probe(t: u32) -> u32 {
    return t * pass_.stride + pass_.phase;
}

@group(1) @binding(0) var<storage, read> pass_: Pass;

const RAYS: u32 = 8u;
// Media steps per ray (jittered; homogeneous media are exact per step).
const MARCH_STEPS: u32 = 12u;
const GOLDEN_ANGLE: f32 = 2.39996323;

fn rand(a: u32, b: u32) -> f32 {
    return f32(hash3(vec3i(i32(a), i32(b), i32(pass_.seed))) >> 8u) / 16777216.0;
}

fn probe_position(i: u32) -> vec3f {
    let d = frame.sh_dims;
    let q = vec3u(i % d.x, (i / d.x) % d.y, i / (d.x * d.y));
    return frame.sh_min + vec3f(q) * frame.sh_cell;
}

// Radiance arriving at `o` from direction `w` (towards o along −w), without the lights
// seen directly; `near` is set when the ray met geometry within half a probe spacing.
fn radiance_from(o: vec3f, w: vec3f, jitter: f32, near: ptr<function, bool>) -> vec3f {
    let hit = closest_hit(o, w, 0.0, frame.max_ray_m);
    *near = hit.tri != 0xffffffffu && hit.t < 0.5 * frame.sh_cell;
    var l = vec3f(0.0);
    var tr = vec3f(1.0);
    if (frame.flags & FLAG_MEDIA) != 0u {
        let dt = hit.t / f32(MARCH_STEPS);
        for (var k = 0u; k < MARCH_STEPS; k++) {
            let x = o + w * ((f32(k) + jitter) * dt);
            let m = media_at(x);
            if m.extinction <= 0.0 && all(m.emission == vec3f(0.0)) {
                continue;
            }
            var vis: array<f32, 8>;
            for (var li = 0u; li < light_count(); li++) {
                vis[li] = select(0.0, 1.0, light_visible(lights[li], x));
            }
            let source = in_scattering(m, x, w, vis);
            let seg = exp(-m.extinction * dt);
            let mass = select(dt, (1.0 - seg) / m.extinction, m.extinction > 1e-6);
            l += tr * source * mass;
            tr *= seg;
        }
    }
    if hit.tri == 0xffffffffu {
        return l + tr * frame.sky;
    }
    let tri = bvh_tris[hit.tri];
    var n = normalize(cross(tri.e1.xyz, tri.e2.xyz));
    if dot(n, w) > 0.0 {
        n = -n;
    }
    let packed = bitcast<u32>(tri.v0.w);
    let albedo = vec3f(f32(packed & 255u), f32((packed >> 8u) & 255u), f32((packed >> 16u) & 255u)) / 255.0;
    let p = o + w * hit.t;
    let origin = p + n * (2e-3 + hit.t * 2e-4);
    var e = ambient_irradiance(origin, n);
    for (var li = 0u; li < light_count(); li++) {
        let lt = lights[li];
        let tl = to_light(lt, origin);
        let ndl = dot(n, tl.xyz);
        if ndl <= 0.0 || !light_visible(lt, origin) {
            continue;
        }
        e += light_radiance(lt, origin) * (ndl * surface_transmittance(li, origin));
    }
    return l + tr * albedo / PI * e;
}

@compute @workgroup_size(64)
fn trace(@builtin(global_invocation_id) gid: vec3u) {
    let i = pass_probe(gid.x);
    if i >= frame.sh_probes {
        return;
    }
    let o = probe_position(i);
    var acc = array<vec4f, 3>(vec4f(0.0), vec4f(0.0), vec4f(0.0));
    var near_hits = 0u;
    let turn = 6.2831853 * rand(i, 0xa5u);
    for (var r = 0u; r < RAYS; r++) {
        // Stratified in z (equal areas), turned at random: uniform over the sphere.
        let z = 1.0 - 2.0 * (f32(r) + rand(i, r)) / f32(RAYS);
        let phi = f32(r) * GOLDEN_ANGLE + turn;
        let s = sqrt(max(1.0 - z * z, 0.0));
        let w = vec3f(s * cos(phi), s * sin(phi), z);
        var near = false;
        let l = radiance_from(o, w, rand(i, r + 64u), &near);
        near_hits += u32(near);
        let y = vec4f(SH_Y0, SH_Y1 * w.y, SH_Y1 * w.z, SH_Y1 * w.x) * (4.0 * PI / f32(RAYS));
        if all(l == l) && all(abs(l) < vec3f(1e30)) {
            acc[0] += l.r * y;
            acc[1] += l.g * y;
            acc[2] += l.b * y;
        }
    }
    // A probe whose rays nearly all meet geometry at once is inside it.
    let valid = select(1.0, 0.0, near_hits * 8u >= RAYS * 7u);
    // How far it sees along each axis (the free box `sh_at` tests points against).
    var free: array<f32, 6>;
    for (var a = 0u; a < 6u; a++) {
        var w = vec3f(0.0);
        w[a / 2u] = select(1.0, -1.0, (a & 1u) == 1u);
        free[a] = closest_hit(o, w, 0.0, frame.max_ray_m).t;
    }
    let at = SH_STRIDE * (frame.sh_probes + i);
    ambient_sh[at] = acc[0];
    ambient_sh[at + 1u] = acc[1];
    ambient_sh[at + 2u] = acc[2];
    ambient_sh[at + 3u] = vec4f(valid, free[0], free[1], free[2]);
    ambient_sh[at + 4u] = vec4f(free[3], free[4], free[5], 0.0);
}

@compute @workgroup_size(64)
fn blend(@builtin(global_invocation_id) gid: vec3u) {
    let i = pass_probe(gid.x);
    if i >= frame.sh_probes {
        return;
    }
    let d = frame.sh_dims;
    let q = vec3i(vec3u(i % d.x, (i / d.x) % d.y, i / (d.x * d.y)));
    let cur = SH_STRIDE * (frame.sh_probes + i);
    for (var c = 0u; c < SH_STRIDE; c++) {
        var history = ambient_sh[SH_STRIDE * i + c];
        // The free distances are the same every pass; the SH and the validity blend.
        if pass_.clamp_history != 0u && c < 4u {
            var lo = vec4f(3e38);
            var hi = vec4f(-3e38);
            for (var k = 0; k < 27; k++) {
                let n = q + vec3i(k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1);
                if any(n < vec3i(0)) || any(n >= vec3i(d)) {
                    continue;
                }
                let j = (u32(n.z) * d.y + u32(n.y)) * d.x + u32(n.x);
                let v = ambient_sh[SH_STRIDE * (frame.sh_probes + j) + c];
                lo = min(lo, v);
                hi = max(hi, v);
            }
            history = clamp(history, lo, hi);
        }
        ambient_sh[SH_STRIDE * i + c] = mix(history, ambient_sh[cur + c], pass_.alpha);
    }
}
