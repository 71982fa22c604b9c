//! The world media layer, with `shaders/media_layer.wgsl`: the media filled once per
//! frame into sparse bricks for every viewer (paper 004's metavoxels), so that a froxel,
//! a surface or a transmittance column reads σs, σt, emission and g with one trilinear
//! lookup instead of evaluating noise (`media_at` in common.wgsl).
//!
//! The layer spans the bounds of the media it holds in bricks of 8³ voxels; a brick is
//! filled only where some medium of the layer covers it *and* some viewer's frustum
//! reaches it (004's eye culling, over the union of every viewer of every size), into a
//! pool sized for the bricks the media can cover. Static media are filled once: a brick
//! keeps its slot while new views add bricks. Moving media (wind in the noise, a volume
//! on a path) empty the table every frame and refill what is seen.
//!
//! Which media go in: those that cost to evaluate (height fog, noise, `[[volume]]`s) and
//! are at least [`MIN_VOXELS_ACROSS`] voxels across. Homogeneous boxes and spheres are
//! exact and cheap analytically, and a medium smaller than a few voxels would be smeared
//! by the trilinear read (a 1 mm puff in a 0.25 m voxel), so those stay analytic.
//!
//! Where the layer has no brick (pool full, a point outside every frustum) readers
//! evaluate the layer's media analytically: the layer changes the cost, never the
//! result beyond its interpolation. Bricks that lie only between a light and a seen
//! region are not filled: the transmittance columns cross such a brick with a few
//! analytic samples, fewer than filling its 729 nodes (docs/decisions.md).

use super::{dispatch, Stage, Timestamps};
use crate::gpu::GpuContext;
use crate::scene::{MediumKind, Scene};
use glam::{UVec3, Vec3};
use std::cell::Cell;

/// Nodes per brick (9³: the corners of its 8³ voxels).
pub(crate) const BRICK_NODES: u64 = 729;
/// A medium smaller than this many voxels across stays analytic.
const MIN_VOXELS_ACROSS: f32 = 4.0;
/// A medium denser than this optical depth across one voxel stays analytic: trilinear
/// density across a near-opaque edge moves the edge (a σt 10⁴ m⁻¹ cloud is opaque in a
/// tenth of a millimetre; the layer would blur it over a voxel).
const MAX_TAU_PER_VOXEL: f32 = 2.0;
/// Most voxels along an axis, and most bricks in the table: past them the voxel grows.
const MAX_VOXELS_PER_AXIS: f32 = 1024.0;
const MAX_TABLE_BRICKS: u64 = 1 << 18;
/// Most bytes of the pool (past it, bricks beyond the pool are evaluated where read).
const MAX_POOL_BYTES: u64 = 128 << 20;
/// Pool slots at first (the pool grows to what the viewers see).
const FIRST_POOL_BRICKS: u32 = 64;

/// Where the layer lies, how fine it is and which media it holds.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LayerPlan {
    pub min: Vec3,
    pub voxel_m: f32,
    /// Bricks a side.
    pub bricks: UVec3,
    /// Pool slots now: it starts at [`FIRST_POOL_BRICKS`] and doubles while the bricks
    /// seen do not fit, up to `max_capacity`.
    pub capacity: u32,
    /// The bricks the layer's media can cover (over their whole paths), up to
    /// `MAX_POOL_BYTES`.
    pub max_capacity: u32,
    /// Per scene medium: read from the layer.
    pub in_layer: Vec<bool>,
    /// The first medium in the layer (whose coefficients all share unless `full`).
    pub first: u32,
    /// Nodes store σs, σt, emission and g (the layer's media differ in their
    /// coefficients); else one f32 density per node.
    pub full: bool,
    /// Whether a medium in the layer moves (then the layer is refilled every frame).
    pub animated: bool,
}

impl LayerPlan {
    /// Bricks in the table.
    pub(crate) fn table_bricks(&self) -> u64 {
        self.bricks.as_u64vec3().element_product()
    }

    /// Bytes of table, slots and pool.
    pub(crate) fn bytes(&self) -> u64 {
        self.table_bricks() * 4 + (1 + 2 * self.capacity as u64) * 4 + self.pool_bytes()
    }

    pub(crate) fn pool_bytes(&self) -> u64 {
        self.capacity as u64 * self.brick_bytes()
    }

    /// u32 words per node: one f32 density, or σs, σt, emission and g as 4 × 2 f16.
    pub(crate) fn node_words(&self) -> u32 {
        if self.full {
            4
        } else {
            1
        }
    }

    /// Bytes of one brick in the pool.
    pub(crate) fn brick_bytes(&self) -> u64 {
        BRICK_NODES * 4 * u64::from(self.node_words())
    }

    /// Bytes of a dense grid of the same nodes over the layer's whole extent (what the
    /// bricks replace).
    pub(crate) fn dense_bytes(&self) -> u64 {
        (self.bricks * 8 + 1).as_u64vec3().element_product() * 4 * u64::from(self.node_words())
    }
}

/// Whether medium `m` costs enough to evaluate to be worth the layer.
fn costly(m: &crate::scene::Medium) -> bool {
    m.kind == MediumKind::Height || m.kind == MediumKind::Volume || m.noise.frequency > 0.0
}

/// Its smallest extent, metres (a volume: its diameter).
fn smallest_extent(m: &crate::scene::Medium) -> f32 {
    match m.volume {
        Some(v) => 2.0 * v.radius_m,
        None => (m.max - m.min).min_element(),
    }
}

/// Its largest extinction, m⁻¹ (noise scales density by at most 1 + amplitude).
fn largest_extinction(m: &crate::scene::Medium) -> f32 {
    let noise = if m.noise.frequency > 0.0 {
        1.0 + m.noise.amplitude
    } else {
        1.0
    };
    (m.scattering.element_sum() / 3.0 + m.absorption) * noise
}

/// Whether costly medium `m` is worth reading at voxels of `voxel_m`: a few voxels
/// across, and not so dense that a trilinear read across one voxel moves its edge.
fn fits_voxels(m: &crate::scene::Medium, voxel_m: f32) -> bool {
    costly(m)
        && smallest_extent(m) >= MIN_VOXELS_ACROSS * voxel_m
        && largest_extinction(m) * voxel_m <= MAX_TAU_PER_VOXEL
}

/// Whether voxels of `voxel_m` resolve medium `m`'s detail with two voxels or more: the
/// finest octave's lattice of its density noise, of a volume's surface displacement
/// (over its radius), a height fog's falloff length. (Coarser voxels smooth the noise
/// away: 0.5 m voxels over a 0.5 m lattice put a 3-octave fog 0.0075 mean FLIP away from
/// evaluating it, `extinction_1e4_between_the_sun_and_the_fog`.)
fn resolves_detail(m: &crate::scene::Medium, voxel_m: f32) -> bool {
    let finest = |frequency: f32, octaves: u32| {
        1.0 / (frequency * (1u32 << octaves.saturating_sub(1).min(16)) as f32)
    };
    let mut scale = f32::INFINITY;
    if m.noise.frequency > 0.0 {
        scale = scale.min(finest(m.noise.frequency, m.noise.octaves));
    }
    if let Some(v) = m.volume.filter(|v| v.amplitude > 0.0 && v.frequency > 0.0) {
        scale = scale.min(v.radius_m * finest(v.frequency, v.octaves));
    }
    if m.kind == MediumKind::Height {
        scale = scale.min(m.radius_or_falloff);
    }
    voxel_m <= 0.5 * scale
}

/// Whether some medium of `ids` moves (wind in its noise, a volume on a path).
fn moves(scene: &Scene, ids: &[usize]) -> bool {
    ids.iter().any(|&i| {
        let m = &scene.media[i];
        (m.noise.frequency > 0.0 && Vec3::from(m.noise.wind) != Vec3::ZERO)
            || m.volume.is_some_and(|v| v.velocity != Vec3::ZERO)
    })
}

/// Whether media `ids` share σs, σa, g and emission (then one density describes them).
fn same_coefficients(scene: &Scene, ids: &[usize]) -> bool {
    let key = |i: usize| {
        let m = &scene.media[i];
        (m.scattering, m.absorption, m.g, m.emission)
    };
    ids.iter().all(|&i| key(i) == key(ids[0]))
}

/// The media whose density the shared grid carries (`grid_media`; shared_grid.wgsl
/// fills it, froxel_lighting.wgsl reads it): the costly media that fit the grid's voxels
/// (as the layer chooses), whose detail those voxels resolve, and that share their
/// coefficients, so that one 8-bit density per voxel, in units of `unit`, describes
/// them all.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GridMedia {
    /// Per scene medium: its density is in the grid.
    pub in_grid: Vec<bool>,
    /// The first of them (whose coefficients they all have).
    pub first: u32,
    /// The box that holds them (over their whole paths): froxels inside read the grid,
    /// and the fill evaluates the media at voxel centres clamped into it, so that a
    /// voxel beyond a face holds the density at the face (shared_grid.wgsl's
    /// `density_code`).
    pub min: Vec3,
    pub max: Vec3,
    /// Density of one step of the 8-bit code: the largest summed density / 254 (code
    /// 0 marks a voxel not filled yet, 1..=255 hold densities 0..=254 steps).
    pub unit: f32,
    /// Whether one of them moves: then every needed voxel is refilled every frame;
    /// static media fill each voxel once, the first frame it is needed.
    pub animated: bool,
    /// The density on cells of half a voxel (`grid_media_fine`): 8 per voxel.
    pub fine: bool,
}

/// [`GridMedia`] for `scene` on a grid of `voxel_m` voxels, or `None` when no medium
/// qualifies or the qualifying ones differ in their coefficients; `fine`: the density on
/// cells of half a voxel.
pub(crate) fn grid_media(scene: &Scene, voxel_m: f32, fine: bool) -> Option<GridMedia> {
    let in_grid: Vec<bool> = scene
        .media
        .iter()
        .map(|m| fits_voxels(m, voxel_m) && resolves_detail(m, voxel_m))
        .collect();
    let ids: Vec<usize> = (0..scene.media.len()).filter(|&i| in_grid[i]).collect();
    if ids.is_empty() || !same_coefficients(scene, &ids) {
        return None;
    }
    let (min, max) = ids.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &i| (lo.min(scene.media[i].min), hi.max(scene.media[i].max)),
    );
    // Height fog and volumes reach density 1, noise scales it by at most 1 + amplitude.
    let largest: f32 = ids
        .iter()
        .map(|&i| {
            let m = &scene.media[i];
            if m.noise.frequency > 0.0 {
                1.0 + m.noise.amplitude
            } else {
                1.0
            }
        })
        .sum();
    Some(GridMedia {
        first: ids[0] as u32,
        min,
        max,
        unit: largest / 254.0,
        animated: moves(scene, &ids),
        fine,
        in_grid,
    })
}

/// The layer for `scene` at voxels of `voxel_m` (0: no layer), or `None` when no
/// medium goes in it.
pub(crate) fn plan(scene: &Scene, voxel_m: f32) -> Option<LayerPlan> {
    if voxel_m <= 0.0 {
        return None;
    }
    let candidates: Vec<usize> = (0..scene.media.len())
        .filter(|&i| costly(&scene.media[i]))
        .collect();
    let bounds = |ids: &[usize]| {
        ids.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &i| (lo.min(scene.media[i].min), hi.max(scene.media[i].max)),
        )
    };
    let (lo, hi) = bounds(&candidates);
    if candidates.is_empty() || !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    // Coarser voxels for media kilometres wide.
    let extent = (hi - lo).max(Vec3::splat(1e-6));
    let mut voxel = voxel_m;
    let bricks_of = |v: f32| (extent / (8.0 * v)).ceil().as_uvec3().max(UVec3::ONE);
    while extent.max_element() / voxel > MAX_VOXELS_PER_AXIS
        || bricks_of(voxel).as_u64vec3().element_product() > MAX_TABLE_BRICKS
    {
        voxel *= 1.25;
    }
    let in_layer: Vec<bool> = (0..scene.media.len())
        .map(|i| candidates.contains(&i) && fits_voxels(&scene.media[i], voxel))
        .collect();
    let ids: Vec<usize> = (0..scene.media.len()).filter(|&i| in_layer[i]).collect();
    if ids.is_empty() {
        return None;
    }
    let (lo, hi) = bounds(&ids);
    let bricks = ((hi - lo).max(Vec3::splat(1e-6)) / (8.0 * voxel))
        .ceil()
        .as_uvec3()
        .max(UVec3::ONE);
    // Slots: every brick some medium's box (over its whole path) touches.
    let edge = 8.0 * voxel;
    let mut covered = 0u64;
    for z in 0..bricks.z {
        for y in 0..bricks.y {
            for x in 0..bricks.x {
                let b_lo = lo + UVec3::new(x, y, z).as_vec3() * edge;
                let b_hi = b_lo + Vec3::splat(edge);
                if ids.iter().any(|&i| {
                    let m = &scene.media[i];
                    b_lo.cmple(m.max).all() && b_hi.cmpge(m.min).all()
                }) {
                    covered += 1;
                }
            }
        }
    }
    let full = !same_coefficients(scene, &ids);
    let brick_bytes = BRICK_NODES * if full { 16 } else { 4 };
    let max_capacity = covered.min(MAX_POOL_BYTES / brick_bytes).max(1) as u32;
    let animated = moves(scene, &ids);
    Some(LayerPlan {
        min: lo,
        voxel_m: voxel,
        bricks,
        capacity: max_capacity.min(FIRST_POOL_BRICKS),
        max_capacity,
        in_layer,
        first: ids[0] as u32,
        full,
        animated,
    })
}

/// The layer's buffers (bindings 9–11 of the scene's group 0).
pub(crate) struct LayerBuffers {
    pub table: wgpu::Buffer,
    pub pool: wgpu::Buffer,
    pub slots: wgpu::Buffer,
}

impl LayerBuffers {
    /// Buffers for `plan` (16-byte stand-ins without a layer).
    pub(crate) fn new(ctx: &GpuContext, plan: Option<&LayerPlan>) -> anyhow::Result<Self> {
        let (table, pool, slots) = plan.map_or((16, 16, 16), |p| {
            (
                p.table_bricks() * 4,
                p.pool_bytes(),
                (1 + 2 * p.capacity as u64) * 4,
            )
        });
        Ok(LayerBuffers {
            table: ctx.storage("media layer table", table, wgpu::BufferUsages::empty())?,
            pool: ctx.storage("media layer pool", pool, wgpu::BufferUsages::empty())?,
            slots: ctx.storage("media layer slots", slots, wgpu::BufferUsages::empty())?,
        })
    }
}

/// The layer's passes and what they know of its freshness.
pub(crate) struct MediaLayer {
    plan: LayerPlan,
    mark: wgpu::ComputePipeline,
    fill: wgpu::ComputePipeline,
    /// The table and slots hold nothing valid (first frame, after a failed frame).
    stale: bool,
    /// Fill stamp of the frame being recorded (never 0: slots start at 0).
    stamp: u32,
    /// Bricks asked for since the table was last emptied (in the pool or not).
    requested: Cell<u64>,
}

impl MediaLayer {
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        plan: LayerPlan,
    ) -> Self {
        let module = super::stage_shader(
            ctx,
            "media_layer",
            include_str!("../../shaders/media_layer.wgsl"),
        );
        MediaLayer {
            mark: ctx.compute_pipeline_entry("media_layer mark", &module, &[scene_layout], "mark"),
            fill: ctx.compute_pipeline_entry("media_layer fill", &module, &[scene_layout], "fill"),
            plan,
            stale: true,
            stamp: 0,
            requested: Cell::new(0),
        }
    }

    pub(crate) fn plan(&self) -> &LayerPlan {
        &self.plan
    }

    /// Forgets the pool: the next frame refills every brick it needs.
    pub(crate) fn invalidate(&mut self) {
        self.stale = true;
    }

    /// The stamp of the frame about to be recorded (`Frame.layer_stamp`).
    pub(crate) fn next_stamp(&mut self) -> u32 {
        self.stamp = self.stamp.wrapping_add(1).max(1);
        self.stamp
    }

    pub(crate) fn mark_workgroups(&self) -> [u32; 3] {
        let groups = self.plan.table_bricks().div_ceil(64).max(1);
        let x = groups.min(32768);
        [x as u32, groups.div_ceil(x) as u32, 1]
    }

    pub(crate) fn fill_workgroups(&self) -> [u32; 3] {
        let slots = u64::from(self.plan.capacity);
        let x = slots.min(32768);
        [x as u32, slots.div_ceil(x) as u32, 1]
    }

    /// Records the frame's mark and fill (after emptying the table when the media move
    /// or nothing in it is valid).
    pub(crate) fn add_passes(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        buffers: &LayerBuffers,
        ts: &Timestamps,
    ) -> bool {
        if self.plan.animated || self.stale {
            enc.clear_buffer(&buffers.table, 0, None);
            enc.clear_buffer(&buffers.slots, 0, None);
            self.requested.set(0);
            self.stale = false;
        }
        let mark = self.mark_workgroups();
        dispatch(enc, ts, Stage::MediaLayer, &self.mark, &[scene], mark);
        dispatch(
            enc,
            ts,
            Stage::MediaLayer,
            &self.fill,
            &[scene],
            self.fill_workgroups(),
        );
        true
    }

    /// Bricks in the pool after a frame that asked for `requested` more of them.
    pub(crate) fn record_requested(&self, requested: u64) -> u64 {
        let n = self.requested.get() + requested;
        self.requested.set(n);
        n.min(u64::from(self.plan.capacity))
    }

    /// The plan with a pool that holds every brick asked for (doubled, up to the most
    /// the media can cover), when the last frame's did not fit.
    pub(crate) fn grown(&self) -> Option<LayerPlan> {
        let asked = self.requested.get();
        let p = &self.plan;
        if asked <= u64::from(p.capacity) || p.capacity >= p.max_capacity {
            return None;
        }
        let capacity = asked.next_power_of_two().min(u64::from(p.max_capacity)) as u32;
        Some(LayerPlan {
            capacity,
            ..p.clone()
        })
    }

    /// Takes the grown plan (its buffers were reallocated): the next frame starts over.
    pub(crate) fn regrow(&mut self, plan: LayerPlan) {
        self.plan = plan;
        self.stale = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layer_holds_costly_media_and_sizes_its_pool_by_their_cover() {
        let colonnade = Scene::load("colonnade").unwrap();
        let p = plan(&colonnade, 0.25).expect("noisy fog goes in the layer");
        assert!(p.in_layer.iter().all(|&b| b));
        assert_eq!(p.voxel_m, 0.25);
        let (lo, hi) = colonnade.media_bounds().unwrap();
        let span = p.bricks.as_vec3() * 8.0 * p.voxel_m;
        assert!((p.min - lo).abs().max_element() < 1e-6);
        assert!(span.cmpge(hi - lo).all(), "{span} covers {}", hi - lo);
        // One box of fog covers every brick of its own bounds; the pool starts small.
        assert_eq!(u64::from(p.max_capacity), p.table_bricks());
        assert!(p.capacity <= FIRST_POOL_BRICKS);
        assert!(p.bytes() < p.dense_bytes() * 2);
        assert!(plan(&colonnade, 0.0).is_none());
        // cloud: local volumes in an open courtyard: the pool is what they cover.
        let cloud = Scene::load("cloud").unwrap();
        let p = plan(&cloud, 0.25).expect("volumes go in the layer");
        assert!(u64::from(p.max_capacity) < p.table_bricks(), "{p:?}");
    }

    #[test]
    fn kilometre_media_get_coarser_voxels_and_tiny_ones_stay_analytic() {
        let text = |volume: &str| {
            format!(
                "name = \"v\"\n[camera]\npath = [[0.0, 1.0, 8.0], [1.0, 1.0, -8.0]]\n\
                 [[mesh]]\nkind = \"box\"\nmin = [-10.0, -0.5, -10.0]\nmax = [10.0, 0.0, 10.0]\n\
                 [[volume]]\n{volume}\n"
            )
        };
        let load = |t: &str| Scene::from_toml(t, std::path::Path::new("inline.toml")).unwrap();
        let huge = load(&text(
            "center = [0.0, 2.0, 0.0]\nradius = 1.0e4\nscattering = [0.005, 0.005, 0.005]",
        ));
        let p = plan(&huge, 0.25).unwrap();
        assert!(p.table_bricks() <= MAX_TABLE_BRICKS);
        assert!(p.voxel_m > 10.0, "{}", p.voxel_m);
        assert!(u64::from(p.max_capacity) * p.brick_bytes() <= MAX_POOL_BYTES);
        let tiny = load(&text(
            "center = [0.0, 1.0, 0.0]\nradius = 0.001\nscattering = [1000.0, 1000.0, 1000.0]",
        ));
        assert!(plan(&tiny, 0.25).is_none(), "a 1 mm puff stays analytic");
        let opaque = load(&text(
            "center = [0.0, 1.0, 0.0]\nradius = 2.0\nscattering = [1.0e4, 1.0e4, 1.0e4]",
        ));
        assert!(plan(&opaque, 0.25).is_none(), "σt 10⁴ stays analytic");
    }
}
