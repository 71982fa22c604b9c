// Smoke particles (issue 15): every emitter's live particles at this frame's time, one
// invocation per particle, written where every later pass reads them (group 0 binding 12
// of the other stages). The GPU half of src/smoke/emitter.rs, which is its CPU twin: the
// host picks each emitter's live birth indices (integers), the shader places particle
// `first_index + k` from the same 32-bit hash draws in the same order.
//
// Prepended as every stage is (for `Particle`); this pass binds none of group 0.

struct Emitter {
    position: vec3f,
    shape: u32,        // 0 point, 1 sphere, 2 disc (EmitterShape)
    velocity: vec3f,   // initial velocity + wind, m/s
    radius: f32,
    scattering: vec3f,
    spread: f32,
    absorption: f32,
    g: f32,
    buoyancy: f32,
    growth: f32,
    falloff_u: f32,
    seed: u32,
    first_index: u32,  // birth index of the oldest live particle (mod 2³²)
    count: u32,        // live particles this frame
    age_first: f32,    // age of the oldest, seconds
    period: f32,       // 1 / rate: the age step from one particle to the next
    out_offset: u32,   // where its particles start in `particles_out`
    emitter: u32,
}

@group(1) @binding(0) var<storage, read> emitters: array<Emitter>;
@group(1) @binding(1) var<storage, read_write> particles_out: array<Particle>;
// [0]: emitters, [1]: particles in all.
@group(1) @binding(2) var<storage, read> sim_counts: array<u32>;

// Chris Wellons' lowbias32 (smoke::emitter::lowbias32).
fn hash_u32(x0: u32) -> u32 {
    var x = x0;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    return x ^ (x >> 16u);
}

struct Draws {
    state: u32,
}

fn draw_unit(d: ptr<function, Draws>) -> f32 {
    (*d).state += 0x9e3779b9u;
    return f32(hash_u32((*d).state) >> 8u) / 16777216.0;
}

fn draw_unit_vector(d: ptr<function, Draws>) -> vec3f {
    let z = 2.0 * draw_unit(d) - 1.0;
    let angle = 6.283185307179586 * draw_unit(d);
    let r = sqrt(max(1.0 - z * z, 0.0));
    return vec3f(r * cos(angle), r * sin(angle), z);
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    let i = gid.x;
    if i >= sim_counts[1] {
        return;
    }
    var e = emitters[0];
    for (var k = 1u; k < sim_counts[0]; k++) {
        if emitters[k].out_offset <= i {
            e = emitters[k];
        }
    }
    let k = i - e.out_offset;
    let age = max(e.age_first - f32(k) * e.period, 0.0);
    var d = Draws(hash_u32((e.first_index + k) ^ hash_u32(e.seed)));
    var birth = e.position;
    if e.shape == 1u {
        let dir = draw_unit_vector(&d);
        birth += dir * e.radius * pow(draw_unit(&d), 1.0 / 3.0);
    } else if e.shape == 2u {
        let angle = 6.283185307179586 * draw_unit(&d);
        let r = e.radius * sqrt(draw_unit(&d));
        birth += vec3f(r * cos(angle), 0.0, r * sin(angle));
    }
    let velocity = e.velocity + e.spread * draw_unit_vector(&d);
    var p: Particle;
    p.centre = birth + velocity * age + vec3f(0.0, 0.5 * e.buoyancy * age * age, 0.0);
    p.falloff_u = e.falloff_u + e.growth * age;
    p.scattering = e.scattering;
    p.absorption = e.absorption;
    p.g = e.g;
    p.index = e.first_index + k;
    p.emitter = e.emitter;
    p._pad = 0u;
    particles_out[i] = p;
}
