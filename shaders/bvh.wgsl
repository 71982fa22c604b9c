// Any-hit shadow rays through the CPU-built BVH (src/scene/bvh.rs).

struct BvhNode {
    min: vec3f,
    prim_count: u32,
    max: vec3f,
    first_index: u32,
}

struct BvhTriangle {
    v0: vec4f,
    e1: vec4f,
    e2: vec4f,
}

fn ray_box(o: vec3f, inv_d: vec3f, t_max: f32, lo: vec3f, hi: vec3f) -> bool {
    let t0 = (lo - o) * inv_d;
    let t1 = (hi - o) * inv_d;
    let tmin = max(max(min(t0.x, t1.x), min(t0.y, t1.y)), max(min(t0.z, t1.z), 0.0));
    let tmax = min(min(max(t0.x, t1.x), max(t0.y, t1.y)), min(max(t0.z, t1.z), t_max));
    return tmin <= tmax;
}

// Möller–Trumbore, as `intersect_triangle` in src/scene/bvh.rs.
fn ray_triangle(o: vec3f, d: vec3f, t_min: f32, t_max: f32, tri: BvhTriangle) -> bool {
    let p = cross(d, tri.e2.xyz);
    let det = dot(tri.e1.xyz, p);
    if abs(det) < 1e-12 {
        return false;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0.xyz;
    let u = dot(s, p) * inv;
    if u < 0.0 || u > 1.0 {
        return false;
    }
    let q = cross(s, tri.e1.xyz);
    let v = dot(d, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let t = dot(tri.e2.xyz, q) * inv;
    return t > t_min && t < t_max;
}

// True when the static scene blocks the segment o + t·d, t in (t_min, t_max).
fn occluded(o: vec3f, d: vec3f, t_min: f32, t_max: f32) -> bool {
    let inv_d = 1.0 / select(d, vec3f(1e-30), abs(d) < vec3f(1e-30));
    return occluded_in(0u, o, d, inv_d, t_min, t_max);
}

// As `occluded`, then the movers' tree (frame.mover_root), if the scene has movers.
fn occluded_with_movers(o: vec3f, d: vec3f, t_min: f32, t_max: f32) -> bool {
    let inv_d = 1.0 / select(d, vec3f(1e-30), abs(d) < vec3f(1e-30));
    return occluded_in(0u, o, d, inv_d, t_min, t_max)
        || (frame.mover_root != 0xffffffffu && occluded_in(frame.mover_root, o, d, inv_d, t_min, t_max));
}

fn occluded_in(root_index: u32, o: vec3f, d: vec3f, inv_d: vec3f, t_min: f32, t_max: f32) -> bool {
    let root = bvh_nodes[root_index];
    if root.min.x > root.max.x {
        return false; // empty tree
    }
    var stack: array<u32, 64>;
    var sp = 1u;
    stack[0] = root_index;
    while sp > 0u {
        sp -= 1u;
        let node = bvh_nodes[stack[sp]];
        if !ray_box(o, inv_d, t_max, node.min, node.max) {
            continue;
        }
        if node.prim_count > 0u {
            for (var i = 0u; i < node.prim_count; i++) {
                if ray_triangle(o, d, t_min, t_max, bvh_tris[node.first_index + i]) {
                    return true;
                }
            }
        } else if sp + 2u <= 64u {
            stack[sp] = node.first_index;
            stack[sp + 1u] = node.first_index + 1u;
            sp += 2u;
        }
    }
    return false;
}

// Shadow ray from `p` to light `l`; true when the light reaches `p`.
fn light_visible(l: Light, p: vec3f) -> bool {
    let tl = to_light(l, p);
    // Relative epsilons keep rays from re-hitting the surface they start on.
    let eps = 1e-4 * (1.0 + length(p) * 0.01);
    return !occluded_with_movers(p, tl.xyz, eps, tl.w - eps);
}

// Möller–Trumbore's hit distance along d (−1 where the ray misses).
fn ray_triangle_t(o: vec3f, d: vec3f, tri: BvhTriangle) -> f32 {
    let p = cross(d, tri.e2.xyz);
    let det = dot(tri.e1.xyz, p);
    if abs(det) < 1e-12 {
        return -1.0;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0.xyz;
    let u = dot(s, p) * inv;
    let q = cross(s, tri.e1.xyz);
    let v = dot(d, q) * inv;
    if u < 0.0 || u > 1.0 || v < 0.0 || u + v > 1.0 {
        return -1.0;
    }
    return dot(tri.e2.xyz, q) * inv;
}

// The nearest static triangle on o + t·d, t in (t_min, t_max): (t, triangle index), or
// (t_max, 0xffffffff) where none is.
struct Hit {
    t: f32,
    tri: u32,
}

fn closest_hit(o: vec3f, d: vec3f, t_min: f32, t_max: f32) -> Hit {
    var hit = Hit(t_max, 0xffffffffu);
    let root = bvh_nodes[0];
    if root.min.x > root.max.x {
        return hit;
    }
    let inv_d = 1.0 / select(d, vec3f(1e-30), abs(d) < vec3f(1e-30));
    var stack: array<u32, 64>;
    var sp = 1u;
    stack[0] = 0u;
    while sp > 0u {
        sp -= 1u;
        let node = bvh_nodes[stack[sp]];
        if !ray_box(o, inv_d, hit.t, node.min, node.max) {
            continue;
        }
        if node.prim_count > 0u {
            for (var i = 0u; i < node.prim_count; i++) {
                let t = ray_triangle_t(o, d, bvh_tris[node.first_index + i]);
                if t > t_min && t < hit.t {
                    hit = Hit(t, node.first_index + i);
                }
            }
        } else if sp + 2u <= 64u {
            stack[sp] = node.first_index;
            stack[sp + 1u] = node.first_index + 1u;
            sp += 2u;
        }
    }
    return hit;
}
