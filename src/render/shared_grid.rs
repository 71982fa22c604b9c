//! Stage 1 (paper 000 §3.1.1): the shared world-space shadow grid, with
//! `shaders/shared_grid.wgsl`. World-space work: it never loops over viewers' pixels.

use super::{compute_pass, Stage, Timestamps, ViewerVolumes};
use crate::gpu::GpuContext;
use glam::{UVec3, Vec3};

/// The shared grid: one 8-bit light bitmask per voxel, 4 voxels per u32 word along x.
pub struct SharedShadowGrid {
    pub(crate) min: Vec3,
    pub(crate) voxel_size_m: f32,
    pub(crate) dims: UVec3,
    pub(crate) words_x: u32,
    pub(crate) grid: wgpu::Buffer,
    /// One nibble per word: which of its 4 voxels were traced this frame.
    pub(crate) touched: wgpu::Buffer,
    /// Demand-driven update: one u32 per voxel, non-zero when a froxel will read it.
    pub(crate) requests: wgpu::Buffer,
    /// Temporal caching: which light bits of each voxel are current (grid layout).
    pub(crate) valid: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    request_layout: wgpu::BindGroupLayout,
    request_pipeline: wgpu::ComputePipeline,
}

/// How the grid pass decides which voxels to trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct UpdatePolicy {
    /// Only voxels requested by froxels (else every voxel in some frustum).
    pub demand: bool,
    /// Keep light bits across frames until the light changes.
    pub cache: bool,
}

impl SharedShadowGrid {
    /// A grid covering `bounds` with cubic voxels of `voxel_size_m`.
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        bounds: (Vec3, Vec3),
        voxel_size_m: f32,
        policy: UpdatePolicy,
    ) -> anyhow::Result<Self> {
        let extent = (bounds.1 - bounds.0).max(Vec3::splat(voxel_size_m));
        let dims = (extent / voxel_size_m).ceil().as_uvec3().max(UVec3::ONE);
        let voxels = dims.x as u64 * dims.y as u64 * dims.z as u64;
        let words_x = dims.x.div_ceil(4);
        let words = words_x as u64 * dims.y as u64 * dims.z as u64;
        // Request and validity buffers exist only for the options that use them (a
        // 16-byte stand-in keeps the bind group valid otherwise).
        let request_bytes = if policy.demand { voxels * 4 } else { 16 };
        let valid_bytes = if policy.cache { words * 4 } else { 16 };
        anyhow::ensure!(
            words * 4 <= ctx.max_storage_binding && request_bytes <= ctx.max_storage_binding,
            "a {voxel_size_m} m shadow grid over {extent:?} m is {}×{}×{} = {voxels} voxels ({:.0} MiB), more than the adapter can bind ({:.0} MiB): use a larger --voxel-size",
            dims.x,
            dims.y,
            dims.z,
            (words * 4).max(request_bytes) as f64 / 1048576.0,
            ctx.max_storage_binding as f64 / 1048576.0
        );
        let layout = ctx.storage_layout("shared grid", &[true, true, false, true]);
        let request_layout = ctx.storage_layout("grid requests", &[true]);
        let request_module = super::stage_shader(
            ctx,
            "grid_requests",
            include_str!("../../shaders/grid_requests.wgsl"),
        );
        let module = super::stage_shader(
            ctx,
            "shared_grid",
            include_str!("../../shaders/shared_grid.wgsl"),
        );
        Ok(SharedShadowGrid {
            min: bounds.0,
            voxel_size_m,
            dims,
            words_x,
            grid: ctx.storage("shared grid", words * 4, wgpu::BufferUsages::empty())?,
            touched: ctx.storage(
                "shared grid touched",
                words.div_ceil(8) * 4,
                wgpu::BufferUsages::empty(),
            )?,
            requests: ctx.storage("grid requests", request_bytes, wgpu::BufferUsages::empty())?,
            valid: ctx.storage("grid valid bits", valid_bytes, wgpu::BufferUsages::empty())?,
            pipeline: ctx.compute_pipeline("shared_grid", &module, &[scene_layout, &layout]),
            layout,
            request_pipeline: ctx.compute_pipeline(
                "grid_requests",
                &request_module,
                &[scene_layout, &request_layout],
            ),
            request_layout,
        })
    }

    pub(crate) fn workgroups(&self) -> [u32; 3] {
        [
            self.words_x.div_ceil(4),
            self.dims.y.div_ceil(4),
            self.dims.z.div_ceil(4),
        ]
    }

    /// Dispatch size of the request pass: froxel tiles × (viewers × grid slices).
    pub(crate) fn request_workgroups(volumes: &ViewerVolumes) -> [u32; 3] {
        let [x, y] = volumes.layout.froxel_dims;
        [
            x.div_ceil(8),
            y.div_ceil(8),
            (volumes.slices - volumes.frustum_slices) * volumes.count as u32,
        ]
    }

    /// Records the froxels' voxel requests (demand-driven update); returns false when no
    /// slice reads the grid (the shadow frustum covers them all) and nothing was recorded.
    pub(crate) fn add_request_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        volumes: &ViewerVolumes,
        ts: &Timestamps,
    ) -> bool {
        enc.clear_buffer(&self.requests, 0, None);
        if volumes.slices <= volumes.frustum_slices {
            return false;
        }
        let bg = ctx.bind_buffers("grid requests", &self.request_layout, &[&self.requests]);
        let mut pass = compute_pass(enc, "grid_requests", ts.writes(Stage::GridRequests));
        pass.set_pipeline(&self.request_pipeline);
        pass.set_bind_group(0, scene, &[]);
        pass.set_bind_group(1, &bg, &[]);
        let [x, y, z] = Self::request_workgroups(volumes);
        pass.dispatch_workgroups(x, y, z);
        true
    }

    /// Records the grid update: every needed voxel traces one ray per (stale) light.
    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        ts: &Timestamps,
    ) {
        enc.clear_buffer(&self.touched, 0, None);
        let bg = ctx.bind_buffers(
            "shared grid",
            &self.layout,
            &[&self.grid, &self.touched, &self.requests, &self.valid],
        );
        let mut pass = compute_pass(enc, "shared_grid", ts.writes(Stage::SharedGrid));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, scene, &[]);
        pass.set_bind_group(1, &bg, &[]);
        let [x, y, z] = self.workgroups();
        pass.dispatch_workgroups(x, y, z);
    }

    /// Bytes of the grid, its touched bits, request and validity buffers.
    pub(crate) fn bytes(&self) -> u64 {
        self.grid.size() + self.touched.size() + self.requests.size() + self.valid.size()
    }
}
