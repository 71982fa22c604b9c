//! The shared ambient grid (issue 16), with `shaders/ambient_grid.wgsl`: order-2 spherical
//! harmonics of the light arriving at probes on a world-space grid, once per frame for
//! every viewer, replacing the constant `ambient` of the fog, the smoke and the surfaces
//! (`FLAG_SH_AMBIENT`; `ambient_radiance` and `ambient_irradiance` in common.wgsl).
//!
//! What the constant stands for — the sky through the media and past the geometry, light
//! scattered by the media and reflected by the surfaces, every further bounce — is traced
//! from each probe: `RAYS` rays a frame, their radiance projected on SH and folded into the
//! grid as seed 003 accumulates its SH volume (the history clamped to the neighbourhood's
//! estimates, then an exponential average, `ALPHA`), a `STRIDE`th of the probes a frame.
//! The grid reads itself for the next bounce, so the bounces add up over frames. The first
//! frame (and any after the world was invalidated) runs `WARMUP` passes over every probe
//! without the clamp instead, so a single frame, as `eval` renders, starts converged.
//!
//! Probes sit in the scene's bounds (geometry and media), at the centres of cells of
//! `sh_ambient_m` metres, at most `MAX_PROBES` (the spacing grows past it). A probe whose
//! rays nearly all meet geometry within half a spacing is inside it and is left out of the
//! interpolation; a probe is also left out for points outside its free box (how far it
//! sees along each axis), so light does not leak through the walls and floors between
//! probe and point.
//! Movers are not seen by the probes' rays (they do shadow the lights).

use super::{dispatch, Stage, Timestamps};
use crate::gpu::{Access::Read, GpuContext};
use crate::scene::Scene;
use glam::{UVec3, Vec3};

/// Most probes (16 B × 10 each: 5 MiB).
pub(crate) const MAX_PROBES: u32 = 32_768;
/// Passes on the first frame, each weighted `max(1/(k + 1), WARMUP_ALPHA)`: a running
/// mean at first (noise), then an exponential one, so that the last passes, which carry
/// the most bounces, dominate. Each pass adds one bounce through the grid: in the furnace
/// test's fog (τ 3.75 from the centre to the edge) 32 such passes leave the image 4.6
/// 8-bit steps darker than the sky, 64 leave 0.4, and a plain running mean over 16 passes
/// 43.
pub(crate) const WARMUP: u32 = 64;
const WARMUP_ALPHA: f32 = 0.25;
/// Weight of each later frame's estimate.
pub(crate) const ALPHA: f32 = 0.1;
/// After the first frame each frame updates every `STRIDE`th probe (in turn): the grid
/// costs a quarter of a full pass a frame, each probe is refreshed every 4 frames.
pub(crate) const STRIDE: u32 = 4;

/// Where the probes are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AmbientPlan {
    pub min: Vec3,
    pub cell: f32,
    pub dims: UVec3,
}

impl AmbientPlan {
    pub(crate) fn probes(&self) -> u32 {
        self.dims.x * self.dims.y * self.dims.z
    }

    /// Bytes of the grid buffer: history and this frame's estimate, 5 × vec4f a probe.
    pub(crate) fn bytes(&self) -> u64 {
        u64::from(self.probes()) * 2 * 80
    }
}

/// The probes for `scene` every `spacing_m` metres (`None` when it is 0: the constant
/// `ambient`).
pub(crate) fn plan(scene: &Scene, spacing_m: f32) -> Option<AmbientPlan> {
    if spacing_m <= 0.0 {
        return None;
    }
    let (lo, hi) = scene.bounds;
    let extent = (hi - lo).max(Vec3::splat(1e-3));
    // Probes at the cells' centres: none on the bounds' faces, where a floor or an outer
    // wall usually is.
    let dims_for = |cell: f32| (extent / cell).ceil().as_uvec3().max(UVec3::ONE);
    let probes = |d: UVec3| u64::from(d.x) * u64::from(d.y) * u64::from(d.z);
    let mut cell = spacing_m;
    let mut dims = dims_for(cell);
    while probes(dims) > u64::from(MAX_PROBES) {
        cell *= 1.1;
        dims = dims_for(cell);
    }
    // The lattice centred on the bounds.
    let span = (dims.as_vec3() - 1.0) * cell;
    Some(AmbientPlan {
        min: (lo + hi) * 0.5 - span * 0.5,
        cell,
        dims,
    })
}

/// Mirrors `Pass` in ambient_grid.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PassGpu {
    seed: u32,
    alpha: f32,
    clamp_history: u32,
    stride: u32,
    phase: u32,
    _pad: [u32; 3],
}

impl PassGpu {
    /// Warm-up pass `k`: every probe, weight max(1/(k + 1), `WARMUP_ALPHA`), no clamp.
    fn warmup(k: u32) -> PassGpu {
        PassGpu {
            seed: 0x8000_0000 | k,
            alpha: (1.0 / (k + 1) as f32).max(WARMUP_ALPHA),
            clamp_history: 0,
            stride: 1,
            phase: 0,
            _pad: [0; 3],
        }
    }

    /// The pass of frame `frame_index` after the warm-up: a `STRIDE`th of the probes.
    fn steady(frame_index: u32) -> PassGpu {
        PassGpu {
            seed: frame_index,
            alpha: ALPHA,
            clamp_history: 1,
            stride: STRIDE,
            phase: frame_index % STRIDE,
            _pad: [0; 3],
        }
    }
}

/// The trace and blend passes and whether the grid holds a converged history.
pub(crate) struct AmbientGrid {
    plan: AmbientPlan,
    trace: wgpu::ComputePipeline,
    blend: wgpu::ComputePipeline,
    /// The warm-up passes' parameters, then the per-frame pass's (rewritten each frame).
    passes: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    warm: bool,
    /// Workgroups of each pass (a trace and a blend) the last frame recorded: 64 over
    /// every probe on a warm-up frame, one over a `STRIDE`th of them after.
    recorded: Vec<[u32; 3]>,
}

impl AmbientGrid {
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        plan: AmbientPlan,
    ) -> Self {
        let module = super::stage_shader(
            ctx,
            "ambient_grid",
            include_str!("../../shaders/ambient_grid.wgsl"),
        );
        let layout = ctx.storage_layout("ambient_grid pass", &[Read]);
        let layouts = [scene_layout, &layout];
        let passes = (0..=WARMUP)
            .map(|k| {
                let p = if k < WARMUP {
                    PassGpu::warmup(k)
                } else {
                    PassGpu::steady(0)
                };
                let buf = ctx.storage_init("ambient_grid pass", &[p], wgpu::BufferUsages::COPY_DST);
                let bg = ctx.bind_buffers("ambient_grid pass", &layout, &[&buf]);
                (buf, bg)
            })
            .collect();
        AmbientGrid {
            plan,
            trace: ctx.compute_pipeline_entry("ambient_grid trace", &module, &layouts, "trace"),
            blend: ctx.compute_pipeline_entry("ambient_grid blend", &module, &layouts, "blend"),
            passes,
            warm: false,
            recorded: Vec::new(),
        }
    }

    pub(crate) fn plan(&self) -> &AmbientPlan {
        &self.plan
    }

    /// The next frame starts over with the warm-up passes.
    pub(crate) fn invalidate(&mut self) {
        self.warm = false;
    }

    /// Workgroups of a steady frame's pass (a `STRIDE`th of the probes).
    fn steady_workgroups(&self) -> [u32; 3] {
        [self.plan.probes().div_ceil(STRIDE).div_ceil(64), 1, 1]
    }

    /// Workgroups of each pass the last frame recorded (what stats report).
    pub(crate) fn recorded(&self) -> &[[u32; 3]] {
        &self.recorded
    }

    /// Records this frame's passes: the warm-up over every probe on the first frame,
    /// else one trace and one blend over a `STRIDE`th of them, seeded by `frame_index`.
    pub(crate) fn add_passes(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        frame_index: u32,
        ts: &Timestamps,
    ) -> bool {
        let (range, groups) = if self.warm {
            let (buf, _) = &self.passes[WARMUP as usize];
            let p = PassGpu::steady(frame_index);
            ctx.queue.write_buffer(buf, 0, bytemuck::bytes_of(&p));
            (
                WARMUP as usize..WARMUP as usize + 1,
                self.steady_workgroups(),
            )
        } else {
            (0..WARMUP as usize, [self.plan.probes().div_ceil(64), 1, 1])
        };
        self.recorded = vec![groups; range.len()];
        for (_, bg) in &self.passes[range] {
            dispatch(
                enc,
                ts,
                Stage::AmbientGrid,
                &self.trace,
                &[scene, bg],
                groups,
            );
            dispatch(
                enc,
                ts,
                Stage::AmbientGrid,
                &self.blend,
                &[scene, bg],
                groups,
            );
        }
        self.warm = true;
        true
    }
}
