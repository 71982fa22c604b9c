//! Animated lights (`swing`) and moving occluders (`[[mover]]`): bad values are named,
//! good ones move as declared.

use fogcast::scene::Scene;
use std::path::Path;

const BASE: &str = r#"
name = "motion"

[camera]
path = [[0.0, 1.5, 4.0], [0.0, 1.5, -4.0]]

[[light]]
kind = "point"
position = [0.0, 3.0, 0.0]
intensity = 50.0
LIGHT_EXTRA

[[mesh]]
kind = "box"
min = [-5.0, -0.25, -5.0]
max = [5.0, 0.0, 5.0]

MOVER
"#;

const MOVER: &str = r#"[[mover]]
min = [-1.0, 1.0, -0.1]
max = [1.0, 1.2, 0.1]
pivot = [0.0, 1.1, 0.0]
axis = [0.0, 1.0, 0.0]
degrees_per_s = 90.0"#;

fn load(light_extra: &str, mover: &str) -> Result<Scene, String> {
    let text = BASE
        .replace("LIGHT_EXTRA", light_extra)
        .replace("MOVER", mover);
    Scene::from_toml(&text, Path::new("motion.toml")).map_err(|e| e.to_string())
}

#[test]
fn bad_motion_values_are_named() {
    let cases = [
        (
            "swing = { axis = [0.0, 0.0, 0.0], degrees = 10.0, period_s = 2.0 }",
            MOVER.to_string(),
            "light[0].swing.axis",
        ),
        (
            "swing = { axis = [0.0, 0.0, 1.0], degrees = 400.0, period_s = 2.0 }",
            MOVER.to_string(),
            "light[0].swing.degrees",
        ),
        (
            "swing = { axis = [0.0, 0.0, 1.0], degrees = 10.0, period_s = 0.0 }",
            MOVER.to_string(),
            "light[0].swing.period_s",
        ),
        (
            "",
            MOVER.replace("max = [1.0, 1.2, 0.1]", "max = [1.0, 0.5, 0.1]"),
            "mover[0].max",
        ),
        (
            "",
            MOVER.replace("axis = [0.0, 1.0, 0.0]", "axis = [0.0, 0.0, 0.0]"),
            "mover[0].axis",
        ),
        (
            "",
            MOVER.replace("degrees_per_s = 90.0", "degrees_per_s = nan"),
            "mover[0].degrees_per_s",
        ),
    ];
    for (light, mover, field) in cases {
        let err = load(light, &mover).expect_err(field);
        assert!(err.contains(field), "expected {field} in: {err}");
    }
}

#[test]
fn lights_swing_and_movers_turn_as_declared() {
    let scene = load(
        "swing = { pivot = [0.0, 5.0, 0.0], axis = [0.0, 0.0, 1.0], degrees = 30.0, period_s = 4.0 }",
        MOVER,
    )
    .unwrap();
    assert!(scene.has_animated_lights());
    // A quarter period: the full amplitude, 30° about the pivot 2 m above the lamp.
    let l0 = scene.lights_at(0.0)[0];
    let l1 = scene.lights_at(1.0)[0];
    let pivot = scene.lights[0].swing.unwrap().pivot;
    assert!((l0.position.distance(pivot) - 2.0).abs() < 1e-4);
    assert!((l1.position.distance(pivot) - 2.0).abs() < 1e-4);
    let angle = (l0.position - pivot).angle_between(l1.position - pivot);
    assert!((angle.to_degrees() - 30.0).abs() < 0.01, "{angle}");

    // The mover turns 90° per second about +y: its long x extent becomes z extent.
    let m = &scene.movers[0];
    let (lo0, hi0) = m.bounds_at(0.0);
    let (lo1, hi1) = m.bounds_at(1.0);
    assert!(((hi0 - lo0).x - 2.0).abs() < 1e-4 && ((hi0 - lo0).z - 0.2).abs() < 1e-4);
    assert!(((hi1 - lo1).z - 2.0).abs() < 1e-4 && ((hi1 - lo1).x - 0.2).abs() < 1e-4);
    // The scene bounds hold everything the mover can reach.
    let (rlo, rhi) = m.reach();
    assert!(rlo.cmpge(scene.bounds.0).all() && rhi.cmple(scene.bounds.1).all());
}
