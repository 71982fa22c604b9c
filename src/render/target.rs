//! What a frame renders into: [`FrameTarget`]s (a session's frame and its viewers'
//! tiles) and what comes back.

use super::{FrameStats, ViewerId};
use crate::scene::Camera;

/// One viewer of a [`FrameTarget`]: who it is, where it looks from, and where its
/// tile lies in the target's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetView {
    /// Stable across frames: the viewer's history follows it.
    pub id: ViewerId,
    /// The camera.
    pub camera: Camera,
    /// Top-left pixel of the viewer's tile in the frame.
    pub origin: [u32; 2],
}

/// A stereo head's eyes, left and right: `head` moved ∓`eye_m`/2 along its right
/// vector, looking parallel.
pub fn stereo_eyes(head: Camera, eye_m: f32) -> [Camera; 2] {
    let right = head.forward.cross(head.up()).normalize();
    [-0.5 * eye_m, 0.5 * eye_m].map(|offset| Camera {
        position: head.position + right * offset,
        ..head
    })
}

/// One image a frame produces (a session's frame): its viewers, all of one view size,
/// tiled into it. The composite writes every tile in place; pixels no tile covers are
/// opaque black.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameTarget {
    /// Frame size, pixels.
    pub width: u32,
    /// Frame size, pixels.
    pub height: u32,
    /// Size of every viewer's tile.
    pub view_width: u32,
    /// Size of every viewer's tile.
    pub view_height: u32,
    /// The viewers.
    pub views: Vec<TargetView>,
}

impl FrameTarget {
    /// A frame of one viewer.
    pub fn single(id: ViewerId, camera: Camera, width: u32, height: u32) -> FrameTarget {
        FrameTarget {
            width,
            height,
            view_width: width,
            view_height: height,
            views: vec![TargetView {
                id,
                camera,
                origin: [0, 0],
            }],
        }
    }

    /// A frame of `cameras` in tiles of `width`×`height`, `cols` to a row, row-major,
    /// with ids `first_id`, `first_id + 1`, …
    pub fn tiled(
        first_id: ViewerId,
        cameras: &[Camera],
        (width, height): (u32, u32),
        cols: u32,
    ) -> FrameTarget {
        let rows = (cameras.len() as u32).div_ceil(cols);
        FrameTarget {
            width: cols * width,
            height: rows * height,
            view_width: width,
            view_height: height,
            views: cameras
                .iter()
                .enumerate()
                .map(|(i, c)| TargetView {
                    id: first_id + i as ViewerId,
                    camera: *c,
                    origin: [(i as u32 % cols) * width, (i as u32 / cols) * height],
                })
                .collect(),
        }
    }

    /// A stereo session's frame: two `width`×`height` eyes side by side (as the server
    /// tiles them), the left one (id `id`) and the right one (`id + 1`), see
    /// [`stereo_eyes`].
    pub fn stereo(id: ViewerId, head: Camera, eye_m: f32, width: u32, height: u32) -> FrameTarget {
        FrameTarget::tiled(id, &stereo_eyes(head, eye_m), (width, height), 2)
    }

    /// Viewer `i`'s tile of this target's RGBA8 `frame`, tightly packed.
    pub fn tile(&self, frame: &[u8], i: usize) -> Vec<u8> {
        let [x0, y0] = self.views[i].origin;
        let row = self.view_width as usize * 4;
        (y0..y0 + self.view_height)
            .flat_map(|y| {
                let start = (y as usize * self.width as usize + x0 as usize) * 4;
                frame[start..start + row].iter().copied()
            })
            .collect()
    }

    pub(crate) fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    pub(crate) fn validate(&self) -> anyhow::Result<()> {
        let (w, h) = (self.view_width, self.view_height);
        anyhow::ensure!(
            (1..=8192).contains(&w) && (1..=8192).contains(&h),
            "viewer size {w}×{h}: must be 1..=8192 on each side"
        );
        anyhow::ensure!(!self.views.is_empty(), "a frame needs at least one viewer");
        for v in &self.views {
            let c = &v.camera;
            anyhow::ensure!(
                c.position.is_finite()
                    && c.forward.is_finite()
                    && c.fov_y.is_finite()
                    && c.fov_y > 0.0
                    && c.fov_y < 3.1,
                "viewer {}: camera {c:?} is not finite or its field of view is out of range",
                v.id
            );
            anyhow::ensure!(
                v.origin[0] as u64 + w as u64 <= self.width as u64
                    && v.origin[1] as u64 + h as u64 <= self.height as u64,
                "viewer {}: its {w}×{h} tile at {:?} is outside the {}×{} frame",
                v.id,
                v.origin,
                self.width,
                self.height
            );
        }
        Ok(())
    }

    /// Paints the pixels no tile covers opaque black.
    pub(crate) fn fill_uncovered(&self, image: &mut [u8]) {
        if self.views.len() as u64 * self.view_width as u64 * self.view_height as u64
            == self.pixels()
        {
            return;
        }
        let covered = |x: u32, y: u32| {
            self.views.iter().any(|v| {
                (v.origin[0]..v.origin[0] + self.view_width).contains(&x)
                    && (v.origin[1]..v.origin[1] + self.view_height).contains(&y)
            })
        };
        for (i, px) in image.chunks_exact_mut(4).enumerate() {
            let (x, y) = (i as u32 % self.width, i as u32 / self.width);
            if !covered(x, y) {
                px.copy_from_slice(&[0, 0, 0, 255]);
            }
        }
    }
}

/// One rendered frame: an RGBA8 image per viewer and the frame's counters.
#[derive(Debug, Clone)]
pub struct FrameOutput {
    /// Width of every image, pixels.
    pub width: u32,
    /// Height of every image, pixels.
    pub height: u32,
    /// One tightly packed RGBA8 image per viewer.
    pub images: Vec<Vec<u8>>,
    /// Counters, memory and timings.
    pub stats: FrameStats,
}

/// One rendered frame of [`Renderer::render_targets`]: an RGBA8 image per target.
#[derive(Debug, Clone)]
pub struct TargetsOutput {
    /// One tightly packed RGBA8 frame per target, in the order given.
    pub images: Vec<Vec<u8>>,
    /// Counters, memory and timings of the whole frame.
    pub stats: FrameStats,
}
