//! The accept loop: hyper's HTTP/1 server under the router, so that every connection
//! has a header-read timeout (a half-sent request is closed, not held open), counts as
//! pending against its address until its hello, and is closed by a shutdown deadline
//! whether it finished its request or not.

use super::admission::PendingSlot;
use super::hub::Hub;
use axum::extract::ConnectInfo;
use axum::Router;
use hyper::body::Incoming;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tower_service::Service as _;

/// Accepts and serves connections until `stop` turns true, then gives every connection
/// `shutdown_timeout_s` to finish and cuts the rest.
pub(crate) async fn serve(
    listener: TcpListener,
    app: Router,
    hub: Arc<Hub>,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let header_timeout = Duration::from_secs_f64(hub.config.header_timeout_s);
    let mut conns = tokio::task::JoinSet::new();
    loop {
        let (tcp, peer) = tokio::select! {
            _ = async { stop.wait_for(|s| *s).await.is_ok() } => break,
            Some(_) = conns.join_next(), if !conns.is_empty() => continue,
            r = listener.accept() => match r {
                Ok(c) => c,
                Err(e) => {
                    // Out of file descriptors, say: back off instead of spinning.
                    tracing::warn!(error = %e, "accepting a connection failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        let Some(slot) = hub.pending.try_acquire(peer.ip()) else {
            hub.telemetry.connections_refused.fetch_add(1, Relaxed);
            tracing::debug!(%peer, "too many connections without a hello from this address: closed");
            continue;
        };
        // Frames queue in the client's latest-frame slot, not in the kernel: a small
        // send buffer keeps a slow client's frames fresh instead of seconds late.
        let sock = socket2::SockRef::from(&tcp);
        if let Err(e) = sock
            .set_send_buffer_size(hub.config.send_buffer_bytes)
            .and_then(|()| tcp.set_nodelay(true))
        {
            tracing::debug!(error = %e, "setting socket options");
        }
        let slot = Arc::new(slot);
        let app = app.clone();
        let mut stop = stop.clone();
        conns.spawn(async move {
            let service = hyper::service::service_fn(move |mut req: hyper::Request<Incoming>| {
                req.extensions_mut().insert(ConnectInfo(peer));
                req.extensions_mut().insert(slot.clone());
                app.clone().call(req)
            });
            let mut builder = http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(header_timeout);
            let conn = builder
                .serve_connection(TokioIo::new(tcp), service)
                .with_upgrades();
            let mut conn = std::pin::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r {
                        tracing::debug!(%peer, error = %e, "connection ended");
                    }
                }
                _ = async { stop.wait_for(|s| *s).await.is_ok() } => {
                    conn.as_mut().graceful_shutdown();
                    let _ = conn.await;
                }
            }
        });
    }
    drop(listener);
    let deadline = Duration::from_secs_f64(hub.config.shutdown_timeout_s);
    let drained = tokio::time::timeout(deadline, async {
        while conns.join_next().await.is_some() {}
    })
    .await;
    if drained.is_err() {
        tracing::warn!(
            open = conns.len(),
            "shutdown deadline passed: closing the connections left"
        );
        conns.shutdown().await;
    }
    Ok(())
}

/// The pending place of the request's connection (absent only for requests that did
/// not come through [`serve`]).
pub(crate) type Slot = Arc<PendingSlot>;
