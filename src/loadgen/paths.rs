//! Where each simulated viewer flies: the scene's own camera loop, viewers spread evenly
//! along it as players over a level would be (as `fogcast render` and the bench place
//! them), or — when the scene file is not on this machine — a slow circle around the
//! viewpoint the server handed out in the welcome.
//!
//! Only the scene's camera loop is read ([`load_camera_path`]), never its meshes, and it
//! stays in the scene file's coordinates, the ones poses are sent in.

use crate::protocol::ViewPose;
use crate::scene::{load_camera_path, Camera, CameraPath};
use glam::{DQuat, DVec3};

/// Radius of the fallback circle, metres.
const ORBIT_RADIUS_M: f64 = 1.0;
/// Angular speed of the fallback circle (and of the view turning with it), rad/s.
const ORBIT_RAD_PER_S: f64 = 0.3;

/// The camera paths of every simulated viewer.
#[derive(Debug, Clone)]
pub(crate) enum Paths {
    /// The scene's camera loop.
    Scene {
        /// Scene name (for the report).
        name: String,
        /// The loop.
        path: CameraPath,
    },
    /// A circle around each view's starting pose.
    Orbit,
}

impl Paths {
    /// The scene's loop if its file (or built-in name) is known here, else circles (the
    /// reason is returned).
    pub(crate) fn load(scene: &str) -> (Paths, Option<String>) {
        match load_camera_path(scene) {
            Ok((name, path)) => (Paths::Scene { name, path }, None),
            Err(e) => (Paths::Orbit, Some(format!("scene {scene:?}: {e}"))),
        }
    }

    /// One sentence for the report.
    pub(crate) fn describe(&self) -> String {
        match self {
            Paths::Scene { name, path } => format!(
                "viewers spread evenly along scene {name:?}'s camera loop, walking it at {} m/s",
                path.speed_mps
            ),
            Paths::Orbit => format!(
                "each view circles its welcome viewpoint ({ORBIT_RADIUS_M} m radius, turning {ORBIT_RAD_PER_S} rad/s)"
            ),
        }
    }

    /// Pose of slot `slot` of `slots` (one slot per pose a client sends) at `time_s`;
    /// `start` is the slot's pose from the welcome.
    pub(crate) fn pose(
        &self,
        slot: usize,
        slots: usize,
        time_s: f64,
        start: &ViewPose,
    ) -> ViewPose {
        match self {
            Paths::Scene { path, .. } => view_pose(&path.viewers(slots, time_s as f32)[slot]),
            Paths::Orbit => {
                let phase = std::f64::consts::TAU * slot as f64 / slots.max(1) as f64;
                let angle = time_s * ORBIT_RAD_PER_S + phase;
                let centre = DVec3::from_array(start.position);
                let offset = DVec3::new(angle.cos() - phase.cos(), 0.0, angle.sin() - phase.sin())
                    * ORBIT_RADIUS_M;
                let [x, y, z, w] = start.orientation;
                let q0 = DQuat::from_xyzw(x, y, z, w);
                let len = q0.length();
                let q0 = if len.is_finite() && len > 1e-9 {
                    q0 / len
                } else {
                    DQuat::IDENTITY
                };
                let q = DQuat::from_rotation_y(time_s * ORBIT_RAD_PER_S) * q0;
                ViewPose {
                    position: (centre + offset).to_array(),
                    orientation: q.to_array(),
                    fov_y_deg: start.fov_y_deg,
                }
            }
        }
    }
}

/// The pose a client sends for `camera`.
fn view_pose(camera: &Camera) -> ViewPose {
    ViewPose {
        position: camera.position.as_dvec3().to_array(),
        orientation: camera.orientation().to_array(),
        fov_y_deg: f64::from(camera.fov_y).to_degrees(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{FOV_RANGE_DEG, MAX_COORD_M};

    /// The wire limits a server checks a pose against.
    fn assert_valid(p: &ViewPose) {
        assert!(
            p.position
                .iter()
                .all(|x| x.is_finite() && x.abs() <= MAX_COORD_M),
            "{p:?}"
        );
        let len = p.orientation.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((len - 1.0).abs() < 1e-6, "{p:?}");
        let (lo, hi) = FOV_RANGE_DEG;
        assert!((lo..=hi).contains(&p.fov_y_deg), "{p:?}");
    }

    #[test]
    fn viewers_are_spread_and_move() {
        let (paths, why) = Paths::load("colonnade");
        assert!(why.is_none(), "{why:?}");
        let start = ViewPose {
            position: [0.0; 3],
            orientation: [0.0, 0.0, 0.0, 1.0],
            fov_y_deg: 60.0,
        };
        let a = paths.pose(0, 4, 0.0, &start);
        let b = paths.pose(1, 4, 0.0, &start);
        let a_later = paths.pose(0, 4, 2.0, &start);
        let dist = |p: &ViewPose, q: &ViewPose| {
            DVec3::from_array(p.position).distance(DVec3::from_array(q.position))
        };
        assert!(dist(&a, &b) > 0.5, "{a:?} vs {b:?}");
        assert!(dist(&a, &a_later) > 0.1, "{a:?} vs {a_later:?}");
        for p in [a, b, a_later] {
            assert_valid(&p);
        }

        // A scene file's loop, read without its glTF meshes.
        let (sponza, why) = Paths::load("scenes/sponza.toml");
        assert!(matches!(sponza, Paths::Scene { .. }), "{why:?}");

        let (orbit, why) = Paths::load("no-such-scene-here");
        assert!(matches!(orbit, Paths::Orbit) && why.is_some());
        let o0 = orbit.pose(0, 1, 0.0, &start);
        assert!(
            dist(&o0, &start) < 1e-9,
            "the circle starts at the welcome pose"
        );
        let o1 = orbit.pose(0, 1, 3.0, &start);
        assert!(dist(&o1, &start) > 0.1, "the circle moves");
        assert_valid(&o1);
    }
}
