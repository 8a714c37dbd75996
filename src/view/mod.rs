//! `tadgs view`: an interactive 4D viewer in the browser, rendered server-side.
//!
//! A small HTTP server (axum on a two-thread tokio runtime) serves one page, embedded in the
//! binary, and renders the frames the page asks for with the project's own rasterizer
//! ([`Renderer`]). Rendering on the server rather than in WebGL means the viewer shows exactly
//! the pixels `tadgs render` writes and `tadgs eval` scores, for any backend, and needs no GPU
//! in the browser.
//!
//! The server answers only these paths; nothing in a request ever names a file:
//!
//! | path | what |
//! |---|---|
//! | `GET /` | the page (HTML, CSS and JS in one file, no external resource) |
//! | `GET /api/info` | the model and scene as JSON: frames, Gaussians, home view, dataset cameras |
//! | `GET /api/status` | open sessions, frames rendered, model version, training progress (JSON) |
//! | `GET /ws` | WebSocket: JSON [`FrameRequest`]s in, frames out (see [`session`]) |
//! | `POST /api/frame` | one [`FrameRequest`] as JSON in, the PNG or JPEG out (scripts, tests) |
//!
//! Safety: by default it listens on 127.0.0.1 only and answers only requests whose `Host` is
//! that address (a web page cannot reach it through DNS rebinding); a WebSocket or POST from
//! a page of another origin is refused (403); request bodies and WebSocket messages are
//! bounded (413 / close); a malformed request gets a 4xx and the server goes on; every
//! WebSocket session holds its state in its own task, dropped when the page closes.

pub mod renderer;

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{DefaultBodyLimit, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use glam::Vec3;
use serde::Serialize;
use tokio::sync::Semaphore;

pub use renderer::{
    FrameRequest, ImageFormat, MAX_VIEW_PIXELS, MAX_VIEW_SIDE, RenderedFrame, Renderer,
    RequestError, camera_ron, encode,
};

use crate::data::Camera;
use crate::io::camera_path::{CameraSpec, Orbit};
use crate::io::model::Model;

/// The page, embedded in the binary: the server never reads a file for a request.
pub const PAGE: &str = include_str!("page.html");

/// The largest request body or WebSocket message accepted: a frame request is a few hundred
/// bytes, so 16 KiB leaves room and stops a client from making the server buffer megabytes.
pub const MAX_REQUEST_BYTES: usize = 16 * 1024;
/// The most WebSocket sessions (browser tabs) served at once; more are refused with 429.
pub const MAX_SESSIONS: usize = 32;
/// The most `POST /api/frame` renders waiting at once; more are refused with 429.
const MAX_PENDING_RENDERS: usize = 4;
/// The JPEG quality used when a request names none.
const DEFAULT_QUALITY: u8 = 85;

/// The viewer could not start.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The address is taken or not this machine's.
    #[error("cannot listen on {address}: {source}")]
    Bind {
        /// The address asked for.
        address: SocketAddr,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The async runtime could not start (no threads left).
    #[error("cannot start the server's runtime: {0}")]
    Runtime(std::io::Error),
    /// The server stopped with an I/O error.
    #[error("the server stopped: {0}")]
    Serve(std::io::Error),
}

/// A dataset camera the page can jump to.
#[derive(Clone, Debug, Serialize)]
pub struct DatasetCamera {
    /// Index in the dataset (as `tadgs render --heldout CAM` takes it).
    pub index: usize,
    /// Held out from training (evaluated by `tadgs eval`).
    pub heldout: bool,
    /// The camera at its own image size.
    pub camera: CameraSpec,
}

/// What the page needs to know about the model (served as `/api/info`).
#[derive(Clone, Debug, Serialize)]
pub struct SceneInfo {
    /// What is shown (the input path, or the scene name).
    pub name: String,
    /// Frames in the sequence.
    pub frames: usize,
    /// Gaussians in the model.
    pub gaussians: usize,
    /// SH degree of the model.
    pub sh_degree: u32,
    /// The view the page starts from and resets to: the first camera of `tadgs render`'s
    /// default orbit.
    pub home: CameraSpec,
    /// The point the view orbits around.
    pub target: [f32; 3],
    /// World up: orbiting turns around it.
    pub up: [f32; 3],
    /// The dataset's cameras (empty for model files).
    pub cameras: Vec<DatasetCamera>,
    /// The largest frame side the server renders.
    pub max_side: u32,
    /// The largest frame the server renders, in pixels.
    pub max_pixels: u64,
}

impl SceneInfo {
    /// Describes `model` for the page: with the dataset's `cameras` (held-out ones listed in
    /// `heldout`), the home view is the first camera of the orbit around the rig, as
    /// `tadgs render --orbit` draws it; without, the orbit around the Gaussians' median.
    /// `up` replaces the orbit's up direction, as `render --up` does.
    pub fn new(
        name: &str,
        model: &Model,
        frames: usize,
        cameras: &[Camera],
        heldout: &[usize],
        up: Option<Vec3>,
    ) -> Self {
        let mut orbit = if cameras.is_empty() {
            let points: Vec<Vec3> = model
                .gaussians
                .iter()
                .map(|g| Vec3::from(g.position.mean))
                .collect();
            Orbit::around_points(&points, Vec3::NEG_Y, 960, 540)
        } else {
            Orbit::around_rig(cameras)
        };
        if let Some(up) = up.filter(|u| u.length() > 1e-6 && u.is_finite()) {
            orbit.up = up.normalize();
            orbit.start = (orbit.start - orbit.up * orbit.start.dot(orbit.up))
                .normalize_or(orbit.up.any_orthonormal_vector());
        }
        Self {
            name: name.to_string(),
            frames,
            gaussians: model.gaussians.len(),
            sh_degree: model.sh_degree,
            home: CameraSpec::of(&orbit.cameras(1)[0]),
            target: orbit.center.to_array(),
            up: orbit.up.to_array(),
            cameras: cameras
                .iter()
                .enumerate()
                .map(|(index, camera)| DatasetCamera {
                    index,
                    heldout: heldout.contains(&index),
                    camera: CameraSpec::of(camera),
                })
                .collect(),
            max_side: MAX_VIEW_SIDE,
            max_pixels: MAX_VIEW_PIXELS,
        }
    }
}

/// Where the server listens.
#[derive(Clone, Copy, Debug)]
pub struct ViewOptions {
    /// Address to bind: 127.0.0.1 keeps the viewer on this machine.
    pub host: IpAddr,
    /// Port; 0 lets the system pick a free one.
    pub port: u16,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            host: IpAddr::from([127, 0, 0, 1]),
            port: 0,
        }
    }
}

/// Where a training run shown live (`tadgs train --view`) stands; served in `/api/status`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TrainingStatus {
    /// The last iteration done.
    pub iteration: u32,
    /// The iterations of the whole run.
    pub iterations: u32,
    /// Its loss.
    pub loss: f32,
    /// The training views' PSNR (moving average), NaN until the first is known.
    pub psnr: f32,
    /// Gaussians now.
    pub gaussians: usize,
    /// The iteration of the model shown (the last [`Viewer::set_model`]).
    pub shown_iteration: u32,
}

/// What every request handler shares: the renderer and the counters.
struct Shared {
    renderer: Mutex<Renderer>,
    info: SceneInfo,
    info_json: String,
    /// Hosts accepted in the `Host` header; None accepts any (bound to a public address).
    allowed_hosts: Option<Vec<String>>,
    sessions: AtomicUsize,
    frames: AtomicU64,
    /// Bumped on every model update, so pages re-render what they show.
    version: AtomicU64,
    pending_renders: Semaphore,
    /// Set while a training run is shown live.
    training: Mutex<Option<TrainingStatus>>,
}

/// The header sent before each frame's image bytes.
#[derive(Debug, Serialize)]
struct FrameHeader {
    id: u64,
    width: u32,
    height: u32,
    time: f32,
    frame: usize,
    frames: usize,
    render_ms: f64,
    encode_ms: f64,
    total: usize,
    alive: Option<usize>,
    drawn: Option<usize>,
    format: ImageFormat,
    version: u64,
    camera_ron: String,
}

impl Shared {
    /// Renders and encodes one request (blocking: call from a blocking thread).
    fn render(&self, request: &FrameRequest) -> Result<(FrameHeader, Vec<u8>), RequestError> {
        let frames = self.info.frames;
        let (camera, time) = request.resolve(frames)?;
        let version = self.version.load(Ordering::Acquire);
        // A panic inside a render leaves nothing half-written that the next render reads (every
        // stage rewrites its buffers), so a poisoned lock is taken over.
        let frame = self
            .renderer
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .render(&camera, time);
        let start = Instant::now();
        let bytes = encode(
            &frame.image,
            request.format,
            request.quality.unwrap_or(DEFAULT_QUALITY),
        );
        self.frames.fetch_add(1, Ordering::Relaxed);
        let header = FrameHeader {
            id: request.id,
            width: camera.width,
            height: camera.height,
            time: frame.time,
            frame: frame.frame,
            frames,
            render_ms: frame.render_seconds * 1e3,
            encode_ms: start.elapsed().as_secs_f64() * 1e3,
            total: frame.total,
            alive: frame.alive,
            drawn: frame.drawn,
            format: request.format,
            version,
            camera_ron: camera_ron(&camera, frame.time),
        };
        Ok((header, bytes))
    }
}

/// A running viewer.
pub struct Viewer {
    address: SocketAddr,
    shared: Arc<Shared>,
    runtime: tokio::runtime::Runtime,
    server: tokio::task::JoinHandle<std::io::Result<()>>,
    stop: tokio::sync::oneshot::Sender<()>,
}

impl Viewer {
    /// Binds `options`' address and serves `info`'s model through `renderer` on a background
    /// runtime; returns once the port is open.
    pub fn start(
        renderer: Renderer,
        info: SceneInfo,
        options: ViewOptions,
    ) -> Result<Self, ViewError> {
        // Two threads are plenty for a few pages: the renders themselves run on blocking
        // threads and use the rayon pool.
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("tadgs-view")
            .enable_all()
            .build()
            .map_err(ViewError::Runtime)?;
        let requested = SocketAddr::new(options.host, options.port);
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(requested))
            .map_err(|source| ViewError::Bind {
                address: requested,
                source,
            })?;
        let address = listener.local_addr().map_err(|source| ViewError::Bind {
            address: requested,
            source,
        })?;
        let allowed_hosts = options.host.is_loopback().then(|| {
            let port = address.port();
            let mut hosts = vec![
                format!("localhost:{port}"),
                format!("127.0.0.1:{port}"),
                format!("[::1]:{port}"),
            ];
            hosts.push(match address.ip() {
                IpAddr::V4(ip) => format!("{ip}:{port}"),
                IpAddr::V6(ip) => format!("[{ip}]:{port}"),
            });
            hosts
        });
        let shared = Arc::new(Shared {
            renderer: Mutex::new(renderer),
            info_json: serde_json::to_string(&info).expect("the scene info serialises"),
            info,
            allowed_hosts,
            sessions: AtomicUsize::new(0),
            frames: AtomicU64::new(0),
            version: AtomicU64::new(0),
            pending_renders: Semaphore::new(MAX_PENDING_RENDERS),
            training: Mutex::new(None),
        });
        let app = router(shared.clone());
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let server = runtime.spawn(async move {
            axum::serve(listener, app)
                .with_graceful_shutdown(async {
                    stopped.await.ok();
                })
                .await
        });
        Ok(Self {
            address,
            shared,
            runtime,
            server,
            stop,
        })
    }

    /// The address the server listens on (with the port chosen when 0 was asked).
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// The page's address, to open in a browser.
    pub fn url(&self) -> String {
        let host = match self.address.ip() {
            ip if ip.is_unspecified() => "127.0.0.1".to_string(),
            IpAddr::V4(ip) => ip.to_string(),
            IpAddr::V6(ip) => format!("[{ip}]"),
        };
        format!("http://{host}:{}/", self.address.port())
    }

    /// WebSocket sessions (open pages) now.
    pub fn sessions(&self) -> usize {
        self.shared.sessions.load(Ordering::Relaxed)
    }

    /// Replaces the model shown (e.g. a newer state during training); open pages re-render.
    pub fn set_model(&self, model: &Model) {
        self.shared
            .renderer
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .set_model(model);
        self.shared.version.fetch_add(1, Ordering::AcqRel);
    }

    /// Publishes where training stands (the page shows it); cheap enough for every
    /// iteration: one uncontended lock.
    pub fn set_training(&self, status: TrainingStatus) {
        *self
            .shared
            .training
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner()) = Some(status);
    }

    /// Serves until the process is stopped (Ctrl-C) or the server fails.
    pub fn wait(self) -> Result<(), ViewError> {
        let Self {
            runtime, server, ..
        } = self;
        match runtime.block_on(server) {
            Ok(result) => result.map_err(ViewError::Serve),
            Err(join) => Err(ViewError::Serve(std::io::Error::other(join))),
        }
    }

    /// Stops the server: open connections are closed, the port is released.
    pub fn stop(self) {
        let Self {
            runtime,
            server,
            stop,
            ..
        } = self;
        stop.send(()).ok();
        // Graceful shutdown waits for open connections (an open page's WebSocket never ends
        // by itself), so the runtime's shutdown ends the rest.
        runtime.block_on(async {
            tokio::time::timeout(std::time::Duration::from_millis(200), server)
                .await
                .ok();
        });
        runtime.shutdown_background();
    }
}

/// The routes, the limits and the host and origin checks.
fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/api/info", get(info))
        .route("/api/status", get(status))
        .route("/api/frame", post(frame))
        .route("/ws", get(websocket))
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(MAX_REQUEST_BYTES))
        .layer(middleware::from_fn_with_state(shared.clone(), guard))
        .with_state(shared)
}

/// A plain-text error response.
fn refuse(status: StatusCode, message: impl Into<String>) -> Response {
    (
        status,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        message.into(),
    )
        .into_response()
}

/// Refuses requests for another host (DNS rebinding) and cross-origin pages (a page of
/// another site opening the WebSocket or posting), and marks every response uncacheable.
async fn guard(State(shared): State<Arc<Shared>>, request: Request, next: Next) -> Response {
    let headers = request.headers();
    let Some(host) = headers.get(header::HOST).and_then(|h| h.to_str().ok()) else {
        return refuse(StatusCode::BAD_REQUEST, "the request has no Host header");
    };
    if let Some(allowed) = &shared.allowed_hosts
        && !allowed.iter().any(|a| a.eq_ignore_ascii_case(host))
    {
        return refuse(
            StatusCode::FORBIDDEN,
            format!("this viewer answers only to {}", allowed.join(", ")),
        );
    }
    // A body announced larger than the limit is refused before it is read.
    let announced = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if announced.is_some_and(|length| length > MAX_REQUEST_BYTES as u64) {
        return refuse(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("requests are at most {MAX_REQUEST_BYTES} bytes"),
        );
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let same = origin
            .to_str()
            .is_ok_and(|o| o.eq_ignore_ascii_case(&format!("http://{host}")));
        if !same {
            return refuse(
                StatusCode::FORBIDDEN,
                "requests from other origins are refused",
            );
        }
    }
    let mut response = next.run(request).await;
    let headers = response.headers_mut();
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    response
}

/// The page; its Content-Security-Policy lets it load nothing but itself, its frames (blob
/// URLs) and its own server.
async fn page() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (
                header::CONTENT_SECURITY_POLICY,
                "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; \
                 img-src 'self' blob: data:; connect-src 'self'; base-uri 'none'; \
                 form-action 'none'; frame-ancestors 'none'",
            ),
        ],
        PAGE,
    )
        .into_response()
}

async fn info(State(shared): State<Arc<Shared>>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        shared.info_json.clone(),
    )
        .into_response()
}

/// Live counters: open sessions, frames rendered, model version, and the training run's
/// progress when one is shown (`null` otherwise).
async fn status(State(shared): State<Arc<Shared>>) -> Response {
    let training = *shared
        .training
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    let body = serde_json::json!({
        "sessions": shared.sessions.load(Ordering::Relaxed),
        "frames": shared.frames.load(Ordering::Relaxed),
        "version": shared.version.load(Ordering::Acquire),
        "training": training,
    });
    (
        [(header::CONTENT_TYPE, "application/json")],
        body.to_string(),
    )
        .into_response()
}

async fn not_found() -> Response {
    refuse(StatusCode::NOT_FOUND, "not found")
}

/// `POST /api/frame`: one frame as an image, its header in `X-Tadgs-Frame` (JSON without the
/// camera text).
async fn frame(State(shared): State<Arc<Shared>>, headers: HeaderMap, body: Bytes) -> Response {
    let json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !json {
        return refuse(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "send the frame request as application/json",
        );
    }
    let request: FrameRequest = match serde_json::from_slice(&body) {
        Ok(request) => request,
        Err(error) => return refuse(StatusCode::BAD_REQUEST, format!("frame request: {error}")),
    };
    let Ok(permit) = shared.pending_renders.try_acquire() else {
        return refuse(
            StatusCode::TOO_MANY_REQUESTS,
            "too many frames waiting; retry",
        );
    };
    let rendering = shared.clone();
    let result = tokio::task::spawn_blocking(move || rendering.render(&request)).await;
    drop(permit);
    match result {
        Ok(Ok((mut header, bytes))) => {
            let content_type = match header.format {
                ImageFormat::Png => "image/png",
                ImageFormat::Jpeg => "image/jpeg",
            };
            header.camera_ron.clear();
            let meta = serde_json::to_string(&header).expect("the header serialises");
            (
                [
                    (header::CONTENT_TYPE.as_str(), content_type.to_string()),
                    ("x-tadgs-frame", meta),
                ],
                bytes,
            )
                .into_response()
        }
        Ok(Err(error)) => refuse(StatusCode::BAD_REQUEST, error.to_string()),
        Err(error) => refuse(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("the render failed: {error}"),
        ),
    }
}

/// Counts an open session for as long as it lives.
struct SessionGuard(Arc<Shared>);

impl Drop for SessionGuard {
    fn drop(&mut self) {
        self.0.sessions.fetch_sub(1, Ordering::AcqRel);
    }
}

/// `GET /ws`: upgrades to a WebSocket [`session`], up to [`MAX_SESSIONS`] at once.
async fn websocket(State(shared): State<Arc<Shared>>, upgrade: WebSocketUpgrade) -> Response {
    let opened = shared
        .sessions
        .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
            (n < MAX_SESSIONS).then_some(n + 1)
        });
    if opened.is_err() {
        return refuse(
            StatusCode::TOO_MANY_REQUESTS,
            format!("{MAX_SESSIONS} pages are open already"),
        );
    }
    let guard = SessionGuard(shared.clone());
    upgrade
        .max_message_size(MAX_REQUEST_BYTES)
        .max_frame_size(MAX_REQUEST_BYTES)
        .on_upgrade(move |socket| session(socket, guard))
}

/// One page's session: reads JSON [`FrameRequest`]s and answers each with a binary message,
/// a little-endian `u32` header length, the header as JSON, then the PNG or JPEG bytes. A
/// request arriving while a frame renders replaces any older one still waiting, so a page
/// that sends faster than frames render sees the newest view, never a backlog. A malformed
/// message is answered with a JSON `{"error": …}` text message and the session goes on; a
/// message over [`MAX_REQUEST_BYTES`] closes it. When the page closes, the session's task
/// ends and its state (and its count in `/api/status`) goes with it.
async fn session(mut socket: WebSocket, guard: SessionGuard) {
    let shared = guard.0.clone();
    let mut waiting: Option<FrameRequest> = None;
    let mut rendering: Option<tokio::task::JoinHandle<Message>> = None;
    loop {
        if rendering.is_none()
            && let Some(request) = waiting.take()
        {
            let shared = shared.clone();
            rendering = Some(tokio::task::spawn_blocking(move || {
                match shared.render(&request) {
                    Ok((header, bytes)) => frame_message(&header, &bytes),
                    Err(error) => error_message(Some(request.id), &error.to_string()),
                }
            }));
        }
        let reply = tokio::select! {
            message = socket.recv() => match message {
                Some(Ok(Message::Text(text))) => match serde_json::from_str::<FrameRequest>(&text) {
                    Ok(request) => {
                        waiting = Some(request);
                        None
                    }
                    Err(error) => Some(error_message(None, &format!("frame request: {error}"))),
                },
                Some(Ok(Message::Binary(_))) => {
                    Some(error_message(None, "frame requests are JSON text messages"))
                }
                Some(Ok(Message::Ping(_) | Message::Pong(_))) => None,
                Some(Ok(Message::Close(_)) | Err(_)) | None => break,
            },
            done = async { rendering.as_mut().expect("guarded by the condition").await },
                if rendering.is_some() => {
                rendering = None;
                Some(done.unwrap_or_else(|error| {
                    error_message(None, &format!("the render failed: {error}"))
                }))
            }
        };
        if let Some(reply) = reply
            && socket.send(reply).await.is_err()
        {
            break;
        }
    }
    tracing::debug!("viewer session closed");
    drop(guard);
}

fn frame_message(header: &FrameHeader, image: &[u8]) -> Message {
    let json = serde_json::to_vec(header).expect("the header serialises");
    let mut bytes = Vec::with_capacity(4 + json.len() + image.len());
    bytes.extend_from_slice(&(json.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&json);
    bytes.extend_from_slice(image);
    Message::Binary(bytes.into())
}

fn error_message(id: Option<u64>, error: &str) -> Message {
    Message::Text(
        serde_json::json!({ "id": id, "error": error })
            .to_string()
            .into(),
    )
}

#[cfg(test)]
mod tests {
    use std::io::{Read, Write};

    use super::*;

    fn get(address: SocketAddr, path: &str) -> std::io::Result<String> {
        let mut stream = std::net::TcpStream::connect(address)?;
        write!(
            stream,
            "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
        )?;
        let mut response = String::new();
        stream.read_to_string(&mut response)?;
        Ok(response)
    }

    /// A viewer of an empty model starts on a free port, answers, and after `stop` no longer
    /// listens.
    #[test]
    fn starts_answers_and_stops() {
        let model = Model {
            gaussians: Vec::new(),
            sh_degree: 0,
            frame_count: Some(3),
            config: None,
            time_windows: None,
            shared_motion: None,
        };
        let scene = model.scene("empty", [0.0; 3]);
        let renderer = Renderer::new(&scene, &model, 3).unwrap();
        let info = SceneInfo::new("empty", &model, 3, &[], &[], None);
        assert_eq!(info.frames, 3);
        let viewer = Viewer::start(renderer, info, ViewOptions::default()).unwrap();
        let address = viewer.address();
        assert!(address.ip().is_loopback() && address.port() != 0);
        assert_eq!(viewer.url(), format!("http://{address}/"));
        let status = get(address, "/api/status").unwrap();
        assert!(status.starts_with("HTTP/1.1 200"), "{status}");
        assert!(status.contains(r#""sessions":0"#), "{status}");
        assert!(
            get(address, "/nothing")
                .unwrap()
                .starts_with("HTTP/1.1 404")
        );
        viewer.stop();
        assert!(get(address, "/api/status").is_err(), "still listening");
    }
}
