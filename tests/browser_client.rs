//! The browser client in real headless Chromium (Debian's `chromium`, installed by
//! `make deps`): it connects, shows frames, flies the camera on synthetic key presses,
//! and reconnects after the server goes away and comes back; it picks H.264 and decodes
//! it with WebCodecs, falls back to JPEG without WebCodecs (or with a decoder that keeps
//! failing), recovers from a decode error with a key frame request, and lets a hidden
//! page go idle.
//!
//! Chromium is driven over the DevTools protocol on a loopback WebSocket. One browser
//! at a time: each test measures frame rates and latencies that a second Chromium
//! decoding next to it would skew.

mod server_support;

use futures_util::{SinkExt as _, StreamExt as _};
use serde_json::{json, Value};
use server_support::*;
use std::io::BufRead as _;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::{Mutex, MutexGuard};
use tokio_tungstenite::tungstenite::Message;

static ONE_BROWSER: Mutex<()> = Mutex::const_new(());

/// The Chromium process and its profile folder, both removed on drop.
struct Browser {
    child: Child,
    profile: PathBuf,
}

/// Profiles of the browsers this process starts (one folder each).
static PROFILES: AtomicU32 = AtomicU32::new(0);

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        // Chromium's helper processes write into the profile for a moment after the
        // browser process is gone: try again until the folder is gone.
        for _ in 0..20 {
            if std::fs::remove_dir_all(&self.profile).is_ok() || !self.profile.exists() {
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

fn chromium_path() -> PathBuf {
    let path = std::env::var_os("FOGCAST_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    assert!(
        path.exists(),
        "{} not found: run `make deps` (installs Debian's chromium), or set FOGCAST_CHROMIUM",
        path.display()
    );
    path
}

/// Starts headless Chromium with a fresh profile; returns it and its DevTools URL.
fn launch() -> (Browser, String) {
    let profile = std::env::temp_dir().join(format!(
        "fogcast-chromium-{}-{}",
        std::process::id(),
        PROFILES.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&profile);
    let mut child = Command::new(chromium_path())
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-extensions",
            "--remote-debugging-address=127.0.0.1",
            "--remote-debugging-port=0",
            "--window-size=800,600",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("about:blank")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("chromium starts");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    // Reads Chromium's stderr to the end (so it never blocks on a full pipe).
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            if let Some(url) = line.strip_prefix("DevTools listening on ") {
                let _ = tx.send(url.trim().to_string());
            }
        }
    });
    let browser = Browser { child, profile };
    let url = rx
        .recv_timeout(Duration::from_secs(60))
        .expect("Chromium prints its DevTools address");
    assert!(
        url.starts_with("ws://127.0.0.1:"),
        "DevTools on loopback: {url}"
    );
    (browser, url)
}

/// A minimal DevTools protocol client: one page session over the browser connection.
struct Cdp {
    ws: Ws,
    next_id: u64,
    session: Option<String>,
}

impl Cdp {
    async fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if let Some(s) = &self.session {
            msg["sessionId"] = s.clone().into();
        }
        self.ws.send(Message::text(msg.to_string())).await.unwrap();
        loop {
            let m = tokio::time::timeout(PATIENCE, self.ws.next())
                .await
                .expect("DevTools answers")
                .expect("open")
                .expect("ok");
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["id"].as_u64() == Some(id) {
                assert!(v.get("error").is_none(), "{method} failed: {v}");
                return v["result"].clone();
            }
        }
    }

    async fn eval(&mut self, expression: &str) -> Value {
        let r = self
            .call(
                "Runtime.evaluate",
                json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
            )
            .await;
        assert!(r.get("exceptionDetails").is_none(), "{expression}: {r}");
        r["result"]["value"].clone()
    }

    async fn stats(&mut self) -> Value {
        self.eval("window.fogcast ? window.fogcast.stats() : null")
            .await
    }

    /// Polls the client's stats until `pred` holds.
    async fn wait_stats(&mut self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        for _ in 0..600 {
            let s = self.stats().await;
            if !s.is_null() && pred(&s) {
                return s;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!(
            "the page never reached: {what} (stats: {})",
            self.stats().await
        );
    }

    async fn key(&mut self, kind: &str, key: &str, code: &str, vk: u32) {
        self.call("Input.dispatchKeyEvent", json!({"type": kind, "key": key, "code": code, "windowsVirtualKeyCode": vk, "nativeVirtualKeyCode": vk})).await;
    }
}

/// A page of the browser client, open in its own Chromium.
struct Page {
    cdp: Cdp,
    _browser: Browser,
    _turn: MutexGuard<'static, ()>,
}

/// Opens `http://{addr}/{query}` in a fresh Chromium; `before_scripts` runs in the page
/// before any of the page's own scripts.
async fn open_page(addr: SocketAddr, query: &str, before_scripts: Option<&str>) -> Page {
    let turn = ONE_BROWSER.lock().await;
    let (browser, devtools) = launch();
    let (ws, _) = tokio_tungstenite::connect_async(&devtools)
        .await
        .expect("DevTools connects");
    let mut cdp = Cdp {
        ws,
        next_id: 0,
        session: None,
    };
    let target = cdp
        .call("Target.createTarget", json!({"url": "about:blank"}))
        .await;
    let attached = cdp
        .call(
            "Target.attachToTarget",
            json!({"targetId": target["targetId"], "flatten": true}),
        )
        .await;
    cdp.session = Some(attached["sessionId"].as_str().unwrap().to_string());
    cdp.call("Page.enable", json!({})).await;
    if let Some(source) = before_scripts {
        cdp.call(
            "Page.addScriptToEvaluateOnNewDocument",
            json!({ "source": source }),
        )
        .await;
    }
    cdp.call(
        "Page.navigate",
        json!({"url": format!("http://{addr}/{query}")}),
    )
    .await;
    Page {
        cdp,
        _browser: browser,
        _turn: turn,
    }
}

/// Holds W (forward) and Left (turn) for a second, then waits for two frames rendered
/// with the final pose. Returns the canvas before and after, and the stats after.
async fn fly(cdp: &mut Cdp) -> (Value, Value, Value) {
    let before = cdp.eval("window.fogcast.canvasStats()").await;
    let cam_before = cdp.stats().await["camera"].clone();
    cdp.eval("document.getElementById('view').focus()").await;
    cdp.key("rawKeyDown", "w", "KeyW", 87).await;
    cdp.key("rawKeyDown", "ArrowLeft", "ArrowLeft", 37).await;
    tokio::time::sleep(Duration::from_millis(1000)).await;
    cdp.key("keyUp", "w", "KeyW", 87).await;
    cdp.key("keyUp", "ArrowLeft", "ArrowLeft", 37).await;
    let moved = cdp.stats().await;
    assert_ne!(moved["camera"], cam_before, "key presses moved the camera");
    let seq = moved["seq"].as_u64().unwrap();
    let shown = moved["shown"].as_u64().unwrap();
    let after_stats = cdp
        .wait_stats("a frame of the new pose", |s| {
            s["frameSeq"].as_u64() >= Some(seq) && s["shown"].as_u64() >= Some(shown + 2)
        })
        .await;
    let after = cdp.eval("window.fogcast.canvasStats()").await;
    (before, after, after_stats)
}

/// The canvas shows something (not a black or blank frame).
fn assert_not_black(canvas: &Value, when: &str) {
    assert!(
        canvas["mean"].as_f64().unwrap() > 10.0,
        "the image {when} is black: {canvas}"
    );
}

fn u64_of(s: &Value, key: &str) -> u64 {
    s[key]
        .as_u64()
        .unwrap_or_else(|| panic!("stats.{key} is a count: {s}"))
}

fn grid_diff(a: &Value, b: &Value) -> f64 {
    let (a, b) = (a["grid"].as_array().unwrap(), b["grid"].as_array().unwrap());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x.as_f64().unwrap() - y.as_f64().unwrap()).abs())
        .sum::<f64>()
        / a.len() as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chromium_shows_frames_and_flies_the_camera() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let mut page = open_page(addr, "?w=160&h=90&quality=90&codec=jpeg", None).await;
    let cdp = &mut page.cdp;

    let s = cdp
        .wait_stats("3 frames shown", |s| s["shown"].as_u64() >= Some(3))
        .await;
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(160), Some(90)),
        "{s}"
    );
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_eq!(
        (s["codec"].as_str(), s["frameCodec"].as_str()),
        (Some("jpeg"), Some("jpeg")),
        "{s}"
    );
    let quality = u64_of(&s, "quality");
    assert!(
        (20..=90).contains(&quality),
        "the header's JPEG quality: at most the 90 asked for, at least the server's 20: {s}"
    );
    assert_not_black(
        &cdp.eval("window.fogcast.canvasStats()").await,
        "first shown",
    );

    let (before, after, after_stats) = fly(cdp).await;
    let diff = grid_diff(&before, &after);
    eprintln!(
        "browser (jpeg): mean luma {:.1} -> {:.1}, 8x8 grid diff {diff:.2}, latency {:?} ms, fps {}",
        before["mean"].as_f64().unwrap(),
        after["mean"].as_f64().unwrap(),
        after_stats["latencyMs"],
        after_stats["fps"]
    );
    assert_not_black(&after, "after moving");
    assert!(
        diff > 2.0,
        "the displayed image did not change after moving (grid diff {diff:.2})"
    );
    assert!(
        after_stats["latencyMs"].as_f64().is_some(),
        "pose-to-frame latency is measured"
    );
    assert!(
        u64_of(&after_stats, "acks") >= u64_of(&after_stats, "shown") / 2,
        "the client acks the frames it shows: {after_stats}"
    );

    let shot = cdp
        .call("Page.captureScreenshot", json!({"format": "png"}))
        .await;
    let png = base64_decode(shot["data"].as_str().unwrap());
    assert!(png.starts_with(b"\x89PNG"), "a PNG screenshot");
    let out = std::env::var_os("FOGCAST_TEST_OUT")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_TARGET_TMPDIR")));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("browser_client.png"), &png).unwrap();

    // The server goes away and comes back on the same port: the page reconnects.
    let config = fogcast::server::ServerConfig {
        port: addr.port(),
        ..test_config()
    };
    server.shutdown().await.unwrap();
    cdp.wait_stats("disconnected", |s| s["connected"] == false)
        .await;
    let server = start(config).await;
    let shown = cdp.stats().await["shown"].as_u64().unwrap();
    cdp.wait_stats("reconnected and streaming", |s| {
        s["connected"] == true && s["shown"].as_u64() >= Some(shown + 2)
    })
    .await;
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chromium_decodes_h264_with_webcodecs() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    // No codec parameter: the page picks H.264 because this Chromium decodes it.
    let mut page = open_page(addr, "?w=160&h=90", None).await;
    let cdp = &mut page.cdp;

    let s = cdp
        .wait_stats("5 H.264 frames decoded", |s| {
            s["framesDecoded"].as_u64() >= Some(5)
        })
        .await;
    assert_eq!(s["askedCodec"].as_str(), Some("h264"), "{s}");
    assert_eq!(
        s["codec"].as_str(),
        Some("h264"),
        "the welcome's codec: {s}"
    );
    assert_eq!(s["frameCodec"].as_str(), Some("h264"), "{s}");
    assert!(
        u64_of(&s, "keyFrames") >= 1,
        "the stream starts with a key frame: {s}"
    );
    assert_eq!(u64_of(&s, "decodeErrors"), 0, "{s}");
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(160), Some(90)),
        "the canvas has the frame size: {s}"
    );
    assert_not_black(
        &cdp.eval("window.fogcast.canvasStats()").await,
        "first decoded",
    );

    // A new welcome (here for a configure from the resolution menu) starts a new stream:
    // the page restarts its decoder at the stream's key frame and the canvas takes the
    // new size.
    cdp.eval(
        "(() => { const menu = document.getElementById('resolution'); \
         menu.value = '320x180'; menu.dispatchEvent(new Event('change')); })()",
    )
    .await;
    let resized = cdp
        .wait_stats("3 frames of the new size decoded", |r| {
            r["width"] == 320
                && r["framesDecoded"].as_u64() >= Some(u64_of(&s, "framesDecoded") + 3)
        })
        .await;
    assert_eq!(resized["height"].as_u64(), Some(180), "{resized}");
    assert!(
        u64_of(&resized, "keyFrames") > u64_of(&s, "keyFrames"),
        "the new stream began with a key frame: {resized}"
    );
    assert_eq!(u64_of(&resized, "decodeErrors"), 0, "{resized}");
    assert_eq!(resized["codec"].as_str(), Some("h264"), "{resized}");

    let (before, after, after_stats) = fly(cdp).await;
    let diff = grid_diff(&before, &after);
    eprintln!(
        "browser (h264): mean luma {:.1} -> {:.1}, 8x8 grid diff {diff:.2}, latency {:?} ms, fps {}, {} kbit/s (target {}), {} acks",
        before["mean"].as_f64().unwrap(),
        after["mean"].as_f64().unwrap(),
        after_stats["latencyMs"],
        after_stats["fps"],
        after_stats["kbps"],
        after_stats["targetKbps"],
        after_stats["acks"],
    );
    assert_not_black(&after, "after moving");
    assert!(
        diff > 2.0,
        "the displayed H.264 image did not change after moving (grid diff {diff:.2})"
    );
    assert_eq!(u64_of(&after_stats, "decodeErrors"), 0, "{after_stats}");
    assert_eq!(
        after_stats["errors"].as_array().map(Vec::len),
        Some(0),
        "{after_stats}"
    );
    let fps = u64_of(&after_stats, "fps");
    assert!(
        (2..=25).contains(&fps),
        "frames shown per second, at most the server's 20 (and some jitter): {after_stats}"
    );
    let kbps = after_stats["kbps"].as_f64().unwrap();
    assert!(
        (1.0..=20_000.0).contains(&kbps),
        "received bitrate over the last second: {after_stats}"
    );
    let target = u64_of(&after_stats, "targetKbps");
    assert!(
        (150..=8000).contains(&target),
        "the header's target bitrate: {after_stats}"
    );
    // Acks: one per frame shown, and the server, which keeps at most ~150 ms in flight
    // for a client that acks, kept streaming.
    let (shown, acks) = (u64_of(&after_stats, "shown"), u64_of(&after_stats, "acks"));
    assert!(
        acks >= shown / 2 && acks <= u64_of(&after_stats, "received"),
        "about one ack per frame shown: {after_stats}"
    );
    let m = metrics(addr).await;
    assert!(
        metric(&m, "fogcast_frames_encoded_total", "codec=\"h264\"") >= shown as f64,
        "the server encoded every frame shown as H.264: {m}"
    );
    assert!(metric(&m, "fogcast_key_frames_total", "") >= 1.0, "{m}");
    assert!(
        metric(&m, "fogcast_frames_sent_total", "") >= shown as f64,
        "{m}"
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chromium_without_webcodecs_falls_back_to_jpeg() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let mut page = open_page(addr, "?w=160&h=90", Some("delete window.VideoDecoder;")).await;
    let cdp = &mut page.cdp;

    let s = cdp
        .wait_stats("3 frames shown", |s| s["shown"].as_u64() >= Some(3))
        .await;
    assert_eq!(
        cdp.eval("typeof window.VideoDecoder").await,
        "undefined",
        "the page ran without WebCodecs"
    );
    assert_eq!(s["askedCodec"].as_str(), Some("jpeg"), "{s}");
    assert_eq!(
        (s["codec"].as_str(), s["frameCodec"].as_str()),
        (Some("jpeg"), Some("jpeg")),
        "{s}"
    );
    assert_eq!(u64_of(&s, "decodeErrors"), 0, "{s}");
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_not_black(&cdp.eval("window.fogcast.canvasStats()").await, "shown");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn h264_decode_error_recovers_with_a_keyframe_request() {
    // No periodic key frames (3 minutes apart): only the request can bring one soon.
    let server = start(fogcast::server::ServerConfig {
        gop_frames: 3600,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut page = open_page(addr, "?w=160&h=90&codec=h264", None).await;
    let cdp = &mut page.cdp;
    // Past the stream's first key frame, so the next one can only be the requested one.
    let s = cdp
        .wait_stats("10 H.264 frames decoded", |s| {
            s["framesDecoded"].as_u64() >= Some(10) && s["codec"] == "h264"
        })
        .await;
    let (keys, requests) = (u64_of(&s, "keyFrames"), u64_of(&s, "keyframeRequests"));

    cdp.eval("window.fogcast.corruptNextFrame()").await;
    let t0 = Instant::now();
    let broken = cdp
        .wait_stats("a decode error", |s| s["decodeErrors"].as_u64() >= Some(1))
        .await;
    assert_eq!(
        u64_of(&broken, "keyframeRequests"),
        requests + 1,
        "the error sent a key frame request at once: {broken}"
    );
    let decoded = u64_of(&broken, "framesDecoded");
    let s = cdp
        .wait_stats("decoding again after a new key frame", |s| {
            s["framesDecoded"].as_u64() >= Some(decoded + 5)
        })
        .await;
    let recovered_s = t0.elapsed().as_secs_f64();
    eprintln!("browser (h264): decode error -> 5 frames decoded again in {recovered_s:.2} s: {s}");
    assert!(
        u64_of(&s, "keyFrames") > keys,
        "a key frame followed the request: {s}"
    );
    assert_eq!(u64_of(&s, "decodeErrors"), 1, "{s}");
    let server_keys = metric(&metrics(addr).await, "fogcast_key_frames_total", "");
    assert!(
        (2.0..=5.0).contains(&server_keys),
        "the stream's first key frame and the requested one(s): {server_keys}"
    );
    assert!(
        u64_of(&s, "keyframeRequests") <= requests + 3,
        "one request, repeated at most every 500 ms: {s}"
    );
    assert!(recovered_s < 5.0, "recovery took {recovered_s:.2} s");
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_not_black(
        &cdp.eval("window.fogcast.canvasStats()").await,
        "after recovery",
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn h264_decoder_that_keeps_failing_falls_back_to_jpeg() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    // WebCodecs says it decodes H.264, then every decode fails.
    let broken = "VideoDecoder.prototype.decode = function () { \
                  throw new DOMException('broken on purpose', 'EncodingError'); };";
    let mut page = open_page(addr, "?w=160&h=90", Some(broken)).await;
    let cdp = &mut page.cdp;

    let s = cdp
        .wait_stats("JPEG frames after giving up on H.264", |s| {
            s["codec"] == "jpeg" && s["shown"].as_u64() >= Some(3)
        })
        .await;
    assert_eq!(s["askedCodec"].as_str(), Some("jpeg"), "{s}");
    assert_eq!(s["frameCodec"].as_str(), Some("jpeg"), "{s}");
    assert_eq!(
        u64_of(&s, "decodeErrors"),
        3,
        "three errors in a row, then JPEG: {s}"
    );
    assert!(
        (1..=3).contains(&u64_of(&s, "keyframeRequests")),
        "key frame requests between the errors, 500 ms apart at most: {s}"
    );
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_not_black(&cdp.eval("window.fogcast.canvasStats()").await, "in JPEG");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hidden_page_goes_idle_and_comes_back_when_shown() {
    let server = start(fogcast::server::ServerConfig {
        idle_timeout_s: 1.0,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    // Headless Chromium's page is always visible: `document.hidden` follows a test flag.
    let hidden =
        "Object.defineProperty(document, 'hidden', { get: () => window.testHidden === true });";
    let mut page = open_page(addr, "?w=160&h=90", Some(hidden)).await;
    let cdp = &mut page.cdp;
    cdp.wait_stats("3 frames shown", |s| s["shown"].as_u64() >= Some(3))
        .await;
    // Visible and still: keepalive poses keep the session open past the idle timeout.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(cdp.stats().await["connected"], true, "a visible page stays");

    cdp.eval("window.testHidden = true").await;
    let t0 = Instant::now();
    cdp.wait_stats("closed as idle", |s| s["connected"] == false)
        .await;
    let idle_s = t0.elapsed().as_secs_f64();
    eprintln!("browser: closed as idle {idle_s:.2} s after the page was hidden");
    // The idle clock started at the last keepalive pose, up to 250 ms before hiding.
    assert!(
        (0.6..=5.0).contains(&idle_s),
        "closed {idle_s:.2} s after the page was hidden (idle_timeout_s 1)"
    );
    let status = cdp
        .eval("document.getElementById('status').textContent")
        .await;
    assert!(
        status.as_str().is_some_and(|s| s.contains("idle")),
        "the page says why: {status}"
    );
    // No reconnect on its own while hidden...
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(
        cdp.stats().await["connected"],
        false,
        "a hidden page stays closed"
    );
    // ...and one as soon as it is shown.
    let shown = u64_of(&cdp.stats().await, "shown");
    cdp.eval("window.testHidden = false; document.dispatchEvent(new Event('visibilitychange'))")
        .await;
    cdp.wait_stats("reconnected and streaming", |s| {
        s["connected"] == true && s["shown"].as_u64() >= Some(shown + 2)
    })
    .await;
    let m = metrics(addr).await;
    assert_eq!(metric(&m, "fogcast_sessions_idle_total", ""), 1.0, "{m}");
    server.shutdown().await.unwrap();
}

/// Standard base64 (the screenshot's encoding).
fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let bytes: Vec<u8> = s
        .bytes()
        .filter(|c| *c != b'=' && !c.is_ascii_whitespace())
        .map(val)
        .collect();
    bytes
        .chunks(4)
        .flat_map(|c| {
            let n = c
                .iter()
                .enumerate()
                .fold(0u32, |acc, (i, v)| acc | (*v as u32) << (18 - 6 * i));
            let out = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            out.into_iter().take(c.len() - 1)
        })
        .collect()
}

/// `fogcast serve --scene smokehall` in Chromium: the smoke is drawn (every smoke stage
/// ran) and drifts while the camera stands still — the smoke is the only thing in
/// smokehall that moves, so any change of the still view is the smoke's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chromium_shows_the_smoke_scene_moving() {
    let server = start(fogcast::server::ServerConfig {
        scene: "smokehall".into(),
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut page = open_page(addr, "?w=160&h=90&quality=90&codec=jpeg", None).await;
    let cdp = &mut page.cdp;
    let s = cdp
        .wait_stats("3 frames shown", |s| s["shown"].as_u64() >= Some(3))
        .await;
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    let first = cdp.eval("window.fogcast.canvasStats()").await;
    assert_not_black(&first, "first shown");
    let camera = s["camera"].clone();
    // The server's scene clock runs on: 8 s later the cloud has grown from a few dozen
    // particles to about a hundred and drifted.
    tokio::time::sleep(Duration::from_secs(8)).await;
    let shown = u64_of(&cdp.stats().await, "shown");
    let later_stats = cdp
        .wait_stats("two more frames", |s| {
            s["shown"].as_u64() >= Some(shown + 2)
        })
        .await;
    assert_eq!(later_stats["camera"], camera, "the camera stood still");
    let later = cdp.eval("window.fogcast.canvasStats()").await;
    assert_not_black(&later, "8 s later");
    let diff = grid_diff(&first, &later);
    // The cloud covers part of the view: the cell that changed most, in luma (0–255).
    let cells = |v: &Value| -> Vec<f64> {
        v["grid"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let most = cells(&first)
        .iter()
        .zip(cells(&later))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "browser (smokehall): over 8 s with a still camera, 8x8 grid diff {diff:.2}, largest cell change {most:.1}"
    );
    assert!(
        most > 3.0,
        "the still view did not change as the smoke drifted (largest cell change {most:.1})"
    );
    let m = metrics(addr).await;
    for stage in [
        "smoke_particles",
        "smoke_shadows",
        "smoke_proxies",
        "smoke_raster",
    ] {
        let runs = metric(
            &m,
            "fogcast_stage_gpu_seconds_count",
            &format!("stage=\"{stage}\""),
        );
        assert!(runs >= 1.0, "stage {stage} ran {runs} times:\n{m}");
    }
    server.shutdown().await.unwrap();
}

/// The luma of the canvas's left and right halves (a stereo frame: left eye, right eye),
/// row by row.
async fn eye_lumas(cdp: &mut Cdp) -> (Vec<f64>, Vec<f64>, usize, usize) {
    let v = cdp
        .eval(
            "(() => { const c = document.getElementById('view'); \
             const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
             const l = []; for (let i = 0; i < d.length; i += 4) \
             l.push(0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2]); \
             return { w: c.width, h: c.height, l }; })()",
        )
        .await;
    let (w, h) = (
        v["w"].as_u64().unwrap() as usize,
        v["h"].as_u64().unwrap() as usize,
    );
    let l: Vec<f64> = v["l"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let half = w / 2;
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for y in 0..h {
        left.extend_from_slice(&l[y * w..y * w + half]);
        right.extend_from_slice(&l[y * w + half..(y + 1) * w]);
    }
    (left, right, half, h)
}

/// Mean |left(x) − right(x + s)| over the columns both cover, for each shift s.
fn shifted_differences(
    left: &[f64],
    right: &[f64],
    w: usize,
    h: usize,
    max: i32,
) -> Vec<(i32, f64)> {
    (-max..=max)
        .map(|s| {
            let (mut sum, mut n) = (0.0, 0);
            for y in 0..h {
                for x in 0..w as i32 {
                    let xr = x + s;
                    if (0..w as i32).contains(&xr) {
                        sum += (left[y * w + x as usize] - right[y * w + xr as usize]).abs();
                        n += 1;
                    }
                }
            }
            (s, sum / f64::from(n))
        })
        .collect()
}

/// A stereo session in the browser: two eyes side by side that differ by the parallax of
/// the eye distance (the right eye sees the scene shifted left by f·e/z pixels), that
/// move with the pose, and that are identical at eye distance 0.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chromium_shows_a_stereo_session_with_parallax() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    const EYE_M: f64 = 0.3;
    let mut page = open_page(
        addr,
        &format!("?w=192&h=72&layout=stereo&eye={EYE_M}&quality=95&codec=jpeg"),
        None,
    )
    .await;
    let cdp = &mut page.cdp;
    let s = cdp
        .wait_stats("3 stereo frames shown", |s| s["shown"].as_u64() >= Some(3))
        .await;
    assert_eq!(s["errors"].as_array().map(Vec::len), Some(0), "{s}");
    assert_eq!(s["layout"].as_str(), Some("stereo"), "{s}");
    let (left, right, w, h) = eye_lumas(cdp).await;
    assert_eq!((w, h), (96, 72), "two 96x72 eyes");
    let fov_y = s["camera"]["fov"]
        .as_f64()
        .expect("the pose's fov")
        .to_radians();
    let f_px = h as f64 / 2.0 / (fov_y / 2.0).tan();
    let diffs = shifted_differences(&left, &right, w, h, 16);
    let (best, best_diff) = diffs
        .iter()
        .copied()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    let at_zero = diffs.iter().find(|(s, _)| *s == 0).unwrap().1;
    // The colonnade from its path: most of the view is 2 to 15 m away.
    let (near_px, far_px) = (f_px * EYE_M / 2.0, f_px * EYE_M / 15.0);
    eprintln!(
        "browser (stereo, eye {EYE_M} m, f {f_px:.1} px): best shift {best} px ({best_diff:.2} mean luma difference, {at_zero:.2} unshifted); expected between -{near_px:.1} and -{far_px:.1}"
    );
    assert!(at_zero > 1.0, "the eyes differ: {at_zero:.2}");
    assert!(
        best < 0 && f64::from(-best) <= near_px + 1.0 && f64::from(-best) >= far_px.floor(),
        "the right eye's image is shifted by {best} px, expected -{far_px:.1}..-{near_px:.1}"
    );
    assert!(
        best_diff < 0.9 * at_zero,
        "the shift explains the difference: {best_diff:.2} vs {at_zero:.2}"
    );

    // Both eyes move with the head.
    let (before_l, before_r) = (left, right);
    fly(cdp).await;
    let (after_l, after_r, _, _) = eye_lumas(cdp).await;
    let moved = |a: &[f64], b: &[f64]| {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
    };
    let (moved_l, moved_r) = (moved(&before_l, &after_l), moved(&before_r, &after_r));
    eprintln!(
        "browser (stereo): after flying, left eye changed {moved_l:.2}, right eye {moved_r:.2}"
    );
    assert!(
        moved_l > 2.0 && moved_r > 2.0,
        "both eyes follow the pose: {moved_l:.2}, {moved_r:.2}"
    );
    drop(page);

    // Eye distance 0: both eyes are the same view.
    let mut page = open_page(
        addr,
        "?w=192&h=72&layout=stereo&eye=0&quality=95&codec=jpeg",
        None,
    )
    .await;
    let cdp = &mut page.cdp;
    cdp.wait_stats("3 frames at eye distance 0", |s| {
        s["shown"].as_u64() >= Some(3)
    })
    .await;
    let (left, right, w, h) = eye_lumas(cdp).await;
    let same = shifted_differences(&left, &right, w, h, 0)[0].1;
    eprintln!("browser (stereo, eye 0): mean luma difference between the eyes {same:.3}");
    assert!(
        same < 0.5,
        "at eye distance 0 the eyes are one view: {same:.3}"
    );
    drop(page);
    server.shutdown().await.unwrap();
}
