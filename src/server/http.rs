//! The HTTP side: the browser client (`clients/web/`, compiled into the binary so the
//! server runs from anywhere), `/ws`, `/healthz` and `/metrics`.

use super::hub::{ConnectionGuard, Hub};
use super::session;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, State};
use axum::http::{header, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use std::net::SocketAddr;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use tokio::sync::watch;

/// The browser client's files: path, content type, contents.
const WEB_FILES: &[(&str, &str, &str)] = &[
    (
        "/",
        "text/html; charset=utf-8",
        include_str!("../../clients/web/index.html"),
    ),
    (
        "/app.js",
        "text/javascript; charset=utf-8",
        include_str!("../../clients/web/app.js"),
    ),
    (
        "/style.css",
        "text/css; charset=utf-8",
        include_str!("../../clients/web/style.css"),
    ),
];

/// WebSocket-layer message limit as a multiple of the protocol's: between the two the
/// session answers with a clear `message_too_large` error; beyond it the socket is cut.
const WS_LIMIT_FACTOR: usize = 4;

#[derive(Clone)]
pub(crate) struct AppState {
    pub(crate) hub: Arc<Hub>,
    pub(crate) shutdown: watch::Receiver<bool>,
}

pub(crate) fn router(state: AppState) -> Router {
    Router::new()
        .route("/ws", get(ws))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .fallback(get(web_file))
        .with_state(state)
}

async fn ws(
    upgrade: WebSocketUpgrade,
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
) -> Response {
    let hub = state.hub;
    let Some(conn) = ConnectionGuard::try_new(&hub.telemetry, hub.config.max_connections) else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            "too many connections; try again later\n",
        )
            .into_response();
    };
    let limit = hub.config.max_message_bytes * WS_LIMIT_FACTOR;
    let shutdown = state.shutdown;
    upgrade
        .max_message_size(limit)
        .max_frame_size(limit)
        // Frames go out as soon as they are sent; the latest-frame slot is the only queue.
        .write_buffer_size(0)
        .on_upgrade(move |socket| session::run(socket, hub, peer, shutdown, conn))
}

async fn healthz(State(state): State<AppState>) -> Response {
    let hub = &state.hub;
    let (sessions, views) = hub.counts();
    let health = hub.health();
    let status = if health.reasons.is_empty() {
        "ok"
    } else {
        "degraded"
    };
    let body = serde_json::json!({
        "status": status,
        "reasons": health.reasons,
        "rendering": health.rendering,
        "render_errors": hub.telemetry.render_errors.load(Relaxed),
        "panics": hub.telemetry.render_panics.load(Relaxed) + hub.telemetry.encode_panics.load(Relaxed),
        "scene": hub.scene.name,
        "sessions": sessions,
        "viewers": views,
        "max_viewers": hub.config.max_views,
        "frames": hub.telemetry.frames.load(Relaxed),
        "frames_sent": hub.telemetry.frames_sent.load(Relaxed),
        "frames_dropped": hub.telemetry.frames_dropped(),
        "uptime_s": hub.started.elapsed().as_secs_f64(),
    });
    // 503 only when nobody can get frames (the render loop stopped or hangs), so a load
    // balancer takes the instance out; failed renders of some sizes leave it in (200).
    let code = if health.rendering {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (
        code,
        [(header::CACHE_CONTROL, "no-store")],
        axum::Json(body),
    )
        .into_response()
}

async fn metrics(State(state): State<AppState>) -> Response {
    let (sessions, views) = state.hub.counts();
    let text = state.hub.telemetry.export(sessions, views);
    (
        [
            (
                header::CONTENT_TYPE,
                "text/plain; version=0.0.4; charset=utf-8",
            ),
            (header::CACHE_CONTROL, "no-store"),
        ],
        text,
    )
        .into_response()
}

async fn web_file(uri: Uri) -> Response {
    let path = match uri.path() {
        "/index.html" => "/",
        p => p,
    };
    match WEB_FILES.iter().find(|(p, _, _)| *p == path) {
        Some((_, content_type, body)) => (
            [
                (header::CONTENT_TYPE, *content_type),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            *body,
        )
            .into_response(),
        None => (StatusCode::NOT_FOUND, "not found\n").into_response(),
    }
}
