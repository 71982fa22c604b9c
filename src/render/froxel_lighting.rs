//! Stage 3 (paper 000 §3.1.3): in-scattering and extinction per froxel, all viewers in
//! one dispatch, with `shaders/froxel_lighting.wgsl` (and `shaders/shadow_lookup.wgsl`
//! for `maps` mode).

use super::gpu_types::ViewGpu;
use super::shadow_maps::ShadowMaps;
use super::{dispatch, SharedShadowGrid, Stage, Timestamps, ViewerId, ViewerSet, ViewerVolumes};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};
use glam::Mat4;
use std::collections::HashMap;

/// What froxel lighting keeps of a viewer's last frame for temporal reprojection.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ViewerHistory {
    /// Last frame's view-projection.
    pub view_proj: Mat4,
    /// Where the viewer's froxels start in last frame's froxel buffer.
    pub froxel_base: u32,
}

/// Froxel lighting's history in one viewer set: an output/history pair — this frame's
/// froxels (`ViewerVolumes::froxels`) and last frame's (`froxel_history`), swapped after
/// each frame instead of copied — and per viewer id where its froxels were, so a viewer
/// whose slot moved reads its own.
#[derive(Default)]
pub(crate) struct FroxelHistory {
    viewers: HashMap<ViewerId, ViewerHistory>,
    /// Last frame's froxels while the set's volumes were reallocated since.
    carried: Option<wgpu::Buffer>,
}

impl FroxelHistory {
    /// Viewer `id`'s last frame, if it has one.
    pub(crate) fn of(&self, id: ViewerId) -> Option<ViewerHistory> {
        self.viewers.get(&id).copied()
    }

    /// The set's volumes were reallocated: `old`'s last froxels stay readable one frame.
    pub(crate) fn reallocated(&mut self, old: ViewerVolumes, temporal: bool) {
        self.carried = temporal.then_some(old.froxel_history);
    }

    /// Last frame's froxels, as the stage reads them.
    pub(crate) fn buffer<'a>(&'a self, vol: &'a ViewerVolumes) -> &'a wgpu::Buffer {
        self.carried.as_ref().unwrap_or(&vol.froxel_history)
    }

    /// Whether some viewer has a history.
    #[cfg(test)]
    pub(crate) fn is_empty(&self) -> bool {
        self.viewers.is_empty()
    }

    /// After the frame: with `keep` (temporal reprojection on and the froxels written),
    /// this frame's froxels become the next one's history for the viewers `ids`;
    /// otherwise, and for viewers that left, the history is dropped.
    pub(crate) fn finish(
        &mut self,
        vol: &mut ViewerVolumes,
        ids: &[ViewerId],
        views: &[ViewGpu],
        volume_view_projs: &[Mat4],
        keep: bool,
    ) {
        self.carried = None;
        self.viewers.clear();
        if !keep {
            return;
        }
        std::mem::swap(&mut vol.froxels, &mut vol.froxel_history);
        for ((id, v), view_proj) in ids.iter().zip(views).zip(volume_view_projs) {
            // A coupled stereo eye without a near field wrote no froxels.
            if v.light_slices == 0 {
                continue;
            }
            let h = ViewerHistory {
                view_proj: *view_proj,
                froxel_base: v.froxel_base,
            };
            self.viewers.insert(*id, h);
        }
    }
}

/// Pipeline of the froxel lighting stage.
pub(crate) struct FroxelLighting {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// Binds in place of the grid's requests where there is no grid.
    no_requests: wgpu::Buffer,
}

impl FroxelLighting {
    /// `constants`: the scene's light count (`super::light_constants`) and
    /// `GRID_MEDIA_FINE` (whether the grid's density is on fine cells; default false).
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        constants: &[(&str, f64)],
    ) -> anyhow::Result<Self> {
        let own = [Read, Read, ReadWrite, Read, Read, Read, Read, ReadWrite]
            .iter()
            .enumerate()
            .map(|(i, a)| storage_entry(i as u32, *a))
            .collect();
        // `maps` mode reads the shared shadow maps (bindings 10–14).
        let layout = ShadowMaps::stage_layout(ctx, "froxel lighting", own);
        let module = super::stage_shader_with(
            ctx,
            "froxel_lighting",
            concat!(
                include_str!("../../shaders/shadow_lookup.wgsl"),
                include_str!("../../shaders/froxel_lighting.wgsl")
            ),
            constants,
            &[],
        );
        Ok(FroxelLighting {
            pipeline: ctx.compute_pipeline_with(
                "froxel_lighting",
                &module,
                &[scene_layout, &layout],
                "main",
                constants,
            ),
            layout,
            no_requests: ctx.storage(
                "froxel lighting: no grid requests",
                16,
                wgpu::BufferUsages::empty(),
            )?,
        })
    }

    /// `grid` is `None` in `reference` mode, where every froxel traces its own rays, and
    /// in `maps` mode, where it reads `maps`.
    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        grid: Option<&SharedShadowGrid>,
        maps: &ShadowMaps,
        ts: &Timestamps,
    ) {
        let volumes = &set.vol;
        // Without a grid its bindings are unused; the frustum buffer stands in.
        let grid_buffer = grid.map_or(&volumes.frustum, |g| &g.grid);
        let bricks = grid.map_or(&volumes.frustum, |g| &g.brick_table);
        let density = grid.map_or(&volumes.frustum, |g| &g.density);
        // FLAG_FROXEL_REQUESTS: a froxel requests the unfilled voxels it read.
        let requests = grid.map_or(&self.no_requests, |g| &g.requests);
        let own = crate::gpu::buffer_entries(&[
            grid_buffer,
            &volumes.frustum,
            &volumes.froxels,
            set.history.buffer(volumes),
            bricks,
            &volumes.column_limit,
            density,
            requests,
        ]);
        let bg = maps.stage_bind_group(ctx, "froxel lighting", &self.layout, own);
        dispatch(
            enc,
            ts,
            Stage::FroxelLighting,
            &self.pipeline,
            &[&set.bind_group, &bg],
            volumes.groups.columns,
        );
    }
}
