//! Scene description: meshes, analytic lights, participating media and a camera path.
//!
//! Scenes are TOML files (see `scenes/*.toml` and `docs/scene-format.md`). Everything a
//! user writes is validated on load; errors name the field and the offending value.
//!
//! - `format`: the scene file as written (the serde types).
//! - `validate`: the checks of every value a user writes.
//! - `load`: built-in scenes, TOML files and bare glTF files turned into a [`Scene`] in
//!   render space.
//! - `types`: the validated scene the renderers use.
//! - `error`: [`SceneError`].

mod builtin;
mod bvh;
mod camera;
mod error;
mod format;
mod gltf_load;
mod load;
mod media;
mod mesh;
mod mover;
mod types;
mod validate;

pub use builtin::{builtin_names, builtin_scene};
pub use bvh::{intersect_triangle, Bvh, GpuBvhNode, GpuTriangle, Ray, MAX_BVH_DEPTH};
pub use camera::{Camera, CameraPath};
pub use error::SceneError;
pub use format::{
    Cull, Displacement, EmitterDesc, EmitterShape, LightDesc, MediumDesc, MediumKind, MeshDesc,
    Noise, RenderDefaults, SceneDesc, SwingDesc, VolumeDesc, VolumeMotion,
};
pub use load::load_camera_path;
pub use media::{density_at, hg_phase, sample_media, MediumSample, VOLUME_EDGE_FRACTION};
pub use mesh::TriangleMesh;
pub use mover::{movers_mesh_at, Mover, MoverDesc};
pub use types::{Light, LightKind, Medium, Scene, Swing, Volume, MAX_LIGHTS};

pub(crate) use error::invalid;
pub(crate) use validate::{check_finite, check_range};
