//! Smoke particles on the GPU (issue 15), with `shaders/smoke_particles.wgsl`: every
//! emitter's live particles at the frame's time, placed by one world pass before anything
//! reads them. The simulation is a pure function of time (src/smoke/emitter.rs, its CPU
//! twin), so `truth`, `bench`, the server and this pass agree: the host picks each
//! emitter's live birth indices (integers, exact in f64), the shader draws each particle's
//! birth point and spread from the same 32-bit hash and moves it in closed form (f32).
//!
//! At most [`MAX_PARTICLES`] live on the GPU at once over all emitters: an emitter gets
//! the smaller of its cap and its steady state `rate × lifetime + 1`, in scene order, and
//! keeps its newest particles when its share is smaller (a warning says so once).

use super::gpu_types::ParticleGpu;
use super::scene_gpu::MAX_PARTICLES;
use super::{dispatch, Stage, Timestamps};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::GpuContext;
use crate::scene::{EmitterDesc, EmitterShape, Scene};
use crate::smoke::emitter::{live_range, particle};
use bytemuck::{Pod, Zeroable};

/// `Emitter` in shaders/smoke_particles.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
struct EmitterGpu {
    position: [f32; 3],
    shape: u32,
    velocity: [f32; 3],
    radius: f32,
    scattering: [f32; 3],
    spread: f32,
    absorption: f32,
    g: f32,
    buoyancy: f32,
    growth: f32,
    falloff_u: f32,
    seed: u32,
    first_index: u32,
    count: u32,
    age_first: f32,
    period: f32,
    out_offset: u32,
    emitter: u32,
}

/// One emitter's live particles this frame: birth indices `first..first + count`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LiveEmitter {
    pub emitter: usize,
    pub first: u64,
    pub count: u32,
}

/// Each emitter's share of the GPU's particles (module header), in scene order.
pub(crate) fn shares(scene: &Scene) -> Vec<u32> {
    let mut left = u64::from(MAX_PARTICLES);
    scene
        .emitters
        .iter()
        .map(|e| {
            let steady = (f64::from(e.rate_per_s) * f64::from(e.lifetime_s)).ceil() as u64 + 1;
            let share = steady.min(u64::from(e.max_particles)).min(left);
            left -= share;
            share as u32
        })
        .collect()
}

/// The live particles of every emitter at `time_s`, each emitter's newest within its
/// share.
pub(crate) fn live(scene: &Scene, time_s: f32) -> Vec<LiveEmitter> {
    scene
        .emitters
        .iter()
        .zip(shares(scene))
        .enumerate()
        .filter_map(|(k, (e, share))| {
            let range = live_range(e, f64::from(time_s))?;
            let newest = *range.end();
            let count = (newest - range.start() + 1).min(u64::from(share));
            (count > 0).then(|| LiveEmitter {
                emitter: k,
                first: newest + 1 - count,
                count: count as u32,
            })
        })
        .collect()
}

/// The CPU twin of the pass (`World::read_particles` reads the GPU's): the particles it writes, in its order (emitter by emitter,
/// oldest first), computed in f64 by src/smoke/emitter.rs.
pub fn cpu_particles(scene: &Scene, time_s: f32) -> Vec<ParticleGpu> {
    let t = f64::from(time_s);
    live(scene, time_s)
        .iter()
        .flat_map(|l| {
            let e = &scene.emitters[l.emitter];
            let rate = f64::from(e.rate_per_s);
            (l.first..l.first + u64::from(l.count)).map(move |i| {
                let p = particle(e, i, t - i as f64 / rate);
                gpu_particle(
                    e,
                    l.emitter,
                    p.index,
                    p.centre.as_vec3(),
                    p.falloff_u_m as f32,
                )
            })
        })
        .collect()
}

fn gpu_particle(
    e: &EmitterDesc,
    emitter: usize,
    index: u64,
    centre: glam::Vec3,
    falloff_u: f32,
) -> ParticleGpu {
    ParticleGpu {
        centre: centre.to_array(),
        falloff_u,
        scattering: e.scattering,
        absorption: e.absorption,
        g: e.g,
        index: index as u32,
        emitter: emitter as u32,
        _pad: 0,
    }
}

/// The simulation pass and its inputs.
pub(crate) struct SmokeParticles {
    pipeline: wgpu::ComputePipeline,
    empty: wgpu::BindGroup,
    bind_group: wgpu::BindGroup,
    emitters: wgpu::Buffer,
    counts: wgpu::Buffer,
    /// Particles placed by the pass recorded next.
    total: u32,
    /// Whether the "share exceeded" warning was given.
    warned: bool,
}

impl SmokeParticles {
    /// `None` for a scene without emitters. `particles`: where the pass writes (the
    /// scene's group-0 particle buffer).
    pub(crate) fn new(
        ctx: &GpuContext,
        scene: &Scene,
        particles: &wgpu::Buffer,
    ) -> Option<SmokeParticles> {
        if scene.emitters.is_empty() {
            return None;
        }
        let module = super::stage_shader(
            ctx,
            "smoke_particles",
            include_str!("../../shaders/smoke_particles.wgsl"),
        );
        let empty_layout = ctx.storage_layout("empty", &[]);
        let layout = ctx.storage_layout("smoke particles", &[Read, ReadWrite, Read]);
        let pipeline = ctx.compute_pipeline("smoke_particles", &module, &[&empty_layout, &layout]);
        let emitters = ctx.storage_init(
            "emitters",
            &vec![EmitterGpu::default(); scene.emitters.len()],
            wgpu::BufferUsages::COPY_DST,
        );
        let counts = ctx.storage_init("emitter counts", &[0u32; 4], wgpu::BufferUsages::COPY_DST);
        let bind_group =
            ctx.bind_buffers("smoke particles", &layout, &[&emitters, particles, &counts]);
        let empty = ctx.bind_buffers("empty", &empty_layout, &[]);
        Some(SmokeParticles {
            pipeline,
            empty,
            bind_group,
            emitters,
            counts,
            total: 0,
            warned: false,
        })
    }

    /// Writes the emitters' live ranges at `time_s`; returns the particles the next pass
    /// places.
    pub(crate) fn prepare(&mut self, ctx: &GpuContext, scene: &Scene, time_s: f32) -> u32 {
        let live = live(scene, time_s);
        let t = f64::from(time_s);
        let mut offset = 0u32;
        let mut gpu = vec![EmitterGpu::default(); scene.emitters.len()];
        for (j, l) in live.iter().enumerate() {
            let e = &scene.emitters[l.emitter];
            let full = live_range(e, t).map_or(0, |r| r.end() - r.start() + 1);
            if u64::from(l.count) < full && !self.warned {
                self.warned = true;
                tracing::warn!(
                    emitter = l.emitter,
                    live = full,
                    kept = l.count,
                    "more smoke particles alive than the GPU holds: the oldest are not drawn"
                );
            }
            let rate = f64::from(e.rate_per_s);
            gpu[j] = EmitterGpu {
                position: e.position,
                shape: match e.shape {
                    EmitterShape::Point => 0,
                    EmitterShape::Sphere => 1,
                    EmitterShape::Disc => 2,
                },
                velocity: (glam::Vec3::from(e.velocity) + glam::Vec3::from(e.wind)).to_array(),
                radius: e.radius,
                scattering: e.scattering,
                spread: e.spread,
                absorption: e.absorption,
                g: e.g,
                buoyancy: e.buoyancy,
                growth: e.growth,
                falloff_u: e.falloff_u,
                seed: e.seed,
                first_index: l.first as u32,
                count: l.count,
                age_first: (t - l.first as f64 / rate) as f32,
                period: (1.0 / rate) as f32,
                out_offset: offset,
                emitter: l.emitter as u32,
            };
            offset += l.count;
        }
        self.total = offset;
        if offset > 0 {
            ctx.queue
                .write_buffer(&self.emitters, 0, bytemuck::cast_slice(&gpu));
            ctx.queue.write_buffer(
                &self.counts,
                0,
                bytemuck::cast_slice(&[live.len() as u32, offset, 0, 0]),
            );
        }
        offset
    }

    /// Workgroups of the pass.
    pub(crate) fn workgroups(&self) -> [u32; 3] {
        [self.total.div_ceil(64), 1, 1]
    }

    /// Records the pass (nothing when no particle is alive).
    pub(crate) fn add_pass(&self, enc: &mut wgpu::CommandEncoder, ts: &Timestamps) -> bool {
        if self.total == 0 {
            return false;
        }
        dispatch(
            enc,
            ts,
            Stage::SmokeParticles,
            &self.pipeline,
            &[&self.empty, &self.bind_group],
            self.workgroups(),
        );
        true
    }
}
