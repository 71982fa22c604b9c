//! The HTTP side: the browser client (`clients/web/`, compiled into the binary so the
//! server runs from anywhere), `/ws`, `/healthz` and `/metrics`.

use super::hub::Hub;
use super::listen::Slot;
use super::session;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, State};
use axum::http::{header, HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Extension;
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
    slot: Option<Extension<Slot>>,
    headers: HeaderMap,
) -> Response {
    let hub = state.hub;
    // Cross-site WebSocket hijacking: a page elsewhere may not open /ws from a browser
    // (which always sends Origin; clients that are not browsers send none).
    if let Some(origin) = headers.get(header::ORIGIN) {
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        let ok = origin
            .to_str()
            .is_ok_and(|o| origin_allowed(o, host, &hub.config.allowed_origins));
        if !ok {
            tracing::info!(%peer, origin = ?origin, "cross-origin WebSocket refused");
            return (
                StatusCode::FORBIDDEN,
                "this origin may not open /ws (see allowed_origins in the server config)\n",
            )
                .into_response();
        }
    }
    let limit = hub.config.max_message_bytes * WS_LIMIT_FACTOR;
    let shutdown = state.shutdown;
    let slot = slot.map(|Extension(s)| s);
    upgrade
        .max_message_size(limit)
        .max_frame_size(limit)
        // Frames go out as soon as they are sent; the latest-frame slot is the only queue.
        .write_buffer_size(0)
        .on_upgrade(move |socket| session::run(socket, hub, peer, shutdown, slot))
}

/// Whether a browser page at `origin` may open `/ws`: the page's own origin (its host
/// is the Host header the request came to), localhost, or one of `allowed`.
fn origin_allowed(origin: &str, host: Option<&str>, allowed: &[String]) -> bool {
    if allowed.iter().any(|a| a.eq_ignore_ascii_case(origin)) {
        return true;
    }
    let Some((scheme, authority)) = origin.split_once("://") else {
        return false;
    };
    if !matches!(scheme, "http" | "https") {
        return false;
    }
    if host.is_some_and(|h| h.eq_ignore_ascii_case(authority)) {
        return true;
    }
    let name = match authority.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => authority.split(':').next().unwrap_or(""),
    };
    matches!(name, "localhost" | "127.0.0.1" | "::1")
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

async fn metrics(State(state): State<AppState>, headers: HeaderMap) -> Response {
    if let Some(want) = &state.hub.config.metrics_token {
        let given = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        if !given.is_some_and(|g| session::constant_time_eq(g.as_bytes(), want.as_bytes())) {
            return (
                StatusCode::UNAUTHORIZED,
                [(header::WWW_AUTHENTICATE, "Bearer")],
                "/metrics needs \"Authorization: Bearer <metrics_token>\"\n",
            )
                .into_response();
        }
    }
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

#[cfg(test)]
mod tests {
    use super::origin_allowed;

    #[test]
    fn origins_are_the_page_itself_localhost_or_listed() {
        let listed = ["https://fog.example.org".to_string()];
        let ok = |o: &str, host: &str| origin_allowed(o, Some(host), &listed);
        assert!(ok("http://10.0.0.5:8080", "10.0.0.5:8080"));
        assert!(ok("https://fog.example.org", "internal:8080"));
        assert!(ok("http://localhost:3000", "10.0.0.5:8080"));
        assert!(ok("http://127.0.0.1", "x"));
        assert!(ok("http://[::1]:8080", "x"));
        assert!(!ok("https://evil.example", "10.0.0.5:8080"));
        assert!(!ok("http://localhost.evil.example", "x"));
        assert!(!ok("null", "x"));
        assert!(!ok("file://", "x"));
    }
}
