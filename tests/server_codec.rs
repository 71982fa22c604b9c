//! H.264 streams, raw debug frames, acks and the idle timeout against a real server and
//! real WebSocket clients; every H.264 frame is decoded with OpenH264's decoder.

mod server_support;

use fogcast::protocol::{FrameCodec, FrameHeader};
use futures_util::StreamExt as _;
use server_support::*;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

fn h264_hello(width: u32, height: u32) -> serde_json::Value {
    serde_json::json!({"type": "hello", "version": 1, "width": width, "height": height, "codec": "h264"})
}

/// NAL unit types in an Annex B access unit.
fn nal_types(au: &[u8]) -> Vec<u8> {
    let mut types = Vec::new();
    let mut i = 0;
    while i + 3 < au.len() {
        if au[i..i + 3] == [0, 0, 1] {
            types.push(au[i + 3] & 0x1f);
            i += 3;
        } else {
            i += 1;
        }
    }
    types
}

/// Decodes an access unit to RGB (panics when it does not decode to a picture).
fn decode(decoder: &mut openh264::decoder::Decoder, au: &[u8], w: u32, h: u32) -> image::RgbImage {
    let yuv = decoder
        .decode(au)
        .expect("the access unit decodes")
        .expect("one picture per access unit");
    use openh264::formats::YUVSource as _;
    let rgb = fogcast::protocol::yuv420_to_rgb(
        (yuv.y(), yuv.u(), yuv.v()),
        yuv.strides(),
        (w as usize, h as usize),
    );
    image::RgbImage::from_raw(w, h, rgb).unwrap()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    let mse: f64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-10)).log10()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn h264_streams_decode_and_key_frames_come_on_request() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let mut ws = connect(addr).await;
    let w = welcome(&mut ws, h264_hello(128, 72)).await;
    assert_eq!((w.codec.as_str(), w.header_bytes), ("h264", 40));
    let mut decoder = openh264::decoder::Decoder::new().unwrap();
    let mut keys = Vec::new();
    let mut last = None;
    for i in 0..12 {
        let (h, au) = next_frame(&mut ws).await;
        assert_eq!((h.codec, h.width, h.height), (FrameCodec::H264, 128, 72));
        assert!(h.target_kbps >= 150, "target {} kbit/s", h.target_kbps);
        let types = nal_types(&au);
        if i == 0 {
            assert!(h.key, "a stream starts with a key frame");
        }
        if h.key {
            // SPS (7), PPS (8) and an IDR slice (5).
            assert!(
                types.contains(&7) && types.contains(&8) && types.contains(&5),
                "{types:?}"
            );
        } else {
            assert!(types.contains(&1) && !types.contains(&5), "{types:?}");
        }
        let img = decode(&mut decoder, &au, 128, 72);
        assert!(mean_luma(&img) > 0.02, "frame {i} decodes to a picture");
        keys.push(h.key);
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": h.frame}),
        )
        .await;
        if i == 5 {
            send_json(&mut ws, serde_json::json!({"type": "keyframe"})).await;
        }
        last = Some(h);
    }
    assert!(keys[0], "{keys:?}");
    assert!(
        keys[6..].iter().any(|k| *k),
        "a key frame follows the request: {keys:?}"
    );
    assert!(
        keys.iter().filter(|k| !**k).count() >= 6,
        "between key frames the stream is P frames: {keys:?}"
    );
    assert!(last.unwrap().frame > 0);
    let m = metrics(addr).await;
    assert!(metric(&m, "fogcast_frames_encoded_total", "codec=\"h264\"") >= 12.0);
    assert!(metric(&m, "fogcast_key_frames_total", "") >= 2.0);

    // Odd sizes cannot be 4:2:0; a configure to JPEG switches codecs with a new welcome.
    let mut odd = connect(addr).await;
    send_json(&mut odd, h264_hello(127, 72)).await;
    let (e, code, _) = expect_fatal(&mut odd).await;
    assert_eq!((e.code.as_str(), code), ("invalid_hello", 4400));
    assert!(
        e.message.contains("codec h264") && e.message.contains("127x72"),
        "{}",
        e.message
    );
    send_json(
        &mut ws,
        serde_json::json!({"type": "configure", "codec": "jpeg"}),
    )
    .await;
    let w = loop {
        if let fogcast::protocol::ServerMessage::Welcome(w) = next_text(&mut ws).await {
            break w;
        }
    };
    assert_eq!(
        (w.codec.as_str(), w.reason),
        ("jpeg", fogcast::protocol::WelcomeReason::Configure)
    );
    loop {
        let (h, jpeg) = next_frame(&mut ws).await;
        if h.codec == FrameCodec::Jpeg {
            assert!(h.key && jpeg.starts_with(&[0xFF, 0xD8]));
            break;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_frames_measure_codec_quality_and_need_the_debug_switch() {
    // Off by default: the hello is refused, naming the field.
    let server = start(test_config()).await;
    let mut ws = connect(server.local_addr()).await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "hello", "version": 1, "width": 128, "height": 72, "raw_every": 2}),
    )
    .await;
    let (e, _, _) = expect_fatal(&mut ws).await;
    assert!(e.message.contains("raw_every 2"), "{}", e.message);

    let server = start(fogcast::server::config::ServerConfig {
        debug_raw_frames: true,
        ..test_config()
    })
    .await;
    for codec in ["jpeg", "h264"] {
        let mut ws = connect(server.local_addr()).await;
        welcome(
            &mut ws,
            serde_json::json!({"type": "hello", "version": 1, "width": 128, "height": 72,
                "codec": codec, "raw_every": 2, "quality": 90}),
        )
        .await;
        let mut decoder = openh264::decoder::Decoder::new().unwrap();
        let mut raw: Option<(FrameHeader, image::RgbImage)> = None;
        let mut compared = Vec::new();
        let deadline = Instant::now() + PATIENCE;
        while compared.len() < 3 {
            assert!(Instant::now() < deadline, "{codec}: raw frames in time");
            let msg = ws.next().await.unwrap().unwrap();
            let Message::Binary(b) = msg else { continue };
            let (h, payload) = FrameHeader::parse(&b).unwrap();
            let img = match h.codec {
                FrameCodec::Raw => {
                    let rgba = image::RgbaImage::from_raw(128, 72, payload.to_vec()).unwrap();
                    raw = Some((h, image::DynamicImage::ImageRgba8(rgba).to_rgb8()));
                    continue;
                }
                FrameCodec::Jpeg => decode_jpeg(payload),
                FrameCodec::H264 => decode(&mut decoder, payload, 128, 72),
            };
            if let Some((rh, r)) = raw.take() {
                // The raw copy goes out just before the frame it copies.
                assert_eq!(rh.frame, h.frame, "{codec}");
                assert_eq!(h.frame % 2, 0, "{codec}: every 2nd frame has a raw copy");
                compared.push(psnr(&r, &img));
            }
            send_json(
                &mut ws,
                serde_json::json!({"type": "ack", "frame": h.frame}),
            )
            .await;
        }
        let worst = compared.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(
            worst > 30.0,
            "{codec}: PSNR vs the raw frame {compared:?} dB"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_without_poses_are_closed_as_idle() {
    let server = start(fogcast::server::config::ServerConfig {
        idle_timeout_s: 1.0,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut quiet = connect(addr).await;
    let w = welcome(&mut quiet, hello(64, 36)).await;
    assert_eq!(w.limits.idle_timeout_s, 1.0);
    let mut busy = connect(addr).await;
    let wb = welcome(&mut busy, hello(64, 36)).await;
    let pose = wb.poses[0];
    // The busy client sends a pose every 200 ms (and acks) while the quiet one only
    // reads; after 1 s the quiet one is closed with `idle`, the busy one is not.
    let busy_task = tokio::spawn(async move {
        let started = Instant::now();
        let mut seq = 0;
        let mut frames = 0;
        while started.elapsed() < Duration::from_millis(2500) {
            seq += 1;
            send_json(
                &mut busy,
                serde_json::json!({"type": "pose", "seq": seq, "views": [pose]}),
            )
            .await;
            let until = Instant::now() + Duration::from_millis(200);
            while let Ok(Some(Ok(m))) = tokio::time::timeout_at(until.into(), busy.next()).await {
                match m {
                    Message::Binary(_) => frames += 1,
                    Message::Close(c) => panic!("the busy session was closed: {c:?}"),
                    _ => {}
                }
            }
        }
        frames
    });
    let started = Instant::now();
    let (e, code, _) = expect_fatal(&mut quiet).await;
    let after = started.elapsed().as_secs_f64();
    assert_eq!((e.code.as_str(), code), ("idle", 4408));
    assert!((0.5..5.0).contains(&after), "closed after {after:.2} s");
    let frames = busy_task.await.unwrap();
    assert!(
        frames > 5,
        "the busy session kept streaming ({frames} frames)"
    );
    let m = metrics(addr).await;
    assert_eq!(metric(&m, "fogcast_sessions_idle_total", ""), 1.0);
    assert_eq!(
        metric(&m, "fogcast_sessions_total", ""),
        metric(&m, "fogcast_sessions_closed_total", "") + metric(&m, "fogcast_sessions", ""),
        "every session accounted for"
    );
}
