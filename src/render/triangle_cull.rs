//! Per-view triangle culling before the G-buffer raster (`triangle_cull`), with
//! `shaders/triangle_cull.wgsl`: every view's index list of the triangles the raster can
//! make a fragment of, and its indirect draw (`GBuffer` draws them).

use super::gbuffer::RASTER_VIEW_WGSL;
use super::{scene_gpu::SceneGpu, Stage, Timestamps};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};

/// Triangle culling's words per (view, cluster) pair: the count, then the masks of its
/// 1024 triangles (`PAIR_WORDS` in shaders/triangle_cull.wgsl).
const PAIR_WORDS: u64 = 33;

/// Bytes of one `DrawIndexedIndirect` record.
pub(crate) const DRAW_ARGS_BYTES: u64 = 20;

/// GPU memory the G-buffer's triangle culling (`triangle_cull`) can hold per view in a
/// scene of `static_triangles`: the view's index list if every cluster were in its
/// frustum, and a pair record per cluster (clusters of one cull each: at most 3 more
/// than a split into 1024s).
pub fn triangle_list_bytes_per_view(settings: &super::Settings, static_triangles: u64) -> u64 {
    if !settings.triangle_cull {
        return 0;
    }
    let clusters = static_triangles.div_ceil(super::scene_gpu::CLUSTER_TRIANGLES as u64) + 3;
    static_triangles * 12 + clusters * (16 + PAIR_WORDS * 4) + DRAW_ARGS_BYTES
}

/// Per-view triangle culling (`triangle_cull`): the frame's (view, cluster) pairs, what
/// the pass keeps of each, and every view's index list and indirect draw.
pub(crate) struct TriangleLists {
    layout: wgpu::BindGroupLayout,
    cull: wgpu::ComputePipeline,
    compact: wgpu::ComputePipeline,
    pairs: wgpu::Buffer,
    kept: wgpu::Buffer,
    pub(crate) indices: wgpu::Buffer,
    pub(crate) args: wgpu::Buffer,
    /// This frame's pair count (the pair buffer is longer).
    count: wgpu::Buffer,
    /// This frame's pairs (0: nothing to cull, or culling off).
    pub(crate) pair_count: u32,
}

impl TriangleLists {
    pub(crate) fn new(ctx: &GpuContext) -> Self {
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("triangle cull"),
                entries: &[
                    storage_entry(0, Read),
                    storage_entry(1, Read),
                    storage_entry(2, Read),
                    storage_entry(3, Read),
                    storage_entry(4, Read),
                    storage_entry(5, ReadWrite),
                    storage_entry(6, ReadWrite),
                    storage_entry(7, ReadWrite),
                    storage_entry(9, ReadWrite),
                    wgpu::BindGroupLayoutEntry {
                        binding: 8,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: wgpu::BufferSize::new(16),
                        },
                        count: None,
                    },
                ],
            });
        let module = ctx.shader(
            "triangle cull",
            &[
                RASTER_VIEW_WGSL,
                include_str!("../../shaders/triangle_cull.wgsl"),
            ],
        );
        let buffer = |label: &str, usage: wgpu::BufferUsages| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | usage,
                mapped_at_creation: false,
            })
        };
        TriangleLists {
            cull: ctx.compute_pipeline_entry("triangle cull", &module, &[&layout], "cull"),
            compact: ctx.compute_pipeline_entry("triangle compact", &module, &[&layout], "compact"),
            layout,
            pairs: buffer("triangle cull pairs", wgpu::BufferUsages::empty()),
            kept: buffer("triangle cull kept", wgpu::BufferUsages::empty()),
            indices: buffer("triangle lists", wgpu::BufferUsages::INDEX),
            args: buffer("triangle list draws", wgpu::BufferUsages::INDIRECT),
            count: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("triangle cull pair count"),
                size: 16,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            pair_count: 0,
        }
    }

    /// Bytes of the views' index lists and the pass's records (what culling holds).
    pub(crate) fn bytes(&self) -> u64 {
        if self.pair_count == 0 {
            return 0;
        }
        self.pairs.size() + self.kept.size() + self.indices.size() + self.args.size()
    }

    /// Plans this frame's lists for every set's views, in order, given the clusters each
    /// one's frustum touches (`visible`): a pair per view and such cluster, each view's
    /// list as long as those clusters' indices, and each view's draw with no indices until
    /// the pass counts them.
    pub(crate) fn upload(
        &mut self,
        ctx: &GpuContext,
        scene: &SceneGpu,
        visible: &[Vec<usize>],
        on: bool,
    ) {
        self.pair_count = 0;
        if !on || scene.clusters.is_empty() {
            return;
        }
        let mut pairs: Vec<[u32; 4]> = Vec::new();
        let mut args: Vec<[u32; 5]> = Vec::with_capacity(visible.len());
        let mut list_end = 0u32;
        for (v, clusters) in visible.iter().enumerate() {
            let first_pair = pairs.len() as u32;
            let base = list_end;
            for &k in clusters {
                let c = &scene.clusters[k];
                pairs.push([v as u32, k as u32, first_pair, 0]);
                list_end += c.indices.end - c.indices.start;
            }
            args.push([0, 1, base, 0, 0]);
        }
        // Buffers grow to the next power of two, never past what every cluster in every
        // view would need (what the server's budget plans with).
        let static_indices = u64::from(scene.clusters.last().map_or(0, |c| c.indices.end));
        let n = pairs.len() as u64;
        let lists = u64::from(list_end) * 4;
        if lists > ctx.max_storage_binding {
            // Larger than the adapter binds: this frame draws the clusters' ranges.
            return;
        }
        let grow = |buffer: &mut wgpu::Buffer, bytes: u64, most: u64| {
            if buffer.size() < bytes {
                *buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("triangle lists"),
                    size: bytes.next_power_of_two().min(most.max(bytes)),
                    usage: buffer.usage(),
                    mapped_at_creation: false,
                });
            }
        };
        let all = visible.len() as u64;
        let clusters = scene.clusters.len() as u64;
        grow(&mut self.pairs, n * 16, all * clusters * 16);
        grow(
            &mut self.kept,
            n * PAIR_WORDS * 4,
            all * clusters * PAIR_WORDS * 4,
        );
        grow(&mut self.indices, lists, all * static_indices * 4);
        grow(&mut self.args, all * DRAW_ARGS_BYTES, all * DRAW_ARGS_BYTES);
        ctx.queue
            .write_buffer(&self.pairs, 0, bytemuck::cast_slice(&pairs));
        ctx.queue
            .write_buffer(&self.args, 0, bytemuck::cast_slice(&args));
        let count = [pairs.len() as u32, 0, 0, 0];
        ctx.queue
            .write_buffer(&self.count, 0, bytemuck::cast_slice(&count));
        self.pair_count = pairs.len() as u32;
    }

    /// Records the two passes over every view of the frame.
    pub(crate) fn add_passes(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        views: &wgpu::Buffer,
        ts: &Timestamps,
    ) {
        if self.pair_count == 0 {
            return;
        }
        let buffers = [
            views,
            &scene.vertices,
            &scene.indices,
            &scene.cluster_table,
            &self.pairs,
            &self.kept,
            &self.indices,
            &self.args,
        ];
        // Then binding 8, the uniform pair count, and 9, the frame's counters.
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .chain([&&self.count, &&scene.counters])
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("triangle cull"),
            layout: &self.layout,
            entries: &entries,
        });
        // The pairs as a 2-D grid of workgroups (the shader reads its pair as x + y·nx).
        let x = self.pair_count.min(32768);
        let groups = [x, self.pair_count.div_ceil(x), 1];
        for pipeline in [&self.cull, &self.compact] {
            super::dispatch(enc, ts, Stage::GBuffer, pipeline, &[&bg], groups);
        }
    }
}
