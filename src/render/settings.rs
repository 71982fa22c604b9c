//! Every setting of the renderer (paper 000's parameters and what fogcast adds), with
//! its default and its valid range.

use serde::{Deserialize, Serialize};

/// How shadows in the fog are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Paper 000's baseline: a shadow ray per light per froxel, per viewer.
    Reference,
    /// Paper 000's method: shared world grid + per-viewer shadow frustum.
    Shared,
}

/// Every parameter of paper 000, with its defaults.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// Rendering mode.
    pub mode: Mode,
    /// Shared grid voxel edge, metres.
    pub voxel_size_m: f32,
    /// Pixels per froxel of the lighting volume (8 in the paper).
    pub froxel_px: u32,
    /// Depth slices of the lighting volume (128 in the paper).
    pub slices: u32,
    /// Pixels per froxel of the shadow frustum (16 in the paper).
    pub frustum_px: u32,
    /// Fraction of the slices covered by the shadow frustum (1/3 in the paper; 0 = off).
    pub frustum_slice_fraction: f32,
    /// Alternate z-parity grid updates (half the grid per frame).
    pub parity: bool,
    /// 8-voxel trilinear grid lookup instead of the nearest voxel.
    pub trilinear: bool,
    /// Temporal jitter along view rays + reprojection of last frame's froxels.
    pub temporal: bool,
    /// Curvature k of the depth-slice distribution
    /// `z = near + (far − near)·(e^{k·s/N} − 1)/(e^k − 1)`: large k crowds slices at the
    /// eye (k = ln(far/near) ≈ the pure exponential near·(far/near)^{s/N}), small k
    /// tends to linear. With near 0.1 m and far 40 m the pure exponential puts the
    /// first third of the slices (the shadow frustum's) within 0.75 m of the eye; the
    /// default 4 reaches 2 m there and is measured in `docs/accuracy.md`.
    pub depth_curve: f32,
    /// Demand-driven grid update (beyond the paper): trace only the voxels that some
    /// froxel's lookup will read, instead of every voxel inside some frustum; froxels
    /// hidden behind the depth buffer are neither lit nor read. On by default.
    #[serde(default)]
    pub demand: bool,
    /// Temporal shadow caching (beyond the paper): a voxel's light bit stays valid
    /// until that light changes or a mover's swept bounds cross its shadow ray, so a
    /// static scene traces each voxel once. On by default; no effect on a sparse grid
    /// (its bricks are allocated afresh every frame).
    #[serde(default)]
    pub cache: bool,
    /// Sparse grid (paper 000 §5.1, beyond its implementation): bricks of 8³ voxels
    /// allocated each frame where froxels read, from a pool of this many bricks
    /// (0: a dense grid over the whole media box). Implies `demand`; not with `cache`.
    /// A froxel whose brick did not fit in the pool traces its own rays.
    #[serde(default)]
    pub brick_pool: u32,
    /// Shadows of directional lights on surfaces and in the near-field fog (the shadow
    /// frustum) from a shared shadow map of this many texels a side, rendered once for
    /// all viewers and only when a light or mover changed (beyond the paper; `shared`
    /// only; default 4096). 0: a shadow ray per pixel or frustum froxel and light, as
    /// `reference` always does.
    #[serde(default)]
    pub shadow_map_px: u32,
    /// Node spacing of the shared media transmittance volumes, metres (`shared` only):
    /// T toward each light computed once per frame for all viewers, cached while media
    /// and light are static (src/render/media_transmittance.rs). 0: every froxel and
    /// pixel marches its own shadow ray through the media, as `reference` does.
    #[serde(default = "default_transmittance_voxel_m")]
    pub transmittance_voxel_m: f32,
    /// Quadrature step of a shadow ray through height and noisy media, metres (at most
    /// 32 steps per medium; homogeneous media are integrated exactly).
    #[serde(default = "default_media_step_m")]
    pub media_step_m: f32,
}

fn default_transmittance_voxel_m() -> f32 {
    0.5
}

fn default_media_step_m() -> f32 {
    0.5
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            mode: Mode::Shared,
            voxel_size_m: 0.25,
            froxel_px: 8,
            slices: 128,
            frustum_px: 16,
            frustum_slice_fraction: 1.0 / 3.0,
            parity: false,
            trilinear: true,
            temporal: false,
            depth_curve: 4.0,
            // Beyond the paper, on where `fogcast bench` shows they win (docs/performance.md):
            // the demand-driven grid, temporal caching and shared surface shadow maps.
            demand: true,
            cache: true,
            brick_pool: 0,
            shadow_map_px: 4096,
            transmittance_voxel_m: default_transmittance_voxel_m(),
            media_step_m: default_media_step_m(),
        }
    }
}

impl Settings {
    /// Checks ranges; the error names the setting and value.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.voxel_size_m.is_finite() && self.voxel_size_m >= 0.01,
            "voxel size {} m: must be at least 0.01 m",
            self.voxel_size_m
        );
        anyhow::ensure!(
            (1..=64).contains(&self.froxel_px),
            "froxel size {} px: must be 1..=64",
            self.froxel_px
        );
        anyhow::ensure!(
            (2..=512).contains(&self.slices),
            "slices {}: must be 2..=512",
            self.slices
        );
        anyhow::ensure!(
            (1..=128).contains(&self.frustum_px),
            "shadow frustum froxel size {} px: must be 1..=128",
            self.frustum_px
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.frustum_slice_fraction),
            "shadow frustum slice fraction {}: must be 0..=1",
            self.frustum_slice_fraction
        );
        anyhow::ensure!(
            self.brick_pool <= 1 << 20,
            "brick pool {}: at most 1048576 bricks",
            self.brick_pool
        );
        anyhow::ensure!(
            self.shadow_map_px == 0 || (64..=8192).contains(&self.shadow_map_px),
            "shadow map {} texels a side: must be 0 (rays) or 64..=8192",
            self.shadow_map_px
        );
        anyhow::ensure!(
            self.transmittance_voxel_m == 0.0
                || (self.transmittance_voxel_m.is_finite() && self.transmittance_voxel_m >= 0.01),
            "transmittance voxel {} m: must be 0 (march per sample) or at least 0.01 m",
            self.transmittance_voxel_m
        );
        anyhow::ensure!(
            self.media_step_m.is_finite() && self.media_step_m >= 0.01,
            "media step {} m: must be at least 0.01 m",
            self.media_step_m
        );
        anyhow::ensure!(
            self.depth_curve.is_finite() && (0.01..=20.0).contains(&self.depth_curve),
            "depth curve {}: must be 0.01..=20",
            self.depth_curve
        );
        Ok(())
    }

    pub(crate) fn frustum_slices(&self) -> u32 {
        (self.slices as f32 * self.frustum_slice_fraction).ceil() as u32
    }

    /// Whether froxels hidden behind the depth buffer are culled: with the demand-driven
    /// grid (dense or sparse) of `shared`, when some slices read the grid and no temporal
    /// history needs the hidden froxels.
    pub fn culls_hidden_froxels(&self) -> bool {
        self.mode == Mode::Shared
            && (self.demand || self.brick_pool > 0)
            && !self.temporal
            && self.frustum_slices() < self.slices
    }
}
