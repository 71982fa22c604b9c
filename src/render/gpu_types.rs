//! Host mirrors of the structs in `shaders/common.wgsl` (layouts must match byte for byte).

use crate::scene::{Light, Medium, MediumKind, Volume};
use bytemuck::{Pod, Zeroable};

pub(crate) const FLAG_PARITY: u32 = 1;
pub(crate) const FLAG_TRILINEAR: u32 = 2;
pub(crate) const FLAG_SHARED: u32 = 4;
pub(crate) const FLAG_MEDIA: u32 = 8;
pub(crate) const FLAG_DEMAND: u32 = 32;
pub(crate) const FLAG_CACHE: u32 = 64;
pub(crate) const FLAG_SPARSE: u32 = 128;
pub(crate) const FLAG_CULL: u32 = 256;
pub(crate) const FLAG_MEDIA_T: u32 = 512;
pub(crate) const FLAG_LAYER: u32 = 1024;
/// Mode `maps`: every froxel reads the shared shadow maps.
pub(crate) const FLAG_MAPS: u32 = 2048;
pub(crate) const FLAG_LAYER_FULL: u32 = 4096;
/// Ambient light from the shared SH grid (ambient_grid.rs), not the constant `ambient`.
pub(crate) const FLAG_SH_AMBIENT: u32 = 8192;
/// `shared` with `froxel_maps`: froxels read the maps of the lights that have one.
pub(crate) const FLAG_FROXEL_MAPS: u32 = 16384;
/// `shared` with `map_edges`: where the grid's voxels around a froxel disagree, the map.
pub(crate) const FLAG_MAP_EDGES: u32 = 32768;
/// `shared` with `grid_media`: the grid carries the costly media's density.
pub(crate) const FLAG_GRID_MEDIA: u32 = 65536;
/// With `FLAG_GRID_MEDIA`: the grid's media move, every needed voxel is refilled.
pub(crate) const FLAG_GRID_MEDIA_MOVES: u32 = 131072;
/// `froxel_requests` this frame: no request pass; froxels request the voxels they find
/// unfilled for the next frame's grid pass, and trace their own rays meanwhile.
pub(crate) const FLAG_FROXEL_REQUESTS: u32 = 262144;
/// With `FLAG_GRID_MEDIA` and `grid_media_fine`: the density on cells of half a voxel.
pub(crate) const FLAG_GRID_MEDIA_FINE: u32 = 524288;

/// Indices into the counters buffer (`C_*` in common.wgsl).
pub(crate) const COUNTERS: usize = 13;
pub(crate) const C_GRID_RAYS: usize = 0;
pub(crate) const C_FRUSTUM_RAYS: usize = 1;
pub(crate) const C_LIGHTING_RAYS: usize = 2;
pub(crate) const C_SURFACE_RAYS: usize = 3;
pub(crate) const C_VOXELS_TRACED: usize = 4;
pub(crate) const C_FROXELS_WITH_MEDIA: usize = 5;
pub(crate) const C_VOXELS_NEEDED: usize = 6;
pub(crate) const C_BRICKS: usize = 7;
pub(crate) const C_TRANSMITTANCE_NODES: usize = 8;
pub(crate) const C_LAYER_BRICKS: usize = 9;
pub(crate) const C_LAYER_NODES: usize = 10;
pub(crate) const C_GRID_MEDIA_VOXELS: usize = 11;
pub(crate) const C_RASTER_TRIANGLES: usize = 12;

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct FrameGpu {
    pub grid_min: [f32; 3],
    pub voxel_size: f32,
    pub grid_dims: [u32; 3],
    pub light_count: u32,
    pub sky: [f32; 3],
    pub medium_count: u32,
    pub ambient: [f32; 3],
    pub exposure: f32,
    pub view_count: u32,
    pub frame_index: u32,
    pub flags: u32,
    pub time_s: f32,
    pub grid_words_x: u32,
    pub max_ray_m: f32,
    pub frustum_slices: u32,
    pub slices: u32,
    pub depth_curve: f32,
    pub dirty_lights: u32,
    pub pool_capacity: u32,
    pub mover_root: u32,
    pub moved_min: [f32; 3],
    pub transmittance_dirty: u32,
    pub moved_max: [f32; 3],
    pub media_step_m: f32,
    /// The world media layer (media_layer.rs): its origin, voxel edge, bricks a side,
    /// pool slots, this frame's fill stamp, its first medium and words per node.
    pub layer_min: [f32; 3],
    pub layer_voxel: f32,
    pub layer_bricks: [u32; 3],
    pub layer_capacity: u32,
    pub layer_stamp: u32,
    pub layer_first: u32,
    pub layer_node_words: u32,
    /// Live smoke particles in `particles` (group 0, binding 12) this frame.
    pub particle_count: u32,
    /// The shared ambient grid (ambient_grid.rs): first probe, spacing, probes a side
    /// and in all.
    pub sh_min: [f32; 3],
    pub sh_cell: f32,
    pub sh_dims: [u32; 3],
    pub sh_probes: u32,
    /// The media in the shared grid (`grid_media`, media_layer.rs `GridMedia`): the box
    /// they fill, the density of one step of the 8-bit code, and their first medium.
    pub grid_media_min: [f32; 3],
    pub grid_media_unit: f32,
    pub grid_media_max: [f32; 3],
    pub grid_media_first: u32,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct ViewGpu {
    pub view_proj: [[f32; 4]; 4],
    pub prev_view_proj: [[f32; 4]; 4],
    pub position: [f32; 3],
    pub near: f32,
    pub forward: [f32; 3],
    pub far: f32,
    pub right: [f32; 3],
    pub tan_x: f32,
    pub up: [f32; 3],
    pub tan_y: f32,
    pub size: [u32; 2],
    pub froxel_dims: [u32; 2],
    pub frustum_dims: [u32; 2],
    pub froxel_px: u32,
    pub frustum_px: u32,
    pub froxel_base: u32,
    pub frustum_base: u32,
    pub pixel_base: u32,
    pub jitter: f32,
    /// Pixels per row of the frame this view's tile is written into.
    pub row_stride: u32,
    /// Where this viewer's froxels start in last frame's froxels ([`NO_HISTORY`]: none).
    pub history_base: u32,
    /// The slot whose froxel volume this view reads: its own, or (coupled stereo) its
    /// partner's, which lit one volume for both (viewer_set.rs, `stereo_pairs`).
    pub volume_view: u32,
    /// Slices this view lights in its own volume: every slice for a view of its own,
    /// the near field for a coupled stereo eye (`stereo_near_px`), 0 for one that reads
    /// its partner's volume only.
    pub light_slices: u32,
    /// Where its froxel volume is lit from: its eye, or for the first eye of a stereo
    /// head (`stereo_head`) the midpoint of the head's eyes (`volume_of` in common.wgsl).
    pub origin: [f32; 3],
    pub _pad: u32,
}

/// `ViewGpu::history_base` of a viewer without last frame's froxels.
pub(crate) const NO_HISTORY: u32 = u32::MAX;

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct LightGpu {
    pub position: [f32; 3],
    pub kind: u32,
    pub direction: [f32; 3],
    pub cos_outer: f32,
    pub radiance: [f32; 3],
    pub cos_inner: f32,
}

impl From<&Light> for LightGpu {
    fn from(l: &Light) -> Self {
        LightGpu {
            position: l.position.to_array(),
            kind: l.kind.gpu_code(),
            direction: l.direction.to_array(),
            cos_outer: l.cos_outer,
            radiance: l.radiance.to_array(),
            cos_inner: l.cos_inner,
        }
    }
}

/// One light's shared media transmittance volume (`LightMedia` in common.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub(crate) struct LightMediaGpu {
    pub centre: [f32; 3],
    pub radius: f32,
    pub dims: [u32; 3],
    pub offset: u32,
    pub spacing: f32,
    pub nodes: u32,
    pub near: f32,
    pub tan_half: f32,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct MediumGpu {
    pub min: [f32; 3],
    pub kind: u32,
    pub max: [f32; 3],
    pub absorption: f32,
    pub scattering: [f32; 3],
    pub g: f32,
    pub emission: [f32; 3],
    pub radius_or_falloff: f32,
    pub wind: [f32; 3],
    pub base_y: f32,
    pub noise_frequency: f32,
    pub noise_octaves: u32,
    pub noise_amplitude: f32,
    /// 1: read from the world media layer where it holds the point (media_layer.rs).
    pub in_layer: u32,
    // Volume primitives (kind 4); zero otherwise.
    pub center: [f32; 3],
    pub period_s: f32,
    pub velocity: [f32; 3],
    pub disp_amplitude: f32,
    pub disp_offset: [f32; 3],
    pub disp_frequency: f32,
    pub disp_octaves: u32,
    pub _pad2: [u32; 3],
}

impl From<&Medium> for MediumGpu {
    fn from(m: &Medium) -> Self {
        let v = m.volume.unwrap_or(Volume {
            center: glam::Vec3::ZERO,
            radius_m: 0.0,
            amplitude: 0.0,
            frequency: 0.0,
            octaves: 1,
            noise_offset: glam::Vec3::ZERO,
            velocity: glam::Vec3::ZERO,
            period_s: 1.0,
        });
        MediumGpu {
            min: m.min.to_array(),
            // MEDIUM_* in shaders/common.wgsl.
            kind: match m.kind {
                MediumKind::Constant => 0,
                MediumKind::Height => 1,
                MediumKind::Box => 2,
                MediumKind::Sphere => 3,
                MediumKind::Volume => 4,
            },
            max: m.max.to_array(),
            absorption: m.absorption,
            scattering: m.scattering.to_array(),
            g: m.g,
            emission: m.emission.to_array(),
            radius_or_falloff: m.radius_or_falloff,
            wind: m.noise.wind,
            base_y: m.base_y,
            noise_frequency: m.noise.frequency,
            noise_octaves: m.noise.octaves,
            noise_amplitude: m.noise.amplitude,
            in_layer: 0,
            center: v.center.to_array(),
            period_s: v.period_s,
            velocity: v.velocity.to_array(),
            disp_amplitude: v.amplitude,
            disp_offset: v.noise_offset.to_array(),
            disp_frequency: v.frequency,
            disp_octaves: v.octaves,
            _pad2: [0; 3],
        }
    }
}

const _: () = assert!(std::mem::size_of::<FrameGpu>() == 256);
const _: () = assert!(std::mem::size_of::<ViewGpu>() == 272);
const _: () = assert!(std::mem::size_of::<LightGpu>() == 48);
const _: () = assert!(std::mem::size_of::<MediumGpu>() == 160);
const _: () = assert!(std::mem::size_of::<LightMediaGpu>() == 48);

/// One live smoke particle (issue 15; `Particle` in common.wgsl): a Gaussian blob of 001
/// Eq. 9, `σ(l) = σ_centre e^{−50 l²/u²}`, with its emitter's coefficients at the centre.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct ParticleGpu {
    /// Centre, metres (render space).
    pub centre: [f32; 3],
    /// Falloff distance `u`, metres (0: a particle of zero size, which does nothing).
    pub falloff_u: f32,
    /// σs at the centre, per channel, m⁻¹.
    pub scattering: [f32; 3],
    /// σa at the centre, m⁻¹.
    pub absorption: f32,
    /// Henyey-Greenstein asymmetry.
    pub g: f32,
    /// Birth order within its emitter (ties in sorts and AVSM insertion).
    pub index: u32,
    /// Which `[[emitter]]` it came from.
    pub emitter: u32,
    /// Padding to 48 bytes.
    pub _pad: u32,
}

/// `SmokeMap.kind` in common.wgsl: no map (the smoke casts no shadow for the light).
pub(crate) const SMOKE_MAP_NONE: u32 = 0;
/// An orthographic map (directional light).
pub(crate) const SMOKE_MAP_ORTHO: u32 = 1;
/// A perspective map (point or spot light).
pub(crate) const SMOKE_MAP_PERSPECTIVE: u32 = 2;
/// A cube of six perspective faces (a point or spot light close to the smoke), on the
/// light's first record, which is also face 0.
pub(crate) const SMOKE_MAP_CUBE: u32 = 3;
/// Map records per light (`SMOKE_MAPS_PER_LIGHT` in common.wgsl): a cube's six faces.
pub(crate) const SMOKE_MAPS_PER_LIGHT: u32 = 6;

/// One light's smoke shadow map (`SmokeMap` in common.wgsl; smoke_shadows.rs).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub(crate) struct SmokeMapGpu {
    pub origin: [f32; 3],
    pub kind: u32,
    pub axis: [f32; 3],
    /// Orthographic: half-width of the map, metres; perspective: tangent of its half angle.
    pub extent: f32,
    pub ex: [f32; 3],
    /// First node of the map in the node buffer.
    pub offset: u32,
    pub ey: [f32; 3],
    /// Texels a side.
    pub px: u32,
    /// Nodes per texel.
    pub nodes: u32,
    /// [`SMOKE_MAP_CUBE`]: bit f set where face f holds a map.
    pub faces: u32,
    pub _pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<SmokeMapGpu>() == 80);
