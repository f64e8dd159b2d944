//! The HTTP edge of `lobe serve`: hyper's HTTP/1.1 server on a current-thread tokio runtime ([`listen`]),
//! replies, JSON errors, query strings, and the one rule for which files a request may name ([`Roots`],
//! [`ServedFiles`]). Nothing here knows about formulas or scenes.
//!
//! Why async: with a thread per connection, 32 clients sending one byte every 10 s held every thread and
//! locked everyone else out. Here an idle or trickling connection is a few kilobytes on one reactor thread;
//! the handlers (all blocking: compiles, renders, file reads) run on tokio's blocking pool, at most
//! [`MAX_BLOCKING`] at once, never on the reactor.
//!
//! Starvation defences, each bounded:
//! - every accepted socket gets `TCP_NODELAY` (a response must not wait for the browser's delayed ACK: with
//!   tiny_http, which could not set it, that cost 44–48 ms per request on loopback);
//! - the request head must arrive within [`HEAD_TIMEOUT`] of the connection becoming ready for one — hyper's
//!   header read timer, which also runs while a keep-alive connection idles, so it is the idle timeout too;
//!   the body within [`BODY_TIMEOUT`]; a client that trickles bytes is dropped;
//! - at most [`PER_CLIENT`] connections per client address and [`MAX_CONNECTIONS`] in all. A new connection
//!   is always accepted: over a cap, the oldest connection whose request is not being answered (idle, or still
//!   sending its head or its body) is shed to make room, so slow clients cannot lock out a new one even when
//!   every client is 127.0.0.1. Only when every connection's request is being answered is the new one refused
//!   (503); the computations among those are capped by the API's job slots and deadline.
//!
//! Protocol subset: request bodies with `Content-Length` (at most the caller's cap, else 413 after draining a
//! bounded amount so the client reads the answer; chunked bodies are refused with 411), keep-alive per
//! HTTP/1.1. Build cost: tokio (rt, net, time), hyper (http1, server), hyper-util, http-body-util and the 7
//! crates they add cost ~35 s of CPU in a clean release build, off its critical path (BENCHMARKS.md §11).

use crate::base::cancel::Cancel;
use crate::base::diag::{Diagnostic, Plain};
use crate::base::source::{read_regular_file, FileAccess, ReadError};
use bytes::Bytes;
use http_body_util::{BodyExt, Full};
use hyper::body::Incoming;
use std::net::{IpAddr, SocketAddr};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Largest request head (request line and headers).
pub(crate) const MAX_HEAD: usize = 16 << 10;
/// Connections open at once, over all clients.
pub(crate) const MAX_CONNECTIONS: usize = 256;
/// Connections open at once from one client address (a browser opens about six per host).
pub(crate) const PER_CLIENT: usize = 32;
/// Handlers running at once (the blocking pool's size; computations are capped lower, by `Limits::max_jobs`).
pub(crate) const MAX_BLOCKING: usize = 32;
/// How long a connection may take to send a request head, counted from when it is ready for one (so it is
/// also how long a keep-alive connection may idle).
pub(crate) const HEAD_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a request may take to send its body.
pub(crate) const BODY_TIMEOUT: Duration = Duration::from_secs(10);
/// What is read and discarded of an oversized body before answering 413, and for how long at most.
const DRAIN_BYTES: usize = 8 << 20;
const DRAIN_TIMEOUT: Duration = Duration::from_secs(1);

/// A parsed request.
#[derive(Debug)]
pub(crate) struct Request {
    pub method: String,
    /// The path without the query.
    pub path: String,
    /// The query string after `?`, still encoded.
    pub query: String,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
    /// Trips when the client closes the connection before the answer (hyper drops the request's future: it
    /// reads the socket's end while the answer is computed): the computation answering it stops at its next
    /// poll and frees its slot, as at its deadline — the page cancels a refinement level it no longer needs by
    /// aborting its fetch.
    pub gone: Cancel,
}

impl Request {
    /// A header's value (names compare case-insensitively).
    pub(crate) fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }
}

/// What answers requests: called on the blocking pool.
pub(crate) type Handler = Arc<dyn Fn(&Request) -> Reply + Send + Sync>;

/// Listens on `addr` and answers every request with `handler` until the process ends. Returns the bound
/// address and the server's thread (the tokio runtime's).
pub(crate) fn listen(addr: SocketAddr, body_cap: usize, handler: Handler) -> std::io::Result<(SocketAddr, std::thread::JoinHandle<()>)> {
    let listener = std::net::TcpListener::bind(addr)?;
    listener.set_nonblocking(true)?;
    let bound = listener.local_addr()?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .enable_time()
        .max_blocking_threads(MAX_BLOCKING)
        .thread_name("lobe-serve-work")
        .build()?;
    let thread = std::thread::Builder::new().name("lobe-serve".into()).spawn(move || {
        rt.block_on(async move {
            let Ok(listener) = tokio::net::TcpListener::from_std(listener) else { return };
            accept_loop(listener, body_cap, handler).await
        })
    })?;
    Ok((bound, thread))
}

/// One open connection as the caps see it.
struct Slot {
    id: u64,
    ip: IpAddr,
    /// Requests of this connection being answered now, their head and body read (such a connection is never
    /// shed).
    busy: Arc<AtomicUsize>,
    task: Option<tokio::task::AbortHandle>,
}

/// The open connections, oldest first.
#[derive(Default)]
struct Table {
    slots: Vec<Slot>,
    next: u64,
}

impl Table {
    /// Admits a connection from `ip`, shedding the oldest idle ones over the caps; `None` when every
    /// connection over a cap is inside a request.
    fn admit(&mut self, ip: IpAddr) -> Option<(u64, Arc<AtomicUsize>)> {
        loop {
            let from_ip = self.slots.iter().filter(|s| s.ip == ip).count();
            let same_ip = from_ip >= PER_CLIENT;
            if !same_ip && self.slots.len() < MAX_CONNECTIONS {
                break;
            }
            let idle = self.slots.iter().position(|s| (!same_ip || s.ip == ip) && s.busy.load(Ordering::SeqCst) == 0)?;
            let shed = self.slots.remove(idle);
            if let Some(t) = shed.task {
                t.abort();
            }
        }
        self.next += 1;
        let busy = Arc::new(AtomicUsize::new(0));
        self.slots.push(Slot { id: self.next, ip, busy: busy.clone(), task: None });
        Some((self.next, busy))
    }

    fn remove(&mut self, id: u64) {
        self.slots.retain(|s| s.id != id);
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Takes a connection out of the table when its task ends (normally, or aborted when shed).
struct Leave(Arc<Mutex<Table>>, u64);

impl Drop for Leave {
    fn drop(&mut self) {
        lock(&self.0).remove(self.1);
    }
}

async fn accept_loop(listener: tokio::net::TcpListener, body_cap: usize, handler: Handler) {
    let table = Arc::new(Mutex::new(Table::default()));
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(c) => c,
            // Out of file descriptors, say: wait for connections to close rather than spin.
            Err(_) => {
                tokio::time::sleep(Duration::from_millis(20)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let mut t = lock(&table);
        let Some((id, busy)) = t.admit(peer.ip()) else {
            drop(t);
            tokio::spawn(refuse(stream));
            continue;
        };
        let leave = Leave(table.clone(), id);
        let task = tokio::spawn(connection(stream, busy, leave, body_cap, handler.clone()));
        if let Some(s) = t.slots.iter_mut().find(|s| s.id == id) {
            s.task = Some(task.abort_handle());
        }
    }
}

/// Every connection is inside a request: its first request is answered 503, then it closes.
async fn refuse(stream: tokio::net::TcpStream) {
    let service = hyper::service::service_fn(|_| async {
        let r = ApiError::new(503, "too many connections").hint("close other tabs of this page").reply();
        Ok::<_, std::convert::Infallible>(response(r))
    });
    let mut b = hyper::server::conn::http1::Builder::new();
    b.timer(hyper_util::rt::TokioTimer::new()).header_read_timeout(DRAIN_TIMEOUT).keep_alive(false);
    let _ = tokio::time::timeout(2 * DRAIN_TIMEOUT, b.serve_connection(hyper_util::rt::TokioIo::new(stream), service)).await;
}

async fn connection(stream: tokio::net::TcpStream, busy: Arc<AtomicUsize>, leave: Leave, body_cap: usize, handler: Handler) {
    let _leave = leave;
    let service = hyper::service::service_fn(move |rq: hyper::Request<Incoming>| {
        let (busy, handler) = (busy.clone(), handler.clone());
        async move { Ok::<_, std::convert::Infallible>(answer(rq, &busy, body_cap, handler).await) }
    });
    let mut b = hyper::server::conn::http1::Builder::new();
    b.timer(hyper_util::rt::TokioTimer::new()).header_read_timeout(HEAD_TIMEOUT).max_buf_size(MAX_HEAD.max(8192)).keep_alive(true);
    let _ = b.serve_connection(hyper_util::rt::TokioIo::new(stream), service).await;
}

/// Trips a request's [`Request::gone`] when dropped: when the answer is sent (the computation is over then), or
/// when the connection ends first and hyper drops the future awaiting the computation.
struct TripOnDrop(Cancel);

impl Drop for TripOnDrop {
    fn drop(&mut self) {
        self.0.cancel();
    }
}

/// Counts a request as being answered while it lives.
struct Busy(Arc<AtomicUsize>);

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

async fn answer(rq: hyper::Request<Incoming>, busy: &Arc<AtomicUsize>, body_cap: usize, handler: Handler) -> hyper::Response<Full<Bytes>> {
    let rq = match read_request(rq, body_cap).await {
        Ok(rq) => rq,
        // A refused request ends its connection: what the client sends next is not known to be a request.
        Err(e) => return response(e.reply().header("Connection", "close".into())),
    };
    // Busy (never shed) only from here: a connection still sending its head or body costs the server nothing
    // but a socket, so over a cap it goes first — a client trickling bodies cannot lock its own address out.
    busy.fetch_add(1, Ordering::SeqCst);
    let _busy = Busy(busy.clone());
    let _gone = TripOnDrop(rq.gone.clone());
    let reply = tokio::task::spawn_blocking(move || handler(&rq)).await;
    response(reply.unwrap_or_else(|_| ApiError::new(500, "internal error while answering the request").reply()))
}

/// The head as a [`Request`], and the body (at most `body_cap` bytes, within [`BODY_TIMEOUT`]).
async fn read_request(rq: hyper::Request<Incoming>, body_cap: usize) -> Result<Request, ApiError> {
    let (parts, mut body) = rq.into_parts();
    let mut headers = vec![];
    for (k, v) in &parts.headers {
        let v = v.to_str().map_err(|_| ApiError::bad(format!("the `{k}` header is not ASCII text")))?;
        headers.push((k.as_str().to_string(), v.to_string()));
    }
    let mut rq = Request {
        method: parts.method.as_str().to_string(),
        path: parts.uri.path().to_string(),
        query: parts.uri.query().unwrap_or("").to_string(),
        headers,
        body: vec![],
        gone: Cancel::untimed(),
    };
    if rq.header("Transfer-Encoding").is_some() {
        return Err(ApiError::new(411, "chunked request bodies are not accepted").hint("send Content-Length"));
    }
    let len = match rq.header("Content-Length") {
        None => 0,
        Some(v) => v.parse::<usize>().map_err(|_| ApiError::bad(format!("bad Content-Length `{v}`")))?,
    };
    let too_large = || {
        ApiError::new(413, format!("the request body is larger than {} KiB", body_cap / 1024))
            .hint("formulas are a few lines; the server caps request bodies")
    };
    let mut seen = 0usize;
    let out = &mut rq.body;
    let read = tokio::time::timeout(if len > body_cap { DRAIN_TIMEOUT } else { BODY_TIMEOUT }, async {
        while let Some(frame) = body.frame().await {
            let frame = frame.map_err(|_| ApiError::bad("the request body ended early"))?;
            if let Some(d) = frame.data_ref() {
                seen += d.len();
                if seen <= body_cap {
                    out.extend_from_slice(d);
                } else if seen > DRAIN_BYTES {
                    break;
                }
            }
        }
        Ok(())
    })
    .await;
    if seen > body_cap || len > body_cap {
        return Err(too_large());
    }
    match read {
        Err(_) => Err(ApiError::new(408, format!("the request body did not arrive within {} s", BODY_TIMEOUT.as_secs()))),
        Ok(r) => r.map(|()| rq),
    }
}

/// A [`Reply`] as hyper's response (its headers are the server's own; one that is not a valid header value
/// is left out rather than split the response).
fn response(r: Reply) -> hyper::Response<Full<Bytes>> {
    let mut b = hyper::Response::builder().status(r.status).header("Content-Type", r.content_type);
    for (k, v) in &r.headers {
        if let Ok(v) = hyper::header::HeaderValue::from_str(v) {
            b = b.header(*k, v);
        }
    }
    b.body(Full::new(Bytes::from(r.body))).unwrap_or_else(|_| {
        let mut fallback = hyper::Response::new(Full::new(Bytes::from_static(br#"{"error":"internal error: bad response"}"#)));
        *fallback.status_mut() = hyper::StatusCode::INTERNAL_SERVER_ERROR;
        fallback
    })
}

/// A response: status, content type, extra headers, body.
#[derive(Debug)]
pub(crate) struct Reply {
    pub status: u16,
    pub content_type: &'static str,
    pub headers: Vec<(&'static str, String)>,
    pub body: Vec<u8>,
}

impl Reply {
    pub(crate) fn json(status: u16, v: &serde_json::Value) -> Reply {
        Reply { status, content_type: "application/json", headers: vec![], body: v.to_string().into_bytes() }
    }
    /// A typed report as the JSON body (a serialisation failure, which lobe's report types do not have, is a 500).
    pub(crate) fn ok_report<T: serde::Serialize>(v: &T) -> Reply {
        match serde_json::to_vec(v) {
            Ok(body) => Reply { status: 200, content_type: "application/json", headers: vec![], body },
            Err(e) => Reply::json(500, &serde_json::json!({ "error": format!("cannot write JSON: {e}") })),
        }
    }
    pub(crate) fn bytes(content_type: &'static str, body: Vec<u8>) -> Reply {
        Reply { status: 200, content_type, headers: vec![], body }
    }
    pub(crate) fn header(mut self, k: &'static str, v: String) -> Reply {
        self.headers.push((k, v));
        self
    }
}

/// A refused request: an HTTP status and a JSON body `{"error", "hint", "diagnostics"}` the page shows.
/// `error` and `hint` are the [`Diagnostic`]'s message and hints in [`Plain`] words (the page has no flags);
/// `diagnostics` are [`crate::Diagnostics::to_json`] items (file, line, col, caret text), as the CLI prints.
#[derive(Debug)]
pub(crate) struct ApiError {
    pub status: u16,
    /// Boxed: the error travels in every handler's `Result`.
    pub error: Box<Diagnostic>,
    pub diagnostics: Option<serde_json::Value>,
}

impl ApiError {
    pub(crate) fn new(status: u16, error: impl Into<String>) -> ApiError {
        ApiError { status, error: Box::new(Diagnostic::error(error)), diagnostics: None }
    }
    pub(crate) fn hint(mut self, h: impl Into<String>) -> ApiError {
        self.error.hints.push(h.into().into());
        self
    }
    pub(crate) fn bad(error: impl Into<String>) -> ApiError {
        ApiError::new(400, error)
    }
    pub(crate) fn reply(&self) -> Reply {
        let mut v = serde_json::json!({ "error": self.error.text(&Plain) });
        let hints = self.error.hint_texts(&Plain);
        if !hints.is_empty() {
            v["hint"] = hints.join("; ").into();
        }
        if let Some(d) = &self.diagnostics {
            v["diagnostics"] = d.clone();
        }
        Reply::json(self.status, &v)
    }
}

/// Bad input in a formula or scene: 422 with the diagnostics.
impl From<crate::Diagnostics> for ApiError {
    fn from(ds: crate::Diagnostics) -> ApiError {
        let first = ds.errors().next().map(|d| d.text(&Plain)).unwrap_or_else(|| "invalid input".into());
        ApiError { status: 422, error: Box::new(Diagnostic::error(first)), diagnostics: Some(ds.to_json()) }
    }
}

/// A failed check (one unlocated message with its hints): 422.
impl From<Diagnostic> for ApiError {
    fn from(e: Diagnostic) -> ApiError {
        ApiError { status: 422, error: Box::new(e), diagnostics: None }
    }
}

/// Decodes `%XX` and `+` in a query component. Invalid escapes are kept as written; invalid UTF-8 is refused.
pub(crate) fn percent_decode(s: &str) -> Result<String, ApiError> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < b.len() && b[i + 1].is_ascii_hexdigit() && b[i + 2].is_ascii_hexdigit() => {
                let hex = |c: u8| (c as char).to_digit(16).unwrap_or(0) as u8;
                out.push(hex(b[i + 1]) << 4 | hex(b[i + 2]));
                i += 2;
            }
            c => out.push(c),
        }
        i += 1;
    }
    String::from_utf8(out).map_err(|_| ApiError::bad("the query is not valid UTF-8"))
}

/// `a=1&b=x%20y` → pairs, decoded, in order.
pub(crate) fn query_pairs(q: &str) -> Result<Vec<(String, String)>, ApiError> {
    q.split('&')
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (k, v) = p.split_once('=').unwrap_or((p, ""));
            Ok((percent_decode(k)?, percent_decode(v)?))
        })
        .collect()
}

/// A JSON request body.
pub(crate) fn json_body(bytes: &[u8]) -> Result<serde_json::Value, ApiError> {
    serde_json::from_slice(bytes).map_err(|e| ApiError::bad(format!("the request body is not valid JSON: {e}")))
}

/// The directories a server may read and write under, canonicalised once at start.
#[derive(Clone, Debug)]
pub(crate) struct Roots {
    dirs: Vec<PathBuf>,
}

impl Roots {
    /// Canonicalises `dirs` (each must exist).
    pub(crate) fn new(dirs: &[PathBuf]) -> Result<Roots, String> {
        let mut out: Vec<PathBuf> = vec![];
        for d in dirs {
            let c = std::fs::canonicalize(d).map_err(|e| format!("cannot serve `{}`: {e}", d.display()))?;
            if !c.is_dir() {
                return Err(format!("`{}` is not a directory", d.display()));
            }
            if !out.contains(&c) {
                out.push(c);
            }
        }
        Ok(Roots { dirs: out })
    }

    pub(crate) fn dirs(&self) -> &[PathBuf] {
        &self.dirs
    }

    /// The canonical path of an existing file named by a request, if it lies under a served directory.
    /// Refused: `..` components (400, before touching the file system), anything that does not exist (404),
    /// and a path that — after resolving symbolic links — leaves every served directory (403), which covers
    /// absolute paths elsewhere and links pointing out.
    pub(crate) fn resolve(&self, requested: &str) -> Result<PathBuf, ApiError> {
        let p = Path::new(requested);
        if requested.is_empty() {
            return Err(ApiError::bad("no file named").hint("pass a path such as examples/brdfs/phong.brdf"));
        }
        if p.components().any(|c| c == Component::ParentDir) {
            return Err(ApiError::bad(format!("`{requested}`: `..` is not allowed in paths")).hint("name files under the served directories"));
        }
        self.contains(p)
    }

    /// The canonical path of `p` if it exists and lies under a served directory once `..` and symbolic links
    /// are resolved (404 if it does not exist, 403 outside). For paths inside files (a scene's `../brdfs/…`).
    /// A path whose own text already leaves every served directory (absolute elsewhere, or `..` past the top,
    /// resolved lexically) is 403 before the file system is asked, whether or not it exists: the answer must not
    /// tell which files outside exist.
    pub(crate) fn contains(&self, p: &Path) -> Result<PathBuf, ApiError> {
        let outside = || {
            ApiError::new(403, format!("`{}` is outside the served directories", p.display()))
                .hint("the server reads and writes only under the directories it was started with")
        };
        let lexical = lexically_absolute(p).ok_or_else(outside)?;
        if !self.dirs.iter().any(|d| lexical.starts_with(d)) {
            return Err(outside());
        }
        let c = std::fs::canonicalize(p).map_err(|e| {
            ApiError::new(404, format!("`{}`: {e}", p.display())).hint("the file list on the page shows what is served")
        })?;
        if !self.dirs.iter().any(|d| c.starts_with(d)) {
            return Err(outside());
        }
        Ok(c)
    }
}

/// `p` made absolute against the working directory with `.` and `..` resolved on the text alone (no symbolic
/// links followed); `None` without a working directory.
fn lexically_absolute(p: &Path) -> Option<PathBuf> {
    let joined = if p.is_absolute() { p.to_path_buf() } else { std::env::current_dir().ok()?.join(p) };
    let mut out = PathBuf::new();
    for c in joined.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c),
        }
    }
    Some(out)
}

/// The server's [`FileAccess`] policy for everything a scene names: regular files under the [`Roots`] only.
/// It remembers whether it refused a path, so that a load that failed for that reason is answered 403 (its
/// diagnostics name the path and never show the refused file's content, which is never opened).
pub(crate) struct ServedFiles {
    roots: Roots,
    refused: AtomicBool,
}

impl ServedFiles {
    pub(crate) fn new(roots: &Roots) -> Arc<ServedFiles> {
        Arc::new(ServedFiles { roots: roots.clone(), refused: AtomicBool::new(false) })
    }

    /// Whether a path was refused for lying outside the served directories.
    pub(crate) fn refused(&self) -> bool {
        self.refused.load(Ordering::SeqCst)
    }
}

impl FileAccess for ServedFiles {
    fn read(&self, path: &Path, max: u64) -> Result<Vec<u8>, ReadError> {
        let c = self.roots.contains(path).map_err(|e| {
            if e.status == 404 {
                return ReadError::Io(std::io::Error::from(std::io::ErrorKind::NotFound));
            }
            self.refused.store(true, Ordering::SeqCst);
            ReadError::Refused("outside the directories the server was started with (name its directory there to serve it)".into())
        })?;
        read_regular_file(&c, max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_decode() {
        let q = query_pairs("file=a%2Fb.toml&set=n%3D50&x=1+2&bad=%zz&end=%4").unwrap();
        assert_eq!(q[0], ("file".into(), "a/b.toml".into()));
        assert_eq!(q[1], ("set".into(), "n=50".into()));
        assert_eq!(q[2], ("x".into(), "1 2".into()));
        assert_eq!(q[3], ("bad".into(), "%zz".into()));
        assert_eq!(q[4], ("end".into(), "%4".into()));
        assert!(query_pairs("a=%ff").is_err());
    }

    #[test]
    fn over_a_cap_the_oldest_idle_connection_is_shed() {
        let (a, b): (IpAddr, IpAddr) = ("127.0.0.1".parse().unwrap(), "127.0.0.2".parse().unwrap());
        let mut t = Table::default();
        let first = t.admit(b).unwrap();
        first.1.fetch_add(1, Ordering::SeqCst); // inside a request: never shed
        let mut ids: Vec<u64> = (0..PER_CLIENT).map(|_| t.admit(a).unwrap().0).collect();
        assert_eq!(t.slots.len(), PER_CLIENT + 1);
        // One more from `a`: its oldest idle connection goes, the other client's stays.
        let (new, _) = t.admit(a).unwrap();
        assert!(!t.slots.iter().any(|s| s.id == ids[0]) && t.slots.iter().any(|s| s.id == first.0 && s.id != new));
        ids.remove(0);
        for s in &t.slots {
            if s.ip == a {
                s.busy.fetch_add(1, Ordering::SeqCst);
            }
        }
        assert!(t.admit(a).is_none(), "every connection of `a` is inside a request: refused");
        t.remove(ids[0]);
        assert!(t.admit(a).is_some());
    }
}
