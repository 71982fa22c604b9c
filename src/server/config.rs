//! Server settings: defaults, a TOML config file, and the checks that run before start.

use super::validate::SpecLimits;
use crate::render::Settings;
use crate::settings_overrides::SettingsOverrides;
use anyhow::Context as _;
use serde::{Deserialize, Serialize};
use std::net::{IpAddr, Ipv4Addr};
use std::path::Path;

/// Everything `fogcast serve` can be told; a config file holds any subset of these keys
/// and of the renderer settings' (see `docs/protocol.md` for the example file), flags
/// override it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ServerConfig {
    /// Built-in scene name, scene .toml or .glb/.gltf file.
    pub scene: String,
    /// Renderer settings by their keys (`mode`, `voxel_size_m`, `demand`, … as
    /// `Settings` names them), over `shared`'s defaults with the scene's voxel size. A
    /// key of the file that is not the server's must be one of these.
    #[serde(flatten)]
    pub settings: SettingsOverrides,
    /// Address to listen on.
    pub addr: IpAddr,
    /// Port to listen on (0: any free port, reported at start).
    pub port: u16,
    /// Frame rate cap of the render loop, frames per second.
    pub fps: f64,
    /// Views rendered in total over all sessions (mono 1, stereo 2, split 2–4 each).
    pub max_views: usize,
    /// Open sessions (connections that completed a hello); connections still in the
    /// handshake are bounded by `max_pending_per_ip` and `max_pending` instead.
    pub max_connections: usize,
    /// Largest frame width a client may ask for, pixels.
    pub max_width: u32,
    /// Largest frame height a client may ask for, pixels.
    pub max_height: u32,
    /// JPEG quality when a hello names none (1–100).
    pub default_quality: u8,
    /// Access token clients must send in their hello; none: open server.
    pub token: Option<String>,
    /// Seconds a new connection has to send its hello.
    pub hello_timeout_s: f64,
    /// Seconds a client has to send a complete HTTP request head (slowloris guard).
    pub header_timeout_s: f64,
    /// Connections from one IP address that have not yet completed a hello (half-sent
    /// requests, upgrades waiting for a hello); more are closed at once.
    pub max_pending_per_ip: usize,
    /// Such connections from all addresses together.
    pub max_pending: usize,
    /// Browser origins allowed on `/ws` (e.g. "https://fog.example.org"), besides the
    /// page's own (the Origin matching the Host header) and localhost, 127.0.0.1, [::1].
    /// Requests without an Origin header (non-browser clients) are allowed.
    pub allowed_origins: Vec<String>,
    /// Token `/metrics` requires (`Authorization: Bearer <token>`); none: public.
    pub metrics_token: Option<String>,
    /// Seconds shutdown waits for connections to finish before cutting them.
    pub shutdown_timeout_s: f64,
    /// Seconds one frame may take to leave the server before the session is closed as stalled.
    pub stall_timeout_s: f64,
    /// Largest client text message, bytes.
    pub max_message_bytes: usize,
    /// Sustained client messages per second; beyond it messages are dropped, and at
    /// twice the rate for a second the session is closed.
    pub max_messages_per_s: f64,
    /// Sustained `configure` messages per second per session (bursts of 4); beyond it a
    /// configure is answered with a `rate_limited` error and not applied.
    pub max_configures_per_s: f64,
    /// Kernel send buffer of each connection, bytes: small keeps latency low, because
    /// frames waiting in the kernel cannot be replaced by newer ones.
    pub send_buffer_bytes: usize,
    /// JPEG encoder threads (0: one per core).
    pub encode_threads: usize,
    /// Seconds a session may go without a frame (from its welcome or its last frame)
    /// before it is closed with `no_frames`.
    pub frame_timeout_s: f64,
    /// Pixels rendered per frame over all views together (the frame-time budget in
    /// pixels); a hello or configure beyond it is refused with `over_budget`.
    pub max_pixels_per_frame: u64,
    /// GPU memory of all views' volumes and G-buffers together, MiB (the scene, grid
    /// and shadow maps come on top, once per view size); past it `over_budget`.
    pub max_view_memory_mib: u64,
    /// Seconds a session may go without sending a pose before it is closed with `idle`
    /// (0: never). Acks do not count: a forgotten tab still acks.
    pub idle_timeout_s: f64,
    /// Highest bitrate a session may get, kbit/s (the ceiling of a hello's `max_kbps`).
    pub max_kbps: u32,
    /// Lowest bitrate the adaptation goes to, kbit/s; below it the frame size is halved.
    pub min_kbps: u32,
    /// Bitrate a new H.264 stream starts at, kbit/s (then adapted).
    pub start_kbps: u32,
    /// Frames between H.264 key frames (besides those on join, configure and request).
    pub gop_frames: u32,
    /// Flow control, for clients that ack: most milliseconds of the client's delivered
    /// rate kept in flight; a frame beyond it is skipped (latest frame wins).
    pub max_queue_ms: f64,
    /// Allow hellos with `raw_every` (uncompressed copies of frames, for measuring codec
    /// quality). Off by default: raw frames are large.
    pub debug_raw_frames: bool,
    /// Fault injection for tests: views of this width fail in the render loop.
    #[doc(hidden)]
    #[serde(skip)]
    pub fault: Option<Fault>,
}

/// A failure the render loop injects for views of one width (tests only).
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fault {
    /// View width (pixels) the fault hits.
    pub view_width: u32,
    /// What happens.
    pub kind: FaultKind,
}

/// What an injected [`Fault`] does.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// A render call with this size returns an error.
    RenderError,
    /// A render call with this size panics.
    RenderPanic,
    /// The encoder job panics.
    EncodePanic,
    /// Sessions of this size are skipped without a word (the failure mode of old).
    Skip,
    /// The render loop destroys the GPU device when it meets this size.
    DeviceLost,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            scene: "colonnade".into(),
            settings: SettingsOverrides::default(),
            addr: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 8080,
            fps: 30.0,
            max_views: 16,
            max_connections: 64,
            max_width: 1920,
            max_height: 1080,
            default_quality: 75,
            token: None,
            hello_timeout_s: 10.0,
            header_timeout_s: 10.0,
            max_pending_per_ip: 16,
            max_pending: 1024,
            allowed_origins: Vec::new(),
            metrics_token: None,
            shutdown_timeout_s: 5.0,
            stall_timeout_s: 30.0,
            max_message_bytes: 16 * 1024,
            max_messages_per_s: 120.0,
            max_configures_per_s: 2.0,
            send_buffer_bytes: 256 * 1024,
            encode_threads: 0,
            frame_timeout_s: 30.0,
            // Four 1920×1080 views.
            max_pixels_per_frame: 4 * 1920 * 1080,
            // Four 1920×1080 views hold 444 MiB.
            max_view_memory_mib: 1024,
            idle_timeout_s: 300.0,
            max_kbps: 8000,
            min_kbps: 150,
            start_kbps: 2000,
            gop_frames: 300,
            max_queue_ms: 150.0,
            debug_raw_frames: false,
            fault: None,
        }
    }
}

impl ServerConfig {
    /// Reads a TOML config file; keys it leaves out keep their defaults.
    pub fn load(path: &Path) -> anyhow::Result<ServerConfig> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading server config {}", path.display()))?;
        let config: ServerConfig = toml::from_str(&text)
            .with_context(|| format!("parsing server config {}", path.display()))?;
        Ok(config)
    }

    /// Checks every range; the error names the key, the value and the range.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.settings.apply(Settings::default())?;
        anyhow::ensure!(
            self.fps.is_finite() && self.fps > 0.0 && self.fps <= 240.0,
            "fps {}: must be in (0, 240]",
            self.fps
        );
        anyhow::ensure!(
            (1..=256).contains(&self.max_views),
            "max_views {}: must be 1..=256",
            self.max_views
        );
        anyhow::ensure!(
            (1..=4096).contains(&self.max_connections),
            "max_connections {}: must be 1..=4096",
            self.max_connections
        );
        anyhow::ensure!(
            (16..=8192).contains(&self.max_width),
            "max_width {}: must be 16..=8192",
            self.max_width
        );
        anyhow::ensure!(
            (16..=8192).contains(&self.max_height),
            "max_height {}: must be 16..=8192",
            self.max_height
        );
        anyhow::ensure!(
            (1..=100).contains(&self.default_quality),
            "default_quality {}: must be 1..=100",
            self.default_quality
        );
        anyhow::ensure!(
            (1..=4096).contains(&self.max_pending_per_ip),
            "max_pending_per_ip {}: must be 1..=4096",
            self.max_pending_per_ip
        );
        anyhow::ensure!(
            (1..=65536).contains(&self.max_pending),
            "max_pending {}: must be 1..=65536",
            self.max_pending
        );
        for o in &self.allowed_origins {
            anyhow::ensure!(
                o.starts_with("http://") || o.starts_with("https://"),
                "allowed_origins entry {o:?}: must be an origin like \"https://fog.example.org\""
            );
        }
        if let Some(t) = &self.metrics_token {
            anyhow::ensure!(
                !t.is_empty() && t.len() <= 256,
                "metrics_token: must be 1 to 256 bytes (or absent for a public /metrics)"
            );
        }
        if let Some(t) = &self.token {
            anyhow::ensure!(
                !t.is_empty() && t.len() <= 256,
                "token: must be 1 to 256 bytes (or absent for an open server)"
            );
        }
        for (name, v) in [
            ("hello_timeout_s", self.hello_timeout_s),
            ("stall_timeout_s", self.stall_timeout_s),
            ("frame_timeout_s", self.frame_timeout_s),
            ("header_timeout_s", self.header_timeout_s),
            ("shutdown_timeout_s", self.shutdown_timeout_s),
        ] {
            anyhow::ensure!(
                v.is_finite() && (0.05..=3600.0).contains(&v),
                "{name} {v}: must be 0.05..=3600 seconds"
            );
        }
        anyhow::ensure!(
            (256..=1 << 20).contains(&self.max_message_bytes),
            "max_message_bytes {}: must be 256..=1048576",
            self.max_message_bytes
        );
        anyhow::ensure!(
            self.max_messages_per_s.is_finite()
                && (1.0..=10_000.0).contains(&self.max_messages_per_s),
            "max_messages_per_s {}: must be 1..=10000",
            self.max_messages_per_s
        );
        anyhow::ensure!(
            self.max_configures_per_s.is_finite()
                && (0.01..=1000.0).contains(&self.max_configures_per_s),
            "max_configures_per_s {}: must be 0.01..=1000",
            self.max_configures_per_s
        );
        anyhow::ensure!(
            (4096..=64 << 20).contains(&self.send_buffer_bytes),
            "send_buffer_bytes {}: must be 4096..=67108864",
            self.send_buffer_bytes
        );
        anyhow::ensure!(
            (1..=1 << 20).contains(&self.max_view_memory_mib),
            "max_view_memory_mib {}: must be 1..=1048576",
            self.max_view_memory_mib
        );
        anyhow::ensure!(
            self.max_pixels_per_frame >= 16 * 16,
            "max_pixels_per_frame {}: must be at least 256",
            self.max_pixels_per_frame
        );
        anyhow::ensure!(
            self.idle_timeout_s == 0.0
                || (self.idle_timeout_s.is_finite()
                    && (0.05..=86_400.0).contains(&self.idle_timeout_s)),
            "idle_timeout_s {}: must be 0 (never) or 0.05..=86400 seconds",
            self.idle_timeout_s
        );
        anyhow::ensure!(
            (50..=1_000_000).contains(&self.min_kbps),
            "min_kbps {}: must be 50..=1000000",
            self.min_kbps
        );
        anyhow::ensure!(
            (self.min_kbps..=1_000_000).contains(&self.max_kbps),
            "max_kbps {}: must be min_kbps ({})..=1000000",
            self.max_kbps,
            self.min_kbps
        );
        anyhow::ensure!(
            (self.min_kbps..=self.max_kbps).contains(&self.start_kbps),
            "start_kbps {}: must be min_kbps..=max_kbps ({}..={})",
            self.start_kbps,
            self.min_kbps,
            self.max_kbps
        );
        anyhow::ensure!(
            (1..=3600).contains(&self.gop_frames),
            "gop_frames {}: must be 1..=3600",
            self.gop_frames
        );
        anyhow::ensure!(
            self.max_queue_ms.is_finite() && (10.0..=10_000.0).contains(&self.max_queue_ms),
            "max_queue_ms {}: must be 10..=10000",
            self.max_queue_ms
        );
        anyhow::ensure!(
            self.encode_threads <= 256,
            "encode_threads {}: must be 0..=256",
            self.encode_threads
        );
        Ok(())
    }

    pub(crate) fn spec_limits(&self) -> SpecLimits {
        SpecLimits {
            max_width: self.max_width,
            max_height: self.max_height,
            default_quality: self.default_quality,
            max_kbps: self.max_kbps,
            min_kbps: self.min_kbps,
            debug_raw_frames: self.debug_raw_frames,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_file_overrides_some_keys() {
        let c: ServerConfig = toml::from_str(
            "scene = \"street\"\nport = 9000\nmax_views = 4\ntoken = \"s3cret\"\nmode = \"reference\"\n\
             voxel_size_m = 1\ndemand = false\nmap = 0\ntransmittance_voxel_m = 0.25\n",
        )
        .unwrap();
        assert_eq!((c.scene.as_str(), c.port, c.max_views), ("street", 9000, 4));
        assert_eq!(c.fps, ServerConfig::default().fps);
        c.validate().unwrap();
        let mut expected = Settings::default();
        expected
            .set_all("mode=reference,voxel_size_m=1,demand=off,shadow_map_px=0,transmittance_voxel_m=0.25")
            .unwrap();
        assert_eq!(c.settings.apply(Settings::default()).unwrap(), expected);
        for (text, needle) in [
            ("prot = 1", "unknown key 'prot'"),
            ("demand = \"maybe\"", "demand=maybe: expected on|off"),
            ("mode = \"truth\"", "mode=truth: expected reference|shared"),
            ("port = \"x\"", "port"),
        ] {
            let e = toml::from_str::<ServerConfig>(text)
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
        let bad_range: ServerConfig = toml::from_str("slices = 1").unwrap();
        let e = bad_range.validate().unwrap_err().to_string();
        assert!(e.contains("slices=1: must be 2..=512"), "{e}");
        assert!(ServerConfig {
            fps: f64::NAN,
            ..Default::default()
        }
        .validate()
        .is_err());
    }
}
