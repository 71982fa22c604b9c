//! Malformed scene files fail to load with a message that names the field at fault and
//! the offending value; degenerate geometry is dropped rather than traced.

use fogcast::scene::Scene;
use scene_support::{base64, write_gltf, TempDir};
use std::path::Path;

mod scene_support;

/// A valid scene; each case replaces one line (or appends a table) to break it.
const VALID: &str = r#"
name = "errors"

[camera]
path = [[0.0, 1.5, 4.0], [0.0, 1.5, -4.0]]

[[light]]
kind = "spot"
position = [0.0, 4.0, 0.0]
direction = [0.0, -1.0, 0.0]
intensity = 50.0
inner_deg = 20.0
outer_deg = 30.0

[[mesh]]
kind = "box"
min = [-5.0, -0.25, -5.0]
max = [5.0, 0.0, 5.0]

[[medium]]
kind = "box"
min = [-4.0, 0.0, -4.0]
max = [4.0, 3.0, 4.0]
scattering = [0.1, 0.1, 0.1]
absorption = 0.01
g = 0.5
"#;

/// `VALID` with the one line that starts with `old` replaced by `new`.
fn with_line(old: &str, new: &str) -> String {
    let mut hits = 0;
    let text: Vec<String> = VALID
        .lines()
        .map(|line| {
            if line.starts_with(old) {
                hits += 1;
                new.to_string()
            } else {
                line.to_string()
            }
        })
        .collect();
    assert_eq!(hits, 1, "test setup: `{old}` must start exactly one line");
    text.join("\n")
}

/// The load error of `text`; panics if it loads.
fn load_error(text: &str) -> String {
    match Scene::from_toml(text, Path::new("inline.toml")) {
        Ok(_) => panic!("this scene must be rejected:\n{text}"),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(message: &str, parts: &[&str]) {
    println!("{message}\n");
    for p in parts {
        assert!(
            message.contains(p),
            "error message does not mention `{p}`:\n{message}"
        );
    }
}

#[test]
fn the_base_scene_is_valid() {
    let scene = Scene::from_toml(VALID, Path::new("inline.toml")).expect("VALID loads");
    assert_eq!(
        (scene.mesh.len(), scene.lights.len(), scene.media.len()),
        (12, 1, 1)
    );
}

#[test]
fn negative_absorption() {
    let msg = load_error(&with_line("absorption", "absorption = -0.5"));
    assert_mentions(&msg, &["medium[0].absorption", "-0.5"]);
}

#[test]
fn hg_g_of_one() {
    let msg = load_error(&with_line("g = ", "g = 1.0"));
    assert_mentions(&msg, &["medium[0].g", "1.0", "between -1 and 1"]);
}

#[test]
fn nan_and_inf_written_in_toml() {
    let cases = [
        (
            with_line("absorption", "absorption = nan"),
            ["medium[0].absorption", "NaN"],
        ),
        (
            with_line("scattering", "scattering = [0.1, -nan, 0.1]"),
            ["medium[0].scattering", "NaN"],
        ),
        (
            with_line("intensity", "intensity = inf"),
            ["light[0].intensity", "inf"],
        ),
        (
            with_line("position", "position = [0.0, -inf, 0.0]"),
            ["light[0].position", "-inf"],
        ),
        (
            with_line("path", "path = [[0.0, 1.5, 4.0], [nan, 1.5, -4.0]]"),
            ["camera.path[1]", "NaN"],
        ),
        (
            with_line("max = [4.0", "max = [4.0, +inf, 4.0]"),
            ["medium[0].max", "inf"],
        ),
        (with_line("g = ", "g = nan"), ["medium[0].g", "NaN"]),
    ];
    for (text, parts) in cases {
        assert_mentions(&load_error(&text), &parts);
    }
}

#[test]
fn missing_box_min() {
    let medium_min = "min = [-4.0";
    let msg = load_error(&with_line(medium_min, ""));
    assert_mentions(&msg, &["medium[0].min", "missing"]);
}

#[test]
fn unknown_fields_are_named() {
    // A typo in a medium, an extra field on a box mesh, an unknown top-level table.
    let msg = load_error(&with_line("scattering", "scatering = [0.1, 0.1, 0.1]"));
    assert_mentions(&msg, &["unknown field", "scatering", "line"]);
    let msg = load_error(&with_line(
        "max = [5.0",
        "max = [5.0, 0.0, 5.0]\nradius = 2.0",
    ));
    assert_mentions(&msg, &["unknown field", "radius"]);
    let msg = load_error(&format!("{VALID}\n[renderer]\nexposure = 2.0\n"));
    assert_mentions(&msg, &["unknown field", "renderer"]);
}

#[test]
fn spot_inner_angle_wider_than_outer() {
    let msg = load_error(&with_line("inner_deg", "inner_deg = 50.0"));
    assert_mentions(&msg, &["light[0].inner_deg", "50.0", "outer_deg"]);
}

#[test]
fn gltf_path_that_does_not_exist() {
    let text = format!("{VALID}\n[[mesh]]\nkind = \"gltf\"\npath = \"meshes/no_such_model.glb\"\n");
    let msg = load_error(&text);
    assert_mentions(
        &msg,
        &[
            "mesh[1].path",
            "\"meshes/no_such_model.glb\"",
            "no such file",
        ],
    );
}

#[test]
fn empty_camera_path() {
    let msg = load_error(&with_line("path", "path = []"));
    assert_mentions(&msg, &["camera.path", "[]", "at least one point"]);
}

/// `VALID` plus the glTF `mesh.gltf`, resolved against the scene file's folder.
fn load_with_gltf(dir: &Path) -> Result<Scene, fogcast::scene::SceneError> {
    let text = format!("{VALID}\n[[mesh]]\nkind = \"gltf\"\npath = \"mesh.gltf\"\n");
    Scene::from_toml(&text, &dir.join("scene.toml"))
}

#[test]
fn base64_matches_rfc_4648_vectors() {
    for (input, want) in [
        ("", ""),
        ("f", "Zg=="),
        ("fo", "Zm8="),
        ("foo", "Zm9v"),
        ("foobar", "Zm9vYmFy"),
    ] {
        assert_eq!(base64(input.as_bytes()), want);
    }
}

#[test]
fn gltf_with_a_nan_vertex() {
    let dir = TempDir::new("nan");
    write_gltf(
        dir.path(),
        &[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]],
    );
    let err = load_with_gltf(dir.path()).expect_err("NaN vertex must be rejected");
    assert_mentions(
        &err.to_string(),
        &["mesh.gltf", "mesh 0 primitive 0 vertex 1", "NaN", "finite"],
    );
}

#[test]
fn zero_area_triangles_are_dropped() {
    let dir = TempDir::new("degenerate");
    let tris: [[[f32; 3]; 3]; 4] = [
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        // Collinear corners.
        [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        // A repeated corner.
        [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, 1.0]],
        [[0.0, 0.0, 2.0], [0.0, 1.0, 2.0], [1.0, 0.0, 2.0]],
    ];
    let vertices: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    write_gltf(dir.path(), &vertices);
    let scene = load_with_gltf(dir.path()).expect("loads");
    // VALID's floor box is 12 triangles; the glTF adds its 2 with area.
    assert_eq!(
        scene.mesh.len(),
        12 + 2,
        "degenerate triangles must be dropped"
    );
    for i in 0..scene.mesh.len() {
        let [a, b, c] = scene.mesh.triangle(i);
        assert!(
            (b - a).cross(c - a).length() > 0.0,
            "triangle {i} has zero area"
        );
    }

    // Built-in primitives: 12 triangles a box, 4 per facet a cylinder (side ×2, two caps).
    let text = with_line("max = [5.0", "max = [5.0, 0.0, 5.0]\n[[mesh]]\nkind = \"cylinder\"\nbase = [0.0, 0.0, 0.0]\nradius = 0.5\nheight = 3.0\nsegments = 7");
    let scene = Scene::from_toml(&text, Path::new("inline.toml")).expect("loads");
    assert_eq!(scene.mesh.len(), 12 + 4 * 7);
}

/// `VALID` with a `[[volume]]` table whose line starting with `old` (if any) is `new`.
/// `VALID` and then `table` with the one line that starts with `old` replaced by `new`
/// (`old` empty: unchanged).
fn replace_line(table: &str, old: &str, new: &str) -> String {
    let mut hits = 0;
    let lines: Vec<&str> = table
        .lines()
        .map(|line| {
            if !old.is_empty() && line.starts_with(old) {
                hits += 1;
                new
            } else {
                line
            }
        })
        .collect();
    assert!(
        old.is_empty() || hits == 1,
        "test setup: `{old}` must start one line"
    );
    format!("{VALID}{}", lines.join("\n"))
}

fn with_volume(old: &str, new: &str) -> String {
    let volume = "\n[[volume]]\ncenter = [0.0, 1.5, 0.0]\nradius = 1.0\n\
                  scattering = [0.5, 0.5, 0.5]\nabsorption = 0.1\n\
                  [volume.displacement]\namplitude = 0.3\nfrequency = 2.0\n\
                  [volume.motion]\nvelocity = [1.0, 0.0, 0.0]\nperiod_s = 4.0\n";
    replace_line(volume, old, new)
}

#[test]
fn a_valid_volume_loads_as_a_medium_bounded_over_its_path() {
    let scene = Scene::from_toml(&with_volume("", ""), Path::new("inline.toml")).unwrap();
    assert_eq!(scene.media.len(), 2);
    let m = &scene.media[1];
    // Path ±2 m along x, outer radius 1.3 m.
    let size = m.max - m.min;
    assert!(
        (size - glam::Vec3::new(6.6, 2.6, 2.6)).abs().max_element() < 1e-4,
        "{size}"
    );
}

#[test]
fn volume_values_out_of_range() {
    let cases: [(String, &[&str]); 10] = [
        (
            with_volume("radius", "radius = 0.0"),
            &["volume[0].radius", "0"],
        ),
        (
            with_volume("radius", "radius = -2.5"),
            &["volume[0].radius", "-2.5"],
        ),
        (
            with_volume("radius", "radius = nan"),
            &["volume[0].radius", "NaN"],
        ),
        (
            with_volume("scattering", "scattering = [0.5, -0.25, 0.5]"),
            &["volume[0].scattering", "-0.25"],
        ),
        (
            with_volume("absorption", "absorption = -1.0"),
            &["volume[0].absorption", "-1"],
        ),
        (
            with_volume("center", "center = [0.0, nan, 0.0]"),
            &["volume[0].center", "NaN"],
        ),
        (
            with_volume("amplitude", "amplitude = 0.95"),
            &["volume[0].displacement.amplitude", "0.95", "0.9"],
        ),
        (
            with_volume("frequency", "frequency = inf"),
            &["volume[0].displacement.frequency", "inf"],
        ),
        (
            with_volume("period_s", "period_s = 0.0"),
            &["volume[0].motion.period_s", "0"],
        ),
        (
            with_volume("velocity", "velocity = [1e5, 0.0, 0.0]"),
            &["volume[0].motion.velocity", "100000"],
        ),
    ];
    for (text, parts) in cases {
        assert_mentions(&load_error(&text), parts);
    }
}

#[test]
fn volumes_are_not_a_medium_kind_and_typos_are_named() {
    let text = VALID.replace(
        "[[medium]]\nkind = \"box\"",
        "[[medium]]\nkind = \"volume\"",
    );
    assert_mentions(&load_error(&text), &["volume"]);
    let msg = load_error(&with_volume("radius", "raduis = 1.0"));
    assert_mentions(&msg, &["raduis"]);
}

/// `VALID` with an `[[emitter]]` table whose line starting with `old` (if any) is `new`.
fn with_emitter(old: &str, new: &str) -> String {
    let emitter = "\n[[emitter]]\nshape = \"disc\"\nposition = [0.0, 2.0, 0.0]\nradius = 0.3\n\
                   rate_per_s = 20.0\nlifetime_s = 4.0\nvelocity = [0.0, 0.5, 0.0]\n\
                   spread = 0.2\nbuoyancy = 0.3\nwind = [0.5, 0.0, 0.0]\ngrowth = 0.2\n\
                   falloff_u = 0.4\nscattering = [2.0, 2.0, 2.0]\nabsorption = 0.5\n\
                   g = 0.3\nmax_particles = 500\n";
    replace_line(emitter, old, new)
}

#[test]
fn a_valid_emitter_loads_and_simulates() {
    let scene = Scene::from_toml(&with_emitter("", ""), Path::new("inline.toml")).unwrap();
    assert_eq!(scene.emitters.len(), 1);
    let live = fogcast::smoke::emitter::particles_at(&scene.emitters[0], 10.0);
    assert_eq!(live.len(), 80);
}

#[test]
fn emitter_values_out_of_range() {
    let cases: [(String, &[&str]); 12] = [
        (
            with_emitter("rate_per_s", "rate_per_s = 0.0"),
            &["emitter[0].rate_per_s", "0"],
        ),
        (
            with_emitter("lifetime_s", "lifetime_s = -1.0"),
            &["emitter[0].lifetime_s", "-1"],
        ),
        (
            with_emitter("position", "position = [0.0, nan, 0.0]"),
            &["emitter[0].position", "NaN"],
        ),
        (
            with_emitter("radius", "radius = 0.0"),
            &["emitter[0].radius", "0", "disc"],
        ),
        (
            with_emitter("shape", "shape = \"point\""),
            &["emitter[0].radius", "0.3", "point"],
        ),
        (
            with_emitter("spread", "spread = -0.5"),
            &["emitter[0].spread", "-0.5"],
        ),
        (
            with_emitter("wind", "wind = [inf, 0.0, 0.0]"),
            &["emitter[0].wind", "inf"],
        ),
        (
            with_emitter("growth", "growth = -0.1"),
            &["emitter[0].growth", "-0.1", "shrink"],
        ),
        (
            with_emitter("falloff_u", "falloff_u = 0.0"),
            &["emitter[0].falloff_u", "0"],
        ),
        (
            with_emitter("scattering", "scattering = [2.0, -1.0, 2.0]"),
            &["emitter[0].scattering", "-1"],
        ),
        (with_emitter("g = ", "g = 1.0"), &["emitter[0].g", "1"]),
        (
            with_emitter("max_particles", "max_particles = 2000000"),
            &["emitter[0].max_particles", "2000000"],
        ),
    ];
    for (text, parts) in cases {
        assert_mentions(&load_error(&text), parts);
    }
}

#[test]
fn emitter_typos_and_unknown_shapes_are_named() {
    assert_mentions(
        &load_error(&with_emitter("lifetime_s", "lifetime = 4.0")),
        &["lifetime"],
    );
    assert_mentions(
        &load_error(&with_emitter("shape", "shape = \"cone\"")),
        &["cone"],
    );
}
