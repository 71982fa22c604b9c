// `micro_raster`'s buffer in shaders/triangle_cull.wgsl where the device lacks 64-bit
// storage atomics: `micro_raster` is then off and nothing is written.
@group(0) @binding(12) var<storage, read_write> micro: array<u32>;

fn micro_put(i: u32, depth: f32, triangle: u32) {}
