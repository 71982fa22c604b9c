//! The frame's stages as one typed list — the order they run in, their names, which are
//! fog stages and which ray counter each fills — and their GPU timing: every pass gets a
//! pair of timestamps and a stage's time is the sum over its passes, whatever the number
//! of viewer sets it was recorded for.

use super::gpu_types::{C_FRUSTUM_RAYS, C_GRID_RAYS, C_LIGHTING_RAYS, C_SURFACE_RAYS};
use super::StageTiming;
use crate::gpu::GpuContext;
use std::cell::RefCell;

/// A stage of the frame. [`Stage::ALL`] is the order they run in: the world's stages
/// (`World` scope) once per frame before any viewer reads them, the viewers' stages once
/// per viewer set, all sets in one dispatch line each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    /// Rasterise every viewer's G-buffer (one render pass per viewer).
    GBuffer,
    /// Every emitter's live smoke particles placed for this frame (world, issue 15).
    SmokeParticles,
    /// Shared shadow maps of the directional lights (world).
    ShadowMaps,
    /// The media filled into the sparse world media layer (world, paper 004).
    MediaLayer,
    /// Optical depth of the media toward every light (world).
    MediaTransmittance,
    /// The smoke's adaptive volumetric shadow maps, one per light (world, seed 002).
    SmokeShadows,
    /// The shared ambient grid's SH probes traced and accumulated (world, issue 16).
    AmbientGrid,
    /// Hidden-froxel culling and the froxels' voxel requests (per viewer set; the sparse
    /// grid's brick allocation between them is world work).
    GridRequests,
    /// The shared shadow grid (world, paper 000 §3.1.1).
    SharedGrid,
    /// Near-field shadow frustum (paper 000 §3.1.2).
    ShadowFrustum,
    /// In-scattering and extinction per froxel (paper 000 §3.1.3).
    FroxelLighting,
    /// Front-to-back integration along froxel columns (paper 000 §3.1.4).
    VolumeIntegration,
    /// Smoke: every viewer's particles sorted back to front and their tetrahedral proxies
    /// written (one dispatch per set; frames with live particles only; paper 001).
    SmokeProxies,
    /// Smoke: the proxies rasterised and integrated per pixel into each viewer's smoke
    /// layer, with the fog around them (one render pass per viewer; paper 001).
    SmokeRaster,
    /// Surfaces, their shadows and the fog in front of them, tone-mapped into the
    /// sessions' frames.
    Composite,
}

/// Where a stage's work lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// Once per frame for every viewer of every size.
    World,
    /// Once per viewer set, each dispatch covering all of the set's viewers.
    Viewers,
}

impl Stage {
    /// Every stage, in the order the frame records them.
    pub const ALL: [Stage; 15] = [
        Stage::GBuffer,
        Stage::SmokeParticles,
        Stage::ShadowMaps,
        Stage::MediaLayer,
        Stage::MediaTransmittance,
        Stage::SmokeShadows,
        Stage::AmbientGrid,
        Stage::GridRequests,
        Stage::SharedGrid,
        Stage::ShadowFrustum,
        Stage::FroxelLighting,
        Stage::VolumeIntegration,
        Stage::SmokeProxies,
        Stage::SmokeRaster,
        Stage::Composite,
    ];

    /// The name used in stats, `/metrics`, bench and eval reports.
    pub const fn name(self) -> &'static str {
        match self {
            Stage::GBuffer => "gbuffer",
            Stage::SmokeParticles => "smoke_particles",
            Stage::ShadowMaps => "shadow_maps",
            Stage::MediaLayer => "media_layer",
            Stage::MediaTransmittance => "media_transmittance",
            Stage::SmokeShadows => "smoke_shadows",
            Stage::AmbientGrid => "ambient_grid",
            Stage::GridRequests => "grid_requests",
            Stage::SharedGrid => "shared_grid",
            Stage::ShadowFrustum => "shadow_frustum",
            Stage::FroxelLighting => "froxel_lighting",
            Stage::VolumeIntegration => "volume_integration",
            Stage::SmokeProxies => "smoke_proxies",
            Stage::SmokeRaster => "smoke_raster",
            Stage::Composite => "composite",
        }
    }

    /// The stage called `name`.
    pub fn from_name(name: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Whether this is one of the fog stages of paper 000 §3.1 (what its tables time);
    /// the others cost the same in every mode.
    pub const fn is_fog(self) -> bool {
        matches!(
            self,
            Stage::MediaLayer
                | Stage::MediaTransmittance
                | Stage::GridRequests
                | Stage::SharedGrid
                | Stage::ShadowFrustum
                | Stage::FroxelLighting
                | Stage::VolumeIntegration
        )
    }

    /// Whether the stage runs once for the world or once per viewer set.
    pub const fn scope(self) -> Scope {
        match self {
            Stage::ShadowMaps
            | Stage::SmokeParticles
            | Stage::MediaLayer
            | Stage::MediaTransmittance
            | Stage::SmokeShadows
            | Stage::AmbientGrid
            | Stage::SharedGrid => Scope::World,
            _ => Scope::Viewers,
        }
    }

    /// The shadow-ray counter the stage fills and its name in [`super::RayCounts`] and
    /// `/metrics` (`None`: the stage traces no shadow rays).
    pub const fn rays(self) -> Option<(usize, &'static str)> {
        match self {
            Stage::SharedGrid => Some((C_GRID_RAYS, "shared_grid")),
            Stage::ShadowFrustum => Some((C_FRUSTUM_RAYS, "shadow_frustum")),
            Stage::FroxelLighting => Some((C_LIGHTING_RAYS, "froxel_lighting")),
            Stage::Composite => Some((C_SURFACE_RAYS, "surface")),
            _ => None,
        }
    }

    /// The names of the fog stages, in frame order.
    pub fn fog_names() -> impl Iterator<Item = &'static str> {
        Stage::ALL
            .into_iter()
            .filter(|s| s.is_fog())
            .map(Stage::name)
    }
}

/// Passes a frame may time; a pass past this count runs untimed (and says so once).
const MAX_TIMED_PASSES: u32 = 256;

/// Timestamp queries: a begin/end pair per pass, when the adapter has them.
pub(crate) struct Timestamps {
    set: Option<wgpu::QuerySet>,
    resolve: Option<wgpu::Buffer>,
    /// The stage of each timed pass of this frame, in the order they were recorded.
    passes: RefCell<Vec<Stage>>,
}

impl Timestamps {
    pub(crate) fn new(ctx: &GpuContext) -> Timestamps {
        let set = ctx.has_timestamps.then(|| {
            ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: MAX_TIMED_PASSES * 2,
            })
        });
        let resolve = set.as_ref().map(|_| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: MAX_TIMED_PASSES as u64 * 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        });
        Timestamps {
            set,
            resolve,
            passes: RefCell::new(Vec::new()),
        }
    }

    /// The query pair of the next pass of `stage`, if it can be timed.
    fn next_pair(&self, stage: Stage) -> Option<(&wgpu::QuerySet, u32)> {
        let set = self.set.as_ref()?;
        let mut passes = self.passes.borrow_mut();
        let i = passes.len() as u32;
        if i >= MAX_TIMED_PASSES {
            if i == MAX_TIMED_PASSES {
                tracing::warn!(
                    "more than {MAX_TIMED_PASSES} passes in a frame: the rest are not timed"
                );
                passes.push(stage);
            }
            return None;
        }
        passes.push(stage);
        Some((set, i * 2))
    }

    /// Timestamps around one compute pass of `stage`.
    pub(crate) fn compute(&self, stage: Stage) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let (query_set, at) = self.next_pair(stage)?;
        Some(wgpu::ComputePassTimestampWrites {
            query_set,
            beginning_of_pass_write_index: Some(at),
            end_of_pass_write_index: Some(at + 1),
        })
    }

    /// Timestamps around one render pass of `stage`.
    pub(crate) fn render(&self, stage: Stage) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        let (query_set, at) = self.next_pair(stage)?;
        Some(wgpu::RenderPassTimestampWrites {
            query_set,
            beginning_of_pass_write_index: Some(at),
            end_of_pass_write_index: Some(at + 1),
        })
    }

    /// Bytes of this frame's resolved timestamps (0 without timestamp queries).
    pub(crate) fn frame_bytes(&self) -> u64 {
        self.passes.borrow().len().min(MAX_TIMED_PASSES as usize) as u64 * 16
    }

    /// Records the resolve of this frame's queries and their copy to `dst` at `offset`.
    pub(crate) fn resolve(&self, enc: &mut wgpu::CommandEncoder, dst: &wgpu::Buffer, offset: u64) {
        let (Some(set), Some(resolve)) = (&self.set, &self.resolve) else {
            return;
        };
        let bytes = self.frame_bytes();
        if bytes > 0 {
            enc.resolve_query_set(set, 0..(bytes / 8) as u32, resolve, 0);
            enc.copy_buffer_to_buffer(resolve, 0, dst, offset, bytes);
        }
    }

    /// GPU milliseconds per stage that ran, in frame order, from the resolved ticks;
    /// forgets this frame's passes.
    pub(crate) fn stage_ms(&self, ticks: &[u64], period_ns: f32) -> Vec<StageTiming> {
        let passes = std::mem::take(&mut *self.passes.borrow_mut());
        Stage::ALL
            .into_iter()
            .filter(|s| passes.contains(s))
            .map(|stage| StageTiming {
                stage: stage.name().to_string(),
                gpu_ms: passes
                    .iter()
                    .zip(ticks.chunks_exact(2))
                    .filter(|(s, _)| **s == stage)
                    .map(|(_, t)| t[1].saturating_sub(t[0]) as f64 * period_ns as f64 * 1e-6)
                    .sum(),
            })
            .collect()
    }
}

/// Records one compute pass of `stage`: `pipeline` with the scene's (or viewer set's)
/// bind group 0 and the stage's own group 1, over `workgroups`.
pub(crate) fn dispatch(
    enc: &mut wgpu::CommandEncoder,
    ts: &Timestamps,
    stage: Stage,
    pipeline: &wgpu::ComputePipeline,
    groups: &[&wgpu::BindGroup],
    [x, y, z]: [u32; 3],
) {
    compute_pass(enc, ts, stage, pipeline, groups).dispatch_workgroups(x, y, z);
}

/// As [`dispatch`], the workgroups read from `args` (x, y, z u32s at `offset`) when the
/// pass runs.
pub(crate) fn dispatch_indirect(
    enc: &mut wgpu::CommandEncoder,
    ts: &Timestamps,
    stage: Stage,
    pipeline: &wgpu::ComputePipeline,
    groups: &[&wgpu::BindGroup],
    (args, offset): (&wgpu::Buffer, u64),
) {
    compute_pass(enc, ts, stage, pipeline, groups).dispatch_workgroups_indirect(args, offset);
}

/// A compute pass of `stage` with `pipeline` and its bind groups set.
fn compute_pass<'e>(
    enc: &'e mut wgpu::CommandEncoder,
    ts: &Timestamps,
    stage: Stage,
    pipeline: &wgpu::ComputePipeline,
    groups: &[&wgpu::BindGroup],
) -> wgpu::ComputePass<'e> {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(stage.name()),
        timestamp_writes: ts.compute(stage),
    });
    pass.set_pipeline(pipeline);
    for (i, g) in groups.iter().enumerate() {
        pass.set_bind_group(i as u32, *g, &[]);
    }
    pass
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_round_trip() {
        for s in Stage::ALL {
            assert_eq!(Stage::from_name(s.name()), Some(s));
        }
        let mut names: Vec<_> = Stage::ALL.iter().map(|s| s.name()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), Stage::ALL.len());
        assert_eq!(Stage::fog_names().count(), 7);
    }

    #[test]
    fn world_stages_run_before_the_viewer_stages_that_read_them() {
        let at = |s: Stage| Stage::ALL.iter().position(|x| *x == s).unwrap();
        assert!(at(Stage::GridRequests) < at(Stage::SharedGrid));
        assert!(at(Stage::SharedGrid) < at(Stage::FroxelLighting));
        assert!(at(Stage::MediaTransmittance) < at(Stage::FroxelLighting));
        // The transmittance columns read the media layer.
        assert!(at(Stage::MediaLayer) < at(Stage::MediaTransmittance));
        assert!(at(Stage::ShadowMaps) < at(Stage::ShadowFrustum));
        // Froxels and surfaces read the smoke's shadow maps.
        assert!(at(Stage::SmokeShadows) < at(Stage::FroxelLighting));
        // The smoke reads the integrated fog and the maps; the composite reads the smoke.
        assert!(at(Stage::VolumeIntegration) < at(Stage::SmokeProxies));
        assert!(at(Stage::SmokeProxies) < at(Stage::SmokeRaster));
        assert!(at(Stage::SmokeRaster) < at(Stage::Composite));
    }
}
