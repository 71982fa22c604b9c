//! Scene data on the GPU, shared by every stage (bind group 0) and the raster.

use super::gpu_types::{
    FrameGpu, LightGpu, LightMediaGpu, MediumGpu, ParticleGpu, SmokeMapGpu, ViewGpu, COUNTERS,
    SMOKE_MAPS_PER_LIGHT,
};
use super::media_layer::{LayerBuffers, LayerPlan};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::GpuContext;
use crate::scene::{Bvh, Cull, GpuBvhNode, GpuTriangle, Scene, TriangleMesh};
use glam::Vec3;

/// `Frame.mover_root` when the scene has no movers.
pub(crate) const NO_MOVERS: u32 = u32::MAX;

/// Raster vertices: position + packed albedo, 16 bytes each.
fn raster_vertices(mesh: &TriangleMesh) -> Vec<[u32; 4]> {
    mesh.positions
        .iter()
        .zip(&mesh.albedo)
        .map(|(p, a)| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits(), *a])
        .collect()
}

/// Triangles per raster cluster: small enough that a viewer's frustum rejects most of a
/// scene it does not see, large enough that a frame issues few draws.
pub(crate) const CLUSTER_TRIANGLES: usize = 1024;

/// A run of static triangles close together in space, culled as one box.
#[derive(Debug, Clone)]
pub(crate) struct RasterCluster {
    /// Index range in `SceneGpu::indices`.
    pub indices: std::ops::Range<u32>,
    pub min: Vec3,
    pub max: Vec3,
    /// The side of its triangles the camera does not see (one per cluster).
    pub cull: Cull,
}

/// The static triangles by their `cull` and then in Morton order of their centroids,
/// cut into clusters of `CLUSTER_TRIANGLES` (each of one `cull`); returns the reordered
/// triangles and the clusters.
fn cluster_triangles(mesh: &TriangleMesh) -> (Vec<[u32; 3]>, Vec<RasterCluster>) {
    let centroid = |t: &[u32; 3]| {
        (mesh.positions[t[0] as usize]
            + mesh.positions[t[1] as usize]
            + mesh.positions[t[2] as usize])
            / 3.0
    };
    let (lo, hi) = mesh.indices.iter().map(centroid).fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), c| (lo.min(c), hi.max(c)),
    );
    let scale = 1023.0 / (hi - lo).max(Vec3::splat(1e-6));
    let spread = |v: u32| {
        // 10 bits to every third of 30.
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x030000ff;
        x = (x | (x << 8)) & 0x0300f00f;
        x = (x | (x << 4)) & 0x030c30c3;
        (x | (x << 2)) & 0x09249249
    };
    let mut order: Vec<(Cull, u32, [u32; 3])> = mesh
        .indices
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let q = ((centroid(t) - lo) * scale).round().as_uvec3();
            let code = spread(q.x) | spread(q.y) << 1 | spread(q.z) << 2;
            (mesh.cull_of(i), code, *t)
        })
        .collect();
    order.sort_by_key(|(cull, code, _)| (*cull as u8, *code));
    // Where each cull's run of triangles starts, and its chunks.
    let mut chunks: Vec<(Cull, std::ops::Range<usize>)> = Vec::new();
    let mut start = 0;
    for end in 1..=order.len() {
        if end == order.len() || order[end].0 != order[start].0 {
            for s in (start..end).step_by(CLUSTER_TRIANGLES) {
                chunks.push((order[start].0, s..(s + CLUSTER_TRIANGLES).min(end)));
            }
            start = end;
        }
    }
    let tris: Vec<[u32; 3]> = order.into_iter().map(|(_, _, t)| t).collect();
    let clusters = chunks
        .into_iter()
        .map(|(cull, range)| {
            let chunk = &tris[range.clone()];
            let (min, max) = chunk.iter().flatten().fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(lo, hi), v| {
                    let p = mesh.positions[*v as usize];
                    (lo.min(p), hi.max(p))
                },
            );
            RasterCluster {
                indices: range.start as u32 * 3..range.end as u32 * 3,
                min,
                max,
                cull,
            }
        })
        .collect();
    (tris, clusters)
}

/// Which media the world reads from a shared structure instead of analytically (both
/// mark theirs `in_layer`; never both at once).
#[derive(Clone, Copy, Default)]
pub(crate) struct SharedMedia<'a> {
    /// The world media layer's plan (`media_layer::plan`), if there is one.
    pub layer: Option<&'a LayerPlan>,
    /// The media whose density the shared grid carries (`media_layer::grid_media`).
    pub in_grid: Option<&'a [bool]>,
}

/// Scene buffers: BVH, lights, media, and the small per-frame uniforms and counters.
pub(crate) struct SceneGpu {
    pub frame: wgpu::Buffer,
    pub views: wgpu::Buffer,
    pub counters: wgpu::Buffer,
    pub layout: wgpu::BindGroupLayout,
    pub bind_group: wgpu::BindGroup,
    pub vertices: wgpu::Buffer,
    pub indices: wgpu::Buffer,
    pub index_count: u32,
    /// The static triangles' clusters, in index order; the movers' indices follow them.
    pub clusters: Vec<RasterCluster>,
    /// The clusters for the triangle culling pass (shaders/triangle_cull.wgsl): first
    /// index, index count, cull, 0.
    pub cluster_table: wgpu::Buffer,
    /// (name, bytes) of every shared scene buffer.
    pub memory: Vec<(&'static str, u64)>,
    views_capacity: usize,
    lights: wgpu::Buffer,
    media: wgpu::Buffer,
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
    /// Shared media transmittance toward each light (media_transmittance.rs) and the
    /// volumes' headers.
    media_t: wgpu::Buffer,
    light_media: wgpu::Buffer,
    /// The world media layer's table, pool and slots (media_layer.rs).
    pub layer: LayerBuffers,
    /// The live smoke particles (issue 15), `particle_capacity` slots.
    pub particles: wgpu::Buffer,
    pub particle_capacity: u32,
    /// The smoke's shadow map nodes (`vec2f` each) and per-light headers
    /// (smoke_shadows.rs): a single placeholder node without emitters or lights.
    pub smoke_nodes: wgpu::Buffer,
    pub smoke_maps: wgpu::Buffer,
    /// The shared ambient grid's SH probes (ambient_grid.rs; a placeholder without it).
    pub ambient_sh: wgpu::Buffer,
    /// Bumped whenever a buffer of group 0 is reallocated: bind groups made before
    /// must be made again.
    pub generation: u32,
    /// Nodes, triangles and raster vertices of the static scene; the movers' follow.
    static_nodes: u32,
    static_tris: u32,
    static_vertices: u32,
    mover_node_capacity: u32,
}

impl SceneGpu {
    /// Overwrites the lights (same count as at creation: animated lights move).
    pub(crate) fn write_lights(&self, ctx: &GpuContext, lights: &[LightGpu]) {
        if !lights.is_empty() {
            ctx.queue
                .write_buffer(&self.lights, 0, bytemuck::cast_slice(lights));
        }
    }

    /// Rebuilds the movers' BVH at `time_s` and writes it (and their raster vertices)
    /// after the static scene's; returns the movers' root node, or `NO_MOVERS`.
    pub(crate) fn write_movers(
        &self,
        ctx: &GpuContext,
        scene: &Scene,
        time_s: f32,
    ) -> anyhow::Result<u32> {
        if scene.movers.is_empty() {
            return Ok(NO_MOVERS);
        }
        let mesh = crate::scene::movers_mesh_at(&scene.movers, time_s);
        let bvh = Bvh::build(&mesh)?;
        // Child and triangle indices move past the static tree's.
        let nodes: Vec<GpuBvhNode> = bvh
            .gpu_nodes
            .iter()
            .map(|n| GpuBvhNode {
                first_index: n.first_index
                    + if n.prim_count > 0 {
                        self.static_tris
                    } else {
                        self.static_nodes
                    },
                ..*n
            })
            .collect();
        anyhow::ensure!(
            nodes.len() as u32 <= self.mover_node_capacity,
            "movers' BVH has {} nodes, more than the {} reserved",
            nodes.len(),
            self.mover_node_capacity
        );
        let node_size = std::mem::size_of::<GpuBvhNode>() as u64;
        let tri_size = std::mem::size_of::<GpuTriangle>() as u64;
        ctx.queue.write_buffer(
            &self.nodes,
            self.static_nodes as u64 * node_size,
            bytemuck::cast_slice(&nodes),
        );
        ctx.queue.write_buffer(
            &self.tris,
            self.static_tris as u64 * tri_size,
            bytemuck::cast_slice(&bvh.gpu_triangles),
        );
        let verts = raster_vertices(&mesh);
        ctx.queue.write_buffer(
            &self.vertices,
            self.static_vertices as u64 * 16,
            bytemuck::cast_slice(&verts),
        );
        Ok(self.static_nodes)
    }

    /// `light_media`: the media transmittance volumes' layout (`media_transmittance::plan`).
    /// `shared_media`: the media read from the layer or the grid instead of analytically.
    /// `ambient`: the shared ambient grid's probes (`ambient_grid::plan`), if any.
    pub(crate) fn new(
        ctx: &GpuContext,
        scene: &Scene,
        bvh: &Bvh,
        light_media: &[LightMediaGpu],
        shared_media: SharedMedia<'_>,
        smoke_nodes: u64,
        ambient: Option<&super::ambient_grid::AmbientPlan>,
    ) -> anyhow::Result<SceneGpu> {
        let SharedMedia { layer, in_grid } = shared_media;
        let lights: Vec<LightGpu> = scene.lights.iter().map(LightGpu::from).collect();
        let media: Vec<MediumGpu> = scene
            .media
            .iter()
            .enumerate()
            .map(|(i, m)| MediumGpu {
                in_layer: u32::from(
                    layer.is_some_and(|l| l.in_layer[i]) || in_grid.is_some_and(|g| g[i]),
                ),
                ..MediumGpu::from(m)
            })
            .collect();
        let layer_buffers = LayerBuffers::new(ctx, layer)?;
        let frame = ctx.storage(
            "frame",
            std::mem::size_of::<FrameGpu>() as u64,
            wgpu::BufferUsages::empty(),
        )?;
        let views_capacity = 16;
        let views = ctx.storage(
            "views",
            (views_capacity * std::mem::size_of::<ViewGpu>()) as u64,
            wgpu::BufferUsages::empty(),
        )?;
        let counters = ctx.storage(
            "counters",
            (COUNTERS * 4) as u64,
            wgpu::BufferUsages::empty(),
        )?;
        let lights = ctx.storage_init("lights", &lights, wgpu::BufferUsages::empty());
        let media = ctx.storage_init("media", &media, wgpu::BufferUsages::empty());
        // Movers' BVH and triangles go after the static ones, rewritten every frame.
        let movers = crate::scene::movers_mesh_at(&scene.movers, 0.0);
        let mover_node_capacity = if movers.is_empty() {
            0
        } else {
            2 * movers.len() as u32
        };
        let mut node_data = bvh.gpu_nodes.clone();
        node_data.resize(
            node_data.len() + mover_node_capacity as usize,
            GpuBvhNode::default(),
        );
        let mut tri_data = bvh.gpu_triangles.clone();
        tri_data.resize(tri_data.len() + movers.len(), GpuTriangle::default());
        let nodes = ctx.storage_init("bvh nodes", &node_data, wgpu::BufferUsages::COPY_DST);
        let tris = ctx.storage_init("bvh triangles", &tri_data, wgpu::BufferUsages::COPY_DST);
        let media_t_bytes = super::media_transmittance::bytes(light_media);
        let media_t = ctx.storage(
            "media transmittance",
            media_t_bytes,
            wgpu::BufferUsages::empty(),
        )?;
        let light_media = ctx.storage_init("light media", light_media, wgpu::BufferUsages::empty());
        // Compute stages and the smoke raster's fragments (smoke_view.rs) read group 0.
        let layout = ctx.storage_layout_for(
            "scene",
            &[
                Read, Read, Read, Read, Read, Read, ReadWrite, ReadWrite, Read, ReadWrite,
                ReadWrite, ReadWrite, Read, ReadWrite, Read, ReadWrite,
            ],
            wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::FRAGMENT,
        );

        // Raster vertices and indices: the static mesh in clusters, then the movers (whose
        // vertices are rewritten every frame).
        let mut all = scene.mesh.clone();
        let (static_tris, clusters) = cluster_triangles(&scene.mesh);
        all.indices = static_tris;
        all.append(&movers);
        let verts = raster_vertices(&all);
        let idx: Vec<u32> = all.indices.iter().flatten().copied().collect();
        let vertices = ctx.storage_init(
            "vertices",
            &verts,
            wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        );
        let indices = ctx.storage_init("indices", &idx, wgpu::BufferUsages::INDEX);
        let table: Vec<[u32; 4]> = clusters
            .iter()
            .map(|c| {
                let n = c.indices.end - c.indices.start;
                [c.indices.start, n, c.cull as u32, 0]
            })
            .collect();
        let cluster_table =
            ctx.storage_init("raster clusters", &table, wgpu::BufferUsages::empty());

        let mut memory = vec![
            ("bvh_nodes", nodes.size()),
            ("bvh_triangles", tris.size()),
            ("raster_vertices", vertices.size()),
            ("raster_indices", indices.size()),
            ("lights_media", lights.size() + media.size()),
        ];
        if media_t_bytes > 0 {
            memory.push(("media_transmittance", media_t.size()));
        }
        if let Some(l) = layer {
            memory.push(("media_layer", l.bytes()));
        }
        let particle_capacity = particle_capacity(scene);
        let particles = ctx.storage(
            "smoke particles",
            u64::from(particle_capacity.max(1)) * std::mem::size_of::<ParticleGpu>() as u64,
            wgpu::BufferUsages::empty(),
        )?;
        if particle_capacity > 0 {
            memory.push(("smoke_particles", particles.size()));
        }
        let smoke_nodes_buf = ctx.storage(
            "smoke shadow nodes",
            smoke_nodes.max(1) * 8,
            wgpu::BufferUsages::empty(),
        )?;
        let smoke_maps = ctx.storage(
            "smoke shadow maps",
            scene.lights.len().max(1) as u64
                * u64::from(SMOKE_MAPS_PER_LIGHT)
                * std::mem::size_of::<SmokeMapGpu>() as u64,
            wgpu::BufferUsages::empty(),
        )?;
        if smoke_nodes > 0 {
            memory.push(("smoke_shadows", smoke_nodes_buf.size() + smoke_maps.size()));
        }
        let ambient_sh = ctx.storage(
            "ambient sh",
            ambient.map_or(16, |a| a.bytes()),
            wgpu::BufferUsages::empty(),
        )?;
        if let Some(a) = ambient {
            memory.push(("ambient_grid", a.bytes()));
        }
        let bind_group = ctx.bind_buffers(
            "scene",
            &layout,
            &[
                &frame,
                &views,
                &lights,
                &media,
                &nodes,
                &tris,
                &counters,
                &media_t,
                &light_media,
                &layer_buffers.table,
                &layer_buffers.pool,
                &layer_buffers.slots,
                &particles,
                &smoke_nodes_buf,
                &smoke_maps,
                &ambient_sh,
            ],
        );
        Ok(SceneGpu {
            ambient_sh,
            layer: layer_buffers,
            particles,
            particle_capacity,
            smoke_nodes: smoke_nodes_buf,
            smoke_maps,
            generation: 0,
            frame,
            views,
            counters,
            layout,
            bind_group,
            vertices,
            indices,
            index_count: idx.len() as u32,
            clusters,
            cluster_table,
            memory,
            views_capacity,
            lights,
            media,
            nodes,
            tris,
            media_t,
            light_media,
            static_nodes: bvh.gpu_nodes.len() as u32,
            static_tris: bvh.gpu_triangles.len() as u32,
            static_vertices: scene.mesh.positions.len() as u32,
            mover_node_capacity,
        })
    }

    /// Reallocates the media layer's buffers for `plan` (its pool grew) and rebinds.
    pub(crate) fn resize_layer(
        &mut self,
        ctx: &GpuContext,
        plan: &LayerPlan,
    ) -> anyhow::Result<()> {
        self.layer = LayerBuffers::new(ctx, Some(plan))?;
        for (name, bytes) in &mut self.memory {
            if *name == "media_layer" {
                *bytes = plan.bytes();
            }
        }
        self.bind_group = self.bind(ctx, &self.frame, &self.views);
        self.generation += 1;
        Ok(())
    }

    /// Grows the views buffer (and rebinds) when more viewers arrive.
    pub(crate) fn ensure_views(&mut self, ctx: &GpuContext, count: usize) -> anyhow::Result<()> {
        if count <= self.views_capacity {
            return Ok(());
        }
        self.views_capacity = count.next_power_of_two();
        self.views = ctx.storage(
            "views",
            (self.views_capacity * std::mem::size_of::<ViewGpu>()) as u64,
            wgpu::BufferUsages::empty(),
        )?;
        self.bind_group = self.bind(ctx, &self.frame, &self.views);
        Ok(())
    }

    /// Bind group 0 with `frame` and `views` and the scene's other buffers: the world's
    /// own (every viewer) or a viewer set's.
    pub(crate) fn bind(
        &self,
        ctx: &GpuContext,
        frame: &wgpu::Buffer,
        views: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        ctx.bind_buffers(
            "scene",
            &self.layout,
            &[
                frame,
                views,
                &self.lights,
                &self.media,
                &self.nodes,
                &self.tris,
                &self.counters,
                &self.media_t,
                &self.light_media,
                &self.layer.table,
                &self.layer.pool,
                &self.layer.slots,
                &self.particles,
                &self.smoke_nodes,
                &self.smoke_maps,
                &self.ambient_sh,
            ],
        )
    }
}

/// The most particles the scene's emitters can have alive at once on the GPU (the sum of
/// their shares, src/render/smoke_particles.rs).
pub(crate) fn particle_capacity(scene: &Scene) -> u32 {
    super::smoke_particles::shares(scene).iter().sum()
}

/// The most smoke particles on the GPU at once, over every emitter (48 bytes each).
pub(crate) const MAX_PARTICLES: u32 = 1 << 16;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clusters_keep_every_triangle_and_bound_their_own() {
        // Sponza: 262k triangles, 256 clusters.
        let scene = Scene::load("scenes/sponza.toml").unwrap();
        let mesh = &scene.mesh;
        let (tris, clusters) = cluster_triangles(mesh);
        assert!(clusters.len() > 100);
        let mut before = mesh.indices.clone();
        let mut after = tris.clone();
        before.sort();
        after.sort();
        assert_eq!(before, after, "the same triangles, reordered");
        assert_eq!(
            clusters.len(),
            mesh.indices.len().div_ceil(CLUSTER_TRIANGLES)
        );
        let mut next = 0;
        for c in &clusters {
            assert_eq!(c.indices.start, next, "clusters are contiguous");
            next = c.indices.end;
            for t in &tris[c.indices.start as usize / 3..c.indices.end as usize / 3] {
                for v in t {
                    let p = mesh.positions[*v as usize];
                    assert!(p.cmpge(c.min).all() && p.cmple(c.max).all());
                }
            }
        }
        assert_eq!(next as usize, tris.len() * 3);
    }

    #[test]
    fn a_cluster_holds_triangles_of_one_cull() {
        // 3000 small triangles along x, every third one-sided: the clusters split by
        // cull first, so no cluster mixes two, and every triangle is kept with its own.
        let mut mesh = TriangleMesh::default();
        for i in 0..3000u32 {
            let x = i as f32 * 0.01;
            mesh.positions.extend([
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 0.01, 0.0, 0.0),
                Vec3::new(x, 0.01, 0.0),
            ]);
            mesh.albedo.extend([0; 3]);
            mesh.indices.push([3 * i, 3 * i + 1, 3 * i + 2]);
            mesh.cull
                .push(if i % 3 == 0 { Cull::Back } else { Cull::None });
        }
        let (tris, clusters) = cluster_triangles(&mesh);
        assert_eq!(tris.len(), 3000);
        let mut back = 0;
        for c in &clusters {
            for t in &tris[c.indices.start as usize / 3..c.indices.end as usize / 3] {
                let cull = mesh.cull_of(t[0] as usize / 3);
                assert_eq!(cull, c.cull, "a cluster of one cull");
                back += usize::from(cull == Cull::Back);
            }
        }
        assert_eq!(back, 1000);
        // 2000 both-sided in 2 clusters, 1000 one-sided in 1.
        assert_eq!(clusters.len(), 3);
    }
}
