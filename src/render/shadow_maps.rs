//! Shared shadow maps for every light kind (beyond paper 000; `shared` and `maps` modes'
//! `shadow_map_px`), with `shaders/shadow_map.wgsl`. Like the shared grid, this is
//! view-independent work done once for every viewer (DESIGN.md §1's light-space stage):
//!
//! - per **directional** light, an orthographic depth map of the static scene (`px`²),
//!   rendered again only when the light turns, and a small map of the movers alone over
//!   the sphere they turn in, rendered every frame they move;
//! - per **spot** light, one perspective map covering its cone (a 10 % wider field),
//!   near 5 cm, far plane at the scene's farthest corner;
//! - per **point** light, a cube: six 90° perspective faces, layers of the same array
//!   (one perspective map aimed at the scene when the light is outside its bounding
//!   sphere).
//!
//! Spot and cube maps share one depth array of [`local_px`]² layers. They hold the
//! static scene *and* the movers (no separate movers map: a documented simplification)
//! and are rendered again only when their light moves, or when movers move in a scene
//! that has some. The composite looks surface shadows up in them (2×2 PCF) instead of
//! tracing a ray per pixel and light, the shadow frustum the near-field fog (nearest
//! texel), and `maps` mode every froxel (2×2 PCF), all through
//! `shaders/shadow_lookup.wgsl`.

use super::gbuffer::{depth_test, dynamic_uniform_layout};
use super::{scene_gpu::SceneGpu, Stage, Timestamps};
use crate::gpu::Access::Read;
use crate::gpu::{storage_entry, GpuContext};
use crate::scene::{Light, LightKind, Scene};
use glam::{Mat4, Vec3};

const VIEW_STRIDE: u64 = 256;

/// Texels a side of each light's movers map.
const MOVER_PX: u32 = 1024;

/// Near plane of spot and cube maps, metres.
const LOCAL_NEAR_M: f32 = 0.05;

/// `ShadowMap.kind` in shaders/shadow_lookup.wgsl.
const KIND_ORTHO: u32 = 0;
const KIND_PERSPECTIVE: u32 = 1;
const KIND_CUBE: u32 = 2;

/// A spot whose cone is wider than this (half angle, degrees) gets a cube, as a point
/// light does: one perspective map would waste most of its texels near its edge.
const SPOT_MAX_HALF_DEG: f32 = 60.0;

/// Texels a side of spot and cube-face maps for `shadow_map_px`: an eighth (512 at the
/// default 4096), at least 64. A 90° face of 512 texels is 4 cm at 10 m from the light.
pub(crate) fn local_px(shadow_map_px: u32) -> u32 {
    (shadow_map_px / 8).max(64)
}

/// One map as the shaders read it.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct MapGpu {
    view_proj: [[f32; 4]; 4],
    /// Layer in its depth array (a cube's first face), or −1: no map.
    layer: i32,
    /// World size of one texel, metres: for perspective and cube maps at 1 m from the
    /// light (scales the lookup's normal offset).
    texel_m: f32,
    /// `KIND_ORTHO`, `KIND_PERSPECTIVE` or `KIND_CUBE`.
    kind: u32,
    _pad: f32,
}

/// Per scene light: its static (or spot, or cube) map, its movers map and a cube's six
/// face projections (+x, −x, +y, −y, +z, −z: [`cube_face`]'s order).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct LightMapsGpu {
    scene: MapGpu,
    movers: MapGpu,
    faces: [[[f32; 4]; 4]; 6],
}

fn no_map() -> MapGpu {
    MapGpu {
        layer: -1,
        ..Default::default()
    }
}

/// The cube face a point at `d` from the light falls on: the axis of d's largest
/// component, + before − (the shader's `cube_face` in shaders/common.wgsl).
#[cfg(test)]
fn cube_face(d: Vec3) -> usize {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        if d.x >= 0.0 {
            0
        } else {
            1
        }
    } else if a.y >= a.z {
        if d.y >= 0.0 {
            2
        } else {
            3
        }
    } else if d.z >= 0.0 {
        4
    } else {
        5
    }
}

/// Forward and up of cube face `f` ([`cube_face`]'s order).
fn face_axes(f: usize) -> (Vec3, Vec3) {
    match f {
        0 => (Vec3::X, Vec3::NEG_Y),
        1 => (Vec3::NEG_X, Vec3::NEG_Y),
        2 => (Vec3::Y, Vec3::Z),
        3 => (Vec3::NEG_Y, Vec3::NEG_Z),
        4 => (Vec3::Z, Vec3::NEG_Y),
        _ => (Vec3::NEG_Z, Vec3::NEG_Y),
    }
}

/// Perspective view-projection from `eye` along `forward` with a square field of
/// `fov_rad`, depth [0, 1] from `LOCAL_NEAR_M` to `far`.
fn perspective_view_proj(eye: Vec3, forward: Vec3, up: Vec3, fov_rad: f32, far: f32) -> Mat4 {
    perspective_view_proj_near(eye, forward, up, fov_rad, LOCAL_NEAR_M, far)
}

/// As [`perspective_view_proj`], with the near plane at `near`.
fn perspective_view_proj_near(
    eye: Vec3,
    forward: Vec3,
    up: Vec3,
    fov_rad: f32,
    near: f32,
    far: f32,
) -> Mat4 {
    let far = far.max(near * 2.0);
    let f = forward.normalize();
    let r = f.cross(up).normalize();
    let u = r.cross(f);
    // Right-handed view (the camera looks down −z), as `Camera::view` builds it.
    let view = Mat4::from_cols(
        glam::Vec4::new(r.x, u.x, -f.x, 0.0),
        glam::Vec4::new(r.y, u.y, -f.y, 0.0),
        glam::Vec4::new(r.z, u.z, -f.z, 0.0),
        glam::Vec4::new(-r.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    );
    let s = 1.0 / (fov_rad * 0.5).tan();
    let range = near - far;
    let proj = Mat4::from_cols(
        glam::Vec4::new(s, 0.0, 0.0, 0.0),
        glam::Vec4::new(0.0, s, 0.0, 0.0),
        glam::Vec4::new(0.0, 0.0, far / range, -1.0),
        glam::Vec4::new(0.0, 0.0, near * far / range, 0.0),
    );
    proj * view
}

/// The six face projections of a cube map at `eye` reaching `far`.
pub(crate) fn cube_view_projs(eye: Vec3, far: f32) -> [Mat4; 6] {
    std::array::from_fn(|f| {
        let (fwd, up) = face_axes(f);
        perspective_view_proj(eye, fwd, up, std::f32::consts::FRAC_PI_2, far)
    })
}

/// Whether light `l` gets a cube (point lights, wide spots) rather than one map.
fn is_cube(l: &Light) -> bool {
    l.kind == LightKind::Point
        || l.cos_outer.clamp(-1.0, 1.0).acos() > SPOT_MAX_HALF_DEG.to_radians()
}

/// The field of a spot's map: its cone, 10 % wider.
fn spot_fov(l: &Light) -> f32 {
    (2.2 * l.cos_outer.clamp(-1.0, 1.0).acos()).min(170f32.to_radians())
}

/// Distance from `eye` to the farthest corner of the box, plus a metre.
fn far_plane(eye: Vec3, (lo, hi): Aabb) -> f32 {
    let far = (0..8)
        .map(|i| {
            let c = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            c.distance(eye)
        })
        .fold(0.0f32, f32::max);
    far + 1.0
}

/// Spot and cube maps: one depth array of [`local_px`]² layers for every point and spot
/// light, holding the static scene and the movers.
struct LocalMaps {
    px: u32,
    texture: wgpu::Texture,
    /// Bounds of the scene with the movers' spheres (the far planes reach them).
    bounds: Aabb,
    /// Per mapped light: (scene light, first layer, cube or not).
    lights: Vec<(usize, usize, bool)>,
    layers: usize,
    /// Per mapped light: the position and direction its layers were rendered for.
    rendered_for: Vec<Option<[f32; 6]>>,
    /// Scene time of the movers drawn into them (scenes with movers only).
    movers_time: Option<f32>,
    has_movers: bool,
}

/// The maps, their pipeline and what the stages that read them bind.
pub(crate) struct ShadowMaps {
    scene_maps: MapSet,
    mover_maps: MapSet,
    local: LocalMaps,
    sampler: wgpu::Sampler,
    /// One [`LightMapsGpu`] per scene light.
    info: wgpu::Buffer,
    info_cpu: Vec<LightMapsGpu>,
    /// Scene lights with orthographic maps (directional ones), in layer order.
    lights: Vec<usize>,
    movers_time: Option<f32>,
    pipeline: Option<wgpu::RenderPipeline>,
    layout: wgpu::BindGroupLayout,
    uniforms: wgpu::Buffer,
}

/// Orthographic light view-projection over the box (lo, hi) looking along `dir`: x, y
/// across the light to [−1, 1], distance along it to depth [0, 1].
fn light_view_proj(dir: Vec3, lo: Vec3, hi: Vec3) -> Mat4 {
    let f = dir.normalize();
    let helper = if f.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let r = f.cross(helper).normalize();
    let u = r.cross(f);
    let (mut a, mut b) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for i in 0..8 {
        let c = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let l = Vec3::new(r.dot(c), u.dot(c), f.dot(c));
        a = a.min(l);
        b = b.max(l);
    }
    a.z -= 1.0;
    b.z += 1.0;
    let s = Vec3::new(2.0, 2.0, 1.0) / (b - a).max(Vec3::splat(1e-3));
    Mat4::from_cols(
        glam::Vec4::new(s.x * r.x, s.y * u.x, s.z * f.x, 0.0),
        glam::Vec4::new(s.x * r.y, s.y * u.y, s.z * f.y, 0.0),
        glam::Vec4::new(s.x * r.z, s.y * u.z, s.z * f.z, 0.0),
        glam::Vec4::new(-s.x * a.x - 1.0, -s.y * a.y - 1.0, -s.z * a.z, 1.0),
    )
}

/// A depth-array texture of orthographic maps and the bounds its layers cover.
struct MapSet {
    px: u32,
    texture: wgpu::Texture,
    bounds: Aabb,
    /// Index range drawn into it.
    indices: std::ops::Range<u32>,
    /// Light directions its layers were rendered for (`None`: never).
    rendered_for: Option<Vec<[f32; 3]>>,
}

/// An axis-aligned box (min, max).
type Aabb = (Vec3, Vec3);

fn union(a: Option<Aabb>, lo: Vec3, hi: Vec3) -> Option<Aabb> {
    Some(match a {
        Some((a, b)) => (a.min(lo), b.max(hi)),
        None => (lo, hi),
    })
}

/// Bounds of the static mesh, and of the spheres the movers turn in.
fn bounds(scene: &Scene) -> (Option<Aabb>, Option<Aabb>) {
    let mut stat = None;
    for p in &scene.mesh.positions {
        stat = union(stat, *p, *p);
    }
    let mut movers = None;
    for m in &scene.movers {
        let r = m
            .mesh
            .positions
            .iter()
            .map(|p| p.distance(m.pivot))
            .fold(0.0f32, f32::max);
        movers = union(movers, m.pivot - Vec3::splat(r), m.pivot + Vec3::splat(r));
    }
    (stat, movers)
}

fn depth_array(ctx: &GpuContext, label: &str, px: u32, layers: usize) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: px,
            height: px,
            depth_or_array_layers: layers.max(1) as u32,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Depth32Float,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    })
}

impl MapSet {
    fn new(
        ctx: &GpuContext,
        label: &str,
        px: u32,
        layers: usize,
        bounds: Option<Aabb>,
        indices: std::ops::Range<u32>,
    ) -> MapSet {
        let px = if bounds.is_some() && layers > 0 {
            px
        } else {
            1
        };
        MapSet {
            px,
            texture: depth_array(ctx, label, px, layers),
            bounds: bounds.unwrap_or((Vec3::ZERO, Vec3::ONE)),
            indices,
            rendered_for: None,
        }
    }

    fn used(&self) -> bool {
        self.px > 1
    }

    fn bytes(&self, layers: usize) -> u64 {
        if self.used() {
            self.px as u64 * self.px as u64 * 4 * layers as u64
        } else {
            0
        }
    }

    fn map_gpu(&self, dir: Vec3, layer: usize) -> MapGpu {
        if !self.used() {
            return no_map();
        }
        let (lo, hi) = self.bounds;
        MapGpu {
            view_proj: light_view_proj(dir, lo, hi).to_cols_array_2d(),
            layer: layer as i32,
            texel_m: (hi - lo).max_element() / self.px as f32,
            kind: KIND_ORTHO,
            _pad: 0.0,
        }
    }
}

impl LocalMaps {
    fn new(ctx: &GpuContext, scene: &Scene, px: u32, bounds: Option<Aabb>) -> LocalMaps {
        let mut lights = Vec::new();
        let mut layers = 0;
        if px > 0 && bounds.is_some() {
            for (i, l) in scene.lights.iter().enumerate() {
                if l.kind != LightKind::Directional {
                    let cube = is_cube(l);
                    lights.push((i, layers, cube));
                    layers += if cube { 6 } else { 1 };
                }
            }
        }
        let px = if layers > 0 { local_px(px) } else { 1 };
        LocalMaps {
            px,
            texture: depth_array(ctx, "spot and cube shadow maps", px, layers),
            bounds: bounds.unwrap_or((Vec3::ZERO, Vec3::ONE)),
            rendered_for: vec![None; lights.len()],
            lights,
            layers,
            movers_time: None,
            has_movers: !scene.movers.is_empty(),
        }
    }

    /// Light `l`'s maps (first layer `layer`) and their projections.
    fn maps_gpu(&self, l: &Light, layer: usize, cube: bool) -> LightMapsGpu {
        let far = far_plane(l.position, self.bounds);
        // A point light outside the scene's bounding sphere sees all of it in one
        // perspective map aimed at it: a cube would spend its texels on empty directions
        // (a lamp 10 km away: 39 m texels at 512²).
        let (lo, hi) = self.bounds;
        let (centre, radius) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
        let to_centre = centre - l.position;
        let d = to_centre.length();
        let (view_proj, kind, fov, faces) = if cube && d > 1.1 * radius {
            let dir = to_centre / d;
            let up = if dir.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
            let fov = (2.1 * (radius / d).asin()).min(170f32.to_radians());
            let near = ((d - radius) * 0.9).max(LOCAL_NEAR_M);
            let vp = perspective_view_proj_near(l.position, dir, up, fov, near, d + radius + 1.0)
                .to_cols_array_2d();
            (vp, KIND_PERSPECTIVE, fov, [vp; 6])
        } else if cube {
            let faces = cube_view_projs(l.position, far).map(|m| m.to_cols_array_2d());
            (faces[0], KIND_CUBE, std::f32::consts::FRAC_PI_2, faces)
        } else {
            let dir = l.direction.normalize();
            let up = if dir.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
            let fov = spot_fov(l);
            let vp = perspective_view_proj(l.position, dir, up, fov, far).to_cols_array_2d();
            (vp, KIND_PERSPECTIVE, fov, [vp; 6])
        };
        LightMapsGpu {
            scene: MapGpu {
                view_proj,
                layer: layer as i32,
                texel_m: 2.0 * (fov * 0.5).tan() / self.px as f32,
                kind,
                _pad: 0.0,
            },
            movers: no_map(),
            faces,
        }
    }

    fn bytes(&self) -> u64 {
        self.px as u64 * self.px as u64 * 4 * self.layers as u64 * u64::from(self.layers > 0)
    }
}

impl ShadowMaps {
    /// Maps of `px`² for the scene's directional lights and of [`local_px`]`(px)`² for
    /// its spot and point lights (none when `px` is 0: 1×1 stand-ins keep the stages'
    /// bindings valid).
    pub(crate) fn new(ctx: &GpuContext, scene: &Scene, px: u32) -> Self {
        let lights: Vec<usize> = if px == 0 {
            Vec::new()
        } else {
            scene
                .lights
                .iter()
                .enumerate()
                .filter(|(_, l)| l.kind == LightKind::Directional)
                .map(|(i, _)| i)
                .collect()
        };
        let (static_bounds, mover_bounds) = bounds(scene);
        let all_bounds = match (static_bounds, mover_bounds) {
            (Some(a), Some(b)) => union(Some(a), b.0, b.1),
            (a, b) => a.or(b),
        };
        let local = LocalMaps::new(ctx, scene, px, all_bounds);
        let static_indices = scene.mesh.indices.len() as u32 * 3;
        let mover_indices = scene
            .movers
            .iter()
            .map(|m| m.mesh.indices.len() as u32 * 3)
            .sum::<u32>();
        let n = lights.len();
        let scene_maps = MapSet::new(ctx, "shadow maps", px, n, static_bounds, 0..static_indices);
        let mover_maps = MapSet::new(
            ctx,
            "mover shadow maps",
            MOVER_PX,
            n,
            mover_bounds,
            static_indices..static_indices + mover_indices,
        );
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow map compare"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let mut info_cpu = vec![
            LightMapsGpu {
                scene: no_map(),
                movers: no_map(),
                faces: Default::default(),
            };
            scene.lights.len().max(1)
        ];
        let lights_now = scene.lights_at(0.0);
        for (layer, li) in lights.iter().enumerate() {
            let dir = lights_now[*li].direction;
            info_cpu[*li] = LightMapsGpu {
                scene: scene_maps.map_gpu(dir, layer),
                movers: mover_maps.map_gpu(dir, layer),
                faces: Default::default(),
            };
        }
        for &(li, layer, cube) in &local.lights {
            info_cpu[li] = local.maps_gpu(&lights_now[li], layer, cube);
        }
        let info = ctx.storage_init("shadow map info", &info_cpu, wgpu::BufferUsages::COPY_DST);
        let layout = dynamic_uniform_layout(ctx, "shadow map", wgpu::ShaderStages::VERTEX, 64);
        let pipeline =
            (!lights.is_empty() || local.layers > 0).then(|| Self::pipeline(ctx, &layout));
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow map views"),
            size: VIEW_STRIDE * (2 * n + local.layers).max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ShadowMaps {
            scene_maps,
            mover_maps,
            local,
            sampler,
            info,
            info_cpu,
            lights,
            movers_time: None,
            pipeline,
            layout,
            uniforms,
        }
    }

    fn pipeline(ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> wgpu::RenderPipeline {
        let module = ctx.shader(
            "shadow_map",
            &[include_str!("../../shaders/shadow_map.wgsl")],
        );
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("shadow map"),
                bind_group_layouts: &[Some(layout)],
                immediate_size: 0,
            });
        ctx.device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("shadow map"),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: 16,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                    })],
                },
                primitive: wgpu::PrimitiveState {
                    cull_mode: None,
                    ..Default::default()
                },
                depth_stencil: Some(depth_test()),
                multisample: Default::default(),
                fragment: None,
                multiview_mask: None,
                cache: None,
            })
    }

    /// The bind-group layout of a compute stage that reads the maps: the stage's own
    /// `entries`, then the maps' at bindings 10–14 (`shaders/shadow_lookup.wgsl`).
    pub(crate) fn stage_layout(
        ctx: &GpuContext,
        label: &str,
        mut entries: Vec<wgpu::BindGroupLayoutEntry>,
    ) -> wgpu::BindGroupLayout {
        entries.extend(Self::layout_entries());
        ctx.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            })
    }

    /// A bind group for [`Self::stage_layout`]'s `layout`: the stage's own `entries`,
    /// then this frame's maps.
    pub(crate) fn stage_bind_group(
        &self,
        ctx: &GpuContext,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        entries: Vec<wgpu::BindGroupEntry<'_>>,
    ) -> wgpu::BindGroup {
        let views = [
            array_view(&self.scene_maps.texture),
            array_view(&self.mover_maps.texture),
            array_view(&self.local.texture),
        ];
        let entries: Vec<wgpu::BindGroupEntry> =
            entries.into_iter().chain(self.entries(&views)).collect();
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        })
    }

    /// Layout entries 10–14: the maps, their sampler and their projections (compute).
    fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 5] {
        Self::layout_entries_for(wgpu::ShaderStages::COMPUTE)
    }

    /// Layout entries 10–14 for the shader stages `visibility` (the smoke raster reads the
    /// maps in its fragment stage).
    pub(crate) fn layout_entries_for(
        visibility: wgpu::ShaderStages,
    ) -> [wgpu::BindGroupLayoutEntry; 5] {
        let depth_array = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Depth,
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        [
            depth_array(10),
            wgpu::BindGroupLayoutEntry {
                binding: 11,
                visibility,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                visibility,
                ..storage_entry(12, Read)
            },
            depth_array(13),
            depth_array(14),
        ]
    }

    /// Bind-group entries 10–14 for [`Self::layout_entries`].
    fn entries<'a>(&'a self, views: &'a [wgpu::TextureView; 3]) -> [wgpu::BindGroupEntry<'a>; 5] {
        let texture = |binding, view| wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(view),
        };
        [
            texture(10, &views[0]),
            wgpu::BindGroupEntry {
                binding: 11,
                resource: wgpu::BindingResource::Sampler(&self.sampler),
            },
            wgpu::BindGroupEntry {
                binding: 12,
                resource: self.info.as_entire_binding(),
            },
            texture(13, &views[1]),
            texture(14, &views[2]),
        ]
    }

    /// Bytes of the depth maps.
    pub(crate) fn bytes(&self) -> u64 {
        let n = self.lights.len();
        self.scene_maps.bytes(n) + self.mover_maps.bytes(n) + self.local.bytes()
    }

    /// Whether every light of the scene has a map (none without geometry or with
    /// `shadow_map_px` 0).
    pub(crate) fn maps_every_light(&self) -> bool {
        self.info_cpu.iter().all(|i| i.scene.layer >= 0)
    }

    /// Forgets what the maps were rendered for: the next frame renders them all.
    pub(crate) fn invalidate(&mut self) {
        self.scene_maps.rendered_for = None;
        self.mover_maps.rendered_for = None;
        self.movers_time = None;
        self.local.rendered_for.iter_mut().for_each(|r| *r = None);
        self.local.movers_time = None;
    }

    /// Re-renders the static maps if a directional light turned, the movers' maps if
    /// the movers moved, and a spot or point light's maps if it moved (or movers did);
    /// returns whether it recorded anything.
    pub(crate) fn add_passes(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &Scene,
        scene_gpu: &SceneGpu,
        time_s: f32,
        ts: &Timestamps,
    ) -> bool {
        let Some(pipeline) = &self.pipeline else {
            return false;
        };
        let lights: Vec<Light> = scene.lights_at(time_s);
        let dirs: Vec<[f32; 3]> = self
            .lights
            .iter()
            .map(|li| lights[*li].direction.to_array())
            .collect();
        let n = self.lights.len();
        let redo_scene = n > 0 && self.scene_maps.rendered_for.as_ref() != Some(&dirs);
        let redo_movers = n > 0
            && self.mover_maps.used()
            && (redo_scene
                || self.mover_maps.rendered_for.as_ref() != Some(&dirs)
                || self.movers_time != Some(time_s));
        let movers_moved = self.local.has_movers && self.local.movers_time != Some(time_s);
        let redo_local: Vec<bool> = self
            .local
            .lights
            .iter()
            .zip(&self.local.rendered_for)
            .map(|((li, _, _), done)| {
                let l = &lights[*li];
                let key = [l.position.to_array(), l.direction.to_array()].concat();
                movers_moved || done.as_ref().map(|d| &d[..]) != Some(&key[..])
            })
            .collect();
        if !redo_scene && !redo_movers && !redo_local.contains(&true) {
            return false;
        }
        // Projections of the current lights: directional static maps in the uniforms'
        // first slots, their movers' maps next, then one slot per spot or cube layer.
        let local_layers = self.local.layers;
        let mut bytes = vec![0u8; VIEW_STRIDE as usize * (2 * n + local_layers).max(1)];
        let mut put = |slot: usize, m: &[[f32; 4]; 4]| {
            let at = slot * VIEW_STRIDE as usize;
            bytes[at..at + 64].copy_from_slice(bytemuck::cast_slice(m));
        };
        for (layer, li) in self.lights.iter().enumerate() {
            let dir = lights[*li].direction;
            self.info_cpu[*li] = LightMapsGpu {
                scene: self.scene_maps.map_gpu(dir, layer),
                movers: self.mover_maps.map_gpu(dir, layer),
                faces: Default::default(),
            };
            put(layer, &self.info_cpu[*li].scene.view_proj);
            put(n + layer, &self.info_cpu[*li].movers.view_proj);
        }
        for &(li, layer, cube) in &self.local.lights {
            let m = self.local.maps_gpu(&lights[li], layer, cube);
            self.info_cpu[li] = m;
            for (f, face) in m.faces.iter().enumerate().take(if cube { 6 } else { 1 }) {
                put(2 * n + layer + f, face);
            }
        }
        ctx.queue.write_buffer(&self.uniforms, 0, &bytes);
        ctx.queue
            .write_buffer(&self.info, 0, bytemuck::cast_slice(&self.info_cpu));
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shadow map"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &self.uniforms,
                    offset: 0,
                    size: wgpu::BufferSize::new(64),
                }),
            }],
        });
        // (texture, layer, uniform slot, indices) of each pass.
        let all = 0..self.mover_maps.indices.end.max(self.scene_maps.indices.end);
        let mut passes: Vec<(&wgpu::Texture, usize, usize, std::ops::Range<u32>)> = Vec::new();
        for layer in 0..n {
            if redo_scene {
                let s = &self.scene_maps;
                passes.push((&s.texture, layer, layer, s.indices.clone()));
            }
            if redo_movers {
                let m = &self.mover_maps;
                passes.push((&m.texture, layer, n + layer, m.indices.clone()));
            }
        }
        for (&(li, layer, _), redo) in self.local.lights.iter().zip(&redo_local) {
            if *redo {
                // A point light far outside the scene has one perspective map.
                let faces = if self.info_cpu[li].scene.kind == KIND_CUBE {
                    6
                } else {
                    1
                };
                for f in 0..faces {
                    passes.push((
                        &self.local.texture,
                        layer + f,
                        2 * n + layer + f,
                        all.clone(),
                    ));
                }
            }
        }
        for (texture, layer, slot, indices) in passes {
            let view = texture.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: layer as u32,
                array_layer_count: Some(1),
                ..Default::default()
            });
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow map"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts.render(Stage::ShadowMaps),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if indices.is_empty() {
                continue;
            }
            let offset = (slot as u64 * VIEW_STRIDE) as u32;
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bg, &[offset]);
            pass.set_vertex_buffer(0, scene_gpu.vertices.slice(..));
            pass.set_index_buffer(scene_gpu.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(indices, 0, 0..1);
        }
        if redo_scene {
            self.scene_maps.rendered_for = Some(dirs.clone());
        }
        if redo_movers {
            self.mover_maps.rendered_for = Some(dirs);
            self.movers_time = Some(time_s);
        }
        for (((li, _, _), done), redo) in self
            .local
            .lights
            .iter()
            .zip(self.local.rendered_for.iter_mut())
            .zip(&redo_local)
        {
            if *redo {
                let l = &lights[*li];
                let mut key = [0.0; 6];
                key[..3].copy_from_slice(&l.position.to_array());
                key[3..].copy_from_slice(&l.direction.to_array());
                *done = Some(key);
            }
        }
        if self.local.has_movers {
            self.local.movers_time = Some(time_s);
        }
        true
    }
}

fn array_view(t: &wgpu::Texture) -> wgpu::TextureView {
    t.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Clip-space xy/w and depth of `p` under `m`.
    fn project(m: Mat4, p: Vec3) -> Option<Vec3> {
        let c = m * p.extend(1.0);
        (c.w > 0.0).then(|| c.truncate() / c.w)
    }

    #[test]
    fn every_direction_lands_inside_the_cube_face_it_selects() {
        let eye = Vec3::new(1.0, 2.0, -3.0);
        let faces = cube_view_projs(eye, 50.0);
        let mut seen = [false; 6];
        let mut rng = 12345u32;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            rng as f32 / u32::MAX as f32 * 2.0 - 1.0
        };
        for k in 0..2000 {
            let d = if k < 6 {
                // Exactly on each axis.
                let (f, _) = face_axes(k);
                f
            } else {
                Vec3::new(next(), next(), next())
            };
            if d.length() < 1e-3 {
                continue;
            }
            let p = eye + d.normalize() * (1.0 + 20.0 * (k % 7) as f32 / 7.0);
            let f = cube_face(p - eye);
            seen[f] = true;
            let c = project(faces[f], p).expect("in front of its face");
            assert!(
                c.x.abs() <= 1.0 + 1e-4 && c.y.abs() <= 1.0 + 1e-4,
                "{d:?} on face {f}: {c:?}"
            );
            assert!((0.0..=1.0).contains(&c.z), "{d:?}: depth {}", c.z);
            // Every other face sees it outside its square or behind it.
            for (g, m) in faces.iter().enumerate() {
                if g != f {
                    let inside =
                        project(*m, p).is_some_and(|c| c.x.abs() < 0.999 && c.y.abs() < 0.999);
                    assert!(!inside, "{d:?}: face {g} also covers it (selected {f})");
                }
            }
        }
        assert_eq!(seen, [true; 6]);
        // Nearer is shallower along a face.
        let a = project(faces[0], eye + Vec3::new(2.0, 0.1, 0.0)).unwrap();
        let b = project(faces[0], eye + Vec3::new(8.0, 0.1, 0.0)).unwrap();
        assert!(a.z < b.z);
    }

    #[test]
    fn spot_maps_cover_the_cone_and_wide_spots_get_cubes() {
        let spot = |outer_deg: f32| Light {
            kind: LightKind::Spot,
            position: Vec3::new(0.0, 5.0, 0.0),
            direction: Vec3::new(0.3, -1.0, 0.1).normalize(),
            radiance: Vec3::ONE,
            cos_outer: outer_deg.to_radians().cos(),
            cos_inner: (outer_deg * 0.5).to_radians().cos(),
            swing: None,
        };
        let l = spot(20.0);
        assert!(!is_cube(&l) && is_cube(&spot(75.0)));
        let bounds = (Vec3::splat(-10.0), Vec3::splat(10.0));
        let vp = perspective_view_proj(
            l.position,
            l.direction,
            Vec3::Y,
            spot_fov(&l),
            far_plane(l.position, bounds),
        );
        // Points on the outer cone at several distances and angles project inside.
        let (r, u) = (
            l.direction.cross(Vec3::Y).normalize(),
            l.direction.cross(l.direction.cross(Vec3::Y)).normalize(),
        );
        for k in 0..16 {
            let a = k as f32 / 16.0 * std::f32::consts::TAU;
            let edge = (l.direction * 20f32.to_radians().cos()
                + (r * a.cos() + u * a.sin()) * 20f32.to_radians().sin())
            .normalize();
            for t in [0.5, 3.0, 12.0] {
                let c = project(vp, l.position + edge * t).unwrap();
                assert!(c.x.abs() < 1.0 && c.y.abs() < 1.0, "{c:?}");
                assert!((0.0..1.0).contains(&c.z));
            }
        }
        assert_eq!(local_px(4096), 512);
        assert_eq!(local_px(64), 64);
    }
}
