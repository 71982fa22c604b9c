//! The world: everything that does not depend on an eye, on the GPU once for every
//! viewer of every size — the scene (BVH, raster meshes, movers), the shared shadow grid,
//! the shared shadow maps, the media's transmittance toward the lights — and what
//! changed since the last frame (lights, movers). Its stages run once per frame, before
//! any viewer set reads them.

use super::ambient_grid::{self, AmbientGrid};
use super::gpu_types::*;
use super::media_layer::{self, MediaLayer};
use super::media_transmittance::{self, MediaTransmittance};
use super::scene_gpu::{SceneGpu, SharedMedia};
use super::shadow_maps::ShadowMaps;
use super::shared_grid::{GridUpdate, SharedShadowGrid};
use super::smoke_particles::SmokeParticles;
use super::smoke_shadows::{self, SmokeShadows};
use super::{Mode, Settings, Timestamps};
use crate::gpu::GpuContext;
use crate::scene::{Bvh, Scene};
use glam::Vec3;
use std::sync::Arc;

/// `froxel_requests`: froxels with media per ray made in place that the request pass
/// costs as much as. Measured on lavapipe (colonnade, one viewer walking its path at
/// 30 fps): the request pass over ~N froxels took as long as N / 64 rays made in place
/// and traced again by the next grid pass (docs/decisions.md).
const IN_PLACE_RAY_FROXELS: u64 = 64;

/// How a froxel beyond the shadow frustum finds whether each light reaches it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lookup {
    /// A shadow ray per froxel and light (`reference`).
    Rays,
    /// The shared grid's nearest voxel.
    GridNearest,
    /// The shared grid's 8 neighbouring voxels, trilinearly (paper 000 §3.1.3).
    GridTrilinear,
    /// The shared shadow maps, every froxel (`maps`).
    Maps,
}

impl Lookup {
    /// The lookup `settings` ask for.
    pub fn of(settings: &Settings) -> Lookup {
        match (settings.mode, settings.trilinear) {
            (Mode::Reference, _) => Lookup::Rays,
            (Mode::Shared, false) => Lookup::GridNearest,
            (Mode::Shared, true) => Lookup::GridTrilinear,
            (Mode::Maps, _) => Lookup::Maps,
        }
    }

    fn flags(self) -> u32 {
        match self {
            Lookup::Rays => 0,
            Lookup::GridNearest => FLAG_SHARED,
            Lookup::GridTrilinear => FLAG_SHARED | FLAG_TRILINEAR,
            Lookup::Maps => FLAG_MAPS,
        }
    }
}

/// The scene and every view-independent structure, one per server or tool run.
pub struct World {
    pub(crate) ctx: Arc<GpuContext>,
    pub(crate) scene: Arc<Scene>,
    pub(crate) settings: Settings,
    pub(crate) gpu: SceneGpu,
    pub(crate) grid: Option<SharedShadowGrid>,
    pub(crate) shadow_maps: ShadowMaps,
    pub(crate) transmittance: MediaTransmittance,
    /// The world media layer (`shared` with costly media; media_layer.rs).
    pub(crate) layer: Option<MediaLayer>,
    /// The smoke particles' simulation pass (scenes with emitters).
    pub(crate) smoke: Option<SmokeParticles>,
    /// Smoke particles alive this frame (`Frame.particle_count`).
    pub(crate) particle_count: u32,
    /// The smoke's adaptive volumetric shadow maps (smoke_shadows.rs).
    pub(crate) smoke_shadows: SmokeShadows,
    /// The shared ambient grid (`sh_ambient_m` > 0; ambient_grid.rs).
    pub(crate) ambient: Option<AmbientGrid>,
    /// The lights as last uploaded (animated lights move; a change marks the light dirty).
    lights_uploaded: Option<Vec<LightGpu>>,
    /// Scene time of the movers as last uploaded.
    movers_time: Option<f32>,
    /// `froxel_requests`: whether the grid pass has run (then froxels can request what
    /// it has not filled), and whether a light changed since (then a filled voxel's
    /// light bits may be stale, and the request pass runs from then on).
    grid_filled: bool,
    grid_changed: bool,
    /// `froxel_requests`: whether this frame's froxels request the voxels (no request
    /// pass), whether this frame filled the grid first, and whether the next frame may
    /// skip the request pass (`weigh_froxel_requests`).
    pub(crate) froxel_requests_now: bool,
    grid_first_fill: bool,
    froxel_requests_pay: bool,
    pub(crate) frame_index: u32,
    pub(crate) triangles: usize,
}

impl World {
    /// Uploads `scene` (with its BVH built before) and allocates the shared structures
    /// `settings` ask for.
    pub fn new(
        ctx: Arc<GpuContext>,
        scene: Arc<Scene>,
        bvh: &Bvh,
        settings: Settings,
    ) -> anyhow::Result<World> {
        settings.validate()?;
        let shared = settings.mode == Mode::Shared;
        // `maps` shares the maps and the transmittance volumes, not the grid.
        let light_space = settings.shares_light_space();
        let light_media = media_transmittance::plan(
            &scene,
            if light_space {
                settings.transmittance_voxel_m
            } else {
                0.0
            },
        );
        let layer_plan = if shared {
            media_layer::plan(&scene, settings.media_voxel_m)
        } else {
            None
        };
        let ambient_plan = ambient_grid::plan(&scene, settings.sh_ambient_m);
        let shadow_maps = ShadowMaps::new(
            &ctx,
            &scene,
            if light_space {
                settings.shadow_map_px
            } else {
                0
            },
        );
        // With `froxel_maps` and a map for every light, no froxel reads a grid.
        let grid_needed = shared
            && !scene.lights.is_empty()
            && !(settings.froxels_read_maps() && shadow_maps.maps_every_light());
        let grid_bounds = scene.media_bounds().filter(|_| grid_needed);
        let grid_media = grid_bounds
            .filter(|_| settings.density_in_grid())
            .and_then(|_| {
                media_layer::grid_media(&scene, settings.voxel_size_m, settings.grid_media_fine)
            });
        let gpu = SceneGpu::new(
            &ctx,
            &scene,
            bvh,
            &light_media,
            SharedMedia {
                layer: layer_plan.as_ref(),
                in_grid: grid_media.as_ref().map(|g| g.in_grid.as_slice()),
            },
            smoke_shadows::node_count(&scene, &settings),
            ambient_plan.as_ref(),
        )?;
        let grid = match grid_bounds {
            Some(bounds) => Some(SharedShadowGrid::new(
                &ctx,
                &gpu.layout,
                bounds,
                settings.voxel_size_m,
                GridUpdate::of(&settings),
                grid_media,
            )?),
            None => None,
        };
        Ok(World {
            shadow_maps,
            transmittance: MediaTransmittance::new(&ctx, &gpu.layout, &scene, &light_media),
            layer: layer_plan.map(|p| MediaLayer::new(&ctx, &gpu.layout, p)),
            smoke: SmokeParticles::new(&ctx, &scene, &gpu.particles),
            particle_count: 0,
            smoke_shadows: SmokeShadows::new(&ctx, &gpu.layout, &scene, &settings),
            ambient: ambient_plan.map(|p| AmbientGrid::new(&ctx, &gpu.layout, p)),
            triangles: bvh.triangle_count()
                + scene.movers.iter().map(|m| m.mesh.len()).sum::<usize>(),
            gpu,
            grid,
            lights_uploaded: None,
            movers_time: None,
            grid_filled: false,
            grid_changed: false,
            froxel_requests_now: false,
            grid_first_fill: false,
            froxel_requests_pay: true,
            frame_index: 0,
            ctx,
            scene,
            settings,
        })
    }

    /// Forgets what changed since which frame, so that the next frame treats every
    /// light as changed: the grid re-traces its cached bits, the shadow maps and the
    /// transmittance volumes are rendered again. For after a frame that failed half-way
    /// (its change tracking may have moved on without its work reaching the GPU).
    pub(crate) fn invalidate(&mut self) {
        self.lights_uploaded = None;
        self.movers_time = None;
        self.shadow_maps.invalidate();
        self.transmittance.invalidate();
        self.smoke_shadows.invalidate();
        if let Some(a) = &mut self.ambient {
            a.invalidate();
        }
        if let Some(l) = &mut self.layer {
            l.invalidate();
        }
    }

    /// `froxel_requests`, after a frame: whether the next may leave the requests to the
    /// froxels. They make the voxels the grid lacks in place (each voxel by every froxel
    /// that reads it, and traced once more by the next grid pass), while the request
    /// pass costs a pass over every froxel with media. The next frame's unfilled voxels
    /// are guessed from this frame's: the rays the froxels made in place, or after a
    /// request pass the grid pass's rays (an upper bound: it counts the voxels movers
    /// made stale too, which are traced either way). The request pass runs while those
    /// rays exceed one per `IN_PLACE_RAY_FROXELS` froxels with media, so a camera that
    /// moves into unseen space gets the request pass and still ones do not. The frame
    /// that first fills the grid is no guide (every voxel is new then).
    pub(crate) fn weigh_froxel_requests(&mut self, counters: &[u32]) {
        let rays = if self.froxel_requests_now {
            counters[C_LIGHTING_RAYS]
        } else {
            counters[C_GRID_RAYS]
        };
        self.froxel_requests_pay = self.grid_first_fill
            || u64::from(rays) * IN_PLACE_RAY_FROXELS <= u64::from(counters[C_FROXELS_WITH_MEDIA]);
    }

    /// Whether the scene has media (else no froxel stage runs).
    pub(crate) fn has_media(&self) -> bool {
        !self.scene.media.is_empty()
    }

    /// Whether `shared`'s froxels read every light from the shadow maps (`froxel_maps`,
    /// each light has a map, the scene has media): then no grid exists.
    pub(crate) fn froxels_from_maps(&self) -> bool {
        self.settings.froxels_read_maps()
            && self.has_media()
            && !self.scene.lights.is_empty()
            && self.shadow_maps.maps_every_light()
    }

    /// Whether the frames cull hidden froxels (`FLAG_CULL`): only where the culling passes
    /// run, so where a grid exists or the maps light every froxel (media and lights).
    pub(crate) fn culls_hidden_froxels(&self) -> bool {
        self.settings.culls_hidden_froxels() && (self.grid.is_some() || self.froxels_from_maps())
    }

    /// The shared grid, when froxels read it this frame (media and lights in `shared`).
    pub(crate) fn grid(&self) -> Option<&SharedShadowGrid> {
        self.grid.as_ref().filter(|_| self.has_media())
    }

    /// Uploads what changed by scene time `time_s` — animated lights (marking those that
    /// moved), the movers' tree and the bounds they swept — and returns the frame's
    /// uniforms (without viewers).
    pub(crate) fn begin_frame(&mut self, time_s: f32) -> anyhow::Result<FrameGpu> {
        let scene = &self.scene;
        let s = &self.settings;
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
            self.gpu.write_lights(&self.ctx, &lights);
        }
        self.lights_uploaded = Some(lights);
        let transmittance_dirty = self.transmittance.dirty(dirty_lights);
        // Movers: their tree and vertices at this time, and the bounds they swept since
        // the last frame (what cached grid bits must be re-checked against).
        let mover_root = self.gpu.write_movers(&self.ctx, scene, time_s)?;
        let mut moved = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        if let Some(prev) = self.movers_time.filter(|p| *p != time_s) {
            for m in &scene.movers {
                for (lo, hi) in [m.bounds_at(prev), m.bounds_at(time_s)] {
                    moved = (moved.0.min(lo), moved.1.max(hi));
                }
            }
        }
        self.movers_time = Some(time_s);
        let particle_count = self
            .smoke
            .as_mut()
            .map_or(0, |sm| sm.prepare(&self.ctx, scene, time_s));
        self.particle_count = particle_count;
        // The shadow maps are fitted to the particles (and keyed by them for the cache)
        // on the host: the CPU twin of the pass above, the same particles in f64.
        let particles = super::smoke_particles::cpu_particles(scene, time_s);
        self.smoke_shadows.prepare(
            &self.ctx,
            &self.gpu,
            &particles[..(particle_count as usize).min(particles.len())],
            self.lights_uploaded.as_deref().unwrap_or_default(),
            dirty_lights,
        );
        let mut flags = Lookup::of(s).flags();
        if s.parity {
            flags |= FLAG_PARITY;
        }
        if self.has_media() {
            flags |= FLAG_MEDIA;
        }
        if let Some(g) = &self.grid {
            flags |= g.update().flags();
            if let Some(m) = &g.media {
                flags |= FLAG_GRID_MEDIA;
                if m.animated {
                    flags |= FLAG_GRID_MEDIA_MOVES;
                }
                if m.fine {
                    flags |= FLAG_GRID_MEDIA_FINE;
                }
            }
        }
        // `froxel_requests`: a filled voxel (density code ≠ 0) has current light bits
        // while no light changed since the grid first ran (every voxel is traced in the
        // frame it is first requested, and with the flag the grid pass traces a filled
        // voxel again when a mover makes its bits stale). From the first frame in which
        // a light changes on, every filled voxel may be stale: the request pass. The
        // request pass runs too while the froxels would make more voxels in place than
        // it costs (`weigh_froxel_requests`: cameras that move into unseen space).
        self.froxel_requests_now = false;
        self.grid_first_fill = false;
        if let Some(g) = self.grid.as_ref().filter(|_| !scene.media.is_empty()) {
            self.grid_changed |= self.grid_filled && dirty_lights != 0;
            // (`requests_from_froxels` implies a cached grid with the density in it.)
            self.froxel_requests_now = s.requests_from_froxels()
                && g.media.as_ref().is_some_and(|m| !m.animated)
                && self.grid_filled
                && !self.grid_changed
                && self.froxel_requests_pay;
            if self.froxel_requests_now {
                flags |= FLAG_FROXEL_REQUESTS;
            }
            self.grid_first_fill = !self.grid_filled;
            self.grid_filled = true;
        }
        if self.transmittance.in_use() {
            flags |= FLAG_MEDIA_T;
        }
        let layer = self
            .layer
            .as_mut()
            .map(|l| (l.next_stamp(), l.plan().clone()));
        if let Some((_, p)) = &layer {
            flags |= FLAG_LAYER;
            if p.full {
                flags |= FLAG_LAYER_FULL;
            }
        }
        let ambient = self.ambient.as_ref().map(|a| *a.plan());
        if ambient.is_some() {
            flags |= FLAG_SH_AMBIENT;
        }
        if s.froxels_read_maps() {
            flags |= FLAG_FROXEL_MAPS;
        }
        if s.edges_from_maps() {
            flags |= FLAG_MAP_EDGES;
        }
        if self.culls_hidden_froxels() {
            flags |= FLAG_CULL;
        }
        let (lo, hi) = scene.bounds;
        let g = self.grid.as_ref();
        let gm = g.and_then(|g| g.media.as_ref());
        Ok(FrameGpu {
            grid_min: g.map_or([0.0; 3], |g| g.min.to_array()),
            voxel_size: g.map_or(1.0, |g| g.voxel_size_m),
            grid_dims: g.map_or([1; 3], |g| g.dims.to_array()),
            light_count: scene.lights.len() as u32,
            sky: scene.render.sky,
            medium_count: scene.media.len() as u32,
            ambient: scene.render.ambient,
            exposure: scene.render.exposure,
            view_count: 0,
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
            layer_min: layer.as_ref().map_or([0.0; 3], |(_, p)| p.min.to_array()),
            layer_voxel: layer.as_ref().map_or(1.0, |(_, p)| p.voxel_m),
            layer_bricks: layer.as_ref().map_or([1; 3], |(_, p)| p.bricks.to_array()),
            layer_capacity: layer.as_ref().map_or(0, |(_, p)| p.capacity),
            layer_stamp: layer.as_ref().map_or(0, |(s, _)| *s),
            layer_first: layer.as_ref().map_or(0, |(_, p)| p.first),
            layer_node_words: layer.as_ref().map_or(1, |(_, p)| p.node_words()),
            particle_count,
            sh_min: ambient.map_or([0.0; 3], |a| a.min.to_array()),
            sh_cell: ambient.map_or(1.0, |a| a.cell),
            sh_dims: ambient.map_or([1; 3], |a| a.dims.to_array()),
            sh_probes: ambient.map_or(0, |a| a.probes()),
            grid_media_min: gm.map_or([0.0; 3], |m| m.min.to_array()),
            grid_media_unit: gm.map_or(0.0, |m| m.unit),
            grid_media_max: gm.map_or([-1.0; 3], |m| m.max.to_array()),
            grid_media_first: gm.map_or(0, |m| m.first),
        })
    }

    /// Writes the world's own uniforms: `frame` with every viewer of every set (the
    /// frustum-gated grid update tests voxels against all of them).
    pub(crate) fn write_views(&mut self, frame: FrameGpu, views: &[ViewGpu]) -> anyhow::Result<()> {
        self.gpu.ensure_views(&self.ctx, views.len())?;
        let frame = FrameGpu {
            view_count: views.len() as u32,
            ..frame
        };
        let q = &self.ctx.queue;
        q.write_buffer(&self.gpu.frame, 0, bytemuck::bytes_of(&frame));
        q.write_buffer(&self.gpu.views, 0, bytemuck::cast_slice(views));
        Ok(())
    }

    /// Records the shared shadow maps (when a light turned or a mover moved).
    pub(crate) fn add_shadow_maps(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        time_s: f32,
        ts: &Timestamps,
    ) -> bool {
        let (ctx, scene, gpu) = (&self.ctx, &self.scene, &self.gpu);
        self.shadow_maps
            .add_passes(ctx, enc, scene, gpu, time_s, ts)
    }

    /// Records the smoke particles' placement (when any is alive).
    pub(crate) fn add_smoke_particles(
        &self,
        enc: &mut wgpu::CommandEncoder,
        ts: &Timestamps,
    ) -> bool {
        self.smoke.as_ref().is_some_and(|s| s.add_pass(enc, ts))
    }

    /// Reads the last frame's smoke particles back (for tests and tools; the CPU twin is
    /// [`super::cpu_particles`]).
    pub fn read_particles(&self) -> anyhow::Result<Vec<ParticleGpu>> {
        let bytes = self.ctx.read_buffer(&self.gpu.particles)?;
        let all: &[ParticleGpu] = bytemuck::cast_slice(&bytes);
        let n = self.particle_count.min(self.gpu.particle_capacity) as usize;
        Ok(all[..n].to_vec())
    }

    /// Records the world media layer's mark and fill (every frame it exists: new views
    /// may need new bricks; moving media refill what is seen).
    pub(crate) fn add_media_layer(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        ts: &Timestamps,
    ) -> bool {
        let (gpu, layer) = (&self.gpu, &mut self.layer);
        layer
            .as_mut()
            .is_some_and(|l| l.add_passes(enc, &gpu.bind_group, &gpu.layer, ts))
    }

    /// Grows the media layer's pool when the last frame's bricks did not fit (the next
    /// frame refills it; every bind group of the scene is made again).
    pub(crate) fn grow_layer(&mut self) -> anyhow::Result<()> {
        let Some(plan) = self.layer.as_ref().and_then(MediaLayer::grown) else {
            return Ok(());
        };
        tracing::debug!(
            bricks = plan.capacity,
            mib = plan.pool_bytes() as f64 / 1048576.0,
            "media layer pool grows"
        );
        self.gpu.resize_layer(&self.ctx, &plan)?;
        if let Some(l) = &mut self.layer {
            l.regrow(plan);
        }
        Ok(())
    }

    /// Records the smoke's shadow maps (when the particles or a light changed).
    pub(crate) fn add_smoke_shadows(
        &self,
        enc: &mut wgpu::CommandEncoder,
        ts: &Timestamps,
    ) -> bool {
        self.smoke_shadows.add_pass(enc, &self.gpu.bind_group, ts)
    }

    /// Records the media transmittance toward the lights whose volume is stale.
    pub(crate) fn add_transmittance(
        &self,
        enc: &mut wgpu::CommandEncoder,
        frame: &FrameGpu,
        ts: &Timestamps,
    ) -> bool {
        self.transmittance
            .add_pass(enc, &self.gpu.bind_group, frame.transmittance_dirty, ts)
    }

    /// Records the shared ambient grid's passes (every frame it exists: it accumulates).
    pub(crate) fn add_ambient(&mut self, enc: &mut wgpu::CommandEncoder, ts: &Timestamps) -> bool {
        let (ctx, gpu, frame_index) = (&self.ctx, &self.gpu, self.frame_index);
        self.ambient
            .as_mut()
            .is_some_and(|a| a.add_passes(ctx, enc, &gpu.bind_group, frame_index, ts))
    }
}
