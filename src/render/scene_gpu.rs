//! Scene data on the GPU, shared by every stage (bind group 0) and the raster.

use super::gpu_types::{FrameGpu, LightGpu, MediumGpu, ViewGpu, COUNTERS};
use crate::gpu::GpuContext;
use crate::scene::{Bvh, Scene};

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
    /// (name, bytes) of every shared scene buffer.
    pub memory: Vec<(&'static str, u64)>,
    views_capacity: usize,
    lights: wgpu::Buffer,
    media: wgpu::Buffer,
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
}

impl SceneGpu {
    /// Overwrites the lights (same count as at creation: animated lights move).
    pub(crate) fn write_lights(&self, ctx: &GpuContext, lights: &[LightGpu]) {
        if !lights.is_empty() {
            ctx.queue
                .write_buffer(&self.lights, 0, bytemuck::cast_slice(lights));
        }
    }

    pub(crate) fn new(ctx: &GpuContext, scene: &Scene, bvh: &Bvh) -> anyhow::Result<SceneGpu> {
        let lights: Vec<LightGpu> = scene.lights.iter().map(LightGpu::from).collect();
        let media: Vec<MediumGpu> = scene.media.iter().map(MediumGpu::from).collect();
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
        let nodes = ctx.storage_init("bvh nodes", &bvh.gpu_nodes, wgpu::BufferUsages::empty());
        let tris = ctx.storage_init(
            "bvh triangles",
            &bvh.gpu_triangles,
            wgpu::BufferUsages::empty(),
        );
        let layout = ctx.storage_layout("scene", &[false, false, false, false, false, false, true]);

        // Raster vertices: position + packed albedo, 16 bytes.
        let mut verts: Vec<[u32; 4]> = Vec::with_capacity(scene.mesh.positions.len().max(1));
        for (p, a) in scene.mesh.positions.iter().zip(&scene.mesh.albedo) {
            verts.push([p.x.to_bits(), p.y.to_bits(), p.z.to_bits(), *a]);
        }
        let idx: Vec<u32> = scene.mesh.indices.iter().flatten().copied().collect();
        let vertices = ctx.storage_init("vertices", &verts, wgpu::BufferUsages::VERTEX);
        let indices = ctx.storage_init("indices", &idx, wgpu::BufferUsages::INDEX);

        let memory = vec![
            ("bvh_nodes", nodes.size()),
            ("bvh_triangles", tris.size()),
            ("raster_vertices", vertices.size()),
            ("raster_indices", indices.size()),
            ("lights_media", lights.size() + media.size()),
        ];
        let bind_group = ctx.bind_buffers(
            "scene",
            &layout,
            &[&frame, &views, &lights, &media, &nodes, &tris, &counters],
        );
        Ok(SceneGpu {
            frame,
            views,
            counters,
            layout,
            bind_group,
            vertices,
            indices,
            index_count: idx.len() as u32,
            memory,
            views_capacity,
            lights,
            media,
            nodes,
            tris,
        })
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
        self.bind_group = ctx.bind_buffers(
            "scene",
            &self.layout,
            &[
                &self.frame,
                &self.views,
                &self.lights,
                &self.media,
                &self.nodes,
                &self.tris,
                &self.counters,
            ],
        );
        Ok(())
    }
}
