//! Stage 1 (paper 000 §3.1.1): the shared world-space shadow grid, with
//! `shaders/shared_grid.wgsl`. World-space work: it never loops over viewers' pixels.

use super::{compute_pass, Timestamps};
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
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl SharedShadowGrid {
    /// A grid covering `bounds` with cubic voxels of `voxel_size_m`.
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        bounds: (Vec3, Vec3),
        voxel_size_m: f32,
    ) -> anyhow::Result<Self> {
        let extent = (bounds.1 - bounds.0).max(Vec3::splat(voxel_size_m));
        let dims = (extent / voxel_size_m).ceil().as_uvec3().max(UVec3::ONE);
        let voxels = dims.x as u64 * dims.y as u64 * dims.z as u64;
        let words_x = dims.x.div_ceil(4);
        let words = words_x as u64 * dims.y as u64 * dims.z as u64;
        anyhow::ensure!(
            words * 4 <= ctx.max_storage_binding,
            "a {voxel_size_m} m shadow grid over {extent:?} m is {}×{}×{} = {voxels} voxels ({:.0} MiB), more than the adapter can bind ({:.0} MiB): use a larger --voxel-size",
            dims.x,
            dims.y,
            dims.z,
            words as f64 * 4.0 / 1048576.0,
            ctx.max_storage_binding as f64 / 1048576.0
        );
        let layout = ctx.storage_layout("shared grid", &[true, true]);
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
            pipeline: ctx.compute_pipeline("shared_grid", &module, &[scene_layout, &layout]),
            layout,
        })
    }

    pub(crate) fn workgroups(&self) -> [u32; 3] {
        [
            self.words_x.div_ceil(4),
            self.dims.y.div_ceil(4),
            self.dims.z.div_ceil(4),
        ]
    }

    /// Records the grid update: every voxel inside some frustum traces one ray per light.
    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        ts: &Timestamps,
    ) {
        enc.clear_buffer(&self.touched, 0, None);
        let bg = ctx.bind_buffers("shared grid", &self.layout, &[&self.grid, &self.touched]);
        let mut pass = compute_pass(enc, "shared_grid", ts.writes(super::Stage::SharedGrid));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, scene, &[]);
        pass.set_bind_group(1, &bg, &[]);
        let [x, y, z] = self.workgroups();
        pass.dispatch_workgroups(x, y, z);
    }

    /// Bytes of the grid and its touched bits.
    pub(crate) fn bytes(&self) -> u64 {
        self.grid.size() + self.touched.size()
    }
}
