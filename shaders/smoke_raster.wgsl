// Smoke raster, one render pass per viewer into its layer of the set's smoke texture
// (premultiplied over, back to front: the proxy list's order). Each fragment of a
// tetrahedron's back face integrates the particle along its pixel's eye ray (001 §3.7–
// 3.10): the interval between the ray's entry and exit planes, the entry clamped to the
// near plane (a particle crossing it or around the eye is clipped, not dropped), the exit
// to the G-buffer's surface (occlusion; sky: the far plane). τ in closed form (001 Eq. 10,
// corrected), A = e^{−τ}; in-scattering in a form that stays bounded for σ to 10⁴ m⁻¹:
// ∫ L(s) dF(s), F = 1 − T_V, over `steps` + 1 Simpson nodes, each node's light times the
// exact mass dF of its cell. The fog around it from the viewer's integrated volume at the
// closest approach d: rgb = a·F_fog(d) + T_fog(d)·C, alpha = a.

@group(1) @binding(0) var<storage, read> integrated: array<vec2u>;
@group(1) @binding(1) var<storage, read> proxies: array<SmokeProxy>;
@group(1) @binding(2) var gbuf: texture_2d_array<u32>;
@group(1) @binding(3) var<uniform> sv: SmokeView;

// One viewer's pass (SmokeViewUniform in smoke_view.rs).
struct SmokeView {
    view_proj: mat4x4f,
    slot: u32,   // the viewer's slot in the set (its layer, its view, its proxy list)
    stride: u32, // proxy records per viewer
    steps: u32,  // smoke_simpson_steps
    _pad: u32,
}

struct VsOut {
    @builtin(position) clip: vec4f,
    @location(0) @interpolate(flat) record: u32,
}

@vertex
fn vs_main(@builtin(vertex_index) vid: u32, @builtin(instance_index) inst: u32) -> VsOut {
    let record = sv.slot * sv.stride + inst;
    let p = proxies[record];
    let world = p.centre + TETRA_DIRS[TETRA_CORNERS[vid]] * (3.0 * p.radius);
    var clip = sv.view_proj * vec4f(world, 1.0);
    // No depth range: clipped at the eye plane alone (z = w/2 keeps 0 ≤ z ≤ w exactly
    // where w ≥ 0), so a back face behind the far plane or across the near plane still
    // covers its pixels; the fragment clamps the interval itself.
    clip.z = 0.5 * clip.w;
    var o: VsOut;
    o.clip = clip;
    o.record = record;
    return o;
}

// Optical depth of the particle between ray parameters ta ≤ tb (metres from the eye):
// `scale` = σ·√π/(2k)·e^{−k²h²}, `b` the closest approach, k = √50/u.
fn smoke_tau(scale: f32, k: f32, b: f32, ta: f32, tb: f32) -> f32 {
    return scale * smoke_erf_diff(k * (ta - b), k * (tb - b));
}

// Light scattered towards the eye per unit of dF at x (before the albedo).
fn smoke_light(p: SmokeProxy, x: f32, pt: vec3f, dir: vec3f) -> vec3f {
    var l_in = vec3f(0.0);
    for (var li = 0u; li < light_count(); li++) {
        let l = lights[li];
        // Geometry: the shared shadow map at this node where the light has one (a
        // particle straddling a sun shaft is lit only inside it), else the proxy pass's
        // one shadow ray from the particle's centre.
        var vis = 0.0;
        if has_map(li) {
            vis = map_visibility(li, l, pt, to_light(l, pt).xyz, 1.0);
        } else {
            let word = select(p.vis.y, p.vis.x, li < 4u);
            vis = f32((word >> (8u * (li & 3u))) & 255u) / 255.0;
        }
        if vis <= 0.0 {
            continue;
        }
        let wl = -to_light(l, pt).xyz;
        l_in += light_radiance(l, pt) * hg_phase(p.g, dot(wl, -dir)) * (vis * light_transmittance(li, pt));
    }
    return l_in;
}

@fragment
fn fs_main(i: VsOut) -> @location(0) vec4f {
    let p = proxies[i.record];
    let v = views[sv.slot];
    let pix = i.clip.xy;
    let dir = view_ray(v, pix);
    let cos_f = max(dot(dir, v.forward), 1e-6);
    let sigma = smoke_sigma_t(p);
    if !(p.radius > 0.0 && sigma > 0.0) {
        return vec4f(0.0);
    }
    // The tetrahedron's interval along the ray, relative to the centre (precision far
    // from the origin): plane k holds x with dot(n_k, x − c) ≤ r.
    let oc = v.position - p.centre;
    var t0 = v.near / cos_f;
    var t1 = 3.0e38;
    for (var k = 0u; k < 4u; k++) {
        let n = -TETRA_DIRS[k];
        let denom = dot(n, dir);
        let num = p.radius - dot(n, oc);
        if denom < 0.0 {
            t0 = max(t0, num / denom);
        } else if denom > 0.0 {
            t1 = min(t1, num / denom);
        } else if num < 0.0 {
            return vec4f(0.0);
        }
    }
    // Occlusion by the surface (or the far plane over the sky).
    let depth = surface_depth(textureLoad(gbuf, vec2i(floor(pix)), i32(sv.slot), 0));
    let depth_end = select(v.far, depth, depth > 0.0);
    t1 = min(t1, depth_end / cos_f);
    if !(t1 > t0) {
        return vec4f(0.0);
    }
    let u = p.falloff_u;
    let k = SQRT_50 / u;
    let b = -dot(oc, dir);
    let off = oc + b * dir;
    let scale = sigma * SQRT_PI / (2.0 * k) * exp(-k * k * dot(off, off));
    let tau = smoke_tau(scale, k, b, t0, t1);
    let a = smoke_one_minus_exp(tau);
    if !(a > 0.0) {
        return vec4f(0.0);
    }
    // ∫ L dF over cells centred on the nodes t0 + j·h (half cells at the ends).
    let steps = max(sv.steps, 2u);
    let h = (t1 - t0) / f32(steps);
    var before = 0.0; // τ from t0 to the current cell's start
    var scattered = vec3f(0.0);
    for (var j = 0u; j <= steps; j++) {
        let lo = t0 + max(f32(j) - 0.5, 0.0) * h;
        let hi = select(t0 + (f32(j) + 0.5) * h, t1, j == steps);
        let cell = smoke_tau(scale, k, b, lo, hi);
        let df = exp(-before) * smoke_one_minus_exp(cell);
        before += cell;
        if df > 1e-7 {
            let t = t0 + f32(j) * h;
            scattered += df * smoke_light(p, t, v.position + dir * t, dir);
        }
    }
    let albedo = p.scattering / sigma;
    let c = albedo * (scattered + ambient_radiance(p.centre, dir, 0.0) * a);
    // The fog in front of the particle, at its closest approach on the interval.
    var fog = vec4f(0.0, 0.0, 0.0, 1.0);
    if (frame.flags & FLAG_MEDIA) != 0u {
        let t = clamp(b, t0, t1);
        fog = sample_integrated(v, pix, t * cos_f);
    }
    let out = vec4f(a * fog.rgb + fog.w * c, a);
    return select(vec4f(0.0), out, all(out == out) && all(abs(out) <= vec4f(6.0e4)));
}
