//! Stage 2 (paper 000 §3.1.2): per-viewer shadow frustums, all viewers in one dispatch,
//! with `shaders/shadow_frustum.wgsl`; directional lights with a shared shadow map are
//! looked up in it (`shaders/shadow_lookup.wgsl`) instead of traced.

use super::{dispatch, shadow_maps::ShadowMaps, Stage, Timestamps, ViewerVolumes};
use crate::gpu::{storage_entry, GpuContext};

/// Pipeline of the shadow frustum update.
pub(crate) struct ShadowFrustum {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl ShadowFrustum {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ShadowMaps::stage_layout(ctx, "shadow frustum", vec![storage_entry(0, false)]);
        let module = super::stage_shader(
            ctx,
            "shadow_frustum",
            concat!(
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/shadow_frustum.wgsl")
            ),
        );
        ShadowFrustum {
            pipeline: ctx.compute_pipeline("shadow_frustum", &module, &[scene_layout, &layout]),
            layout,
        }
    }

    pub(crate) fn workgroups(volumes: &ViewerVolumes) -> [u32; 3] {
        let [x, y] = volumes.layout.frustum_dims;
        [x.div_ceil(8), y.div_ceil(8), volumes.count as u32]
    }

    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        volumes: &ViewerVolumes,
        maps: &ShadowMaps,
        ts: &Timestamps,
    ) {
        let own = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: volumes.frustum.as_entire_binding(),
        }];
        let bg = maps.stage_bind_group(ctx, "shadow frustum", &self.layout, own);
        dispatch(
            enc,
            "shadow_frustum",
            ts.writes(Stage::ShadowFrustum),
            &self.pipeline,
            [scene, &bg],
            Self::workgroups(volumes),
        );
    }
}
