//! `lobe serve`: the papers' comparison program as a local web page — edit a formula with inline
//! diagnostics, move a slider per parameter and see the render follow, put two models side by side with
//! the difference heat map and the papers' numbers, and save the formula back to its file.
//!
//! Design:
//! - **HTTP**: hyper's HTTP/1.1 server on a current-thread tokio runtime ([`http::listen`]), the handlers on
//!   tokio's bounded blocking pool: an idle or trickling connection costs no thread, timeouts drop slow
//!   clients, and over the connection caps the oldest idle connection is shed, so a new client is always
//!   served (see [`http`]; hyper rather than axum: the routing is one `match`, and axum adds tower's crates).
//! - **Page**: `assets/serve/{index.html,app.js,app.css}`, plain JS, compiled in ([`page`]); no CDN.
//! - **Endpoints** ([`api`]): `/api/session`, `/api/file`, `/api/compile`, `/api/render`, `/api/compare`,
//!   `/api/plot`, `/api/analyze`, `/api/save`, the BRDF Explorer views `/api/lobe` and `/api/slice` ([`views`]),
//!   and the scriptable `GET /render.png?file=SCENE&set=n=50&size=256`, byte-identical to `lobe render`. Every
//!   refusal is JSON `{"error", "hint", "diagnostics"}` (diagnostics with file/line/col, as
//!   [`crate::Diagnostics::to_json`]), never a panic (a handler that panics anyway is caught and answered with
//!   500).
//! - **Limits** ([`Limits`]): request bodies, formula size, image side, an estimated cost budget (IR nodes ×
//!   evaluations) checked before work starts, a per-request deadline at which the computation is stopped
//!   ([`crate::base::cancel`], polled between a compile's stages and by its accuracy pass, the renderer and the
//!   numerics; the stages between polls are bounded by the size limits; [`api::limited`]), and caps on
//!   computations in flight: heavy ones (over a light cost) take slots of their own, so that they cannot
//!   starve light ones, and each computation runs on worker threads of its own, so that the cores are shared
//!   among requests by the operating system instead of one queue serving them in order.
//! - **Files**: only regular files under the directories the server was started with — the formula files'
//!   and the scene's ([`http::Roots`]: no `..` in a request, symbolic links resolved before the check;
//!   FIFOs and devices refused without blocking). Everything a scene names (meshes, formula files, measured
//!   tables) is read through the same rule ([`http::ServedFiles`], the scene loader's file-access policy);
//!   a file outside is 403. Saving is atomic ([`crate::base::output::write_atomic`]), `.brdf` only, and
//!   refused with 409 when the file changed on disk since the page loaded it.
//! - **Cross-site requests**: POSTs must carry the `X-Lobe-Client` header (a page from another origin cannot
//!   send it without a CORS preflight, which the server never approves), and on loopback the `Host` header
//!   must name a loopback host (no DNS rebinding).
//!
//! Cost model: a slider move is one render of the scene with the cached kernel (no compilation) plus PNG
//! encoding; for the paper sphere at 512² that is a few milliseconds of shading and a few of encoding
//! (BENCHMARKS.md has the measured frame time in a real browser), and a 3D lobe and image slice of a few
//! thousand kernel calls each (under a millisecond). A new formula text costs its accuracy pass: up to the
//! commands' 2 s search the first time (principled: 1.8 s), a read of the decision cache afterwards (tens of
//! milliseconds); the page debounces typing (200 ms) so a burst of keystrokes is one compile. The exact frame
//! at rest compiles with the values baked, as `lobe render` does (its pass decisions cached the same way).
//! A traced scene (an environment map, shadows) costs per camera sample: the page drags at 1 spp and at most
//! 128², then refines at rest through 1, 4, 16, … spp, each level priced against the budget before it runs
//! ([`api::render`]).

pub(crate) mod api;
pub(crate) mod http;
pub(crate) mod page;
pub(crate) mod views;

use http::{ApiError, Reply, Roots};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Resource limits for requests.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest request body.
    pub body_bytes: usize,
    /// Largest formula text.
    pub formula_bytes: usize,
    /// Largest image side.
    pub max_size: usize,
    /// Longest a computation runs: then it is stopped and the request answered 503.
    pub deadline: Duration,
    /// Heavy computations running at once (a stopped one counts until it has stopped, milliseconds after its
    /// deadline): those whose estimated cost is over `light_cost`.
    pub max_jobs: usize,
    /// Computations beyond `max_jobs` kept for light work (a compile, a small render, a save), so that heavy
    /// requests — one client's or many — leave the page answering.
    pub light_jobs: usize,
    /// The estimated cost (IR nodes × evaluations) up to which a computation is light.
    pub light_cost: f64,
    /// Largest estimated cost, in IR nodes × kernel evaluations (~1 ns each on the JIT).
    pub cost_budget: f64,
}

impl Default for Limits {
    fn default() -> Limits {
        Limits {
            body_bytes: 256 << 10,
            formula_bytes: 64 << 10,
            max_size: 2048,
            deadline: Duration::from_secs(10),
            max_jobs: 8,
            light_jobs: 8,
            light_cost: 2.0e8,
            cost_budget: 4.0e9,
        }
    }
}

/// What to serve.
#[derive(Clone, Debug, Default)]
pub struct Config {
    /// Formula files and directories; their directories are the served ones (the current directory if empty),
    /// and the scene's directory.
    pub paths: Vec<PathBuf>,
    /// The scene page renders use (default: the built-in paper sphere).
    pub scene: Option<PathBuf>,
    pub bind: Option<std::net::IpAddr>,
    pub port: u16,
    pub limits: Limits,
}

/// A running server.
pub struct Server {
    pub addr: SocketAddr,
    accept: std::thread::JoinHandle<()>,
}

impl Server {
    /// Blocks while the server runs (until the process is stopped with a signal).
    pub fn wait(self) {
        let _ = self.accept.join();
    }
}

/// Why [`start`] failed: the scene's own diagnostics, or a message (a path, the port).
#[derive(Debug)]
pub enum StartError {
    Scene(crate::Diagnostics),
    Other(String),
}

impl From<String> for StartError {
    fn from(s: String) -> StartError {
        StartError::Other(s)
    }
}

/// Checks the configuration and starts listening (loopback unless `bind` says otherwise).
pub fn start(cfg: Config) -> Result<Server, StartError> {
    let mut dirs = vec![];
    let mut files = vec![];
    for p in &cfg.paths {
        let meta = std::fs::metadata(p).map_err(|e| format!("cannot serve `{}`: {e}", p.display()))?;
        if meta.is_dir() {
            dirs.push(p.clone());
        } else {
            files.push(p.display().to_string());
            dirs.push(p.parent().filter(|d| !d.as_os_str().is_empty()).map(PathBuf::from).unwrap_or_else(|| ".".into()));
        }
    }
    if dirs.is_empty() {
        dirs.push(".".into());
    }
    let scene = match &cfg.scene {
        Some(s) => {
            let c = std::fs::canonicalize(s).map_err(|e| format!("cannot read scene `{}`: {e}", s.display()))?;
            dirs.extend(c.parent().map(PathBuf::from));
            Some(c)
        }
        None => None,
    };
    let roots = Roots::new(&dirs)?;
    if let Some(c) = &scene {
        // Fail now, with the scene's own diagnostics, rather than on the page's first frame; read as the page
        // will read it.
        let files = crate::base::source::Files::new(http::ServedFiles::new(&roots));
        crate::render::scene::load_geometry(c, None, &files).map_err(StartError::Scene)?;
    }
    let ip = cfg.bind.unwrap_or(std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST));
    let state = Arc::new(api::State::new(roots, scene, files, cfg.limits.clone()));
    let bound = Arc::new(std::sync::OnceLock::<SocketAddr>::new());
    let b2 = bound.clone();
    let handler = Arc::new(move |rq: &http::Request| handle(&state, b2.get().copied(), rq));
    let (addr, accept) = http::listen(SocketAddr::new(ip, cfg.port), cfg.limits.body_bytes, handler)
        .map_err(|e| format!("cannot listen on {ip}:{}: {e}", cfg.port))?;
    let _ = bound.set(addr);
    Ok(Server { addr, accept })
}

/// Answers one request; a panic inside a handler becomes a 500 JSON error.
fn handle(state: &Arc<api::State>, addr: Option<SocketAddr>, rq: &http::Request) -> Reply {
    let reply = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| route(state, addr, rq).unwrap_or_else(|e| e.reply())))
        .unwrap_or_else(|_| ApiError::new(500, "internal error while answering the request").reply());
    reply
        .header("Cache-Control", "no-store".into())
        .header("X-Content-Type-Options", "nosniff".into())
        .header(
            "Content-Security-Policy",
            "default-src 'self'; img-src 'self' blob: data:; connect-src 'self' blob:; style-src 'self'; script-src 'self'".into(),
        )
}

/// `Host` must name a loopback host when the server listens on loopback (DNS-rebinding defence).
fn host_ok(rq: &http::Request, addr: Option<SocketAddr>) -> bool {
    if addr.is_some_and(|a| !a.ip().is_loopback()) {
        return true;
    }
    let Some(host) = rq.header("Host") else { return false };
    let name = match host.rsplit_once(':') {
        Some((h, port)) if port.chars().all(|c| c.is_ascii_digit()) => h,
        _ => host,
    };
    matches!(name, "localhost" | "[::1]") || name.parse::<std::net::Ipv4Addr>().is_ok_and(|ip| ip.is_loopback())
}

fn route(state: &Arc<api::State>, addr: Option<SocketAddr>, rq: &http::Request) -> Result<Reply, ApiError> {
    if !host_ok(rq, addr) {
        return Err(ApiError::new(403, "the Host header does not name this loopback server").hint("open the address the server printed"));
    }
    let (method, path, query) = (rq.method.as_str(), rq.path.as_str(), rq.query.as_str());
    match (method, path) {
        ("GET", "/") | ("GET", "/index.html") => Ok(page::asset("index.html")),
        ("GET", "/app.js") => Ok(page::asset("app.js")),
        ("GET", "/app.css") => Ok(page::asset("app.css")),
        ("GET", "/api/session") => Ok(api::session(state)),
        ("GET", "/api/file") => {
            let q = http::query_pairs(query)?;
            let p = q.iter().find(|(k, _)| k == "path").map(|(_, v)| v.as_str()).unwrap_or("");
            api::file(state, p)
        }
        ("GET", "/render.png") => api::render_png(state, &rq.gone, query),
        ("POST", p) if p.starts_with("/api/") => {
            if rq.header("X-Lobe-Client").is_none() {
                return Err(ApiError::new(403, "POST requests need the X-Lobe-Client header").hint("the lobe page sends it; other sites cannot"));
            }
            let req = http::json_body(&rq.body)?;
            match p {
                "/api/compile" => api::compile(state, &rq.gone, req),
                "/api/render" => api::render(state, &rq.gone, req),
                "/api/compare" => api::compare(state, &rq.gone, req),
                "/api/plot" => api::plot(state, &rq.gone, req),
                "/api/analyze" => api::analyze(state, &rq.gone, req),
                "/api/save" => api::save(state, &req),
                "/api/lobe" => views::lobe(state, &rq.gone, req),
                "/api/slice" => views::slice(state, &rq.gone, req),
                _ => Err(ApiError::new(404, format!("no endpoint {p}"))),
            }
        }
        (m, p) => Err(ApiError::new(if matches!(m, "GET" | "POST") { 404 } else { 405 }, format!("no such page: {m} {p}"))
            .hint("open / for the page; GET /render.png?file=SCENE renders a scene")),
    }
}
