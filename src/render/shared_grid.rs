//! Stage 1 (paper 000 §3.1.1): the shared world-space shadow grid, with
//! `shaders/shared_grid.wgsl` and `shaders/grid_requests.wgsl`. World-space work: the
//! update never loops over viewers' pixels.
//!
//! Three ways to decide what to trace (see [`GridUpdate`]): the paper's frustum-gated
//! update, fogcast's demand-driven update (froxels request the voxels they read), and on
//! top of either temporal caching. Storage is dense (the whole media box) or sparse:
//! bricks of 8³ voxels allocated each frame where froxels read (paper §5.1).

use super::froxel_cull::FroxelCull;
use super::gpu_types::{FLAG_CACHE, FLAG_DEMAND, FLAG_SPARSE};
use super::media_layer::GridMedia;
use super::{dispatch, dispatch_indirect, Settings, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::GpuContext;
use glam::{UVec3, Vec3};

/// Voxels per brick edge (`BRICK` in common.wgsl).
const BRICK: u32 = 8;
/// u32 words per brick: 512 voxels, 4 per word.
const BRICK_WORDS: u64 = 128;

/// The shared grid: one 8-bit light bitmask per voxel, 4 voxels per u32 word.
pub struct SharedShadowGrid {
    pub(crate) min: Vec3,
    pub(crate) voxel_size_m: f32,
    pub(crate) dims: UVec3,
    pub(crate) words_x: u32,
    /// Dense: the words of the whole grid (4 voxels along x each). Sparse: the brick pool.
    pub(crate) grid: wgpu::Buffer,
    /// One nibble per word: which of its 4 voxels were traced this frame (dense only).
    pub(crate) touched: wgpu::Buffer,
    /// Demand-driven update. Dense: one bit per voxel (`request_bit`, common.wgsl); a
    /// trilinear lookup sets the bit of the lowest of the 8 voxels it reads. Sparse: one
    /// bit per pool voxel.
    pub(crate) requests: wgpu::Buffer,
    /// Temporal caching: which light bits of each voxel are current (grid layout).
    pub(crate) valid: wgpu::Buffer,
    /// Sparse: one u32 per brick of the whole grid (0, pool slot + 1, or missing).
    pub(crate) brick_table: wgpu::Buffer,
    /// Sparse: the brick of each pool slot.
    slot_brick: wgpu::Buffer,
    /// `grid_media`: the costly media's density on a lattice twice as fine as the
    /// voxels, 8 bits in units of `GridMedia::unit`: first a code per voxel in the
    /// grid's layout (4 voxels per word; nonzero once the voxel's cells are filled),
    /// then the cells in that layout at twice the resolution (`fine_row` in
    /// common.wgsl); a
    /// 16-byte stand-in without.
    pub(crate) density: wgpu::Buffer,
    /// The media the grid carries the density of (`grid_media`, dense grids).
    pub(crate) media: Option<GridMedia>,
    policy: GridUpdate,
    layout: wgpu::BindGroupLayout,
    /// The update, compiled for this grid's policy alone.
    update: Update,
    /// The listed workgroups' numbers (x + gx·(y + gy·z)), one u32 each (a 16-byte
    /// stand-in without a list).
    listed_groups: wgpu::Buffer,
    /// The indirect dispatch's workgroups (x, y, z); x is the list's length.
    listed_args: wgpu::Buffer,
    request_layout: wgpu::BindGroupLayout,
    request_pipelines: RequestPipelines,
}

/// The demand-driven dense grid's update over the workgroups that have work. With a
/// cached grid most voxels are current every frame, and `main`'s workgroup barriers make
/// llvmpipe run it invocation by invocation over the whole grid (Sponza's 203k words:
/// about 8 ms a frame with no ray to trace). `scan`, barrier-free, lists the workgroups
/// whose words trace, fill a media code or drop a stale bit; `main_listed` runs `main`
/// over them, dispatched indirectly.
struct Listed {
    scan: wgpu::ComputePipeline,
    update: wgpu::ComputePipeline,
    /// `main`'s workgroups over the whole grid.
    count: u64,
}

/// The grid pass a policy runs: one dispatch over the whole grid (`main`, or
/// `update_sparse` over the pool), or the demand-driven dense update in two passes, a
/// scan listing the workgroups with work and the update over those alone ([`Listed`]).
enum Update {
    Whole(wgpu::ComputePipeline),
    Listed(Listed),
}

/// The request passes a policy runs (none for the frustum-gated update): one over the
/// froxels for a dense grid; for a sparse one the bricks, their slots, then the voxels.
enum RequestPipelines {
    None,
    Dense(wgpu::ComputePipeline),
    Sparse {
        mark_bricks: wgpu::ComputePipeline,
        allocate: wgpu::ComputePipeline,
        mark_voxels: wgpu::ComputePipeline,
    },
}

/// The two request passes of a viewer set (the sparse grid allocates bricks between).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RequestPhase {
    /// Voxels (dense) or bricks (sparse) the set's froxels read.
    Mark,
    /// Sparse: the voxels, inside the bricks that got a pool slot.
    Voxels,
}

/// How the grid pass decides which voxels to trace, and how the grid is stored: the one
/// place `demand`, `cache` and `brick_pool` are combined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridUpdate {
    /// Paper 000: every voxel inside some viewer's frustum.
    Frustum {
        /// A voxel's light bits stay valid until that light changes or a mover crosses
        /// its shadow ray.
        cached: bool,
    },
    /// Only the voxels some froxel's lookup reads (beyond the paper).
    Demand {
        /// As for `Frustum`.
        cached: bool,
    },
    /// Bricks of 8³ voxels allocated each frame where froxels read (paper 000 §5.1);
    /// demand-driven, never cached.
    Sparse {
        /// Bricks in the pool.
        pool_bricks: u32,
    },
}

impl GridUpdate {
    /// The update `settings` ask for.
    pub fn of(settings: &Settings) -> GridUpdate {
        match (settings.brick_pool, settings.demand) {
            (pool_bricks @ 1.., _) => GridUpdate::Sparse { pool_bricks },
            (0, true) => GridUpdate::Demand {
                cached: settings.cache,
            },
            (0, false) => GridUpdate::Frustum {
                cached: settings.cache,
            },
        }
    }

    /// Whether froxels request the voxels they read (a request stage runs first).
    pub fn requests(self) -> bool {
        !matches!(self, GridUpdate::Frustum { .. })
    }

    /// Whether light bits are kept across frames.
    pub fn cached(self) -> bool {
        matches!(
            self,
            GridUpdate::Frustum { cached: true } | GridUpdate::Demand { cached: true }
        )
    }

    fn sparse(self) -> bool {
        matches!(self, GridUpdate::Sparse { .. })
    }

    /// Bricks in the sparse pool (0: dense).
    pub fn pool_bricks(self) -> u32 {
        match self {
            GridUpdate::Sparse { pool_bricks } => pool_bricks,
            _ => 0,
        }
    }

    /// The `Frame.flags` bits of this update (common.wgsl).
    pub(crate) fn flags(self) -> u32 {
        let mut flags = 0;
        if self.requests() {
            flags |= FLAG_DEMAND;
        }
        if self.sparse() {
            flags |= FLAG_SPARSE;
        }
        if self.cached() {
            flags |= FLAG_CACHE;
        }
        flags
    }
}

fn grid_dims(bounds: (Vec3, Vec3), voxel_size_m: f32) -> (UVec3, Vec3) {
    let extent = (bounds.1 - bounds.0).max(Vec3::splat(voxel_size_m));
    let dims = (extent / voxel_size_m).ceil().as_uvec3().max(UVec3::ONE);
    (dims, extent)
}

/// A 2D dispatch of 64-wide workgroups covering `n` invocations (x + y·64·groups_x).
fn dispatch_1d(n: u64) -> [u32; 3] {
    let groups = n.div_ceil(64).max(1);
    let x = groups.min(32768);
    [x as u32, groups.div_ceil(x) as u32, 1]
}

impl SharedShadowGrid {
    /// A grid covering `bounds` with cubic voxels of `voxel_size_m`; with `media` (a
    /// dense grid only) it carries their density too.
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        bounds: (Vec3, Vec3),
        voxel_size_m: f32,
        policy: GridUpdate,
        media: Option<GridMedia>,
    ) -> anyhow::Result<Self> {
        let media = media.filter(|_| !policy.sparse());
        let (dims, extent) = grid_dims(bounds, voxel_size_m);
        let voxels = dims.x as u64 * dims.y as u64 * dims.z as u64;
        let words_x = dims.x.div_ceil(4);
        let words = words_x as u64 * dims.y as u64 * dims.z as u64;
        let bricks = (dims.x.div_ceil(BRICK) as u64)
            * (dims.y.div_ceil(BRICK) as u64)
            * (dims.z.div_ceil(BRICK) as u64);
        let pool = policy.pool_bricks() as u64;
        // Buffers exist only for the options that use them (a 16-byte stand-in keeps
        // the bind groups valid otherwise).
        let (grid_bytes, request_bytes, table_bytes) = if policy.sparse() {
            (pool * BRICK_WORDS * 4, pool * BRICK_WORDS, bricks * 4)
        } else if policy.requests() {
            // One request bit per voxel and one more layer below the grid on each
            // axis, rows along x padded to whole words (`request_bit`, common.wgsl).
            let rows = (dims.y as u64 + 1) * (dims.z as u64 + 1);
            (words * 4, (dims.x as u64 + 32) / 32 * rows * 4, 16)
        } else {
            (words * 4, 16, 16)
        };
        let valid_bytes = if policy.cached() { words * 4 } else { 16 };
        // Coarse codes (4 voxels a word), then the fine cells' codes in the same layout
        // at twice the resolution (8 words for each coarse word).
        let density_bytes = match &media {
            Some(m) if m.fine => words * 4 * 9,
            Some(_) => words * 4,
            None => 16,
        };
        let largest = grid_bytes
            .max(request_bytes)
            .max(table_bytes)
            .max(density_bytes);
        anyhow::ensure!(
            largest <= ctx.max_storage_binding,
            "a {voxel_size_m} m shadow grid over {extent:?} m is {}×{}×{} = {voxels} voxels; its largest buffer is {:.0} MiB, more than the adapter can bind ({:.0} MiB): use a larger --voxel-size-m{}",
            dims.x,
            dims.y,
            dims.z,
            largest as f64 / 1048576.0,
            ctx.max_storage_binding as f64 / 1048576.0,
            if policy.sparse() { "" } else { " or a sparse grid (--brick-pool N)" }
        );
        let layout = ctx.storage_layout(
            "shared grid",
            &[
                ReadWrite, ReadWrite, Read, ReadWrite, Read, ReadWrite, ReadWrite, ReadWrite,
            ],
        );
        let request_layout =
            ctx.storage_layout("grid requests", &[ReadWrite, ReadWrite, ReadWrite, Read]);
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
        let request = |entry: &str| {
            ctx.compute_pipeline_entry(
                entry,
                &request_module,
                &[scene_layout, &request_layout],
                entry,
            )
        };
        let storage =
            |label: &str, bytes: u64| ctx.storage(label, bytes, wgpu::BufferUsages::empty());
        // `main`'s workgroups (4 × 4 × 4 words); listed only where one dispatch
        // dimension holds them all.
        let group_count = (words_x.div_ceil(4) as u64)
            * (dims.y.div_ceil(4) as u64)
            * (dims.z.div_ceil(4) as u64);
        let grid_pipeline = |label: &str, entry: &str| {
            ctx.compute_pipeline_entry(label, &module, &[scene_layout, &layout], entry)
        };
        let update = match policy {
            GridUpdate::Demand { .. }
                if group_count
                    <= u64::from(ctx.device.limits().max_compute_workgroups_per_dimension) =>
            {
                Update::Listed(Listed {
                    scan: grid_pipeline("shared_grid_scan", "scan"),
                    update: grid_pipeline("shared_grid_listed", "main_listed"),
                    count: group_count,
                })
            }
            GridUpdate::Sparse { .. } => {
                Update::Whole(grid_pipeline("shared_grid_sparse", "update_sparse"))
            }
            _ => Update::Whole(grid_pipeline("shared_grid", "main")),
        };
        let listed = matches!(update, Update::Listed(_));
        let request_pipelines = match policy {
            _ if !policy.requests() => RequestPipelines::None,
            GridUpdate::Sparse { .. } => RequestPipelines::Sparse {
                mark_bricks: request("mark_bricks"),
                allocate: request("allocate"),
                mark_voxels: request("mark_voxels"),
            },
            _ => RequestPipelines::Dense(request("main")),
        };
        Ok(SharedShadowGrid {
            min: bounds.0,
            voxel_size_m,
            dims,
            words_x,
            grid: storage("shared grid", grid_bytes)?,
            touched: storage(
                "shared grid touched",
                if policy.sparse() {
                    16
                } else {
                    words.div_ceil(8) * 4
                },
            )?,
            requests: storage("grid requests", request_bytes)?,
            valid: storage("grid valid bits", valid_bytes)?,
            brick_table: storage("grid brick table", table_bytes)?,
            slot_brick: storage("grid brick slots", (pool * 4).max(16))?,
            density: storage("shared grid media density", density_bytes)?,
            media,
            policy,
            listed_groups: storage(
                "shared grid listed workgroups",
                if listed { group_count * 4 } else { 16 },
            )?,
            listed_args: ctx.storage(
                "shared grid listed dispatch",
                12,
                wgpu::BufferUsages::INDIRECT,
            )?,
            update,
            layout,
            request_pipelines,
            request_layout,
        })
    }

    /// Bricks of 8³ voxels over the whole grid.
    fn bricks(&self) -> u64 {
        (self.dims.x.div_ceil(BRICK) as u64)
            * (self.dims.y.div_ceil(BRICK) as u64)
            * (self.dims.z.div_ceil(BRICK) as u64)
    }

    /// Whether the grid is stored as sparse bricks.
    pub(crate) fn is_sparse(&self) -> bool {
        self.policy.sparse()
    }

    /// Bricks in the sparse pool (0 when dense).
    pub(crate) fn pool_capacity(&self) -> u32 {
        self.policy.pool_bricks()
    }

    /// Bytes the light masks of a dense grid over the same box take (for reports).
    pub(crate) fn dense_bytes(&self) -> u64 {
        self.words_x as u64 * self.dims.y as u64 * self.dims.z as u64 * 4
    }

    /// Dispatch size of the update pass.
    pub(crate) fn workgroups(&self) -> [u32; 3] {
        if self.policy.sparse() {
            return dispatch_1d(self.policy.pool_bricks() as u64 * BRICK_WORDS);
        }
        [
            self.words_x.div_ceil(4),
            self.dims.y.div_ceil(4),
            self.dims.z.div_ceil(4),
        ]
    }

    /// The grid's update policy.
    pub(crate) fn update(&self) -> GridUpdate {
        self.policy
    }

    /// Records the requests of every viewer set (demand-driven and sparse updates;
    /// returns false for the frustum-gated update, which has none): last frame's
    /// requests cleared, each set's hidden froxels culled (`cull`), each set's voxels (or
    /// bricks) marked, the sparse pool allocated, then the sparse bricks' voxels marked.
    /// With `from_froxels` (`FLAG_FROXEL_REQUESTS`) only the culling: the requests are
    /// those last frame's froxels made, cleared after the grid pass ([`Self::add_pass`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn add_requests(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        world: &wgpu::BindGroup,
        sets: &[&ViewerSet],
        cull: Option<&FroxelCull>,
        from_froxels: bool,
        ts: &Timestamps,
    ) -> bool {
        if !self.policy.requests() {
            return false;
        }
        if !from_froxels {
            enc.clear_buffer(&self.requests, 0, None);
        }
        if self.policy.sparse() {
            enc.clear_buffer(&self.brick_table, 0, None);
        }
        for set in sets {
            if let Some(cull) = cull {
                cull.add_passes(ctx, enc, set, ts);
            }
            if !from_froxels {
                self.add_request_pass(ctx, enc, set, RequestPhase::Mark, ts);
            }
        }
        if from_froxels {
            return cull.is_some();
        }
        self.add_allocation(ctx, enc, world, ts);
        for set in sets {
            self.add_request_pass(ctx, enc, set, RequestPhase::Voxels, ts);
        }
        true
    }

    fn request_bind_group(&self, ctx: &GpuContext, column_limit: &wgpu::Buffer) -> wgpu::BindGroup {
        ctx.bind_buffers(
            "grid requests",
            &self.request_layout,
            &[
                &self.requests,
                &self.brick_table,
                &self.slot_brick,
                column_limit,
            ],
        )
    }

    /// Records one viewer set's requests: the voxels (dense) or bricks (sparse, first
    /// `phase`) and then, after [`Self::add_allocation`], the voxels of the allocated
    /// bricks (sparse, second `phase`). Nothing when no slice of the set reads the grid.
    fn add_request_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        set: &ViewerSet,
        phase: RequestPhase,
        ts: &Timestamps,
    ) {
        let pipeline = match (phase, &self.request_pipelines) {
            (RequestPhase::Mark, RequestPipelines::Dense(p)) => p,
            (RequestPhase::Mark, RequestPipelines::Sparse { mark_bricks, .. }) => mark_bricks,
            (RequestPhase::Voxels, RequestPipelines::Sparse { mark_voxels, .. }) => mark_voxels,
            _ => return,
        };
        if set.vol.slices <= set.vol.frustum_slices {
            return;
        }
        let bg = self.request_bind_group(ctx, &set.vol.column_limit);
        dispatch(
            enc,
            ts,
            Stage::GridRequests,
            pipeline,
            &[&set.bind_group, &bg],
            set.vol.groups.columns,
        );
    }

    /// Sparse grid: allocates pool slots to the requested bricks (world work, between
    /// the sets' two request phases).
    fn add_allocation(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        world: &wgpu::BindGroup,
        ts: &Timestamps,
    ) {
        let RequestPipelines::Sparse { allocate, .. } = &self.request_pipelines else {
            return;
        };
        // The allocation reads no column limits: a stand-in fills the binding.
        let bg = self.request_bind_group(ctx, &self.valid);
        dispatch(
            enc,
            ts,
            Stage::GridRequests,
            allocate,
            &[world, &bg],
            dispatch_1d(self.bricks()),
        );
    }

    /// Records the grid update: every needed voxel traces one ray per (stale) light.
    /// The requests it read are cleared after it: with `FLAG_FROXEL_REQUESTS` they were
    /// last frame's froxels', and this frame's froxels make the next frame's.
    pub(crate) fn add_pass(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        world: &wgpu::BindGroup,
        ts: &Timestamps,
    ) -> bool {
        enc.clear_buffer(&self.touched, 0, None);
        // Binding 7 is the list's dispatch arguments for the scan, which writes them;
        // the dispatch that reads them as its arguments may not bind them as storage too,
        // so it binds a buffer no grid pass uses there (a dense grid's brick table).
        let bind = |args: &wgpu::Buffer| {
            ctx.bind_buffers(
                "shared grid",
                &self.layout,
                &[
                    &self.grid,
                    &self.touched,
                    &self.requests,
                    &self.valid,
                    &self.slot_brick,
                    &self.density,
                    &self.listed_groups,
                    args,
                ],
            )
        };
        let bg = bind(&self.listed_args);
        match &self.update {
            Update::Listed(listed) => {
                enc.clear_buffer(&self.listed_args, 0, None);
                let scan = dispatch_1d(listed.count);
                dispatch(
                    enc,
                    ts,
                    Stage::SharedGrid,
                    &listed.scan,
                    &[world, &bg],
                    scan,
                );
                let update_bg = bind(&self.brick_table);
                let args = (&self.listed_args, 0);
                dispatch_indirect(
                    enc,
                    ts,
                    Stage::SharedGrid,
                    &listed.update,
                    &[world, &update_bg],
                    args,
                );
            }
            Update::Whole(pipeline) => dispatch(
                enc,
                ts,
                Stage::SharedGrid,
                pipeline,
                &[world, &bg],
                self.workgroups(),
            ),
        }
        // Read: cleared for this frame's froxels or the next request pass.
        if self.policy.requests() {
            enc.clear_buffer(&self.requests, 0, None);
        }
        true
    }

    /// Bytes of every grid buffer (words or pool, touched bits, requests, validity,
    /// brick table and slots, media density, the listed workgroups).
    pub(crate) fn bytes(&self) -> u64 {
        [
            &self.grid,
            &self.touched,
            &self.requests,
            &self.valid,
            &self.brick_table,
            &self.slot_brick,
            &self.density,
            &self.listed_groups,
            &self.listed_args,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }
}
