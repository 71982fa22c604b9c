//! The froxel renderer: the four stages of paper 000 §3.1 plus G-buffer and composite.
//!
//! [`Renderer::render`] reads top to bottom as the frame runs: upload, G-buffer,
//! shared grid (world space, once), shadow frustums, froxel lighting, integration and
//! composite (each one dispatch for all viewers), then one readback.

mod composite;
mod froxel_cull;
mod froxel_lighting;
mod gbuffer;
mod gpu_types;
#[cfg(test)]
mod history_tests;
mod media_transmittance;
mod ray_query;
mod scene_gpu;
mod settings;
mod shadow_frustum;
mod shadow_maps;
mod shared_grid;
mod stats;
mod viewer_volumes;
mod volume_integration;

pub use ray_query::{trace_shadow_rays, ShadowRayQuery};
pub use settings::{Mode, Settings};
pub use shared_grid::SharedShadowGrid;
pub use stats::{FrameStats, MemoryReport, RayCounts, StageTiming};
pub use viewer_volumes::{largest_binding, viewer_memory_bytes, ViewerLayout, ViewerVolumes};

use crate::gpu::{map_read, GpuContext};
use crate::scene::{Bvh, Camera, Scene};
use glam::Vec3;
use gpu_types::*;
use std::sync::Arc;
use std::time::Instant;

const COMMON_WGSL: &str = include_str!("../../shaders/common.wgsl");
const BVH_WGSL: &str = include_str!("../../shaders/bvh.wgsl");

/// Compiles one compute stage: the shared bindings and helpers (common.wgsl), the
/// frame-counter helper for this adapter (per subgroup where supported), BVH traversal,
/// then the stage itself.
pub(crate) fn stage_shader(ctx: &GpuContext, label: &str, stage: &str) -> wgpu::ShaderModule {
    // naga (wgpu 30) takes subgroup built-ins when the device has the feature, and
    // rejects the `enable subgroups;` directive.
    let count = if ctx.has_subgroups {
        include_str!("../../shaders/count_subgroup.wgsl")
    } else {
        include_str!("../../shaders/count_atomic.wgsl")
    };
    ctx.shader(label, &[COMMON_WGSL, count, BVH_WGSL, stage])
}

/// Stages with a GPU time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stage {
    GBuffer = 0,
    SharedGrid = 1,
    ShadowFrustum = 2,
    FroxelLighting = 3,
    VolumeIntegration = 4,
    Composite = 5,
    GridRequests = 6,
    ShadowMaps = 7,
    MediaTransmittance = 8,
}

const STAGES: [(Stage, &str); 9] = [
    (Stage::GBuffer, "gbuffer"),
    (Stage::ShadowMaps, "shadow_maps"),
    (Stage::MediaTransmittance, "media_transmittance"),
    (Stage::GridRequests, "grid_requests"),
    (Stage::SharedGrid, "shared_grid"),
    (Stage::ShadowFrustum, "shadow_frustum"),
    (Stage::FroxelLighting, "froxel_lighting"),
    (Stage::VolumeIntegration, "volume_integration"),
    (Stage::Composite, "composite"),
];

/// Timestamp queries for each stage, when the adapter has them.
pub(crate) struct Timestamps {
    set: Option<wgpu::QuerySet>,
}

impl Timestamps {
    fn writes(&self, stage: Stage) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        self.span_writes(stage, true, true)
    }

    /// Timestamps for one of several passes of a stage: its start on the first, its end
    /// on the last.
    fn span_writes(
        &self,
        stage: Stage,
        first: bool,
        last: bool,
    ) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let q = self.set.as_ref()?;
        (first || last).then_some(wgpu::ComputePassTimestampWrites {
            query_set: q,
            beginning_of_pass_write_index: first.then_some(stage as u32 * 2),
            end_of_pass_write_index: last.then_some(stage as u32 * 2 + 1),
        })
    }

    fn render_writes(
        &self,
        stage: Stage,
        first: bool,
        last: bool,
    ) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        let q = self.set.as_ref()?;
        (first || last).then_some(wgpu::RenderPassTimestampWrites {
            query_set: q,
            beginning_of_pass_write_index: first.then_some(stage as u32 * 2),
            end_of_pass_write_index: last.then_some(stage as u32 * 2 + 1),
        })
    }
}

/// Records one compute pass of a stage: `pipeline` with the scene's bind group (0) and
/// the stage's own (1), over `workgroups`.
pub(crate) fn dispatch(
    enc: &mut wgpu::CommandEncoder,
    label: &str,
    ts: Option<wgpu::ComputePassTimestampWrites<'_>>,
    pipeline: &wgpu::ComputePipeline,
    [scene, stage]: [&wgpu::BindGroup; 2],
    [x, y, z]: [u32; 3],
) {
    let mut pass = compute_pass(enc, label, ts);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, scene, &[]);
    pass.set_bind_group(1, stage, &[]);
    pass.dispatch_workgroups(x, y, z);
}

pub(crate) fn compute_pass<'e>(
    enc: &'e mut wgpu::CommandEncoder,
    label: &str,
    ts: Option<wgpu::ComputePassTimestampWrites<'_>>,
) -> wgpu::ComputePass<'e> {
    enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: ts,
    })
}

/// One rendered frame: an RGBA8 image per viewer and the frame's counters.
#[derive(Debug, Clone)]
pub struct FrameOutput {
    /// Width of every image, pixels.
    pub width: u32,
    /// Height of every image, pixels.
    pub height: u32,
    /// One tightly packed RGBA8 image per viewer.
    pub images: Vec<Vec<u8>>,
    /// Counters, memory and timings.
    pub stats: FrameStats,
}

/// Renders a scene for many viewers at once.
pub struct Renderer {
    ctx: Arc<GpuContext>,
    scene: Arc<Scene>,
    settings: Settings,
    scene_gpu: scene_gpu::SceneGpu,
    grid: Option<SharedShadowGrid>,
    volumes: Option<ViewerVolumes>,
    gbuffer: gbuffer::GBuffer,
    frustum: shadow_frustum::ShadowFrustum,
    cull: froxel_cull::FroxelCull,
    shadow_maps: shadow_maps::ShadowMaps,
    transmittance: media_transmittance::MediaTransmittance,
    lighting: froxel_lighting::FroxelLighting,
    integration: volume_integration::VolumeIntegration,
    composite: composite::Composite,
    timestamps: Timestamps,
    ts_resolve: Option<wgpu::Buffer>,
    frame_index: u32,
    prev_view_proj: Vec<glam::Mat4>,
    /// The lights as last uploaded (animated lights move; a change marks the light dirty).
    lights_uploaded: Option<Vec<LightGpu>>,
    /// Scene time of the movers as last uploaded.
    movers_time: Option<f32>,
    triangles: usize,
}

impl Renderer {
    /// Builds the BVH and every pipeline for `scene`.
    pub fn new(
        ctx: Arc<GpuContext>,
        scene: Arc<Scene>,
        settings: Settings,
    ) -> anyhow::Result<Renderer> {
        settings.validate()?;
        let t = Instant::now();
        let bvh = Bvh::build(&scene.mesh)?;
        tracing::info!(
            triangles = bvh.triangle_count(),
            nodes = bvh.gpu_nodes.len(),
            ms = t.elapsed().as_millis() as u64,
            "BVH built"
        );
        Self::with_bvh(ctx, scene, &bvh, settings)
    }

    /// As [`Renderer::new`], reusing a BVH built before.
    pub fn with_bvh(
        ctx: Arc<GpuContext>,
        scene: Arc<Scene>,
        bvh: &Bvh,
        settings: Settings,
    ) -> anyhow::Result<Renderer> {
        settings.validate()?;
        let light_media = media_transmittance::plan(
            &scene,
            if settings.mode == Mode::Shared {
                settings.transmittance_voxel_m
            } else {
                0.0
            },
        );
        let scene_gpu = scene_gpu::SceneGpu::new(&ctx, &scene, bvh, &light_media)?;
        let grid = match (settings.mode, scene.media_bounds()) {
            (Mode::Shared, Some(bounds)) if !scene.lights.is_empty() => {
                Some(SharedShadowGrid::new(
                    &ctx,
                    &scene_gpu.layout,
                    bounds,
                    settings.voxel_size_m,
                    shared_grid::UpdatePolicy {
                        demand: settings.demand || settings.brick_pool > 0,
                        cache: settings.cache && settings.brick_pool == 0,
                        brick_pool: settings.brick_pool,
                    },
                )?)
            }
            _ => None,
        };
        let set = ctx.has_timestamps.then(|| {
            ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("stage timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: STAGES.len() as u32 * 2,
            })
        });
        let ts_resolve = set.as_ref().map(|_| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: STAGES.len() as u64 * 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        });
        Ok(Renderer {
            gbuffer: gbuffer::GBuffer::new(&ctx),
            frustum: shadow_frustum::ShadowFrustum::new(&ctx, &scene_gpu.layout),
            cull: froxel_cull::FroxelCull::new(&ctx, &scene_gpu.layout),
            shadow_maps: shadow_maps::ShadowMaps::new(
                &ctx,
                &scene,
                if settings.mode == Mode::Shared {
                    settings.shadow_map_px
                } else {
                    0
                },
            ),
            transmittance: media_transmittance::MediaTransmittance::new(
                &ctx,
                &scene_gpu.layout,
                &scene,
                &light_media,
            ),
            lighting: froxel_lighting::FroxelLighting::new(&ctx, &scene_gpu.layout),
            integration: volume_integration::VolumeIntegration::new(&ctx, &scene_gpu.layout),
            composite: composite::Composite::new(&ctx, &scene_gpu.layout),
            triangles: bvh.triangle_count()
                + scene.movers.iter().map(|m| m.mesh.len()).sum::<usize>(),
            scene_gpu,
            grid,
            volumes: None,
            timestamps: Timestamps { set },
            ts_resolve,
            frame_index: 0,
            prev_view_proj: Vec::new(),
            lights_uploaded: None,
            movers_time: None,
            ctx,
            scene,
            settings,
        })
    }

    /// The settings in force.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The shared grid (mode `shared` with media and lights only).
    pub fn shared_grid(&self) -> Option<&SharedShadowGrid> {
        self.grid.as_ref()
    }

    /// Reads the shared grid's words and touched nibbles back (for tests and tools).
    pub fn read_shared_grid(&self) -> anyhow::Result<Option<(Vec<u32>, Vec<u32>)>> {
        let Some(g) = &self.grid else { return Ok(None) };
        let words = bytemuck::cast_slice(&self.ctx.read_buffer(&g.grid)?).to_vec();
        let touched = bytemuck::cast_slice(&self.ctx.read_buffer(&g.touched)?).to_vec();
        Ok(Some((words, touched)))
    }

    /// Reads every viewer's integrated froxel volume back as f32 `[r, g, b, transmittance]`
    /// (for tests and tools: NaN or inf here is hidden by the RGBA8 clamp of the image).
    /// Viewer `i`'s froxel `(x, y, slice)` is at `i·X·Y·slices + x + X·(y + Y·slice)` for
    /// an `X × Y` froxel grid; empty before the first frame.
    pub fn read_integrated_volume(&self) -> anyhow::Result<Vec<[f32; 4]>> {
        let Some(v) = &self.volumes else {
            return Ok(Vec::new());
        };
        let bytes = self.ctx.read_buffer(&v.integrated)?;
        let froxels = v.count * v.froxels_per_view() as usize;
        // `pack_rgba16` in common.wgsl: two u32 words, each the low half first.
        Ok(bytes
            .chunks_exact(8)
            .take(froxels)
            .map(|f| [0, 2, 4, 6].map(|k| f16_to_f32(u16::from_le_bytes([f[k], f[k + 1]]))))
            .collect())
    }

    fn ensure_volumes(&mut self, count: usize, width: u32, height: u32) -> anyhow::Result<()> {
        let s = &self.settings;
        let layout = ViewerLayout::new(s, width, height);
        let fits = self
            .volumes
            .as_ref()
            .is_some_and(|v| v.count == count && v.layout == layout);
        if !fits {
            self.volumes = Some(ViewerVolumes::new(
                &self.ctx,
                count,
                layout,
                s.slices,
                s.frustum_slices(),
                s.temporal,
            )?);
            self.prev_view_proj.clear();
        }
        Ok(())
    }

    /// Writes the frame's uniforms; returns the flags, whether the scene has media, and
    /// the lights whose media transmittance is refilled this frame.
    fn upload(&mut self, cameras: &[Camera], time_s: f32) -> anyhow::Result<(u32, bool, u32)> {
        let scene = &self.scene;
        let s = &self.settings;
        let vol = self
            .volumes
            .as_ref()
            .expect("volumes allocated before upload");
        let (near, far) = (scene.render.near_m, scene.render.far_m);
        let has_media = !scene.media.is_empty();
        let history = s.temporal && vol.has_history && self.prev_view_proj.len() == cameras.len();
        // Per-frame jitter along the view ray (a 1D low-discrepancy sequence), centred.
        let jitter = if s.temporal {
            ((self.frame_index as f32 * 0.618_034).fract() - 0.5) * 0.999
        } else {
            0.0
        };
        let aspect = vol.layout.width as f32 / vol.layout.height as f32;
        let mut views = Vec::with_capacity(cameras.len());
        let mut view_projs = Vec::with_capacity(cameras.len());
        for (i, c) in cameras.iter().enumerate() {
            let vp = c.projection(aspect, near, far) * c.view();
            let right = c.forward.cross(c.up()).normalize();
            let up = right.cross(c.forward);
            let tan_y = (c.fov_y * 0.5).tan();
            let prev = if history { self.prev_view_proj[i] } else { vp };
            views.push(ViewGpu {
                view_proj: vp.to_cols_array_2d(),
                prev_view_proj: prev.to_cols_array_2d(),
                position: c.position.to_array(),
                near,
                forward: c.forward.to_array(),
                far,
                right: right.to_array(),
                tan_x: tan_y * aspect,
                up: up.to_array(),
                tan_y,
                size: [vol.layout.width, vol.layout.height],
                froxel_dims: vol.layout.froxel_dims,
                frustum_dims: vol.layout.frustum_dims,
                froxel_px: s.froxel_px,
                frustum_px: s.frustum_px,
                froxel_base: i as u32 * vol.froxels_per_view(),
                frustum_base: i as u32 * vol.frustum_per_view(),
                pixel_base: i as u32 * vol.layout.width * vol.layout.height,
                jitter,
            });
            view_projs.push(vp);
        }
        self.prev_view_proj = view_projs;
        let mut flags = 0;
        if s.parity {
            flags |= FLAG_PARITY;
        }
        if s.trilinear {
            flags |= FLAG_TRILINEAR;
        }
        if s.mode == Mode::Shared {
            flags |= FLAG_SHARED;
        }
        if has_media {
            flags |= FLAG_MEDIA;
        }
        if history {
            flags |= FLAG_HISTORY;
        }
        if s.demand || s.brick_pool > 0 {
            flags |= FLAG_DEMAND;
        }
        if s.brick_pool > 0 {
            flags |= FLAG_SPARSE;
        }
        if s.cache && s.brick_pool == 0 {
            flags |= FLAG_CACHE;
        }
        if self.transmittance.in_use() {
            flags |= FLAG_MEDIA_T;
        }
        // Only where the culling passes run: a grid exists (media and lights).
        if s.culls_hidden_froxels() && self.grid.is_some() && !scene.lights.is_empty() {
            flags |= FLAG_CULL;
        }
        // Animated lights: upload the lights at this time, marking the ones that changed.
        let lights: Vec<LightGpu> = scene.lights_at(time_s).iter().map(LightGpu::from).collect();
        let dirty_lights = match &self.lights_uploaded {
            Some(prev) => lights
                .iter()
                .zip(prev)
                .enumerate()
                .filter(|(_, (a, b))| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
                .fold(0u32, |m, (i, _)| m | (1 << i)),
            None => (1u32 << lights.len()) - 1,
        };
        if dirty_lights != 0 {
            self.scene_gpu.write_lights(&self.ctx, &lights);
        }
        self.lights_uploaded = Some(lights);
        let transmittance_dirty = self.transmittance.dirty(dirty_lights);
        // Movers: their tree and vertices at this time, and the bounds they swept since
        // the last frame (what cached grid bits must be re-checked against).
        let mover_root = self.scene_gpu.write_movers(&self.ctx, scene, time_s)?;
        let mut moved = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        if let Some(prev) = self.movers_time.filter(|p| *p != time_s) {
            for m in &scene.movers {
                for (lo, hi) in [m.bounds_at(prev), m.bounds_at(time_s)] {
                    moved = (moved.0.min(lo), moved.1.max(hi));
                }
            }
        }
        self.movers_time = Some(time_s);
        let s = &self.settings;
        let (lo, hi) = scene.bounds;
        let g = self.grid.as_ref();
        let frame = FrameGpu {
            grid_min: g.map_or([0.0; 3], |g| g.min.to_array()),
            voxel_size: g.map_or(1.0, |g| g.voxel_size_m),
            grid_dims: g.map_or([1; 3], |g| g.dims.to_array()),
            light_count: scene.lights.len() as u32,
            sky: scene.render.sky,
            medium_count: scene.media.len() as u32,
            ambient: scene.render.ambient,
            exposure: scene.render.exposure,
            view_count: cameras.len() as u32,
            frame_index: self.frame_index,
            flags,
            time_s,
            grid_words_x: g.map_or(1, |g| g.words_x),
            // A directional shadow ray never needs to be longer than the scene.
            max_ray_m: (hi - lo).length() + 1.0,
            frustum_slices: if s.mode == Mode::Shared {
                s.frustum_slices()
            } else {
                0
            },
            slices: s.slices,
            depth_curve: s.depth_curve,
            dirty_lights,
            pool_capacity: s.brick_pool,
            mover_root,
            moved_min: moved.0.to_array(),
            transmittance_dirty,
            moved_max: moved.1.to_array(),
            media_step_m: s.media_step_m,
        };
        self.scene_gpu.ensure_views(&self.ctx, cameras.len())?;
        self.ctx
            .queue
            .write_buffer(&self.scene_gpu.frame, 0, bytemuck::bytes_of(&frame));
        self.ctx
            .queue
            .write_buffer(&self.scene_gpu.views, 0, bytemuck::cast_slice(&views));
        Ok((flags, has_media, transmittance_dirty))
    }

    /// Renders one frame for every camera (all the same size) at scene time `time_s`.
    pub fn render(
        &mut self,
        cameras: &[Camera],
        width: u32,
        height: u32,
        time_s: f32,
    ) -> anyhow::Result<FrameOutput> {
        anyhow::ensure!(!cameras.is_empty(), "at least one viewer is needed");
        anyhow::ensure!(
            (1..=8192).contains(&width) && (1..=8192).contains(&height),
            "viewer size {width}×{height}: must be 1..=8192 on each side"
        );
        anyhow::ensure!(time_s.is_finite(), "scene time {time_s} must be finite");
        for (i, c) in cameras.iter().enumerate() {
            anyhow::ensure!(
                c.position.is_finite()
                    && c.forward.is_finite()
                    && c.fov_y.is_finite()
                    && c.fov_y > 0.0
                    && c.fov_y < 3.1,
                "viewer {i}: camera {c:?} is not finite or its field of view is out of range"
            );
        }
        let started = Instant::now();
        self.ensure_volumes(cameras.len(), width, height)?;
        let (flags, has_media, transmittance_dirty) = self.upload(cameras, time_s)?;
        let ctx = self.ctx.clone();
        let has_lights = !self.scene.lights.is_empty();
        let shared = self.settings.mode == Mode::Shared;
        let vol = self.volumes.as_ref().expect("allocated above");
        let scene_bg = &self.scene_gpu.bind_group;
        let mut dispatches = Vec::new();

        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        enc.clear_buffer(&self.scene_gpu.counters, 0, None);
        self.gbuffer.add_passes(
            &ctx,
            &mut enc,
            &self.scene_gpu,
            vol,
            &gbuffer::RasterView::for_cameras(
                cameras,
                vol.layout.width as f32 / vol.layout.height as f32,
                self.scene.render.near_m,
                self.scene.render.far_m,
            ),
            &self.timestamps,
        );
        if self.shadow_maps.add_passes(
            &ctx,
            &mut enc,
            &self.scene,
            &self.scene_gpu,
            time_s,
            &self.timestamps,
        ) {
            dispatches.push(("shadow_maps", [0, 0, 0]));
        }
        // Media transmittance toward the lights: world space, before any viewer reads it;
        // skipped when no light's volume is stale.
        if self
            .transmittance
            .add_pass(&mut enc, scene_bg, transmittance_dirty, &self.timestamps)
        {
            dispatches.push(("media_transmittance", self.transmittance.workgroups()));
        }
        // Passes with no work are skipped: no media means no froxel stages at all, and
        // no lights means no shadow rays.
        if has_media {
            if shared && has_lights {
                if let Some(grid) = &self.grid {
                    let culled = flags & FLAG_CULL != 0;
                    if culled {
                        self.cull
                            .add_passes(&ctx, &mut enc, scene_bg, vol, &self.timestamps);
                    }
                    if (self.settings.demand || grid.is_sparse())
                        && grid.add_request_passes(
                            &ctx,
                            &mut enc,
                            scene_bg,
                            vol,
                            &self.timestamps,
                            culled,
                        )
                    {
                        dispatches
                            .push(("grid_requests", SharedShadowGrid::request_workgroups(vol)));
                    }
                    grid.add_pass(&ctx, &mut enc, scene_bg, &self.timestamps);
                    dispatches.push(("shared_grid", grid.workgroups()));
                }
                if vol.frustum_slices > 0 {
                    self.frustum.add_pass(
                        &ctx,
                        &mut enc,
                        scene_bg,
                        vol,
                        &self.shadow_maps,
                        &self.timestamps,
                    );
                    dispatches.push((
                        "shadow_frustum",
                        shadow_frustum::ShadowFrustum::workgroups(vol),
                    ));
                }
            }
            self.lighting.add_pass(
                &ctx,
                &mut enc,
                scene_bg,
                self.grid.as_ref(),
                vol,
                &self.timestamps,
            );
            dispatches.push((
                "froxel_lighting",
                froxel_lighting::FroxelLighting::workgroups(vol),
            ));
            self.integration
                .add_pass(&ctx, &mut enc, scene_bg, vol, &self.timestamps);
            dispatches.push((
                "volume_integration",
                volume_integration::VolumeIntegration::workgroups(vol),
            ));
            if self.settings.temporal {
                enc.copy_buffer_to_buffer(
                    &vol.froxels,
                    0,
                    &vol.froxel_history,
                    0,
                    vol.froxels.size(),
                );
            }
        }
        self.composite.add_pass(
            &ctx,
            &mut enc,
            scene_bg,
            vol,
            &self.shadow_maps,
            &self.timestamps,
        );
        dispatches.push(("composite", composite::Composite::workgroups(vol)));

        // One readback of images, counters and timestamps.
        let staging = |size: u64, label: &str| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let pixels_bytes = vol.count as u64 * width as u64 * height as u64 * 4;
        let image_staging = staging(pixels_bytes, "image readback");
        enc.copy_buffer_to_buffer(&vol.output, 0, &image_staging, 0, pixels_bytes);
        let counter_staging = staging(self.scene_gpu.counters.size(), "counter readback");
        enc.copy_buffer_to_buffer(
            &self.scene_gpu.counters,
            0,
            &counter_staging,
            0,
            self.scene_gpu.counters.size(),
        );
        let ts_staging = match (&self.timestamps.set, &self.ts_resolve) {
            (Some(set), Some(resolve)) => {
                enc.resolve_query_set(set, 0..STAGES.len() as u32 * 2, resolve, 0);
                let s = staging(resolve.size(), "timestamp readback");
                enc.copy_buffer_to_buffer(resolve, 0, &s, 0, resolve.size());
                Some(s)
            }
            _ => None,
        };
        ctx.queue.submit([enc.finish()]);
        let pixels = map_read(&ctx.device, &image_staging)?;
        let counters: Vec<u32> =
            bytemuck::cast_slice(&map_read(&ctx.device, &counter_staging)?).to_vec();
        let ticks: Option<Vec<u64>> = match ts_staging {
            Some(s) => Some(bytemuck::cast_slice(&map_read(&ctx.device, &s)?).to_vec()),
            None => None,
        };
        let frame_ms = started.elapsed().as_secs_f64() * 1e3;
        if let Some(v) = self.volumes.as_mut() {
            v.has_history = self.settings.temporal && has_media;
        }
        let vol = self.volumes.as_ref().expect("allocated above");

        let ran: Vec<&str> = std::iter::once("gbuffer")
            .chain(dispatches.iter().map(|(n, _)| *n))
            .collect();
        let stage_ms = match &ticks {
            Some(t) => STAGES
                .iter()
                .filter(|(_, name)| ran.contains(name))
                .map(|(st, name)| {
                    let i = *st as usize * 2;
                    let ms = t[i + 1].saturating_sub(t[i]) as f64
                        * ctx.timestamp_period_ns as f64
                        * 1e-6;
                    StageTiming {
                        stage: name.to_string(),
                        gpu_ms: ms,
                    }
                })
                .collect(),
            None => Vec::new(),
        };
        let images = pixels
            .chunks_exact((width * height * 4) as usize)
            .map(<[u8]>::to_vec)
            .collect();
        let stats = stats::build(stats::StatsInput {
            settings: &self.settings,
            scene: &self.scene,
            triangles: self.triangles,
            counters: &counters,
            grid: self.grid.as_ref(),
            shadow_map_bytes: self.shadow_maps.bytes(),
            scene_memory: &self.scene_gpu.memory,
            volumes: vol,
            stage_ms,
            frame_ms,
            dispatches,
            frame_index: self.frame_index,
            timestamps: ctx.has_timestamps,
        });
        self.frame_index = self.frame_index.wrapping_add(1);
        Ok(FrameOutput {
            width,
            height,
            images,
            stats,
        })
    }
}

/// IEEE 754 binary16 bits to f32, exactly (subnormals, inf and NaN included).
fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exponent = u32::from((h >> 10) & 0x1f);
    let mantissa = u32::from(h & 0x3ff);
    match exponent {
        0 => sign * mantissa as f32 * 2f32.powi(-24),
        0x1f => f32::from_bits((u32::from(h & 0x8000) << 16) | 0x7f80_0000 | (mantissa << 13)),
        _ => f32::from_bits(
            (u32::from(h & 0x8000) << 16) | ((exponent + 112) << 23) | (mantissa << 13),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::f16_to_f32;

    #[test]
    fn f16_decodes_known_values() {
        let cases: [(u16, f32); 10] = [
            (0x0000, 0.0),
            (0x3c00, 1.0),
            (0xc000, -2.0),
            (0x3555, 0.333_251_95),
            (0x7bff, 65504.0),
            (0xfbff, -65504.0),
            (0x0400, 6.103_515_6e-5),
            (0x0001, 5.960_464_5e-8),
            (0x83ff, -6.097_555e-5),
            (0x7c00, f32::INFINITY),
        ];
        for (bits, want) in cases {
            assert_eq!(f16_to_f32(bits), want, "{bits:#06x}");
        }
        assert_eq!(f16_to_f32(0xfc00), f32::NEG_INFINITY);
        assert!(f16_to_f32(0x7e00).is_nan() && f16_to_f32(0xfe01).is_nan());
        assert!(f16_to_f32(0x8000).is_sign_negative());
    }
}
