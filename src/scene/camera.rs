//! Cameras and the path viewers travel along.

use super::{invalid, SceneError};
use glam::{DMat3, DQuat, Mat4, Vec3};
use serde::{Deserialize, Serialize};

/// A closed loop of points that viewers walk around, optionally with look-at points.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraPath {
    /// Corners of the loop, metres (at least one; the last joins the first).
    pub path: Vec<[f32; 3]>,
    /// Points to look at, one per path point; empty: look along the path.
    #[serde(default)]
    pub look_at: Vec<[f32; 3]>,
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    pub fov_deg: f32,
    /// Walking speed along the path, metres per second.
    #[serde(default = "default_speed")]
    pub speed_mps: f32,
    /// Upward tilt of the view when looking along the path, degrees.
    #[serde(default)]
    pub pitch_deg: f32,
}

/// A viewer looking along the path turns at a corner over the path it walks from this
/// long before the corner to this long after, seconds (at least half a metre each way).
const TURN_S: f32 = 1.0;

fn default_fov() -> f32 {
    70.0
}
fn default_speed() -> f32 {
    1.0
}

/// One viewer's camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position, render space.
    pub position: Vec3,
    /// Unit view direction.
    pub forward: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl Camera {
    /// A camera at `position` looking along `forward` (any non-zero vector).
    pub fn new(position: Vec3, forward: Vec3, fov_y: f32) -> Camera {
        Camera {
            position,
            forward: forward.try_normalize().unwrap_or(Vec3::NEG_Z),
            fov_y,
        }
    }

    /// An up vector that is never parallel to `forward`.
    pub fn up(&self) -> Vec3 {
        if self.forward.y.abs() > 0.999 {
            Vec3::Z
        } else {
            Vec3::Y
        }
    }

    /// The roll-free rotation (+y up) that turns the camera's −z into `forward`: the
    /// orientation the viewer protocol sends.
    pub fn orientation(&self) -> DQuat {
        let f = self.forward.as_dvec3().normalize();
        let up = self.up().as_dvec3();
        let right = f.cross(up).normalize();
        let up = right.cross(f);
        DQuat::from_mat3(&DMat3::from_cols(right, up, -f)).normalize()
    }

    /// World-to-view matrix (right-handed, −z forward).
    pub fn view(&self) -> Mat4 {
        let f = self.forward;
        let r = f.cross(self.up()).normalize();
        let u = r.cross(f);
        let e = self.position;
        Mat4::from_cols(
            glam::Vec4::new(r.x, u.x, -f.x, 0.0),
            glam::Vec4::new(r.y, u.y, -f.y, 0.0),
            glam::Vec4::new(r.z, u.z, -f.z, 0.0),
            glam::Vec4::new(-r.dot(e), -u.dot(e), f.dot(e), 1.0),
        )
    }

    /// View-to-clip matrix (depth 0..1).
    pub fn projection(&self, aspect: f32, near: f32, far: f32) -> Mat4 {
        let f = 1.0 / (self.fov_y * 0.5).tan();
        let range = near - far;
        Mat4::from_cols(
            glam::Vec4::new(f / aspect, 0.0, 0.0, 0.0),
            glam::Vec4::new(0.0, f, 0.0, 0.0),
            glam::Vec4::new(0.0, 0.0, far / range, -1.0),
            glam::Vec4::new(0.0, 0.0, near * far / range, 0.0),
        )
    }

    /// Unit ray direction through pixel-space point (x, y) of a `w`×`h` image
    /// (y down, pixel centres at +0.5).
    pub fn ray_dir(&self, x: f32, y: f32, w: u32, h: u32) -> Vec3 {
        let aspect = w as f32 / h as f32;
        let t = (self.fov_y * 0.5).tan();
        let nx = (2.0 * x / w as f32 - 1.0) * t * aspect;
        let ny = (1.0 - 2.0 * y / h as f32) * t;
        let right = self.forward.cross(self.up()).normalize();
        let up = right.cross(self.forward);
        (self.forward + right * nx + up * ny).normalize()
    }
}

impl CameraPath {
    pub(crate) fn validate(&self) -> Result<(), SceneError> {
        if self.path.is_empty() {
            return Err(invalid("camera.path", "[]", "needs at least one point"));
        }
        for (i, p) in self.path.iter().enumerate() {
            if !p.iter().all(|x| x.is_finite()) {
                return Err(invalid(format!("camera.path[{i}]"), p, "must be finite"));
            }
        }
        if !self.look_at.is_empty() && self.look_at.len() != self.path.len() {
            return Err(invalid(
                "camera.look_at",
                self.look_at.len(),
                "needs one point per path point, or none",
            ));
        }
        for (i, p) in self.look_at.iter().enumerate() {
            if !p.iter().all(|x| x.is_finite()) {
                return Err(invalid(format!("camera.look_at[{i}]"), p, "must be finite"));
            }
        }
        if !(self.fov_deg.is_finite() && (1.0..=170.0).contains(&self.fov_deg)) {
            return Err(invalid(
                "camera.fov_deg",
                self.fov_deg,
                "must be between 1 and 170 degrees",
            ));
        }
        if !(self.pitch_deg.is_finite() && (-89.0..=89.0).contains(&self.pitch_deg)) {
            return Err(invalid(
                "camera.pitch_deg",
                self.pitch_deg,
                "must be between -89 and 89 degrees",
            ));
        }
        if !(self.speed_mps.is_finite() && (0.0..=1e4).contains(&self.speed_mps)) {
            return Err(invalid(
                "camera.speed_mps",
                self.speed_mps,
                "must be between 0 and 10000",
            ));
        }
        Ok(())
    }

    pub(crate) fn translated(&self, f: &impl Fn([f32; 3]) -> Vec3) -> CameraPath {
        CameraPath {
            path: self.path.iter().map(|p| f(*p).to_array()).collect(),
            look_at: self.look_at.iter().map(|p| f(*p).to_array()).collect(),
            ..self.clone()
        }
    }

    /// Segments of the closed loop (last point back to the first).
    fn segments(&self) -> impl Iterator<Item = (Vec3, Vec3, usize)> + '_ {
        let n = self.path.len();
        (0..n).map(move |i| {
            (
                Vec3::from(self.path[i]),
                Vec3::from(self.path[(i + 1) % n]),
                i,
            )
        })
    }

    /// Length of the closed loop, metres.
    fn length(&self) -> f32 {
        self.segments().map(|(a, b, _)| a.distance(b)).sum()
    }

    /// Point, look target and direction of travel at arc length `s` along the loop.
    fn sample(&self, s: f32) -> (Vec3, Option<Vec3>, Vec3) {
        let n = self.path.len();
        let mut rest = s;
        for (a, b, i) in self.segments() {
            let len = a.distance(b);
            if rest <= len || i + 1 == n {
                let t = if len > 0.0 {
                    (rest / len).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let look = (!self.look_at.is_empty()).then(|| {
                    Vec3::from(self.look_at[i]).lerp(Vec3::from(self.look_at[(i + 1) % n]), t)
                });
                return (a.lerp(b, t), look, (b - a).normalize_or(Vec3::NEG_Z));
            }
            rest -= len;
        }
        unreachable!("a validated path has at least one point")
    }

    /// `n` viewers spread evenly along the closed path at time `time_s`, each walking
    /// it and looking where it goes (pitched by `pitch_deg`), as players spread over a
    /// level would be.
    pub fn viewers(&self, n: usize, time_s: f32) -> Vec<Camera> {
        let len = self.length();
        let fov_y = self.fov_deg.to_radians();
        (0..n)
            .map(|i| {
                let (pos, look, dir) = if len <= 0.0 {
                    (
                        Vec3::from(self.path[0]),
                        self.look_at.first().map(|l| Vec3::from(*l)),
                        Vec3::NEG_Z,
                    )
                } else {
                    let s = (i as f32 + 0.5) / n as f32 * len + time_s * self.speed_mps;
                    let (pos, look, tangent) = self.sample(s.rem_euclid(len));
                    // Look along the chord from TURN_S behind to TURN_S ahead: the
                    // tangent on straight stretches, a steady turn around a corner
                    // (instead of snapping to the next segment's direction).
                    let reach = (TURN_S * self.speed_mps).max(0.5);
                    let behind = self.sample((s - reach).rem_euclid(len)).0;
                    let ahead = self.sample((s + reach).rem_euclid(len)).0;
                    (pos, look, (ahead - behind).normalize_or(tangent))
                };
                let pitched = {
                    let flat = Vec3::new(dir.x, 0.0, dir.z).normalize_or(Vec3::NEG_Z);
                    let (s, c) = self.pitch_deg.to_radians().sin_cos();
                    if dir.y.abs() > 0.99 {
                        dir
                    } else {
                        flat * c + Vec3::Y * s
                    }
                };
                let forward = match look {
                    Some(target) if target.distance(pos) > 1e-3 => target - pos,
                    _ => pitched,
                };
                Camera::new(pos, forward, fov_y)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use crate::scene::Scene;

    #[test]
    fn viewers_turn_smoothly_around_corners() {
        // street's loop turns 180° over two corners 3 m apart; a frame is 1/30 s.
        for name in [
            "colonnade",
            "street",
            "islands",
            "cloud",
            "scenes/sponza.toml",
        ] {
            let cam = Scene::load(name).unwrap().camera;
            let mut worst = 0.0f32;
            for frame in 0..(60.0 * 30.0) as usize {
                let t = frame as f32 / 30.0;
                let a = cam.viewers(1, t)[0].forward;
                let b = cam.viewers(1, t + 1.0 / 30.0)[0].forward;
                worst = worst.max(a.angle_between(b).to_degrees());
            }
            println!("{name}: largest turn between frames {worst:.2}°");
            assert!(worst < 5.0, "{name}: the view turns {worst}° in one frame");
        }
    }
}
