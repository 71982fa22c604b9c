//! Composite + tone map, all viewers in one dispatch, with `shaders/composite.wgsl`.

use super::viewer_volumes::gbuffer_entry;
use super::{dispatch, shadow_maps::ShadowMaps, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};

/// Pipeline of the composite stage.
pub(crate) struct Composite {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// Bound as the smoke layers of a set without them (never read: no particles).
    no_smoke: wgpu::Texture,
}

fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
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
    /// `constants`: the scene's light count (`super::light_constants`).
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        constants: &[(&str, f64)],
    ) -> Self {
        let layout = ShadowMaps::stage_layout(
            ctx,
            "composite",
            vec![
                storage_entry(0, Read),
                storage_entry(1, ReadWrite),
                gbuffer_entry(2),
                texture_entry(5),
            ],
        );
        let module = super::stage_shader_with(
            ctx,
            "composite",
            concat!(
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/integrated_lookup.wgsl"),
                include_str!("../../shaders/composite.wgsl")
            ),
            constants,
            &[super::LightSum {
                name: "surface_lights",
                term: "surface_light",
                params: "p: vec3f, n: vec3f, origin: vec3f, rays: ptr<function, u32>",
                args: "p, n, origin, rays",
            }],
        );
        let no_smoke = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("no smoke"),
            size: wgpu::Extent3d {
                width: 1,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: super::smoke_view::SMOKE_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        Composite {
            pipeline: ctx.compute_pipeline_with(
                "composite",
                &module,
                &[scene_layout, &layout],
                "main",
                constants,
            ),
            layout,
            no_smoke,
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
        let gbuf = volumes.gbuf_array();
        let smoke = array_view(volumes.smoke.as_ref().map_or(&self.no_smoke, |s| &s.layers));
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
                resource: wgpu::BindingResource::TextureView(&gbuf),
            },
            wgpu::BindGroupEntry {
                binding: 5,
                resource: wgpu::BindingResource::TextureView(&smoke),
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
