//! Scene description: meshes, analytic lights, participating media and a camera path.
//!
//! Scenes are TOML files (see `scenes/*.toml` and `docs/scene-format.md`). Everything a
//! user writes is validated on load; errors name the field and the offending value.

mod builtin;
mod bvh;
mod camera;
mod gltf_load;
mod media;
mod mesh;
mod mover;

pub use builtin::{builtin_names, builtin_scene};
pub use bvh::{intersect_triangle, Bvh, GpuBvhNode, GpuTriangle, Ray, MAX_BVH_DEPTH};
pub use camera::{Camera, CameraPath};
pub use media::{density_at, hg_phase, sample_media, MediumSample};
pub use mesh::TriangleMesh;
pub use mover::{movers_mesh_at, Mover, MoverDesc};

use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Upper bound on analytic lights in the shadow bitmask (paper 000 §3.1.1: one bit per light).
pub const MAX_LIGHTS: usize = 8;

/// An error in a scene description, naming the field and value at fault.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// The path that failed.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// TOML syntax or a type mismatch; the parser names line, column and field.
    #[error("scene file {path}: {message}")]
    Parse {
        /// The scene file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A value that parsed but makes no sense.
    #[error("scene field `{field}` = {value}: {reason}")]
    Invalid {
        /// Dotted path of the field, e.g. `media[1].absorption`.
        field: String,
        /// The offending value as written.
        value: String,
        /// What is expected instead.
        reason: String,
    },
    /// A glTF file could not be loaded.
    #[error("glTF {path}: {message}")]
    Gltf {
        /// The glTF path.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// No built-in scene and no file of that name.
    #[error("unknown scene `{0}`: not a built-in scene ({names}) and no such file", names = builtin_names().join(", "))]
    Unknown(String),
}

pub(crate) fn invalid(
    field: impl Into<String>,
    value: impl std::fmt::Debug,
    reason: &str,
) -> SceneError {
    SceneError::Invalid {
        field: field.into(),
        value: format!("{value:?}"),
        reason: reason.to_string(),
    }
}

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
fn default_voxel() -> f32 {
    0.25
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
    },
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
    /// Lights (more than 8: the strongest 8 are kept, see [`Scene::lights`]).
    #[serde(default, rename = "light")]
    pub lights: Vec<LightDesc>,
    /// Participating media.
    #[serde(default, rename = "medium")]
    pub media: Vec<MediumDesc>,
    /// Moving occluders (spinning boxes).
    #[serde(default, rename = "mover")]
    pub movers: Vec<MoverDesc>,
    /// Where viewers stand.
    pub camera: CameraPath,
}

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

/// A validated light in the form the renderers use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// 0 directional, 1 point, 2 spot.
    pub kind: u32,
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
        if l.kind != 0 {
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

    /// Loads a built-in scene by name, a `.toml` scene file, or a `.glb`/`.gltf` file
    /// (which gets a default sun, fog and camera path around its bounds).
    pub fn load(name_or_path: &str) -> Result<Scene, SceneError> {
        if let Some(text) = builtin_scene(name_or_path) {
            let desc: SceneDesc = toml::from_str(text).map_err(|e| SceneError::Parse {
                path: PathBuf::from(format!("<built-in {name_or_path}>")),
                message: e.to_string(),
            })?;
            return Scene::from_desc(desc, Path::new("."));
        }
        let path = Path::new(name_or_path);
        if !path.exists() {
            return Err(SceneError::Unknown(name_or_path.to_string()));
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        if ext == "glb" || ext == "gltf" {
            return Scene::from_desc(gltf_load::default_desc_for(path)?, Path::new("."));
        }
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Scene::from_toml(&text, path)
    }

    /// Parses and validates TOML text; relative mesh paths resolve against `path`'s folder.
    pub fn from_toml(text: &str, path: &Path) -> Result<Scene, SceneError> {
        let desc: SceneDesc = toml::from_str(text).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        Scene::from_desc(desc, base)
    }

    /// Validates a description and moves it to render space.
    pub fn from_desc(desc: SceneDesc, base_dir: &Path) -> Result<Scene, SceneError> {
        validate_render(&desc.render)?;
        let mesh = mesh::build_meshes(&desc.meshes, base_dir)?;
        let lights_world = validate_lights(&desc.lights)?;
        validate_media(&desc.media)?;
        desc.camera.validate()?;

        // World bounds of geometry and bounded media; the camera path if nothing else.
        let mut lo = glam::DVec3::splat(f64::INFINITY);
        let mut hi = glam::DVec3::splat(f64::NEG_INFINITY);
        let mut grow = |p: glam::DVec3| {
            lo = lo.min(p);
            hi = hi.max(p);
        };
        for v in &mesh.world_positions {
            grow(*v);
        }
        for m in &desc.media {
            if let Some((a, b)) = media::bounded_extent(m) {
                grow(a.as_dvec3());
                grow(b.as_dvec3());
            }
        }
        for p in &desc.camera.path {
            grow(Vec3::from(*p).as_dvec3());
        }
        // Movers, validated in world space (origin 0) to find their reach.
        for (i, m) in desc.movers.iter().enumerate() {
            let (a, b) = Mover::new(i, m, glam::DVec3::ZERO)?.reach();
            grow(a.as_dvec3());
            grow(b.as_dvec3());
        }
        let origin = ((lo + hi) * 0.5).round();
        let to_render = |p: [f32; 3]| (Vec3::from(p).as_dvec3() - origin).as_vec3();
        let bounds = ((lo - origin).as_vec3(), (hi - origin).as_vec3());

        let mesh = mesh.into_render_space(origin);
        let (lights, dropped_lights) = rank_lights(lights_world, origin, bounds);
        let media = desc
            .media
            .iter()
            .map(|m| media::to_render_space(m, &to_render, bounds))
            .collect();
        let camera = desc.camera.translated(&to_render);
        let movers = desc
            .movers
            .iter()
            .enumerate()
            .map(|(i, m)| Mover::new(i, m, origin))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Scene {
            movers,
            name: desc.name,
            render: desc.render,
            mesh,
            lights,
            media,
            camera,
            origin,
            bounds,
            dropped_lights,
        })
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

pub(crate) fn check_finite(field: &str, v: &[f32]) -> Result<(), SceneError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(invalid(field, v, "must be a finite number"))
    }
}

pub(crate) fn check_range(
    field: &str,
    v: f32,
    lo: f32,
    hi: f32,
    what: &str,
) -> Result<(), SceneError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(invalid(field, v, what))
    }
}

fn validate_render(r: &RenderDefaults) -> Result<(), SceneError> {
    check_range(
        "render.near_m",
        r.near_m,
        1e-4,
        1e3,
        "must be between 0.0001 and 1000 m",
    )?;
    check_range(
        "render.far_m",
        r.far_m,
        r.near_m * 1.01,
        1e5,
        "must be greater than near_m and at most 100000 m",
    )?;
    check_range(
        "render.voxel_size_m",
        r.voxel_size_m,
        0.01,
        100.0,
        "must be between 0.01 and 100 m",
    )?;
    check_finite("render.sky", &r.sky)?;
    check_finite("render.ambient", &r.ambient)?;
    for (f, v) in [("render.sky", r.sky), ("render.ambient", r.ambient)] {
        if v.iter().any(|x| *x < 0.0) {
            return Err(invalid(f, v, "must not be negative"));
        }
    }
    check_range("render.exposure", r.exposure, 1e-6, 1e6, "must be positive")
}

fn validate_lights(lights: &[LightDesc]) -> Result<Vec<(Light, glam::DVec3)>, SceneError> {
    let mut out = Vec::with_capacity(lights.len());
    for (i, l) in lights.iter().enumerate() {
        let f = |name: &str| format!("light[{i}].{name}");
        let unit = |name: &str, d: [f32; 3]| -> Result<Vec3, SceneError> {
            check_finite(&f(name), &d)?;
            Vec3::from(d)
                .try_normalize()
                .ok_or_else(|| invalid(f(name), d, "must be a non-zero vector"))
        };
        let radiance = |color: [f32; 3], intensity: f32| -> Result<Vec3, SceneError> {
            check_finite(&f("color"), &color)?;
            if color.iter().any(|c| *c < 0.0) {
                return Err(invalid(f("color"), color, "must not be negative"));
            }
            check_range(
                &f("intensity"),
                intensity,
                0.0,
                1e9,
                "must be between 0 and 1e9",
            )?;
            Ok(Vec3::from(color) * intensity)
        };
        let light = match *l {
            LightDesc::Directional {
                direction,
                color,
                intensity,
                ..
            } => (
                Light {
                    kind: 0,
                    position: Vec3::ZERO,
                    direction: unit("direction", direction)?,
                    radiance: radiance(color, intensity)?,
                    cos_outer: -1.0,
                    cos_inner: -1.0,
                    swing: None,
                },
                glam::DVec3::ZERO,
            ),
            LightDesc::Point {
                position,
                color,
                intensity,
                ..
            } => {
                check_finite(&f("position"), &position)?;
                (
                    Light {
                        kind: 1,
                        position: Vec3::ZERO,
                        direction: Vec3::Y,
                        radiance: radiance(color, intensity)?,
                        cos_outer: -1.0,
                        cos_inner: -1.0,
                        swing: None,
                    },
                    Vec3::from(position).as_dvec3(),
                )
            }
            LightDesc::Spot {
                position,
                direction,
                color,
                intensity,
                inner_deg,
                outer_deg,
                ..
            } => {
                check_finite(&f("position"), &position)?;
                check_range(
                    &f("outer_deg"),
                    outer_deg,
                    0.1,
                    179.0,
                    "must be between 0.1 and 179 degrees",
                )?;
                check_range(
                    &f("inner_deg"),
                    inner_deg,
                    0.0,
                    outer_deg - 0.01,
                    "must be at least 0 and smaller than outer_deg",
                )?;
                (
                    Light {
                        kind: 2,
                        position: Vec3::ZERO,
                        direction: unit("direction", direction)?,
                        radiance: radiance(color, intensity)?,
                        cos_outer: outer_deg.to_radians().cos(),
                        cos_inner: inner_deg.to_radians().cos(),
                        swing: None,
                    },
                    Vec3::from(position).as_dvec3(),
                )
            }
        };
        let (mut light, world_pos) = light;
        let swing = match l {
            LightDesc::Directional { swing, .. }
            | LightDesc::Point { swing, .. }
            | LightDesc::Spot { swing, .. } => swing,
        };
        if let Some(sw) = swing {
            check_finite(&f("swing.pivot"), &sw.pivot)?;
            check_range(
                &f("swing.degrees"),
                sw.degrees,
                0.0,
                180.0,
                "must be between 0 and 180 degrees",
            )?;
            check_range(
                &f("swing.period_s"),
                sw.period_s,
                1e-3,
                1e6,
                "must be between 0.001 and 1e6 seconds",
            )?;
            light.swing = Some(Swing {
                pivot: Vec3::from(sw.pivot),
                axis: unit("swing.axis", sw.axis)?,
                amplitude_rad: sw.degrees.to_radians(),
                period_s: sw.period_s,
            });
        }
        out.push((light, world_pos));
    }
    Ok(out)
}

/// Keeps the [`MAX_LIGHTS`] lights with the most radiance at the centre of the scene
/// (paper 000 §3.1.1 recommends keeping the strongest 8); returns the kept lights in
/// their original order and how many were dropped.
fn rank_lights(
    lights: Vec<(Light, glam::DVec3)>,
    origin: glam::DVec3,
    bounds: (Vec3, Vec3),
) -> (Vec<Light>, usize) {
    let placed: Vec<Light> = lights
        .into_iter()
        .map(|(mut l, world_pos)| {
            if l.kind != 0 {
                l.position = (world_pos - origin).as_vec3();
            }
            if let Some(sw) = l.swing.as_mut() {
                sw.pivot = (sw.pivot.as_dvec3() - origin).as_vec3();
            }
            l
        })
        .collect();
    if placed.len() <= MAX_LIGHTS {
        return (placed, 0);
    }
    let centre = (bounds.0 + bounds.1) * 0.5;
    let strength = |l: &Light| -> f32 {
        let lum = l.radiance.dot(Vec3::new(0.2126, 0.7152, 0.0722));
        if l.kind == 0 {
            lum
        } else {
            lum / l.position.distance_squared(centre).max(1.0)
        }
    };
    let mut order: Vec<usize> = (0..placed.len()).collect();
    order.sort_by(|a, b| strength(&placed[*b]).total_cmp(&strength(&placed[*a])));
    let mut keep: Vec<usize> = order[..MAX_LIGHTS].to_vec();
    keep.sort_unstable();
    let dropped = placed.len() - MAX_LIGHTS;
    (keep.into_iter().map(|i| placed[i]).collect(), dropped)
}

fn validate_media(media: &[MediumDesc]) -> Result<(), SceneError> {
    for (i, m) in media.iter().enumerate() {
        let f = |name: &str| format!("medium[{i}].{name}");
        check_finite(&f("scattering"), &m.scattering)?;
        for c in m.scattering {
            check_range(
                &f("scattering"),
                c,
                0.0,
                1e6,
                "each channel must be between 0 and 1e6 m⁻¹",
            )?;
        }
        check_range(
            &f("absorption"),
            m.absorption,
            0.0,
            1e6,
            "must be between 0 and 1e6 m⁻¹",
        )?;
        check_range(
            &f("g"),
            m.g,
            -0.9999,
            0.9999,
            "Henyey-Greenstein g must be strictly between -1 and 1",
        )?;
        check_finite(&f("emission"), &m.emission)?;
        if m.emission.iter().any(|c| *c < 0.0) {
            return Err(invalid(f("emission"), m.emission, "must not be negative"));
        }
        match m.kind {
            MediumKind::Constant => {}
            MediumKind::Height => {
                let base = m.base_y_m.ok_or_else(|| {
                    invalid(f("base_y_m"), "missing", "height fog needs base_y_m")
                })?;
                check_finite(&f("base_y_m"), &[base])?;
                let falloff = m.falloff_m.ok_or_else(|| {
                    invalid(f("falloff_m"), "missing", "height fog needs falloff_m")
                })?;
                check_range(
                    &f("falloff_m"),
                    falloff,
                    1e-3,
                    1e5,
                    "must be between 0.001 and 100000 m",
                )?;
            }
            MediumKind::Box => {
                let lo = m.min.ok_or_else(|| {
                    invalid(f("min"), "missing", "a box medium needs min and max")
                })?;
                let hi = m.max.ok_or_else(|| {
                    invalid(f("max"), "missing", "a box medium needs min and max")
                })?;
                check_finite(&f("min"), &lo)?;
                check_finite(&f("max"), &hi)?;
                if (0..3).any(|k| hi[k] <= lo[k]) {
                    return Err(invalid(
                        f("max"),
                        hi,
                        "must be greater than min on every axis",
                    ));
                }
            }
            MediumKind::Sphere => {
                let c = m.center.ok_or_else(|| {
                    invalid(
                        f("center"),
                        "missing",
                        "a sphere medium needs center and radius",
                    )
                })?;
                check_finite(&f("center"), &c)?;
                let r = m.radius.ok_or_else(|| {
                    invalid(
                        f("radius"),
                        "missing",
                        "a sphere medium needs center and radius",
                    )
                })?;
                check_range(
                    &f("radius"),
                    r,
                    1e-3,
                    1e5,
                    "must be between 0.001 and 100000 m",
                )?;
            }
        }
        if let Some(n) = m.noise {
            check_range(
                &f("noise.frequency"),
                n.frequency,
                0.0,
                1e3,
                "must be between 0 and 1000 per metre",
            )?;
            if !(1..=6).contains(&n.octaves) {
                return Err(invalid(
                    f("noise.octaves"),
                    n.octaves,
                    "must be between 1 and 6",
                ));
            }
            check_range(
                &f("noise.amplitude"),
                n.amplitude,
                0.0,
                1.0,
                "must be between 0 and 1",
            )?;
            check_finite(&f("noise.wind"), &n.wind)?;
        }
    }
    Ok(())
}
