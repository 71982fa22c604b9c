//! Control messages are never dropped: a configure storm (12 in one write) gets a reply
//! for each — a welcome, or a `rate_limited` error for the configures past the burst —
//! and every frame the client gets has the size of the last welcome it received.

mod server_support;

use fogcast::protocol::{FrameHeader, ServerMessage};
use futures_util::{SinkExt as _, StreamExt as _};
use server_support::*;
use tokio_tungstenite::tungstenite::Message;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_configure_storm_gets_a_reply_for_each_and_no_unannounced_frames() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let mut ws = connect(addr).await;
    let w = welcome(&mut ws, hello(64, 36)).await;
    let mut size = (w.width, w.height);
    next_frame(&mut ws).await;

    const STORM: usize = 12;
    for i in 0..STORM {
        let (w, h) = if i % 2 == 0 { (96, 54) } else { (64, 36) };
        let c = serde_json::json!({"type": "configure", "width": w, "height": h});
        ws.feed(Message::text(c.to_string())).await.unwrap();
    }
    ws.flush().await.unwrap();

    let (mut welcomes, mut limited, mut frames) = (0, 0, 0);
    while welcomes + limited < STORM {
        let msg = tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("a reply in time")
            .expect("stream open")
            .expect("no error");
        match msg {
            Message::Text(t) => match serde_json::from_str(&t).unwrap() {
                ServerMessage::Welcome(w) => {
                    welcomes += 1;
                    size = (w.width, w.height);
                }
                ServerMessage::Error(e) => {
                    assert_eq!(e.code.as_str(), "rate_limited", "{e:?}");
                    assert!(!e.fatal && e.message.contains("configure"), "{e:?}");
                    limited += 1;
                }
            },
            Message::Binary(b) => {
                let (h, _) = FrameHeader::parse(&b).unwrap();
                assert_eq!(
                    (h.width as u32, h.height as u32),
                    size,
                    "frame of an unannounced size"
                );
                frames += 1;
            }
            Message::Close(c) => panic!("closed during the storm: {c:?}"),
            _ => {}
        }
    }
    eprintln!("{welcomes} welcomes, {limited} rate_limited, {frames} frames during the storm");
    assert_eq!(welcomes + limited, STORM);
    assert!(welcomes >= 1, "the burst is applied");
    // Frames go on at the last announced size.
    for _ in 0..3 {
        let (h, _) = next_frame(&mut ws).await;
        assert_eq!((h.width as u32, h.height as u32), size);
    }
    server.shutdown().await.unwrap();
}
