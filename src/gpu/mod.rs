//! Device selection, buffer helpers and readback.

use anyhow::{anyhow, Context as _};
use wgpu::util::DeviceExt as _;

/// Storage buffers a compute stage binds at most: the scene's group 0 (16, the smoke's
/// shadow maps and the ambient grid included) and the stage's own group (8: the shared
/// grid's).
const STORAGE_BUFFERS_NEEDED: u32 = 24;

/// The wgpu device and queue fogcast renders with, and what the adapter can do.
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name, driver and type, for logs and stats.
    pub adapter_info: wgpu::AdapterInfo,
    /// Whether compute and render passes can write timestamps.
    pub has_timestamps: bool,
    /// Whether shaders may use subgroup operations (counters are then summed per
    /// subgroup instead of per workgroup, which avoids workgroup barriers).
    pub has_subgroups: bool,
    /// Whether shaders may use 64-bit integers and atomicMax on them in storage buffers
    /// (`micro_raster`'s depth-and-triangle words).
    pub has_int64_atomics: bool,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Largest storage buffer binding, bytes.
    pub max_storage_binding: u64,
    /// Command buffers submitted through [`GpuContext::submit`] (a frame is one).
    submissions: std::sync::atomic::AtomicU64,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.adapter_info.name)
            .finish()
    }
}

static ADAPTER_NAME: std::sync::OnceLock<String> = std::sync::OnceLock::new();

impl GpuContext {
    /// Name and driver of the first adapter this process opened ("none" before).
    pub fn last_adapter_name() -> String {
        ADAPTER_NAME.get().cloned().unwrap_or_else(|| "none".into())
    }

    /// Opens the first Vulkan adapter (a GPU if there is one, else lavapipe).
    ///
    /// Vulkan is forced unless `WGPU_BACKEND` says otherwise: wgpu's GL backend on
    /// llvmpipe writes only slice 0 of 3D storage textures (DESIGN.md §8).
    pub fn new() -> anyhow::Result<GpuContext> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if std::env::var_os("WGPU_BACKEND").is_none() {
            desc.backends = wgpu::Backends::VULKAN;
        }
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| {
            anyhow!(
                "no Vulkan adapter found ({e}). On a machine without a GPU install Mesa's software \
                 driver: `make deps` (or `apt-get install mesa-vulkan-drivers libvulkan1`)"
            )
        })?;
        let info = adapter.get_info();
        let features = adapter.features();
        let has_timestamps = features.contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut required_features = wgpu::Features::empty();
        if has_timestamps {
            required_features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let has_subgroups = features.contains(wgpu::Features::SUBGROUP)
            && std::env::var_os("FOGCAST_NO_SUBGROUPS").is_none();
        if has_subgroups {
            required_features |= wgpu::Features::SUBGROUP;
        }
        let int64_atomics =
            wgpu::Features::SHADER_INT64 | wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX;
        let has_int64_atomics = features.contains(int64_atomics)
            && std::env::var_os("FOGCAST_NO_INT64_ATOMICS").is_none();
        if has_int64_atomics {
            required_features |= int64_atomics;
        }
        let adapter_limits = adapter.limits();
        // Group 0 (the scene, 16 buffers) and a stage's own group (at most 6) together.
        anyhow::ensure!(
            adapter_limits.max_storage_buffers_per_shader_stage >= STORAGE_BUFFERS_NEEDED,
            "the adapter {} binds {} storage buffers per shader stage; fogcast needs {}",
            info.name,
            adapter_limits.max_storage_buffers_per_shader_stage,
            STORAGE_BUFFERS_NEEDED
        );
        let required_limits = wgpu::Limits {
            max_storage_buffer_binding_size: adapter_limits.max_storage_buffer_binding_size,
            max_buffer_size: adapter_limits.max_buffer_size,
            max_storage_buffers_per_shader_stage: adapter_limits
                .max_storage_buffers_per_shader_stage
                .min(32),
            max_texture_array_layers: adapter_limits.max_texture_array_layers,
            max_compute_workgroups_per_dimension: adapter_limits
                .max_compute_workgroups_per_dimension,
            ..wgpu::Limits::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("fogcast"),
            required_features,
            required_limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .context("requesting a wgpu device")?;
        tracing::info!(adapter = %info.name, driver = %info.driver_info, "GPU adapter");
        let _ = ADAPTER_NAME.set(format!("{} ({})", info.name, info.driver_info));
        Ok(GpuContext {
            timestamp_period_ns: queue.get_timestamp_period(),
            device,
            queue,
            adapter_info: info,
            has_timestamps,
            has_subgroups,
            has_int64_atomics,
            max_storage_binding: adapter_limits.max_storage_buffer_binding_size as u64,
            submissions: Default::default(),
        })
    }

    /// A storage buffer initialised with `data`; when `data` is empty, one zeroed `T`
    /// (and at least 16 bytes), because wgpu rejects binding a runtime-sized
    /// `array<T>` smaller than one element (a scene without lights has an empty light list).
    pub fn storage_init<T: bytemuck::Pod>(
        &self,
        label: &str,
        data: &[T],
        extra: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let zero = vec![0u8; std::mem::size_of::<T>().max(16)];
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: if bytes.is_empty() { &zero } else { bytes },
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
            })
    }

    /// A zeroed storage buffer of `size` bytes (rounded up to 16).
    pub fn storage(
        &self,
        label: &str,
        size: u64,
        extra: wgpu::BufferUsages,
    ) -> anyhow::Result<wgpu::Buffer> {
        let size = size.max(16).next_multiple_of(16);
        anyhow::ensure!(
            size <= self.max_storage_binding,
            "{label} needs {:.1} MiB but the adapter binds at most {:.1} MiB per buffer; use fewer viewers, a smaller resolution or a larger voxel size",
            size as f64 / 1048576.0,
            self.max_storage_binding as f64 / 1048576.0
        );
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC
                | extra,
            mapped_at_creation: false,
        }))
    }

    /// Compiles WGSL assembled from `parts` (shared includes first, the stage last).
    pub fn shader(&self, label: &str, parts: &[&str]) -> wgpu::ShaderModule {
        self.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(parts.concat().into()),
            })
    }

    /// A compute pipeline with an explicit layout, entry point `main`.
    pub fn compute_pipeline(
        &self,
        label: &str,
        module: &wgpu::ShaderModule,
        layouts: &[&wgpu::BindGroupLayout],
    ) -> wgpu::ComputePipeline {
        self.compute_pipeline_entry(label, module, layouts, "main")
    }

    /// A compute pipeline with an explicit layout and entry point.
    pub fn compute_pipeline_entry(
        &self,
        label: &str,
        module: &wgpu::ShaderModule,
        layouts: &[&wgpu::BindGroupLayout],
        entry: &str,
    ) -> wgpu::ComputePipeline {
        self.compute_pipeline_with(label, module, layouts, entry, &[])
    }

    /// As [`GpuContext::compute_pipeline_entry`], with values for the module's
    /// pipeline-overridable constants (WGSL `override`), by name.
    pub fn compute_pipeline_with(
        &self,
        label: &str,
        module: &wgpu::ShaderModule,
        layouts: &[&wgpu::BindGroupLayout],
        entry: &str,
        constants: &[(&str, f64)],
    ) -> wgpu::ComputePipeline {
        let layouts: Vec<Option<&wgpu::BindGroupLayout>> =
            layouts.iter().map(|l| Some(*l)).collect();
        let layout = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &layouts,
                immediate_size: 0,
            });
        self.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&layout),
                module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    ..Default::default()
                },
                cache: None,
            })
    }

    /// A bind group layout of storage buffers for compute, bindings 0, 1, … in order.
    pub fn storage_layout(&self, label: &str, access: &[Access]) -> wgpu::BindGroupLayout {
        self.storage_layout_for(label, access, wgpu::ShaderStages::COMPUTE)
    }

    /// As [`GpuContext::storage_layout`], visible to the shader stages `visibility`
    /// (the scene's group 0 is also read by fragment shaders: the smoke raster).
    pub fn storage_layout_for(
        &self,
        label: &str,
        access: &[Access],
        visibility: wgpu::ShaderStages,
    ) -> wgpu::BindGroupLayout {
        let entries: Vec<wgpu::BindGroupLayoutEntry> = access
            .iter()
            .enumerate()
            .map(|(i, a)| wgpu::BindGroupLayoutEntry {
                visibility,
                ..storage_entry(i as u32, *a)
            })
            .collect();
        self.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            })
    }

    /// A bind group binding `buffers` in order.
    pub fn bind_buffers(
        &self,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let entries = buffer_entries(buffers);
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        })
    }

    /// Submits `enc`'s commands to the queue (every submission of fogcast goes here).
    pub fn submit(&self, enc: wgpu::CommandEncoder) {
        self.submissions
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.queue.submit([enc.finish()]);
    }

    /// Queue submissions made so far through [`GpuContext::submit`].
    pub fn submissions(&self) -> u64 {
        self.submissions.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Copies `buffer` to the host (blocking).
    pub fn read_buffer(&self, buffer: &wgpu::Buffer) -> anyhow::Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: buffer.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
        self.submit(enc);
        map_read(&self.device, &staging)
    }
}

/// How a compute stage may use a storage buffer binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// Bind group entries 0, 1, … for whole buffers, in order.
pub fn buffer_entries<'a>(buffers: &[&'a wgpu::Buffer]) -> Vec<wgpu::BindGroupEntry<'a>> {
    buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect()
}

/// A compute-visible storage buffer binding.
pub fn storage_entry(binding: u32, access: Access) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage {
                read_only: access == Access::Read,
            },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Maps a MAP_READ buffer, waits, and copies its contents out.
pub fn map_read(device: &wgpu::Device, staging: &wgpu::Buffer) -> anyhow::Result<Vec<u8>> {
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .context("waiting for the GPU")?;
    rx.recv()
        .context("map callback dropped")?
        .context("mapping a readback buffer")?;
    let data = staging
        .get_mapped_range(..)
        .map_err(|e| anyhow!("{e:?}"))?
        .to_vec();
    staging.unmap();
    Ok(data)
}
