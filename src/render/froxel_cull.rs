//! Hidden-froxel culling (beyond paper 000), with `shaders/froxel_cull.wgsl`: with the
//! demand-driven grid, froxels behind every surface their column shows are neither lit
//! nor allowed to request voxels. Timed as part of the `grid_requests` stage, whose work
//! it decides.

use super::viewer_volumes::gbuffer_entry;
use super::{dispatch, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::ReadWrite;
use crate::gpu::{storage_entry, GpuContext};

/// Pipelines of the two culling passes.
pub(crate) struct FroxelCull {
    layout: wgpu::BindGroupLayout,
    tile_max: wgpu::ComputePipeline,
    column_limit: wgpu::ComputePipeline,
}

impl FroxelCull {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("froxel cull"),
                entries: &[
                    storage_entry(0, ReadWrite),
                    storage_entry(1, ReadWrite),
                    gbuffer_entry(2),
                ],
            });
        let module = super::stage_shader(
            ctx,
            "froxel_cull",
            include_str!("../../shaders/froxel_cull.wgsl"),
        );
        let pipeline = |entry: &str| {
            ctx.compute_pipeline_entry(entry, &module, &[scene_layout, &layout], entry)
        };
        FroxelCull {
            tile_max: pipeline("tile_max"),
            column_limit: pipeline("column_limit_pass"),
            layout,
        }
    }

    /// Records both passes (timed as part of `grid_requests`).
    pub(crate) fn add_passes(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        let volumes = &set.vol;
        let gbuf = volumes.gbuf_array();
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("froxel cull"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: volumes.tile_depth.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: volumes.column_limit.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&gbuf),
                },
            ],
        });
        // Every view's tiles (a coupled eye's widen its partner's limits), then the
        // limits of the views that light their own volume.
        let [x, y, _] = volumes.groups.columns;
        let all = [x, y, volumes.count as u32];
        for (pipeline, groups) in [
            (&self.tile_max, all),
            (&self.column_limit, volumes.groups.columns),
        ] {
            dispatch(
                enc,
                ts,
                Stage::GridRequests,
                pipeline,
                &[&set.bind_group, &bg],
                groups,
            );
        }
    }
}
