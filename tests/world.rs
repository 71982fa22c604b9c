//! One world per frame (issue 12): sessions of three view sizes and layouts render in one
//! frame with one submission; the world's stages run once and trace the union of what
//! the viewers need; every session's frame is bit-identical to rendering it alone against
//! the same world state; and a viewer's frames do not change when others join or leave.

mod gpu_support;

use fogcast::gpu::GpuContext;
use fogcast::render::{FrameTarget, Renderer, Settings, ViewerId};
use fogcast::scene::Camera;
use gpu_support::{colonnade, gpu};
use std::sync::Arc;

/// A session's frame of `cols × rows` tiles of `view` pixels, one camera per tile.
fn session(first_id: ViewerId, cams: &[Camera], view: (u32, u32), cols: u32) -> FrameTarget {
    FrameTarget::tiled(first_id, cams, view, cols)
}

fn popcount(words: &[u32]) -> u32 {
    words.iter().map(|w| w.count_ones()).sum()
}

#[test]
fn three_sessions_of_three_sizes_share_one_world_in_one_submission() {
    let scene = colonnade();
    let cams = scene.camera.viewers(7, 0.0);
    let targets = [
        // A 320×180 mono session, a 640×360 stereo one (two 320×360 eyes side by side,
        // as the server tiles them) and a 2×2 split of 480×270 (four 240×135 views).
        session(10, &cams[0..1], (320, 180), 1),
        session(20, &cams[1..3], (320, 360), 2),
        session(30, &cams[3..7], (240, 135), 2),
    ];
    assert_eq!(
        [
            (targets[1].width, targets[1].height),
            (targets[2].width, targets[2].height)
        ],
        [(640, 360), (480, 270)]
    );
    let settings = Settings::default();
    let time = 0.5;
    // A device of its own: the other tests of this binary submit to the shared one.
    let own = Arc::new(GpuContext::new().expect("a Vulkan adapter"));
    let mut together = Renderer::new(own.clone(), scene.clone(), settings).unwrap();
    let submissions = own.submissions();
    let all = together.render_targets(&targets, time).unwrap();
    assert_eq!(
        own.submissions() - submissions,
        1,
        "one queue submission per frame"
    );
    let s = &all.stats;
    let ran = |name: &str| s.dispatches.iter().filter(|(n, _)| n == name).count();
    println!("dispatches: {:?}", s.dispatches);
    assert_eq!(
        (ran("shared_grid"), ran("shadow_maps")),
        (1, 1),
        "world stages once"
    );
    assert_eq!(ran("froxel_lighting"), 3, "one dispatch per view size");
    assert_eq!(s.viewers, 7);
    assert_eq!(s.view_sizes.len(), 3);
    let (_, touched_all) = together.read_shared_grid().unwrap().expect("a grid");

    let mut union = vec![0u32; touched_all.len()];
    let mut rays_alone = Vec::new();
    for (i, t) in targets.iter().enumerate() {
        let mut alone = Renderer::new(gpu(), scene.clone(), settings).unwrap();
        let one = alone.render_targets(std::slice::from_ref(t), time).unwrap();
        assert_eq!(one.images[0].len(), (t.width * t.height * 4) as usize);
        assert!(
            one.images[0] == all.images[i],
            "session {i} differs from rendering it alone"
        );
        let (_, touched) = alone.read_shared_grid().unwrap().expect("a grid");
        for (u, w) in union.iter_mut().zip(&touched) {
            *u |= w;
        }
        rays_alone.push(one.stats.rays.shared_grid);
    }
    println!(
        "grid rays: together {}, alone {rays_alone:?} (sum {}); voxels traced together {}, union of alone {}",
        s.rays.shared_grid,
        rays_alone.iter().sum::<u64>(),
        popcount(&touched_all),
        popcount(&union)
    );
    assert!(
        union == touched_all,
        "the grid traced exactly the union of what the sessions need"
    );
    assert!(s.rays.shared_grid >= *rays_alone.iter().max().unwrap());
    assert!(
        s.rays.shared_grid < rays_alone.iter().sum::<u64>(),
        "overlapping sessions share voxels: {} vs sum {}",
        s.rays.shared_grid,
        rays_alone.iter().sum::<u64>()
    );
}

#[test]
fn a_viewer_is_unchanged_by_others_joining_and_leaving() {
    let scene = colonnade();
    let settings = Settings {
        temporal: true,
        ..Settings::default()
    };
    let (w, h) = (96, 54);
    let frames = 5;
    let cam = |id: u64, f: u32| scene.camera.viewers(3, f as f32 / 30.0)[id as usize % 3];
    let b = |f: u32| FrameTarget::single(1, cam(1, f), w, h);
    let a = |f: u32| FrameTarget::single(2, cam(2, f), w, h);
    let c = |f: u32| FrameTarget::single(3, cam(0, f), 64, 36);
    // B alone every frame, then B while A (same size: B's slot moves) and C (another
    // size) come and go between frames, A placed before B.
    let mut alone = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    let mut churn = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    for f in 0..frames {
        let t = f as f32 / 30.0;
        let solo = alone.render_targets(&[b(f)], t).unwrap();
        let others: Vec<FrameTarget> = match f {
            0 => vec![b(f)],
            1 => vec![a(f), b(f)],
            2 => vec![a(f), c(f), b(f)],
            3 => vec![b(f)],
            _ => vec![c(f), a(f), b(f)],
        };
        let with = churn.render_targets(&others, t).unwrap();
        let mine = with.images.last().unwrap();
        assert!(
            *mine == solo.images[0],
            "frame {f}: viewer B changed when others joined or left ({} viewers)",
            others.len()
        );
    }
}

#[test]
fn uncovered_tiles_are_opaque_black_and_views_land_in_their_tiles() {
    let scene = colonnade();
    let cams = scene.camera.viewers(3, 0.0);
    let view = (64, 36);
    // A 2×2 split with three views: the fourth tile is nobody's.
    let split = session(1, &cams, view, 2);
    let mut r = Renderer::new(gpu(), scene.clone(), Settings::default()).unwrap();
    let out = r.render_targets(std::slice::from_ref(&split), 0.0).unwrap();
    let frame = &out.images[0];
    let px = |x: u32, y: u32| {
        let i = ((y * split.width + x) * 4) as usize;
        &frame[i..i + 4]
    };
    assert_eq!(px(100, 50), [0, 0, 0, 255], "the empty tile");
    // Each tile equals that view rendered on its own.
    let mut single = Renderer::new(gpu(), scene.clone(), Settings::default()).unwrap();
    let views = single.render(&cams, view.0, view.1, 0.0).unwrap();
    for (i, img) in views.images.iter().enumerate() {
        let (x0, y0) = ((i as u32 % 2) * view.0, (i as u32 / 2) * view.1);
        for y in 0..view.1 {
            let row = &img[(y * view.0 * 4) as usize..((y + 1) * view.0 * 4) as usize];
            let at = (((y0 + y) * split.width + x0) * 4) as usize;
            assert!(row == &frame[at..at + row.len()], "view {i} row {y}");
        }
    }
}

#[test]
fn after_invalidate_a_frame_is_computed_from_scratch() {
    let scene = colonnade();
    let cams = scene.camera.viewers(2, 0.0);
    let mut r = Renderer::new(gpu(), scene.clone(), Settings::default()).unwrap();
    let first = r.render(&cams, 96, 54, 0.0).unwrap();
    let cached = r.render(&cams, 96, 54, 0.0).unwrap();
    assert!(
        cached.stats.rays.shared_grid < first.stats.rays.shared_grid,
        "the second frame reads its grid from the cache"
    );
    r.invalidate();
    let again = r.render(&cams, 96, 54, 0.0).unwrap();
    assert_eq!(again.stats.rays.shared_grid, first.stats.rays.shared_grid);
    assert!(again.images == first.images);
}
