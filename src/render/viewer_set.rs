//! A viewer set: every viewer of one view size, whatever session it belongs to, in
//! stacked volumes that one dispatch per stage covers. Viewers are slots in the stack
//! this frame; what a viewer keeps between frames (its last view-projection and where
//! its froxels were) is keyed by its stable [`ViewerId`], so viewers joining or leaving
//! never hand one viewer another's history.

use super::froxel_lighting::FroxelHistory;
use super::gbuffer::RasterView;
use super::gpu_types::{FrameGpu, ViewGpu, NO_HISTORY};
use super::scene_gpu::SceneGpu;
use super::smoke_view::SmokeBuffers;
use super::{FrameTarget, Settings, ViewerLayout, ViewerVolumes};
use crate::gpu::GpuContext;
use crate::scene::Camera;

/// A viewer's identity across frames (a session's view: session id and view index).
pub type ViewerId = u64;

/// Where one target's frame lies in the set's output buffer.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TargetSlice {
    /// Index of the target in the frame's list.
    pub target: usize,
    /// First pixel in the output buffer.
    pub first_pixel: u64,
    /// Pixels of the target's frame.
    pub pixels: u64,
}

/// The viewers of one size and everything they own on the GPU.
pub(crate) struct ViewerSet {
    pub(crate) vol: ViewerVolumes,
    /// Bind group 0 of this set's per-viewer stages: the world's buffers with this set's
    /// frame uniforms and views.
    pub(crate) bind_group: wgpu::BindGroup,
    /// `SceneGpu::generation` the bind group was made for.
    scene_generation: u32,
    frame: wgpu::Buffer,
    views: wgpu::Buffer,
    /// This frame's views, in slot order.
    pub(crate) gpu_views: Vec<ViewGpu>,
    /// The view-projection of each slot's froxel volume (its eye's, or a stereo head's
    /// midpoint's): what temporal reprojection reads last frame's froxels with.
    volume_view_projs: Vec<glam::Mat4>,
    pub(crate) raster_views: Vec<RasterView>,
    /// Index of the set's first viewer among every set's viewers this frame.
    pub(crate) first_view: usize,
    /// Where each target of this frame goes in `vol.output`.
    pub(crate) targets: Vec<TargetSlice>,
    ids: Vec<ViewerId>,
    /// Froxel lighting's temporal history of these viewers, keyed by id.
    pub(crate) history: FroxelHistory,
    /// Views that light froxels of their own this frame (whole volumes and coupled eyes'
    /// near fields): slots `0..volume_views`.
    pub(crate) volume_views: u32,
}

impl ViewerSet {
    /// Allocates a set for `targets` (all of one view size) under `settings`.
    pub(crate) fn new(
        ctx: &GpuContext,
        scene: &SceneGpu,
        settings: &Settings,
        targets: &[(usize, &FrameTarget)],
    ) -> anyhow::Result<ViewerSet> {
        let vol = Self::volumes(ctx, scene, settings, targets)?;
        let (frame, views, bind_group) = Self::uniforms(ctx, scene, vol.count)?;
        Ok(ViewerSet {
            vol,
            bind_group,
            scene_generation: scene.generation,
            frame,
            views,
            gpu_views: Vec::new(),
            volume_view_projs: Vec::new(),
            raster_views: Vec::new(),
            first_view: 0,
            targets: Vec::new(),
            ids: Vec::new(),
            history: FroxelHistory::default(),
            volume_views: 0,
        })
    }

    fn volumes(
        ctx: &GpuContext,
        scene: &SceneGpu,
        s: &Settings,
        targets: &[(usize, &FrameTarget)],
    ) -> anyhow::Result<ViewerVolumes> {
        let (_, first) = targets[0];
        let count = targets.iter().map(|(_, t)| t.views.len()).sum();
        let mut vol = ViewerVolumes::new(
            ctx,
            count,
            ViewerLayout::new(s, first.view_width, first.view_height),
            s.slices,
            s.frustum_slices(),
            s.temporal,
            targets.iter().map(|(_, t)| t.pixels()).sum(),
        )?;
        // Smoke proxies and layers only in a scene with emitters.
        if scene.particle_capacity > 0 {
            vol.smoke = Some(SmokeBuffers::new(
                ctx,
                count,
                first.view_width,
                first.view_height,
                scene.particle_capacity,
            )?);
        }
        Ok(vol)
    }

    fn uniforms(
        ctx: &GpuContext,
        scene: &SceneGpu,
        count: usize,
    ) -> anyhow::Result<(wgpu::Buffer, wgpu::Buffer, wgpu::BindGroup)> {
        let frame = ctx.storage(
            "set frame",
            std::mem::size_of::<FrameGpu>() as u64,
            wgpu::BufferUsages::empty(),
        )?;
        let views = ctx.storage(
            "set views",
            (count * std::mem::size_of::<ViewGpu>()) as u64,
            wgpu::BufferUsages::empty(),
        )?;
        let bind_group = scene.bind(ctx, &frame, &views);
        Ok((frame, views, bind_group))
    }

    /// Lays this frame's `targets` out in the set (reallocating when the number of
    /// viewers or pixels changed, carrying last frame's froxels over as history) and
    /// writes the set's uniforms: `frame` with this set's viewer count, and every view.
    pub(crate) fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &SceneGpu,
        settings: &Settings,
        targets: &[(usize, &FrameTarget)],
        (near, far): (f32, f32),
        frame: FrameGpu,
    ) -> anyhow::Result<()> {
        let count: usize = targets.iter().map(|(_, t)| t.views.len()).sum();
        let pixels: u64 = targets.iter().map(|(_, t)| t.pixels()).sum();
        if count != self.vol.count || pixels != self.vol.output_pixels {
            let old =
                std::mem::replace(&mut self.vol, Self::volumes(ctx, scene, settings, targets)?);
            self.history.reallocated(old, settings.temporal);
            (self.frame, self.views, self.bind_group) = Self::uniforms(ctx, scene, count)?;
        } else if self.scene_generation != scene.generation {
            // A scene buffer was reallocated (the media layer's pool grew): rebind.
            self.bind_group = scene.bind(ctx, &self.frame, &self.views);
        }
        self.scene_generation = scene.generation;
        let vol = &self.vol;
        let layout = vol.layout;
        let aspect = layout.width as f32 / layout.height as f32;
        let tan_x_scale = aspect;
        self.gpu_views.clear();
        self.volume_view_projs.clear();
        self.raster_views.clear();
        self.targets.clear();
        self.ids.clear();
        // Slots: first every view that lights froxels of its own (whole volumes, and the
        // near fields of coupled stereo eyes, in target order so that an eye's near field
        // sits beside its partner), then the coupled eyes that only read their partner's,
        // so that the froxel stages dispatch over the first `volume_views` slots only.
        // (With the eyes' idle workgroups in the dispatch, lavapipe gave each of its
        // threads a contiguous range of workgroups: one thread lit the whole volume while
        // the other idled, and a stereo pair cost what two eyes cost.)
        struct Placed<'a> {
            view: &'a super::TargetView,
            frame_pixel: u64,
            row_stride: u32,
            /// (target, view) of the partner whose volume it reads beyond its own slices.
            partner: Option<(usize, usize)>,
            /// Slices it lights itself.
            light_slices: u32,
            /// Where its volume is lit from (`stereo_head`: a partner's, its group's
            /// midpoint).
            origin: glam::Vec3,
        }
        let focal_px = layout.width as f32 * 0.5;
        let mut placed: Vec<Vec<Placed>> = Vec::with_capacity(targets.len());
        let mut first_pixel = 0u64;
        for (k, &(index, t)) in targets.iter().enumerate() {
            let cameras: Vec<Camera> = t.views.iter().map(|v| v.camera).collect();
            let partners = stereo_pairs(&cameras, settings.stereo_share_m);
            let origins = volume_origins(&cameras, &partners, settings.stereo_head);
            self.targets.push(TargetSlice {
                target: index,
                first_pixel,
                pixels: t.pixels(),
            });
            placed.push(
                t.views
                    .iter()
                    .zip(partners)
                    .zip(origins)
                    .map(|((v, p), origin)| {
                        let c = &v.camera;
                        let tan_x = (c.fov_y * 0.5).tan() * tan_x_scale;
                        // A stereo head's eyes both read its volume: no near field.
                        let near_field = p.map(|i| {
                            let eye_m = c.position.distance(cameras[i].position);
                            if settings.stereo_head {
                                return 0;
                            }
                            near_slices(settings, focal_px / tan_x, eye_m, (near, far))
                        });
                        // A near field as deep as the volume is a volume of its own.
                        let partner = p.filter(|_| near_field < Some(settings.slices));
                        Placed {
                            view: v,
                            frame_pixel: first_pixel
                                + v.origin[1] as u64 * t.width as u64
                                + v.origin[0] as u64,
                            row_stride: t.width,
                            partner: partner.map(|p| (k, p)),
                            light_slices: near_field
                                .filter(|_| partner.is_some())
                                .unwrap_or(settings.slices),
                            origin,
                        }
                    })
                    .collect(),
            );
            first_pixel += t.pixels();
        }
        // (target, view) of every view in slot order, and each one's slot.
        let at = |lights: bool| {
            placed.iter().enumerate().flat_map(move |(k, views)| {
                (0..views.len())
                    .filter(move |&j| (views[j].light_slices > 0) == lights)
                    .map(move |j| (k, j))
            })
        };
        let order: Vec<(usize, usize)> = at(true).chain(at(false)).collect();
        let mut slot_of: Vec<Vec<u32>> = placed.iter().map(|v| vec![0; v.len()]).collect();
        for (slot, &(k, j)) in order.iter().enumerate() {
            slot_of[k][j] = slot as u32;
        }
        self.volume_views = at(true).count() as u32;
        let mut cameras = Vec::with_capacity(count);
        for &(k, j) in &order {
            let p = &placed[k][j];
            let v = p.view;
            let slot = slot_of[k][j];
            let volume_view = p.partner.map_or(slot, |(pk, pj)| slot_of[pk][pj]);
            let c = &v.camera;
            let vp = c.projection(aspect, near, far) * c.view();
            // A stereo head's volume is seen from between the eyes; any other from the eye.
            let volume_vp = if p.origin == c.position {
                vp
            } else {
                let lit_from = Camera {
                    position: p.origin,
                    ..*c
                };
                lit_from.projection(aspect, near, far) * lit_from.view()
            };
            self.volume_view_projs.push(volume_vp);
            let right = c.forward.cross(c.up()).normalize();
            let up = right.cross(c.forward);
            let tan_y = (c.fov_y * 0.5).tan();
            // A view that lights no froxels keeps none.
            let history = self.history.of(v.id).filter(|_| p.light_slices > 0);
            self.gpu_views.push(ViewGpu {
                view_proj: vp.to_cols_array_2d(),
                prev_view_proj: history.map_or(vp, |h| h.view_proj).to_cols_array_2d(),
                position: c.position.to_array(),
                near,
                forward: c.forward.to_array(),
                far,
                right: right.to_array(),
                tan_x: tan_y * tan_x_scale,
                up: up.to_array(),
                tan_y,
                size: [layout.width, layout.height],
                froxel_dims: layout.froxel_dims,
                frustum_dims: layout.frustum_dims,
                froxel_px: settings.froxel_px,
                frustum_px: settings.frustum_px,
                froxel_base: slot * vol.froxels_per_view(),
                frustum_base: slot * vol.frustum_per_view(),
                pixel_base: p.frame_pixel as u32,
                jitter: frame_jitter(settings, frame.frame_index),
                row_stride: p.row_stride,
                history_base: history.map_or(NO_HISTORY, |h| h.froxel_base),
                volume_view,
                light_slices: p.light_slices,
                origin: p.origin.to_array(),
                _pad: 0,
            });
            self.ids.push(v.id);
            cameras.push(*c);
        }
        self.raster_views =
            RasterView::for_cameras(&cameras, (layout.width, layout.height), near, far);
        let owners = self.volume_views;
        self.vol.groups.columns[2] = owners;
        self.vol.groups.frustum[2] = owners;
        let frame = FrameGpu {
            view_count: count as u32,
            ..frame
        };
        ctx.queue
            .write_buffer(&self.frame, 0, bytemuck::bytes_of(&frame));
        ctx.queue
            .write_buffer(&self.views, 0, bytemuck::cast_slice(&self.gpu_views));
        if let Some(smoke) = &self.vol.smoke {
            let view_projs: Vec<_> = self.gpu_views.iter().map(|v| v.view_proj).collect();
            smoke.write_views(ctx, &view_projs, settings.smoke_simpson_steps);
        }
        Ok(())
    }

    /// After the frame: froxel lighting's history moves on (see [`FroxelHistory`]).
    pub(crate) fn finish(&mut self, settings: &Settings, froxels_written: bool) {
        let keep = settings.temporal && froxels_written;
        self.history.finish(
            &mut self.vol,
            &self.ids,
            &self.gpu_views,
            &self.volume_view_projs,
            keep,
        );
    }
}

/// Coupled stereo: for each of one frame's `cameras`, the earlier camera whose froxels
/// it shares (`None`: it lights its own). A camera shares with the first earlier one that
/// lights its own volume, looks the same way with the same field of view and stands at
/// most `share_m` from it: a stereo session's eyes at a normal eye distance, or split
/// views that nearly coincide. It then lights only its near field ([`near_slices`]) and
/// its integration reads that volume's froxels beyond, where its own froxels' points
/// project (shaders/volume_integration.wgsl); the error is the interpolation between the
/// partner's froxels, which docs/decisions.md ("Coupled stereo") measures against the
/// eye rendered alone.
pub(crate) fn stereo_pairs(cameras: &[Camera], share_m: f32) -> Vec<Option<usize>> {
    let mut partners: Vec<Option<usize>> = Vec::with_capacity(cameras.len());
    for (j, c) in cameras.iter().enumerate() {
        let partner = (0..j).find(|&i| {
            let o = &cameras[i];
            partners[i].is_none()
                && o.forward.dot(c.forward) > 1.0 - 1e-6
                && (o.fov_y - c.fov_y).abs() <= 1e-6
                && o.position.distance(c.position) <= share_m
        });
        partners.push(partner);
    }
    partners
}

/// Where each of one frame's `cameras` lights its froxel volume from, given its
/// `partners` ([`stereo_pairs`]): its own eye, or with `head` (setting `stereo_head`), for
/// a view that others share, the midpoint of its own and their eyes (a stereo head's two
/// eyes: the point between them). The views look the same way, so the volume's slices
/// are the views' depth planes, and every eye reads it half an eye distance away.
pub(crate) fn volume_origins(
    cameras: &[Camera],
    partners: &[Option<usize>],
    head: bool,
) -> Vec<glam::Vec3> {
    let mut sum: Vec<(glam::Vec3, f32)> = cameras.iter().map(|c| (c.position, 1.0)).collect();
    if head {
        for (j, p) in partners.iter().enumerate() {
            if let Some(i) = *p {
                sum[i].0 += cameras[j].position;
                sum[i].1 += 1.0;
            }
        }
    }
    sum.into_iter().map(|(p, n)| p / n).collect()
}

/// Coupled stereo's near field: the slices a second eye `eye_m` from its partner lights
/// itself, those nearer than the depth where the eyes' disparity, `focal_px · eye_m / z`
/// pixels, falls to `stereo_near_px` (rounded out to a slice boundary; 0 with
/// `stereo_near_px` 0). The slices are the exponential ones of `slice_depth`
/// (common.wgsl), between the view's `near` and `far`.
pub(crate) fn near_slices(s: &Settings, focal_px: f32, eye_m: f32, (near, far): (f32, f32)) -> u32 {
    if s.stereo_near_px <= 0.0 || eye_m <= 0.0 {
        return 0;
    }
    let z = focal_px * eye_m / s.stereo_near_px;
    let u = ((z - near) / (far - near)).clamp(0.0, 1.0);
    let k = s.depth_curve;
    let slice = s.slices as f32 * (u * k.exp_m1()).ln_1p() / k;
    (slice.ceil() as u32).min(s.slices)
}

/// Per-frame jitter along the view ray (a 1-D low-discrepancy sequence, centred) with
/// temporal reprojection on; 0 without.
fn frame_jitter(s: &Settings, frame_index: u32) -> f32 {
    if s.temporal {
        ((frame_index as f32 * 0.618_034).fract() - 0.5) * 0.999
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_head_volume_is_lit_from_between_the_eyes_that_share_it() {
        use glam::Vec3;
        let eye = |x: f32| Camera::new(Vec3::new(x, 1.0, 0.0), Vec3::NEG_Z, 1.2);
        // Two eyes 6 cm apart and a third view far off.
        let cameras = [eye(0.0), eye(0.06), eye(5.0)];
        let partners = stereo_pairs(&cameras, 0.07);
        assert_eq!(partners, vec![None, Some(0), None]);
        let own = volume_origins(&cameras, &partners, false);
        assert_eq!(own, cameras.map(|c| c.position).to_vec());
        let head = volume_origins(&cameras, &partners, true);
        assert!((head[0] - Vec3::new(0.03, 1.0, 0.0)).length() < 1e-6);
        assert_eq!(head[1], cameras[1].position);
        assert_eq!(head[2], cameras[2].position);
        // Three views that nearly coincide share the first: its volume is lit from
        // their centroid.
        let three = [eye(0.0), eye(0.03), eye(0.06)];
        let p = stereo_pairs(&three, 0.07);
        assert_eq!(p, vec![None, Some(0), Some(0)]);
        assert!((volume_origins(&three, &p, true)[0].x - 0.03).abs() < 1e-6);
    }

    #[test]
    fn the_near_field_ends_where_the_disparity_falls_to_stereo_near_px() {
        let s = Settings::default();
        let (near, far) = (0.1, 40.0);
        let focal_px = 128.5;
        let n = near_slices(&s, focal_px, 0.064, (near, far));
        // The split depth's disparity is at most the tolerance, the slice before's more.
        let depth = |slice: u32| {
            let k = s.depth_curve;
            near + (far - near) * (k * slice as f32 / s.slices as f32).exp_m1() / k.exp_m1()
        };
        let disparity = |z: f32| focal_px * 0.064 / z;
        assert!(n > 0 && n < s.slices, "{n} slices");
        assert!(disparity(depth(n)) <= s.stereo_near_px + 1e-3);
        assert!(disparity(depth(n - 1)) > s.stereo_near_px);
        // None without the setting or the eye distance; all of them for a split past far.
        let off = Settings {
            stereo_near_px: 0.0,
            ..s
        };
        assert_eq!(near_slices(&off, focal_px, 0.064, (near, far)), 0);
        assert_eq!(near_slices(&s, focal_px, 0.0, (near, far)), 0);
        assert_eq!(near_slices(&s, focal_px, 10.0, (near, far)), s.slices);
    }
}
