//! Stage 3 (paper 000 §3.1.3): in-scattering and extinction per froxel, all viewers in
//! one dispatch, with `shaders/froxel_lighting.wgsl`.

use super::{dispatch, SharedShadowGrid, Stage, Timestamps, ViewerSet};
use crate::gpu::GpuContext;

/// Pipeline of the froxel lighting stage.
pub(crate) struct FroxelLighting {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl FroxelLighting {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ctx.storage_layout(
            "froxel lighting",
            &[false, false, true, false, false, false],
        );
        let module = super::stage_shader(
            ctx,
            "froxel_lighting",
            include_str!("../../shaders/froxel_lighting.wgsl"),
        );
        FroxelLighting {
            pipeline: ctx.compute_pipeline("froxel_lighting", &module, &[scene_layout, &layout]),
            layout,
        }
    }

    /// `grid` is `None` in `reference` mode, where every froxel traces its own rays.
    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        grid: Option<&SharedShadowGrid>,
        ts: &Timestamps,
    ) {
        let volumes = &set.vol;
        // In reference mode the grid binding is unused; the frustum buffer stands in.
        let grid_buffer = grid.map_or(&volumes.frustum, |g| &g.grid);
        let bricks = grid.map_or(&volumes.frustum, |g| &g.brick_table);
        let bg = ctx.bind_buffers(
            "froxel lighting",
            &self.layout,
            &[
                grid_buffer,
                &volumes.frustum,
                &volumes.froxels,
                set.froxel_history(),
                bricks,
                &volumes.column_limit,
            ],
        );
        dispatch(
            enc,
            ts,
            Stage::FroxelLighting,
            &self.pipeline,
            &[&set.bind_group, &bg],
            volumes.groups.columns,
        );
    }
}
