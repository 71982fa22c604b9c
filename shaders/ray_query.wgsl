// Batched shadow-ray queries (tests and tools): one any-hit `occluded()` from bvh.wgsl
// per segment, so the answer is exactly what every fog and surface stage would get.
// Only bvh_nodes and bvh_tris of group 0 are used.

struct RaySegment {
    origin: vec3f,
    t_min: f32,
    dir: vec3f,
    t_max: f32,
}

@group(1) @binding(0) var<storage, read> segments: array<RaySegment>;
@group(1) @binding(1) var<storage, read_write> hits: array<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3u) {
    let i = gid.x;
    if i >= arrayLength(&segments) {
        return;
    }
    let r = segments[i];
    hits[i] = select(0u, 1u, occluded(r.origin, r.dir, r.t_min, r.t_max));
}
