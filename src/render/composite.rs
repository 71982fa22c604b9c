//! Composite + tone map, all viewers in one dispatch, with `shaders/composite.wgsl`.

use super::{dispatch, shadow_maps::ShadowMaps, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};

/// Pipeline of the composite stage.
pub(crate) struct Composite {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

pub(crate) fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    }
}

impl Composite {
    pub(crate) fn new(ctx: &GpuContext, scene_layout: &wgpu::BindGroupLayout) -> Self {
        let layout = ShadowMaps::stage_layout(
            ctx,
            "composite",
            vec![
                storage_entry(0, Read),
                storage_entry(1, ReadWrite),
                texture_entry(2),
                texture_entry(3),
                texture_entry(4),
            ],
        );
        let module = super::stage_shader(
            ctx,
            "composite",
            concat!(
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/composite.wgsl")
            ),
        );
        Composite {
            pipeline: ctx.compute_pipeline("composite", &module, &[scene_layout, &layout]),
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
        let volumes = &set.vol;
        let array_view = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            })
        };
        let (pos, nrm, alb) = (
            array_view(&volumes.gbuf_position),
            array_view(&volumes.gbuf_normal),
            array_view(&volumes.gbuf_albedo),
        );
        let entries = vec![
            wgpu::BindGroupEntry {
                binding: 0,
                resource: volumes.integrated.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: volumes.output.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&pos),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::TextureView(&nrm),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::TextureView(&alb),
            },
        ];
        let bg = maps.stage_bind_group(ctx, "composite", &self.layout, entries);
        dispatch(
            enc,
            ts,
            Stage::Composite,
            &self.pipeline,
            &[&set.bind_group, &bg],
            volumes.groups.pixels,
        );
    }
}
