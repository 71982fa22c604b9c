//! G-buffer raster (one render pass per viewer, one submission), with `shaders/gbuffer.wgsl`.

use super::{scene_gpu::SceneGpu, Stage, Timestamps, ViewerVolumes};
use crate::gpu::GpuContext;
use crate::scene::Camera;

const VIEW_STRIDE: u64 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct RasterView {
    view_proj: [[f32; 4]; 4],
    position: [f32; 4],
    forward: [f32; 4],
}

impl RasterView {
    /// One raster view per camera, sharing the clip range and aspect ratio.
    pub(crate) fn for_cameras(cameras: &[Camera], aspect: f32, near: f32, far: f32) -> Vec<Self> {
        cameras
            .iter()
            .map(|c| Self {
                view_proj: (c.projection(aspect, near, far) * c.view()).to_cols_array_2d(),
                position: c.position.extend(0.0).to_array(),
                forward: c.forward.extend(0.0).to_array(),
            })
            .collect()
    }
}

/// Depth32Float, write on, nearer wins: the depth state of every raster pass.
pub(crate) fn depth_test() -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: wgpu::TextureFormat::Depth32Float,
        depth_write_enabled: Some(true),
        depth_compare: Some(wgpu::CompareFunction::Less),
        stencil: Default::default(),
        bias: Default::default(),
    }
}

/// A layout with one uniform buffer at binding 0, read at a dynamic offset per pass.
pub(crate) fn dynamic_uniform_layout(
    ctx: &GpuContext,
    label: &str,
    visibility: wgpu::ShaderStages,
    size: u64,
) -> wgpu::BindGroupLayout {
    ctx.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(size),
                },
                count: None,
            }],
        })
}

/// The raster pipeline and its per-viewer uniforms.
pub(crate) struct GBuffer {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    uniforms: wgpu::Buffer,
    capacity: usize,
}

impl GBuffer {
    pub(crate) fn new(ctx: &GpuContext) -> Self {
        let layout = dynamic_uniform_layout(
            ctx,
            "gbuffer",
            wgpu::ShaderStages::VERTEX_FRAGMENT,
            std::mem::size_of::<RasterView>() as u64,
        );
        let module = ctx.shader("gbuffer", &[include_str!("../../shaders/gbuffer.wgsl")]);
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("gbuffer"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let pipeline = ctx
            .device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("gbuffer"),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: 16,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Uint32],
                    })],
                },
                primitive: wgpu::PrimitiveState {
                    cull_mode: None,
                    ..Default::default()
                },
                depth_stencil: Some(depth_test()),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs_main"),
                    compilation_options: Default::default(),
                    targets: &[
                        target(wgpu::TextureFormat::Rgba32Float),
                        target(wgpu::TextureFormat::Rgba16Float),
                        target(wgpu::TextureFormat::Rgba8Unorm),
                    ],
                }),
                multiview_mask: None,
                cache: None,
            });
        GBuffer {
            pipeline,
            layout,
            uniforms: Self::uniform_buffer(ctx, 16),
            capacity: 16,
        }
    }

    fn uniform_buffer(ctx: &GpuContext, n: usize) -> wgpu::Buffer {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gbuffer views"),
            size: VIEW_STRIDE * n as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Records one render pass per viewer into its layer of the G-buffer arrays.
    pub(crate) fn add_passes(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        volumes: &ViewerVolumes,
        views: &[RasterView],
        ts: &Timestamps,
    ) {
        if views.len() > self.capacity {
            self.capacity = views.len().next_power_of_two();
            self.uniforms = Self::uniform_buffer(ctx, self.capacity);
        }
        let mut bytes = vec![0u8; VIEW_STRIDE as usize * views.len()];
        for (i, rv) in views.iter().enumerate() {
            let at = i * VIEW_STRIDE as usize;
            bytes[at..at + std::mem::size_of::<RasterView>()]
                .copy_from_slice(bytemuck::bytes_of(rv));
        }
        ctx.queue.write_buffer(&self.uniforms, 0, &bytes);
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gbuffer"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &self.uniforms,
                    offset: 0,
                    size: wgpu::BufferSize::new(std::mem::size_of::<RasterView>() as u64),
                }),
            }],
        });
        let layer = |t: &wgpu::Texture, i: u32| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: i,
                array_layer_count: Some(1),
                ..Default::default()
            })
        };
        let n = views.len() as u32;
        for i in 0..n {
            let views = [
                layer(&volumes.gbuf_position, i),
                layer(&volumes.gbuf_normal, i),
                layer(&volumes.gbuf_albedo, i),
            ];
            let depth = layer(&volumes.gbuf_depth, i);
            let clear = wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            };
            let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = views
                .iter()
                .map(|v| {
                    Some(wgpu::RenderPassColorAttachment {
                        view: v,
                        depth_slice: None,
                        resolve_target: None,
                        ops: clear,
                    })
                })
                .collect();
            let timestamp_writes = ts.render_writes(Stage::GBuffer, i == 0, i + 1 == n);
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("gbuffer"),
                color_attachments: &attachments,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if scene.index_count == 0 {
                continue;
            }
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bg, &[i * VIEW_STRIDE as u32]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..scene.index_count, 0, 0..1);
        }
    }
}
