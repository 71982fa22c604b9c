//! Per-view triangle culling before the G-buffer (`triangle_cull`, shaders/triangle_cull.wgsl):
//! each view draws only the triangles the raster makes fragments of — inside the clip
//! volume, facing the eye where the mesh is one-sided, their screen box holding a pixel
//! centre — written in the scene's order into its own index list. The picture must be
//! the one every cluster's triangles give (a triangle that covers no pixel centre makes
//! no fragment), from far fewer triangles.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{
    FrameTarget, Renderer, Settings, TargetsOutput, MICRO_MIN_TRIANGLES, OCCLUSION_MIN_TRIANGLES,
};
use fogcast::scene::Scene;
use gpu_support::{colonnade, gpu};
use std::sync::Arc;

/// One frame of `viewers` mono views of `w`×`h` along the scene's path at `time_s`.
/// The last of the frames at scene times `times` of `viewers` path viewers, one renderer
/// with `settings` (a renderer keeps its occlusion history from frame to frame).
fn render(
    scene: &Arc<Scene>,
    settings: Settings,
    viewers: usize,
    (w, h): (u32, u32),
    times: &[f32],
) -> TargetsOutput {
    let mut r = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    let mut last = None;
    for &t in times {
        let targets: Vec<FrameTarget> = scene
            .camera
            .viewers(viewers, t)
            .into_iter()
            .enumerate()
            .map(|(i, c)| FrameTarget::single(i as u64, c, w, h))
            .collect();
        last = Some(r.render_targets(&targets, t).unwrap());
    }
    last.expect("at least one frame")
}

/// One frame at `time_s`, with or without per-view triangle culling; every kept
/// triangle drawn by the raster (`micro_raster` off: its own test below).
fn frame(
    scene: &Arc<Scene>,
    cull: bool,
    viewers: usize,
    size: (u32, u32),
    time_s: f32,
) -> TargetsOutput {
    let settings = Settings {
        triangle_cull: cull,
        micro_raster: false,
        ..Settings::default()
    };
    render(scene, settings, viewers, size, &[time_s])
}

/// One frame at `time_s` with triangle culling, the small triangles rasterised in
/// compute (`micro_raster`) or by the raster.
fn frame_micro(
    scene: &Arc<Scene>,
    micro: bool,
    viewers: usize,
    size: (u32, u32),
    time_s: f32,
) -> TargetsOutput {
    let settings = Settings {
        micro_raster: micro,
        ..Settings::default()
    };
    render(scene, settings, viewers, size, &[time_s])
}

/// The share of the views' pixels that `pixels` is.
fn share(pixels: usize, (w, h): (u32, u32), views: usize) -> f64 {
    pixels as f64 / (w as u64 * h as u64 * views as u64) as f64
}

#[test]
fn small_triangles_rasterised_in_compute_draw_the_rasters_picture() {
    // `micro_raster`: Sponza's triangles whose screen box holds at most 4 × 4 pixel
    // centres are rasterised by the culling pass (snapped corners, top-left rule) and
    // resolved against the raster's depth. Pixels may differ where the two disagree on
    // an edge exactly through a centre or on a depth tie; the picture must not.
    let scene = Arc::new(Scene::load("scenes/sponza.toml").expect("scenes/sponza.toml loads"));
    const SIZE: (u32, u32) = (320, 180);
    let micro = frame_micro(&scene, true, 4, SIZE, 0.0);
    let raster = frame_micro(&scene, false, 4, SIZE, 0.0);
    let (pixels, flip) = differences(&micro, &raster, SIZE);
    println!(
        "4 views of Sponza at 320×180: {} triangles drawn with micro_raster, {} without; \
         {pixels} pixels differ ({:.3} %), worst mean FLIP {flip:.2e}",
        micro.stats.raster_triangles,
        raster.stats.raster_triangles,
        100.0 * share(pixels, SIZE, 4)
    );
    assert!(share(pixels, SIZE, 4) < 0.002, "{pixels} pixels differ");
    assert!(flip < 1e-3, "FLIP {flip}");
    // The triangles drawn: the small ones count where they covered a centre, fewer than
    // the list keeps of them (it keeps any that may cover one, 61,334 against 77,131).
    let (m, r) = (micro.stats.raster_triangles, raster.stats.raster_triangles);
    assert!(m <= r && m as f64 > 0.7 * r as f64, "{m} vs {r}");
    // Its word a pixel is per-viewer memory.
    let lists = |o: &TargetsOutput| {
        o.stats
            .memory
            .per_viewer
            .iter()
            .find(|(n, _)| n == "triangle_lists")
            .map_or(0, |(_, b)| *b)
    };
    assert!(lists(&micro) >= lists(&raster) + 4 * 320 * 180 * 8 / 4);
    // Views of 7×3 and 1×1 pixels, where every triangle is small; a second frame reads
    // the words the first one's resolve cleared.
    for size in [(7, 3), (1, 1)] {
        let micro = render(&scene, Settings::default(), 3, size, &[0.0, 0.1]);
        let raster = frame_micro(&scene, false, 3, size, 0.1);
        let (pixels, flip) = differences(&micro, &raster, size);
        println!("Sponza at {size:?}: {pixels} pixels differ, FLIP {flip:.2e}");
        assert!(
            pixels <= 1,
            "{size:?}: {pixels} pixels differ (FLIP {flip})"
        );
    }
}

#[test]
fn small_scenes_leave_small_triangles_to_the_raster() {
    // Colonnade's few hundred triangles: `micro_raster`'s resolve would cost more than
    // its small triangles, so the raster draws them, the same with the setting on.
    let scene = colonnade();
    assert!((scene.mesh.indices.len() as u64 / 3) < MICRO_MIN_TRIANGLES);
    let on = frame_micro(&scene, true, 3, (7, 3), 1.2);
    let off = frame_micro(&scene, false, 3, (7, 3), 1.2);
    assert_eq!(on.stats.raster_triangles, off.stats.raster_triangles);
    assert_eq!(differences(&on, &off, (7, 3)).0, 0);
}

/// Pixels that differ, and the worst image's mean FLIP, culled against unculled.
fn differences(a: &TargetsOutput, b: &TargetsOutput, (w, h): (u32, u32)) -> (usize, f64) {
    let mut pixels = 0;
    let mut worst: f64 = 0.0;
    for (x, y) in a.images.iter().zip(&b.images) {
        pixels += x
            .chunks_exact(4)
            .zip(y.chunks_exact(4))
            .filter(|(p, q)| p != q)
            .count();
        worst = worst.max(compare(x, y, w, h).unwrap().flip_mean);
    }
    (pixels, worst)
}

#[test]
fn sponza_culled_to_a_fifth_of_its_triangles_draws_the_same_picture() {
    let scene = Arc::new(Scene::load("scenes/sponza.toml").expect("scenes/sponza.toml loads"));
    const SIZE: (u32, u32) = (320, 180);
    let culled = frame(&scene, true, 4, SIZE, 0.0);
    let whole = frame(&scene, false, 4, SIZE, 0.0);
    let (pixels, flip) = differences(&culled, &whole, SIZE);
    let (drawn, all) = (
        culled.stats.raster_triangles,
        culled.stats.raster_triangles_in_clusters,
    );
    println!(
        "4 views of Sponza at 320×180: {drawn} of {all} triangles drawn ({:.1} %); \
         {pixels} pixels differ, worst mean FLIP {flip:.2e}",
        100.0 * drawn as f64 / all as f64
    );
    // Without culling every triangle of the touched clusters is drawn.
    assert_eq!(whole.stats.raster_triangles, all);
    assert_eq!(whole.stats.raster_triangles_in_clusters, all);
    assert!(
        (drawn as f64) < 0.3 * all as f64,
        "{drawn} of {all} triangles drawn"
    );
    assert!(drawn > 0);
    // A triangle the test keeps or drops differently from the raster (its area within
    // rounding of zero) can change a pixel: 1 of 230,400 measured.
    assert!(pixels <= 4, "{pixels} pixels differ");
    assert!(flip < 1e-4, "FLIP {flip}");
    // The lists are memory of their own, per viewer.
    let lists = culled
        .stats
        .memory
        .per_viewer
        .iter()
        .find(|(n, _)| n == "triangle_lists")
        .map(|(_, b)| *b);
    assert!(lists.is_some_and(|b| b > 0), "{:?}", culled.stats.memory);
}

#[test]
fn one_sided_meshes_movers_and_tiny_views_draw_the_same_picture_culled() {
    // Colonnade: one-sided boxes and cylinders (their back faces culled in the pass),
    // a swinging mover (drawn whole after the list), at 1.2 s; and views of 1×1 and
    // 7×3 pixels, where nearly every triangle falls between pixel centres.
    let scene = colonnade();
    for size in [(160, 90), (7, 3), (1, 1)] {
        let culled = frame(&scene, true, 3, size, 1.2);
        let whole = frame(&scene, false, 3, size, 1.2);
        let (pixels, flip) = differences(&culled, &whole, size);
        println!(
            "colonnade at {size:?}: {} of {} triangles drawn, {pixels} pixels differ",
            culled.stats.raster_triangles, culled.stats.raster_triangles_in_clusters
        );
        assert!(
            pixels <= 1,
            "{size:?}: {pixels} pixels differ (FLIP {flip})"
        );
        assert!(
            culled.stats.raster_triangles < culled.stats.raster_triangles_in_clusters,
            "{size:?}"
        );
    }
}

/// `frames` frames at 30 fps from t = 0 of `viewers` mono views with `occlusion_cull`
/// on or off (triangle culling on); the last frame's output.
fn frames_occluded(
    scene: &Arc<Scene>,
    occlusion: bool,
    viewers: usize,
    size: (u32, u32),
    frames: usize,
) -> TargetsOutput {
    let settings = Settings {
        occlusion_cull: occlusion,
        micro_raster: false,
        ..Settings::default()
    };
    let times: Vec<f32> = (0..frames).map(|f| f as f32 / 30.0).collect();
    render(scene, settings, viewers, size, &times)
}

#[test]
fn occlusion_culling_draws_the_same_picture_from_fewer_triangles() {
    // Sponza's arcades hide much of what each view's frustum holds. The first frame has
    // no history (its first phase is empty, its test passes everything); the third
    // draws last frame's visible triangles, then the rest that pass the depth tiles.
    let scene = Arc::new(Scene::load("scenes/sponza.toml").expect("scenes/sponza.toml loads"));
    assert!(scene.mesh.indices.len() as u64 / 3 >= OCCLUSION_MIN_TRIANGLES);
    const SIZE: (u32, u32) = (320, 180);
    let occluded = frames_occluded(&scene, true, 4, SIZE, 3);
    let kept = frames_occluded(&scene, false, 4, SIZE, 3);
    let (pixels, flip) = differences(&occluded, &kept, SIZE);
    let (with, without) = (occluded.stats.raster_triangles, kept.stats.raster_triangles);
    println!(
        "4 views of Sponza at 320×180, frame 3: {with} triangles drawn with occlusion \
         culling, {without} without ({:.1} %); {pixels} pixels differ, worst FLIP {flip:.2e}",
        100.0 * with as f64 / without as f64
    );
    assert!(
        (with as f64) < 0.85 * without as f64,
        "{with} vs {without} triangles"
    );
    assert!(with > 0);
    assert!(pixels <= 4, "{pixels} pixels differ");
    assert!(flip < 1e-4, "FLIP {flip}");
    // The depth tiles and the seen-triangle bits are per-viewer memory.
    let lists = |o: &TargetsOutput| {
        o.stats
            .memory
            .per_viewer
            .iter()
            .find(|(n, _)| n == "triangle_lists")
            .map_or(0, |(_, b)| *b)
    };
    assert!(lists(&occluded) > lists(&kept));
}

#[test]
fn occlusion_culling_leaves_small_scenes_to_one_phase() {
    // Colonnade's few hundred triangles: the second phase would cost more than it saves,
    // so the raster draws what triangle culling keeps, the same with the setting on.
    let scene = colonnade();
    assert!((scene.mesh.indices.len() as u64 / 3) < OCCLUSION_MIN_TRIANGLES);
    let on = frames_occluded(&scene, true, 3, (160, 90), 3);
    let off = frames_occluded(&scene, false, 3, (160, 90), 3);
    assert_eq!(on.stats.raster_triangles, off.stats.raster_triangles);
    assert_eq!(differences(&on, &off, (160, 90)).0, 0);
}
