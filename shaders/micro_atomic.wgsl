// `micro_raster`'s buffer in shaders/triangle_cull.wgsl, where the device has 64-bit
// storage atomics: per pixel of every view (from RasterView.micro_base) the nearest
// small triangle as one word, the bit-inverted depth above the bit-inverted triangle,
// so that atomicMax keeps the nearest and, at equal depth, the first in the scene's
// order (as the raster's depth test `Less` does). 0: none (shaders/micro_resolve.wgsl
// reads and clears it).
@group(0) @binding(12) var<storage, read_write> micro: array<atomic<u64>>;

fn micro_put(i: u32, depth: f32, triangle: u32) {
    atomicMax(&micro[i], (u64(~bitcast<u32>(depth)) << 32u) | u64(~triangle));
}
