//! The validated scene in render space: what the renderers and the truth renderer use.

use super::{CameraPath, MediumKind, Mover, Noise, RenderDefaults, TriangleMesh};
use glam::Vec3;

/// Upper bound on analytic lights in the shadow bitmask (paper 000 §3.1.1: one bit per light).
pub const MAX_LIGHTS: usize = 8;

/// A validated pendulum motion, render space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Swing {
    /// Pivot, render space.
    pub pivot: Vec3,
    /// Unit rotation axis.
    pub axis: Vec3,
    /// Amplitude, radians.
    pub amplitude_rad: f32,
    /// Period, seconds.
    pub period_s: f32,
}

/// What shape of light a [`Light`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LightKind {
    /// A sun: parallel rays along `direction`, no position.
    Directional,
    /// Radiates from `position` in every direction (inverse-square falloff).
    Point,
    /// A point light limited to a cone around `direction`.
    Spot,
}

impl LightKind {
    /// The code of this kind in `Light.kind` of shaders/common.wgsl (`LIGHT_*`).
    pub fn gpu_code(self) -> u32 {
        match self {
            LightKind::Directional => 0,
            LightKind::Point => 1,
            LightKind::Spot => 2,
        }
    }
}

/// A validated light in the form the renderers use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Directional, point or spot.
    pub kind: LightKind,
    /// Position (point/spot), metres, in render space.
    pub position: Vec3,
    /// Unit direction of travel (directional/spot).
    pub direction: Vec3,
    /// colour × intensity.
    pub radiance: Vec3,
    /// cos of the spot's outer half angle (−1 otherwise).
    pub cos_outer: f32,
    /// cos of the spot's inner half angle (−1 otherwise).
    pub cos_inner: f32,
    /// Animation (`None`: the light never moves).
    pub swing: Option<Swing>,
}

impl Light {
    /// The light at scene time `time_s` (itself when it does not move).
    pub fn at(&self, time_s: f32) -> Light {
        let Some(sw) = self.swing else { return *self };
        let phase = (std::f64::consts::TAU * (time_s as f64 / sw.period_s as f64)).sin();
        let rot = glam::Quat::from_axis_angle(sw.axis, sw.amplitude_rad * phase as f32);
        let mut l = *self;
        l.direction = (rot * self.direction).normalize();
        if l.kind != LightKind::Directional {
            l.position = sw.pivot + rot * (self.position - sw.pivot);
        }
        l
    }
}

/// A validated medium in render space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Medium {
    /// Shape.
    pub kind: MediumKind,
    /// σs per channel, m⁻¹.
    pub scattering: Vec3,
    /// σa, m⁻¹.
    pub absorption: f32,
    /// HG g.
    pub g: f32,
    /// Emission.
    pub emission: Vec3,
    /// Bounds min (box: the box; sphere: centre − r; constant/height: the scene's media bounds).
    pub min: Vec3,
    /// Bounds max.
    pub max: Vec3,
    /// Sphere radius, or height falloff length.
    pub radius_or_falloff: f32,
    /// Height-fog base, render space.
    pub base_y: f32,
    /// Noise (frequency 0 = none).
    pub noise: Noise,
    /// The displaced sphere of a volume primitive (kind = volume), `None` otherwise.
    pub volume: Option<Volume>,
}

/// A validated displaced-sphere volume primitive (paper 004 §5.3), render space. Its
/// density is [`crate::scene::density_at`]; its medium's `min`/`max` bound it over its
/// whole path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Volume {
    /// Centre at time 0, render space.
    pub center: glam::Vec3,
    /// Radius before displacement, metres.
    pub radius_m: f32,
    /// Largest displacement as a fraction of the radius (0 = a sphere with a soft edge).
    pub amplitude: f32,
    /// Displacement noise frequency over the unit sphere of directions.
    pub frequency: f32,
    /// Displacement noise octaves.
    pub octaves: u32,
    /// Offset of the displacement noise (from the seed).
    pub noise_offset: glam::Vec3,
    /// Velocity, metres per second.
    pub velocity: glam::Vec3,
    /// Period after which the motion wraps, seconds.
    pub period_s: f32,
}

impl Volume {
    /// The centre at scene time `time_s`: `center + velocity·period_s·(fract(t/period_s
    /// + 1/2) − 1/2)` (common.wgsl `volume_center`).
    pub fn center_at(&self, time_s: f32) -> glam::Vec3 {
        let x = time_s / self.period_s + 0.5;
        self.center + self.velocity * (self.period_s * (x - x.floor() - 0.5))
    }

    /// Radius of the sphere that holds the displaced surface, r·(1 + amplitude).
    pub fn outer_radius_m(&self) -> f32 {
        self.radius_m * (1.0 + self.amplitude)
    }
}

/// A loaded, validated scene in render space.
///
/// Render space is the scene's world space shifted by `origin`, the centre of its bounds,
/// so that a scene placed 10⁵ m from the world origin keeps full f32 precision on the GPU.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name.
    pub name: String,
    /// Render defaults.
    pub render: RenderDefaults,
    /// All triangles (render space).
    pub mesh: TriangleMesh,
    /// Up to 8 lights (render space).
    pub lights: Vec<Light>,
    /// Media (render space).
    pub media: Vec<Medium>,
    /// Camera path (render space).
    pub camera: CameraPath,
    /// World-space position of the render-space origin.
    pub origin: glam::DVec3,
    /// Bounds of all geometry and media, render space.
    pub bounds: (Vec3, Vec3),
    /// Lights dropped because more than 8 were given.
    pub dropped_lights: usize,
    /// Moving occluders (render space, at time 0); not in `mesh`.
    pub movers: Vec<Mover>,
    /// Smoke emitters, validated, `position` in render space (simulated on the CPU by
    /// [`crate::smoke::emitter::particles_at`]; its GPU twin is src/render/smoke_particles.rs).
    pub emitters: Vec<super::EmitterDesc>,
}

impl Scene {
    /// The lights at scene time `time_s` (animated lights moved).
    pub fn lights_at(&self, time_s: f32) -> Vec<Light> {
        self.lights.iter().map(|l| l.at(time_s)).collect()
    }

    /// Whether any light moves over time.
    pub fn has_animated_lights(&self) -> bool {
        self.lights.iter().any(|l| l.swing.is_some())
    }

    /// Render-space bounds of the region that holds media (the shared grid's extent),
    /// or `None` when the scene has no media.
    pub fn media_bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.media.iter();
        let first = it.next()?;
        Some(it.fold((first.min, first.max), |(a, b), m| {
            (a.min(m.min), b.max(m.max))
        }))
    }
}
