//! `lobe serve` end to end: the real binary on a free loopback port, spoken to over plain HTTP.
//!
//! - `/render.png` is byte-identical to `lobe render` of the same scene and settings;
//! - traversal (`..`, absolute paths outside, symbolic links out) gets 4xx, a POST without the page's header
//!   and a foreign `Host` get 403, oversized bodies, formulas and images are refused, and bad formulas come
//!   back as JSON diagnostics with line and column;
//! - saving is atomic, `.brdf` only, and refused with 409 when the file changed on disk since it was loaded;
//! - the page in a real headless Chromium: `browser.rs`.

use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A `lobe serve` child process, killed on drop.
pub(crate) struct Served {
    child: Child,
    pub(crate) addr: SocketAddr,
}

impl Served {
    pub(crate) fn start(args: &[&str]) -> Served {
        let mut child = Command::new(env!("CARGO_BIN_EXE_lobe"))
            .arg("serve")
            .args(args)
            .args(["--port", "0"])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start lobe serve");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        let addr = line
            .trim()
            .strip_prefix("lobe serve: http://")
            .and_then(|s| s.strip_suffix('/'))
            .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
            .parse()
            .unwrap();
        Served { child, addr }
    }
    pub(crate) fn get(&self, path: &str) -> Resp {
        http(self.addr, "GET", path, &[], None)
    }
    pub(crate) fn post(&self, path: &str, body: &Value) -> Resp {
        http(self.addr, "POST", path, &[("X-Lobe-Client", "test"), ("Content-Type", "application/json")], Some(body.to_string().as_bytes()))
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub(crate) struct Resp {
    pub(crate) status: u16,
    headers: Vec<(String, String)>,
    pub(crate) body: Vec<u8>,
}

impl Resp {
    pub(crate) fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }
    fn header(&self, k: &str) -> Option<&str> {
        self.headers.iter().find(|(h, _)| h.eq_ignore_ascii_case(k)).map(|(_, v)| v.as_str())
    }
}

/// A minimal HTTP/1.1 client (one request per connection), enough for lobe serve and chromedriver.
pub(crate) fn http(addr: SocketAddr, method: &str, path: &str, headers: &[(&str, &str)], body: Option<&[u8]>) -> Resp {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let body = body.unwrap_or(b"");
    let mut req = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n", body.len());
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    // Read the head, then exactly Content-Length bytes (chromedriver keeps connections open), else chunks or
    // everything up to the close.
    let mut raw = vec![];
    let mut buf = [0u8; 65536];
    let split = loop {
        if let Some(p) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
            break p;
        }
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "connection closed before the response head");
        raw.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let headers: Vec<(String, String)> =
        lines.filter_map(|l| l.split_once(':')).map(|(k, v)| (k.trim().to_string(), v.trim().to_string())).collect();
    let mut body = raw[split + 4..].to_vec();
    let len = headers.iter().find(|(k, _)| k.eq_ignore_ascii_case("content-length")).and_then(|(_, v)| v.parse::<usize>().ok());
    let chunked = headers.iter().any(|(k, v)| k.eq_ignore_ascii_case("transfer-encoding") && v.contains("chunked"));
    match len {
        Some(len) if !chunked => {
            while body.len() < len {
                let n = s.read(&mut buf).unwrap();
                assert!(n > 0, "connection closed after {} of {len} body bytes", body.len());
                body.extend_from_slice(&buf[..n]);
            }
            body.truncate(len);
        }
        _ => {
            s.read_to_end(&mut body).unwrap();
            if chunked {
                body = dechunk(&body);
            }
        }
    }
    Resp { status, headers, body }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = vec![];
    while let Some(eol) = b.windows(2).position(|w| w == b"\r\n") {
        let n = usize::from_str_radix(String::from_utf8_lossy(&b[..eol]).split(';').next().unwrap().trim(), 16).unwrap_or(0);
        if n == 0 {
            break;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
    out
}

pub(crate) fn scratch(tag: &str) -> PathBuf {
    crate::scratch_dir("serve", tag)
}

pub(crate) fn cli_render(scene: &Path, set: &str, size: &str, out: &Path) -> Vec<u8> {
    cli_render_with(scene, &["--set", set, "--size", size], out)
}

/// `lobe render SCENE ARGS… -q --force -o OUT`, its PNG bytes.
pub(crate) fn cli_render_with(scene: &Path, args: &[&str], out: &Path) -> Vec<u8> {
    let o = Command::new(env!("CARGO_BIN_EXE_lobe"))
        .arg("render")
        .arg(scene)
        .args(args)
        .args(["-q", "--force", "-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read(out).unwrap()
}

#[test]
fn render_png_is_the_cli_render_byte_for_byte() {
    let d = scratch("bytes");
    let s = Served::start(&["examples"]);
    for (scene, set, size) in [("examples/scenes/paper_sphere.toml", "n=50", "256"), ("examples/scenes/torus.toml", "n=200", "200x120"),
        // A colour (RGB) formula: one kernel per channel on the page as in the CLI.
        ("examples/scenes/principled.toml", "n=50", "96")] {
        let r = s.get(&format!("/render.png?file={scene}&set={set}&size={size}"));
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        assert_eq!(r.header("Content-Type"), Some("image/png"));
        let cli = cli_render(Path::new(scene), set, size, &d.join("cli.png"));
        assert!(r.body == cli, "{scene}: /render.png ({} bytes) differs from lobe render ({} bytes)", r.body.len(), cli.len());
    }
    assert_eq!(s.addr.ip().to_string(), "127.0.0.1", "the default address");
    // --bind is honoured (another loopback address, so the test opens nothing to the network).
    let other = Served::start(&["examples", "--bind", "127.0.0.2"]);
    assert_eq!(other.addr.ip().to_string(), "127.0.0.2");
    assert_eq!(other.get("/api/session").status, 200);
    // An absolute path inside a served directory is fine too.
    let abs = std::fs::canonicalize("examples/scenes/paper_sphere.toml").unwrap();
    assert_eq!(s.get(&format!("/render.png?file={}&size=64", abs.display())).status, 200);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn traversal_and_foreign_requests_are_refused() {
    let d = scratch("traversal");
    let served = d.join("served");
    std::fs::create_dir_all(&served).unwrap();
    std::fs::write(d.join("secret.brdf"), "NH^n # outside\n").unwrap();
    std::fs::write(served.join("mine.brdf"), "VR^n\n").unwrap();
    std::os::unix::fs::symlink(d.join("secret.brdf"), served.join("link.brdf")).unwrap();
    std::os::unix::fs::symlink(&d, served.join("up")).unwrap();
    let s = Served::start(&[served.to_str().unwrap()]);
    let inside = served.join("mine.brdf");
    assert_eq!(s.get(&format!("/api/file?path={}", inside.display())).status, 200);
    for (path, want) in [
        (format!("{}/../secret.brdf", served.display()), 400),
        ("../../etc/passwd".to_string(), 400),
        ("/etc/passwd".to_string(), 403),
        (d.join("secret.brdf").display().to_string(), 403),
        (served.join("link.brdf").display().to_string(), 403),
        (served.join("up/secret.brdf").display().to_string(), 403),
        (served.join("missing.brdf").display().to_string(), 404),
    ] {
        for url in [format!("/api/file?path={path}"), format!("/render.png?file={path}")] {
            let r = s.get(&url);
            assert_eq!(r.status, want, "{url}: {}", String::from_utf8_lossy(&r.body));
            assert!(r.json()["error"].as_str().is_some_and(|e| !e.is_empty()));
        }
        let r = s.post("/api/save", &json!({"path": path, "text": "NH^n", "force": true}));
        assert_eq!(r.status, want, "save {path}");
    }
    assert_eq!(std::fs::read_to_string(d.join("secret.brdf")).unwrap(), "NH^n # outside\n");
    // Cross-site: a POST without the page's header, and a Host that is not loopback (DNS rebinding).
    let r = http(s.addr, "POST", "/api/compile", &[], Some(br#"{"text":"NH^n"}"#));
    assert_eq!(r.status, 403);
    let mut raw = TcpStream::connect(s.addr).unwrap();
    raw.write_all(b"GET /api/session HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n").unwrap();
    let mut got = String::new();
    raw.read_to_string(&mut got).unwrap();
    assert!(got.starts_with("HTTP/1.1 403"), "{got}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn saving_is_atomic_and_refuses_files_changed_on_disk() {
    let (d, name) = (scratch("save"), "model.brdf");
    std::fs::write(d.join("notes.txt"), "keep").unwrap();
    let f = d.join(name);
    std::fs::write(&f, "NH^n\n").unwrap();
    let s = Served::start(&[f.to_str().unwrap()]);
    let session = s.get("/api/session").json();
    assert_eq!(session["open"], json!(f.to_str().unwrap()));
    let loaded = s.get(&format!("/api/file?path={}", f.display())).json();
    let hash = loaded["hash"].as_str().unwrap().to_string();
    let r = s.post("/api/save", &json!({"path": f, "text": "VR^n\n", "hash": hash}));
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "VR^n\n");
    let hash2 = r.json()["hash"].as_str().unwrap().to_string();
    // Someone edits the file; the page's hash is now stale.
    std::fs::write(&f, "NH^(2*n)\n").unwrap();
    let r = s.post("/api/save", &json!({"path": f, "text": "NH^n\n", "hash": hash2}));
    assert_eq!(r.status, 409);
    assert!(r.json()["error"].as_str().unwrap().contains("changed on disk"));
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "NH^(2*n)\n");
    let r = s.post("/api/save", &json!({"path": f, "text": "NH^n\n", "hash": hash2, "force": true}));
    assert_eq!(r.status, 200);
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "NH^n\n");
    // Only .brdf files; nothing else in the directory is touched, no temporaries are left.
    let r = s.post("/api/save", &json!({"path": d.join("notes.txt"), "text": "x", "force": true}));
    assert_eq!(r.status, 403);
    assert_eq!(std::fs::read_to_string(d.join("notes.txt")).unwrap(), "keep");
    let names: Vec<String> = std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(names.len(), 2, "{names:?}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_and_oversized_requests_get_json_errors() {
    let s = Served::start(&["examples/brdfs"]);
    // A formula error: 422 with the CLI's diagnostics (file, line, column, caret text).
    let r = s.post("/api/compile", &json!({"name": "x.brdf", "text": "param a = 2 in 1..5\nNH^n * (a +\n"}));
    assert_eq!(r.status, 422);
    let d = &r.json()["diagnostics"][0];
    assert_eq!((d["file"].as_str(), d["line"].as_u64()), (Some("x.brdf"), Some(2)), "{d}");
    assert!(d["col"].as_u64().is_some() && d["rendered"].as_str().unwrap().contains("x.brdf:2:"), "{d}");
    // Out-of-range parameter on a render: the scene loader's range message.
    let r = s.post("/api/render", &json!({"text": "NH^n", "params": {"n": 5000}, "size": 64}));
    assert_eq!(r.status, 422, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(s.post("/api/render", &json!({"text": "NH^n", "size": 100000})).status, 400);
    assert_eq!(s.get("/render.png?file=examples/brdfs/phong.brdf&size=100000").status, 400);
    assert_eq!(s.post("/api/render", &json!({"text": "x".repeat(100 << 10)})).status, 413);
    let big = format!("{{\"text\": \"{}\"}}", "x".repeat(1 << 20));
    let r = http(s.addr, "POST", "/api/render", &[("X-Lobe-Client", "t")], Some(big.as_bytes()));
    assert_eq!(r.status, 413);
    assert_eq!(s.post("/api/render", &json!({"nope": 1})).status, 400);
    let r = http(s.addr, "POST", "/api/render", &[("X-Lobe-Client", "t")], Some(b"{not json"));
    assert_eq!(r.status, 400);
    // A formula far over the cost budget at the largest size is refused before it runs.
    let heavy: String = (0..3000).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0";
    let t = Instant::now();
    let r = s.post("/api/render", &json!({"text": heavy, "size": 2048}));
    assert_eq!(r.status, 422, "{}", String::from_utf8_lossy(&r.body));
    assert!(r.json()["error"].as_str().unwrap().contains("budget"));
    eprintln!("heavy formula refused in {:?}", t.elapsed());
    // The server is still there.
    assert_eq!(s.get("/api/session").status, 200);
}

#[test]
fn live_render_compare_plot_and_analysis_answer() {
    let s = Served::start(&["examples/brdfs"]);
    let r = s.post("/api/render", &json!({"text": "VR^n", "params": {"n": 50}, "size": 128}));
    assert_eq!(r.status, 200);
    let img = lobe::base::image::Image::decode_png(&r.body).unwrap();
    assert_eq!((img.width, img.height), (128, 128));
    let r2 = s.post("/api/render", &json!({"text": "VR^n", "params": {"n": 5}, "size": 128}));
    assert_ne!(r.body, r2.body, "a new parameter value changes the image");
    let r = s.post("/api/compare", &json!({"a": {"text": "VR^n"}, "b": {"text": "NH^n"}, "params": {"n": 20}, "size": 96}));
    assert_eq!(r.status, 200);
    let m: Value = serde_json::from_str(r.header("X-Lobe-Metrics").unwrap()).unwrap();
    assert!(m["manhattan"].as_f64().unwrap() > 0.0, "{m}");
    assert!(lobe::base::image::Image::decode_png(&r.body).unwrap().width > 3 * 96);
    let r = s.post("/api/plot", &json!({"formulas": [{"text": "VR^n"}, {"text": "NH^n"}], "params": {"n": 20}, "polar": true}));
    assert_eq!(r.status, 200);
    let r = s.post("/api/analyze", &json!({"text": "VR^n", "params": {"n": 10}, "reference": {"text": "NH^n"}}));
    let a = r.json();
    // Phong's coefficient is (n+2)/(2π) exactly.
    assert!((a["coef"].as_f64().unwrap() - 12.0 / (2.0 * std::f64::consts::PI)).abs() < 1e-6, "{a}");
    assert!(a["jit_ns"].as_f64().unwrap() > 0.0 && a["mean_abs_grid"].as_f64().is_some(), "{a}");
    // A formula that reads no n: no papers' sweep and no lobe coefficient, the hemisphere's metrics instead.
    let ggx = "param alpha = 0.3 in 0.01..1\nalpha^2 / (3.14159265 * (NH*NH*(alpha^2 - 1) + 1)^2) / (4*NL*NV)\n";
    let r = s.post("/api/analyze", &json!({"text": ggx, "reference": {"text": "NH^n"}}));
    let a = r.json();
    assert!(a.get("mean_abs_grid").is_none() && a["coef_error"].as_str().is_some_and(|e| e.contains("one cosine")), "{a}");
    let h = &a["hemisphere"];
    assert!(h["entries"].as_u64().unwrap() > 10_000 && h["log"].as_f64().unwrap() > 0.0 && h["cosine"].as_f64().unwrap() > 0.0, "{a}");
}

#[test]
fn a_slow_request_does_not_hold_up_the_page() {
    let s = Served::start(&["examples/brdfs"]);
    // ~600 IR nodes at 2048² (a comparison): under the cost budget even when the accuracy pass's choice grows
    // the kernel by its budget (1.3×), most of a second of work.
    let heavy: String = (0..150).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0";
    let addr = s.addr;
    let body = json!({"a": {"text": heavy}, "b": {"text": "NH^n"}, "size": 2048}).to_string();
    let slow = std::thread::spawn(move || http(addr, "POST", "/api/compare", &[("X-Lobe-Client", "t")], Some(body.as_bytes())).status);
    std::thread::sleep(Duration::from_millis(300));
    // Meanwhile the page's own requests are answered: a frame, a compile, the session.
    for n in [10, 20, 30] {
        assert_eq!(s.post("/api/render", &json!({"text": "VR^n", "params": {"n": n}, "size": 128})).status, 200);
    }
    assert_eq!(s.post("/api/compile", &json!({"text": "NH^n"})).status, 200);
    assert_eq!(s.get("/api/session").status, 200);
    let still_running = !slow.is_finished();
    let status = slow.join().unwrap();
    assert!(status == 200 || status == 503, "slow comparison: {status}");
    assert!(still_running, "the slow comparison (~100× the work of the others) was expected to be still running");
}

#[test]
fn bad_command_lines_fail_cleanly() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    for (args, says) in [
        (vec!["serve", "no/such/dir"], "cannot serve `no/such/dir`"),
        (vec!["serve", "--scene", "examples/brdfs/phong.brdf", "examples"], "phong.brdf:3:7"),
        // The scene's mesh is in examples/meshes, which is not served.
        (vec!["serve", "examples/brdfs", "--scene", "examples/scenes/mesh.toml"], "bumpy.obj: outside the directories"),
        (vec!["serve", "examples", "--port", &port], "cannot listen on 127.0.0.1"),
        (vec!["serve", "--bind", "localhost.example"], "invalid value"),
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_lobe")).args(&args).stdin(Stdio::null()).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

/// The issue's functional bound: a new client is answered within 1 s while others hold connections open.
const PROMPT: Duration = Duration::from_secs(1);

/// Slow clients (64 connections, each sending one byte of a request every 2 s) do not lock out a new one: with
/// async I/O they cost no thread, and over the per-client cap the oldest idle connection is shed for the new
/// one. The 1 s bound is the issue's (a generous functional bound, not a benchmark).
#[test]
fn slow_clients_do_not_lock_out_a_new_one() {
    let s = Served::start(&["examples/brdfs"]);
    let mut slow: Vec<TcpStream> = (0..64).map(|_| TcpStream::connect(s.addr).unwrap()).collect();
    let request = b"GET /api/session HTTP/1.1\r\nHost: localhost\r\n\r\n";
    let mut sent = 0;
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(5) {
        for c in &mut slow {
            let _ = c.write_all(&request[sent..sent + 1]);
        }
        sent += 1;
        std::thread::sleep(Duration::from_millis(200));
        let t0 = Instant::now();
        let r = s.get("/");
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        assert!(t0.elapsed() < PROMPT, "GET / took {:?} with 64 slow connections open", t0.elapsed());
        std::thread::sleep(Duration::from_millis(1800));
    }
}

/// A small valid scene whose one material is `material` (TOML lines) and whose object is `object`.
fn scene_text(material: &str, object: &str) -> String {
    format!(
        "width = 32\nheight = 32\n[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
         [materials.m]\n{material}\n[[object]]\nmaterial = \"m\"\n{object}\n"
    )
}

/// FIFOs in a served folder — requested as a formula file and as a scene, and named by a scene as a mesh and
/// as a formula file — are refused at once (each within the issue's 1 s bound; eight of each, the number that
/// once stopped all rendering), and a normal render works afterwards.
#[test]
fn fifos_are_refused_without_blocking() {
    let d = scratch("fifo");
    for f in ["pipe.brdf", "pipe.toml", "pipe.obj"] {
        assert!(Command::new("mkfifo").arg(d.join(f)).status().unwrap().success());
    }
    let sphere = "shape = \"sphere\"";
    std::fs::write(d.join("names_mesh.toml"), scene_text("formula = \"NH^20\"", "shape = \"mesh\"\npath = \"pipe.obj\"")).unwrap();
    std::fs::write(d.join("names_brdf.toml"), scene_text("brdf = \"pipe.brdf\"", sphere)).unwrap();
    std::fs::write(d.join("ok.toml"), scene_text("formula = \"NH^20\"", sphere)).unwrap();
    let s = Served::start(&[d.to_str().unwrap()]);
    let at = |f: &str| d.join(f).display().to_string();
    for _ in 0..8 {
        for url in [
            format!("/api/file?path={}", at("pipe.brdf")),
            format!("/render.png?file={}", at("pipe.toml")),
            format!("/render.png?file={}", at("names_mesh.toml")),
            format!("/render.png?file={}", at("names_brdf.toml")),
        ] {
            let t = Instant::now();
            let r = s.get(&url);
            assert!((400..500).contains(&r.status), "{url}: {} {}", r.status, String::from_utf8_lossy(&r.body));
            assert!(r.json()["error"].as_str().is_some_and(|e| e.contains("regular file")), "{url}: {}", r.json());
            assert!(t.elapsed() < PROMPT, "{url} took {:?}", t.elapsed());
        }
    }
    let r = s.get(&format!("/render.png?file={}", at("ok.toml")));
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let _ = std::fs::remove_dir_all(&d);
}

/// Analyses past the deadline are stopped, not abandoned: after ten of them no slot is leaked (the in-flight
/// count is back to 0 and a render succeeds at once). The formula (800 IR nodes of `sin`, just under the cost
/// budget) with a reference takes seconds; the deadline is 0.5 s.
#[test]
fn computations_past_the_deadline_are_stopped_and_free_their_slots() {
    let s = Served::start(&["examples/brdfs", "--deadline", "0.5"]);
    // The render compiles its kernel and tessellates the scene once, now, so that the one after the analyses
    // measures only the slots.
    let frame = json!({"text": "VR^n", "params": {"n": 20}, "size": 64});
    assert_eq!(s.post("/api/render", &frame).status, 200);
    let heavy: String = (0..200).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "NH^n";
    for _ in 0..10 {
        let r = s.post("/api/analyze", &json!({"text": heavy, "params": {"n": 10}, "reference": {"text": "NH^n"}}));
        assert_eq!(r.status, 503, "{}", String::from_utf8_lossy(&r.body));
        let e = r.json();
        assert!(e["error"].as_str().unwrap().contains("stopped") && e["hint"].as_str().is_some(), "{e}");
    }
    // The handler returns only once its computation has stopped, so nothing is running now.
    assert_eq!(s.get("/api/session").json()["jobs_running"], json!(0));
    let r = s.post("/api/render", &frame);
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
}

/// A compile whose accuracy pass would outlast the request's deadline is stopped at the deadline (the pass's
/// search polls the job's token; before, it ran to its own 2 s budget and the request was answered after it),
/// answered 503, its slot free, and a normal request answered right after. The formula (~700 IR nodes, under
/// the cost budget; its search takes seconds) carries this run's own constants so that no decision cached by an earlier run answers it.
#[test]
fn a_compile_past_its_deadline_stops_within_a_second() {
    let s = Served::start(&["examples/brdfs", "--deadline", "0.3"]);
    let salt = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().subsec_nanos();
    let text: String = (0..60).map(|i| format!("exp(-(1-NH*NH)/(NH*NH*{i}.{salt}))*pow(1-NV*NV, n*{i}.5)/(NL+NV*{i}.5) + ")).collect::<String>() + "0";
    let t0 = Instant::now();
    let r = s.post("/api/compile", &json!({"name": "slow.brdf", "text": text}));
    let took = t0.elapsed();
    assert_eq!(r.status, 503, "{}", String::from_utf8_lossy(&r.body));
    assert!(r.json()["error"].as_str().unwrap().contains("stopped"), "{}", r.json());
    assert!(took < Duration::from_millis(1300), "answered {took:?} after the request, the deadline being 0.3 s");
    assert_eq!(s.get("/api/session").json()["jobs_running"], json!(0));
    let r = s.post("/api/compile", &json!({"name": "ok.brdf", "text": "NH^n"}));
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
}

/// `lobe serve FILE --scene SCENE` serves the scene's folder: `/render.png` of that scene is `lobe render`'s
/// PNG byte for byte. A scene naming a file outside the served folders is 403, and the outside file's text is
/// not in the answer.
#[test]
fn the_scene_folder_is_served_and_scenes_cannot_name_outside_files() {
    let d = scratch("scene-root");
    let s = Served::start(&["examples/brdfs/modified_schlick.brdf", "--scene", "examples/scenes/paper_sphere.toml"]);
    let r = s.get("/render.png?file=examples/scenes/paper_sphere.toml&set=n=50&size=96");
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let cli = cli_render(Path::new("examples/scenes/paper_sphere.toml"), "n=50", "96", &d.join("cli.png"));
    assert!(r.body == cli, "/render.png ({} bytes) differs from lobe render ({} bytes)", r.body.len(), cli.len());
    // A served folder with a scene (saved as .brdf, as the page can) naming files outside it.
    let (served, outside) = (d.join("served"), d.join("outside"));
    std::fs::create_dir_all(&served).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(outside.join("secret.brdf"), "SECRET-LINE (1 +\n").unwrap();
    std::fs::write(outside.join("secret.obj"), "v SECRET-LINE 0 0\nf 1 2 3\n").unwrap();
    let secret_brdf = outside.join("secret.brdf").display().to_string();
    let secret_obj = outside.join("secret.obj").display().to_string();
    let sphere = "shape = \"sphere\"";
    std::fs::write(served.join("a.brdf"), scene_text(&format!("brdf = \"{secret_brdf}\""), sphere)).unwrap();
    std::fs::write(served.join("b.brdf"), scene_text("brdf = \"../outside/secret.brdf\"", sphere)).unwrap();
    std::fs::write(served.join("c.brdf"), scene_text("formula = \"NH^20\"", &format!("shape = \"mesh\"\npath = \"{secret_obj}\""))).unwrap();
    std::fs::write(served.join("ok.brdf"), scene_text("formula = \"NH^20\"", sphere)).unwrap();
    let s = Served::start(&[served.to_str().unwrap()]);
    for f in ["a.brdf", "b.brdf", "c.brdf"] {
        let r = s.get(&format!("/render.png?file={}", served.join(f).display()));
        let body = String::from_utf8_lossy(&r.body);
        assert_eq!(r.status, 403, "{f}: {body}");
        assert!(!body.contains("SECRET"), "{f}: the answer quotes the outside file: {body}");
        assert!(r.json()["error"].as_str().is_some_and(|e| e.contains("outside")), "{f}: {body}");
    }
    assert_eq!(s.get(&format!("/render.png?file={}", served.join("ok.brdf").display())).status, 200);
    let _ = std::fs::remove_dir_all(&d);
}

/// `lobe render SCENE --size SIZE` (no `--set`), its PNG bytes.
pub(crate) fn cli_render_plain(scene: &Path, size: &str, out: &Path) -> Vec<u8> {
    cli_render_with(scene, &["--size", size], out)
}

fn values(v: &Value) -> Vec<f64> {
    v["values"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect()
}

#[test]
fn views_follow_the_parameters_and_the_incident_direction() {
    let s = Served::start(&["examples/brdfs"]);
    let lobe = |text: &str, n: f64, ti: f64, pi: f64| {
        let r = s.post("/api/lobe", &json!({"text": text, "params": {"n": n}, "theta_i": ti, "phi_i": pi, "n_theta": 19, "n_phi": 36}));
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        r.json()
    };
    let a = lobe("VR^n", 20.0, 30.0, 0.0);
    assert_eq!((a["n_theta"].as_u64(), a["n_phi"].as_u64(), values(&a).len()), (Some(19), Some(36), 19 * 36));
    assert_ne!(values(&a), values(&lobe("VR^n", 60.0, 30.0, 0.0)), "the lobe follows n");
    assert_ne!(values(&a), values(&lobe("VR^n", 20.0, 50.0, 0.0)), "the lobe follows θᵢ");
    assert_ne!(values(&a), values(&lobe("VR^n", 20.0, 30.0, 90.0)), "the lobe follows φᵢ");
    // Phong's peak is the mirror direction: θₒ = θᵢ, φₒ = φᵢ + 180° (grid steps of 5° and 10°).
    for (ti, pi) in [(30.0, 0.0), (50.0, 90.0)] {
        let v = values(&lobe("VR^n", 200.0, ti, pi));
        let best = (0..v.len()).max_by(|&x, &y| v[x].total_cmp(&v[y])).unwrap();
        let (t, p) = ((best / 36) as f64 * 5.0, (best % 36) as f64 * 10.0);
        assert_eq!((t, p), (ti, (pi + 180.0) % 360.0), "peak of VR^200 at θᵢ={ti}, φᵢ={pi}");
    }
    // The same numbers as the CLI's kernel at one grid point (θₒ = 45°, φₒ = 90°; L at θᵢ = 30°, φᵢ = 0).
    let (ti, to): (f64, f64) = (30f64.to_radians(), 45f64.to_radians());
    let at = format!("L={},{},{},V={},{},{}", ti.sin(), 0.0, ti.cos(), to.sin() * 90f64.to_radians().cos(), to.sin(), to.cos());
    let o = Command::new(env!("CARGO_BIN_EXE_lobe")).args(["eval", "--expr", "VR^n", "--set", "n=20", "--at", &at]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cli: f64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    let page = values(&a)[9 * 36 + 9];
    assert!((page - cli).abs() <= 1e-12 * cli.abs().max(1e-300), "page {page} vs lobe eval {cli}");

    // The image slice: θ_h × θ_d, below-horizon cells null, following n.
    let slice = |n: f64| {
        let r = s.post("/api/slice", &json!({"text": "NH^n", "params": {"n": n}, "res": 16}));
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        r.json()
    };
    let sl = slice(10.0);
    let v = values(&sl);
    assert_eq!(v.len(), 256);
    assert!(v.iter().all(|x| x.is_finite()), "at φ_d = 90° both directions stay above the horizon");
    let r = s.post("/api/slice", &json!({"text": "NH^n", "res": 16, "phi_d": 0})).json();
    assert!(values(&r).iter().any(|x| x.is_nan()), "at φ_d = 0 large θ_h + θ_d put V below the horizon: null");
    // NH = cos θ_h: the first row (θ_d = 0) is cos(θ_h)^n.
    for (i, x) in v[..16].iter().enumerate() {
        let want = (90f64 * i as f64 / 16.0).to_radians().cos().powf(10.0);
        assert!((x - want).abs() < 1e-9, "slice[0][{i}] = {x}, cos^10 = {want}");
    }
    assert_ne!(v, values(&slice(40.0)));
    // Bounds: too large a grid, a bad angle.
    assert_eq!(s.post("/api/lobe", &json!({"text": "NH^n", "n_theta": 5000})).status, 400);
    assert_eq!(s.post("/api/lobe", &json!({"text": "NH^n", "theta_i": 95})).status, 400);
    assert_eq!(s.post("/api/slice", &json!({"text": "NH^n", "res": 4096})).status, 400);

    // The plot in the plane of incidence (several formulas overlaid, polar to scale) changes with θᵢ.
    let plot = |ti: f64, polar: bool| {
        let r = s.post("/api/plot", &json!({"formulas": [{"text": "VR^n"}, {"text": "NH^n"}, {"text": "NL"}], "params": {"n": 20}, "polar": polar, "theta_i": ti, "phi_i": 0}));
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        r.body
    };
    assert_ne!(plot(20.0, true), plot(60.0, true));
    assert_ne!(plot(20.0, false), plot(60.0, false));
    // A formula that is NaN everywhere: a 4xx that says so, never a 500.
    for body in [json!({"formulas": [{"text": "0/0*NH"}]}), json!({"formulas": [{"text": "0/0*NH"}], "theta_i": 30, "polar": true})] {
        let r = s.post("/api/plot", &body);
        assert_eq!(r.status, 422, "{}", String::from_utf8_lossy(&r.body));
        let e = r.json();
        assert!(e["error"].as_str().unwrap().contains("NaN") && e["hint"].as_str().is_some_and(|h| !h.is_empty()), "{e}");
    }

    // ρ(θᵢ) with the numbers; the heat map's colour bar under the comparison.
    let a = s.post("/api/analyze", &json!({"text": "VR^n", "params": {"n": 10}})).json();
    let rows = a["albedo"].as_array().unwrap();
    assert_eq!(rows.len(), 91, "{a}");
    assert_eq!(rows.iter().map(|r| r[1].as_f64().unwrap()).fold(0.0, f64::max), a["albedo_max"].as_f64().unwrap());
    let r = s.post("/api/compare", &json!({"a": {"text": "VR^n"}, "b": {"text": "NH^n"}, "params": {"n": 20}, "size": 64}));
    assert_eq!(r.status, 200);
    let img = lobe::base::image::Image::decode_png(&r.body).unwrap();
    assert!(img.width > 3 * 64 && img.height > 64, "{}×{}", img.width, img.height);
    // Right of the three pictures (and the figure's narrow margin), a colour bar at least a picture tall: white
    // at its top, black at its foot, darker all the way down, coloured between (the CLI's figure).
    let bar = (3 * 64 + 9..img.width).any(|x| {
        (0..img.height).any(|y0| {
            img.pixel(x, y0) == [255, 255, 255]
                && (y0 + 63 < img.height)
                && img.pixel(x, y0 + 63) == [0, 0, 0]
                && (y0 + 1..y0 + 64).all(|y| (0..3).all(|c| img.pixel(x, y)[c] <= img.pixel(x, y - 1)[c]))
                && ![[0, 0, 0], [255, 255, 255]].contains(&img.pixel(x, y0 + 32))
        })
    });
    assert!(bar, "no colour bar beside the comparison");
    assert!(r.header("X-Lobe-Heat-Scale").unwrap().parse::<f64>().unwrap() >= 1.0);
}

#[test]
fn compile_reports_what_the_cli_reports() {
    let s = Served::start(&["examples/brdfs"]);
    // The CLI's note on a formula that reads both lobe variables, as a warning in the reply.
    let r = s.post("/api/compile", &json!({"text": "param k = 0.25 in 0..1\nVR^n * (1 - k) + k * NH^n"}));
    assert_eq!(r.status, 200);
    let c = r.json();
    let w = c["warnings"].as_array().unwrap();
    assert!(w.iter().any(|d| d["message"].as_str().unwrap().contains("reads both NH and VR")), "{c}");
    let read = |c: &Value, name: &str| c["params"].as_array().unwrap().iter().find(|p| p["name"] == json!(name)).map(|p| p["read"].clone());
    assert_eq!(read(&c, "k"), Some(json!(true)));
    assert_eq!(read(&c, "n"), Some(json!(true)));
    // A declared parameter the formula never reads is reported as such (the page shows no slider for it).
    let c = s.post("/api/compile", &json!({"text": "param k = 1 in 0..2\nNH * 2"})).json();
    assert_eq!(read(&c, "k"), Some(json!(false)), "{c}");
    assert!(read(&c, "n").is_none_or(|r| r == json!(false)), "{c}");
    // The page compiles the accuracy pass's form, as `lobe check` shows the CLI does.
    let text = std::fs::read_to_string("examples/brdfs/modified_schlick_vr.brdf").unwrap();
    let c = s.post("/api/compile", &json!({"text": text})).json();
    assert!(c["simplified"].as_str().is_some_and(|t| !t.is_empty()), "{c}");
}

#[test]
fn scenes_on_the_page_render_as_the_cli_renders_them() {
    let d = scratch("scenes");
    let s = Served::start(&["examples"]);
    let session = s.get("/api/session").json();
    assert!(session["scenes"].as_array().unwrap().iter().any(|x| x == "examples/scenes/principled.toml"), "{session}");
    let principled = "examples/explorer/principled.brdf";
    let text = std::fs::read_to_string(principled).unwrap();
    let defaults: serde_json::Map<String, Value> = s.post("/api/compile", &json!({"text": text})).json()["params"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["read"] == json!(true))
        .map(|p| (p["name"].as_str().unwrap().to_string(), p["default"].clone()))
        .collect();
    // Two materials of one formula with their own values: the exact frame is the CLI's, byte for byte; the
    // live frame is within the golden tolerance of it (so it too shows a dielectric and a metal).
    let req = |exact: bool| {
        json!({"name": principled, "text": text, "path": principled, "params": defaults, "moved": [], "scene": "examples/scenes/principled.toml", "size": 96, "exact": exact})
    };
    let cli = cli_render_plain(Path::new("examples/scenes/principled.toml"), "96", &d.join("p.png"));
    let exact = s.post("/api/render", &req(true));
    assert_eq!(exact.status, 200, "{}", String::from_utf8_lossy(&exact.body));
    assert!(exact.body == cli, "the page's exact principled.toml differs from lobe render");
    let live = lobe::base::image::Image::decode_png(&s.post("/api/render", &req(false)).body).unwrap();
    let cli = lobe::base::image::Image::decode_png(&cli).unwrap();
    let diffs = live.rgb.iter().zip(&cli.rgb).filter(|(a, c)| a.abs_diff(**c) > 0).count();
    assert!(live.rgb.iter().zip(&cli.rgb).all(|(a, c)| a.abs_diff(*c) <= 1) && diffs * 1000 <= cli.rgb.len(), "{diffs} channels differ");
    // A moved slider applies to every material, as `lobe render --set` does.
    let mut moved = req(true);
    moved["params"]["roughness"] = json!(0.8);
    moved["moved"] = json!(["roughness"]);
    let cli = {
        let o = d.join("r.png");
        cli_render(Path::new("examples/scenes/principled.toml"), "roughness=0.8", "96", &o)
    };
    assert!(s.post("/api/render", &moved).body == cli, "roughness=0.8 on both materials");

    // Another formula on the paper sphere renders at its own declared values (gold_blinn: n = 80), not at the
    // scene's n = 50, which was written for the scene's formula.
    let gold = "examples/vector/gold_blinn.brdf";
    let gtext = std::fs::read_to_string(gold).unwrap();
    let r = s.post("/api/render", &json!({"name": gold, "text": gtext, "path": gold, "params": {"n": 80}, "scene": "", "size": 96, "exact": true}));
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let abs = std::fs::canonicalize(gold).unwrap();
    let scene = lobe::render::scene::PAPER_SCENE.replace("brdf = \"../brdfs/modified_schlick_vr.brdf\"", &format!("brdf = {:?}", abs.display().to_string()));
    std::fs::write(d.join("gold.toml"), scene).unwrap();
    assert!(r.body == cli_render(&d.join("gold.toml"), "n=80", "96", &d.join("g.png")), "gold_blinn at n = 80");
    assert_ne!(r.body, cli_render(&d.join("gold.toml"), "n=50", "96", &d.join("g50.png")));
    // Not a scene: refused with a hint.
    let r = s.post("/api/render", &json!({"text": "NH^n", "scene": "examples/brdfs/phong.brdf", "size": 32}));
    assert_eq!(r.status, 400);
    let _ = std::fs::remove_dir_all(&d);
}

/// Whether a file outside the served folders exists is not told: a scene naming an outside file that exists and
/// one naming a file that does not are both 403, with the same words (but for the path).
#[test]
fn outside_paths_get_one_answer_whether_or_not_they_exist() {
    let d = scratch("outside-oracle");
    let (served, outside) = (d.join("served"), d.join("outside"));
    std::fs::create_dir_all(&served).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(outside.join("real.brdf"), "NH^20\n").unwrap();
    let sphere = "shape = \"sphere\"";
    let mut answers = vec![];
    for (scene, named) in [
        ("exists.brdf", outside.join("real.brdf").display().to_string()),
        ("missing.brdf", outside.join("missing.brdf").display().to_string()),
        ("exists_rel.brdf", "../outside/real.brdf".to_string()),
        ("missing_rel.brdf", "../outside/missing.brdf".to_string()),
    ] {
        std::fs::write(served.join(scene), scene_text(&format!("brdf = \"{named}\""), sphere)).unwrap();
        answers.push((scene, named));
    }
    let s = Served::start(&[served.to_str().unwrap()]);
    let mut words = vec![];
    for (scene, named) in &answers {
        let r = s.get(&format!("/render.png?file={}", served.join(scene).display()));
        assert_eq!(r.status, 403, "{scene}: {}", String::from_utf8_lossy(&r.body));
        let e = r.json();
        words.push(format!("{} / {}", e["error"], e["hint"]).replace(named.as_str(), "PATH"));
    }
    // Existing and missing, named absolutely (0, 1) and relatively (2, 3).
    assert!(words[0] == words[1] && words[2] == words[3], "the answers differ: {words:#?}");
    // And a file the page asks for directly: the same status for a missing and an existing outside path.
    for named in [outside.join("real.brdf"), outside.join("missing.brdf")] {
        assert_eq!(s.get(&format!("/api/file?path={}", named.display())).status, 403, "{}", named.display());
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// 40 connections from one address, each trickling a request body, do not lock that address out: a normal
/// request from it is answered (the connections still sending are shed first).
#[test]
fn slow_bodies_from_one_address_do_not_lock_it_out() {
    let s = Served::start(&["examples/brdfs"]);
    let head = format!(
        "POST /api/compile HTTP/1.1\r\nHost: {}\r\nX-Lobe-Client: test\r\nContent-Type: application/json\r\nContent-Length: 4096\r\n\r\n{{",
        s.addr
    );
    let mut slow: Vec<TcpStream> = (0..40)
        .map(|_| {
            let mut c = TcpStream::connect(s.addr).unwrap();
            c.write_all(head.as_bytes()).unwrap();
            c
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    let mut worst = Duration::ZERO;
    for round in 0..5 {
        for c in &mut slow {
            let _ = c.write_all(b" ");
        }
        let t0 = Instant::now();
        let r = s.post("/api/compile", &json!({"text": "NH^n", "params": {"n": 20}}));
        worst = worst.max(t0.elapsed());
        assert_eq!(r.status, 200, "round {round}: {}", String::from_utf8_lossy(&r.body));
        std::thread::sleep(Duration::from_millis(200));
    }
    eprintln!("slowest normal request beside 40 slow bodies: {worst:?}");
    assert!(worst < PROMPT, "a normal request took {worst:?}");
}


/// Eight heavy renders (each under the cost budget but running to the deadline) do not keep the page's normal
/// render waiting: it is answered within a second while they run, every time.
#[test]
fn eight_heavy_renders_leave_a_normal_render_answered() {
    let s = Served::start(&["examples/brdfs", "--deadline", "6"]);
    // About half the cost budget at 1024²: seconds of work each, so all eight run to the deadline.
    let heavy: String = (0..500).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0";
    let addr = s.addr;
    // Compiled once first, so the eight below start rendering at once.
    let warm = s.post("/api/compile", &json!({"name": "heavy.brdf", "text": heavy}));
    assert_eq!(warm.status, 200, "{}", String::from_utf8_lossy(&warm.body));
    let started = Instant::now();
    let runs: Vec<_> = (0..8)
        .map(|_| {
            let body = json!({"name": "heavy.brdf", "text": heavy, "size": 1024}).to_string();
            std::thread::spawn(move || {
                let r = http(addr, "POST", "/api/render", &[("X-Lobe-Client", "test"), ("Content-Type", "application/json")], Some(body.as_bytes()));
                (r.status, Instant::now())
            })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(1500));
    let mut worst = Duration::ZERO;
    for k in 0..4 {
        let t0 = Instant::now();
        let r = s.post("/api/render", &json!({"text": "VR^n", "params": {"n": 20 + k}, "size": 128}));
        worst = worst.max(t0.elapsed());
        assert_eq!(r.status, 200, "normal render {k}: {}", String::from_utf8_lossy(&r.body));
    }
    let measured_at = Instant::now();
    let ends: Vec<(u16, Instant)> = runs.into_iter().map(|h| h.join().unwrap()).collect();
    let running = ends.iter().filter(|(_, end)| *end > measured_at).count();
    eprintln!("normal render beside eight heavy ones: slowest {worst:?}; {running} heavy still running after; statuses {:?}; heavy ran {:?}", ends.iter().map(|e| e.0).collect::<Vec<_>>(), started.elapsed());
    assert!(running >= 6, "the heavy renders had ended before the measurement ({running} running)");
    assert!(ends.iter().all(|(st, _)| *st == 200 || *st == 503), "{:?}", ends.iter().map(|e| e.0).collect::<Vec<_>>());
    assert!(worst < PROMPT, "a normal render took {worst:?} beside eight heavy ones");
}

/// The hostile corpus's 722-byte formula (forty functions, each calling the one before twice) compiles on the
/// server within its deadline and a gibibyte.
#[test]
fn a_self_doubling_formula_request_ends_within_its_deadline_and_memory() {
    let s = Served::start(&["examples/brdfs"]);
    let mut text = String::from("fn f0(x) = x*NH + NV\n");
    for i in 1..=40 {
        text += &format!("fn f{i}(x) = f{j}(x) + f{j}(x + 1)\n", j = i - 1);
    }
    text += "f40(NH)\n";
    let t0 = Instant::now();
    let r = s.post("/api/compile", &json!({"name": "chain.brdf", "text": text}));
    let took = t0.elapsed();
    assert!(r.status == 200 || r.status == 422 || r.status == 503, "{}: {}", r.status, String::from_utf8_lossy(&r.body));
    let kib = super::hostile::peak_rss_kib(s.child.id()).unwrap_or(0);
    eprintln!("fn chain on the server: {} in {took:?}, peak {} MiB", r.status, kib / 1024);
    assert!(took < Duration::from_secs(11), "{took:?}");
    assert!(kib < 1 << 20, "peak {} MiB", kib / 1024);
    let after = s.post("/api/render", &json!({"text": "VR^n", "size": 64}));
    assert_eq!(after.status, 200);
}

/// Seven renders of a 200-light scene at once (the hostile corpus held job slots with them for 88–98 s): each
/// answered within its deadline, and a normal render right after them within a second.
#[test]
fn seven_renders_of_a_two_hundred_light_scene_end_promptly() {
    let d = scratch("lights");
    let mut scene = String::from("width = 256\nheight = 256\n[camera]\nposition = [0, 0, 6]\nfov = 30\n");
    for i in 0..200 {
        let a = f64::from(i) * 0.1;
        scene += &format!("[[light]]\nkind = \"point\"\nposition = [{:.3}, {:.3}, 10]\ncolor = [0.01, 0.01, 0.01]\n", 10.0 * a.cos(), 10.0 * a.sin());
    }
    scene += "[materials.m]\nformula = \"VR^n\"\nparams = { n = 50 }\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";
    std::fs::write(d.join("lights.toml"), scene).unwrap();
    let s = Served::start(&[d.to_str().unwrap()]);
    let (addr, path) = (s.addr, d.join("lights.toml").display().to_string());
    let t0 = Instant::now();
    let runs: Vec<_> = (0..7)
        .map(|_| {
            let url = format!("/render.png?file={path}&size=256");
            std::thread::spawn(move || {
                let r = http(addr, "GET", &url, &[], None);
                (r.status, t0.elapsed())
            })
        })
        .collect();
    let ends: Vec<(u16, Duration)> = runs.into_iter().map(|h| h.join().unwrap()).collect();
    eprintln!("seven 200-light renders: {ends:?}");
    assert!(ends.iter().all(|(st, took)| *st == 200 && *took < Duration::from_secs(10)), "{ends:?}");
    let t1 = Instant::now();
    assert_eq!(s.post("/api/render", &json!({"text": "VR^n", "size": 128})).status, 200);
    assert!(t1.elapsed() < PROMPT, "{:?}", t1.elapsed());
    let _ = std::fs::remove_dir_all(&d);
}

/// A traced scene on the page: `spp` picks the level (said in `X-Lobe-Spp`, the scene's own in
/// `X-Lobe-Scene-Spp`), an exact frame at a level is `lobe render --spp` of it byte for byte, a level over the
/// budget is refused before it runs, and a bad `spp` (0, 10⁹, not a number) is a 400 with a hint. A
/// rasterised scene answers without the headers.
#[test]
fn traced_scenes_render_at_the_requested_spp() {
    let d = scratch("spp");
    let s = Served::start(&["examples"]);
    let ggx = "examples/explorer/ggx.brdf";
    let text = std::fs::read_to_string(ggx).unwrap();
    let req = |spp: Value, size: u64| {
        json!({"name": ggx, "text": text, "path": ggx, "params": {}, "moved": [], "scene": "examples/scenes/environment.toml", "size": size, "exact": true, "spp": spp})
    };
    for (level, file) in [(1, "e1.png"), (4, "e4.png")] {
        let r = s.post("/api/render", &req(json!(level), 32));
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        assert_eq!((r.header("X-Lobe-Spp"), r.header("X-Lobe-Scene-Spp")), (Some(level.to_string().as_str()), Some("64")));
        assert_eq!(r.header("X-Lobe-Next-Spp"), Some((4 * level).to_string().as_str()), "the next level after {level}");
        let cli = cli_render_with(Path::new("examples/scenes/environment.toml"), &["--size", "32", "--spp", &level.to_string()], &d.join(file));
        assert!(r.body == cli, "the page's exact environment.toml at {level} spp differs from lobe render --spp {level}");
    }
    for bad in [json!(0), json!(1_000_000_000u64), json!("many"), json!(2.5), json!(-1)] {
        let r = s.post("/api/render", &req(bad.clone(), 32));
        assert_eq!(r.status, 400, "spp {bad}: {}", String::from_utf8_lossy(&r.body));
        let e = r.json();
        assert!(e["error"].as_str().unwrap().contains("spp") && e["hint"].as_str().is_some_and(|h| !h.is_empty()), "spp {bad}: {e}");
    }
    // The whole 65 536 spp at 2048² is far over the budget: refused at once, not run to the deadline.
    let r = s.post("/api/render", &req(json!(65536), 2048));
    assert_eq!(r.status, 422, "{}", String::from_utf8_lossy(&r.body));
    assert!(r.json()["error"].as_str().unwrap().contains("budget"));
    let r = s.post("/api/render", &json!({"text": "NH^n", "scene": "", "size": 32, "spp": 4}));
    assert_eq!((r.status, r.header("X-Lobe-Spp")), (200, None), "a rasterised scene ignores spp");
    let _ = std::fs::remove_dir_all(&d);
}

/// A request whose client leaves before the answer (the page aborts a refinement level it no longer needs)
/// stops its computation at the next poll and frees its slot: a heavy render that takes seconds when awaited
/// ends within a second of its connection's close, long before the deadline.
#[test]
fn a_computation_whose_client_leaves_stops_and_frees_its_slot() {
    let s = Served::start(&["examples/brdfs", "--deadline", "60"]);
    let heavy: String = (0..500).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0";
    let body = json!({"name": "heavy.brdf", "text": heavy, "size": 1024});
    assert_eq!(s.post("/api/compile", &json!({"name": "heavy.brdf", "text": heavy})).status, 200);
    let t0 = Instant::now();
    let r = s.post("/api/render", &body);
    let awaited = t0.elapsed();
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    // The same request on a kept-alive connection (as a browser's fetch), closed once the job runs.
    let mut c = TcpStream::connect(s.addr).unwrap();
    let text = body.to_string();
    let head = format!("POST /api/render HTTP/1.1\r\nHost: {}\r\nX-Lobe-Client: test\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n", s.addr, text.len());
    c.write_all(head.as_bytes()).unwrap();
    c.write_all(text.as_bytes()).unwrap();
    let running = |s: &Served| s.get("/api/session").json()["jobs_running"].as_u64().unwrap();
    let t1 = Instant::now();
    while running(&s) == 0 {
        assert!(t1.elapsed() < awaited, "the render did not start");
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(c);
    let t2 = Instant::now();
    while running(&s) > 0 {
        assert!(t2.elapsed() < Duration::from_secs(30), "the render still runs 30 s after its client left");
        std::thread::sleep(Duration::from_millis(10));
    }
    let stopped = t2.elapsed();
    eprintln!("render awaited {awaited:?}; stopped {stopped:?} after its client left");
    assert!(stopped < Duration::from_secs(1).min(awaited / 2), "stopped {stopped:?} after the close; the render takes {awaited:?}");
    // The slot is free: a normal render is answered.
    let r = s.post("/api/render", &json!({"text": "VR^n", "params": {"n": 20}, "size": 64}));
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
}
