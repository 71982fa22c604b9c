//! Per-view triangle culling before the G-buffer raster (`triangle_cull`), with
//! `shaders/triangle_cull.wgsl`: every view's index list of the triangles the raster can
//! make a fragment of, and its indirect draw (`GBuffer` draws them). With
//! `occlusion_cull` two lists a view, drawn in two phases, and `shaders/hiz.wgsl`'s
//! depth tiles between them.

use super::gbuffer::{Phase, HIZ_LEVELS, RASTER_VIEW_WGSL, VIEW_STRIDE};
use super::viewer_volumes::gbuffer_entry;
use super::{scene_gpu::SceneGpu, Stage, Timestamps, ViewerSet};
use crate::gpu::Access::{Read, ReadWrite};
use crate::gpu::{storage_entry, GpuContext};

/// Triangle culling's words per (view, cluster) pair: the count, then the masks of its
/// 1024 triangles (`PAIR_WORDS` in shaders/triangle_cull.wgsl).
const PAIR_WORDS: u64 = 33;

/// Bytes of one `DrawIndexedIndirect` record.
pub(crate) const DRAW_ARGS_BYTES: u64 = 20;

/// Words of `visible` per view and cluster: a bit per triangle of a 1024-triangle cluster.
const VISIBLE_WORDS: u64 = 32;

/// Static triangles a scene needs before `occlusion_cull` applies: below it the raster's
/// cost is its fixed per-view work, not its triangles, and the second phase only adds
/// (colonnade, 336 triangles, 16 viewers: G-buffer 23.5 → 26.7 ms with it;
/// docs/decisions.md, "G-buffer: two-phase occlusion culling").
pub const OCCLUSION_MIN_TRIANGLES: u64 = 65_536;

/// GPU memory the G-buffer's triangle culling (`triangle_cull`) can hold per view in a
/// scene of `static_triangles`: the view's index list if every cluster were in its
/// frustum, and a pair record per cluster (clusters of one cull each: at most 3 more
/// than a split into 1024s).
pub fn triangle_list_bytes_per_view(settings: &super::Settings, static_triangles: u64) -> u64 {
    if !settings.triangle_cull {
        return 0;
    }
    let clusters = static_triangles.div_ceil(super::scene_gpu::CLUSTER_TRIANGLES as u64) + 3;
    let lists = static_triangles * 12 + clusters * (16 + 3 * PAIR_WORDS * 4) + 2 * DRAW_ARGS_BYTES;
    if !settings.occlusion_cull || static_triangles < OCCLUSION_MIN_TRIANGLES {
        return lists;
    }
    // A 1920×1080 view's depth pyramid, and which triangles it saw.
    let tiles: u64 = (0..=HIZ_LEVELS)
        .map(|k| 1920u64.div_ceil(1 << k) * 1080u64.div_ceil(1 << k))
        .sum();
    lists + tiles * 4 + clusters * VISIBLE_WORDS * 4
}

/// Static triangles a scene needs before `micro_raster` applies: below it few triangles
/// are small, and the resolve, a pass over every pixel, costs more than they do
/// (colonnade, 336 triangles, 16 viewers: G-buffer 30.4 → 33.9 ms with it).
pub const MICRO_MIN_TRIANGLES: u64 = 65_536;

/// Bytes `micro_raster` holds per pixel of every view: the nearest small triangle's
/// 64-bit (depth, triangle) word (shaders/micro_atomic.wgsl).
const MICRO_BYTES_PER_PIXEL: u64 = 8;

/// GPU memory `micro_raster` holds per pixel of every view in a scene of
/// `static_triangles` (0 where it does not apply).
pub fn micro_bytes_per_pixel(settings: &super::Settings, static_triangles: u64) -> u64 {
    let switches = (
        settings.triangle_cull,
        settings.occlusion_cull,
        settings.micro_raster,
    );
    if micro_applies(switches, static_triangles) {
        MICRO_BYTES_PER_PIXEL
    } else {
        0
    }
}

/// Whether `micro_raster` applies given (`triangle_cull`, `occlusion_cull`,
/// `micro_raster`): culling on, one phase (occlusion culling applies only from
/// `OCCLUSION_MIN_TRIANGLES`), and a scene of at least `MICRO_MIN_TRIANGLES`.
fn micro_applies((cull, occlusion, micro): (bool, bool, bool), static_triangles: u64) -> bool {
    let two_phases = occlusion && static_triangles >= OCCLUSION_MIN_TRIANGLES;
    cull && micro && !two_phases && static_triangles >= MICRO_MIN_TRIANGLES
}

/// Binding `binding`: `set`'s raster views in the frame's view buffer, from its first.
fn set_views<'a>(
    binding: u32,
    views: &'a wgpu::Buffer,
    set: &ViewerSet,
) -> wgpu::BindGroupEntry<'a> {
    wgpu::BindGroupEntry {
        binding,
        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: views,
            offset: set.first_view as u64 * VIEW_STRIDE,
            size: wgpu::BufferSize::new(set.raster_views.len() as u64 * VIEW_STRIDE),
        }),
    }
}

/// Per-view triangle culling (`triangle_cull`): the frame's (view, cluster) pairs, what
/// the pass keeps of each, and every view's index list and indirect draw.
pub(crate) struct TriangleLists {
    layout: wgpu::BindGroupLayout,
    cull: wgpu::ComputePipeline,
    compact: wgpu::ComputePipeline,
    occlude: wgpu::ComputePipeline,
    hiz_layout: wgpu::BindGroupLayout,
    hiz_pipeline: wgpu::ComputePipeline,
    pairs: wgpu::Buffer,
    /// Three regions of masks and counts: kept, first list, second list.
    kept: wgpu::Buffer,
    pub(crate) indices: wgpu::Buffer,
    /// Every view's first list's draw, then every view's second list's.
    pub(crate) args: wgpu::Buffer,
    /// Per view and cluster, which triangles the view saw last frame.
    visible: wgpu::Buffer,
    /// Every view's depth tiles (`RasterView::hiz`).
    hiz: wgpu::Buffer,
    /// The pass parameters writing the first list, and the second
    /// (`params` in shaders/triangle_cull.wgsl).
    params: [wgpu::Buffer; 2],
    /// `micro_raster`: the resolve's pipeline and bindings, and every view's pixels'
    /// nearest small triangle (`RasterView::hiz[1]` places a view's; all zero between
    /// frames: the resolve clears what the culling wrote).
    micro_layout: wgpu::BindGroupLayout,
    micro_pipeline: wgpu::ComputePipeline,
    micro: wgpu::Buffer,
    /// Whether the culling rasterises the small triangles this frame.
    pub(crate) micro_on: bool,
    /// This frame's pairs (0: nothing to cull, or culling off).
    pub(crate) pair_count: u32,
    /// This frame's views (all sets), and whether they draw in two phases.
    pub(crate) views: u32,
    pub(crate) occlusion: bool,
}

impl TriangleLists {
    pub(crate) fn new(ctx: &GpuContext) -> Self {
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("triangle cull"),
                entries: &[
                    storage_entry(0, Read),
                    storage_entry(1, Read),
                    storage_entry(2, Read),
                    storage_entry(3, Read),
                    storage_entry(4, Read),
                    storage_entry(5, ReadWrite),
                    storage_entry(6, ReadWrite),
                    storage_entry(7, ReadWrite),
                    storage_entry(9, ReadWrite),
                    storage_entry(10, ReadWrite),
                    storage_entry(11, Read),
                    storage_entry(12, ReadWrite),
                    wgpu::BindGroupLayoutEntry {
                        binding: 8,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: wgpu::BufferSize::new(32),
                        },
                        count: None,
                    },
                ],
            });
        let hiz_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("depth tiles"),
                entries: &[
                    storage_entry(0, Read),
                    gbuffer_entry(1),
                    storage_entry(2, ReadWrite),
                ],
            });
        let hiz_module = ctx.shader(
            "depth tiles",
            &[
                RASTER_VIEW_WGSL,
                super::GBUFFER_SURFACE_WGSL,
                include_str!("../../shaders/hiz.wgsl"),
            ],
        );
        let module = ctx.shader(
            "triangle cull",
            &[
                RASTER_VIEW_WGSL,
                if ctx.has_int64_atomics {
                    include_str!("../../shaders/micro_atomic.wgsl")
                } else {
                    include_str!("../../shaders/micro_none.wgsl")
                },
                include_str!("../../shaders/triangle_cull.wgsl"),
            ],
        );
        let micro_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("small triangles"),
                entries: &[
                    storage_entry(0, Read),
                    storage_entry(1, Read),
                    storage_entry(2, Read),
                    storage_entry(3, ReadWrite),
                    wgpu::BindGroupLayoutEntry {
                        binding: 4,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Texture {
                            sample_type: wgpu::TextureSampleType::Depth,
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                            multisampled: false,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 5,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::StorageTexture {
                            access: wgpu::StorageTextureAccess::WriteOnly,
                            format: super::viewer_volumes::GBUFFER_FORMAT,
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                        },
                        count: None,
                    },
                ],
            });
        let micro_module = ctx.shader(
            "small triangles",
            &[
                RASTER_VIEW_WGSL,
                super::GBUFFER_SURFACE_WGSL,
                include_str!("../../shaders/micro_resolve.wgsl"),
            ],
        );
        let buffer = |label: &str, usage: wgpu::BufferUsages| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | usage,
                mapped_at_creation: false,
            })
        };
        let params = || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("triangle cull parameters"),
                size: 32,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        TriangleLists {
            cull: ctx.compute_pipeline_entry("triangle cull", &module, &[&layout], "cull"),
            compact: ctx.compute_pipeline_entry("triangle compact", &module, &[&layout], "compact"),
            occlude: ctx.compute_pipeline_entry("triangle occlude", &module, &[&layout], "occlude"),
            hiz_pipeline: ctx.compute_pipeline("depth tiles", &hiz_module, &[&hiz_layout]),
            hiz_layout,
            micro_pipeline: ctx.compute_pipeline(
                "small triangles",
                &micro_module,
                &[&micro_layout],
            ),
            micro_layout,
            micro: buffer("small triangles", wgpu::BufferUsages::empty()),
            micro_on: false,
            layout,
            pairs: buffer("triangle cull pairs", wgpu::BufferUsages::empty()),
            kept: buffer("triangle cull kept", wgpu::BufferUsages::empty()),
            indices: buffer("triangle lists", wgpu::BufferUsages::INDEX),
            args: buffer("triangle list draws", wgpu::BufferUsages::INDIRECT),
            visible: buffer("triangles seen", wgpu::BufferUsages::empty()),
            hiz: buffer("depth tiles", wgpu::BufferUsages::empty()),
            params: [params(), params()],
            pair_count: 0,
            views: 0,
            occlusion: false,
        }
    }

    /// Bytes of the views' index lists and the pass's records (what culling holds).
    pub(crate) fn bytes(&self) -> u64 {
        if self.pair_count == 0 {
            return 0;
        }
        let occlusion = if self.occlusion {
            self.visible.size() + self.hiz.size()
        } else {
            0
        };
        let micro = if self.micro_on { self.micro.size() } else { 0 };
        self.pairs.size()
            + self.kept.size()
            + self.indices.size()
            + self.args.size()
            + occlusion
            + micro
    }

    /// Plans this frame's lists for every set's views, in order, given the clusters each
    /// one's frustum touches (`visible`): a pair per view and such cluster, each view's
    /// list as long as those clusters' indices, and each view's draws with no indices
    /// until the passes count them. With `occlusion`, `views` hold their depth tiles'
    /// places (`hiz_tiles` of them in all); with `micro` (`micro_raster`, one phase
    /// only) their pixels' places in the small triangles' buffer (`pixels` in all).
    pub(crate) fn upload(
        &mut self,
        ctx: &GpuContext,
        scene: &SceneGpu,
        visible: &[Vec<usize>],
        (on, occlusion, micro): (bool, bool, bool),
        (hiz_tiles, pixels): (u64, u64),
    ) {
        self.pair_count = 0;
        self.views = visible.len() as u32;
        self.occlusion = false;
        self.micro_on = false;
        if !on || scene.clusters.is_empty() {
            return;
        }
        let mut pairs: Vec<[u32; 4]> = Vec::new();
        let mut args: Vec<[u32; 5]> = Vec::with_capacity(visible.len());
        let mut list_end = 0u32;
        for (v, clusters) in visible.iter().enumerate() {
            let first_pair = pairs.len() as u32;
            let base = list_end;
            for &k in clusters {
                let c = &scene.clusters[k];
                pairs.push([v as u32, k as u32, first_pair, 0]);
                list_end += c.indices.end - c.indices.start;
            }
            args.push([0, 1, base, 0, 0]);
        }
        // Buffers grow to the next power of two, never past what every cluster in every
        // view would need (what the server's budget plans with).
        let static_indices = u64::from(scene.clusters.last().map_or(0, |c| c.indices.end));
        let occlusion = occlusion && static_indices / 3 >= OCCLUSION_MIN_TRIANGLES;
        let n = pairs.len() as u64;
        let lists = u64::from(list_end) * 4;
        if lists > ctx.max_storage_binding {
            // Larger than the adapter binds: this frame draws the clusters' ranges.
            return;
        }
        let grow = |buffer: &mut wgpu::Buffer, bytes: u64, most: u64| {
            if buffer.size() < bytes {
                *buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("triangle lists"),
                    size: bytes.next_power_of_two().min(most.max(bytes)),
                    usage: buffer.usage(),
                    mapped_at_creation: false,
                });
            }
        };
        let all = visible.len() as u64;
        let clusters = scene.clusters.len() as u64;
        grow(&mut self.pairs, n * 16, all * clusters * 16);
        grow(
            &mut self.kept,
            3 * n * PAIR_WORDS * 4,
            3 * all * clusters * PAIR_WORDS * 4,
        );
        grow(&mut self.indices, lists, all * static_indices * 4);
        grow(
            &mut self.args,
            2 * all * DRAW_ARGS_BYTES,
            2 * all * DRAW_ARGS_BYTES,
        );
        if occlusion {
            // Which triangles each view saw last frame: kept while the views and the
            // scene's clusters stay (a view joining or leaving starts them afresh, which
            // costs one frame's culling, never a pixel).
            let seen = all * clusters * VISIBLE_WORDS * 4;
            if self.visible.size() != seen {
                self.visible = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("triangles seen"),
                    size: seen,
                    usage: self.visible.usage(),
                    mapped_at_creation: false,
                });
            }
            grow(&mut self.hiz, hiz_tiles * 4, hiz_tiles * 4);
        }
        let micro =
            ctx.has_int64_atomics && micro_applies((on, occlusion, micro), static_indices / 3);
        if micro {
            // New buffers are zeroed, and the resolve leaves every word it reads zero.
            let bytes = pixels * MICRO_BYTES_PER_PIXEL;
            grow(&mut self.micro, bytes, bytes);
        }
        // The second lists' draws follow the first lists'; both start at the view's base
        // until `compact` places them.
        let draws: Vec<[u32; 5]> = args.iter().chain(args.iter()).copied().collect();
        ctx.queue
            .write_buffer(&self.pairs, 0, bytemuck::cast_slice(&pairs));
        ctx.queue
            .write_buffer(&self.args, 0, bytemuck::cast_slice(&draws));
        // A region of `kept` (its masks and counts) for this frame's pairs.
        let region = pairs.len() as u32 * PAIR_WORDS as u32;
        for (list, buffer) in self.params.iter().enumerate() {
            let p = [
                pairs.len() as u32,
                region,
                clusters as u32,
                self.views,
                list as u32,
                u32::from(occlusion),
                u32::from(micro),
                0,
            ];
            ctx.queue.write_buffer(buffer, 0, bytemuck::cast_slice(&p));
        }
        self.pair_count = pairs.len() as u32;
        self.occlusion = occlusion;
        self.micro_on = micro;
    }

    /// Records one phase's passes over every (view, cluster) pair of the frame: for the
    /// first, the culling test and the first lists' compaction (before any raster); for
    /// the second (`occlusion_cull`, after the first phase's raster and every set's depth
    /// tiles), the occlusion test and the second lists' compaction.
    pub(crate) fn add_phase(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        views: &wgpu::Buffer,
        phase: Phase,
        ts: &Timestamps,
    ) {
        let (list, test) = match phase {
            Phase::First => (0, &self.cull),
            Phase::Second => (1, &self.occlude),
        };
        if self.pair_count == 0 || (phase == Phase::Second && !self.occlusion) {
            return;
        }
        let bg = self.bind_group(ctx, scene, views, list);
        for pipeline in [test, &self.compact] {
            super::dispatch(enc, ts, Stage::GBuffer, pipeline, &[&bg], self.groups());
        }
    }

    /// With `occlusion_cull`: the depth tiles of `set`'s views from its first phase.
    pub(crate) fn add_hiz(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        views: &wgpu::Buffer,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        if self.pair_count == 0 || !self.occlusion {
            return;
        }
        let n = set.raster_views.len() as u64;
        let gbuf = set.vol.gbuf_array();
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("depth tiles"),
            layout: &self.hiz_layout,
            entries: &[
                set_views(0, views, set),
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&gbuf),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.hiz.as_entire_binding(),
                },
            ],
        });
        // One invocation per tile of the top level.
        let (cols, rows) = set
            .raster_views
            .first()
            .map_or((0, 0), |v| v.hiz_dims(HIZ_LEVELS));
        let groups = [cols.div_ceil(8), rows.div_ceil(8), n as u32];
        super::dispatch(enc, ts, Stage::GBuffer, &self.hiz_pipeline, &[&bg], groups);
    }

    /// With `micro_raster`: `set`'s small triangles written into its G-buffer where they
    /// lie nearer than its raster drew (after the set's raster).
    pub(crate) fn add_micro_resolve(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        scene: &SceneGpu,
        views: &wgpu::Buffer,
        set: &ViewerSet,
        ts: &Timestamps,
    ) {
        if self.pair_count == 0 || !self.micro_on {
            return;
        }
        let n = set.raster_views.len() as u64;
        let depth = set
            .vol
            .gbuf_depth
            .create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            });
        let gbuf = set.vol.gbuf_array();
        let bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("small triangles"),
            layout: &self.micro_layout,
            entries: &[
                set_views(0, views, set),
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: scene.vertices.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: scene.indices.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.micro.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&depth),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&gbuf),
                },
            ],
        });
        let (w, h) = set.raster_views.first().map_or((0, 0), |v| v.pixels());
        let groups = [w.div_ceil(8), h.div_ceil(8), n as u32];
        super::dispatch(
            enc,
            ts,
            Stage::GBuffer,
            &self.micro_pipeline,
            &[&bg],
            groups,
        );
    }

    /// The pairs as a 2-D grid of workgroups (the shader reads its pair as x + y·nx).
    fn groups(&self) -> [u32; 3] {
        let x = self.pair_count.min(32768);
        [x, self.pair_count.div_ceil(x), 1]
    }

    /// The passes' bindings, with the parameters that write list `list` (0 or 1).
    fn bind_group(
        &self,
        ctx: &GpuContext,
        scene: &SceneGpu,
        views: &wgpu::Buffer,
        list: usize,
    ) -> wgpu::BindGroup {
        let buffers = [
            views,
            &scene.vertices,
            &scene.indices,
            &scene.cluster_table,
            &self.pairs,
            &self.kept,
            &self.indices,
            &self.args,
        ];
        // Then binding 8, the parameters, 9, the frame's counters, 10 and 11 what the
        // views saw and their depth tiles.
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .chain([
                &&self.params[list],
                &&scene.counters,
                &&self.visible,
                &&self.hiz,
                &&self.micro,
            ])
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("triangle cull"),
            layout: &self.layout,
            entries: &entries,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Settings;

    #[test]
    fn small_triangles_hold_a_word_a_pixel_only_where_they_apply() {
        let on = Settings::default();
        assert_eq!(micro_bytes_per_pixel(&on, 262_267), 8);
        // Small scenes, no culling, the switch off, two phases: the raster draws them.
        assert_eq!(micro_bytes_per_pixel(&on, 336), 0);
        let mut off = on;
        off.triangle_cull = false;
        assert_eq!(micro_bytes_per_pixel(&off, 262_267), 0);
        off = on;
        off.micro_raster = false;
        assert_eq!(micro_bytes_per_pixel(&off, 262_267), 0);
        off = on;
        off.occlusion_cull = true;
        assert_eq!(micro_bytes_per_pixel(&off, 262_267), 0);
    }
}
