//! G-buffer raster (one render pass per viewer, one submission), with `shaders/gbuffer.wgsl`;
//! with `triangle_cull`, each view draws the index list triangle_cull.rs wrote for it.

use super::triangle_cull::{TriangleLists, DRAW_ARGS_BYTES};
use super::{scene_gpu::SceneGpu, Stage, Timestamps, ViewerSet};
use crate::gpu::GpuContext;
use crate::scene::{Camera, Cull};
use glam::{Mat4, Vec3};

pub(crate) const VIEW_STRIDE: u64 = 256;

/// Levels of `occlusion_cull`'s depth pyramid above its pixels: level k holds 2^k × 2^k
/// pixels a tile, level 0 the pixels (`HIZ_LEVELS` in shaders/raster_view.wgsl).
pub(crate) const HIZ_LEVELS: u32 = 4;

/// Which of the raster's phases a pass draws: with `occlusion_cull` the triangles the
/// view saw last frame first, then those the occlusion test finds visible besides;
/// without it, everything in the first.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    First,
    Second,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct RasterView {
    view_proj: [[f32; 4]; 4],
    position: [f32; 4],
    forward: [f32; 4],
    /// Pixels (width, height).
    size: [f32; 2],
    /// Where the view's depth pyramid starts in its buffer (`occlusion_cull`), and its
    /// pixels in the small triangles' buffer (`micro_raster`); `GBuffer::upload` places
    /// them.
    hiz: [u32; 2],
    /// To `VIEW_STRIDE` bytes, the stride of the views in their buffer.
    _pad: [[f32; 4]; 9],
}

/// shaders/raster_view.wgsl, prepended to the raster's and the culling's shaders.
pub(crate) const RASTER_VIEW_WGSL: &str = include_str!("../../shaders/raster_view.wgsl");

const _: () = assert!(std::mem::size_of::<RasterView>() as u64 == VIEW_STRIDE);

impl RasterView {
    /// Tiles of level `k` of the view's depth pyramid, per row and column.
    pub(crate) fn hiz_dims(&self, k: u32) -> (u32, u32) {
        let t = 1 << k;
        (
            (self.size[0] as u32).div_ceil(t),
            (self.size[1] as u32).div_ceil(t),
        )
    }

    /// The view's pixels per row and column.
    pub(crate) fn pixels(&self) -> (u32, u32) {
        (self.size[0] as u32, self.size[1] as u32)
    }

    /// Tiles of the view's depth pyramid, all levels.
    pub(crate) fn hiz_tiles(&self) -> u64 {
        (0..=HIZ_LEVELS)
            .map(|k| {
                let (x, y) = self.hiz_dims(k);
                u64::from(x * y)
            })
            .sum()
    }

    /// One raster view per camera of `width`×`height` pixels, sharing the clip range.
    pub(crate) fn for_cameras(
        cameras: &[Camera],
        (width, height): (u32, u32),
        near: f32,
        far: f32,
    ) -> Vec<Self> {
        let aspect = width as f32 / height as f32;
        cameras
            .iter()
            .map(|c| Self {
                view_proj: (c.projection(aspect, near, far) * c.view()).to_cols_array_2d(),
                position: c.position.extend(0.0).to_array(),
                forward: c.forward.extend(0.0).to_array(),
                size: [width as f32, height as f32],
                hiz: [0, 0],
                _pad: [[0.0; 4]; 9],
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

/// The raster pipelines and their per-viewer uniforms.
pub(crate) struct GBuffer {
    /// One per `Cull`: both sides, without back faces, without front faces (counter-
    /// clockwise on screen is the front, as in glTF).
    pipelines: [wgpu::RenderPipeline; 3],
    layout: wgpu::BindGroupLayout,
    uniforms: wgpu::Buffer,
    capacity: usize,
    /// `None` where the adapter lacks subgroups of 8 lanes or more (the culling pass
    /// needs them): every view draws its clusters' ranges.
    lists: Option<TriangleLists>,
    /// This frame's triangles in the clusters each view's frustum touches, movers
    /// included, summed over views: what the views draw without `triangle_cull`.
    in_clusters: u64,
    /// This frame's movers' triangles, summed over views (drawn whole either way).
    mover_triangles: u64,
}

/// Whether the box (lo, hi) is outside the clip volume of `view_proj`: all eight corners
/// beyond one of its planes (conservative: a box that straddles a corner is kept).
fn box_outside(view_proj: &Mat4, lo: Vec3, hi: Vec3) -> bool {
    let mut outside = [true; 6];
    for k in 0..8 {
        let p = Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let c = *view_proj * p.extend(1.0);
        let beyond = [
            c.x < -c.w,
            c.x > c.w,
            c.y < -c.w,
            c.y > c.w,
            c.z < 0.0,
            c.z > c.w,
        ];
        for (o, b) in outside.iter_mut().zip(beyond) {
            *o &= b;
        }
    }
    outside.iter().any(|o| *o)
}

/// Index ranges to draw for one viewer, each with the side it culls: the clusters
/// inside its frustum (neighbours of one cull merged into one draw) and the movers
/// (both sides). (Drawing the clusters nearest first did not speed lavapipe up: its
/// G-buffer cost is in the triangles, not the fragments.)
fn visible_ranges(scene: &SceneGpu, view: &RasterView) -> Vec<(Cull, std::ops::Range<u32>)> {
    let mut ranges: Vec<(Cull, std::ops::Range<u32>)> = Vec::new();
    let visible = visible_clusters(scene, view).map(|k| {
        let c = &scene.clusters[k];
        (c.cull, c.indices.clone())
    });
    for (cull, r) in visible.chain(movers(scene)) {
        match ranges.last_mut() {
            Some((c, last)) if *c == cull && last.end == r.start => last.end = r.end,
            _ => ranges.push((cull, r)),
        }
    }
    ranges
}

/// The clusters whose boxes `view`'s frustum touches, in index order.
pub(crate) fn visible_clusters<'a>(
    scene: &'a SceneGpu,
    view: &RasterView,
) -> impl Iterator<Item = usize> + 'a {
    let vp = Mat4::from_cols_array_2d(&view.view_proj);
    (0..scene.clusters.len())
        .filter(move |&k| !box_outside(&vp, scene.clusters[k].min, scene.clusters[k].max))
}

/// The movers' index range (both sides seen), if there are movers.
fn movers(scene: &SceneGpu) -> Option<(Cull, std::ops::Range<u32>)> {
    let static_end = scene.clusters.last().map_or(0, |c| c.indices.end);
    (static_end < scene.index_count).then_some((Cull::None, static_end..scene.index_count))
}

impl GBuffer {
    pub(crate) fn new(ctx: &GpuContext) -> Self {
        let layout = dynamic_uniform_layout(
            ctx,
            "gbuffer",
            wgpu::ShaderStages::VERTEX_FRAGMENT,
            std::mem::size_of::<RasterView>() as u64,
        );
        let module = ctx.shader(
            "gbuffer",
            &[
                RASTER_VIEW_WGSL,
                super::GBUFFER_SURFACE_WGSL,
                include_str!("../../shaders/gbuffer.wgsl"),
            ],
        );
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
        let pipeline = |cull_mode| {
            ctx.device
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
                        cull_mode,
                        ..Default::default()
                    },
                    depth_stencil: Some(depth_test()),
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some("fs_main"),
                        compilation_options: Default::default(),
                        targets: &[target(super::viewer_volumes::GBUFFER_FORMAT)],
                    }),
                    multiview_mask: None,
                    cache: None,
                })
        };
        GBuffer {
            pipelines: [
                pipeline(None),
                pipeline(Some(wgpu::Face::Back)),
                pipeline(Some(wgpu::Face::Front)),
            ],
            layout,
            uniforms: Self::uniform_buffer(ctx, 16),
            capacity: 16,
            lists: (ctx.has_subgroups && ctx.adapter_info.subgroup_min_size >= 8)
                .then(|| TriangleLists::new(ctx)),
            in_clusters: 0,
            mover_triangles: 0,
        }
    }

    fn uniform_buffer(ctx: &GpuContext, n: usize) -> wgpu::Buffer {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gbuffer views"),
            size: VIEW_STRIDE * n as u64,
            usage: wgpu::BufferUsages::UNIFORM
                | wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Writes every viewer's raster view of this frame, all sets one after another
    /// (before any set's passes are recorded), and with `triangle_cull` plans the
    /// views' triangle lists.
    pub(crate) fn upload(
        &mut self,
        ctx: &GpuContext,
        scene: &SceneGpu,
        views: &[RasterView],
        (triangle_cull, occlusion_cull, micro_raster): (bool, bool, bool),
    ) {
        // Each view's clusters, found once: the culling's pairs and the stats read them.
        let visible: Vec<Vec<usize>> = views
            .iter()
            .map(|v| visible_clusters(scene, v).collect())
            .collect();
        // The views' depth tiles one after another (`occlusion_cull`), and their pixels
        // (`micro_raster`).
        let mut views = views.to_vec();
        let (mut tiles, mut pixels) = (0u64, 0u64);
        for v in &mut views {
            v.hiz = [tiles as u32, pixels as u32];
            tiles += v.hiz_tiles();
            let (w, h) = v.pixels();
            pixels += u64::from(w) * u64::from(h);
        }
        if let Some(lists) = &mut self.lists {
            lists.upload(
                ctx,
                scene,
                &visible,
                (triangle_cull, occlusion_cull, micro_raster),
                (tiles, pixels),
            );
        }
        let movers = movers(scene).map_or(0, |(_, r)| u64::from(r.end - r.start) / 3);
        self.mover_triangles = movers * views.len() as u64;
        self.in_clusters = self.mover_triangles
            + visible
                .iter()
                .flatten()
                .map(|&k| u64::from(scene.clusters[k].indices.len() as u32) / 3)
                .sum::<u64>();
        if views.len() > self.capacity {
            self.capacity = views.len().next_power_of_two();
            self.uniforms = Self::uniform_buffer(ctx, self.capacity);
        }
        // A view is VIEW_STRIDE bytes: the views lie at the stride as they are.
        ctx.queue
            .write_buffer(&self.uniforms, 0, bytemuck::cast_slice(&views));
    }

    /// Records the triangle culling of every view of the frame (before any set's raster).
    pub(crate) fn add_culling(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        ts: &Timestamps,
    ) {
        if let Some(lists) = &self.lists {
            lists.add_phase(ctx, enc, scene, &self.uniforms, Phase::First, ts);
        }
    }

    /// The active triangle lists, if the views draw them this frame.
    fn active_lists(&self) -> Option<&TriangleLists> {
        self.lists.as_ref().filter(|l| l.pair_count > 0)
    }

    /// Whether this frame's raster has a second phase (`occlusion_cull`).
    pub(crate) fn two_phases(&self) -> bool {
        self.active_lists().is_some_and(|l| l.occlusion)
    }

    /// Records `set`'s depth tiles from its first phase (`occlusion_cull`).
    pub(crate) fn add_hiz(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        if let Some(lists) = self.active_lists() {
            lists.add_hiz(ctx, enc, &self.uniforms, set, ts);
        }
    }

    /// Records `set`'s small triangles' resolve into its G-buffer (`micro_raster`, after
    /// the set's raster).
    pub(crate) fn add_micro_resolve(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        if let Some(lists) = self.active_lists() {
            lists.add_micro_resolve(ctx, enc, scene, &self.uniforms, set, ts);
        }
    }

    /// Records the occlusion test of every view's kept triangles and the second lists
    /// (after every set's depth tiles).
    pub(crate) fn add_occlusion(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        ts: &Timestamps,
    ) {
        if let Some(lists) = self.active_lists() {
            lists.add_phase(ctx, enc, scene, &self.uniforms, Phase::Second, ts);
        }
    }

    /// (triangles drawn, triangles in the clusters the views' frustums touch) this
    /// frame, summed over views, movers included; `kept` is the culling pass's count
    /// of the static triangles it kept (`C_RASTER_TRIANGLES`).
    pub(crate) fn raster_triangles(&self, kept: u64) -> (u64, u64) {
        let culled = self.active_lists().is_some();
        let drawn = if culled {
            kept + self.mover_triangles
        } else {
            self.in_clusters
        };
        (drawn, self.in_clusters)
    }

    /// Bytes the views' triangle lists hold this frame (0 without `triangle_cull`).
    pub(crate) fn list_bytes(&self) -> u64 {
        self.lists.as_ref().map_or(0, TriangleLists::bytes)
    }

    /// Records one render pass per viewer of `set` into its layer of the G-buffer
    /// arrays; the set's raster views start at `set.first_view` in the uploaded list.
    /// The first phase clears and draws the first lists and the movers, the second
    /// (`two_phases`) draws the second lists over it.
    pub(crate) fn add_passes(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        set: &ViewerSet,
        phase: Phase,
        ts: &Timestamps,
    ) {
        let first = set.first_view;
        let volumes = &set.vol;
        let views = &set.raster_views;
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
            let targets = [layer(&volumes.gbuf, i)];
            let depth = layer(&volumes.gbuf_depth, i);
            let (load, load_depth) = match phase {
                Phase::First => (
                    wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    wgpu::LoadOp::Clear(1.0),
                ),
                Phase::Second => (wgpu::LoadOp::Load, wgpu::LoadOp::Load),
            };
            let clear = wgpu::Operations {
                load,
                store: wgpu::StoreOp::Store,
            };
            let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = targets
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
            let timestamp_writes = ts.render(Stage::GBuffer);
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("gbuffer"),
                color_attachments: &attachments,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth,
                    depth_ops: Some(wgpu::Operations {
                        load: load_depth,
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
            pass.set_bind_group(0, &bg, &[(first as u32 + i) * VIEW_STRIDE as u32]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            if let Some(lists) = self.active_lists() {
                // The view's culled list (its sides already culled), then the movers.
                pass.set_pipeline(&self.pipelines[Cull::None as usize]);
                pass.set_index_buffer(lists.indices.slice(..), wgpu::IndexFormat::Uint32);
                let mut draw = first as u64 + u64::from(i);
                if phase == Phase::Second {
                    draw += u64::from(lists.views);
                }
                pass.draw_indexed_indirect(&lists.args, draw * DRAW_ARGS_BYTES);
                if phase == Phase::Second {
                    continue;
                }
                if let Some((_, range)) = movers(scene) {
                    pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(range, 0, 0..1);
                }
                continue;
            }
            let mut bound = None;
            for (cull, range) in visible_ranges(scene, &views[i as usize]) {
                if bound != Some(cull) {
                    pass.set_pipeline(&self.pipelines[cull as usize]);
                    bound = Some(cull);
                }
                pass.draw_indexed(range, 0, 0..1);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view_proj(position: Vec3, forward: Vec3) -> Mat4 {
        let c = Camera::new(position, forward, 60f32.to_radians());
        c.projection(16.0 / 9.0, 0.1, 40.0) * c.view()
    }

    #[test]
    fn boxes_outside_the_frustum_are_rejected_and_no_visible_box_is() {
        let vp = view_proj(Vec3::ZERO, Vec3::NEG_Z);
        let unit = Vec3::splat(0.5);
        // In front of the eye, behind it, past the far plane, far off to the side.
        assert!(!box_outside(
            &vp,
            Vec3::new(0.0, 0.0, -5.0) - unit,
            Vec3::new(0.0, 0.0, -5.0) + unit
        ));
        assert!(box_outside(
            &vp,
            Vec3::new(0.0, 0.0, 5.0) - unit,
            Vec3::new(0.0, 0.0, 5.0) + unit
        ));
        assert!(box_outside(
            &vp,
            Vec3::new(0.0, 0.0, -50.0) - unit,
            Vec3::new(0.0, 0.0, -50.0) + unit
        ));
        assert!(box_outside(
            &vp,
            Vec3::new(40.0, 0.0, -5.0) - unit,
            Vec3::new(40.0, 0.0, -5.0) + unit
        ));
        // Around the eye, and a long wall crossing the view whose corners are all outside.
        assert!(!box_outside(&vp, -unit, unit));
        assert!(!box_outside(
            &vp,
            Vec3::new(-100.0, -1.0, -6.0),
            Vec3::new(100.0, 1.0, -5.0)
        ));
        // Every corner beyond a different plane, the box seen through its middle.
        assert!(!box_outside(&vp, Vec3::splat(-100.0), Vec3::splat(100.0)));
    }
}
