//! Per-viewer resources, stacked so that one dispatch covers every viewer.

use crate::gpu::GpuContext;

/// Sizes of one viewer's volumes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ViewerLayout {
    /// Image size, pixels.
    pub width: u32,
    /// Image size, pixels.
    pub height: u32,
    /// Froxel grid (x, y) of the lighting volume.
    pub froxel_dims: [u32; 2],
    /// Froxel grid (x, y) of the shadow frustum.
    pub frustum_dims: [u32; 2],
}

impl ViewerLayout {
    /// The layout of a `width`×`height` viewer under `settings`.
    pub fn new(settings: &super::Settings, width: u32, height: u32) -> ViewerLayout {
        let dims = |px: u32| [width.div_ceil(px), height.div_ceil(px)];
        ViewerLayout {
            width,
            height,
            froxel_dims: dims(settings.froxel_px),
            frustum_dims: dims(settings.frustum_px),
        }
    }
}

/// Bytes of each stacked storage buffer of [`ViewerVolumes`] for `count` viewers, in the
/// order they are allocated: the one list `ViewerVolumes::new` allocates from and
/// [`largest_binding`] predicts from.
fn storage_sizes(
    count: usize,
    layout: &ViewerLayout,
    slices: u32,
    frustum_slices: u32,
    temporal: bool,
    output_pixels: u64,
) -> [(&'static str, u64); 7] {
    let n = count as u64;
    let columns = n * (layout.froxel_dims[0] * layout.froxel_dims[1]) as u64;
    let froxels = columns * slices as u64 * 8;
    let frustum =
        n * (layout.frustum_dims[0] * layout.frustum_dims[1] * frustum_slices.max(1)) as u64 * 4;
    [
        ("froxels", froxels),
        ("froxel history", if temporal { froxels } else { 16 }),
        ("integrated", froxels),
        ("shadow frustum", frustum),
        ("tile depth", columns * 4),
        ("column limit", columns * 4),
        ("output", output_pixels * 4),
    ]
}

/// [`storage_sizes`] of a set of `count` views of `width`×`height` under `settings`, each
/// view its own frame (what the server's budget plans with).
fn planned_sizes(
    settings: &super::Settings,
    count: usize,
    width: u32,
    height: u32,
) -> [(&'static str, u64); 7] {
    storage_sizes(
        count,
        &ViewerLayout::new(settings, width, height),
        settings.slices,
        settings.frustum_slices(),
        settings.temporal,
        count as u64 * width as u64 * height as u64,
    )
}

/// The largest storage buffer that [`ViewerVolumes`] for `count` views of
/// `width`×`height` under `settings` would bind, as (label, bytes) — rounded up to 16
/// bytes, as `GpuContext::storage` checks it against the adapter's binding limit — so
/// that a caller can refuse a size before its allocation fails.
pub fn largest_binding(
    settings: &super::Settings,
    count: usize,
    width: u32,
    height: u32,
) -> (&'static str, u64) {
    planned_sizes(settings, count, width, height)
        .into_iter()
        .map(|(label, size)| (label, size.max(16).next_multiple_of(16)))
        // The first of equal sizes, as allocation fails on it first.
        .reduce(|a, b| if b.1 > a.1 { b } else { a })
        .expect("seven sizes")
}

/// G-buffer bytes per pixel: the packed surface (rgba32uint,
/// shaders/gbuffer_surface.wgsl) and the depth attachment (32f).
const GBUFFER_BYTES_PER_PIXEL: u64 = 16 + 4;

/// Format of the packed G-buffer: view depth (f32 bits), octahedral normal (2 × snorm16),
/// albedo (rgba8), one spare word.
pub(crate) const GBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;

/// Layout entry of the packed G-buffer array (`ViewerVolumes::gbuf_array`) at `binding`.
pub(crate) fn gbuffer_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Uint,
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    }
}

/// GPU memory of [`ViewerVolumes`] for `count` views of `width`×`height` under
/// `settings` in a scene holding at most `smoke_particles` particles
/// ([`particle_capacity`](super::scene_gpu::particle_capacity), 0 without emitters):
/// every stacked buffer, the G-buffer and the smoke's proxy lists and layers (what the
/// server's admission budget adds up over all view sizes).
pub fn viewer_memory_bytes(
    settings: &super::Settings,
    count: usize,
    width: u32,
    height: u32,
    smoke_particles: u32,
) -> u64 {
    let buffers: u64 = planned_sizes(settings, count, width, height)
        .iter()
        .map(|(_, bytes)| bytes.max(&16).next_multiple_of(16))
        .sum();
    let pixels = width as u64 * height as u64;
    let smoke = if smoke_particles > 0 {
        super::smoke_view::bytes_per_viewer(smoke_particles, pixels)
    } else {
        0
    };
    buffers + count as u64 * (pixels * GBUFFER_BYTES_PER_PIXEL + smoke)
}

/// Dispatch sizes of the per-viewer stages, computed once per allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Workgroups {
    /// One invocation per froxel column (8 × 8 per workgroup) × the views that light
    /// froxels of their own (all but coupled stereo eyes without a near field; set every
    /// frame by `ViewerSet::prepare`).
    pub columns: [u32; 3],
    /// One invocation per froxel column × every view (each integrates its own volume:
    /// a coupled stereo eye reads its partner's froxels beyond its near field).
    pub integration: [u32; 3],
    /// One invocation per shadow-frustum column × the views that light froxels.
    pub frustum: [u32; 3],
    /// One invocation per strip of 4 pixels (8·4 × 8 per workgroup) × viewers.
    pub pixels: [u32; 3],
}

/// Pixels per composite invocation (`STRIP` in `shaders/composite.wgsl`).
const STRIP: u32 = 4;

/// Every viewer's froxel volumes, shadow frustums, G-buffer and output image.
///
/// Viewer `i`'s froxels start at `i × froxels_per_view` in each stacked buffer.
pub struct ViewerVolumes {
    pub(crate) count: usize,
    pub(crate) layout: ViewerLayout,
    pub(crate) slices: u32,
    pub(crate) frustum_slices: u32,
    pub(crate) groups: Workgroups,
    /// Pixels of the output buffer: the frames of every target of the set, one after
    /// another, each viewer's image a tile of its frame.
    pub(crate) output_pixels: u64,
    /// In-scattering (src rgb, σt), packed f16: the output of froxel lighting.
    pub(crate) froxels: wgpu::Buffer,
    /// Last frame's froxels (temporal reprojection): the two buffers swap after every
    /// frame (a 16-byte stub when off).
    pub(crate) froxel_history: wgpu::Buffer,
    pub(crate) integrated: wgpu::Buffer,
    pub(crate) frustum: wgpu::Buffer,
    /// Hidden-froxel culling: farthest depth of each froxel column's 8 × 8 pixel tile,
    /// and the last slice each column must light (u32 per column).
    pub(crate) tile_depth: wgpu::Buffer,
    pub(crate) column_limit: wgpu::Buffer,
    pub(crate) output: wgpu::Buffer,
    /// Each pixel's surface, packed (`GBUFFER_FORMAT`; shaders/gbuffer_surface.wgsl).
    pub(crate) gbuf: wgpu::Texture,
    pub(crate) gbuf_depth: wgpu::Texture,
    /// Smoke proxies and layers (a scene with emitters only; smoke_view.rs).
    pub(crate) smoke: Option<super::smoke_view::SmokeBuffers>,
}

impl ViewerVolumes {
    pub(crate) fn new(
        ctx: &GpuContext,
        count: usize,
        layout: ViewerLayout,
        slices: u32,
        frustum_slices: u32,
        temporal: bool,
        output_pixels: u64,
    ) -> anyhow::Result<ViewerVolumes> {
        let [froxels, froxel_history, integrated, frustum, tile_depth, column_limit, output] =
            storage_sizes(
                count,
                &layout,
                slices,
                frustum_slices,
                temporal,
                output_pixels,
            )
            .map(|(label, bytes)| ctx.storage(label, bytes, wgpu::BufferUsages::empty()));
        let tex = |label: &str, format: wgpu::TextureFormat, usage: wgpu::TextureUsages| {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: layout.width,
                    height: layout.height,
                    depth_or_array_layers: count as u32,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING
                    | usage,
                view_formats: &[],
            })
        };
        let n = count as u32;
        let per_8 = |[x, y]: [u32; 2]| [x.div_ceil(8), y.div_ceil(8), n];
        Ok(ViewerVolumes {
            count,
            layout,
            slices,
            frustum_slices,
            output_pixels,
            groups: Workgroups {
                columns: per_8(layout.froxel_dims),
                integration: per_8(layout.froxel_dims),
                frustum: per_8(layout.frustum_dims),
                pixels: [
                    layout.width.div_ceil(8 * STRIP),
                    layout.height.div_ceil(8),
                    n,
                ],
            },
            froxels: froxels?,
            froxel_history: froxel_history?,
            integrated: integrated?,
            frustum: frustum?,
            tile_depth: tile_depth?,
            column_limit: column_limit?,
            output: output?,
            // Also written by `micro_raster`'s resolve (src/render/triangle_cull.rs).
            gbuf: tex(
                "gbuffer",
                GBUFFER_FORMAT,
                wgpu::TextureUsages::STORAGE_BINDING,
            ),
            gbuf_depth: tex(
                "gbuffer depth",
                wgpu::TextureFormat::Depth32Float,
                wgpu::TextureUsages::empty(),
            ),
            smoke: None,
        })
    }

    /// The packed G-buffer of every view as one array view (composite, hidden-froxel
    /// culling and the smoke raster read it; gbuffer_entry is its layout entry).
    pub(crate) fn gbuf_array(&self) -> wgpu::TextureView {
        self.gbuf.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        })
    }

    pub(crate) fn froxels_per_view(&self) -> u32 {
        self.layout.froxel_dims[0] * self.layout.froxel_dims[1] * self.slices
    }

    pub(crate) fn frustum_per_view(&self) -> u32 {
        self.layout.frustum_dims[0] * self.layout.frustum_dims[1] * self.frustum_slices.max(1)
    }

    /// (name, bytes per viewer) of every per-viewer resource.
    pub(crate) fn memory_per_viewer(&self) -> Vec<(&'static str, u64)> {
        let n = self.count.max(1) as u64;
        let pixels = (self.layout.width * self.layout.height) as u64;
        let history = if self.froxel_history.size() > 16 {
            self.froxel_history.size() / n
        } else {
            0
        };
        let mut list = vec![
            ("froxels", self.froxels.size() / n),
            ("froxel_history", history),
            ("integrated", self.integrated.size() / n),
            ("shadow_frustum", self.frustum.size() / n),
            (
                "froxel_cull",
                (self.tile_depth.size() + self.column_limit.size()) / n,
            ),
            ("gbuffer", pixels * GBUFFER_BYTES_PER_PIXEL),
            ("output", pixels * 4),
        ];
        if let Some(s) = &self.smoke {
            list.push(("smoke", s.bytes_per_viewer(pixels)));
        }
        list
    }
}
