//! What the render and truth tests share: the GPU device, scenes, sample points.

use fogcast::gpu::GpuContext;
use fogcast::scene::Scene;
use glam::Vec3;
use std::sync::{Arc, OnceLock};

/// One device per test binary (lavapipe on CI).
#[allow(dead_code)]
pub fn gpu() -> Arc<GpuContext> {
    static CTX: OnceLock<Arc<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| Arc::new(GpuContext::new().expect("a Vulkan adapter (run `make deps`)")))
        .clone()
}

/// The built-in colonnade scene.
#[allow(dead_code)]
pub fn colonnade() -> Arc<Scene> {
    Arc::new(Scene::load("colonnade").expect("built-in scene"))
}

/// Deterministic points in [0, 1)³ (a 64-bit LCG).
#[allow(dead_code)]
pub fn unit_points(n: usize) -> Vec<Vec3> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n).map(|_| Vec3::new(next(), next(), next())).collect()
}
