//! Stage 2 (paper 000 §3.1.2): per-viewer shadow frustums, all viewers in one dispatch,
//! with `shaders/shadow_frustum.wgsl`; directional lights with a shared shadow map are
//! looked up in it (`shaders/shadow_lookup.wgsl`) instead of traced.

use super::{dispatch, shadow_maps::ShadowMaps, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::ReadWrite;
use crate::gpu::{storage_entry, GpuContext};

/// Pipeline of the shadow frustum update.
pub(crate) struct ShadowFrustum {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl ShadowFrustum {
    /// `constants`: the scene's light count (`super::light_constants`).
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        constants: &[(&str, f64)],
    ) -> Self {
        let layout =
            ShadowMaps::stage_layout(ctx, "shadow frustum", vec![storage_entry(0, ReadWrite)]);
        let module = super::stage_shader(
            ctx,
            "shadow_frustum",
            concat!(
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/shadow_frustum.wgsl")
            ),
        );
        ShadowFrustum {
            pipeline: ctx.compute_pipeline_with(
                "shadow_frustum",
                &module,
                &[scene_layout, &layout],
                "main",
                constants,
            ),
            layout,
        }
    }

    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        maps: &ShadowMaps,
        ts: &Timestamps,
    ) {
        let own = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: set.vol.frustum.as_entire_binding(),
        }];
        let bg = maps.stage_bind_group(ctx, "shadow frustum", &self.layout, own);
        dispatch(
            enc,
            ts,
            Stage::ShadowFrustum,
            &self.pipeline,
            &[&set.bind_group, &bg],
            set.vol.groups.frustum,
        );
    }
}
