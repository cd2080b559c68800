//! HTTP and WebSocket on axum.
//!
//! - `GET /?token=T`: the page (HTML with its CSS and JavaScript inlined: one request).
//! - `GET /ws?token=T`: the WebSocket. Frames go out as binary JPEG messages, everything else
//!   as JSON text ([`crate::protocol`]).
//!
//! Every request must carry the token (compared in constant time); a missing or wrong one is
//! refused with 403 before anything else. Bound to a loopback address, the server also refuses
//! a `Host` that is not a loopback name (a DNS-rebinding page cannot reach it), and a WebSocket
//! whose `Origin` is not the page's own. At most [`ServeOptions::max_clients`] pages are connected at
//! once; one more is refused with 503 and the reason. Each client is its own task: it forwards
//! the latest frame when the render thread publishes one and drops what it could not send in
//! time, so a slow or vanished client costs nothing but its own connection.

use crate::protocol::{ClientMessage, MAX_MESSAGE_BYTES, parse};
use crate::worker::{Command, Event, Frame, Worker, error_json};
use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{broadcast, watch};
use volume_pt::Scene;

/// How the viewer serves.
#[derive(Debug)]
pub struct ServeOptions {
    /// The address to listen on: 127.0.0.1 unless told otherwise.
    pub bind: IpAddr,
    /// The port (0: any free one).
    pub port: u16,
    /// Where Save writes.
    pub output: PathBuf,
    /// Pages connected at once.
    pub max_clients: usize,
    /// Connections open at once and the time each has to send its request head.
    pub limits: crate::Limits,
    /// Open Image Denoise for the page's denoise toggle, loaded when the toggle is first
    /// turned on (not at start-up: loading runs the library's code).
    pub denoiser: denoise::OnDemand,
    /// The size the view renders at, against the page's view area.
    pub resolution: crate::worker::Resolution,
    /// Whether denoising is on from the start, and until how many samples a pixel a still
    /// view is shown filtered.
    pub denoising: crate::worker::Denoising,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 8765,
            output: PathBuf::from("out/view"),
            max_clients: 4,
            denoiser: denoise::OnDemand::new(0),
            limits: crate::Limits::default(),
            resolution: crate::worker::Resolution::default(),
            // A library caller turns denoising on itself (the program and the Python module
            // start it where the library loads: `Denoising::default()`).
            denoising: crate::worker::Denoising {
                start: crate::worker::DenoiseStart::Off,
                ..crate::worker::Denoising::default()
            },
        }
    }
}

/// How long a client may take to take one message before it is dropped.
const SEND_TIMEOUT: Duration = Duration::from_secs(10);

/// What every request handler shares.
struct App {
    token: String,
    port: u16,
    loopback: bool,
    commands: Mutex<std::sync::mpsc::Sender<Command>>,
    cancel: Arc<AtomicBool>,
    frames: watch::Receiver<Option<Arc<Frame>>>,
    events: broadcast::Sender<Event>,
    clients: AtomicUsize,
    next_client: AtomicU64,
    max_clients: usize,
    page: String,
}

impl App {
    fn command(&self, c: Command) {
        // The render thread gone means the server is stopping: nothing to tell.
        let _ = self.commands.lock().map(|s| s.send(c));
    }

    /// Refuses a request without the token, or (bound to loopback) with a foreign `Host`.
    fn admit(
        &self,
        query: &HashMap<String, String>,
        headers: &HeaderMap,
    ) -> Result<(), (StatusCode, String)> {
        let given = query.get("token").map(String::as_str).unwrap_or("");
        if !constant_time_eq(given.as_bytes(), self.token.as_bytes()) {
            return Err((
                StatusCode::FORBIDDEN,
                "a missing or wrong token: open the URL gscache view printed".into(),
            ));
        }
        if self.loopback {
            let host = headers
                .get(header::HOST)
                .and_then(|h| h.to_str().ok())
                .unwrap_or("");
            let allowed = ["127.0.0.1", "localhost", "[::1]"]
                .iter()
                .any(|name| host == format!("{name}:{}", self.port));
            if !allowed {
                return Err((
                    StatusCode::FORBIDDEN,
                    format!(
                        "host `{host}`: this viewer answers only to 127.0.0.1, localhost or [::1] on port {}",
                        self.port
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Compares without stopping at the first difference, so the time taken says nothing of how
/// much of a guessed token was right.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// 128 random bits from the operating system, as 32 hex digits.
fn new_token() -> std::io::Result<String> {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// A running viewer.
pub struct Viewer {
    url: String,
    address: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    server: Option<std::thread::JoinHandle<()>>,
    worker: Option<std::thread::JoinHandle<()>>,
    commands: std::sync::mpsc::Sender<Command>,
}

impl Viewer {
    /// The URL to open, token included.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The address it listens on.
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// Stops serving and rendering, and waits for both.
    pub fn stop(mut self) {
        self.shut_down();
    }

    fn shut_down(&mut self) {
        let _ = self.commands.send(Command::Shutdown);
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(t) = self.server.take() {
            let _ = t.join();
        }
        if let Some(t) = self.worker.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.shut_down();
    }
}

/// Starts serving `scene` (`scene_text` is its file's text and `scene_file` the file, for
/// Save) and returns at once; see [`Viewer`].
pub fn serve(
    scene: Scene,
    scene_text: String,
    scene_file: PathBuf,
    options: ServeOptions,
) -> crate::Result<Viewer> {
    crate::save::check_output_folder(&options.output)?;
    let listener = std::net::TcpListener::bind((options.bind, options.port)).map_err(|source| {
        crate::ViewerError::Bind {
            address: format!("{}:{}", options.bind, options.port),
            source,
        }
    })?;
    listener.set_nonblocking(true)?;
    let address = listener.local_addr()?;
    let token = new_token()?;
    let (frames_tx, frames_rx) = watch::channel(None);
    let worker = Worker::new(
        scene,
        scene_text,
        scene_file,
        options.output.clone(),
        options.denoiser,
        options.resolution,
        frames_tx,
    )?
    .with_denoising(options.denoising);
    let (commands, command_rx) = std::sync::mpsc::channel();
    let cancel = Arc::new(AtomicBool::new(false));
    let (events, _) = broadcast::channel(64);
    let worker_thread = {
        let (cancel, events) = (cancel.clone(), events.clone());
        std::thread::Builder::new()
            .name("gscache-view-render".into())
            .spawn(move || worker.run(command_rx, cancel, events))?
    };
    let host = url_host(options.bind);
    let url = format!("http://{host}:{}/?token={token}", address.port());
    let app = Arc::new(App {
        token,
        port: address.port(),
        loopback: options.bind.is_loopback(),
        commands: Mutex::new(commands.clone()),
        cancel,
        frames: frames_rx,
        events,
        clients: AtomicUsize::new(0),
        next_client: AtomicU64::new(1),
        max_clients: options.max_clients.max(1),
        page: page(),
    });
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let limits = options.limits;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("gscache-view-net")
        .enable_all()
        .build()?;
    let server_thread = std::thread::Builder::new()
        .name("gscache-view-server".into())
        .spawn(move || {
            runtime.block_on(async move {
                let router = Router::new()
                    .route("/", get(get_page))
                    .route("/ws", get(websocket))
                    .fallback(get_page)
                    .with_state(app);
                let Ok(listener) = tokio::net::TcpListener::from_std(listener) else {
                    eprintln!("gscache view: the listening socket could not join the runtime");
                    return;
                };
                crate::connections::serve(listener, router, limits, stop_rx).await;
            });
            // Clients still connected are dropped with the runtime.
            runtime.shutdown_timeout(Duration::from_secs(1));
        })?;
    Ok(Viewer {
        url,
        address,
        stop: Some(stop_tx),
        server: Some(server_thread),
        worker: Some(worker_thread),
        commands,
    })
}

/// The host to print in the URL for a server bound to `bind`: the loopback address of the
/// same family for a loopback or unspecified address (a server on `::1` does not answer on
/// 127.0.0.1), an IPv6 address in brackets.
fn url_host(bind: IpAddr) -> String {
    match bind {
        IpAddr::V4(a) if a.is_unspecified() || a.is_loopback() => "127.0.0.1".into(),
        IpAddr::V6(a) if a.is_unspecified() || a.is_loopback() => "[::1]".into(),
        IpAddr::V4(a) => a.to_string(),
        IpAddr::V6(a) => format!("[{a}]"),
    }
}

/// The page, its CSS and JavaScript inlined.
fn page() -> String {
    include_str!("../page/index.html")
        .replace("/*STYLE*/", include_str!("../page/style.css"))
        .replace("/*SCRIPT*/", include_str!("../page/app.js"))
}

/// A plain GET: the page at `/`, 404 elsewhere, each behind the token.
async fn get_page(
    State(app): State<Arc<App>>,
    Query(query): Query<HashMap<String, String>>,
    headers: HeaderMap,
    uri: axum::http::Uri,
) -> Response {
    if let Err(refused) = app.admit(&query, &headers) {
        return refused.into_response();
    }
    if uri.path() != "/" {
        return (StatusCode::NOT_FOUND, "no such page").into_response();
    }
    (
        [
            (header::CACHE_CONTROL, "no-store"),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        ],
        Html(app.page.clone()),
    )
        .into_response()
}

/// Counts a connected client; dropping it frees the place.
struct ClientPlace(Arc<App>);

impl Drop for ClientPlace {
    fn drop(&mut self) {
        self.0.clients.fetch_sub(1, Ordering::SeqCst);
    }
}

async fn websocket(
    State(app): State<Arc<App>>,
    Query(query): Query<HashMap<String, String>>,
    headers: HeaderMap,
    upgrade: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Response {
    // The token first: a request without it learns nothing, not even that this is a WebSocket.
    if let Err(refused) = app.admit(&query, &headers) {
        return refused.into_response();
    }
    let upgrade = match upgrade {
        Ok(u) => u,
        Err(rejection) => return rejection.into_response(),
    };
    if let Some(origin) = headers.get(header::ORIGIN) {
        let host = headers
            .get(header::HOST)
            .and_then(|h| h.to_str().ok())
            .unwrap_or("");
        if origin.to_str().ok() != Some(&format!("http://{host}")) {
            return (
                StatusCode::FORBIDDEN,
                "a WebSocket from another page's origin: open the viewer's own URL",
            )
                .into_response();
        }
    }
    if app.clients.fetch_add(1, Ordering::SeqCst) >= app.max_clients {
        app.clients.fetch_sub(1, Ordering::SeqCst);
        // Said in a close frame after the upgrade: a browser's WebSocket cannot read the body
        // of a refused upgrade, so a page told "503" only showed "disconnected".
        let reason = format!(
            "{} pages are connected, the most this viewer serves: close one (or --max-clients)",
            app.max_clients
        );
        return upgrade
            .max_message_size(MAX_MESSAGE_BYTES)
            .max_frame_size(MAX_MESSAGE_BYTES)
            .on_upgrade(move |mut socket| async move {
                let frame = axum::extract::ws::CloseFrame {
                    code: 1013,
                    reason: reason.into(),
                };
                let _ = send(&mut socket, Message::Close(Some(frame))).await;
            });
    }
    let place = ClientPlace(app.clone());
    upgrade
        .max_message_size(MAX_MESSAGE_BYTES)
        .max_frame_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| client(socket, app, place))
}

/// The close frame for a message that could not be read: 1009 ("message too big") for one over
/// the size bound, 1002 (protocol error) otherwise, with the reason in words (a close reason is
/// at most 123 bytes).
fn close_frame(error: &str) -> axum::extract::ws::CloseFrame {
    let too_big = error.contains("too long") || error.contains("Space limit");
    let reason = if too_big {
        format!("a message over {MAX_MESSAGE_BYTES} bytes: the viewer takes at most that")
    } else {
        let mut text: String = format!("unreadable message: {error}");
        while text.len() > 123 {
            text.pop();
        }
        text
    };
    axum::extract::ws::CloseFrame {
        code: if too_big { 1009 } else { 1002 },
        reason: reason.into(),
    }
}

/// Sends `message`, giving up after [`SEND_TIMEOUT`]: false if the client is gone or stuck.
async fn send(socket: &mut WebSocket, message: Message) -> bool {
    matches!(
        tokio::time::timeout(SEND_TIMEOUT, socket.send(message)).await,
        Ok(Ok(()))
    )
}

/// One connected page, until it leaves.
async fn client(mut socket: WebSocket, app: Arc<App>, _place: ClientPlace) {
    let id = app.next_client.fetch_add(1, Ordering::SeqCst);
    let mut frames = app.frames.clone();
    let mut events = app.events.subscribe();
    app.command(Command::Hello { client: id });
    // Whether this page's last message was a drag's camera (its next is then not a first step).
    let mut was_dragging = false;
    loop {
        tokio::select! {
            incoming = socket.recv() => {
                let reply = match incoming {
                    None | Some(Ok(Message::Close(_))) => break,
                    Some(Err(e)) => {
                        // Said before the connection ends: a page (or a person reading its
                        // console) learns why, instead of seeing a reset.
                        let _ = send(
                            &mut socket,
                            Message::Close(Some(close_frame(&e.to_string()))),
                        )
                        .await;
                        break;
                    }
                    Some(Ok(Message::Text(text))) => match parse(text.as_str()) {
                        Ok(message) => {
                            // The frame under way is cancelled so the edit shows sooner, and so
                            // is it at a drag's first step (a full-size frame under way would
                            // hold the drag back for its whole time), but not for the rest of
                            // a drag's stream of cameras: each small frame is let finish.
                            let dragging =
                                matches!(message, ClientMessage::Camera { moving: true, .. });
                            app.command(Command::Message { client: id, message });
                            if !(dragging && was_dragging) {
                                app.cancel.store(true, Ordering::SeqCst);
                            }
                            was_dragging = dragging;
                            None
                        }
                        Err(e) => Some(error_json(&e)),
                    },
                    Some(Ok(Message::Binary(_))) => {
                        Some(error_json("a binary message: the viewer takes JSON text messages only"))
                    }
                    Some(Ok(_)) => None,
                };
                if let Some(text) = reply
                    && !send(&mut socket, Message::Text(text.into())).await
                {
                    break;
                }
            }
            changed = frames.changed() => {
                if changed.is_err() {
                    break;
                }
                let frame = frames.borrow_and_update().clone();
                if let Some(frame) = frame
                    && !(send(&mut socket, Message::Binary(frame.jpeg.clone().into())).await
                        && send(&mut socket, Message::Text(frame.stats.clone().into())).await)
                {
                    break;
                }
            }
            event = events.recv() => match event {
                Ok(e) if e.to.include(id) => {
                    if !send(&mut socket, Message::Text(e.text.as_str().into())).await {
                        break;
                    }
                }
                Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
        }
    }
    app.command(Command::Goodbye { client: id });
}
