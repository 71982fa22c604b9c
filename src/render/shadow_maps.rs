//! Surface shadow maps for directional lights (beyond paper 000; `shared` mode's
//! `shadow_map_px`), with `shaders/shadow_map.wgsl`. Like the shared grid, this is
//! view-independent work done once per frame for every viewer: one orthographic depth
//! map per directional light over the scene's bounds, re-rendered only when a light or
//! a mover changed. The composite then looks surface shadows up (2×2 PCF) instead of
//! tracing a ray per pixel and light. Point and spot lights keep their rays.

use super::{scene_gpu::SceneGpu, Stage, Timestamps};
use crate::gpu::GpuContext;
use crate::scene::Scene;
use glam::{Mat4, Vec3};

const VIEW_STRIDE: u64 = 256;

/// Per light (indexed like the scene's lights), as the composite reads it.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ShadowMapGpu {
    view_proj: [[f32; 4]; 4],
    /// Layer of the depth array, or -1: trace a ray.
    layer: i32,
    /// World size of one texel, metres (sets the lookup's normal offset).
    texel_m: f32,
    /// Depth bias in the map's [0, 1] depth units.
    depth_bias: f32,
    _pad: f32,
}

/// The depth maps, their pipeline and what the composite binds.
pub(crate) struct ShadowMaps {
    pub(crate) px: u32,
    pub(crate) texture: wgpu::Texture,
    pub(crate) sampler: wgpu::Sampler,
    /// One [`ShadowMapGpu`] per scene light.
    pub(crate) info: wgpu::Buffer,
    /// (scene light, its view-projection) per layer.
    layers: Vec<(usize, Mat4)>,
    info_cpu: Vec<ShadowMapGpu>,
    bounds: (Vec3, Vec3),
    pipeline: Option<wgpu::RenderPipeline>,
    layout: wgpu::BindGroupLayout,
    uniforms: wgpu::Buffer,
    /// Scene state the maps were rendered for: (light positions/directions, mover time).
    rendered_for: Option<(Vec<[f32; 3]>, f32)>,
}

/// Orthographic light view-projection over the box (lo, hi) looking along `dir`: x, y
/// across the light to [−1, 1], distance along it to depth [0, 1].
fn light_view_proj(dir: Vec3, lo: Vec3, hi: Vec3) -> Mat4 {
    let f = dir.normalize();
    let helper = if f.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let r = f.cross(helper).normalize();
    let u = r.cross(f);
    let (mut a, mut b) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for i in 0..8 {
        let c = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let l = Vec3::new(r.dot(c), u.dot(c), f.dot(c));
        a = a.min(l);
        b = b.max(l);
    }
    a.z -= 1.0;
    b.z += 1.0;
    let s = Vec3::new(2.0, 2.0, 1.0) / (b - a).max(Vec3::splat(1e-3));
    Mat4::from_cols(
        glam::Vec4::new(s.x * r.x, s.y * u.x, s.z * f.x, 0.0),
        glam::Vec4::new(s.x * r.y, s.y * u.y, s.z * f.y, 0.0),
        glam::Vec4::new(s.x * r.z, s.y * u.z, s.z * f.z, 0.0),
        glam::Vec4::new(-s.x * a.x - 1.0, -s.y * a.y - 1.0, -s.z * a.z, 1.0),
    )
}

/// Bounds of every triangle the maps must hold: the static mesh and each mover's
/// sphere around its pivot (it turns). `None` for a scene without geometry.
pub(crate) fn caster_bounds(scene: &Scene) -> Option<(Vec3, Vec3)> {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for p in &scene.mesh.positions {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    for m in &scene.movers {
        let r = m
            .mesh
            .positions
            .iter()
            .map(|p| p.distance(m.pivot))
            .fold(0.0f32, f32::max);
        lo = lo.min(m.pivot - Vec3::splat(r));
        hi = hi.max(m.pivot + Vec3::splat(r));
    }
    (lo.cmple(hi).all()).then_some((lo, hi))
}

impl ShadowMaps {
    /// Maps of `px`² for the scene's directional lights (none when `px` is 0 or the scene
    /// has no directional light: a 1×1 stand-in keeps the composite's bindings valid).
    pub(crate) fn new(ctx: &GpuContext, scene: &Scene, bounds: (Vec3, Vec3), px: u32) -> Self {
        let lights = scene.lights_at(0.0);
        let (lo, hi) = bounds;
        let layers: Vec<(usize, Mat4)> = if px == 0 {
            Vec::new()
        } else {
            lights
                .iter()
                .enumerate()
                .filter(|(_, l)| l.kind == 0)
                .map(|(i, l)| (i, light_view_proj(l.direction, lo, hi)))
                .collect()
        };
        let size = if layers.is_empty() { 1 } else { px };
        let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: size,
                height: size,
                depth_or_array_layers: layers.len().max(1) as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Depth32Float,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow map compare"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let extent = (hi - lo).max_element().max(1e-3);
        let mut info = vec![
            ShadowMapGpu {
                view_proj: Mat4::IDENTITY.to_cols_array_2d(),
                layer: -1,
                texel_m: 0.0,
                depth_bias: 0.0,
                _pad: 0.0,
            };
            lights.len().max(1)
        ];
        for (layer, (li, vp)) in layers.iter().enumerate() {
            // Depth spans the box's extent along the light plus 2 m: ~2 texels of bias.
            let range = (hi - lo).length() + 2.0;
            let texel_m = 1.5 * extent / px as f32;
            info[*li] = ShadowMapGpu {
                view_proj: vp.to_cols_array_2d(),
                layer: layer as i32,
                texel_m,
                depth_bias: texel_m / range,
                _pad: 0.0,
            };
        }
        let info_cpu = info.clone();
        let info = ctx.storage_init("shadow map info", &info, wgpu::BufferUsages::empty());
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("shadow map"),
                entries: &[wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(64),
                    },
                    count: None,
                }],
            });
        let pipeline = (!layers.is_empty()).then(|| {
            let module = ctx.shader(
                "shadow_map",
                &[include_str!("../../shaders/shadow_map.wgsl")],
            );
            let pl = ctx
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("shadow map"),
                    bind_group_layouts: &[Some(&layout)],
                    immediate_size: 0,
                });
            ctx.device
                .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("shadow map"),
                    layout: Some(&pl),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs_main"),
                        compilation_options: Default::default(),
                        buffers: &[Some(wgpu::VertexBufferLayout {
                            array_stride: 16,
                            step_mode: wgpu::VertexStepMode::Vertex,
                            attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                        })],
                    },
                    primitive: wgpu::PrimitiveState {
                        cull_mode: None,
                        ..Default::default()
                    },
                    depth_stencil: Some(wgpu::DepthStencilState {
                        format: wgpu::TextureFormat::Depth32Float,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(wgpu::CompareFunction::Less),
                        stencil: Default::default(),
                        bias: Default::default(),
                    }),
                    multisample: Default::default(),
                    fragment: None,
                    multiview_mask: None,
                    cache: None,
                })
        });
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow map views"),
            size: VIEW_STRIDE * layers.len().max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ShadowMaps {
            px: size,
            texture,
            sampler,
            info,
            layers,
            info_cpu,
            bounds,
            pipeline,
            layout,
            uniforms,
            rendered_for: None,
        }
    }

    /// Bytes of the depth maps.
    pub(crate) fn bytes(&self) -> u64 {
        if !self.layers.is_empty() {
            self.px as u64 * self.px as u64 * 4 * self.layers.len() as u64
        } else {
            0
        }
    }

    /// Re-renders the maps if a light or a mover changed since they were last rendered;
    /// returns whether it recorded anything.
    pub(crate) fn add_passes(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &Scene,
        scene_gpu: &SceneGpu,
        time_s: f32,
        ts: &Timestamps,
    ) -> bool {
        let Some(pipeline) = &self.pipeline else {
            return false;
        };
        let lights = scene.lights_at(time_s);
        let key = (
            self.layers
                .iter()
                .map(|(li, _)| lights[*li].direction.to_array())
                .collect::<Vec<_>>(),
            if scene.movers.is_empty() { 0.0 } else { time_s },
        );
        if self.rendered_for.as_ref() == Some(&key) {
            return false;
        }
        // A directional light that turned gets a fresh projection.
        let mut bytes = vec![0u8; VIEW_STRIDE as usize * self.layers.len()];
        for (layer, (li, vp)) in self.layers.iter_mut().enumerate() {
            *vp = light_view_proj(lights[*li].direction, self.bounds.0, self.bounds.1);
            self.info_cpu[*li].view_proj = vp.to_cols_array_2d();
            let at = layer * VIEW_STRIDE as usize;
            bytes[at..at + 64].copy_from_slice(bytemuck::cast_slice(&vp.to_cols_array()));
        }
        ctx.queue
            .write_buffer(&self.info, 0, bytemuck::cast_slice(&self.info_cpu));
        ctx.queue.write_buffer(&self.uniforms, 0, &bytes);
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shadow map"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &self.uniforms,
                    offset: 0,
                    size: wgpu::BufferSize::new(64),
                }),
            }],
        });
        let n = self.layers.len();
        for layer in 0..n {
            let view = self.texture.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: layer as u32,
                array_layer_count: Some(1),
                ..Default::default()
            });
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow map"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts.render_writes(Stage::ShadowMaps, layer == 0, layer + 1 == n),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if scene_gpu.index_count == 0 {
                continue;
            }
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bg, &[layer as u32 * VIEW_STRIDE as u32]);
            pass.set_vertex_buffer(0, scene_gpu.vertices.slice(..));
            pass.set_index_buffer(scene_gpu.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..scene_gpu.index_count, 0, 0..1);
        }
        self.rendered_for = Some(key);
        true
    }
}
