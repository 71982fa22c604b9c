//! Shared media transmittance toward each light, with `shaders/media_transmittance.wgsl`:
//! world / light-space work, once per frame for every viewer, cached while the media and
//! the light are static.
//!
//! Light reaching a point in the fog or a surface is dimmed by the media on the way,
//! T = exp(−∫σt) along the shadow ray (DESIGN.md §4). `reference` marches that integral
//! per froxel and pixel; `shared` keeps one volume of T per light instead, separate from
//! the opaque visibility of the shadow grid and maps (so wind moving the media refills
//! this volume and traces no opaque ray, and a mover re-traces grid bits without touching
//! it). Every froxel and surface reads it with one trilinear lookup per light.
//!
//! Layout per light (`LightMedia` in common.wgsl): columns of nodes along which the
//! optical depth is propagated away from the light (paper 004's light-aligned columns,
//! with Beer-Lambert exp(−τ)). A directional light's columns are parallel to it and tile
//! the plane across the media's bounding sphere (so the volume fits whatever way the
//! light turns); a point or spot light's columns are rays from the light, one per texel
//! of a `POINT_MAP_TEXELS`² map of directions, from the nearest to the farthest point of
//! that sphere: an octahedral map of every direction for a light in or near the media,
//! a perspective map of the cone around the sphere for a light far from it (a lamp 10 km
//! away still gets all its texels on the media).

use super::gpu_types::LightMediaGpu;
use super::{dispatch, Stage, Timestamps};
use crate::gpu::GpuContext;
use crate::scene::{LightKind, Scene};
use glam::Vec3;

/// Texels a side of a point or spot light's map of directions.
const POINT_MAP_TEXELS: u32 = 96;
/// Most nodes of one light's volume (2 MiB of f32): past it the spacing grows.
const MAX_NODES_PER_LIGHT: u32 = 1 << 19;
/// A point or spot light farther than this many bounding-sphere radii from the media's
/// centre maps only the cone around the sphere (perspective), not every direction.
const PERSPECTIVE_BEYOND_RADII: f32 = 1.5;

/// The volumes' layout for `scene`: one header per light (all with `nodes == 0` when
/// `spacing_m` is 0 or the scene has no media: transmittance is then marched).
pub(crate) fn plan(scene: &Scene, spacing_m: f32) -> Vec<LightMediaGpu> {
    let Some((lo, hi)) = scene.media_bounds().filter(|_| spacing_m > 0.0) else {
        return vec![LightMediaGpu::default(); scene.lights.len()];
    };
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let mut offset = 0;
    scene
        .lights
        .iter()
        .map(|l| {
            let mut v = LightMediaGpu {
                centre: centre.to_array(),
                radius,
                offset,
                ..Default::default()
            };
            if l.kind == LightKind::Directional {
                // Columns across the bounding sphere, nodes along the light through it.
                // Counted in u64: media kilometres wide at the default spacing need
                // more than 2³² nodes before the spacing grows.
                let fit = |s: f32| (2.0 * radius / s).ceil() as u32 + 1;
                let mut s = spacing_m;
                while u64::from(fit(s)).pow(3) > u64::from(MAX_NODES_PER_LIGHT) {
                    s *= 1.05;
                }
                v.dims = [fit(s); 3];
                v.spacing = s;
            } else {
                // Rays from the light through the sphere, wherever a swinging lamp goes.
                let reach = l
                    .swing
                    .map_or(0.0, |sw| (l.position - sw.pivot).length() * 2.0);
                let d = (l.position - centre).length();
                let closest = d - reach;
                if closest > PERSPECTIVE_BEYOND_RADII * radius {
                    // The cone around the sphere, one texel wider on every side.
                    let n = POINT_MAP_TEXELS as f32;
                    v.tan_half =
                        radius / (closest * closest - radius * radius).sqrt() * (n + 2.0) / n;
                    v.near = closest - radius;
                }
                let far = d + reach + radius;
                let columns = POINT_MAP_TEXELS * POINT_MAP_TEXELS;
                let depth = (((far - v.near) / spacing_m).ceil() as u32 + 1)
                    .clamp(2, MAX_NODES_PER_LIGHT / columns);
                v.dims = [POINT_MAP_TEXELS, POINT_MAP_TEXELS, depth];
                v.spacing = (far - v.near) / (depth - 1) as f32;
            }
            v.nodes = v.dims.iter().product();
            offset += v.nodes;
            v
        })
        .collect()
}

/// Whether any medium moves over time (noise carried by wind, a moving volume): then
/// every light's volume is refilled every frame.
pub(crate) fn media_animated(scene: &Scene) -> bool {
    scene.media.iter().any(|m| {
        (m.noise.frequency > 0.0 && Vec3::from(m.noise.wind) != Vec3::ZERO)
            || m.volume.is_some_and(|v| v.velocity != Vec3::ZERO)
    })
}

/// The fill stage and what it knows of the volumes' freshness.
pub(crate) struct MediaTransmittance {
    pipeline: wgpu::ComputePipeline,
    /// Columns of the widest volume (x, y of the dispatch).
    max_columns: [u32; 2],
    lights: u32,
    has_volumes: bool,
    animated: bool,
    /// Lights whose volume holds the current media (bit per light).
    filled: u32,
}

impl MediaTransmittance {
    pub(crate) fn new(
        ctx: &GpuContext,
        scene_layout: &wgpu::BindGroupLayout,
        scene: &Scene,
        plan: &[LightMediaGpu],
    ) -> Self {
        let module = super::stage_shader(
            ctx,
            "media_transmittance",
            include_str!("../../shaders/media_transmittance.wgsl"),
        );
        let max_columns = plan
            .iter()
            .fold([0, 0], |[x, y], v| [x.max(v.dims[0]), y.max(v.dims[1])]);
        MediaTransmittance {
            pipeline: ctx.compute_pipeline("media_transmittance", &module, &[scene_layout]),
            max_columns,
            lights: plan.len() as u32,
            has_volumes: plan.iter().any(|v| v.nodes > 0),
            animated: media_animated(scene),
            filled: 0,
        }
    }

    /// Forgets which volumes are filled: the next frame refills them all.
    pub(crate) fn invalidate(&mut self) {
        self.filled = 0;
    }

    /// Whether the frame reads transmittance from the volumes (`FLAG_MEDIA_T`).
    pub(crate) fn in_use(&self) -> bool {
        self.has_volumes
    }

    /// The lights to refill this frame, given the lights that changed since the last
    /// frame: all of them while wind moves the media, none once a static scene is filled.
    pub(crate) fn dirty(&mut self, changed_lights: u32) -> u32 {
        if !self.has_volumes {
            return 0;
        }
        let all = (1u32 << self.lights) - 1;
        let dirty = if self.animated {
            all
        } else {
            (all & !self.filled) | changed_lights
        };
        self.filled = all;
        dirty
    }

    pub(crate) fn workgroups(&self) -> [u32; 3] {
        [
            self.max_columns[0].div_ceil(8),
            self.max_columns[1].div_ceil(8),
            self.lights,
        ]
    }

    /// Records the fill of the `dirty` lights' volumes; false (nothing recorded) when
    /// none is dirty.
    pub(crate) fn add_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        scene: &wgpu::BindGroup,
        dirty: u32,
        ts: &Timestamps,
    ) -> bool {
        if dirty == 0 {
            return false;
        }
        dispatch(
            enc,
            ts,
            Stage::MediaTransmittance,
            &self.pipeline,
            &[scene],
            self.workgroups(),
        );
        true
    }
}

/// Bytes of the volumes in `plan`.
pub(crate) fn bytes(plan: &[LightMediaGpu]) -> u64 {
    plan.iter().map(|v| v.nodes as u64 * 4).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volumes_fit_the_budget_and_do_not_overlap() {
        let scene = Scene::load("street").unwrap();
        let p = plan(&scene, 0.5);
        assert_eq!(p.len(), scene.lights.len());
        let mut next = 0;
        for (v, l) in p.iter().zip(&scene.lights) {
            assert_eq!(v.offset, next);
            assert_eq!(v.nodes, v.dims.iter().product::<u32>());
            assert!(v.nodes <= MAX_NODES_PER_LIGHT);
            // The last node reaches past every corner of the media.
            let (lo, hi) = scene.media_bounds().unwrap();
            let far = (l.position - (lo + hi) * 0.5).length() + (hi - lo).length() * 0.5;
            assert!(
                v.near + v.spacing * (v.dims[2] - 1) as f32 >= far * 0.999,
                "{v:?}"
            );
            next += v.nodes;
        }
        let sun = plan(&Scene::load("colonnade").unwrap(), 0.5);
        assert!(
            sun[0].spacing >= 0.5 && sun[0].spacing < 0.6,
            "{:?}",
            sun[0]
        );
        assert!(plan(&scene, 0.0).iter().all(|v| v.nodes == 0));
    }
}
