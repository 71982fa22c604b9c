//! Triangle meshes: built-in primitives and glTF, gathered into one list.

use super::{gltf_load, invalid, Cull, MeshDesc, SceneError};
use glam::{DVec3, Vec3};
use std::path::Path;

/// All triangles of a scene, indexed, with a per-vertex albedo.
#[derive(Debug, Clone, Default)]
pub struct TriangleMesh {
    /// Vertex positions, render space.
    pub positions: Vec<Vec3>,
    /// Vertex albedo, packed RGBA8 (linear).
    pub albedo: Vec<u32>,
    /// Triangle vertex indices.
    pub indices: Vec<[u32; 3]>,
    /// The side of each triangle the camera does not see; shorter than `indices` (empty,
    /// say) where the rest see both sides.
    pub cull: Vec<Cull>,
}

impl TriangleMesh {
    /// The side of triangle `i` the camera does not see.
    pub fn cull_of(&self, i: usize) -> Cull {
        self.cull.get(i).copied().unwrap_or_default()
    }

    /// The three corners of triangle `i`.
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        let [a, b, c] = self.indices[i];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.indices.len()
    }

    /// True when the scene has no triangles.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// Appends `other`'s triangles (indices shifted past this mesh's vertices).
    pub fn append(&mut self, other: &TriangleMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend(&other.positions);
        self.albedo.extend(&other.albedo);
        if !other.cull.is_empty() || !self.cull.is_empty() {
            self.cull.resize(self.indices.len(), Cull::None);
            self.cull.extend(&other.cull);
            self.cull
                .resize(self.indices.len() + other.indices.len(), Cull::None);
        }
        self.indices
            .extend(other.indices.iter().map(|t| t.map(|i| i + base)));
    }
}

/// Meshes in world space (f64), before the shift to render space.
#[derive(Debug, Default)]
pub(crate) struct WorldMesh {
    pub world_positions: Vec<DVec3>,
    pub albedo: Vec<u32>,
    pub indices: Vec<[u32; 3]>,
    /// Per triangle, as `TriangleMesh::cull`.
    pub cull: Vec<Cull>,
}

pub(crate) fn pack_albedo(c: [f32; 3]) -> u32 {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u32;
    q(c[0]) | (q(c[1]) << 8) | (q(c[2]) << 16) | (255 << 24)
}

impl WorldMesh {
    /// Appends triangles; zero-area triangles are dropped (they can never occlude).
    pub(crate) fn push(
        &mut self,
        positions: &[DVec3],
        indices: &[[u32; 3]],
        albedo: [f32; 3],
        cull: Cull,
    ) {
        let base = self.world_positions.len() as u32;
        self.world_positions.extend_from_slice(positions);
        self.albedo
            .extend(std::iter::repeat_n(pack_albedo(albedo), positions.len()));
        for t in indices {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            if (b - a).cross(c - a).length_squared() > 0.0 {
                self.indices.push(t.map(|i| i + base));
                self.cull.push(cull);
            }
        }
    }

    pub(crate) fn into_render_space(self, origin: DVec3) -> TriangleMesh {
        TriangleMesh {
            positions: self
                .world_positions
                .iter()
                .map(|p| (*p - origin).as_vec3())
                .collect(),
            albedo: self.albedo,
            indices: self.indices,
            cull: self.cull,
        }
    }
}

fn check_albedo(field: String, a: [f32; 3]) -> Result<(), SceneError> {
    if a.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x)) {
        Ok(())
    } else {
        Err(invalid(field, a, "each channel must be between 0 and 1"))
    }
}

fn check_point(field: String, p: [f32; 3]) -> Result<(), SceneError> {
    if p.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(invalid(field, p, "must be finite"))
    }
}

pub(crate) fn build_meshes(descs: &[MeshDesc], base_dir: &Path) -> Result<WorldMesh, SceneError> {
    let mut out = WorldMesh::default();
    for (i, d) in descs.iter().enumerate() {
        let f = |name: &str| format!("mesh[{i}].{name}");
        let (MeshDesc::Gltf { cull, .. }
        | MeshDesc::Box { cull, .. }
        | MeshDesc::Cylinder { cull, .. }) = d;
        let cull = Cull::parse(cull)
            .ok_or_else(|| invalid(f("cull"), cull, "must be \"none\", \"back\" or \"front\""))?;
        match d {
            MeshDesc::Gltf {
                path,
                translate,
                scale,
                albedo,
                ..
            } => {
                check_albedo(f("albedo"), *albedo)?;
                check_point(f("translate"), *translate)?;
                if !(scale.is_finite() && *scale > 0.0) {
                    return Err(invalid(f("scale"), scale, "must be a positive number"));
                }
                let full = if path.is_absolute() {
                    path.clone()
                } else {
                    base_dir.join(path)
                };
                if !full.is_file() {
                    let reason = format!(
                        "no such file: looked for {} (relative paths start at the scene file's folder)",
                        full.display()
                    );
                    return Err(invalid(f("path"), path, &reason));
                }
                let (pos, idx) = gltf_load::load_triangles(&full)?;
                let t = Vec3::from(*translate).as_dvec3();
                let moved: Vec<DVec3> = pos
                    .iter()
                    .map(|p| p.as_dvec3() * *scale as f64 + t)
                    .collect();
                out.push(&moved, &idx, *albedo, cull);
            }
            MeshDesc::Box {
                min, max, albedo, ..
            } => {
                check_albedo(f("albedo"), *albedo)?;
                check_point(f("min"), *min)?;
                check_point(f("max"), *max)?;
                if (0..3).any(|k| max[k] <= min[k]) {
                    return Err(invalid(
                        f("max"),
                        max,
                        "must be greater than min on every axis",
                    ));
                }
                let (p, t) =
                    box_triangles(Vec3::from(*min).as_dvec3(), Vec3::from(*max).as_dvec3());
                out.push(&p, &t, *albedo, cull);
            }
            MeshDesc::Cylinder {
                base,
                radius,
                height,
                segments,
                albedo,
                ..
            } => {
                check_albedo(f("albedo"), *albedo)?;
                check_point(f("base"), *base)?;
                if !(radius.is_finite() && *radius > 0.0) {
                    return Err(invalid(f("radius"), radius, "must be a positive number"));
                }
                if !(height.is_finite() && *height > 0.0) {
                    return Err(invalid(f("height"), height, "must be a positive number"));
                }
                if !(3..=256).contains(segments) {
                    return Err(invalid(
                        f("segments"),
                        segments,
                        "must be between 3 and 256",
                    ));
                }
                let (p, t) = cylinder_triangles(
                    Vec3::from(*base).as_dvec3(),
                    *radius as f64,
                    *height as f64,
                    *segments,
                );
                out.push(&p, &t, *albedo, cull);
            }
        }
    }
    Ok(out)
}

/// 12 outward-facing triangles of an axis-aligned box.
pub(crate) fn box_triangles(lo: DVec3, hi: DVec3) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let p: Vec<DVec3> = (0..8)
        .map(|i| {
            DVec3::new(
                if i & 1 != 0 { hi.x } else { lo.x },
                if i & 2 != 0 { hi.y } else { lo.y },
                if i & 4 != 0 { hi.z } else { lo.z },
            )
        })
        .collect();
    let faces = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let t = faces
        .iter()
        .flat_map(|[a, b, c, d]| [[*a, *b, *c], [*a, *c, *d]])
        .collect();
    (p, t)
}

fn cylinder_triangles(base: DVec3, r: f64, h: f64, n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut p = vec![base, base + DVec3::Y * h];
    let mut t = Vec::new();
    for k in 0..n {
        let a = std::f64::consts::TAU * k as f64 / n as f64;
        let off = DVec3::new(a.cos() * r, 0.0, a.sin() * r);
        p.push(base + off);
        p.push(base + off + DVec3::Y * h);
    }
    for k in 0..n {
        let (b0, t0) = (2 + 2 * k, 3 + 2 * k);
        let (b1, t1) = (2 + 2 * ((k + 1) % n), 3 + 2 * ((k + 1) % n));
        t.push([b0, t0, t1]);
        t.push([b0, t1, b1]);
        t.push([0, b0, b1]);
        t.push([1, t1, t0]);
    }
    (p, t)
}
