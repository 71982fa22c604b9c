//! Stage 2 (paper 000 §3.1.2): per-viewer shadow frustums, all viewers in one dispatch,
//! with `shaders/shadow_frustum.wgsl`.

use super::{compute_pass, Stage, Timestamps, ViewerVolumes};
use crate::gpu::GpuContext;

/// Pipeline of the shadow frustum update.
pub(crate) struct ShadowFrustum {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl ShadowFrustum {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ctx.storage_layout("shadow frustum", &[true]);
        let module = super::stage_shader(
            ctx,
            "shadow_frustum",
            include_str!("../../shaders/shadow_frustum.wgsl"),
        );
        ShadowFrustum {
            pipeline: ctx.compute_pipeline("shadow_frustum", &module, &[scene_layout, &layout]),
            layout,
        }
    }

    pub(crate) fn workgroups(volumes: &ViewerVolumes) -> [u32; 3] {
        let [x, y] = volumes.layout.frustum_dims;
        [
            x.div_ceil(8),
            y.div_ceil(8),
            volumes.frustum_slices * volumes.count as u32,
        ]
    }

    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        volumes: &ViewerVolumes,
        ts: &Timestamps,
    ) {
        let bg = ctx.bind_buffers("shadow frustum", &self.layout, &[&volumes.frustum]);
        let mut pass = compute_pass(enc, "shadow_frustum", ts.writes(Stage::ShadowFrustum));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, scene, &[]);
        pass.set_bind_group(1, &bg, &[]);
        let [x, y, z] = Self::workgroups(volumes);
        pass.dispatch_workgroups(x, y, z);
    }
}
