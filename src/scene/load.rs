//! Loading: a built-in scene, a TOML scene file or a bare glTF file becomes a [`Scene`]
//! in render space (validated, moved by its origin, lights ranked); or just its camera
//! loop, read without the meshes.

use super::format::NameAndCamera;
use super::validate::{
    validate_emitters, validate_lights, validate_media, validate_render, validate_volumes,
};
use super::{
    builtin_scene, gltf_load, media, mesh, CameraPath, EmitterDesc, Light, LightKind, Mover, Scene,
    SceneDesc, SceneError, MAX_LIGHTS,
};
use glam::Vec3;
use serde::de::DeserializeOwned;
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// Where a scene's description comes from.
enum Source<'a> {
    /// TOML text (a built-in scene or a file); `path` names it in errors and relative
    /// mesh paths resolve against `base_dir`.
    Toml {
        text: Cow<'static, str>,
        path: PathBuf,
        base_dir: PathBuf,
    },
    /// A bare glTF file.
    Gltf(&'a Path),
}

impl<'a> Source<'a> {
    /// A built-in scene by name, a `.toml` file, or a `.glb`/`.gltf` file.
    fn find(name_or_path: &'a str) -> Result<Source<'a>, SceneError> {
        if let Some(text) = builtin_scene(name_or_path) {
            return Ok(Source::Toml {
                text: Cow::Borrowed(text),
                path: PathBuf::from(format!("<built-in {name_or_path}>")),
                base_dir: PathBuf::from("."),
            });
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
            return Ok(Source::Gltf(path));
        }
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Source::Toml {
            text: Cow::Owned(text),
            path: path.to_path_buf(),
            base_dir: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
        })
    }
}

/// Parses TOML text; errors name `path`.
fn parse<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, SceneError> {
    toml::from_str(text).map_err(|e| SceneError::Parse {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The name and camera loop of a built-in scene, a `.toml` scene file or a `.glb`/`.gltf`
/// file, in the coordinates the file gives (world space, not render space) — what a
/// client flying the scene's loop needs. A TOML scene's meshes are not loaded (its glTF
/// files need not exist here) and its other sections are not checked; a bare glTF file's
/// loop follows its bounds, so its triangles are read.
pub fn load_camera_path(name_or_path: &str) -> Result<(String, CameraPath), SceneError> {
    let (name, camera) = match Source::find(name_or_path)? {
        Source::Toml { text, path, .. } => {
            let c: NameAndCamera = parse(&text, &path)?;
            (c.name, c.camera)
        }
        Source::Gltf(path) => {
            let desc = gltf_load::default_desc_for(path)?;
            (desc.name, desc.camera)
        }
    };
    camera.validate()?;
    Ok((name, camera))
}

impl Scene {
    /// Loads a built-in scene by name, a `.toml` scene file, or a `.glb`/`.gltf` file
    /// (which gets a default sun, fog and camera path around its bounds).
    pub fn load(name_or_path: &str) -> Result<Scene, SceneError> {
        match Source::find(name_or_path)? {
            Source::Toml {
                text,
                path,
                base_dir,
            } => Scene::from_desc(parse(&text, &path)?, &base_dir),
            Source::Gltf(path) => {
                Scene::from_desc(gltf_load::default_desc_for(path)?, Path::new("."))
            }
        }
    }

    /// Parses and validates TOML text; relative mesh paths resolve against `path`'s folder.
    pub fn from_toml(text: &str, path: &Path) -> Result<Scene, SceneError> {
        let base = path.parent().unwrap_or(Path::new("."));
        Scene::from_desc(parse(text, path)?, base)
    }

    /// Validates a description and moves it to render space.
    pub fn from_desc(desc: SceneDesc, base_dir: &Path) -> Result<Scene, SceneError> {
        validate_render(&desc.render)?;
        let mesh = mesh::build_meshes(&desc.meshes, base_dir)?;
        let lights_world = validate_lights(&desc.lights)?;
        validate_media(&desc.media)?;
        validate_volumes(&desc.volumes)?;
        validate_emitters(&desc.emitters)?;
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
        for v in &desc.volumes {
            let (a, b) = media::volume_extent(v);
            grow(a.as_dvec3());
            grow(b.as_dvec3());
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
            .chain(
                desc.volumes
                    .iter()
                    .map(|v| media::volume_to_render_space(v, &to_render)),
            )
            .collect();
        let camera = desc.camera.translated(&to_render);
        let movers = desc
            .movers
            .iter()
            .enumerate()
            .map(|(i, m)| Mover::new(i, m, origin))
            .collect::<Result<Vec<_>, _>>()?;
        let emitters = desc
            .emitters
            .iter()
            .map(|e| EmitterDesc {
                position: to_render(e.position).to_array(),
                ..e.clone()
            })
            .collect();
        Ok(Scene {
            movers,
            emitters,
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
            if l.kind != LightKind::Directional {
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
        if l.kind == LightKind::Directional {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_paths_are_read_without_meshes_in_file_coordinates() {
        // The built-in loop is the loaded scene's, before the move to render space.
        let scene = Scene::load("colonnade").unwrap();
        let (name, world) = load_camera_path("colonnade").unwrap();
        assert_eq!(name, "colonnade");
        assert_ne!(
            scene.origin,
            glam::DVec3::ZERO,
            "a test of the move needs one"
        );
        for (w, r) in world.path.iter().zip(&scene.camera.path) {
            let moved = Vec3::from(*w).as_dvec3() - scene.origin;
            assert!(
                moved.distance(Vec3::from(*r).as_dvec3()) < 1e-5,
                "{w:?} vs {r:?}"
            );
        }
        // A TOML scene whose glTF is not on this machine still has its loop.
        let dir = std::env::temp_dir().join(format!("fogcast-camera-path-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("far.toml");
        std::fs::write(
            &file,
            "name = \"far\"\n[camera]\npath = [[1.0, 2.0, 3.0], [4.0, 2.0, 3.0]]\n\
             [[mesh]]\nkind = \"gltf\"\npath = \"missing.glb\"\n",
        )
        .unwrap();
        let file = file.to_str().unwrap();
        let e = Scene::load(file).unwrap_err().to_string();
        assert!(e.contains("missing.glb"), "{e}");
        let (name, path) = load_camera_path(file).unwrap();
        assert_eq!((name.as_str(), path.path.len()), ("far", 2));
        // The loop itself is still checked.
        std::fs::write(file, "name = \"x\"\n[camera]\npath = []\n").unwrap();
        let e = load_camera_path(file).unwrap_err().to_string();
        assert!(e.contains("camera.path"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
