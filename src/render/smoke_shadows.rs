//! The smoke's shadows: adaptive volumetric shadow maps (seed 002), one per light, built
//! once per frame for every viewer (world / light space) by `shaders/smoke_avsm.wgsl`, the
//! GPU twin of [`crate::smoke::avsm`]. Every stage reads them through
//! `smoke_transmittance` in common.wgsl, which `light_transmittance` and
//! `surface_transmittance` multiply into the media's transmittance: the fog (froxel
//! lighting, near field and beyond), the surfaces (composite) and the smoke itself.
//!
//! **Map fitting.** Every frame with particles the CPU takes the bounding sphere of the
//! live particles' proxies (centre ± 1.5 u) and fits each light's map to it, one texel of
//! margin on every side: an orthographic map across the sphere for a directional light
//! (depth from the plane upstream of the sphere), a perspective map of the cone around the
//! sphere for a point or spot light (depth = distance from the light).
//!
//! **Point lights and spots near the smoke**: a single perspective map is used while the
//! sphere lies within a 90° cone from the light (the light at least √2 radii from its
//! centre). Closer — a lamp inside or beside the plume — the light gets a cube: six 90°
//! perspective faces around it (`cube_face` order, one texel of margin), of which only
//! those whose frustum can meet the sphere are built; a lookup reads the face its point
//! falls on. Every point and spot light therefore reserves six maps' nodes, a sun one.
//!
//! **Cache.** The maps are rebuilt only when the live particles (compared byte for byte)
//! or a light changed since the last build; a static scene time and static lights cost no
//! dispatch.
//!
//! **Crossing cap.** A texel keeps at most [`MAX_CROSSINGS`] particles, the nearest by
//! their first inserted node; farther ones along that ray are dropped (they cast no
//! shadow there). Crossings whose optical depth along the whole line is below 10⁻⁴ are
//! not counted: a plume's big old proxies (1.5 u, up to ~9 m) graze most rays with
//! nothing, and used to fill the 64 slots so that the particles further along cast no
//! shadow at all (chimney's lower plume was lit through).

use super::gpu_types::*;
use super::scene_gpu::SceneGpu;
use super::{dispatch, Settings, Stage, Timestamps};
use crate::gpu::{Access, GpuContext};
use crate::scene::Scene;
use glam::Vec3;

/// Most particles one texel's ray inserts (`MAX_CROSSINGS` in smoke_avsm.wgsl).
pub const MAX_CROSSINGS: u32 = 64;
/// A particle's proxy radius in units of its falloff u (`PROXY_RADIUS_PER_U` in WGSL).
const PROXY_RADIUS_PER_U: f32 = 1.5;
/// A point or spot light maps the smoke with one perspective map while the smoke's
/// bounding sphere lies within this half angle's tangent (45°: a 90° cone).
const MAX_TAN_HALF: f32 = 1.0;

/// Maps whose nodes a light reserves: one for a sun, a cube's six for a point or spot light.
fn maps_reserved(directional: bool) -> u32 {
    if directional {
        1
    } else {
        SMOKE_MAPS_PER_LIGHT
    }
}

/// Nodes of every light's maps for `scene` (0: no emitter or no light, nothing allocated).
pub(crate) fn node_count(scene: &Scene, settings: &Settings) -> u64 {
    if super::scene_gpu::particle_capacity(scene) == 0 || scene.lights.is_empty() {
        return 0;
    }
    let maps: u64 = scene
        .lights
        .iter()
        .map(|l| {
            u64::from(maps_reserved(
                l.kind == crate::scene::LightKind::Directional,
            ))
        })
        .sum();
    maps * u64::from(settings.avsm_px).pow(2) * u64::from(settings.avsm_nodes)
}

/// How a light's smoke shadow map projects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SmokeMapKind {
    /// Parallel rays (directional light); depth from the map's plane.
    Orthographic,
    /// Rays from the light (point, spot); depth = distance from the light.
    Perspective,
}

/// One smoke shadow map (a light's only map, or one face of its cube) as read back (for
/// tests and tools).
#[derive(Debug, Clone)]
pub struct SmokeShadowMap {
    /// Orthographic or perspective.
    pub kind: SmokeMapKind,
    /// Orthographic: the centre of the map's plane; perspective: the light.
    pub origin: Vec3,
    /// Direction of the depth axis (the light's travel, or the cone's axis).
    pub axis: Vec3,
    /// The map's first unit axis across `axis` (texel x).
    pub ex: Vec3,
    /// The second (texel y).
    pub ey: Vec3,
    /// Orthographic: half-width in metres; perspective: tangent of the half angle.
    pub extent: f32,
    /// Texels a side.
    pub px: u32,
    /// Nodes per texel.
    pub nodes_per_texel: u32,
    /// `(depth, transmittance)` nodes, texel `(x, y)` at `(x + px·y)·nodes_per_texel`;
    /// unused nodes sit at depth 3e38 with the last node's transmittance.
    pub nodes: Vec<[f32; 2]>,
}

impl SmokeShadowMap {
    /// Texel `(x, y)`'s light ray: its start and unit direction (as `smoke_texel_ray`).
    pub fn texel_ray(&self, x: u32, y: u32) -> (Vec3, Vec3) {
        let e = |i: u32| (i as f32 + 0.5) / self.px as f32 * 2.0 - 1.0;
        let across = self.ex * e(x) + self.ey * e(y);
        match self.kind {
            SmokeMapKind::Orthographic => (self.origin + across * self.extent, self.axis),
            SmokeMapKind::Perspective => {
                (self.origin, (self.axis + across * self.extent).normalize())
            }
        }
    }

    /// Texel `(x, y)`'s nodes.
    pub fn curve(&self, x: u32, y: u32) -> &[[f32; 2]] {
        let n = self.nodes_per_texel as usize;
        let at = (x + self.px * y) as usize * n;
        &self.nodes[at..at + n]
    }
}

/// An orthonormal pair across unit `n`.
fn basis(n: Vec3) -> (Vec3, Vec3) {
    let helper = if n.y.abs() < 0.9 { Vec3::Y } else { Vec3::X };
    let ex = n.cross(helper).normalize();
    (ex, n.cross(ex))
}

/// Forward of cube face `f` (`cube_face` order in common.wgsl: +x, −x, +y, −y, +z, −z).
fn cube_axis(f: usize) -> Vec3 {
    [
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ][f]
}

/// Makes `m` a perspective map from the light at `pos` around unit `axis`, `tan_half` the
/// tangent of its half angle.
fn perspective(m: &mut SmokeMapGpu, pos: Vec3, axis: Vec3, tan_half: f32) {
    let (ex, ey) = basis(axis);
    m.kind = SMOKE_MAP_PERSPECTIVE;
    m.origin = pos.to_array();
    m.axis = axis.to_array();
    m.ex = ex.to_array();
    m.ey = ey.to_array();
    m.extent = tan_half;
}

/// Every light's map records ([`SMOKE_MAPS_PER_LIGHT`] per light) fitted to `particles`
/// (module header), and the lights that got a cube (bit per light).
pub(crate) fn fit(
    particles: &[ParticleGpu],
    lights: &[LightGpu],
    px: u32,
    nodes: u32,
) -> (Vec<SmokeMapGpu>, u32) {
    let per_light = SMOKE_MAPS_PER_LIGHT as usize;
    let mut maps = vec![SmokeMapGpu::default(); lights.len() * per_light];
    let live: Vec<&ParticleGpu> = particles.iter().filter(|p| p.falloff_u > 0.0).collect();
    if live.is_empty() {
        return (maps, 0);
    }
    let (lo, hi) = live.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| {
            let r = Vec3::splat(PROXY_RADIUS_PER_U * p.falloff_u);
            let c = Vec3::from(p.centre);
            (lo.min(c - r), hi.max(c + r))
        },
    );
    let centre = (lo + hi) * 0.5;
    let radius = live
        .iter()
        .map(|p| (Vec3::from(p.centre) - centre).length() + PROXY_RADIUS_PER_U * p.falloff_u)
        .fold(0.0_f32, f32::max)
        * 1.001;
    // One texel of margin on every side.
    let margin = (px as f32 + 2.0) / px as f32;
    let texels = px * px * nodes;
    // A cube face's frustum lies within this angle of its axis (the corner, with margin).
    let face_half_diagonal = (std::f32::consts::SQRT_2 * margin).atan();
    let mut cubes = 0;
    let mut first_map = 0;
    for (i, l) in lights.iter().enumerate() {
        let directional = l.kind == crate::scene::LightKind::Directional.gpu_code();
        let records = &mut maps[i * per_light..(i + 1) * per_light];
        for (f, m) in records.iter_mut().enumerate() {
            m.offset = (first_map + f as u32) * texels;
            m.px = px;
            m.nodes = nodes;
        }
        first_map += maps_reserved(directional);
        if directional {
            let axis = Vec3::from(l.direction).normalize();
            let (ex, ey) = basis(axis);
            let m = &mut records[0];
            m.kind = SMOKE_MAP_ORTHO;
            m.origin = (centre - axis * radius).to_array();
            m.axis = axis.to_array();
            m.ex = ex.to_array();
            m.ey = ey.to_array();
            m.extent = radius * margin;
            continue;
        }
        let pos = Vec3::from(l.position);
        let d = (centre - pos).length();
        let tan_half = if d > radius {
            radius / (d * d - radius * radius).sqrt() * margin
        } else {
            f32::INFINITY
        };
        if tan_half <= MAX_TAN_HALF {
            perspective(&mut records[0], pos, (centre - pos) / d, tan_half);
            continue;
        }
        // A cube: the faces whose frustum can meet the sphere (all of them from inside).
        cubes |= 1 << i;
        let sphere_half_angle = if d > radius {
            (radius / d).asin()
        } else {
            std::f32::consts::PI
        };
        let mut faces = 0;
        for (f, m) in records.iter_mut().enumerate() {
            let axis = cube_axis(f);
            let off_axis = if d > 0.0 {
                ((centre - pos) / d).dot(axis).clamp(-1.0, 1.0).acos()
            } else {
                0.0
            };
            let sees = off_axis <= face_half_diagonal + sphere_half_angle;
            // Face 0 is the cube's header: its geometry is needed by every lookup.
            if !sees && f != 0 {
                continue;
            }
            faces |= u32::from(sees) << f;
            perspective(m, pos, axis, margin);
        }
        records[0].kind = SMOKE_MAP_CUBE;
        records[0].faces = faces;
    }
    (maps, cubes)
}

/// The build stage and what it knows of the maps' freshness.
pub(crate) struct SmokeShadows {
    pipeline: wgpu::ComputePipeline,
    probe: wgpu::ComputePipeline,
    probe_layout: wgpu::BindGroupLayout,
    px: u32,
    nodes: u32,
    lights: u32,
    /// Whether the scene has emitters and lights (else nothing is ever built).
    enabled: bool,
    /// The particles the maps were last built from (None: build at the next chance).
    built_from: Option<Vec<ParticleGpu>>,
    /// This frame rebuilds the maps.
    pending: bool,
    /// Lights whose maps are cubes (bit per light), to log when that changes.
    cubes: u32,
}

impl SmokeShadows {
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        scene: &Scene,
        settings: &Settings,
    ) -> Self {
        let module = super::stage_shader(
            ctx,
            "smoke_avsm",
            include_str!("../../shaders/smoke_avsm.wgsl"),
        );
        let probe_layout = ctx.storage_layout("smoke probe", &[Access::Read, Access::ReadWrite]);
        SmokeShadows {
            pipeline: ctx.compute_pipeline("smoke_avsm", &module, &[scene_layout]),
            probe: ctx.compute_pipeline_entry(
                "smoke probe",
                &module,
                &[scene_layout, &probe_layout],
                "probe",
            ),
            probe_layout,
            px: settings.avsm_px,
            nodes: settings.avsm_nodes,
            lights: scene.lights.len() as u32,
            enabled: node_count(scene, settings) > 0,
            built_from: None,
            pending: false,
            cubes: 0,
        }
    }

    /// Forgets the maps: the next frame with particles rebuilds them.
    pub(crate) fn invalidate(&mut self) {
        self.built_from = None;
    }

    /// Decides whether this frame rebuilds the maps (the live `particles` or a light
    /// changed: `dirty_lights`, bit per light) and, if so, fits and uploads them.
    pub(crate) fn prepare(
        &mut self,
        ctx: &GpuContext,
        gpu: &SceneGpu,
        particles: &[ParticleGpu],
        lights: &[LightGpu],
        dirty_lights: u32,
    ) {
        self.pending = false;
        if !self.enabled || particles.is_empty() {
            return;
        }
        let same = self.built_from.as_deref().is_some_and(|b| {
            bytemuck::cast_slice::<_, u8>(b) == bytemuck::cast_slice::<_, u8>(particles)
        });
        if same && dirty_lights == 0 {
            return;
        }
        let (maps, cubes) = fit(particles, lights, self.px, self.nodes);
        if cubes != self.cubes {
            tracing::debug!(
                cubes = format!("{cubes:#b}"),
                "smoke shadows: lights mapped with a cube (the smoke within √2 radii of them)"
            );
            self.cubes = cubes;
        }
        ctx.queue
            .write_buffer(&gpu.smoke_maps, 0, bytemuck::cast_slice(&maps));
        self.built_from = Some(particles.to_vec());
        self.pending = true;
    }

    pub(crate) fn workgroups(&self) -> [u32; 3] {
        [
            self.px.div_ceil(8),
            self.px.div_ceil(8),
            self.lights * SMOKE_MAPS_PER_LIGHT,
        ]
    }

    /// Records the build when `prepare` asked for one; false (nothing recorded) otherwise.
    pub(crate) fn add_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        ts: &Timestamps,
    ) -> bool {
        if !self.pending {
            return false;
        }
        dispatch(
            enc,
            ts,
            Stage::SmokeShadows,
            &self.pipeline,
            &[scene],
            self.workgroups(),
        );
        true
    }

    /// Reads every light's maps back: none, its one map, or its cube's built faces.
    pub(crate) fn read(
        &self,
        ctx: &GpuContext,
        gpu: &SceneGpu,
    ) -> anyhow::Result<Vec<Vec<SmokeShadowMap>>> {
        if !self.enabled {
            return Ok(vec![Vec::new(); self.lights as usize]);
        }
        let headers: Vec<SmokeMapGpu> =
            bytemuck::pod_collect_to_vec(&ctx.read_buffer(&gpu.smoke_maps)?);
        let nodes: Vec<[f32; 2]> =
            bytemuck::pod_collect_to_vec(&ctx.read_buffer(&gpu.smoke_nodes)?);
        let map = |h: &SmokeMapGpu, kind| {
            let at = h.offset as usize;
            let len = (h.px * h.px * h.nodes) as usize;
            SmokeShadowMap {
                kind,
                origin: h.origin.into(),
                axis: h.axis.into(),
                ex: h.ex.into(),
                ey: h.ey.into(),
                extent: h.extent,
                px: h.px,
                nodes_per_texel: h.nodes,
                nodes: nodes[at..at + len].to_vec(),
            }
        };
        Ok(headers
            .chunks(SMOKE_MAPS_PER_LIGHT as usize)
            .take(self.lights as usize)
            .map(|records| match records[0].kind {
                SMOKE_MAP_ORTHO => vec![map(&records[0], SmokeMapKind::Orthographic)],
                SMOKE_MAP_PERSPECTIVE => vec![map(&records[0], SmokeMapKind::Perspective)],
                SMOKE_MAP_CUBE => records
                    .iter()
                    .enumerate()
                    .filter(|(f, _)| records[0].faces & (1 << f) != 0)
                    .map(|(_, h)| map(h, SmokeMapKind::Perspective))
                    .collect(),
                other => {
                    debug_assert_eq!(other, SMOKE_MAP_NONE, "unknown smoke map kind");
                    Vec::new()
                }
            })
            .collect())
    }

    /// `smoke_transmittance(light, p)` evaluated on the GPU for every `(light, p)`, with
    /// the maps and particles of the last frame (for tests).
    pub(crate) fn probe(
        &self,
        ctx: &GpuContext,
        scene: &wgpu::BindGroup,
        points: &[(u32, Vec3)],
    ) -> anyhow::Result<Vec<f32>> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let data: Vec<[f32; 4]> = points
            .iter()
            .map(|(l, p)| [p.x, p.y, p.z, *l as f32])
            .collect();
        let input = ctx.storage_init("smoke probe points", &data, wgpu::BufferUsages::empty());
        let output = ctx.storage(
            "smoke probe out",
            points.len() as u64 * 4,
            wgpu::BufferUsages::empty(),
        )?;
        let group = ctx.bind_buffers("smoke probe", &self.probe_layout, &[&input, &output]);
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("smoke probe"),
            });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("smoke probe"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.probe);
            pass.set_bind_group(0, scene, &[]);
            pass.set_bind_group(1, &group, &[]);
            pass.dispatch_workgroups((points.len() as u32).div_ceil(64), 1, 1);
        }
        ctx.submit(enc);
        let out: Vec<f32> = bytemuck::pod_collect_to_vec(&ctx.read_buffer(&output)?);
        Ok(out[..points.len()].to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn particle(c: [f32; 3], u: f32) -> ParticleGpu {
        ParticleGpu {
            centre: c,
            falloff_u: u,
            scattering: [1.0; 3],
            ..Default::default()
        }
    }

    fn light(kind: u32, position: [f32; 3], direction: [f32; 3]) -> LightGpu {
        LightGpu {
            position,
            kind,
            direction,
            ..Default::default()
        }
    }

    #[test]
    fn maps_fit_the_smoke_and_close_lights_get_cubes() {
        let ps = [
            particle([0.0, 2.0, 0.0], 0.5),
            particle([1.0, 2.0, 0.0], 0.5),
        ];
        let lights = [
            light(0, [0.0; 3], [0.0, -1.0, 0.0]),
            light(1, [0.5, 10.0, 0.0], [0.0, -1.0, 0.0]),
            light(2, [0.5, 2.5, 0.0], [0.0, -1.0, 0.0]),
            light(1, [1.9, 2.0, 0.0], [0.0, -1.0, 0.0]),
        ];
        let (maps, cubes) = fit(&ps, &lights, 32, 8);
        let per = SMOKE_MAPS_PER_LIGHT as usize;
        assert_eq!(maps.len(), 4 * per);
        assert_eq!(cubes, 0b1100);
        assert_eq!(maps[0].kind, SMOKE_MAP_ORTHO);
        assert!(maps[1..per].iter().all(|m| m.kind == SMOKE_MAP_NONE));
        assert_eq!(maps[per].kind, SMOKE_MAP_PERSPECTIVE);
        // A sun reserves one map, a point or spot light six.
        assert_eq!(maps[per].offset, 32 * 32 * 8);
        assert_eq!(maps[2 * per].offset, 7 * 32 * 32 * 8);
        // Inside the smoke's sphere: every face.
        assert_eq!(maps[2 * per].kind, SMOKE_MAP_CUBE);
        assert_eq!(maps[2 * per].faces, 0b11_1111);
        // Beside it (on +x, the smoke towards −x): not the +x face.
        let beside = &maps[3 * per..4 * per];
        assert_eq!(beside[0].kind, SMOKE_MAP_CUBE);
        assert_eq!(beside[0].faces & 1, 0, "{:#b}", beside[0].faces);
        assert_ne!(beside[0].faces & 0b10, 0);
        // Every proxy lies inside the orthographic map's square and depth ≥ 0.
        let m = maps[0];
        for p in &ps {
            let d = Vec3::from(p.centre) - Vec3::from(m.origin);
            let r = 1.5 * p.falloff_u;
            assert!(d.dot(Vec3::from(m.ex)).abs() + r <= m.extent);
            assert!(d.dot(Vec3::from(m.ey)).abs() + r <= m.extent);
            assert!(d.dot(Vec3::from(m.axis)) - r >= 0.0);
        }
        // Every direction from a cube's light lands inside the face `cube_face` picks.
        let cube = &maps[2 * per..3 * per];
        for k in 0..2000 {
            let t = k as f32 * 0.618_034;
            let z = (k as f32 / 1000.0) - 1.0;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = t * std::f32::consts::TAU;
            let dir = Vec3::new(r * phi.cos(), z, r * phi.sin());
            let a = dir.abs();
            let f = if a.x >= a.y && a.x >= a.z {
                usize::from(dir.x < 0.0)
            } else if a.y >= a.z {
                2 + usize::from(dir.y < 0.0)
            } else {
                4 + usize::from(dir.z < 0.0)
            };
            let m = &cube[f];
            let along = dir.dot(Vec3::from(m.axis));
            assert!(along > 0.0);
            let e = Vec3::new(dir.dot(Vec3::from(m.ex)), dir.dot(Vec3::from(m.ey)), 0.0)
                / (along * m.extent);
            assert!(e.x.abs() < 1.0 && e.y.abs() < 1.0, "{dir}: face {f}, {e}");
        }
        let (none, _) = fit(&[], &lights, 32, 8);
        assert!(none.iter().all(|m| m.kind == SMOKE_MAP_NONE));
    }
}
