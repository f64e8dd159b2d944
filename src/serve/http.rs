//! The HTTP edge of `lobe serve`: a small HTTP/1.1 server on std threads ([`listen`]), replies, JSON errors,
//! query strings, and the one rule for which files a request may name ([`Roots`]). Nothing here knows about
//! formulas or scenes.
//!
//! Why not a crate: tiny_http 0.12 (the first choice) cannot set `TCP_NODELAY` and writes a response's head
//! and body separately, so every response whose body fits one segment waited for the browser's delayed ACK —
//! measured 44–48 ms per request on loopback, the whole frame budget. This server writes each response with
//! one `write_all` on a no-delay socket, which also removes four dependencies.
//!
//! Protocol subset: request line + headers (at most [`MAX_HEAD`] bytes), a `Content-Length` body (at most the
//! caller's cap; chunked request bodies are refused with 411), keep-alive per HTTP/1.1 (`Connection: close`
//! honoured, HTTP/1.0 closes). One thread per connection, at most [`MAX_CONNECTIONS`] at once (the rest get
//! 503); idle or slow connections are closed after [`IDLE`].

use crate::base::diag::{Diagnostic, Plain};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Largest request head (request line and headers).
pub(crate) const MAX_HEAD: usize = 16 << 10;
/// Connections served at once (a browser opens about six per host).
pub(crate) const MAX_CONNECTIONS: usize = 32;
/// How long a connection may sit idle, or take to send a request or read a response.
pub(crate) const IDLE: Duration = Duration::from_secs(30);

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
}

impl Request {
    /// A header's value (names compare case-insensitively).
    pub(crate) fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }
}

/// Listens on `addr` and answers every request with `handler` until the process ends. Returns the bound
/// address and the accept thread.
pub(crate) fn listen(
    addr: SocketAddr,
    body_cap: usize,
    handler: Arc<dyn Fn(&Request) -> Reply + Send + Sync>,
) -> std::io::Result<(SocketAddr, std::thread::JoinHandle<()>)> {
    let listener = TcpListener::bind(addr)?;
    let bound = listener.local_addr()?;
    let open = Arc::new(AtomicUsize::new(0));
    let accept = std::thread::Builder::new().name("lobe-serve-accept".into()).spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { continue };
            if open.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
                open.fetch_sub(1, Ordering::SeqCst);
                let busy = ApiError::new(503, "too many connections").hint("close other tabs of this page").reply();
                let _ = write_reply(&mut stream, &busy, false);
                continue;
            }
            let (open2, handler) = (open.clone(), handler.clone());
            let spawned = std::thread::Builder::new().name("lobe-serve-conn".into()).spawn(move || {
                serve_connection(stream, body_cap, handler.as_ref());
                open2.fetch_sub(1, Ordering::SeqCst);
            });
            if spawned.is_err() {
                open.fetch_sub(1, Ordering::SeqCst);
            }
        }
    })?;
    Ok((bound, accept))
}

fn serve_connection(stream: TcpStream, body_cap: usize, handler: &(dyn Fn(&Request) -> Reply + Send + Sync)) {
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(IDLE));
    let _ = stream.set_write_timeout(Some(IDLE));
    let Ok(mut out) = stream.try_clone() else { return };
    let mut input = BufReader::new(stream);
    loop {
        match read_request(&mut input, body_cap) {
            Ok(None) => return,
            Ok(Some((rq, keep))) => {
                if write_reply(&mut out, &handler(&rq), keep).is_err() || !keep {
                    return;
                }
            }
            // A malformed or oversized request: answer, close our side, and drain (boundedly) what the client
            // is still sending, so that closing does not reset the connection before it reads the answer.
            Err(e) => {
                let _ = write_reply(&mut out, &e.reply(), false);
                let _ = out.shutdown(std::net::Shutdown::Write);
                let _ = input.get_ref().set_read_timeout(Some(Duration::from_secs(1)));
                let _ = std::io::copy(&mut input.take(8 << 20), &mut std::io::sink());
                return;
            }
        }
    }
}

/// One response in one write: status line, length, headers, body.
fn write_reply(out: &mut TcpStream, r: &Reply, keep: bool) -> std::io::Result<()> {
    let mut head = format!(
        "HTTP/1.1 {} {}\r\nContent-Type: {}\r\nContent-Length: {}\r\nConnection: {}\r\n",
        r.status,
        reason(r.status),
        r.content_type,
        r.body.len(),
        if keep { "keep-alive" } else { "close" }
    );
    for (k, v) in &r.headers {
        // Header values are the server's own; a stray line break would split the response.
        if !v.contains(['\r', '\n']) {
            head.push_str(&format!("{k}: {v}\r\n"));
        }
    }
    head.push_str("\r\n");
    let mut bytes = head.into_bytes();
    bytes.extend_from_slice(&r.body);
    out.write_all(&bytes)?;
    out.flush()
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        400 => "Bad Request",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        409 => "Conflict",
        411 => "Length Required",
        413 => "Payload Too Large",
        422 => "Unprocessable Entity",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        503 => "Service Unavailable",
        _ => "",
    }
}

/// Reads one request; `Ok(None)` when the client closed (or idled out) between requests. The flag says
/// whether the connection stays open afterwards.
pub(crate) fn read_request(input: &mut dyn BufRead, body_cap: usize) -> Result<Option<(Request, bool)>, ApiError> {
    let mut head = Vec::new();
    loop {
        let before = head.len();
        let n = input
            .take((MAX_HEAD + 1 - head.len()) as u64)
            .read_until(b'\n', &mut head)
            .map_err(|_| ApiError::bad("the request could not be read"))?;
        if n == 0 {
            if head.is_empty() {
                return Ok(None);
            }
            return Err(ApiError::bad("the connection closed inside the request head"));
        }
        if head.len() > MAX_HEAD {
            return Err(ApiError::new(431, format!("the request head is larger than {} KiB", MAX_HEAD >> 10)));
        }
        let line = &head[before..];
        if line == b"\r\n" || line == b"\n" {
            if before == 0 {
                head.clear(); // tolerate blank lines between requests
                continue;
            }
            break;
        }
    }
    let text = String::from_utf8(head).map_err(|_| ApiError::bad("the request head is not UTF-8"))?;
    let mut lines = text.lines();
    let first = lines.next().unwrap_or("");
    let mut parts = first.split(' ');
    let (Some(method), Some(target), Some(version), None) = (parts.next(), parts.next(), parts.next(), parts.next()) else {
        return Err(ApiError::bad(format!("not an HTTP request line: `{}`", first.chars().take(80).collect::<String>())));
    };
    if !version.starts_with("HTTP/1.") {
        return Err(ApiError::bad(format!("unsupported protocol `{version}`")));
    }
    let mut headers = vec![];
    for l in lines.filter(|l| !l.is_empty()) {
        let (k, v) = l.split_once(':').ok_or_else(|| ApiError::bad(format!("malformed header line `{l}`")))?;
        headers.push((k.trim().to_string(), v.trim().to_string()));
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    let mut rq = Request { method: method.to_string(), path: path.to_string(), query: query.to_string(), headers, body: vec![] };
    if rq.header("Transfer-Encoding").is_some() {
        return Err(ApiError::new(411, "chunked request bodies are not accepted").hint("send Content-Length"));
    }
    let len = match rq.header("Content-Length") {
        None => 0,
        Some(v) => v.parse::<usize>().map_err(|_| ApiError::bad(format!("bad Content-Length `{v}`")))?,
    };
    if len > body_cap {
        return Err(ApiError::new(413, format!("the request body is larger than {} KiB", body_cap / 1024))
            .hint("formulas are a few lines; the server caps request bodies"));
    }
    rq.body = vec![0; len];
    input.read_exact(&mut rq.body).map_err(|_| ApiError::bad("the request body ended early"))?;
    let connection = rq.header("Connection").map(str::to_ascii_lowercase);
    let keep = match connection.as_deref() {
        Some("close") => false,
        Some("keep-alive") => true,
        _ => version == "HTTP/1.1",
    };
    Ok(Some((rq, keep)))
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
    pub(crate) fn ok_json(v: serde_json::Value) -> Reply {
        Reply::json(200, &v)
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
        let c = std::fs::canonicalize(p).map_err(|e| {
            ApiError::new(404, format!("`{requested}`: {e}")).hint("the file list on the page shows what is served")
        })?;
        if !self.dirs.iter().any(|d| c.starts_with(d)) {
            return Err(ApiError::new(403, format!("`{requested}` is outside the served directories"))
                .hint("lobe serve reads and writes only under the directories it was started with"));
        }
        Ok(c)
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

    fn parse(raw: &[u8], cap: usize) -> Result<Option<(Request, bool)>, ApiError> {
        read_request(&mut std::io::BufReader::new(raw), cap)
    }

    #[test]
    fn requests_parse_and_are_bounded() {
        let (rq, keep) = parse(b"POST /api/x?a=1 HTTP/1.1\r\nHost: h\r\nContent-Length: 3\r\n\r\nabcNEXT", 3).unwrap().unwrap();
        assert_eq!((rq.method.as_str(), rq.path.as_str(), rq.query.as_str(), rq.body.as_slice(), keep), ("POST", "/api/x", "a=1", &b"abc"[..], true));
        assert_eq!(rq.header("host"), Some("h"));
        assert!(!parse(b"GET / HTTP/1.0\r\n\r\n", 0).unwrap().unwrap().1);
        assert!(!parse(b"GET / HTTP/1.1\r\nConnection: close\r\n\r\n", 0).unwrap().unwrap().1);
        assert!(parse(b"", 0).unwrap().is_none());
        assert_eq!(parse(b"POST / HTTP/1.1\r\nContent-Length: 4\r\n\r\nabcd", 3).unwrap_err().status, 413);
        assert_eq!(parse(b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n", 3).unwrap_err().status, 411);
        assert_eq!(parse(b"POST / HTTP/1.1\r\nContent-Length: 9\r\n\r\nab", 30).unwrap_err().status, 400);
        assert_eq!(parse(b"garbage\r\n\r\n", 0).unwrap_err().status, 400);
        let long = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        assert_eq!(parse(long.as_bytes(), 0).unwrap_err().status, 431);
    }
}
