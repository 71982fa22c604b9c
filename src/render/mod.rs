//! The froxel renderer: the four stages of paper 000 §3.1 plus G-buffer and composite,
//! for every viewer of every size in one frame.
//!
//! A [`Renderer`] is one [`World`] (the scene and everything view-independent, updated
//! once per frame) and a viewer set per view size. [`Renderer::render_targets`] reads top
//! to bottom as the frame runs, one line per [`Stage`]: G-buffers, the world's shadow
//! maps, media transmittance and shared grid (fed by every set's requests), then the
//! per-viewer stages for each set, one submission and one readback. See
//! docs/architecture.md.

mod ambient_grid;
mod composite;
mod froxel_cull;
mod froxel_lighting;
mod gbuffer;
mod gpu_types;
#[cfg(test)]
mod history_tests;
#[cfg(test)]
mod light_constant_tests;
mod media_layer;
mod media_transmittance;
mod ray_query;
mod readback;
mod scene_gpu;
mod settings;
mod shadow_frustum;
mod shadow_maps;
mod shared_grid;
mod smoke_particles;
mod smoke_shadows;
mod smoke_view;
mod stage;
mod stats;
mod target;
mod triangle_cull;
mod viewer_set;
mod viewer_volumes;
mod volume_integration;
mod world;

pub use gpu_types::ParticleGpu;
pub use ray_query::{trace_shadow_rays, ShadowRayQuery};
pub(crate) use scene_gpu::particle_capacity;
pub use settings::{Mode, Settings};
pub use shared_grid::{GridUpdate, SharedShadowGrid};
pub use smoke_particles::cpu_particles;
pub use smoke_shadows::{SmokeMapKind, SmokeShadowMap, MAX_CROSSINGS as SMOKE_MAX_CROSSINGS};
pub use stage::{Scope, Stage};
pub use stats::{FrameStats, MemoryReport, RayCounts, StageTiming, ViewSize};
pub use target::{stereo_eyes, FrameOutput, FrameTarget, TargetView, TargetsOutput};
pub use triangle_cull::{
    micro_bytes_per_pixel, triangle_list_bytes_per_view, MICRO_MIN_TRIANGLES,
    OCCLUSION_MIN_TRIANGLES,
};
pub use viewer_set::ViewerId;
pub use viewer_volumes::{largest_binding, viewer_memory_bytes, ViewerLayout, ViewerVolumes};
pub use world::{Lookup, World};

use crate::gpu::GpuContext;
use crate::scene::{Bvh, Camera, Scene};
use gbuffer::Phase;
use gpu_types::*;
use readback::{Readback, ReadbackBytes};
pub(crate) use stage::{dispatch, dispatch_indirect, Timestamps};
use std::collections::btree_map::Entry;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;
use viewer_set::ViewerSet;

const COMMON_WGSL: &str = include_str!("../../shaders/common.wgsl");
const BVH_WGSL: &str = include_str!("../../shaders/bvh.wgsl");
const GBUFFER_SURFACE_WGSL: &str = include_str!("../../shaders/gbuffer_surface.wgsl");

/// The `LIGHTS` pipeline constant of shaders/common.wgsl: the scene's light count,
/// given to the stages that loop over the lights per froxel or per pixel (froxel
/// lighting, the shadow frustum, the composite), so that their loops run a count the
/// shader compiler knows.
pub(crate) fn light_constants(scene: &Scene) -> [(&'static str, f64); 1] {
    [("LIGHTS", scene.lights.len() as f64)]
}

/// A sum over the scene's lights that the WGSL calls and Rust writes out:
/// `fn {name}(acc: vec3f, {params}) -> vec3f` returns `acc` plus `{term}(li, {args})` for
/// each light in order. Where the stage knows the light count (the `LIGHTS` constant,
/// [`light_constants`]) and it is at most [`WRITTEN_OUT_LIGHTS`], each term names its
/// light by a literal, so lavapipe reads that light's records (its `Light`, media
/// volume, maps) as constants; a loop over `light_count()` leaves the index a variable,
/// and the same reads cost a quarter of the composite and a fifth of Sponza's froxel
/// lighting (docs/decisions.md, "Light loops written out"). Same terms in the same
/// order either way: the same bits.
pub(crate) struct LightSum {
    pub name: &'static str,
    pub term: &'static str,
    pub params: &'static str,
    pub args: &'static str,
}

/// The most lights a [`LightSum`] writes out: each term inlines its light's whole path
/// (a traced shadow ray's BVH walk included), and lavapipe's compile time grows with the
/// copies (written out for every count, `light_constant_tests` did not finish street,
/// six lights, within 10 minutes).
const WRITTEN_OUT_LIGHTS: u32 = 2;

/// In-scattered light in the fog, per light (shaders/common.wgsl `in_scattering`).
const SCATTERED_LIGHTS: LightSum = LightSum {
    name: "scattered_lights",
    term: "scattered_light",
    params: "g: f32, p: vec3f, view_dir: vec3f, vis: array<f32, 8>",
    args: "g, p, view_dir, vis",
};

impl LightSum {
    /// The function's WGSL for a stage with `constants` (its `LIGHTS`, if any).
    fn wgsl(&self, constants: &[(&str, f64)]) -> String {
        let LightSum {
            name,
            term,
            params,
            args,
        } = self;
        let lights = constants
            .iter()
            .find(|(k, _)| *k == "LIGHTS")
            .map_or(0, |&(_, v)| v as u32);
        let body = if lights == 0 || lights > WRITTEN_OUT_LIGHTS {
            format!(
                "    for (var li = 0u; li < light_count(); li++) {{\n        sum += {term}(li, {args});\n    }}\n"
            )
        } else {
            (0..lights)
                .map(|li| format!("    sum += {term}({li}u, {args});\n"))
                .collect()
        };
        format!("\nfn {name}(acc: vec3f, {params}) -> vec3f {{\n    var sum = acc;\n{body}    return sum;\n}}\n")
    }
}

/// Compiles one compute stage: the shared bindings and helpers (common.wgsl), the
/// frame-counter helper for this adapter (per subgroup where supported), BVH traversal,
/// then the stage itself.
pub(crate) fn stage_shader(ctx: &GpuContext, label: &str, stage: &str) -> wgpu::ShaderModule {
    stage_shader_with(ctx, label, stage, &[], &[])
}

/// As [`stage_shader`], for a stage created with pipeline `constants` (its `LIGHTS`
/// writes its light sums out, [`LightSum`]), with the stage's own `sums`.
pub(crate) fn stage_shader_with(
    ctx: &GpuContext,
    label: &str,
    stage: &str,
    constants: &[(&str, f64)],
    sums: &[LightSum],
) -> wgpu::ShaderModule {
    // naga (wgpu 30) takes subgroup built-ins when the device has the feature, and
    // rejects the `enable subgroups;` directive.
    let count = if ctx.has_subgroups {
        include_str!("../../shaders/count_subgroup.wgsl")
    } else {
        include_str!("../../shaders/count_atomic.wgsl")
    };
    let generated: String = std::iter::once(&SCATTERED_LIGHTS)
        .chain(sums)
        .map(|sum| sum.wgsl(constants))
        .collect();
    ctx.shader(
        label,
        &[
            COMMON_WGSL,
            GBUFFER_SURFACE_WGSL,
            count,
            BVH_WGSL,
            stage,
            &generated,
        ],
    )
}

/// The per-viewer stages' pipelines, shared by every viewer set.
struct ViewerStages {
    gbuffer: gbuffer::GBuffer,
    cull: froxel_cull::FroxelCull,
    frustum: shadow_frustum::ShadowFrustum,
    lighting: froxel_lighting::FroxelLighting,
    integration: volume_integration::VolumeIntegration,
    smoke: smoke_view::SmokeView,
    composite: composite::Composite,
}

/// Renders a scene for many viewers of any sizes at once: one [`World`] and a
/// [`viewer_set::ViewerSet`] per view size, one submission and one readback per frame.
pub struct Renderer {
    world: World,
    stages: ViewerStages,
    sets: BTreeMap<(u32, u32), ViewerSet>,
    timestamps: Timestamps,
    /// Live smoke particles of the last frame.
    particles: u32,
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
        let world = World::new(ctx.clone(), scene, bvh, settings)?;
        let layout = &world.gpu.layout;
        let lights = light_constants(&world.scene);
        // Froxel lighting also knows whether the grid's density is on fine cells
        // (`grid_media_fine`): off, its code for them is compiled out.
        let fine = world
            .grid()
            .and_then(|g| g.media.as_ref())
            .is_some_and(|m| m.fine);
        let lighting_constants = [lights[0], ("GRID_MEDIA_FINE", f64::from(u8::from(fine)))];
        Ok(Renderer {
            stages: ViewerStages {
                gbuffer: gbuffer::GBuffer::new(&ctx),
                cull: froxel_cull::FroxelCull::new(&ctx, layout),
                frustum: shadow_frustum::ShadowFrustum::new(&ctx, layout, &lights),
                lighting: froxel_lighting::FroxelLighting::new(&ctx, layout, &lighting_constants)?,
                integration: volume_integration::VolumeIntegration::new(&ctx, layout),
                smoke: smoke_view::SmokeView::new(&ctx, &world.gpu),
                composite: composite::Composite::new(&ctx, layout, &lights),
            },
            timestamps: Timestamps::new(&ctx),
            sets: BTreeMap::new(),
            particles: 0,
            world,
        })
    }

    /// After a frame that failed: the next frame starts from scratch (every light
    /// changed, every viewer without history), whatever the failed one left behind.
    pub fn invalidate(&mut self) {
        self.world.invalidate();
        self.sets.clear();
    }

    /// The settings in force.
    pub fn settings(&self) -> &Settings {
        &self.world.settings
    }

    /// The world: the scene and the structures every viewer shares.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The shared grid (mode `shared` with media and lights only).
    pub fn shared_grid(&self) -> Option<&SharedShadowGrid> {
        self.world.grid.as_ref()
    }

    /// View sizes with viewer volumes allocated (those of the last frame).
    pub fn view_sizes(&self) -> Vec<(u32, u32)> {
        self.sets.keys().copied().collect()
    }

    /// Reads the shared grid's words and touched nibbles back (for tests and tools).
    pub fn read_shared_grid(&self) -> anyhow::Result<Option<(Vec<u32>, Vec<u32>)>> {
        let Some(g) = &self.world.grid else {
            return Ok(None);
        };
        let ctx = &self.world.ctx;
        let words = bytemuck::cast_slice(&ctx.read_buffer(&g.grid)?).to_vec();
        let touched = bytemuck::cast_slice(&ctx.read_buffer(&g.touched)?).to_vec();
        Ok(Some((words, touched)))
    }

    /// Reads every light's smoke shadow maps back as the last frame built them (per light:
    /// none, its one map, or its cube's built faces; for tests and tools).
    pub fn read_smoke_shadows(&self) -> anyhow::Result<Vec<Vec<SmokeShadowMap>>> {
        self.world
            .smoke_shadows
            .read(&self.world.ctx, &self.world.gpu)
    }

    /// `smoke_transmittance(light, p)` (common.wgsl, what every stage multiplies into a
    /// light's transmittance) at every `(light, p)`, on the GPU, with the last frame's
    /// particles and maps (for tests).
    pub fn probe_smoke_transmittance(
        &self,
        points: &[(u32, glam::Vec3)],
    ) -> anyhow::Result<Vec<f32>> {
        let w = &self.world;
        w.smoke_shadows.probe(&w.ctx, &w.gpu.bind_group, points)
    }

    /// Reads the integrated froxel volume of the last frame's first view size back as f32
    /// `[r, g, b, transmittance]` (for tests and tools: NaN or inf here is hidden by the
    /// RGBA8 clamp of the image). Viewer `i`'s froxel `(x, y, slice)` is at
    /// `i·X·Y·slices + x + X·(y + Y·slice)` for an `X × Y` froxel grid; empty before the
    /// first frame. With hidden froxels culled, the GPU integrates each column only up to
    /// its limit (no pixel reads past it, and nothing was lit there); the readback
    /// continues each column past its limit with the value at the limit, what integrating
    /// the unlit slices gives.
    pub fn read_integrated_volume(&self) -> anyhow::Result<Vec<[f32; 4]>> {
        let Some(set) = self.sets.values().next() else {
            return Ok(Vec::new());
        };
        let v = &set.vol;
        let bytes = self.world.ctx.read_buffer(&v.integrated)?;
        let froxels = v.count * v.froxels_per_view() as usize;
        // `pack_rgba16` in common.wgsl: two u32 words, each the low half first.
        let mut volume: Vec<[f32; 4]> = bytes
            .chunks_exact(8)
            .take(froxels)
            .map(|f| [0, 2, 4, 6].map(|k| f16_to_f32(u16::from_le_bytes([f[k], f[k + 1]]))))
            .collect();
        if self.world.culls_hidden_froxels() {
            let limits: Vec<u32> = self
                .world
                .ctx
                .read_buffer(&v.column_limit)?
                .chunks_exact(4)
                .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
                .collect();
            let columns = (v.layout.froxel_dims[0] * v.layout.froxel_dims[1]) as usize;
            // The views' limits as the integration took them (a coupled eye without a
            // near field: its partner's).
            let limit_views: Vec<usize> = set
                .gpu_views
                .iter()
                .enumerate()
                .map(|(i, g)| {
                    if g.light_slices == 0 {
                        g.volume_view as usize
                    } else {
                        i
                    }
                })
                .collect();
            continue_past_limits(
                &mut volume,
                &limits,
                &limit_views,
                columns,
                v.slices as usize,
            );
        }
        Ok(volume)
    }

    /// Live smoke particles in the last frame (0: no smoke stage ran).
    pub fn particle_count(&self) -> u32 {
        self.particles
    }

    /// Reads the last frame's smoke layers of the first view size back as f32 RGBA
    /// (premultiplied, the fog around the smoke included), viewer by viewer, row-major
    /// (for tests and tools); empty in a scene without emitters. Stale after a frame
    /// without particles.
    pub fn read_smoke_layers(&self) -> anyhow::Result<Vec<Vec<[f32; 4]>>> {
        let Some((_, set)) = self.sets.iter().next() else {
            return Ok(Vec::new());
        };
        match &set.vol.smoke {
            Some(s) => {
                let l = set.vol.layout;
                smoke_view::read_layers(&self.world.ctx, s, l.width, l.height)
            }
            None => Ok(Vec::new()),
        }
    }

    /// The last frame's back-to-front particle order of the first view size, per viewer:
    /// (slot in the frame's particle list, distance from the eye as sorted on the GPU).
    pub fn read_smoke_order(&self) -> anyhow::Result<Vec<Vec<(u32, f32)>>> {
        let Some(set) = self.sets.values().next() else {
            return Ok(Vec::new());
        };
        match &set.vol.smoke {
            Some(s) => smoke_view::read_order(&self.world.ctx, s, self.particles),
            None => Ok(Vec::new()),
        }
    }

    /// Renders one frame for every camera (all the same size, each its own image, viewer
    /// ids 0, 1, …) at scene time `time_s`.
    pub fn render(
        &mut self,
        cameras: &[Camera],
        width: u32,
        height: u32,
        time_s: f32,
    ) -> anyhow::Result<FrameOutput> {
        anyhow::ensure!(!cameras.is_empty(), "at least one viewer is needed");
        let targets: Vec<FrameTarget> = cameras
            .iter()
            .enumerate()
            .map(|(i, c)| FrameTarget::single(i as ViewerId, *c, width, height))
            .collect();
        let out = self.render_targets(&targets, time_s)?;
        Ok(FrameOutput {
            width,
            height,
            images: out.images,
            stats: out.stats,
        })
    }

    /// Renders one frame of every target at scene time `time_s`: the world's stages
    /// once, then each stage for every viewer set, in one submission with one readback.
    pub fn render_targets(
        &mut self,
        targets: &[FrameTarget],
        time_s: f32,
    ) -> anyhow::Result<TargetsOutput> {
        anyhow::ensure!(!targets.is_empty(), "at least one frame target is needed");
        anyhow::ensure!(time_s.is_finite(), "scene time {time_s} must be finite");
        targets.iter().try_for_each(FrameTarget::validate)?;
        let started = Instant::now();
        let frame = self.world.begin_frame(time_s)?;
        self.particles = frame.particle_count;
        self.prepare_sets(targets, frame)?;
        let (world, stages, sets, ts) =
            (&mut self.world, &self.stages, &self.sets, &self.timestamps);
        let ctx = world.ctx.clone();
        let mut f = FrameRecorder::new(&ctx, sets);
        f.enc.clear_buffer(&world.gpu.counters, 0, None);
        // The frame, top to bottom: one line per stage, for the world or every set.
        stages.gbuffer.add_culling(&ctx, &mut f.enc, &world.gpu, ts);
        f.each_set(Stage::GBuffer, |e, s| {
            stages
                .gbuffer
                .add_passes(&ctx, e, &world.gpu, s, Phase::First, ts);
            stages.gbuffer.add_micro_resolve(&ctx, e, &world.gpu, s, ts)
        });
        if stages.gbuffer.two_phases() {
            // `occlusion_cull`: every set's depth tiles, the test, the second phase.
            for s in f.sets.values() {
                stages.gbuffer.add_hiz(&ctx, &mut f.enc, s, ts);
            }
            stages
                .gbuffer
                .add_occlusion(&ctx, &mut f.enc, &world.gpu, ts);
            for s in f.sets.values() {
                stages
                    .gbuffer
                    .add_passes(&ctx, &mut f.enc, &world.gpu, s, Phase::Second, ts);
            }
        }
        f.world(Stage::SmokeParticles, |e, _| {
            world.add_smoke_particles(e, ts)
        });
        f.world(Stage::ShadowMaps, |e, _| {
            world.add_shadow_maps(e, time_s, ts)
        });
        f.world(Stage::MediaLayer, |e, _| world.add_media_layer(e, ts));
        f.world(Stage::MediaTransmittance, |e, _| {
            world.add_transmittance(e, &frame, ts)
        });
        f.world(Stage::SmokeShadows, |e, _| world.add_smoke_shadows(e, ts));
        f.world(Stage::AmbientGrid, |e, _| world.add_ambient(e, ts));
        let (grid, maps, cull) = (
            world.grid(),
            &world.shadow_maps,
            frame.flags & FLAG_CULL != 0,
        );
        if let Some(grid) = grid {
            let world_bg = &world.gpu.bind_group;
            let cull = cull.then_some(&stages.cull);
            let from_froxels = frame.flags & FLAG_FROXEL_REQUESTS != 0;
            f.world(Stage::GridRequests, |e, sets| {
                grid.add_requests(&ctx, e, world_bg, sets, cull, from_froxels, ts)
            });
            f.world(Stage::SharedGrid, |e, _| {
                grid.add_pass(&ctx, e, world_bg, ts)
            });
            if frame.frustum_slices > 0 {
                f.each_set(Stage::ShadowFrustum, |e, s| {
                    stages.frustum.add_pass(&ctx, e, s, maps, ts)
                });
            }
        } else if cull {
            // `froxel_maps` without a grid: the culling passes alone.
            f.each_set(Stage::GridRequests, |e, s| {
                stages.cull.add_passes(&ctx, e, s, ts)
            });
        }
        if world.has_media() {
            f.each_set(Stage::FroxelLighting, |e, s| {
                stages.lighting.add_pass(&ctx, e, s, grid, maps, ts)
            });
            f.each_set(Stage::VolumeIntegration, |e, s| {
                stages.integration.add_pass(&ctx, e, s, ts)
            });
        }
        // Smoke only in a frame with live particles (else the images are bit-identical to
        // a scene without emitters: the composite does not read the layers).
        let particles = frame.particle_count;
        if particles > 0 {
            f.each_set(Stage::SmokeProxies, |e, s| {
                stages.smoke.add_proxies(&ctx, e, s, maps, particles, ts)
            });
            f.each_set(Stage::SmokeRaster, |e, s| {
                stages.smoke.add_raster(&ctx, e, s, maps, particles, ts)
            });
        }
        f.each_set(Stage::Composite, |e, s| {
            stages.composite.add_pass(&ctx, e, s, maps, ts)
        });
        let (mut enc, ran) = (f.enc, f.ran);
        let readback = Readback::record(&ctx, &mut enc, world, sets, ts);
        ctx.submit(enc);
        let bytes = readback.map(&ctx)?;
        let frame_ms = started.elapsed().as_secs_f64() * 1e3;
        self.finish_frame(targets, bytes, &ran, frame_ms, frame.particle_count)
    }

    /// Groups the targets by view size into viewer sets (dropping sets no target uses),
    /// lays each set out and writes every set's and the world's viewer uniforms.
    fn prepare_sets(&mut self, targets: &[FrameTarget], frame: FrameGpu) -> anyhow::Result<()> {
        let mut by_size: BTreeMap<(u32, u32), Vec<(usize, &FrameTarget)>> = BTreeMap::new();
        for (i, t) in targets.iter().enumerate() {
            by_size
                .entry((t.view_width, t.view_height))
                .or_default()
                .push((i, t));
        }
        self.sets.retain(|size, _| by_size.contains_key(size));
        let w = &mut self.world;
        let clip = (w.scene.render.near_m, w.scene.render.far_m);
        let mut first_view = 0;
        for (size, members) in &by_size {
            let set = match self.sets.entry(*size) {
                Entry::Occupied(e) => e.into_mut(),
                Entry::Vacant(e) => e.insert(ViewerSet::new(&w.ctx, &w.gpu, &w.settings, members)?),
            };
            set.prepare(&w.ctx, &w.gpu, &w.settings, members, clip, frame)?;
            set.first_view = first_view;
            first_view += set.vol.count;
        }
        let views: Vec<ViewGpu> = self
            .sets
            .values()
            .flat_map(|s| s.gpu_views.iter().copied())
            .collect();
        let rasters: Vec<_> = self
            .sets
            .values()
            .flat_map(|s| s.raster_views.iter().copied())
            .collect();
        self.stages.gbuffer.upload(
            &w.ctx,
            &w.gpu,
            &rasters,
            (
                w.settings.triangle_cull,
                w.settings.occlusion_cull,
                w.settings.micro_raster,
            ),
        );
        w.write_views(frame, &views)
    }

    /// Splits the readback into the targets' images and the frame's stats; hands every
    /// set its history for the next frame.
    fn finish_frame(
        &mut self,
        targets: &[FrameTarget],
        bytes: ReadbackBytes,
        ran: &[Stage],
        frame_ms: f64,
        particles: u32,
    ) -> anyhow::Result<TargetsOutput> {
        self.world.weigh_froxel_requests(&bytes.counters);
        let world = &self.world;
        let mut images = vec![Vec::new(); targets.len()];
        for (set, output) in self.sets.values().zip(&bytes.outputs) {
            for t in &set.targets {
                let at = (t.first_pixel * 4) as usize;
                let mut image = output[at..at + (t.pixels * 4) as usize].to_vec();
                targets[t.target].fill_uncovered(&mut image);
                images[t.target] = image;
            }
        }
        let stage_ms = self
            .timestamps
            .stage_ms(&bytes.ticks, world.ctx.timestamp_period_ns);
        let dispatches = dispatches(ran, world, &self.sets, particles);
        let stats = stats::build(stats::StatsInput {
            world,
            counters: &bytes.counters,
            sets: self.sets.values().map(|s| &s.vol).collect(),
            stage_ms,
            frame_ms,
            dispatches,
            triangle_list_bytes: self.stages.gbuffer.list_bytes(),
            raster_triangles: self
                .stages
                .gbuffer
                .raster_triangles(u64::from(bytes.counters[C_RASTER_TRIANGLES])),
        });
        let froxels_written = world.has_media();
        for set in self.sets.values_mut() {
            set.finish(&world.settings, froxels_written);
        }
        self.world.frame_index = self.world.frame_index.wrapping_add(1);
        self.world.grow_layer()?;
        Ok(TargetsOutput { images, stats })
    }
}

/// Records the frame's stages into one encoder, noting which ran.
struct FrameRecorder<'a> {
    enc: wgpu::CommandEncoder,
    sets: &'a BTreeMap<(u32, u32), ViewerSet>,
    ran: Vec<Stage>,
}

impl<'a> FrameRecorder<'a> {
    fn new(ctx: &GpuContext, sets: &'a BTreeMap<(u32, u32), ViewerSet>) -> Self {
        let enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        FrameRecorder {
            enc,
            sets,
            ran: Vec::new(),
        }
    }

    /// Records a world stage once (`record` returns whether it had work).
    fn world(
        &mut self,
        stage: Stage,
        record: impl FnOnce(&mut wgpu::CommandEncoder, &[&ViewerSet]) -> bool,
    ) {
        let sets: Vec<&ViewerSet> = self.sets.values().collect();
        if record(&mut self.enc, &sets) {
            self.ran.push(stage);
        }
    }

    /// Records a per-viewer stage for every viewer set.
    fn each_set(
        &mut self,
        stage: Stage,
        mut record: impl FnMut(&mut wgpu::CommandEncoder, &ViewerSet),
    ) {
        for set in self.sets.values() {
            record(&mut self.enc, set);
        }
        self.ran.push(stage);
    }
}

/// Workgroups of every stage that ran: world stages once, viewer stages per set (what
/// stats report; the G-buffer and the smoke raster are raster work and have none).
fn dispatches(
    ran: &[Stage],
    world: &World,
    sets: &BTreeMap<(u32, u32), ViewerSet>,
    particles: u32,
) -> Vec<(&'static str, [u32; 3])> {
    let mut out = Vec::new();
    for &stage in ran {
        let per_set = |f: fn(&viewer_volumes::Workgroups) -> [u32; 3]| {
            sets.values().map(move |s| f(&s.vol.groups))
        };
        let groups: Vec<[u32; 3]> = match stage {
            Stage::GBuffer | Stage::SmokeRaster => Vec::new(),
            Stage::ShadowMaps => vec![[0, 0, 0]],
            Stage::SmokeParticles => world.smoke.iter().map(|s| s.workgroups()).collect(),
            Stage::MediaLayer => world
                .layer
                .iter()
                .flat_map(|l| [l.mark_workgroups(), l.fill_workgroups()])
                .collect(),
            Stage::MediaTransmittance => vec![world.transmittance.workgroups()],
            Stage::SmokeShadows => vec![world.smoke_shadows.workgroups()],
            Stage::AmbientGrid => world
                .ambient
                .iter()
                .flat_map(|a| a.recorded().iter().copied())
                .collect(),
            Stage::SharedGrid => world.grid.iter().map(|g| g.workgroups()).collect(),
            Stage::GridRequests | Stage::FroxelLighting => per_set(|g| g.columns).collect(),
            Stage::VolumeIntegration => per_set(|g| g.integration).collect(),
            Stage::ShadowFrustum => per_set(|g| g.frustum).collect(),
            Stage::SmokeProxies => sets
                .values()
                .filter_map(|s| s.vol.smoke.as_ref().map(|b| b.workgroups(particles)))
                .collect(),
            Stage::Composite => per_set(|g| g.pixels).collect(),
        };
        out.extend(groups.into_iter().map(|g| (stage.name(), g)));
    }
    out
}

/// Fills each column of stacked froxel volumes (`columns` columns of `slices` slices a
/// view, slice-major) past its last integrated slice with that slice's value: view `i`'s
/// column `c` ends at `limits[limit_views[i]·columns + c]`.
fn continue_past_limits(
    volume: &mut [[f32; 4]],
    limits: &[u32],
    limit_views: &[usize],
    columns: usize,
    slices: usize,
) {
    for (block, &limit_view) in volume.chunks_exact_mut(columns * slices).zip(limit_views) {
        for c in 0..columns {
            let Some(&limit) = limits.get(limit_view * columns + c) else {
                return;
            };
            let last = (limit as usize).min(slices - 1);
            let value = block[c + columns * last];
            for s in last + 1..slices {
                block[c + columns * s] = value;
            }
        }
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
    use super::{continue_past_limits, f16_to_f32};

    #[test]
    fn columns_continue_past_their_limits() {
        // 2 views of 2 columns × 3 slices, slice-major within a view: (limits, the view
        // whose limits each view takes, the volume's red channel after).
        let cases: [([u32; 4], [usize; 2], [f32; 12]); 2] = [
            // View 0 integrated columns 0 and 1 up to slices 0 and 2, view 1 up to 1
            // and 0.
            (
                [0, 2, 1, 0],
                [0, 1],
                [0.0, 1.0, 0.0, 3.0, 0.0, 5.0, 6.0, 7.0, 8.0, 7.0, 8.0, 7.0],
            ),
            // View 1 takes view 0's limits (a coupled eye without a near field).
            (
                [0, 2, 9, 9],
                [0, 0],
                [0.0, 1.0, 0.0, 3.0, 0.0, 5.0, 6.0, 7.0, 6.0, 9.0, 6.0, 11.0],
            ),
        ];
        for (limits, limit_views, want) in cases {
            let mut volume: Vec<[f32; 4]> = (0..12).map(|i| [i as f32, 0.0, 0.0, 1.0]).collect();
            continue_past_limits(&mut volume, &limits, &limit_views, 2, 3);
            let red: Vec<f32> = volume.iter().map(|x| x[0]).collect();
            assert_eq!(
                red, want,
                "limits {limits:?}, taken from views {limit_views:?}"
            );
        }
    }

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
