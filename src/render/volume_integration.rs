//! Stage 4 (paper 000 §3.1.4): front-to-back integration of every froxel column, all
//! viewers in one dispatch, with `shaders/volume_integration.wgsl`.

use super::{dispatch, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::GpuContext;

/// Pipeline of the volume integration stage.
pub(crate) struct VolumeIntegration {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl VolumeIntegration {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ctx.storage_layout("volume integration", &[Read, ReadWrite, Read]);
        let module = super::stage_shader(
            ctx,
            "volume_integration",
            include_str!("../../shaders/volume_integration.wgsl"),
        );
        VolumeIntegration {
            pipeline: ctx.compute_pipeline("volume_integration", &module, &[scene_layout, &layout]),
            layout,
        }
    }

    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        let v = &set.vol;
        let bg = ctx.bind_buffers(
            "volume integration",
            &self.layout,
            &[&v.froxels, &v.integrated, &v.column_limit],
        );
        dispatch(
            enc,
            ts,
            Stage::VolumeIntegration,
            &self.pipeline,
            &[&set.bind_group, &bg],
            v.groups.integration,
        );
    }
}
