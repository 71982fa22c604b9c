// Smoke per viewer (issue 15, paper 001): what the proxy pass (smoke_proxies.wgsl) and the
// raster (smoke_raster.wgsl) share — the sorted proxy record, the tetrahedron, and the
// f32 error functions of the interval integral (CPU twin: src/smoke/interval.rs).

// One particle in a viewer's back-to-front list (SMOKE_PROXY_BYTES in smoke_view.rs).
struct SmokeProxy {
    centre: vec3f,
    radius: f32,       // inradius of the tetrahedron: PROXY_INRADIUS · u (0: draws nothing)
    scattering: vec3f, // σs at the centre, m⁻¹
    absorption: f32,   // σa at the centre, m⁻¹
    vis: vec2u,        // geometry visibility of lights 0–7 at the centre, 8 bits each
    falloff_u: f32,
    g: f32,
    key: f32,          // the sort key: distance from the eye to the centre, metres
    index: u32,        // the particle's slot in `particles`
    _pad0: u32,
    _pad1: u32,
}

// The proxy is a regular tetrahedron circumscribing the sphere of radius 0.6·u around the
// centre: there σt is e^{−18} of its peak, and the optical depth a ray leaves outside along
// any chord is below σ·u·√π/(2√50)·erfc(0.6·√50) ≈ 6·10⁻¹⁰·σ·u (docs/decisions.md).
const PROXY_INRADIUS: f32 = 0.6;

// Unit directions of its four vertices (circumradius = 3 × inradius); face k lies opposite
// vertex k, with outward normal −TETRA_DIRS[k] at the inradius from the centre.
const TETRA_DIRS = array<vec3f, 4>(
    vec3f(0.57735027, 0.57735027, 0.57735027),
    vec3f(0.57735027, -0.57735027, -0.57735027),
    vec3f(-0.57735027, 0.57735027, -0.57735027),
    vec3f(-0.57735027, -0.57735027, 0.57735027),
);
// The 12 corners of the four faces, counter-clockwise seen from outside.
const TETRA_CORNERS = array<u32, 12>(1u, 3u, 2u, 0u, 2u, 3u, 0u, 3u, 1u, 0u, 1u, 2u);

const SQRT_50: f32 = 7.0710678;
const SQRT_PI: f32 = 1.7724539;

// erfc(x) for x ≥ 0 with a relative error below 1.2·10⁻⁷ everywhere (Numerical Recipes'
// Chebyshev fit), so that the tail stays accurate where erf(x) rounds to 1.
fn smoke_erfc_pos(x: f32) -> f32 {
    let t = 1.0 / (1.0 + 0.5 * x);
    let p = -1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (-0.18628806
        + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    return t * exp(-x * x + p);
}

// erf(x2) − erf(x1) for x1 ≤ x2 without catastrophic cancellation (`erf_diff` in
// interval.rs): close together, 4-point Gauss–Legendre of 2/√π·e^{−t²}; on one side of
// 0, the difference of the erfc tails; straddling 0, 2 − erfc(x2) − erfc(−x1).
fn smoke_erf_diff(x1: f32, x2: f32) -> f32 {
    let w = x2 - x1;
    if !(w > 0.0) {
        return 0.0;
    }
    let m = 0.5 * (x1 + x2);
    if w * max(1.0, abs(m)) < 0.5 {
        let h = 0.5 * w;
        let a = 0.33998104 * h;
        let b = 0.86113631 * h;
        let s = 0.65214515 * (exp(-(m - a) * (m - a)) + exp(-(m + a) * (m + a)))
            + 0.34785485 * (exp(-(m - b) * (m - b)) + exp(-(m + b) * (m + b)));
        return 2.0 / SQRT_PI * h * s;
    }
    if x1 >= 0.0 {
        return smoke_erfc_pos(x1) - smoke_erfc_pos(x2);
    }
    if x2 <= 0.0 {
        return smoke_erfc_pos(-x2) - smoke_erfc_pos(-x1);
    }
    return 2.0 - smoke_erfc_pos(x2) - smoke_erfc_pos(-x1);
}

// 1 − e^{−x}, x ≥ 0, accurate in relative terms for small x.
fn smoke_one_minus_exp(x: f32) -> f32 {
    if x < 1e-3 {
        return x * (1.0 - x * (0.5 - x / 6.0));
    }
    return 1.0 - exp(-x);
}

// The scalar extinction at the centre: σa + mean σs (one alpha per particle).
fn smoke_sigma_t(p: SmokeProxy) -> f32 {
    return p.absorption + (p.scattering.x + p.scattering.y + p.scattering.z) / 3.0;
}
