//! Shadow maps for directional lights (beyond paper 000; `shared` mode's
//! `shadow_map_px`), with `shaders/shadow_map.wgsl`. Like the shared grid, this is
//! view-independent work done once for every viewer (DESIGN.md §1's light-space stage):
//! per directional light, an orthographic depth map of the static scene, rendered again
//! only when the light turns, and a small map of the movers alone over the sphere they
//! turn in, rendered every frame they move. The composite looks surface shadows up in
//! both (2×2 PCF) instead of tracing a ray per pixel and light, and the shadow frustum
//! the near-field fog (nearest texel) instead of a ray per frustum froxel
//! (`shaders/shadow_lookup.wgsl`). Point and spot lights keep their rays.

use super::gbuffer::{depth_test, dynamic_uniform_layout};
use super::{scene_gpu::SceneGpu, Stage, Timestamps};
use crate::gpu::Access::Read;
use crate::gpu::{storage_entry, GpuContext};
use crate::scene::{Light, LightKind, Scene};
use glam::{Mat4, Vec3};

const VIEW_STRIDE: u64 = 256;

/// Texels a side of each light's movers map.
const MOVER_PX: u32 = 1024;

/// One orthographic map as the composite reads it.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct MapGpu {
    view_proj: [[f32; 4]; 4],
    /// Layer in its depth array, or −1: no map.
    layer: i32,
    /// World size of one texel, metres (scales the lookup's normal offset).
    texel_m: f32,
    _pad: [f32; 2],
}

/// Per scene light: its static map and its movers map.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct LightMapsGpu {
    scene: MapGpu,
    movers: MapGpu,
}

/// A depth-array texture and the bounds its layers cover.
struct MapSet {
    px: u32,
    texture: wgpu::Texture,
    bounds: Aabb,
    /// Index range drawn into it.
    indices: std::ops::Range<u32>,
    /// Light directions its layers were rendered for (`None`: never).
    rendered_for: Option<Vec<[f32; 3]>>,
}

/// The maps, their pipeline and what the composite binds.
pub(crate) struct ShadowMaps {
    scene_maps: MapSet,
    mover_maps: MapSet,
    sampler: wgpu::Sampler,
    /// One [`LightMapsGpu`] per scene light.
    info: wgpu::Buffer,
    info_cpu: Vec<LightMapsGpu>,
    /// Scene lights with maps (directional ones), in layer order.
    lights: Vec<usize>,
    movers_time: Option<f32>,
    pipeline: Option<wgpu::RenderPipeline>,
    layout: wgpu::BindGroupLayout,
    uniforms: wgpu::Buffer,
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

/// An axis-aligned box (min, max).
type Aabb = (Vec3, Vec3);

fn union(a: Option<Aabb>, lo: Vec3, hi: Vec3) -> Option<Aabb> {
    Some(match a {
        Some((a, b)) => (a.min(lo), b.max(hi)),
        None => (lo, hi),
    })
}

/// Bounds of the static mesh, and of the spheres the movers turn in.
fn bounds(scene: &Scene) -> (Option<Aabb>, Option<Aabb>) {
    let mut stat = None;
    for p in &scene.mesh.positions {
        stat = union(stat, *p, *p);
    }
    let mut movers = None;
    for m in &scene.movers {
        let r = m
            .mesh
            .positions
            .iter()
            .map(|p| p.distance(m.pivot))
            .fold(0.0f32, f32::max);
        movers = union(movers, m.pivot - Vec3::splat(r), m.pivot + Vec3::splat(r));
    }
    (stat, movers)
}

fn depth_array(ctx: &GpuContext, label: &str, px: u32, layers: usize) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: px,
            height: px,
            depth_or_array_layers: layers.max(1) as u32,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Depth32Float,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    })
}

impl MapSet {
    fn new(
        ctx: &GpuContext,
        label: &str,
        px: u32,
        layers: usize,
        bounds: Option<Aabb>,
        indices: std::ops::Range<u32>,
    ) -> MapSet {
        let px = if bounds.is_some() && layers > 0 {
            px
        } else {
            1
        };
        MapSet {
            px,
            texture: depth_array(ctx, label, px, layers),
            bounds: bounds.unwrap_or((Vec3::ZERO, Vec3::ONE)),
            indices,
            rendered_for: None,
        }
    }

    fn used(&self) -> bool {
        self.px > 1
    }

    fn bytes(&self, layers: usize) -> u64 {
        if self.used() {
            self.px as u64 * self.px as u64 * 4 * layers as u64
        } else {
            0
        }
    }

    fn map_gpu(&self, dir: Vec3, layer: usize) -> MapGpu {
        if !self.used() {
            return MapGpu {
                layer: -1,
                ..Default::default()
            };
        }
        let (lo, hi) = self.bounds;
        MapGpu {
            view_proj: light_view_proj(dir, lo, hi).to_cols_array_2d(),
            layer: layer as i32,
            texel_m: (hi - lo).max_element() / self.px as f32,
            _pad: [0.0; 2],
        }
    }

    pub(crate) fn view(&self) -> wgpu::TextureView {
        self.texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        })
    }
}

impl ShadowMaps {
    /// Maps of `px`² for the scene's directional lights (none when `px` is 0 or the scene
    /// has no directional light: 1×1 stand-ins keep the composite's bindings valid).
    pub(crate) fn new(ctx: &GpuContext, scene: &Scene, px: u32) -> Self {
        let lights: Vec<usize> = if px == 0 {
            Vec::new()
        } else {
            scene
                .lights
                .iter()
                .enumerate()
                .filter(|(_, l)| l.kind == LightKind::Directional)
                .map(|(i, _)| i)
                .collect()
        };
        let (static_bounds, mover_bounds) = bounds(scene);
        let static_indices = scene.mesh.indices.len() as u32 * 3;
        let mover_indices = scene
            .movers
            .iter()
            .map(|m| m.mesh.indices.len() as u32 * 3)
            .sum::<u32>();
        let n = lights.len();
        let scene_maps = MapSet::new(ctx, "shadow maps", px, n, static_bounds, 0..static_indices);
        let mover_maps = MapSet::new(
            ctx,
            "mover shadow maps",
            MOVER_PX,
            n,
            mover_bounds,
            static_indices..static_indices + mover_indices,
        );
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow map compare"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let mut info_cpu = vec![
            LightMapsGpu {
                scene: MapGpu {
                    layer: -1,
                    ..Default::default()
                },
                movers: MapGpu {
                    layer: -1,
                    ..Default::default()
                },
            };
            scene.lights.len().max(1)
        ];
        let lights_now = scene.lights_at(0.0);
        for (layer, li) in lights.iter().enumerate() {
            let dir = lights_now[*li].direction;
            info_cpu[*li] = LightMapsGpu {
                scene: scene_maps.map_gpu(dir, layer),
                movers: mover_maps.map_gpu(dir, layer),
            };
        }
        let info = ctx.storage_init("shadow map info", &info_cpu, wgpu::BufferUsages::empty());
        let layout = dynamic_uniform_layout(ctx, "shadow map", wgpu::ShaderStages::VERTEX, 64);
        let pipeline = (!lights.is_empty()).then(|| Self::pipeline(ctx, &layout));
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow map views"),
            size: VIEW_STRIDE * 2 * n.max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ShadowMaps {
            scene_maps,
            mover_maps,
            sampler,
            info,
            info_cpu,
            lights,
            movers_time: None,
            pipeline,
            layout,
            uniforms,
        }
    }

    fn pipeline(ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> wgpu::RenderPipeline {
        let module = ctx.shader(
            "shadow_map",
            &[include_str!("../../shaders/shadow_map.wgsl")],
        );
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("shadow map"),
                bind_group_layouts: &[Some(layout)],
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
                depth_stencil: Some(depth_test()),
                multisample: Default::default(),
                fragment: None,
                multiview_mask: None,
                cache: None,
            })
    }

    /// The bind-group layout of a compute stage that reads the maps: the stage's own
    /// `entries`, then the maps' at bindings 5–8 (`shaders/shadow_lookup.wgsl`).
    pub(crate) fn stage_layout(
        ctx: &GpuContext,
        label: &str,
        mut entries: Vec<wgpu::BindGroupLayoutEntry>,
    ) -> wgpu::BindGroupLayout {
        entries.extend(Self::layout_entries());
        ctx.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            })
    }

    /// A bind group for [`Self::stage_layout`]'s `layout`: the stage's own `entries`,
    /// then this frame's maps.
    pub(crate) fn stage_bind_group(
        &self,
        ctx: &GpuContext,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        entries: Vec<wgpu::BindGroupEntry<'_>>,
    ) -> wgpu::BindGroup {
        let views = (self.scene_maps.view(), self.mover_maps.view());
        let entries: Vec<wgpu::BindGroupEntry> =
            entries.into_iter().chain(self.entries(&views)).collect();
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        })
    }

    /// Layout entries 5–8: the maps, their sampler and their projections.
    fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 4] {
        let depth_array = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Depth,
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        [
            depth_array(5),
            wgpu::BindGroupLayoutEntry {
                binding: 6,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                count: None,
            },
            storage_entry(7, Read),
            depth_array(8),
        ]
    }

    /// Bind-group entries 5–8 for [`Self::layout_entries`].
    fn entries<'a>(
        &'a self,
        views: &'a (wgpu::TextureView, wgpu::TextureView),
    ) -> [wgpu::BindGroupEntry<'a>; 4] {
        [
            wgpu::BindGroupEntry {
                binding: 5,
                resource: wgpu::BindingResource::TextureView(&views.0),
            },
            wgpu::BindGroupEntry {
                binding: 6,
                resource: wgpu::BindingResource::Sampler(&self.sampler),
            },
            wgpu::BindGroupEntry {
                binding: 7,
                resource: self.info.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 8,
                resource: wgpu::BindingResource::TextureView(&views.1),
            },
        ]
    }

    /// Bytes of the depth maps.
    pub(crate) fn bytes(&self) -> u64 {
        let n = self.lights.len();
        self.scene_maps.bytes(n) + self.mover_maps.bytes(n)
    }

    /// Forgets what the maps were rendered for: the next frame renders them all.
    pub(crate) fn invalidate(&mut self) {
        self.scene_maps.rendered_for = None;
        self.mover_maps.rendered_for = None;
        self.movers_time = None;
    }

    /// Re-renders the static maps if a directional light turned, and the movers' maps if
    /// the movers moved; returns whether it recorded anything.
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
        let lights: Vec<Light> = scene.lights_at(time_s);
        let dirs: Vec<[f32; 3]> = self
            .lights
            .iter()
            .map(|li| lights[*li].direction.to_array())
            .collect();
        let redo_scene = self.scene_maps.rendered_for.as_ref() != Some(&dirs);
        let redo_movers = self.mover_maps.used()
            && (redo_scene
                || self.mover_maps.rendered_for.as_ref() != Some(&dirs)
                || self.movers_time != Some(time_s));
        if !redo_scene && !redo_movers {
            return false;
        }
        // Projections of the current light directions: static maps in the uniforms'
        // first half, movers' maps in the second.
        let n = self.lights.len();
        let mut bytes = vec![0u8; VIEW_STRIDE as usize * 2 * n];
        for (layer, li) in self.lights.iter().enumerate() {
            let dir = lights[*li].direction;
            self.info_cpu[*li] = LightMapsGpu {
                scene: self.scene_maps.map_gpu(dir, layer),
                movers: self.mover_maps.map_gpu(dir, layer),
            };
            for (half, m) in [self.info_cpu[*li].scene, self.info_cpu[*li].movers]
                .iter()
                .enumerate()
            {
                let at = (half * n + layer) * VIEW_STRIDE as usize;
                bytes[at..at + 64].copy_from_slice(bytemuck::cast_slice(&m.view_proj));
            }
        }
        ctx.queue.write_buffer(&self.uniforms, 0, &bytes);
        ctx.queue
            .write_buffer(&self.info, 0, bytemuck::cast_slice(&self.info_cpu));
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
        let mut passes: Vec<(&MapSet, usize, usize)> = Vec::new();
        for layer in 0..n {
            if redo_scene {
                passes.push((&self.scene_maps, 0, layer));
            }
            if redo_movers {
                passes.push((&self.mover_maps, 1, layer));
            }
        }
        for (set, half, layer) in passes {
            let view = set.texture.create_view(&wgpu::TextureViewDescriptor {
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
                timestamp_writes: ts.render(Stage::ShadowMaps),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if set.indices.is_empty() {
                continue;
            }
            let offset = ((half * n + layer) as u64 * VIEW_STRIDE) as u32;
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bg, &[offset]);
            pass.set_vertex_buffer(0, scene_gpu.vertices.slice(..));
            pass.set_index_buffer(scene_gpu.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(set.indices.clone(), 0, 0..1);
        }
        if redo_scene {
            self.scene_maps.rendered_for = Some(dirs.clone());
        }
        if redo_movers {
            self.mover_maps.rendered_for = Some(dirs);
            self.movers_time = Some(time_s);
        }
        true
    }
}
