//! Smoke per viewer (issue 15, paper 001), batched over every viewer of a set: a compute
//! pass sorts each viewer's particles back to front and writes their proxies
//! (`shaders/smoke_proxies.wgsl`), then one render pass per viewer rasterises the proxies'
//! back faces into the viewer's layer of the set's smoke texture, each fragment
//! integrating its particle along the pixel's interval with the fog around it
//! (`shaders/smoke_raster.wgsl`). The composite lays the layer over the surface and fog.
//! Skipped entirely in a frame without live particles. See docs/decisions.md, "Smoke per
//! viewer: tetrahedra, interval shading, fog around it".

use super::scene_gpu::SceneGpu;
use super::shadow_maps::ShadowMaps;
use super::viewer_volumes::gbuffer_entry;
use super::{dispatch, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::ReadWrite;
use crate::gpu::{storage_entry, GpuContext};

/// Bytes of one proxy record (`SmokeProxy` in `shaders/smoke_common.wgsl`).
pub(crate) const SMOKE_PROXY_BYTES: u64 = 64;
/// Bytes per smoke texel (`Rgba16Float`).
const SMOKE_TEXEL_BYTES: u64 = 8;
/// Particles per proxy workgroup (`@workgroup_size` of smoke_proxies.wgsl).
const PROXY_GROUP: u32 = 64;
/// Stride of the per-viewer raster uniforms (the dynamic-offset alignment).
const VIEW_STRIDE: u64 = 256;
/// The smoke layers' format.
pub(crate) const SMOKE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

/// `SmokeView` in smoke_raster.wgsl: one viewer's raster pass.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SmokeViewUniform {
    view_proj: [[f32; 4]; 4],
    slot: u32,
    stride: u32,
    steps: u32,
    _pad: u32,
}

/// A viewer set's smoke buffers (only in a scene with emitters).
pub(crate) struct SmokeBuffers {
    /// Every viewer's sorted proxy list, `capacity` records each.
    pub(crate) proxies: wgpu::Buffer,
    /// One premultiplied `Rgba16Float` layer per viewer.
    pub(crate) layers: wgpu::Texture,
    uniforms: wgpu::Buffer,
    capacity: u32,
    count: u32,
}

/// Smoke bytes per viewer of `pixels` with room for `capacity` particles: its proxy list
/// and its smoke layer.
pub(crate) fn bytes_per_viewer(capacity: u32, pixels: u64) -> u64 {
    u64::from(capacity.max(1)) * SMOKE_PROXY_BYTES + pixels * SMOKE_TEXEL_BYTES
}

impl SmokeBuffers {
    pub(crate) fn new(
        ctx: &GpuContext,
        count: usize,
        width: u32,
        height: u32,
        capacity: u32,
    ) -> anyhow::Result<SmokeBuffers> {
        let capacity = capacity.max(1);
        let proxies = ctx.storage(
            "smoke proxies",
            count as u64 * u64::from(capacity) * SMOKE_PROXY_BYTES,
            wgpu::BufferUsages::empty(),
        )?;
        let layers = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("smoke layers"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: count as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SMOKE_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("smoke views"),
            size: VIEW_STRIDE * count.max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(SmokeBuffers {
            proxies,
            layers,
            uniforms,
            capacity,
            count: count as u32,
        })
    }

    /// Bytes per viewer: its proxy list and its smoke layer.
    pub(crate) fn bytes_per_viewer(&self, pixels: u64) -> u64 {
        bytes_per_viewer(self.capacity, pixels)
    }

    /// Writes every viewer's raster uniforms (view-projections in slot order).
    pub(crate) fn write_views(&self, ctx: &GpuContext, view_projs: &[[[f32; 4]; 4]], steps: u32) {
        let mut bytes = vec![0u8; VIEW_STRIDE as usize * view_projs.len()];
        for (i, vp) in view_projs.iter().enumerate() {
            let u = SmokeViewUniform {
                view_proj: *vp,
                slot: i as u32,
                stride: self.capacity,
                steps,
                _pad: 0,
            };
            let at = i * VIEW_STRIDE as usize;
            bytes[at..at + std::mem::size_of::<SmokeViewUniform>()]
                .copy_from_slice(bytemuck::bytes_of(&u));
        }
        if !bytes.is_empty() {
            ctx.queue.write_buffer(&self.uniforms, 0, &bytes);
        }
    }

    /// The proxy pass's workgroups for `particles` live particles.
    pub(crate) fn workgroups(&self, particles: u32) -> [u32; 3] {
        [particles.div_ceil(PROXY_GROUP), 1, self.count]
    }
}

/// The smoke stages' pipelines, shared by every viewer set.
pub(crate) struct SmokeView {
    proxy_layout: wgpu::BindGroupLayout,
    proxy_pipeline: wgpu::ComputePipeline,
    raster_layout: wgpu::BindGroupLayout,
    raster_pipeline: wgpu::RenderPipeline,
}

impl SmokeView {
    pub(crate) fn new(ctx: &GpuContext, scene: &SceneGpu) -> SmokeView {
        let common = include_str!("../../shaders/smoke_common.wgsl");
        let proxy_layout =
            ShadowMaps::stage_layout(ctx, "smoke proxies", vec![storage_entry(0, ReadWrite)]);
        let module = super::stage_shader(
            ctx,
            "smoke proxies",
            &[
                common,
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/smoke_proxies.wgsl"),
            ]
            .concat(),
        );
        let proxy_pipeline =
            ctx.compute_pipeline("smoke proxies", &module, &[&scene.layout, &proxy_layout]);

        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let storage_ro = |binding, visibility| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let mut raster_entries = vec![
            storage_ro(0, wgpu::ShaderStages::FRAGMENT),
            storage_ro(1, vf),
            wgpu::BindGroupLayoutEntry {
                visibility: wgpu::ShaderStages::FRAGMENT,
                ..gbuffer_entry(2)
            },
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility: vf,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(
                        std::mem::size_of::<SmokeViewUniform>() as u64,
                    ),
                },
                count: None,
            },
        ];
        // The shared shadow maps, read per Simpson node (geometric visibility).
        raster_entries.extend(ShadowMaps::layout_entries_for(wgpu::ShaderStages::FRAGMENT));
        let raster_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("smoke raster"),
                entries: &raster_entries,
            });
        let module = super::stage_shader(
            ctx,
            "smoke raster",
            &[
                common,
                include_str!("../../shaders/integrated_lookup.wgsl"),
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/smoke_raster.wgsl"),
            ]
            .concat(),
        );
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("smoke raster"),
                bind_group_layouts: &[Some(&scene.layout), Some(&raster_layout)],
                immediate_size: 0,
            });
        let blend = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        };
        let raster_pipeline = ctx
            .device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("smoke raster"),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                // Back faces only: one fragment per pixel a proxy covers, also with the
                // eye inside it or its front across the near plane.
                primitive: wgpu::PrimitiveState {
                    cull_mode: Some(wgpu::Face::Front),
                    ..Default::default()
                },
                depth_stencil: None,
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs_main"),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: SMOKE_FORMAT,
                        blend: Some(wgpu::BlendState {
                            color: blend,
                            alpha: blend,
                        }),
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            });
        SmokeView {
            proxy_layout,
            proxy_pipeline,
            raster_layout,
            raster_pipeline,
        }
    }

    /// Records the set's proxy pass: every viewer's particles sorted and their proxies
    /// written (`particles` live this frame, > 0).
    pub(crate) fn add_proxies(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        maps: &ShadowMaps,
        particles: u32,
        ts: &Timestamps,
    ) {
        let Some(smoke) = &set.vol.smoke else {
            return;
        };
        let entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: smoke.proxies.as_entire_binding(),
        }];
        let bg = maps.stage_bind_group(ctx, "smoke proxies", &self.proxy_layout, entries);
        dispatch(
            enc,
            ts,
            Stage::SmokeProxies,
            &self.proxy_pipeline,
            &[&set.bind_group, &bg],
            smoke.workgroups(particles),
        );
    }

    /// Records one render pass per viewer of the set into its smoke layer, cleared to 0.
    pub(crate) fn add_raster(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        maps: &ShadowMaps,
        particles: u32,
        ts: &Timestamps,
    ) {
        let vol = &set.vol;
        let Some(smoke) = &vol.smoke else {
            return;
        };
        let gbuf = vol.gbuf_array();
        let bg = maps.stage_bind_group(
            ctx,
            "smoke raster",
            &self.raster_layout,
            vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: vol.integrated.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: smoke.proxies.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&gbuf),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &smoke.uniforms,
                        offset: 0,
                        size: wgpu::BufferSize::new(std::mem::size_of::<SmokeViewUniform>() as u64),
                    }),
                },
            ],
        );
        let instances = particles.min(smoke.capacity);
        for i in 0..smoke.count {
            let layer = smoke.layers.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: i,
                array_layer_count: Some(1),
                ..Default::default()
            });
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("smoke raster"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &layer,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: ts.render(Stage::SmokeRaster),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.raster_pipeline);
            pass.set_bind_group(0, &set.bind_group, &[]);
            pass.set_bind_group(1, &bg, &[i * VIEW_STRIDE as u32]);
            pass.draw(0..12, 0..instances);
        }
    }
}

/// Reads every viewer's smoke layer back as f32 RGBA (premultiplied), row-major.
pub(crate) fn read_layers(
    ctx: &GpuContext,
    smoke: &SmokeBuffers,
    width: u32,
    height: u32,
) -> anyhow::Result<Vec<Vec<[f32; 4]>>> {
    let row = (u64::from(width) * SMOKE_TEXEL_BYTES).next_multiple_of(256);
    let layer_bytes = row * u64::from(height);
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("smoke readback"),
        size: layer_bytes * u64::from(smoke.count),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    enc.copy_texture_to_buffer(
        smoke.layers.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &staging,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row as u32),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: smoke.count,
        },
    );
    ctx.submit(enc);
    let bytes = crate::gpu::map_read(&ctx.device, &staging)?;
    let half = |b: &[u8], k: usize| super::f16_to_f32(u16::from_le_bytes([b[k], b[k + 1]]));
    Ok(bytes
        .chunks_exact(layer_bytes as usize)
        .map(|layer| {
            layer
                .chunks_exact(row as usize)
                .flat_map(|r| {
                    r[..(u64::from(width) * SMOKE_TEXEL_BYTES) as usize]
                        .chunks_exact(8)
                        .map(|t| [0, 2, 4, 6].map(|k| half(t, k)))
                })
                .collect()
        })
        .collect())
}

/// Every viewer's proxy list back to front, `particles` records each, as (particle slot,
/// sort key).
pub(crate) fn read_order(
    ctx: &GpuContext,
    smoke: &SmokeBuffers,
    particles: u32,
) -> anyhow::Result<Vec<Vec<(u32, f32)>>> {
    let bytes = ctx.read_buffer(&smoke.proxies)?;
    let word =
        |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    Ok((0..smoke.count as usize)
        .map(|v| {
            (0..particles.min(smoke.capacity) as usize)
                .map(|r| {
                    let at = (v * smoke.capacity as usize + r) * SMOKE_PROXY_BYTES as usize;
                    (word(at + 52), f32::from_bits(word(at + 48)))
                })
                .collect()
        })
        .collect())
}
