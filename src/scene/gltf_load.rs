//! glTF/GLB loading (positions and indices of every mesh primitive, node transforms applied).

use super::{
    CameraPath, LightDesc, MediumDesc, MediumKind, MeshDesc, RenderDefaults, SceneDesc, SceneError,
};
use glam::{Mat4, Vec3};
use std::path::Path;

fn gltf_err(path: &Path, message: impl std::fmt::Display) -> SceneError {
    SceneError::Gltf {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// Loads all triangles of a glTF file in its own coordinates (node transforms applied).
/// A NaN or infinite vertex is an error naming the mesh and vertex.
pub(crate) fn load_triangles(path: &Path) -> Result<(Vec<Vec3>, Vec<[u32; 3]>), SceneError> {
    if !path.exists() {
        return Err(gltf_err(
            path,
            "file not found (paths are relative to the scene file)",
        ));
    }
    let (doc, buffers, _images) = gltf::import(path).map_err(|e| gltf_err(path, e))?;
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let scene = doc.default_scene().or_else(|| doc.scenes().next());
    let mut stack: Vec<(gltf::Node, Mat4)> = match &scene {
        Some(s) => s.nodes().map(|n| (n, Mat4::IDENTITY)).collect(),
        None => doc.nodes().map(|n| (n, Mat4::IDENTITY)).collect(),
    };
    while let Some((node, parent)) = stack.pop() {
        let m = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, m));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else {
                continue;
            };
            let base = positions.len() as u32;
            for (vi, p) in pos.enumerate() {
                if !p.iter().all(|x| x.is_finite()) {
                    return Err(gltf_err(
                        path,
                        format!(
                            "mesh {} primitive {} vertex {vi} is {p:?}: positions must be finite",
                            mesh.index(),
                            prim.index()
                        ),
                    ));
                }
                positions.push(m.transform_point3(Vec3::from(p)));
            }
            let count = positions.len() as u32 - base;
            let idx: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..count).collect(),
            };
            for t in idx.chunks_exact(3) {
                if t.iter().any(|i| *i >= count) {
                    return Err(gltf_err(
                        path,
                        format!(
                            "mesh {} primitive {} index {t:?} out of range ({count} vertices)",
                            mesh.index(),
                            prim.index()
                        ),
                    ));
                }
                indices.push([t[0] + base, t[1] + base, t[2] + base]);
            }
        }
    }
    if indices.is_empty() {
        return Err(gltf_err(path, "no triangles found"));
    }
    Ok((positions, indices))
}

/// A scene around a bare glTF file: the model, a sun from high above (slightly tilted so
/// shafts fall through openings), thin fog filling the bounds, and a camera path through
/// the middle of the bounds at a third of the height.
pub(crate) fn default_desc_for(path: &Path) -> Result<SceneDesc, SceneError> {
    let (pos, _) = load_triangles(path)?;
    let (lo, hi) = pos.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(a, b), p| (a.min(*p), b.max(*p)),
    );
    let size = hi - lo;
    let centre = (lo + hi) * 0.5;
    let y = lo.y + size.y * 0.3;
    let long_x = size.x >= size.z;
    let along = |t: f32| {
        let mut p = Vec3::new(centre.x, y, centre.z);
        if long_x {
            p.x = lo.x + size.x * t;
        } else {
            p.z = lo.z + size.z * t;
        }
        p.to_array()
    };
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("gltf")
        .to_string();
    Ok(SceneDesc {
        volumes: Vec::new(),
        movers: Vec::new(),
        emitters: Vec::new(),
        name,
        render: RenderDefaults {
            far_m: size.length().clamp(8.0, 1000.0),
            ..RenderDefaults::default()
        },
        meshes: vec![MeshDesc::Gltf {
            path: path.to_path_buf(),
            translate: [0.0; 3],
            scale: 1.0,
            albedo: [0.7, 0.65, 0.55],
            // A bare file's winding is not known: both sides are seen.
            cull: "none".into(),
        }],
        lights: vec![LightDesc::Directional {
            swing: None,
            direction: [0.25, -1.0, 0.18],
            color: [1.0, 0.92, 0.8],
            intensity: 6.0,
        }],
        media: vec![MediumDesc {
            kind: MediumKind::Box,
            scattering: [0.06, 0.06, 0.06],
            absorption: 0.01,
            g: 0.6,
            emission: [0.0; 3],
            min: Some(lo.to_array()),
            max: Some(hi.to_array()),
            center: None,
            radius: None,
            base_y_m: None,
            falloff_m: None,
            noise: None,
        }],
        camera: CameraPath {
            path: vec![along(0.25), along(0.75)],
            look_at: vec![],
            fov_deg: 70.0,
            speed_mps: 1.0,
            pitch_deg: 10.0,
        },
    })
}
