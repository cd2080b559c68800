//! Accepting connections, so that no client can hold the viewer: hyper's HTTP/1 server with a
//! timeout on idle connections and on reading a request's head, and a cap on open connections.
//!
//! `axum::serve` has neither a header timeout nor a connection cap: 1000 idle sockets (half
//! sending nothing, half a partial header line) all stayed open, and with a 256-descriptor limit
//! 300 of them starved a real page. Here each connection is served by hyper's own HTTP/1
//! connection (its `header_read_timeout` on tokio's timer, for a head that has begun), and a
//! connection with no request under way is closed once it has been idle for
//! [`Limits::idle_timeout`] (from being accepted, or from its last response). When
//! [`Limits::max_connections`] are open, the one idle the longest is closed to make room, so a
//! flood of silent sockets cannot keep out a page that asks at once; a connection with a
//! request under way is never closed for another. A WebSocket leaves this count once upgraded
//! (the viewer's client limit, token and message bounds hold it).

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{Notify, oneshot, watch};
use tokio::time::Instant;
use tower::ServiceExt;

/// How many connections, and how long one may stay idle or take to send a request head.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Connections open at once (a WebSocket counts until it is upgraded).
    pub max_connections: usize,
    /// How long a connection may go without a request under way: from being accepted, or from
    /// its last response, to its next request head read whole.
    pub idle_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_connections: 64,
            idle_timeout: Duration::from_secs(10),
        }
    }
}

/// One open connection, as the accept loop and its own task see it.
struct Connection {
    /// A request is being answered: the connection is not idle.
    busy: AtomicBool,
    /// When it last became idle (accepted, or a response sent).
    idle_since: Mutex<Instant>,
    /// Closes it (to make room, or when idle too long).
    close: Notify,
}

impl Connection {
    fn idle_since(&self) -> Instant {
        *self
            .idle_since
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

/// The open connections, in the order accepted.
type Open = Arc<Mutex<Vec<(u64, Arc<Connection>)>>>;

fn lock(open: &Open) -> std::sync::MutexGuard<'_, Vec<(u64, Arc<Connection>)>> {
    // Each change is one push or one removal: the list is whole after a panic elsewhere.
    open.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Serves `router` on `listener` until `stop` fires, then lets the responses under way finish
/// (for at most a second).
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: Limits,
    mut stop: oneshot::Receiver<()>,
) {
    let open: Open = Arc::default();
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let mut next_id = 0u64;
    loop {
        let stream = tokio::select! {
            _ = &mut stop => break,
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                // Out of descriptors, or a connection reset before it was taken: go on.
                Err(_) => {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    continue;
                }
            },
        };
        // Frames go out as soon as they are written (each is a JPEG and a line of stats):
        // without this, Nagle's algorithm held them back by tens of milliseconds.
        let _ = stream.set_nodelay(true);
        next_id += 1;
        let connection = Arc::new(Connection {
            busy: AtomicBool::new(false),
            idle_since: Mutex::new(Instant::now()),
            close: Notify::new(),
        });
        {
            let mut open = lock(&open);
            if open.len() >= limits.max_connections.max(1) {
                let longest_idle = open
                    .iter()
                    .enumerate()
                    .filter(|(_, (_, c))| !c.busy.load(Ordering::SeqCst))
                    .min_by_key(|(_, (_, c))| c.idle_since())
                    .map(|(at, _)| at);
                match longest_idle {
                    Some(at) => open.remove(at).1.close.notify_one(),
                    // Every connection has a request under way: this one is refused.
                    None => continue,
                }
            }
            open.push((next_id, connection.clone()));
        }
        tokio::spawn(serve_connection(
            stream,
            next_id,
            connection,
            router.clone(),
            limits,
            open.clone(),
            shutdown_rx.clone(),
        ));
    }
    let _ = shutdown_tx.send(true);
    // The connections' tasks see the signal and finish their responses.
    for _ in 0..100 {
        if lock(&open).is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Serves one connection until it ends, is closed to make room, stays idle too long, or the
/// server stops (then gracefully: a response under way is finished).
async fn serve_connection(
    stream: tokio::net::TcpStream,
    id: u64,
    connection: Arc<Connection>,
    router: Router,
    limits: Limits,
    open: Open,
    mut shutdown: watch::Receiver<bool>,
) {
    let service = {
        let connection = connection.clone();
        tower::service_fn(
            move |request: axum::extract::Request<hyper::body::Incoming>| {
                let (connection, router) = (connection.clone(), router.clone());
                async move {
                    connection.busy.store(true, Ordering::SeqCst);
                    let response = router.oneshot(request.map(axum::body::Body::new)).await;
                    *connection
                        .idle_since
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner) = Instant::now();
                    connection.busy.store(false, Ordering::SeqCst);
                    response
                }
            },
        )
    };
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.idle_timeout);
    let served = builder
        .serve_connection(TokioIo::new(stream), TowerToHyperService::new(service))
        .with_upgrades();
    tokio::pin!(served);
    let idle_check = tokio::time::sleep(limits.idle_timeout);
    tokio::pin!(idle_check);
    loop {
        tokio::select! {
            _ = served.as_mut() => break,
            _ = connection.close.notified() => break,
            _ = &mut idle_check => {
                let deadline = connection.idle_since() + limits.idle_timeout;
                if !connection.busy.load(Ordering::SeqCst) && Instant::now() >= deadline {
                    break;
                }
                let next = if connection.busy.load(Ordering::SeqCst) {
                    Instant::now() + limits.idle_timeout
                } else {
                    deadline
                };
                idle_check.as_mut().reset(next);
            }
            changed = shutdown.changed() => {
                if changed.is_err() || *shutdown.borrow() {
                    served.as_mut().graceful_shutdown();
                    let _ = tokio::time::timeout(Duration::from_secs(1), served.as_mut()).await;
                    break;
                }
            }
        }
    }
    lock(&open).retain(|(i, _)| *i != id);
}
