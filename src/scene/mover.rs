//! Moving occluders: boxes that spin about an axis through a pivot. They cast shadows
//! in the fog and on surfaces, are drawn like any mesh, and (with temporal caching)
//! invalidate exactly the grid voxels whose shadow rays their swept bounds touch.

use super::mesh::{box_triangles, pack_albedo, TriangleMesh};
use super::{check_finite, check_range, invalid, SceneError};
use glam::{DVec3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// A box that spins about `axis` through `pivot` at `degrees_per_s` (scene file
/// `[[mover]]`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MoverDesc {
    /// Box corner at time 0, metres.
    pub min: [f32; 3],
    /// Opposite corner at time 0, metres.
    pub max: [f32; 3],
    /// Linear RGB albedo, 0..1.
    #[serde(default = "grey")]
    pub albedo: [f32; 3],
    /// Point on the rotation axis, metres.
    pub pivot: [f32; 3],
    /// Rotation axis (need not be normalised).
    #[serde(default = "up")]
    pub axis: [f32; 3],
    /// Angular speed, degrees per second (negative: the other way).
    pub degrees_per_s: f32,
}

fn grey() -> [f32; 3] {
    [0.6, 0.6, 0.6]
}

fn up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

/// A validated mover in render space.
#[derive(Debug, Clone)]
pub struct Mover {
    /// Its triangles at time 0, render space.
    pub mesh: TriangleMesh,
    /// Pivot, render space.
    pub pivot: Vec3,
    /// Unit axis.
    pub axis: Vec3,
    /// Radians per second.
    pub rad_per_s: f32,
}

impl Mover {
    /// Validates `d` (the i-th mover) and moves it to render space.
    pub(crate) fn new(i: usize, d: &MoverDesc, origin: DVec3) -> Result<Mover, SceneError> {
        let f = |name: &str| format!("mover[{i}].{name}");
        for (name, v) in [
            ("min", d.min),
            ("max", d.max),
            ("pivot", d.pivot),
            ("axis", d.axis),
            ("albedo", d.albedo),
        ] {
            check_finite(&f(name), &v)?;
        }
        if (0..3).any(|k| d.max[k] <= d.min[k]) {
            return Err(invalid(
                f("max"),
                d.max,
                "must be greater than min on every axis",
            ));
        }
        if d.albedo.iter().any(|a| !(0.0..=1.0).contains(a)) {
            return Err(invalid(
                f("albedo"),
                d.albedo,
                "each channel must be between 0 and 1",
            ));
        }
        check_range(
            &f("degrees_per_s"),
            d.degrees_per_s,
            -36000.0,
            36000.0,
            "must be between -36000 and 36000",
        )?;
        let axis = Vec3::from(d.axis)
            .try_normalize()
            .ok_or_else(|| invalid(f("axis"), d.axis, "must be a non-zero vector"))?;
        let to_render = |p: DVec3| (p - origin).as_vec3();
        let (corners, tris) =
            box_triangles(Vec3::from(d.min).as_dvec3(), Vec3::from(d.max).as_dvec3());
        Ok(Mover {
            mesh: TriangleMesh {
                positions: corners.iter().map(|p| to_render(*p)).collect(),
                albedo: vec![pack_albedo(d.albedo); corners.len()],
                indices: tris,
                cull: Vec::new(),
            },
            pivot: to_render(Vec3::from(d.pivot).as_dvec3()),
            axis,
            rad_per_s: d.degrees_per_s.to_radians(),
        })
    }

    /// World-space extent the mover can ever reach (a box around the sphere its
    /// corners sweep about the pivot), for the scene bounds.
    pub fn reach(&self) -> (Vec3, Vec3) {
        let r = self
            .mesh
            .positions
            .iter()
            .map(|p| p.distance(self.pivot))
            .fold(0.0f32, f32::max);
        (self.pivot - Vec3::splat(r), self.pivot + Vec3::splat(r))
    }

    /// Its vertices at scene time `time_s`.
    pub fn positions_at(&self, time_s: f32) -> Vec<Vec3> {
        let angle = (self.rad_per_s as f64 * time_s as f64).rem_euclid(std::f64::consts::TAU);
        let rot = Quat::from_axis_angle(self.axis, angle as f32);
        self.mesh
            .positions
            .iter()
            .map(|p| self.pivot + rot * (*p - self.pivot))
            .collect()
    }

    /// Axis-aligned bounds at scene time `time_s`.
    pub fn bounds_at(&self, time_s: f32) -> (Vec3, Vec3) {
        self.positions_at(time_s).iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }
}

/// All movers' triangles at `time_s` as one mesh (empty without movers).
pub fn movers_mesh_at(movers: &[Mover], time_s: f32) -> TriangleMesh {
    let mut out = TriangleMesh::default();
    for m in movers {
        out.append(&TriangleMesh {
            positions: m.positions_at(time_s),
            ..m.mesh.clone()
        });
    }
    out
}
