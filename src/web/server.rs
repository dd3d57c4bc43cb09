//! The live page's HTTP and WebSocket server (axum on the node's tokio runtime).
//!
//! `GET /?token=…` serves the page, `GET /ws?token=…` upgrades to the WebSocket (same origin
//! only), the page's scripts and libraries are served without a token (they hold no personal
//! data). A refused request gets a plain-text reason and is logged.

use super::access::{same_origin, Access, AccessError};
use super::state::{LiveState, Payload};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{header, HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use std::borrow::Cow;
use std::net::SocketAddr;
use std::sync::Arc;
use tokio::sync::{broadcast, oneshot};

/// Why the live page could not start.
#[derive(Debug, thiserror::Error)]
pub enum WebError {
    /// The address may not be served as asked (no token off loopback).
    #[error(transparent)]
    Access(#[from] AccessError),
    /// The address could not be bound.
    #[error("outputs.web {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
}

#[derive(Clone)]
struct Shared {
    access: Arc<Access>,
    state: Arc<LiveState>,
}

#[derive(serde::Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

/// The running server; stops when dropped.
pub struct WebServer {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<()>,
}

impl WebServer {
    /// Binds `addr` (now, so a taken port fails here) and serves `state` on `runtime`.
    pub fn start(
        addr: SocketAddr,
        token: Option<String>,
        state: Arc<LiveState>,
        runtime: &tokio::runtime::Handle,
    ) -> Result<Self, WebError> {
        let access = Access::for_address(addr, token)?;
        let bind = |e| WebError::Bind { addr, source: e };
        let listener = std::net::TcpListener::bind(addr).map_err(bind)?;
        listener.set_nonblocking(true).map_err(bind)?;
        let local = listener.local_addr().map_err(bind)?;
        let needs_token = access.needs_token();
        let app = Router::new()
            .route("/", get(page))
            .route("/ws", get(websocket))
            .fallback(get(file))
            .with_state(Shared {
                access: Arc::new(access),
                state,
            });
        let (stop, stopped) = oneshot::channel::<()>();
        let task = runtime.spawn(async move {
            let listener = match tokio::net::TcpListener::from_std(listener) {
                Ok(l) => l,
                Err(e) => {
                    tracing::error!("live page {local}: {e}");
                    return;
                }
            };
            let serve = axum::serve(listener, app).with_graceful_shutdown(async {
                let _ = stopped.await;
            });
            if let Err(e) = serve.await {
                tracing::error!("live page {local}: {e}");
            }
        });
        tracing::info!(
            url = %format!("http://{local}/"),
            token = needs_token,
            "live page up"
        );
        Ok(Self {
            addr: local,
            stop: Some(stop),
            task,
        })
    }

    /// The address served (the bound port when port 0 was asked).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for WebServer {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        // Open WebSockets would hold a graceful shutdown: end them too.
        self.task.abort();
    }
}

/// A refusal: status and a plain-text reason, logged.
fn refuse(status: StatusCode, reason: String) -> Response {
    tracing::warn!("live page: refused ({status}): {reason}");
    (
        status,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        reason,
    )
        .into_response()
}

fn header_str(headers: &HeaderMap, name: header::HeaderName) -> Option<&str> {
    headers.get(name).and_then(|v| v.to_str().ok())
}

fn unauthorised(what: &str, query: &TokenQuery) -> Response {
    let reason = match query.token {
        None => format!("{what} needs the node's --web-token: open the page with ?token=TOKEN"),
        Some(_) => format!("{what}: wrong token"),
    };
    refuse(StatusCode::UNAUTHORIZED, reason)
}

async fn page(State(s): State<Shared>, Query(q): Query<TokenQuery>) -> Response {
    if !s.access.allows(q.token.as_deref()) {
        return unauthorised("this live page", &q);
    }
    file_response("/")
}

async fn file(uri: Uri) -> Response {
    file_response(uri.path())
}

fn file_response(path: &str) -> Response {
    match super::assets::file(path) {
        Some((bytes, kind)) => {
            let headers = [
                (header::CONTENT_TYPE, kind),
                (header::CACHE_CONTROL, "no-cache"),
            ];
            match bytes {
                Cow::Borrowed(b) => (headers, b).into_response(),
                Cow::Owned(b) => (headers, b).into_response(),
            }
        }
        None => refuse(StatusCode::NOT_FOUND, format!("{path}: no such file")),
    }
}

async fn websocket(
    State(s): State<Shared>,
    Query(q): Query<TokenQuery>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    if !s.access.allows(q.token.as_deref()) {
        return unauthorised("the live page's WebSocket", &q);
    }
    let origin = header_str(&headers, header::ORIGIN);
    let host = header_str(&headers, header::HOST);
    if !same_origin(origin, host) {
        return refuse(
            StatusCode::FORBIDDEN,
            format!(
                "cross-origin WebSocket upgrade refused: Origin {} is not this page's (Host {})",
                origin.unwrap_or("-"),
                host.unwrap_or("-")
            ),
        );
    }
    let state = Arc::clone(&s.state);
    upgrade.on_upgrade(move |socket| serve_page(socket, state))
}

/// What the page sends after each frame it draws: it may be sent newer poses.
const DRAWN: &str = "drawn";

async fn send(socket: &mut WebSocket, payload: Payload) -> Result<(), axum::Error> {
    let message = match payload {
        Payload::Text(t) => Message::Text(t.as_ref().into()),
        Payload::Binary(b) => Message::Binary(b.to_vec().into()),
    };
    socket.send(message).await
}

/// Sends the latest state, then every avatar and status, until the page goes away; a page that
/// falls behind is sent the latest state again. Poses go as the page asks for them: after it
/// draws a frame it sends `drawn`, and is then sent each person's newest pose that it has not
/// had (so a page that draws slower than poses arrive shows the newest, never a backlog).
async fn serve_page(mut socket: WebSocket, state: Arc<LiveState>) {
    let mut updates = state.subscribe();
    let mut poses = state.watch_poses();
    let mut poses_sent = *poses.borrow_and_update();
    for p in state.snapshot() {
        if send(&mut socket, p).await.is_err() {
            return;
        }
    }
    // The page may be sent poses (it drew a frame since the last ones).
    let mut asked = true;
    loop {
        tokio::select! {
            changed = poses.changed(), if asked => {
                if changed.is_err() {
                    return;
                }
                poses.borrow_and_update();
                let (newest, at) = state.poses_after(poses_sent);
                poses_sent = at;
                asked = false;
                for p in newest {
                    if send(&mut socket, p).await.is_err() {
                        return;
                    }
                }
            }
            update = updates.recv() => match update {
                Ok(p) => {
                    if send(&mut socket, p).await.is_err() {
                        return;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {
                    for p in state.snapshot() {
                        if send(&mut socket, p).await.is_err() {
                            return;
                        }
                    }
                }
                Err(broadcast::error::RecvError::Closed) => return,
            },
            incoming = socket.recv() => match incoming {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return,
                Some(Ok(Message::Text(t))) if t.as_str() == DRAWN => asked = true,
                Some(Ok(_)) => {}
            },
        }
    }
}
