//! Coupled stereo (issue 16): a stereo session's two eyes light one froxel volume when
//! they stand at most `stereo_share_m` apart. The left eye lights and integrates it; the
//! right eye lights only its near field (where the eyes' disparity exceeds
//! `stereo_near_px`) and its composite reads the left eye's volume beyond, at its pixels'
//! world points. Each eye must stay within mean FLIP 0.02 of rendering that eye alone,
//! with far fewer froxels lit than two eyes light. Eye distance 0 shares fully (both eyes
//! identical); a wide pair (1 m) falls back to two volumes and is exactly two eyes
//! rendered alone; a 1×1 eye still renders. With `stereo_head` the volume is lit from
//! between the eyes instead, and both eyes read it along their own rays.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{FrameTarget, Renderer, Settings, TargetsOutput as FrameOutput};
use fogcast::scene::{Camera, Scene};
use gpu_support::{colonnade, gpu};
use std::sync::Arc;

const W: u32 = 160;
const H: u32 = 90;
const TIME: f32 = 0.5;

/// The head: the colonnade's first path camera.
fn head(scene: &Scene) -> Camera {
    scene.camera.viewers(1, TIME)[0]
}

/// One frame of `targets` from a fresh renderer (no history, no cached grid).
fn render(scene: &Arc<Scene>, settings: Settings, targets: &[FrameTarget]) -> FrameOutput {
    let mut r = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    r.render_targets(targets, TIME).unwrap()
}

/// The stereo session's two eyes, and its frame's stats.
fn stereo(
    scene: &Arc<Scene>,
    settings: Settings,
    eye_m: f32,
    (w, h): (u32, u32),
) -> ([Vec<u8>; 2], FrameOutput) {
    let t = FrameTarget::stereo(0, head(scene), eye_m, w, h);
    let out = render(scene, settings, std::slice::from_ref(&t));
    ([t.tile(&out.images[0], 0), t.tile(&out.images[0], 1)], out)
}

/// Each eye of the session rendered alone, as a mono view of its own.
fn alone(
    scene: &Arc<Scene>,
    settings: Settings,
    eye_m: f32,
    (w, h): (u32, u32),
) -> [(Vec<u8>, FrameOutput); 2] {
    let t = FrameTarget::stereo(0, head(scene), eye_m, w, h);
    [0, 1].map(|i| {
        let one = FrameTarget::single(0, t.views[i].camera, w, h);
        let out = render(scene, settings, &[one]);
        (out.images[0].clone(), out)
    })
}

fn flip(a: &[u8], b: &[u8], (w, h): (u32, u32)) -> f64 {
    compare(a, b, w, h).unwrap().flip_mean
}

#[test]
fn coupled_eyes_light_one_volume_within_flip_0_02_of_each_eye_alone() {
    let scene = colonnade();
    let settings = Settings::default();
    // At the size issue 16 bounds (its bench's): at 160×90 a froxel is a 20th of the
    // view and the grid's edges from the map (`map_edges`) put the right eye at 0.023.
    const SIZE: (u32, u32) = (320, 180);
    assert!(
        settings.stereo_share_m >= 0.064,
        "a normal eye distance shares by default"
    );
    let eye_m = 0.064;
    let (coupled, c) = stereo(&scene, settings, eye_m, SIZE);
    let independent = Settings {
        stereo_share_m: 0.0,
        ..settings
    };
    let (two, t) = stereo(&scene, independent, eye_m, SIZE);
    let [(left, l), (right, r)] = alone(&scene, settings, eye_m, SIZE);
    let lit = |o: &FrameOutput| o.stats.froxels_with_media;
    let errors = [
        flip(&left, &coupled[0], SIZE),
        flip(&right, &coupled[1], SIZE),
    ];
    println!(
        "froxels lit: coupled {}, independent {}, eyes alone {} + {}; FLIP against each \
         eye alone: {errors:?}",
        lit(&c),
        lit(&t),
        lit(&l),
        lit(&r)
    );
    // The froxel stages ran over both eyes' slots: the left eye's volume and the right
    // eye's near field.
    let z = |o: &FrameOutput, stage: &str| {
        o.stats
            .dispatches
            .iter()
            .find(|(n, _)| n == stage)
            .map(|(_, g)| g[2])
    };
    assert_eq!(z(&c, "froxel_lighting"), Some(2));
    assert_eq!(z(&t, "froxel_lighting"), Some(2));
    assert_eq!(
        z(&c, "composite"),
        Some(2),
        "each eye composites its own pixels"
    );
    // Without coupling the two eyes are exactly the two eyes alone.
    assert!(
        two[0] == left && two[1] == right,
        "independent eyes differ from alone"
    );
    assert_eq!(lit(&t), lit(&l) + lit(&r));
    // Coupled: one volume, lit for the left eye (plus what the right eye's tiles add to
    // its culling), and the right eye's near field.
    assert!(lit(&c) >= lit(&l), "the shared volume covers the left eye");
    assert!(
        (lit(&c) as f64) < 0.75 * lit(&t) as f64,
        "coupled eyes lit {} froxels, two volumes {}",
        lit(&c),
        lit(&t)
    );
    // Without the near field the right eye lights nothing: the froxel stages run over
    // the left eye's slot alone and about half the froxels are lit.
    let far_only = Settings {
        stereo_near_px: 0.0,
        ..settings
    };
    let (shared, f) = stereo(&scene, far_only, eye_m, SIZE);
    assert_eq!(z(&f, "froxel_lighting"), Some(1));
    assert!(
        (lit(&f) as f64) < 0.6 * lit(&t) as f64 && lit(&f) < lit(&c),
        "one volume lit {} froxels, with the near field {}, two volumes {}",
        lit(&f),
        lit(&c),
        lit(&t)
    );
    assert!(shared[0] == left, "the left eye is its own either way");
    // The left eye reads its own volume: what it shows is what it shows alone.
    assert!(errors[0] < 1e-3, "left eye: FLIP {}", errors[0]);
    assert!(
        errors[1] <= 0.02,
        "right eye: FLIP {} against alone",
        errors[1]
    );
    // And it is not the left eye's picture: the right eye has its own parallax.
    assert!(coupled[1] != coupled[0]);
}

/// `stereo_head`: the volume is lit once, from the point between the eyes, and both eyes
/// read it along their own rays (no near field). Each eye reads froxels lit half an eye
/// distance away, so both stay within the bound, and the session lights about one eye's
/// froxels.
#[test]
fn a_head_volume_between_the_eyes_is_lit_once_and_both_eyes_stay_within_flip_0_02() {
    let scene = colonnade();
    const SIZE: (u32, u32) = (320, 180);
    let settings = Settings {
        stereo_head: true,
        ..Settings::default()
    };
    let eye_m = 0.064;
    let (eyes, c) = stereo(&scene, settings, eye_m, SIZE);
    let [(left, l), (right, r)] = alone(&scene, settings, eye_m, SIZE);
    let lit = |o: &FrameOutput| o.stats.froxels_with_media as f64;
    let errors = [flip(&left, &eyes[0], SIZE), flip(&right, &eyes[1], SIZE)];
    println!(
        "head volume: froxels lit {} (eyes alone {} + {}); FLIP against each eye alone: \
         {errors:?}",
        lit(&c),
        lit(&l),
        lit(&r)
    );
    let lighting = c
        .stats
        .dispatches
        .iter()
        .find(|(n, _)| n == "froxel_lighting")
        .map(|(_, g)| g[2]);
    assert_eq!(
        lighting,
        Some(1),
        "one volume is lit, in the first eye's slot"
    );
    // The head's volume, culled for what both eyes' tiles show: about one eye's.
    assert!(
        lit(&c) <= 1.05 * lit(&l).max(lit(&r)),
        "head volume lit {} froxels, an eye alone {} and {}",
        lit(&c),
        lit(&l),
        lit(&r)
    );
    for (i, e) in errors.iter().enumerate() {
        assert!(*e <= 0.02, "eye {i}: FLIP {e} against alone");
    }
    // Neither eye reads its own volume any more, and each keeps its own parallax.
    assert!(eyes[0] != left && eyes[0] != eyes[1]);
    // With the history reprojected by the head's view (temporal reprojection), the
    // eyes stay as close to themselves alone after a few frames.
    let temporal = Settings {
        temporal: true,
        ..settings
    };
    let t = FrameTarget::stereo(0, head(&scene), eye_m, SIZE.0, SIZE.1);
    let mut r = Renderer::new(gpu(), scene.clone(), temporal).unwrap();
    let mut out = None;
    for _ in 0..3 {
        out = Some(r.render_targets(std::slice::from_ref(&t), TIME).unwrap());
    }
    let frame = &out.unwrap().images[0];
    for i in 0..2 {
        let mut r = Renderer::new(gpu(), scene.clone(), temporal).unwrap();
        let one = FrameTarget::single(0, t.views[i].camera, SIZE.0, SIZE.1);
        let mut alone = None;
        for _ in 0..3 {
            alone = Some(r.render_targets(std::slice::from_ref(&one), TIME).unwrap());
        }
        let e = flip(&alone.unwrap().images[0], &t.tile(frame, i), SIZE);
        assert!(e <= 0.02, "temporal, eye {i}: FLIP {e} against alone");
    }
}

#[test]
fn eye_distance_zero_shares_fully_and_the_eyes_are_identical() {
    let scene = colonnade();
    let settings = Settings::default();
    let [(left, l), _] = alone(&scene, settings, 0.0, (W, H));
    // The head between two eyes at one point is that point: both ways are the same.
    for head in [false, true] {
        let s = Settings {
            stereo_head: head,
            ..settings
        };
        let (eyes, c) = stereo(&scene, s, 0.0, (W, H));
        assert!(eyes[0] == eyes[1], "both eyes at one point see the same");
        assert!(eyes[0] == left, "and what one eye alone sees (head {head})");
        assert_eq!(
            c.stats.froxels_with_media, l.stats.froxels_with_media,
            "one volume for both"
        );
    }
}

#[test]
fn a_one_metre_eye_distance_falls_back_to_two_volumes_exactly() {
    let scene = colonnade();
    let settings = Settings::default();
    assert!(settings.stereo_share_m < 1.0);
    let (eyes, c) = stereo(&scene, settings, 1.0, (W, H));
    let [(left, l), (right, r)] = alone(&scene, settings, 1.0, (W, H));
    assert!(eyes[0] == left && eyes[1] == right, "each eye as alone");
    assert_eq!(
        c.stats.froxels_with_media,
        l.stats.froxels_with_media + r.stats.froxels_with_media
    );
    assert!(eyes[0] != eyes[1]);
}

/// The crossover behind `stereo_share_m`'s and `stereo_near_px`'s defaults: the right
/// eye's error against rendering it alone when coupling is forced at growing eye
/// distances, without a near field (the error grows with the parallax) and with the
/// default one (which deepens with the eye distance, and with it the froxels lit).
#[test]
fn the_coupled_eyes_error_grows_with_the_eye_distance_unless_the_near_field_is_lit() {
    let scene = colonnade();
    let forced = Settings {
        stereo_share_m: 10.0,
        ..Settings::default()
    };
    let far_only = Settings {
        stereo_near_px: 0.0,
        ..forced
    };
    let mut errors = Vec::new();
    for eye_m in [0.032f32, 0.064, 0.07, 0.1, 0.2, 0.5, 1.0] {
        let [_, (right, _)] = alone(&scene, forced, eye_m, (W, H));
        let mut row = (eye_m, [0.0; 2], [0; 2]);
        for (k, s) in [far_only, forced].into_iter().enumerate() {
            let (coupled, out) = stereo(&scene, s, eye_m, (W, H));
            row.1[k] = flip(&right, &coupled[1], (W, H));
            row.2[k] = out.stats.froxels_with_media;
        }
        println!(
            "eye distance {eye_m} m: right eye FLIP against alone {:.4} without the near \
             field, {:.4} with it; froxels lit {} / {}",
            row.1[0], row.1[1], row.2[0], row.2[1]
        );
        errors.push(row);
    }
    let at = |m: f32| errors.iter().find(|(d, ..)| *d == m).unwrap();
    // At these 160 px a froxel is a 20th of the view: the default eye distance errs
    // 0.023 here (0.0194 with the grid's blurred edges, `map_edges` off); the bench's
    // 320×180 eyes, which issue 16 bounds, keep every head's worst eye under 0.02
    // (docs/performance.md, and `coupled_eyes_light_one_volume_within_flip_0_02_of_each_eye_alone`).
    let typical = fogcast::protocol::DEFAULT_EYE_DISTANCE_M as f32;
    assert!(at(typical).1[1] <= 0.03, "{errors:?}");
    assert!(
        at(1.0).1[0] > 2.0 * at(typical).1[0],
        "a wider pair errs more: {errors:?}"
    );
    // The near field never errs more, and takes most of a wide pair's error away (at
    // 160 px across, a froxel's disparity lies 0.5 m from a 6.4 cm pair: the near field
    // is shallow there, and what is left is the right eye's froxels interpolated
    // between the left eye's).
    for (eye_m, e, lit) in &errors {
        assert!(e[1] <= e[0] + 1e-3, "{eye_m} m: {e:?}");
        assert!(lit[1] > lit[0], "{eye_m} m: the near field lights froxels");
    }
    assert!(at(1.0).1[1] < 0.25 * at(1.0).1[0], "{errors:?}");
    assert!(at(1.0).2[1] > at(0.064).2[1], "the near field deepens");
}

#[test]
fn one_pixel_eyes_render_and_share() {
    let scene = colonnade();
    let settings = Settings::default();
    let (eyes, c) = stereo(&scene, settings, 0.064, (1, 1));
    let [(left, _), (right, _)] = alone(&scene, settings, 0.064, (1, 1));
    println!("1×1 eyes: {eyes:?}, alone {left:?} {right:?}");
    assert_eq!(c.stats.viewers, 2);
    for (eye, solo) in eyes.iter().zip([&left, &right]) {
        assert_eq!(eye.len(), 4);
        assert!(eye[..3].iter().any(|&c| c > 0), "a black eye: {eye:?}");
        let diff = eye[..3]
            .iter()
            .zip(&solo[..3])
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(diff <= 8, "{eye:?} against alone {solo:?}");
    }
}

/// Physics is the ruler: against the CPU truth, the coupled right eye is about as close
/// as the same eye rendered alone. Heads spread along colonnade's path at 160×90 per
/// eye, 6.4 cm apart; mean FLIP against `truth` of the right eye rendered alone, coupled
/// with the near field (the default) and coupled without it.
#[test]
fn the_coupled_right_eye_is_as_close_to_truth_as_the_eye_alone() {
    use fogcast::render::stereo_eyes;
    use fogcast::scene::Bvh;
    use fogcast::truth::{render_truth, TruthSettings};
    let scene = colonnade();
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let settings = Settings::default();
    let far_only = Settings {
        stereo_near_px: 0.0,
        ..settings
    };
    let between = Settings {
        stereo_head: true,
        ..settings
    };
    let eye_m = 0.064;
    let heads = scene.camera.viewers(4, TIME);
    let rights: Vec<Camera> = heads.iter().map(|h| stereo_eyes(*h, eye_m)[1]).collect();
    let (truth, _) = render_truth(
        &scene,
        &bvh,
        &rights,
        (W, H),
        TIME,
        TruthSettings::default(),
        &|_, _| {},
    );
    let mut sums = [0.0; 4];
    for (k, head) in heads.iter().enumerate() {
        let t = FrameTarget::stereo(0, *head, eye_m, W, H);
        let one = FrameTarget::single(0, t.views[1].camera, W, H);
        let alone = render(&scene, settings, &[one]).images[0].clone();
        let coupled = |s: Settings| {
            let out = render(&scene, s, std::slice::from_ref(&t));
            t.tile(&out.images[0], 1)
        };
        let errors = [
            alone,
            coupled(settings),
            coupled(far_only),
            coupled(between),
        ]
        .map(|img| flip(&truth[k], &img, (W, H)));
        println!(
            "head {k}: right eye FLIP against truth: alone {:.4}, coupled {:.4}, coupled \
             without the near field {:.4}, from the head's volume {:.4}",
            errors[0], errors[1], errors[2], errors[3]
        );
        for (s, e) in sums.iter_mut().zip(errors) {
            *s += e / heads.len() as f64;
        }
    }
    println!(
        "mean over {} heads: alone {:.4}, coupled {:.4}, without the near field {:.4}, \
         from the head's volume {:.4}",
        heads.len(),
        sums[0],
        sums[1],
        sums[2],
        sums[3]
    );
    assert!(sums[1] <= sums[0] + 0.003, "{sums:?}");
    assert!(sums[3] <= sums[0] + 0.003, "{sums:?}");
}
