//! Temporal reprojection with a poisoned history (issue 3's hard case): the froxel
//! history is private to the renderer, so this test lives inside the crate and writes
//! NaN and inf straight into it between two frames.

use super::{Mode, Renderer, Settings};
use crate::gpu::GpuContext;
use crate::metrics::compare;
use crate::scene::Scene;
use std::sync::Arc;

const W: u32 = 64;
const H: u32 = 36;

/// binary16 bit patterns a history word may hold: quiet NaN, +inf, −inf, −NaN.
const POISON: [u16; 4] = [0x7e00, 0x7c00, 0xfc00, 0xfe01];

#[test]
fn nan_and_inf_in_the_history_are_discarded() {
    let ctx = Arc::new(GpuContext::new().expect("a Vulkan adapter (lavapipe on CI)"));
    let scene = Arc::new(Scene::load("colonnade").expect("built-in scene"));
    let cams = scene.camera.viewers(2, 0.0);
    let mut frames = Vec::new();
    for poison in [false, true] {
        let settings = Settings {
            mode: Mode::Reference,
            temporal: true,
            ..Settings::default()
        };
        let mut r = Renderer::new(ctx.clone(), scene.clone(), settings).expect("renderer");
        r.render(&cams, W, H, 0.0).expect("frame 1");
        let set = r.sets.values().next().expect("a viewer set after a frame");
        assert!(!set.history.is_empty(), "frame 1 leaves a history behind");
        if poison {
            // Every f16 of every history froxel: rgb and σt alike.
            let history = set.history.buffer(&set.vol);
            let halves = (history.size() / 2) as usize;
            let words: Vec<u16> = (0..halves).map(|i| POISON[i % POISON.len()]).collect();
            ctx.queue
                .write_buffer(history, 0, bytemuck::cast_slice(&words));
        }
        let second = r.render(&cams, W, H, 1.0 / 30.0).expect("frame 2");
        for (i, f) in r
            .read_integrated_volume()
            .expect("integrated volume")
            .iter()
            .enumerate()
        {
            assert!(
                f.iter().all(|x| x.is_finite()) && (0.0..=1.0).contains(&f[3]),
                "poisoned history {poison}: integrated froxel {i} is {f:?}"
            );
        }
        // Frame 3 reprojects frame 2, which must itself be clean.
        let third = r.render(&cams, W, H, 2.0 / 30.0).expect("frame 3");
        assert!(
            r.read_integrated_volume()
                .expect("integrated volume")
                .iter()
                .all(|f| f.iter().all(|x| x.is_finite())),
            "poisoned history {poison}: frame 3 has non-finite froxels"
        );
        frames.push((second, third));
    }
    // Discarding the history leaves frame 2 at this frame's own estimate, which differs
    // from the 90 % history blend of the clean run only by the jitter between frames.
    let (clean, poisoned) = (&frames[0], &frames[1]);
    for (v, (a, b)) in clean.0.images.iter().zip(&poisoned.0.images).enumerate() {
        let e = compare(a, b, W, H).expect("same size");
        println!(
            "viewer {v}: frame 2 with poisoned vs clean history: FLIP {:.4}",
            e.flip_mean
        );
        assert!(
            e.flip_mean < 0.05,
            "viewer {v}: a discarded history moves frame 2 by FLIP {}",
            e.flip_mean
        );
        for (i, px) in b.chunks_exact(4).enumerate() {
            assert!(px[..3] != [0, 0, 0], "viewer {v}: pixel {i} is black");
        }
    }
    for (v, (a, b)) in clean.1.images.iter().zip(&poisoned.1.images).enumerate() {
        let e = compare(a, b, W, H).expect("same size");
        assert!(
            e.flip_mean < 0.05,
            "viewer {v}: frame 3 after a poisoned history differs by FLIP {}",
            e.flip_mean
        );
    }
}

/// A stereo head's volume is lit from between the eyes (`stereo_head`): its history is
/// kept with that point's view-projection, which the next frame reprojects with, not
/// the first eye's (whose volume it is not).
#[test]
fn a_stereo_heads_history_is_reprojected_from_between_the_eyes() {
    use super::FrameTarget;
    let ctx = Arc::new(GpuContext::new().expect("a Vulkan adapter (lavapipe on CI)"));
    let scene = Arc::new(Scene::load("colonnade").expect("built-in scene"));
    let settings = Settings {
        temporal: true,
        stereo_head: true,
        ..Settings::default()
    };
    let head = scene.camera.viewers(1, 0.0)[0];
    let target = FrameTarget::stereo(7, head, 0.064, W, H);
    let mut r = Renderer::new(ctx, scene.clone(), settings).expect("renderer");
    r.render_targets(std::slice::from_ref(&target), 0.0)
        .expect("frame 1");
    let set = r.sets.values().next().expect("a viewer set after a frame");
    let (near, far) = (scene.render.near_m, scene.render.far_m);
    let aspect = W as f32 / H as f32;
    let vp = |c: crate::scene::Camera| c.projection(aspect, near, far) * c.view();
    let first_eye = target.views[0];
    let h = set
        .history
        .of(first_eye.id)
        .expect("the head's volume keeps a history");
    let expected = vp(head);
    assert!(
        h.view_proj.abs_diff_eq(expected, 1e-5),
        "history kept with {:?}, the head's view-projection is {expected:?}",
        h.view_proj
    );
    assert!(!h.view_proj.abs_diff_eq(vp(first_eye.camera), 1e-4));
    // The second eye lights nothing of its own and keeps no history.
    assert!(set.history.of(target.views[1].id).is_none());
}
