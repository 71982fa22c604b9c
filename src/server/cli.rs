//! `fogcast serve` flags: a config file, then flags over it.

use super::{Server, ServerConfig};
use crate::render::{Mode, Settings};
use crate::settings_overrides::SettingsOverrides;
use std::net::IpAddr;
use std::path::PathBuf;

/// Flags of `fogcast serve`; each overrides the same key of `--config`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServeArgs {
    /// TOML config file (keys as in docs/protocol.md, "Server configuration").
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Built-in scene (colonnade, street, islands, cloud, chimney, smokehall), a scene .toml, or a .glb/.gltf file [default: colonnade].
    #[arg(long)]
    pub scene: Option<String>,
    /// Rendering mode.
    #[arg(long, value_enum, help = format!("Rendering mode [default: {}]", Settings::default().mode.name()))]
    pub mode: Option<Mode>,
    /// Address to listen on [default: 127.0.0.1].
    #[arg(long)]
    pub addr: Option<IpAddr>,
    /// Port (0: any free port) [default: 8080].
    #[arg(long)]
    pub port: Option<u16>,
    /// Frame rate cap [default: 30].
    #[arg(long)]
    pub fps: Option<f64>,
    /// Views rendered in total over all sessions [default: 16].
    #[arg(long)]
    pub max_views: Option<usize>,
    /// Largest frame width a client may ask for [default: 1920].
    #[arg(long)]
    pub max_width: Option<u32>,
    /// Largest frame height a client may ask for [default: 1080].
    #[arg(long)]
    pub max_height: Option<u32>,
    /// JPEG quality for clients that name none [default: 75].
    #[arg(long)]
    pub quality: Option<u8>,
    /// Token clients must send in their hello [default: none, open server].
    #[arg(long)]
    pub token: Option<String>,
    /// Close sessions that send no pose for this many seconds, 0: never [default: 300].
    #[arg(long)]
    pub idle_timeout_s: Option<f64>,
    /// Highest bitrate a session may get, kbit/s [default: 8000].
    #[arg(long)]
    pub max_kbps: Option<u32>,
    /// Allow hellos with `raw_every` (uncompressed frame copies for measuring codec
    /// quality; `fogcast loadgen --raw-every`).
    #[arg(long)]
    pub debug_raw_frames: bool,
    /// The renderer's settings (as in `fogcast render`).
    #[command(flatten)]
    pub settings: SettingsOverrides,
}

impl ServeArgs {
    /// The config file (or the defaults) with every given flag applied, checked.
    pub fn config(&self) -> anyhow::Result<ServerConfig> {
        let mut c = match &self.config {
            Some(path) => ServerConfig::load(path)?,
            None => ServerConfig::default(),
        };
        if let Some(v) = &self.scene {
            c.scene = v.clone();
        }
        if let Some(v) = self.mode {
            c.settings.set("mode", v.name())?;
        }
        c.settings.extend(&self.settings);
        if let Some(v) = self.addr {
            c.addr = v;
        }
        if let Some(v) = self.port {
            c.port = v;
        }
        if let Some(v) = self.fps {
            c.fps = v;
        }
        if let Some(v) = self.max_views {
            c.max_views = v;
        }
        if let Some(v) = self.max_width {
            c.max_width = v;
        }
        if let Some(v) = self.max_height {
            c.max_height = v;
        }
        if let Some(v) = self.quality {
            c.default_quality = v;
        }
        if let Some(v) = &self.token {
            c.token = Some(v.clone());
        }
        if let Some(v) = self.idle_timeout_s {
            c.idle_timeout_s = v;
        }
        if let Some(v) = self.max_kbps {
            c.max_kbps = v;
            c.start_kbps = c.start_kbps.min(v);
        }
        if self.debug_raw_frames {
            c.debug_raw_frames = true;
        }
        c.validate()?;
        Ok(c)
    }
}

/// Runs `fogcast serve` until Ctrl-C or SIGTERM; prints the client's URL once listening.
pub fn serve(args: &ServeArgs) -> anyhow::Result<()> {
    let config = args.config()?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("fogcast-io")
        .build()?;
    runtime.block_on(async move {
        let server = Server::start(config).await?;
        println!(
            "fogcast serving {} — open it in a browser (Ctrl-C stops)",
            server.url()
        );
        server.run_until_signal().await
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser as _;

    #[derive(clap::Parser)]
    struct Serve {
        #[command(flatten)]
        args: ServeArgs,
    }

    #[test]
    fn flags_override_the_config_files_settings() {
        let file =
            std::env::temp_dir().join(format!("fogcast-serve-args-{}.toml", std::process::id()));
        std::fs::write(
            &file,
            "port = 9000\nmode = \"reference\"\ndemand = false\nmap = 0\n",
        )
        .unwrap();
        let args = Serve::try_parse_from([
            "serve",
            "--config",
            file.to_str().unwrap(),
            "--mode",
            "shared",
            "--demand",
            "on",
            "--voxel-size-m",
            "0.5",
        ])
        .unwrap()
        .args;
        let c = args.config();
        std::fs::remove_file(&file).unwrap();
        let c = c.unwrap();
        assert_eq!(c.port, 9000);
        let mut expected = Settings::default();
        expected
            .set_all("voxel_size_m=0.5,shadow_map_px=0")
            .unwrap();
        assert_eq!(c.settings.apply(Settings::default()).unwrap(), expected);
        let e = Serve::try_parse_from(["serve", "--slices", "1"])
            .unwrap()
            .args
            .config()
            .unwrap_err();
        assert!(e.to_string().contains("slices=1: must be 2..=512"), "{e}");
    }
}
