//! Batched shadow-ray queries on the GPU, with `shaders/ray_query.wgsl`: the same
//! any-hit `occluded()` of `shaders/bvh.wgsl` that every stage traces, exposed so tests
//! can hold it against the CPU traversals of [`Bvh`].

use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};
use crate::scene::{Bvh, Ray};

/// Segments per dispatch: 1 Mi × 32 bytes stays far below the storage binding limit,
/// and 1 Mi / 64 workgroups below the 65 535 workgroups a dispatch dimension allows.
const RAYS_PER_DISPATCH: usize = 1 << 20;

/// `RaySegment` in `shaders/ray_query.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RaySegmentGpu {
    origin: [f32; 3],
    t_min: f32,
    dir: [f32; 3],
    t_max: f32,
}

const _: () = assert!(std::mem::size_of::<RaySegmentGpu>() == 32);

/// A BVH uploaded once and a compute pipeline that answers batches of shadow rays.
pub struct ShadowRayQuery {
    /// Group 0: only `bvh_nodes` (binding 4) and `bvh_tris` (binding 5) of common.wgsl.
    scene_bind_group: wgpu::BindGroup,
    rays_layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl std::fmt::Debug for ShadowRayQuery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ShadowRayQuery").finish_non_exhaustive()
    }
}

impl ShadowRayQuery {
    /// Uploads `bvh`'s flattened nodes and triangles and compiles the query shader.
    pub fn new(ctx: &GpuContext, bvh: &Bvh) -> ShadowRayQuery {
        let nodes = ctx.storage_init(
            "ray query bvh nodes",
            &bvh.gpu_nodes,
            wgpu::BufferUsages::empty(),
        );
        let tris = ctx.storage_init(
            "ray query bvh triangles",
            &bvh.gpu_triangles,
            wgpu::BufferUsages::empty(),
        );
        // The shader declares every group-0 binding of common.wgsl but uses only the
        // BVH's two, so a layout with just those is compatible and needs no stand-ins.
        let scene_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("ray query scene"),
                entries: &[storage_entry(4, Read), storage_entry(5, Read)],
            });
        let scene_bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ray query scene"),
            layout: &scene_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: nodes.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: tris.as_entire_binding(),
                },
            ],
        });
        let rays_layout = ctx.storage_layout("ray query segments", &[Read, ReadWrite]);
        let module = super::stage_shader(
            ctx,
            "ray_query",
            include_str!("../../shaders/ray_query.wgsl"),
        );
        let pipeline = ctx.compute_pipeline("ray_query", &module, &[&scene_layout, &rays_layout]);
        ShadowRayQuery {
            scene_bind_group,
            rays_layout,
            pipeline,
        }
    }

    /// For each ray, in order: whether a triangle blocks `origin + t·dir` for some
    /// `t` in `(t_min, t_max)`. Every component of every ray must be finite.
    pub fn trace(&self, ctx: &GpuContext, rays: &[Ray]) -> anyhow::Result<Vec<bool>> {
        if let Some((i, r)) = rays.iter().enumerate().find(|(_, r)| {
            !(r.origin.is_finite()
                && r.dir.is_finite()
                && r.t_min.is_finite()
                && r.t_max.is_finite())
        }) {
            anyhow::bail!("shadow ray {i} is not finite: {r:?}");
        }
        let mut occluded = Vec::with_capacity(rays.len());
        for chunk in rays.chunks(RAYS_PER_DISPATCH) {
            let segments: Vec<RaySegmentGpu> = chunk
                .iter()
                .map(|r| RaySegmentGpu {
                    origin: r.origin.to_array(),
                    t_min: r.t_min,
                    dir: r.dir.to_array(),
                    t_max: r.t_max,
                })
                .collect();
            let segments_buf =
                ctx.storage_init("ray query segments", &segments, wgpu::BufferUsages::empty());
            let hits_buf = ctx.storage(
                "ray query hits",
                chunk.len() as u64 * 4,
                wgpu::BufferUsages::empty(),
            )?;
            let bind_group = ctx.bind_buffers(
                "ray query segments",
                &self.rays_layout,
                &[&segments_buf, &hits_buf],
            );
            let mut enc = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("ray query"),
                });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("ray_query"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &self.scene_bind_group, &[]);
                pass.set_bind_group(1, &bind_group, &[]);
                pass.dispatch_workgroups((chunk.len() as u32).div_ceil(64), 1, 1);
            }
            ctx.submit(enc);
            let hits = ctx.read_buffer(&hits_buf)?;
            occluded.extend(
                hits.chunks_exact(4)
                    .take(chunk.len())
                    .map(|word| word != [0; 4]),
            );
        }
        Ok(occluded)
    }
}

/// Traces `rays` against `bvh` on the GPU with the stages' own traversal and returns,
/// per ray, whether it is blocked (see [`ShadowRayQuery::trace`]). Uploads the BVH each
/// call; keep a [`ShadowRayQuery`] to trace several batches against one scene.
pub fn trace_shadow_rays(ctx: &GpuContext, bvh: &Bvh, rays: &[Ray]) -> anyhow::Result<Vec<bool>> {
    ShadowRayQuery::new(ctx, bvh).trace(ctx, rays)
}
