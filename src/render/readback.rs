//! The frame's one readback: counters, timestamps and every viewer set's frames copied
//! into one staging buffer, mapped once.

use super::{Timestamps, ViewerSet, World};
use crate::gpu::{map_read, GpuContext};
use std::collections::BTreeMap;

/// The frame's one readback: counters, timestamps and every set's output in one buffer.
pub(crate) struct Readback {
    staging: wgpu::Buffer,
    counters: u64,
    ticks: (u64, u64),
    outputs: Vec<(u64, u64)>,
}

/// What a [`Readback`] brought back.
pub(crate) struct ReadbackBytes {
    /// The frame counters (`C_*`).
    pub counters: Vec<u32>,
    /// Resolved timestamp ticks, a begin/end pair per timed pass.
    pub ticks: Vec<u64>,
    /// Every viewer set's output buffer, in set order.
    pub outputs: Vec<Vec<u8>>,
}

impl Readback {
    pub(crate) fn record(
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        world: &World,
        sets: &BTreeMap<(u32, u32), ViewerSet>,
        ts: &Timestamps,
    ) -> Readback {
        let align = |n: u64| n.next_multiple_of(256);
        let counters = world.gpu.counters.size();
        let tick_bytes = ts.frame_bytes();
        let mut at = align(counters) + align(tick_bytes);
        let outputs: Vec<(u64, u64)> = sets
            .values()
            .map(|s| {
                let range = (at, s.vol.output_pixels * 4);
                at += align(range.1);
                range
            })
            .collect();
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame readback"),
            size: at.max(16),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        enc.copy_buffer_to_buffer(&world.gpu.counters, 0, &staging, 0, counters);
        ts.resolve(enc, &staging, align(counters));
        for (set, (offset, bytes)) in sets.values().zip(&outputs) {
            enc.copy_buffer_to_buffer(&set.vol.output, 0, &staging, *offset, *bytes);
        }
        Readback {
            staging,
            counters,
            ticks: (align(counters), tick_bytes),
            outputs,
        }
    }

    pub(crate) fn map(self, ctx: &GpuContext) -> anyhow::Result<ReadbackBytes> {
        let bytes = map_read(&ctx.device, &self.staging)?;
        let range = |(at, n): (u64, u64)| &bytes[at as usize..(at + n) as usize];
        Ok(ReadbackBytes {
            counters: bytemuck::pod_collect_to_vec(range((0, self.counters))),
            ticks: bytemuck::pod_collect_to_vec(range(self.ticks)),
            outputs: self.outputs.iter().map(|r| range(*r).to_vec()).collect(),
        })
    }
}
