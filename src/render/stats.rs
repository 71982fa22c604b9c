//! Per-frame counters: rays per stage, voxels traced, dispatch sizes, memory, timings.

use super::gpu_types::*;
use super::{Settings, SharedShadowGrid, ViewerVolumes};
use crate::scene::Scene;
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
    /// Resources of one viewer (name → bytes).
    pub per_viewer: Vec<(String, u64)>,
    /// Sum of `shared`.
    pub shared_total: u64,
    /// Sum of `per_viewer`.
    pub per_viewer_total: u64,
    /// shared_total + viewers × per_viewer_total.
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
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
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
    pub settings: &'a Settings,
    pub scene: &'a Scene,
    pub triangles: usize,
    pub counters: &'a [u32],
    pub grid: Option<&'a SharedShadowGrid>,
    /// Bytes of the surface shadow maps (0 without).
    pub shadow_map_bytes: u64,
    pub scene_memory: &'a [(&'static str, u64)],
    pub volumes: &'a ViewerVolumes,
    pub stage_ms: Vec<StageTiming>,
    pub frame_ms: f64,
    pub dispatches: Vec<(&'static str, [u32; 3])>,
    pub frame_index: u32,
    pub timestamps: bool,
}

pub(super) fn build(i: StatsInput<'_>) -> FrameStats {
    let c = |k: usize| i.counters[k] as u64;
    let mut rays = RayCounts {
        shared_grid: c(C_GRID_RAYS),
        shadow_frustum: c(C_FRUSTUM_RAYS),
        froxel_lighting: c(C_LIGHTING_RAYS),
        surface: c(C_SURFACE_RAYS),
        ..Default::default()
    };
    rays.fog_total = rays.shared_grid + rays.shadow_frustum + rays.froxel_lighting;
    rays.total = rays.fog_total + rays.surface;
    let mut shared: Vec<(String, u64)> = i
        .scene_memory
        .iter()
        .map(|(n, b)| (n.to_string(), *b))
        .collect();
    if let Some(g) = i.grid {
        shared.push(("shared_grid".into(), g.bytes()));
    }
    if i.shadow_map_bytes > 0 {
        shared.push(("shadow_maps".into(), i.shadow_map_bytes));
    }
    let per_viewer: Vec<(String, u64)> = i
        .volumes
        .memory_per_viewer()
        .into_iter()
        .map(|(n, b)| (n.to_string(), b))
        .collect();
    let shared_total = shared.iter().map(|(_, b)| b).sum();
    let per_viewer_total = per_viewer.iter().map(|(_, b)| b).sum::<u64>();
    FrameStats {
        scene: i.scene.name.clone(),
        settings: *i.settings,
        viewers: i.volumes.count,
        width: i.volumes.layout.width,
        height: i.volumes.layout.height,
        frame_index: i.frame_index,
        triangles: i.triangles,
        lights: i.scene.lights.len(),
        rays,
        voxels_traced: c(C_VOXELS_TRACED),
        voxels_needed: c(C_VOXELS_NEEDED),
        froxels_with_media: c(C_FROXELS_WITH_MEDIA),
        transmittance_nodes: c(C_TRANSMITTANCE_NODES),
        grid_dense_bytes: i.grid.map_or(0, |g| g.dense_bytes()),
        grid_pool_bricks: i.grid.map_or(0, |g| g.pool_capacity() as u64),
        grid_bricks_requested: if i.grid.is_some_and(|g| g.is_sparse()) {
            c(C_BRICKS)
        } else {
            0
        },
        grid_dims: i.grid.map_or([0; 3], |g| g.dims.to_array()),
        dispatches: i
            .dispatches
            .into_iter()
            .map(|(n, d)| (n.to_string(), d))
            .collect(),
        memory: MemoryReport {
            total: shared_total + per_viewer_total * i.volumes.count as u64,
            shared,
            per_viewer,
            shared_total,
            per_viewer_total,
        },
        stage_gpu_ms: i.stage_ms,
        timestamps: i.timestamps,
        frame_ms: i.frame_ms,
    }
}
