//! Shadow-ray geometry: a BVH built on the CPU with `obvhs` (PLOC + reinsertion),
//! flattened into the buffers `shaders/bvh.wgsl` traverses with any-hit termination.

use super::{Cull, TriangleMesh};
use glam::{Vec3, Vec3A};
use obvhs::{bvh2::builder::build_bvh2_from_tris, triangle::Triangle, BvhBuildParams};

/// Deepest tree the WGSL traversal stack (64 entries) accepts.
pub const MAX_BVH_DEPTH: usize = 60;

/// A BVH node as the GPU reads it (32 bytes). Inner nodes have `prim_count == 0` and
/// their children at `first_index` and `first_index + 1`; leaves index the triangle list.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuBvhNode {
    /// AABB minimum.
    pub min: [f32; 3],
    /// Triangles in the leaf (0 for inner nodes).
    pub prim_count: u32,
    /// AABB maximum.
    pub max: [f32; 3],
    /// Left child, or first triangle of the leaf.
    pub first_index: u32,
}

/// A triangle as the GPU reads it: a vertex and two edges (Möller–Trumbore form).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriangle {
    /// Vertex 0; w holds the triangle's albedo (the mesh's packed RGBA8 of its first
    /// vertex, as bits), what the shared ambient grid's rays see where they hit.
    pub v0: [f32; 4],
    /// v1 − v0.
    pub e1: [f32; 4],
    /// v2 − v0.
    pub e2: [f32; 4],
}

/// A ray segment `origin + t·dir`, `t ∈ (t_min, t_max)`.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Direction (unit length not required).
    pub dir: Vec3,
    /// Start of the segment.
    pub t_min: f32,
    /// End of the segment.
    pub t_max: f32,
}

/// The scene's BVH: the `obvhs` tree for CPU traversal and its flattened GPU form.
pub struct Bvh {
    tree: obvhs::bvh2::Bvh2,
    triangles: Vec<[Vec3; 3]>,
    /// The side of each triangle (input order) camera rays do not see.
    cull: Vec<Cull>,
    /// Flattened nodes (at least one, so GPU buffers are never empty).
    pub gpu_nodes: Vec<GpuBvhNode>,
    /// Triangles in leaf order (at least one).
    pub gpu_triangles: Vec<GpuTriangle>,
    /// Depth of the deepest leaf.
    pub depth: usize,
}

impl std::fmt::Debug for Bvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bvh")
            .field("nodes", &self.tree.nodes.len())
            .field("triangles", &self.triangles.len())
            .field("depth", &self.depth)
            .finish()
    }
}

impl Bvh {
    /// Builds the tree over every triangle of `mesh`.
    pub fn build(mesh: &TriangleMesh) -> anyhow::Result<Bvh> {
        let triangles: Vec<[Vec3; 3]> = (0..mesh.len()).map(|i| mesh.triangle(i)).collect();
        let cull = (0..mesh.len()).map(|i| mesh.cull_of(i)).collect();
        if triangles.is_empty() {
            return Ok(Bvh {
                tree: obvhs::bvh2::Bvh2::default(),
                triangles,
                cull,
                gpu_nodes: vec![GpuBvhNode {
                    min: [1.0; 3],
                    max: [-1.0; 3],
                    prim_count: 0,
                    first_index: 0,
                }],
                gpu_triangles: vec![GpuTriangle::default()],
                depth: 0,
            });
        }
        let tris: Vec<Triangle> = triangles
            .iter()
            .map(|[a, b, c]| Triangle {
                v0: Vec3A::from(*a),
                v1: Vec3A::from(*b),
                v2: Vec3A::from(*c),
            })
            .collect();
        let mut build_time = std::time::Duration::ZERO;
        let tree = build_bvh2_from_tris(&tris, BvhBuildParams::medium_build(), &mut build_time);

        let gpu_nodes: Vec<GpuBvhNode> = tree
            .nodes
            .iter()
            .map(|n| GpuBvhNode {
                min: n.aabb().min.to_array(),
                max: n.aabb().max.to_array(),
                prim_count: n.prim_count,
                first_index: n.first_index,
            })
            .collect();
        let gpu_triangles = tree
            .primitive_indices
            .iter()
            .map(|&i| {
                let [a, b, c] = triangles[i as usize];
                let albedo = mesh.albedo[mesh.indices[i as usize][0] as usize];
                GpuTriangle {
                    v0: a.extend(f32::from_bits(albedo)).to_array(),
                    e1: (b - a).extend(0.0).to_array(),
                    e2: (c - a).extend(0.0).to_array(),
                }
            })
            .collect();
        let depth = tree_depth(&gpu_nodes);
        anyhow::ensure!(
            depth <= MAX_BVH_DEPTH,
            "BVH depth {depth} exceeds the GPU traversal stack ({MAX_BVH_DEPTH}); the mesh is pathological"
        );
        tracing::debug!(
            nodes = gpu_nodes.len(),
            depth,
            ms = build_time.as_secs_f64() * 1e3,
            "BVH built"
        );
        Ok(Bvh {
            tree,
            triangles,
            cull,
            gpu_nodes,
            gpu_triangles,
            depth,
        })
    }

    /// Number of triangles in the scene.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Any-hit query with `obvhs`' own traversal (independent of the flattened GPU form).
    pub fn occluded(&self, ray: &Ray) -> bool {
        if self.triangles.is_empty() {
            return false;
        }
        let r = obvhs::ray::Ray::new(
            Vec3A::from(ray.origin),
            Vec3A::from(ray.dir),
            ray.t_min,
            ray.t_max,
        );
        let mut hit = false;
        self.tree.ray_traverse_anyhit(r, |_, prim| {
            if !hit {
                let id = self.tree.primitive_indices[prim] as usize;
                hit = intersect_triangle(ray, &self.triangles[id]).is_some();
            }
        });
        hit
    }

    /// Closest hit with `obvhs`' traversal: (distance, index of the triangle in the mesh).
    /// Both sides of every triangle: what light and shadow rays meet.
    pub fn closest_hit(&self, ray: &Ray) -> Option<(f32, usize)> {
        self.closest_hit_but(ray, |_| false)
    }

    /// The closest hit a camera ray sees: as `closest_hit`, through the culled side of
    /// a triangle (the mesh's `cull`), as the G-buffer raster does.
    pub fn closest_camera_hit(&self, ray: &Ray) -> Option<(f32, usize)> {
        self.closest_hit_but(ray, |id| {
            let [a, b, c] = self.triangles[id];
            self.cull[id].hides((b - a).cross(c - a), ray.dir)
        })
    }

    /// The closest hit among the triangles `skip` does not reject.
    fn closest_hit_but(&self, ray: &Ray, skip: impl Fn(usize) -> bool) -> Option<(f32, usize)> {
        if self.triangles.is_empty() {
            return None;
        }
        let r = obvhs::ray::Ray::new(
            Vec3A::from(ray.origin),
            Vec3A::from(ray.dir),
            ray.t_min,
            ray.t_max,
        );
        let mut hit = obvhs::ray::RayHit::none();
        let found = self.tree.ray_traverse(r, &mut hit, |r, prim| {
            let id = self.tree.primitive_indices[prim] as usize;
            if skip(id) {
                return f32::INFINITY;
            }
            let seg = Ray {
                origin: ray.origin,
                dir: ray.dir,
                t_min: ray.t_min,
                t_max: r.tmax,
            };
            intersect_triangle(&seg, &self.triangles[id]).unwrap_or(f32::INFINITY)
        });
        found.then(|| {
            (
                hit.t,
                self.tree.primitive_indices[hit.primitive_id as usize] as usize,
            )
        })
    }

    /// Any-hit by testing every triangle (the brute-force yardstick for tests).
    pub fn occluded_brute_force(&self, ray: &Ray) -> bool {
        self.triangles
            .iter()
            .any(|t| intersect_triangle(ray, t).is_some())
    }

    /// The triangles in input order.
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }
}

fn tree_depth(nodes: &[GpuBvhNode]) -> usize {
    let mut max_depth = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((i, d)) = stack.pop() {
        max_depth = max_depth.max(d);
        let n = nodes[i];
        if n.prim_count == 0 {
            stack.push((n.first_index as usize, d + 1));
            stack.push((n.first_index as usize + 1, d + 1));
        }
    }
    max_depth
}

/// Möller–Trumbore ray–triangle intersection; returns the hit distance within the segment.
pub fn intersect_triangle(ray: &Ray, [a, b, c]: &[Vec3; 3]) -> Option<f32> {
    let e1 = *b - *a;
    let e2 = *c - *a;
    let p = ray.dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.origin - *a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > ray.t_min && t < ray.t_max).then_some(t)
}
