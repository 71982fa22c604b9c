//! Loading: a built-in scene, a TOML scene file or a bare glTF file becomes a [`Scene`]
//! in render space (validated, moved by its origin, lights ranked).

use super::validate::{validate_lights, validate_media, validate_render};
use super::{
    builtin_scene, gltf_load, media, mesh, Light, Mover, Scene, SceneDesc, SceneError, MAX_LIGHTS,
};
use glam::Vec3;
use std::path::{Path, PathBuf};

impl Scene {
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
