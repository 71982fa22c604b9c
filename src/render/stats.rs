//! Per-frame counters: rays per stage, voxels traced, dispatch sizes, memory, timings.

use super::gpu_types::*;
use super::{Settings, Stage, ViewerVolumes, World};
use serde::{Deserialize, Serialize};

/// Shadow rays traced in one frame, per stage (deterministic: the noise-free cost).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    /// Stage 1: shared grid voxels × lights.
    pub shared_grid: u64,
    /// Stage 2: shadow frustum froxels × lights traced (directional lights with a
    /// shared shadow map are looked up in it instead).
    pub shadow_frustum: u64,
    /// Stage 3: froxels × lights (`reference` only).
    pub froxel_lighting: u64,
    /// Surface shadow rays in the composite (the same in every mode).
    pub surface: u64,
    /// Rays of the fog stages (1–3).
    pub fog_total: u64,
    /// All rays.
    pub total: u64,
}

impl RayCounts {
    /// The rays `stage` traced (0 for a stage without shadow rays).
    pub fn of_stage(&self, stage: Stage) -> u64 {
        match stage {
            Stage::SharedGrid => self.shared_grid,
            Stage::ShadowFrustum => self.shadow_frustum,
            Stage::FroxelLighting => self.froxel_lighting,
            Stage::Composite => self.surface,
            _ => 0,
        }
    }
}

/// The viewers of one size in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ViewSize {
    /// View width, pixels.
    pub width: u32,
    /// View height, pixels.
    pub height: u32,
    /// Viewers of this size.
    pub viewers: usize,
}

/// GPU time of one stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    /// Stage name.
    pub stage: String,
    /// Milliseconds between the stage's begin and end timestamps.
    pub gpu_ms: f64,
}

/// Bytes of every GPU resource, split into shared and per viewer.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MemoryReport {
    /// Resources shared by all viewers (name → bytes).
    pub shared: Vec<(String, u64)>,
    /// Resources of one viewer of the first view size (name → bytes).
    pub per_viewer: Vec<(String, u64)>,
    /// Sum of `shared`.
    pub shared_total: u64,
    /// Sum of `per_viewer`.
    pub per_viewer_total: u64,
    /// shared_total + every viewer's resources (of every size).
    pub total: u64,
}

/// Everything measured about one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    /// Scene name.
    pub scene: String,
    /// Settings used.
    pub settings: Settings,
    /// Number of views rendered.
    pub viewers: usize,
    /// View width (of the first view size when there are several).
    pub width: u32,
    /// View height (of the first view size when there are several).
    pub height: u32,
    /// Every view size of the frame, with its number of viewers.
    #[serde(default)]
    pub view_sizes: Vec<ViewSize>,
    /// Frame number since the renderer was made.
    pub frame_index: u32,
    /// Triangles in the BVH.
    pub triangles: usize,
    /// Lights in use.
    pub lights: usize,
    /// Shadow rays per stage.
    pub rays: RayCounts,
    /// Grid voxels traced this frame.
    pub voxels_traced: u64,
    /// Grid voxels needed this frame (in some frustum, or requested by a froxel with
    /// `demand`); with `cache` most are served from earlier frames without tracing.
    pub voxels_needed: u64,
    /// Froxels with non-zero media (the rest skip shadow work).
    pub froxels_with_media: u64,
    /// Nodes of the shared media transmittance volumes refilled this frame (0 in a
    /// static scene after the first frame, and always in `reference`, which marches).
    #[serde(default)]
    pub transmittance_nodes: u64,
    /// World media layer: bricks filled this frame (static media: only bricks newly
    /// seen; moving media: every brick seen).
    #[serde(default)]
    pub layer_bricks_filled: u64,
    /// World media layer: nodes evaluated this frame (729 per brick filled).
    #[serde(default)]
    pub layer_nodes_filled: u64,
    /// `froxel_requests`: whether this frame's froxels requested the grid voxels they
    /// found unfilled (and made them in place) instead of a request pass.
    #[serde(default)]
    pub froxel_requests: bool,
    /// `grid_media`: grid voxels whose media density was evaluated this frame (once for
    /// every viewer, in the grid pass; 0 without it).
    #[serde(default)]
    pub grid_media_voxels: u64,
    /// Triangles the G-buffer drew this frame, summed over views, movers included: with
    /// `triangle_cull` those the culling pass kept, else every triangle of the clusters
    /// each view's frustum touches.
    #[serde(default)]
    pub raster_triangles: u64,
    /// Triangles of the clusters each view's frustum touches, summed over views, movers
    /// included (what the views draw without `triangle_cull`).
    #[serde(default)]
    pub raster_triangles_in_clusters: u64,
    /// World media layer: bricks holding media after this frame (the pool grows for the
    /// next frame when the bricks seen did not fit).
    #[serde(default)]
    pub layer_bricks_in_use: u64,
    /// World media layer: bricks its pool holds at most (0: no layer).
    #[serde(default)]
    pub layer_pool_bricks: u64,
    /// Bytes of the layer's bricks in use.
    #[serde(default)]
    pub layer_bytes_in_use: u64,
    /// Bytes a dense grid of the same nodes over the layer's extent would take (what
    /// the bricks replace).
    #[serde(default)]
    pub layer_dense_bytes: u64,
    /// Bytes of the light masks of a dense grid over the media box (what a sparse grid
    /// avoids; equal to the grid's words when dense).
    pub grid_dense_bytes: u64,
    /// Sparse grid: bricks in the pool (0: dense grid).
    pub grid_pool_bricks: u64,
    /// Sparse grid: bricks the froxels read this frame; those beyond the pool were not
    /// stored, and their froxels traced their own rays.
    pub grid_bricks_requested: u64,
    /// Shared grid dimensions (0 when there is no grid).
    pub grid_dims: [u32; 3],
    /// Workgroups of every dispatch that ran.
    pub dispatches: Vec<(String, [u32; 3])>,
    /// GPU memory.
    pub memory: MemoryReport,
    /// Per-stage GPU time (empty without timestamp queries).
    pub stage_gpu_ms: Vec<StageTiming>,
    /// Whether `stage_gpu_ms` came from timestamp queries.
    pub timestamps: bool,
    /// Host time from upload to readback, milliseconds.
    pub frame_ms: f64,
}

pub(super) struct StatsInput<'a> {
    pub world: &'a World,
    pub counters: &'a [u32],
    /// Every viewer set's volumes (at least one).
    pub sets: Vec<&'a ViewerVolumes>,
    pub stage_ms: Vec<StageTiming>,
    pub frame_ms: f64,
    pub dispatches: Vec<(&'static str, [u32; 3])>,
    /// Bytes of the G-buffer's per-view triangle lists (`triangle_cull`; 0 without).
    pub triangle_list_bytes: u64,
    /// (triangles the G-buffer drew, triangles in the clusters the frustums touched),
    /// summed over views (`GBuffer::raster_triangles`).
    pub raster_triangles: (u64, u64),
}

pub(super) fn build(i: StatsInput<'_>) -> FrameStats {
    let c = |k: usize| i.counters[k] as u64;
    let w = i.world;
    let grid = w.grid.as_ref();
    let layer = w.layer.as_ref();
    let layer_bricks_in_use = layer.map_or(0, |l| l.record_requested(c(C_LAYER_BRICKS)));
    let mut rays = RayCounts {
        shared_grid: c(C_GRID_RAYS),
        shadow_frustum: c(C_FRUSTUM_RAYS),
        froxel_lighting: c(C_LIGHTING_RAYS),
        surface: c(C_SURFACE_RAYS),
        ..Default::default()
    };
    rays.fog_total = rays.shared_grid + rays.shadow_frustum + rays.froxel_lighting;
    rays.total = rays.fog_total + rays.surface;
    let mut shared: Vec<(String, u64)> = w
        .gpu
        .memory
        .iter()
        .map(|(n, b)| (n.to_string(), *b))
        .collect();
    if let Some(g) = grid {
        shared.push((Stage::SharedGrid.name().into(), g.bytes()));
    }
    if w.shadow_maps.bytes() > 0 {
        shared.push((Stage::ShadowMaps.name().into(), w.shadow_maps.bytes()));
    }
    // The triangle lists are one buffer over every view of every set.
    let views: u64 = i.sets.iter().map(|v| v.count as u64).sum();
    let lists_per_view = i.triangle_list_bytes / views.max(1);
    let per_viewer_of = |v: &ViewerVolumes| -> Vec<(String, u64)> {
        let mut list: Vec<(String, u64)> = v
            .memory_per_viewer()
            .into_iter()
            .map(|(n, b)| (n.to_string(), b))
            .collect();
        if lists_per_view > 0 {
            list.push(("triangle_lists".into(), lists_per_view));
        }
        list
    };
    let total_of = |list: &[(String, u64)]| list.iter().map(|(_, b)| b).sum::<u64>();
    let first = i.sets[0];
    let per_viewer = per_viewer_of(first);
    let shared_total = total_of(&shared);
    let per_viewer_total = total_of(&per_viewer);
    let viewers_total: u64 = i
        .sets
        .iter()
        .map(|v| total_of(&per_viewer_of(v)) * v.count as u64)
        .sum();
    FrameStats {
        scene: w.scene.name.clone(),
        settings: w.settings,
        viewers: i.sets.iter().map(|v| v.count).sum(),
        width: first.layout.width,
        height: first.layout.height,
        view_sizes: i
            .sets
            .iter()
            .map(|v| ViewSize {
                width: v.layout.width,
                height: v.layout.height,
                viewers: v.count,
            })
            .collect(),
        frame_index: w.frame_index,
        triangles: w.triangles,
        lights: w.scene.lights.len(),
        rays,
        voxels_traced: c(C_VOXELS_TRACED),
        voxels_needed: c(C_VOXELS_NEEDED),
        froxels_with_media: c(C_FROXELS_WITH_MEDIA),
        transmittance_nodes: c(C_TRANSMITTANCE_NODES),
        layer_bricks_filled: c(C_LAYER_NODES) / super::media_layer::BRICK_NODES,
        layer_nodes_filled: c(C_LAYER_NODES),
        grid_media_voxels: c(C_GRID_MEDIA_VOXELS),
        froxel_requests: w.froxel_requests_now,
        raster_triangles: i.raster_triangles.0,
        raster_triangles_in_clusters: i.raster_triangles.1,
        layer_bricks_in_use,
        layer_pool_bricks: layer.map_or(0, |l| u64::from(l.plan().capacity)),
        layer_bytes_in_use: layer.map_or(0, |l| layer_bricks_in_use * l.plan().brick_bytes()),
        layer_dense_bytes: layer.map_or(0, |l| l.plan().dense_bytes()),
        grid_dense_bytes: grid.map_or(0, |g| g.dense_bytes()),
        grid_pool_bricks: grid.map_or(0, |g| g.pool_capacity() as u64),
        grid_bricks_requested: if grid.is_some_and(|g| g.is_sparse()) {
            c(C_BRICKS)
        } else {
            0
        },
        grid_dims: grid.map_or([0; 3], |g| g.dims.to_array()),
        dispatches: i
            .dispatches
            .into_iter()
            .map(|(n, d)| (n.to_string(), d))
            .collect(),
        memory: MemoryReport {
            total: shared_total + viewers_total,
            shared,
            per_viewer,
            shared_total,
            per_viewer_total,
        },
        stage_gpu_ms: i.stage_ms,
        timestamps: w.ctx.has_timestamps,
        frame_ms: i.frame_ms,
    }
}
