//! The streaming server (`fogcast serve`): every viewer's frames over WebSocket to
//! browsers, with mono, stereo (VR) and split-screen sessions. Protocol: `docs/protocol.md`.
//!
//! - `validate`: client messages parsed and checked into session specs and cameras (the
//!   wire types are [`crate::protocol`]).
//! - [`config`]: settings, config file; [`ServeArgs`]: the flags over it.
//! - `hub`: sessions, view accounting, latest poses, latest-frame slots.
//! - `render_loop`: the render thread (owns the GPU work: one world, every session's
//!   frame in one submission).
//! - `encode`: JPEG-encodes a session's frame on an encoder pool.
//! - `session`: one connection — handshake, validation, rate limits, sending.
//! - `http`: routes (`/`, `/ws`, `/healthz`, `/metrics`).
//!
//! Threads: tokio tasks do all I/O; one std thread renders; a small rayon pool encodes.
//! Nothing on the I/O side waits for the GPU and the render thread waits for no client.

mod admission;
mod budget;
mod cli;
pub mod config;
mod encode;
mod http;
mod hub;
mod listen;
mod render_loop;
mod session;
mod stream;
mod telemetry;
mod validate;

pub use cli::{serve, ServeArgs};
pub use config::ServerConfig;
pub use telemetry::resident_memory_bytes;

use crate::gpu::GpuContext;
use crate::render::{Renderer, Settings};
use crate::scene::{Bvh, Scene};
use anyhow::Context as _;
use hub::Hub;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::watch;

/// A running server: bound socket, render thread and HTTP task.
pub struct Server {
    addr: SocketAddr,
    hub: Arc<Hub>,
    shutdown: watch::Sender<bool>,
    http: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
    render: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Server")
            .field("addr", &self.addr)
            .finish_non_exhaustive()
    }
}

impl Server {
    /// Loads the scene, opens the GPU, builds the BVH, binds `addr:port` and starts
    /// serving. Must be called inside a tokio runtime.
    pub async fn start(config: ServerConfig) -> anyhow::Result<Server> {
        config.validate()?;
        let cfg = config.clone();
        let (scene, ctx, bvh, settings, renderer) =
            tokio::task::spawn_blocking(move || -> anyhow::Result<_> {
                let scene = Arc::new(Scene::load(&cfg.scene)?);
                let ctx = Arc::new(GpuContext::new()?);
                let settings = cfg.settings.apply(Settings::for_scene(&scene))?;
                let started = Instant::now();
                let bvh = Bvh::build(&scene.mesh)?;
                tracing::info!(
                    triangles = bvh.triangle_count(),
                    ms = started.elapsed().as_millis() as u64,
                    "BVH built"
                );
                let started = Instant::now();
                let renderer = Renderer::with_bvh(ctx.clone(), scene.clone(), &bvh, settings)?;
                tracing::info!(
                    ms = started.elapsed().as_millis() as u64,
                    "renderer built: one world for every viewer"
                );
                Ok((scene, ctx, bvh, settings, renderer))
            })
            .await
            .context("server start-up task")??;

        let bind = SocketAddr::new(config.addr, config.port);
        let listener = tokio::net::TcpListener::bind(bind)
            .await
            .with_context(|| format!("binding {bind} (is another server running? try --port)"))?;
        let addr = listener.local_addr()?;
        let budget = budget::Budget {
            settings,
            max_binding_bytes: ctx.max_storage_binding,
            max_pixels_per_frame: config.max_pixels_per_frame,
            max_view_memory_bytes: config.max_view_memory_mib << 20,
            smoke_particles: crate::render::particle_capacity(&scene),
            triangle_lists_per_view: 0,
            micro_bytes_per_pixel: 0,
        }
        .with_triangles(scene.mesh.len() as u64);
        let hub = Arc::new(Hub::new(config, scene, budget));
        let lost_hub = Arc::downgrade(&hub);
        ctx.device.set_device_lost_callback(move |reason, message| {
            if let Some(hub) = lost_hub.upgrade() {
                if !hub.shutdown.load(std::sync::atomic::Ordering::Relaxed) {
                    hub.lose_device(format!("{reason:?}: {message}"));
                }
            }
        });
        let render_loop = render_loop::RenderLoop::new(hub.clone(), ctx, bvh, settings, renderer)?;
        let render = std::thread::Builder::new()
            .name("fogcast-render".into())
            .spawn(move || render_loop.run())?;
        let (shutdown, shutdown_rx) = watch::channel(false);
        let app = http::router(http::AppState {
            hub: hub.clone(),
            shutdown: shutdown_rx.clone(),
        });
        let http = tokio::spawn(listen::serve(listener, app, hub.clone(), shutdown_rx));
        tracing::info!(%addr, scene = %hub.scene.name, max_views = hub.config.max_views, fps = hub.config.fps, "serving");
        Ok(Server {
            addr,
            hub,
            shutdown,
            http: Some(http),
            render: Some(render),
        })
    }

    /// The bound address (the real port when the config asked for port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://` URL of the browser client.
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Open sessions and the views they render.
    pub fn counts(&self) -> (usize, usize) {
        self.hub.counts()
    }

    /// Closes every session (close code 1001), stops the render thread and waits for both.
    pub async fn shutdown(mut self) -> anyhow::Result<()> {
        self.begin_shutdown();
        if let Some(http) = self.http.take() {
            http.await.context("HTTP task")?.context("HTTP server")?;
        }
        if let Some(render) = self.render.take() {
            tokio::task::spawn_blocking(move || render.join())
                .await
                .context("joining the render thread")?
                .map_err(|_| anyhow::anyhow!("the render thread panicked"))?;
        }
        Ok(())
    }

    /// Serves until Ctrl-C (or SIGTERM), then shuts down.
    pub async fn run_until_signal(self) -> anyhow::Result<()> {
        let ctrl_c = tokio::signal::ctrl_c();
        #[cfg(unix)]
        {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
            tokio::select! {
                r = ctrl_c => r?,
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        ctrl_c.await?;
        tracing::info!("shutting down");
        self.shutdown().await
    }

    fn begin_shutdown(&self) {
        let _ = self.shutdown.send(true);
        self.hub.begin_shutdown();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        // A server dropped without `shutdown` (a failed test, say) still stops its threads.
        self.begin_shutdown();
    }
}
