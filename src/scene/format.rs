//! The scene file as written (`docs/scene-format.md`): the serde types a TOML scene
//! parses into, with their defaults. Nothing here is checked yet (`super::validate`).

use super::{CameraPath, MoverDesc};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Render defaults a scene recommends; the CLI can override each.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderDefaults {
    /// Near plane of every camera, metres.
    #[serde(default = "default_near")]
    pub near_m: f32,
    /// Far end of the fog volume (and the camera far plane), metres.
    #[serde(default = "default_far")]
    pub far_m: f32,
    /// Shared shadow grid voxel edge, metres.
    #[serde(default = "default_voxel")]
    pub voxel_size_m: f32,
    /// Radiance of the sky seen where no surface is hit.
    #[serde(default = "default_sky")]
    pub sky: [f32; 3],
    /// Uniform ambient radiance lighting surfaces and fog (isotropic).
    #[serde(default = "default_ambient")]
    pub ambient: [f32; 3],
    /// Exposure multiplier before tone mapping.
    #[serde(default = "default_exposure")]
    pub exposure: f32,
}

fn default_near() -> f32 {
    0.1
}
fn default_far() -> f32 {
    64.0
}
/// A scene that names no voxel size gets the renderer's default (defined once, in
/// `src/render/settings.rs`).
fn default_voxel() -> f32 {
    crate::render::Settings::default().voxel_size_m
}
fn default_sky() -> [f32; 3] {
    [0.35, 0.45, 0.6]
}
fn default_ambient() -> [f32; 3] {
    [0.03, 0.035, 0.045]
}
fn default_exposure() -> f32 {
    1.0
}

impl Default for RenderDefaults {
    fn default() -> Self {
        Self {
            near_m: default_near(),
            far_m: default_far(),
            voxel_size_m: default_voxel(),
            sky: default_sky(),
            ambient: default_ambient(),
            exposure: default_exposure(),
        }
    }
}

/// Which side of a mesh's triangles the camera does not see (a mesh's `cull`). Only
/// camera rays skip it: light and shadow rays meet both sides, so a one-sided wall still
/// casts its shadow (the engines' two-sided shadows). The G-buffer culls those faces and
/// `truth`'s camera rays pass through them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Cull {
    /// Both sides are seen (the default).
    #[default]
    None,
    /// The side from which a triangle's corners run clockwise: glTF's back faces, the
    /// inside of a built-in box or cylinder.
    Back,
    /// The side from which they run counter-clockwise: for a file whose winding is the
    /// reverse of glTF's.
    Front,
}

impl Cull {
    /// The cull a scene file names (`none`, `back`, `front`).
    pub fn parse(name: &str) -> Option<Cull> {
        match name {
            "none" => Some(Cull::None),
            "back" => Some(Cull::Back),
            "front" => Some(Cull::Front),
            _ => None,
        }
    }

    /// Whether a camera ray along `dir` meets the culled side of a triangle whose
    /// normal, by the right-hand rule over its corners, is `n` (grazing: seen).
    pub fn hides(self, n: glam::Vec3, dir: glam::Vec3) -> bool {
        match self {
            Cull::None => false,
            Cull::Back => n.dot(dir) > 0.0,
            Cull::Front => n.dot(dir) < 0.0,
        }
    }
}

/// A mesh source: a glTF file or a built-in primitive.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MeshDesc {
    /// Triangles of every mesh in a glTF/GLB file (path relative to the scene file).
    Gltf {
        /// File path.
        path: PathBuf,
        /// Translation applied after scaling, metres.
        #[serde(default)]
        translate: [f32; 3],
        /// Uniform scale.
        #[serde(default = "one")]
        scale: f32,
        /// Diffuse albedo.
        #[serde(default = "grey")]
        albedo: [f32; 3],
        /// The side the camera does not see: `none`, `back` or `front` (`Cull`).
        #[serde(default = "no_cull")]
        cull: String,
    },
    /// Axis-aligned box.
    Box {
        /// Minimum corner, metres.
        min: [f32; 3],
        /// Maximum corner, metres.
        max: [f32; 3],
        /// Diffuse albedo.
        #[serde(default = "grey")]
        albedo: [f32; 3],
        /// The side the camera does not see: `none`, `back` or `front` (`Cull`).
        #[serde(default = "no_cull")]
        cull: String,
    },
    /// Vertical cylinder (a pillar), capped.
    Cylinder {
        /// Centre of the bottom cap, metres.
        base: [f32; 3],
        /// Radius, metres.
        radius: f32,
        /// Height, metres.
        height: f32,
        /// Facets around the axis.
        #[serde(default = "default_segments")]
        segments: u32,
        /// Diffuse albedo.
        #[serde(default = "grey")]
        albedo: [f32; 3],
        /// The side the camera does not see: `none`, `back` or `front` (`Cull`).
        #[serde(default = "no_cull")]
        cull: String,
    },
}

fn no_cull() -> String {
    "none".into()
}
fn one() -> f32 {
    1.0
}
fn grey() -> [f32; 3] {
    [0.6, 0.6, 0.6]
}
fn default_segments() -> u32 {
    16
}

/// An analytic light. Radiometric values are in linear RGB radiance units.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightDesc {
    /// Sun-like light; `direction` is the way the light travels.
    Directional {
        /// Direction of travel (need not be normalised).
        direction: [f32; 3],
        /// Linear RGB colour.
        #[serde(default = "white")]
        color: [f32; 3],
        /// Irradiance multiplier.
        intensity: f32,
        /// Optional pendulum motion (an animated light).
        #[serde(default)]
        swing: Option<SwingDesc>,
    },
    /// Omnidirectional point light with inverse-square falloff.
    Point {
        /// Position, metres.
        position: [f32; 3],
        /// Linear RGB colour.
        #[serde(default = "white")]
        color: [f32; 3],
        /// Intensity (radiance at 1 m).
        intensity: f32,
        /// Optional pendulum motion (an animated light).
        #[serde(default)]
        swing: Option<SwingDesc>,
    },
    /// Spot light: a point light limited to a cone with a smooth edge.
    Spot {
        /// Position, metres.
        position: [f32; 3],
        /// Axis of the cone (way the light travels).
        direction: [f32; 3],
        /// Linear RGB colour.
        #[serde(default = "white")]
        color: [f32; 3],
        /// Intensity (radiance at 1 m on the axis).
        intensity: f32,
        /// Full-intensity half angle, degrees.
        inner_deg: f32,
        /// Zero-intensity half angle, degrees.
        outer_deg: f32,
        /// Optional pendulum motion (an animated light).
        #[serde(default)]
        swing: Option<SwingDesc>,
    },
}

/// Pendulum motion of a light: at time t it is rotated about `axis` through `pivot` by
/// `degrees · sin(2π t / period_s)` (position and direction alike; a directional light
/// only turns). A swinging street lamp, or a sun moving across the sky.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SwingDesc {
    /// Point the light swings about, metres (ignored for directional lights).
    #[serde(default)]
    pub pivot: [f32; 3],
    /// Rotation axis (need not be normalised).
    pub axis: [f32; 3],
    /// Amplitude, degrees (0..=180).
    pub degrees: f32,
    /// Period, seconds (> 0).
    pub period_s: f32,
}

fn white() -> [f32; 3] {
    [1.0, 1.0, 1.0]
}

/// Where a medium exists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MediumKind {
    /// Everywhere inside the scene bounds.
    Constant,
    /// Density `exp(-(y - base_y_m) / falloff_m)` above `base_y_m`, 1 below.
    Height,
    /// An axis-aligned box.
    Box,
    /// A sphere.
    Sphere,
    /// A displaced-sphere volume primitive: written as a `[[volume]]` table
    /// ([`VolumeDesc`]), never as a `[[medium]]` kind.
    #[serde(skip)]
    Volume,
}

/// fbm value-noise modulation of a medium's density.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    /// Base frequency, cycles per metre.
    pub frequency: f32,
    /// Octaves (1..=6).
    #[serde(default = "default_octaves")]
    pub octaves: u32,
    /// Modulation depth 0..=1: density × max(0, 1 + amplitude·(2·fbm − 1)).
    #[serde(default = "one")]
    pub amplitude: f32,
    /// Scroll velocity of the noise field, metres per second.
    #[serde(default)]
    pub wind: [f32; 3],
}

fn default_octaves() -> u32 {
    3
}

/// A participating medium (Hillaire 2015 parameters, DESIGN.md §4).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MediumDesc {
    /// Shape of the medium.
    pub kind: MediumKind,
    /// Scattering coefficient σs per channel, m⁻¹.
    pub scattering: [f32; 3],
    /// Absorption coefficient σa, m⁻¹ (grey).
    #[serde(default)]
    pub absorption: f32,
    /// Henyey-Greenstein asymmetry g, −1 < g < 1.
    #[serde(default)]
    pub g: f32,
    /// Emitted radiance per metre.
    #[serde(default)]
    pub emission: [f32; 3],
    /// Box minimum corner (kind = box).
    pub min: Option<[f32; 3]>,
    /// Box maximum corner (kind = box).
    pub max: Option<[f32; 3]>,
    /// Sphere centre (kind = sphere).
    pub center: Option<[f32; 3]>,
    /// Sphere radius (kind = sphere).
    pub radius: Option<f32>,
    /// Height-fog base (kind = height).
    pub base_y_m: Option<f32>,
    /// Height-fog falloff length (kind = height).
    pub falloff_m: Option<f32>,
    /// Optional noise modulation.
    pub noise: Option<Noise>,
}

/// Radial displacement of a volume's sphere by fbm noise over its directions (paper 004
/// §5.3: the surface lies at r·(1 + amplitude·(2·fbm(frequency·û + offset) − 1)) along
/// the unit direction û from the centre).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Displacement {
    /// Largest displacement as a fraction of the radius, 0..=0.9.
    #[serde(default = "default_displacement_amplitude")]
    pub amplitude: f32,
    /// Noise frequency over the unit sphere of directions (cycles per radius), 0.1..=64.
    #[serde(default = "default_displacement_frequency")]
    pub frequency: f32,
    /// Octaves (1..=6).
    #[serde(default = "default_octaves")]
    pub octaves: u32,
    /// Picks the noise pattern (0..=1000): volumes with different seeds differ in shape.
    #[serde(default)]
    pub seed: u32,
}

fn default_displacement_amplitude() -> f32 {
    0.3
}
fn default_displacement_frequency() -> f32 {
    2.0
}

/// Straight-line motion of a volume that wraps: at time t its centre is
/// `center + velocity · period_s · (fract(t/period_s + 1/2) − 1/2)`, so it passes
/// `center` at t = 0 and travels the segment `center ± velocity·period_s/2` once per period.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeMotion {
    /// Velocity, metres per second.
    pub velocity: [f32; 3],
    /// Time to travel the whole path before wrapping back, seconds (0.001..=1e6).
    pub period_s: f32,
}

/// A displaced-sphere volume primitive (paper 004 §5.3) — a cloud, a fog bank, a dust
/// cloud — with the optical parameters of a [`MediumDesc`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeDesc {
    /// Centre at time 0, metres.
    pub center: [f32; 3],
    /// Radius before displacement, metres (0.001..=100000).
    pub radius: f32,
    /// Scattering coefficient σs per channel at density 1, m⁻¹.
    pub scattering: [f32; 3],
    /// Absorption coefficient σa at density 1, m⁻¹ (grey).
    #[serde(default)]
    pub absorption: f32,
    /// Henyey-Greenstein asymmetry g, −1 < g < 1.
    #[serde(default)]
    pub g: f32,
    /// Emitted radiance per metre at density 1.
    #[serde(default)]
    pub emission: [f32; 3],
    /// Displacement of the surface (none: a sphere with a soft edge).
    pub displacement: Option<Displacement>,
    /// Motion (none: the volume stays put).
    pub motion: Option<VolumeMotion>,
    /// Optional density modulation inside the volume (as a medium's `noise`).
    pub noise: Option<Noise>,
}

/// Where an emitter's particles are born.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum EmitterShape {
    /// All at `position`.
    #[default]
    Point,
    /// Uniformly inside a ball of `radius` about `position`.
    Sphere,
    /// Uniformly on a horizontal disc of `radius` centred on `position` (a chimney mouth).
    Disc,
}

/// A smoke emitter (issue 15): Gaussian particles (001 Eq. 9) born at a steady rate,
/// moving in closed form (`crate::smoke::emitter::particles_at`). Parsed and simulated on
/// the CPU and on the GPU; rendered by every mode.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmitterDesc {
    /// Where particles are born.
    #[serde(default)]
    pub shape: EmitterShape,
    /// Centre of the shape, metres.
    pub position: [f32; 3],
    /// Radius of a `sphere` or `disc`, metres (ignored for a `point`).
    #[serde(default)]
    pub radius: f32,
    /// Particles born per second.
    pub rate_per_s: f32,
    /// How long a particle lives, seconds.
    pub lifetime_s: f32,
    /// Initial velocity of every particle, m/s.
    #[serde(default)]
    pub velocity: [f32; 3],
    /// Speed of each particle's random extra velocity (a uniform direction), m/s.
    #[serde(default)]
    pub spread: f32,
    /// Upward (+y) acceleration, m/s² (negative: the smoke sinks).
    #[serde(default)]
    pub buoyancy: f32,
    /// Drift added to every particle's velocity, m/s.
    #[serde(default)]
    pub wind: [f32; 3],
    /// How fast a particle's falloff distance `u` grows, metres per second.
    #[serde(default)]
    pub growth: f32,
    /// The falloff distance `u` at birth (001 §3.8: `σt = σ e^{−50}` at `u`), metres.
    pub falloff_u: f32,
    /// Scattering coefficient σs at a particle's centre, per channel, m⁻¹.
    pub scattering: [f32; 3],
    /// Absorption coefficient σa at a particle's centre, m⁻¹.
    #[serde(default)]
    pub absorption: f32,
    /// Henyey-Greenstein asymmetry.
    #[serde(default)]
    pub g: f32,
    /// At most this many particles live at once; the oldest go first.
    pub max_particles: u32,
    /// Picks the pattern of birth points and spread directions (0..=1000).
    #[serde(default)]
    pub seed: u32,
}

/// The scene file as written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDesc {
    /// Scene name.
    pub name: String,
    /// Render defaults.
    #[serde(default)]
    pub render: RenderDefaults,
    /// Meshes.
    #[serde(default, rename = "mesh")]
    pub meshes: Vec<MeshDesc>,
    /// Lights (more than 8: the strongest 8 are kept, see [`Scene::lights`](super::Scene::lights)).
    #[serde(default, rename = "light")]
    pub lights: Vec<LightDesc>,
    /// Participating media.
    #[serde(default, rename = "medium")]
    pub media: Vec<MediumDesc>,
    /// Displaced-sphere volume primitives (become media after the `[[medium]]` ones).
    #[serde(default, rename = "volume")]
    pub volumes: Vec<VolumeDesc>,
    /// Moving occluders (spinning boxes).
    #[serde(default, rename = "mover")]
    pub movers: Vec<MoverDesc>,
    /// Smoke emitters (simulated on the GPU, with a CPU twin; rendered by every mode).
    #[serde(default, rename = "emitter")]
    pub emitters: Vec<EmitterDesc>,
    /// Where viewers stand.
    pub camera: CameraPath,
}

/// The name and camera loop of a scene file; every other key is skipped unread.
#[derive(Debug, Deserialize)]
pub(super) struct NameAndCamera {
    /// Scene name.
    pub(super) name: String,
    /// Where viewers stand.
    pub(super) camera: CameraPath,
}
