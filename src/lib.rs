//! fogcast: participating media (fog, light shafts, dust, smoke) for many viewers of one
//! scene on one GPU, with the view-independent shadow work shared in a world-space grid
//! (Stojanovic et al., HPG 2023 — `shared/papers/000`).
//!
//! - [`scene`]: scene files, built-in scenes, glTF, the BVH for shadow rays.
//! - [`gpu`]: device selection and buffer helpers.
//! - [`loadgen`]: `fogcast loadgen`, real WebSocket viewers loading a running server.
//! - [`render`]: the froxel pipeline (`reference` and `shared` modes).
//! - [`bench`]: `fogcast bench`, how each cost grows with the number of viewers.
//! - [`metrics`]: image error (FLIP, PSNR, RMSE).
//! - [`protocol`]: the viewer protocol's wire types (messages, frame header), shared by
//!   the server and its clients.
//! - [`server`]: `fogcast serve`, streaming every viewer's frames to browsers over WebSocket.
//! - [`smoke`]: smoke particles: the interval integral (seed 001) and adaptive volumetric
//!   shadow maps (seed 002), CPU references.
//! - [`settings_overrides`]: renderer settings given by flags or a config file's keys.
//! - [`truth`]: the CPU ground-truth renderer every error is measured against.

#![deny(missing_docs)]
#![warn(unreachable_pub)]
// One exception, with its reasoning beside it: the H.264 encoder's runtime bitrate
// option, which the OpenH264 wrapper exposes only through its raw API
// (`server::stream::H264Stream::set_bitrate`).
#![deny(unsafe_code)]

pub mod bench;
pub mod eval;
pub mod gpu;
pub mod loadgen;
pub mod metrics;
pub mod output;
pub mod protocol;
pub mod render;
pub mod report;
pub mod scene;
pub mod server;
pub mod settings_overrides;
pub mod smoke;
pub mod truth;
