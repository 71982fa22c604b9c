//! One-sided meshes (a mesh's `cull`): the camera does not see the culled side of their
//! triangles, in the G-buffer raster and in `truth`'s camera rays alike, while light and
//! shadow rays still meet both sides. A room of four walls and a roof around the camera
//! with `cull = "back"` (a box's inside is its back side): from inside, the camera sees
//! through the walls to the lit ground and the sky outside, yet the roof still shades
//! the floor around the camera; `cull = "front"` keeps the inside and drops the outside.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::{Bvh, Camera, Scene};
use fogcast::truth::{render_truth, TruthSettings};
use glam::Vec3;
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

const SIZE: (u32, u32) = (96, 54);

fn room(cull: &str) -> Arc<Scene> {
    let text = format!(
        r#"
name = "room"
[render]
near_m = 0.1
far_m = 40.0
voxel_size_m = 0.5
sky = [0.6, 0.7, 0.9]
ambient = [0.02, 0.02, 0.02]
[camera]
path = [[0.0, 1.5, 0.0]]
fov_deg = 70.0
[[light]]
kind = "directional"
direction = [0.2, -1.0, 0.3]
color = [1.0, 1.0, 1.0]
intensity = 3.0
[[mesh]]
kind = "box"
min = [-20.0, -0.1, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.5, 0.5, 0.5]
[[mesh]]
kind = "box"
min = [-2.0, 0.02, -2.0]
max = [2.0, 3.0, 2.0]
albedo = [0.8, 0.3, 0.2]
cull = "{cull}"
[[medium]]
kind = "box"
min = [-10.0, 0.0, -10.0]
max = [10.0, 4.0, 10.0]
scattering = [0.03, 0.03, 0.03]
absorption = 0.005
g = 0.3
"#
    );
    Arc::new(
        Scene::from_toml(&text, Path::new("inline.toml"))
            .unwrap_or_else(|e| panic!("scene does not load: {e}")),
    )
}

/// Two cameras at the room's middle (world (0, 1.5, 0)), one looking out level, one down
/// past the floor toward the ground outside.
fn cameras(scene: &Scene) -> Vec<Camera> {
    let fov = 70f32.to_radians();
    let eye = (glam::DVec3::new(0.0, 1.5, 0.0) - scene.origin).as_vec3();
    vec![
        Camera::new(eye, Vec3::new(1.0, 0.0, 0.2), fov),
        Camera::new(eye, Vec3::new(0.3, -0.5, 1.0), fov),
    ]
}

/// Mean of the RGB of the RGBA8 pixels `pick` selects, 0..1.
fn mean_rgb(image: &[u8], pick: impl Fn(usize, usize) -> bool) -> f64 {
    let (w, h) = (SIZE.0 as usize, SIZE.1 as usize);
    let (mut sum, mut n) = (0.0, 0usize);
    for y in 0..h {
        for x in 0..w {
            if pick(x, y) {
                let p = &image[4 * (y * w + x)..4 * (y * w + x) + 3];
                sum += p.iter().map(|c| f64::from(*c)).sum::<f64>() / (3.0 * 255.0);
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

#[test]
fn the_camera_skips_a_culled_side_in_raster_and_truth_and_light_does_not() {
    let (w, h) = SIZE;
    let mut level = Vec::new();
    for cull in ["none", "back", "front"] {
        let scene = room(cull);
        let cams = cameras(&scene);
        let bvh = Bvh::build(&scene.mesh).unwrap();
        let (truth, _) = render_truth(
            &scene,
            &bvh,
            &cams,
            SIZE,
            0.0,
            TruthSettings {
                steps: 128,
                ..TruthSettings::default()
            },
            &|_, _| {},
        );
        let s = Settings {
            mode: Mode::Shared,
            ..Settings::for_scene(&scene)
        };
        let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, s).unwrap();
        let out = r.render(&cams, w, h, 0.0).unwrap();
        // The walls reach behind the eye: the per-view triangle culling must take their
        // side as the raster does (the clipped part winds as the whole triangle).
        let whole = Settings {
            triangle_cull: false,
            ..s
        };
        let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, whole).unwrap();
        let unculled = r.render(&cams, w, h, 0.0).unwrap();
        for (a, b) in out.images.iter().zip(&unculled.images) {
            let differ = a
                .chunks_exact(4)
                .zip(b.chunks_exact(4))
                .filter(|(p, q)| p != q)
                .count();
            assert!(
                differ <= 1,
                "cull {cull}: {differ} pixels differ from the unculled raster"
            );
        }
        for (i, (t, g)) in truth.iter().zip(&out.images).enumerate() {
            let e = compare(t, g, w, h).unwrap();
            println!(
                "cull {cull} camera {i}: shared vs truth FLIP {:.4}, mean {:.3} / {:.3}",
                e.flip_mean,
                mean_rgb(g, |_, _| true),
                mean_rgb(t, |_, _| true)
            );
            assert!(
                e.flip_mean <= 0.05,
                "cull {cull} camera {i}: FLIP {}",
                e.flip_mean
            );
            assert!((mean_rgb(g, |_, _| true) - mean_rgb(t, |_, _| true)).abs() < 0.02);
        }
        level.push(mean_rgb(&out.images[0], |_, _| true));
        if cull == "back" {
            // The roof casts its shadow through its culled side: the floor at the
            // camera's feet (the bottom rows of the downward view) is darker than the
            // sunlit ground beyond the walls (its top rows).
            let near = mean_rgb(&out.images[1], |_, y| y >= h as usize - 6);
            let far = mean_rgb(&out.images[1], |_, y| y < 6);
            println!("floor under the roof {near:.3}, ground outside {far:.3}");
            assert!(
                near < 0.7 * far,
                "the roof shades the floor: {near} vs {far}"
            );
        }
    }
    // Inside a both-sided or front-culled room the level view meets a wall in the
    // roof's shadow; with its inside culled it looks out through it to the sunlit ground
    // and the sky.
    assert!(level[0] < 0.1 && level[2] < 0.1, "{level:?}");
    assert!(level[1] > 0.5, "{level:?}");
}

#[test]
fn a_bad_cull_names_the_field_and_the_choices() {
    let text = "name = \"x\"\n[camera]\npath = [[0.0, 1.0, 0.0]]\n[[mesh]]\nkind = \"box\"\nmin = [0.0, 0.0, 0.0]\nmax = [1.0, 1.0, 1.0]\ncull = \"sideways\"\n";
    let err = Scene::from_toml(text, Path::new("inline.toml"))
        .expect_err("an unknown cull is an error")
        .to_string();
    println!("{err}");
    for part in ["mesh[0].cull", "sideways", "none", "back", "front"] {
        assert!(err.contains(part), "{part} not in: {err}");
    }
}
