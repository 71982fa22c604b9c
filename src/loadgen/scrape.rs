//! The server seen from outside: `/healthz` (JSON) and `/metrics` (Prometheus text) over
//! a minimal HTTP/1.1 GET, and the per-point server numbers computed from two scrapes.

use super::ServerStats;
use anyhow::Context as _;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio::net::TcpStream;

/// Longest a `/healthz` or `/metrics` answer may take.
const HTTP_TIMEOUT: Duration = Duration::from_secs(10);
/// Largest HTTP answer read (the metrics text is a few KiB).
const MAX_RESPONSE_BYTES: u64 = 8 << 20;

/// `GET path` on `authority` (`host:port`); the body of a `200` answer.
pub(crate) async fn http_get(authority: &str, path: &str) -> anyhow::Result<String> {
    let url = format!("http://{authority}{path}");
    let exchange = async {
        let mut stream = TcpStream::connect(authority).await?;
        stream
            .write_all(
                format!("GET {path} HTTP/1.1\r\nHost: {authority}\r\nConnection: close\r\n\r\n")
                    .as_bytes(),
            )
            .await?;
        let mut buf = Vec::new();
        (&mut stream)
            .take(MAX_RESPONSE_BYTES)
            .read_to_end(&mut buf)
            .await?;
        Ok::<_, std::io::Error>(buf)
    };
    let raw = tokio::time::timeout(HTTP_TIMEOUT, exchange)
        .await
        .map_err(|_| anyhow::anyhow!("{url}: no answer within {} s", HTTP_TIMEOUT.as_secs()))?
        .map_err(|e| {
            anyhow::anyhow!(
                "cannot reach {url} ({e}): is `fogcast serve` running there? (`make run` starts one on 127.0.0.1:8080)"
            )
        })?;
    let text = String::from_utf8_lossy(&raw);
    let (head, body) = text
        .split_once("\r\n\r\n")
        .with_context(|| format!("{url}: not an HTTP answer ({} bytes)", raw.len()))?;
    let status: u16 = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .with_context(|| format!("{url}: no status in {:?}", head.lines().next()))?;
    let chunked = head.lines().any(|l| {
        let l = l.to_ascii_lowercase();
        l.starts_with("transfer-encoding:") && l.contains("chunked")
    });
    let body = if chunked {
        dechunk(body).with_context(|| format!("{url}: malformed chunked body"))?
    } else {
        body.to_string()
    };
    anyhow::ensure!(
        status == 200,
        "{url} answered HTTP {status}: {}",
        body.trim()
    );
    Ok(body)
}

/// The payload of a `Transfer-Encoding: chunked` body.
fn dechunk(mut body: &str) -> Option<String> {
    let mut out = String::new();
    loop {
        let (size, rest) = body.split_once("\r\n")?;
        let size = usize::from_str_radix(size.split(';').next()?.trim(), 16).ok()?;
        if size == 0 {
            return Some(out);
        }
        out.push_str(rest.get(..size)?);
        body = rest.get(size..)?.strip_prefix("\r\n")?;
    }
}

/// What `/healthz` says about the server.
#[derive(Debug, Clone)]
pub(crate) struct Health {
    pub(crate) scene: String,
    pub(crate) viewers: usize,
    pub(crate) max_viewers: usize,
}

pub(crate) async fn health(authority: &str) -> anyhow::Result<Health> {
    let body = http_get(authority, "/healthz").await?;
    let v: serde_json::Value = serde_json::from_str(&body)
        .with_context(|| format!("http://{authority}/healthz is not JSON: {body}"))?;
    let count = |k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_u64)
            .map(|n| n as usize)
            .with_context(|| format!("http://{authority}/healthz has no {k:?}: {body}"))
    };
    Ok(Health {
        scene: v
            .get("scene")
            .and_then(serde_json::Value::as_str)
            .unwrap_or_default()
            .to_string(),
        viewers: count("viewers")?,
        max_viewers: count("max_viewers")?,
    })
}

/// One `/metrics` answer: every sample by its full key (`name{labels}`), and when.
#[derive(Debug, Clone)]
pub(crate) struct Scrape {
    pub(crate) at: Instant,
    samples: BTreeMap<String, f64>,
}

impl Scrape {
    /// Parses the Prometheus text format (comments skipped, values as f64).
    pub(crate) fn parse(text: &str, at: Instant) -> Scrape {
        let samples = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| {
                let (key, value) = l.trim().rsplit_once(' ')?;
                Some((key.to_string(), value.parse::<f64>().ok()?))
            })
            .collect();
        Scrape { at, samples }
    }

    /// Sum of the samples of `name` whose labels contain `labels` (0 when absent).
    pub(crate) fn get(&self, name: &str, labels: &str) -> f64 {
        self.samples
            .iter()
            .filter(|(k, _)| {
                let (n, rest) = k.split_once('{').unwrap_or((k.as_str(), ""));
                n == name && rest.contains(labels)
            })
            .map(|(_, v)| *v)
            .sum()
    }

    /// Whether the server reports metric `name` at all (with any labels).
    pub(crate) fn has(&self, name: &str) -> bool {
        self.samples
            .keys()
            .any(|k| k.split_once('{').map_or(k.as_str(), |(n, _)| n) == name)
    }

    /// Values of label `label` over the samples of `name`.
    fn label_values(&self, name: &str, label: &str) -> Vec<String> {
        let prefix = format!("{name}{{{label}=\"");
        self.samples
            .keys()
            .filter_map(|k| Some(k.strip_prefix(&prefix)?.split('"').next()?.to_string()))
            .collect()
    }
}

pub(crate) async fn metrics(authority: &str) -> anyhow::Result<Scrape> {
    let text = http_get(authority, "/metrics").await?;
    Ok(Scrape::parse(&text, Instant::now()))
}

/// Labels of the rays traced into the shared world-space shadow grid.
const GRID_RAYS: &str = "stage=\"shared_grid\"";

/// Server numbers over the interval between two scrapes.
pub(crate) fn server_stats(before: &Scrape, after: &Scrape) -> ServerStats {
    let d =
        |name: &str, labels: &str| (after.get(name, labels) - before.get(name, labels)).max(0.0);
    let seconds = after.at.duration_since(before.at).as_secs_f64().max(1e-9);
    let mean_ms = |name: &str, labels: &str| {
        let count = d(&format!("{name}_count"), labels);
        (count > 0.0).then(|| d(&format!("{name}_sum"), labels) / count * 1e3)
    };
    let frames = d("fogcast_frames_total", "");
    let render_calls = d("fogcast_render_calls_total", "");
    let per = |n: f64, of: f64| if of > 0.0 { n / of } else { 0.0 };
    let grid_rays = d("fogcast_rays_traced_total", GRID_RAYS);
    let stage_gpu_ms = after
        .label_values("fogcast_stage_gpu_seconds_sum", "stage")
        .into_iter()
        .filter_map(|stage| {
            let ms = mean_ms("fogcast_stage_gpu_seconds", &format!("stage=\"{stage}\""))?;
            Some((stage, ms))
        })
        .collect();
    let rays_per_frame = after
        .label_values("fogcast_rays_traced_total", "stage")
        .into_iter()
        .map(|stage| {
            let rays = d("fogcast_rays_traced_total", &format!("stage=\"{stage}\""));
            (stage, if frames > 0.0 { rays / frames } else { 0.0 })
        })
        .collect();
    ServerStats {
        seconds,
        frames: frames as u64,
        fps: frames / seconds,
        frame_ms: mean_ms("fogcast_frame_seconds", ""),
        render_ms: mean_ms("fogcast_render_seconds", ""),
        encode_ms: mean_ms("fogcast_encode_seconds", ""),
        render_calls: render_calls as u64,
        views_rendered: d("fogcast_views_rendered_total", "") as u64,
        render_errors: d("fogcast_render_errors_total", "") as u64,
        stage_gpu_ms,
        rays_per_frame,
        render_calls_per_frame: per(render_calls, frames),
        grid_rays_per_frame: per(grid_rays, frames),
        grid_rays_per_render_call: per(grid_rays, render_calls),
        frames_encoded: (d("fogcast_frames_encoded_total", "codec=\"jpeg\"")
            + d("fogcast_frames_encoded_total", "codec=\"h264\"")) as u64,
        frames_sent: d("fogcast_frames_sent_total", "") as u64,
        bytes_sent: d("fogcast_bytes_sent_total", "") as u64,
        dropped_client_slow: d("fogcast_frames_dropped_total", "reason=\"client_slow\"") as u64,
        dropped_encoder_busy: d("fogcast_frames_dropped_total", "reason=\"encoder_busy\"") as u64,
        sessions: after.get("fogcast_sessions", "") as u64,
        viewers: after.get("fogcast_viewers", "") as u64,
        view_sizes: after.get("fogcast_view_sizes", "") as u64,
        resident_memory_mib: after.get("fogcast_resident_memory_bytes", "") / (1024.0 * 1024.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunked_bodies_are_joined() {
        assert_eq!(
            dechunk("5\r\nhello\r\n6\r\n world\r\n0\r\n\r\n").as_deref(),
            Some("hello world")
        );
        assert_eq!(dechunk("zz\r\n"), None);
    }

    #[test]
    fn deltas_between_scrapes() {
        let t0 = Instant::now();
        let a = Scrape::parse(
            "# TYPE x counter\nfogcast_frames_total 10\nfogcast_frame_seconds_sum 1.0\nfogcast_frame_seconds_count 10\n\
             fogcast_stage_gpu_seconds_sum{stage=\"froxel_lighting\"} 0.5\nfogcast_stage_gpu_seconds_count{stage=\"froxel_lighting\"} 10\n\
             fogcast_rays_traced_total{stage=\"surface\"} 100\nfogcast_frames_dropped_total{reason=\"client_slow\"} 1\n\
             fogcast_render_calls_total 10\nfogcast_rays_traced_total{stage=\"shared_grid\"} 1000\n",
            t0,
        );
        let b = Scrape::parse(
            "fogcast_frames_total 30\nfogcast_frame_seconds_sum 5.0\nfogcast_frame_seconds_count 30\n\
             fogcast_stage_gpu_seconds_sum{stage=\"froxel_lighting\"} 2.5\nfogcast_stage_gpu_seconds_count{stage=\"froxel_lighting\"} 30\n\
             fogcast_rays_traced_total{stage=\"surface\"} 2100\nfogcast_frames_dropped_total{reason=\"client_slow\"} 4\nfogcast_viewers 2\n\
             fogcast_render_calls_total 70\nfogcast_rays_traced_total{stage=\"shared_grid\"} 61000\n",
            t0 + Duration::from_secs(2),
        );
        let s = server_stats(&a, &b);
        assert_eq!((s.frames, s.viewers, s.dropped_client_slow), (20, 2, 3));
        assert!((s.fps - 10.0).abs() < 1e-9);
        assert!((s.frame_ms.unwrap() - 200.0).abs() < 1e-6);
        assert!((s.stage_gpu_ms["froxel_lighting"] - 100.0).abs() < 1e-6);
        assert!((s.rays_per_frame["surface"] - 100.0).abs() < 1e-9);
        assert_eq!(s.encode_ms, None);
        // Three view sizes, each filling the grid: 3 calls and 3000 grid rays a frame.
        assert_eq!(s.render_calls, 60);
        assert!((s.render_calls_per_frame - 3.0).abs() < 1e-9);
        assert!((s.grid_rays_per_frame - 3000.0).abs() < 1e-9);
        assert!((s.grid_rays_per_render_call - 1000.0).abs() < 1e-9);
    }
}
