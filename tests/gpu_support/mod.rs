//! The GPU device and scenes the GPU tests share.

use fogcast::gpu::GpuContext;
use fogcast::scene::Scene;
use std::sync::{Arc, OnceLock};

/// One device per test binary (lavapipe on CI).
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
