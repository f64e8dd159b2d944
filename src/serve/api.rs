//! The server's endpoints: each takes the parsed request and returns a [`Reply`] or an [`ApiError`]. The work
//! is the library's: formulas compile through [`crate::compile_formula`], scenes load and render through
//! [`crate::render`], comparisons through [`crate::render::compare::compare_in`], plots through
//! [`crate::report::plot`], numbers through [`crate::numerics`] and [`crate::report::measure`].
//!
//! Live parameters: the page's formula is compiled once per text with **no** parameter baked (every
//! parameter is a runtime argument) through the accuracy pass as the commands run it (budgeted, its decisions
//! cached on disk; priced against the cost budget first), kept in a small cache, and handed to the scene
//! loader through [`Live`], a [`BrdfCompiler`] that returns the cached kernel; a slider move then only builds
//! a new material list (parameter values, the normalisation coefficient if the scene asks for it) and
//! renders. The views ([`super::views`]), plots and numbers sample the same kernel. Scene geometry is parsed
//! and tessellated once per (scene, version of its file, size). The exact frame (`/api/render` with `exact`,
//! which the page asks for when the controls rest) and `/render.png` instead run the CLI's `lobe render`
//! compile (parameters baked, [`LobeCompiler::for_commands`]), so their bytes equal the CLI's.

use super::http::{self, ApiError, Reply, Roots, ServedFiles};
use super::Limits;
use crate::base::cancel::Cancel;
use crate::base::diag::Diagnostics;
use crate::base::source::Files;
use crate::ir::ParamDecl;
use crate::render::scene::{self, BrdfCompiler, CompiledBrdf, Geometry, LoadOptions, LobeCompiler};
use crate::render::RenderOptions;
use crate::{Backend, Kernel, Options};
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Entries kept in each cache before it is emptied (a typing user makes one entry per keystroke).
const CACHE_ENTRIES: usize = 64;

/// The accuracy pass's cost per IR node and domain point, in the budget's units (~1 ns): measured 2026-12-02,
/// a 200-term sum of sines (~800 nodes, 4096 points) took 3.5 s of CPU in the pass, ~1 µs per node and point
/// (the truth is evaluated in higher precision, for several candidates).
const PASS_COST_PER_NODE_POINT: f64 = 1000.0;

/// A formula compiled with every parameter live.
pub(super) struct Compiled {
    /// The formula's kernel, or a colour formula's red, green and blue ones (renders use all; the plots and
    /// analyses show the first).
    pub(super) kernels: Vec<Arc<Kernel>>,
    warnings: Diagnostics,
    parse_us: f64,
}

impl Compiled {
    /// The formula's kernel, or a colour formula's red one.
    pub(super) fn kernel(&self) -> &Arc<Kernel> {
        &self.kernels[0]
    }
}

/// A cached scene geometry: the scene file (`None`: the built-in paper sphere), its modification time, the
/// image side.
type SceneKey = (Option<PathBuf>, Option<std::time::SystemTime>, usize);

/// Everything the endpoints share.
pub(crate) struct State {
    pub roots: Roots,
    /// The scene page renders use: a served file, or `None` for the built-in paper sphere.
    pub scene: Option<PathBuf>,
    /// Formula files named on the command line (the page opens the first).
    pub files: Vec<String>,
    pub limits: Limits,
    kernels: Mutex<HashMap<(String, String), Arc<Compiled>>>,
    geometry: Mutex<HashMap<SceneKey, Arc<Geometry>>>,
    /// Compute jobs running now, including ones whose request already timed out.
    jobs: AtomicUsize,
    /// Of those, the heavy ones ([`check_cost`] over [`Limits::light_cost`]).
    heavy: AtomicUsize,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl State {
    pub(crate) fn new(roots: Roots, scene: Option<PathBuf>, files: Vec<String>, limits: Limits) -> State {
        State { roots, scene, files, limits, kernels: Mutex::default(), geometry: Mutex::default(), jobs: AtomicUsize::new(0), heavy: AtomicUsize::new(0) }
    }

    /// The formula `text` (file name `name`) compiled with every parameter live, from the cache or now. `cancel`
    /// (the request's deadline) reaches every stage: it is checked between parsing, each channel's compile and
    /// caching, and the accuracy pass's search polls it between candidates; the stages between the polls are
    /// bounded by the size budgets (formula bytes, term and program budgets), so a compile past its deadline
    /// stops within milliseconds of it. A compile that was stopped is not cached.
    pub(super) fn compiled(&self, name: &str, text: &str, cancel: &Cancel) -> Result<Arc<Compiled>, ApiError> {
        if text.len() > self.limits.formula_bytes {
            return Err(ApiError::new(413, format!("the formula is larger than {} KiB", self.limits.formula_bytes / 1024))
                .hint("a formula is a few lines"));
        }
        let key = (name.to_string(), text.to_string());
        if let Some(c) = lock(&self.kernels).get(&key) {
            return Ok(c.clone());
        }
        let stopped = |_| ApiError::new(503, crate::base::cancel::Cancelled.to_string());
        cancel.check().map_err(stopped)?;
        let t = Instant::now();
        let (f, warnings) = crate::front::parse_with_warnings(name, text)?;
        let parse_us = t.elapsed().as_secs_f64() * 1e6;
        cancel.check().map_err(stopped)?;
        // Through the accuracy pass as the commands compile (`LobeCompiler::for_commands`), parameters live: the
        // page shades and measures the form the CLI would, and the pass's decision is cached on disk. The pass
        // measures against the high-precision truth, so it is priced like any work, before it starts.
        let mut warnings = warnings;
        let plain = Options { backend: Backend::Jit, ..Options::default() };
        let points = crate::numerics::robust::PassOptions::default().points as f64;
        let opts = if f.ir.len() as f64 * points * PASS_COST_PER_NODE_POINT <= self.limits.cost_budget {
            live_options(cancel)
        } else {
            warnings.push(
                crate::Diagnostic::warning("the accuracy pass was skipped: the formula is too large for the server's budget")
                    .hint("the page shows the plain simplification; rendering and evaluating outside the page run the pass"),
            );
            plain
        };
        let mut kernels = Vec::new();
        for c in f.channels() {
            kernels.push(Arc::new(crate::compile_formula(c, &opts)?));
            // A search the deadline cut short compiled its best form so far: not the page's form, and not cached.
            cancel.check().map_err(stopped)?;
        }
        // The CLI's note about the lobe variable (plots, energy and accuracy use it), shown as a warning.
        if let Some(note) = crate::numerics::choose_lobe_input(kernels.iter().map(|k| k.used_inputs()).collect()).1 {
            let hint = "the energy coefficient and the error against the reference use this lobe variable";
            warnings.push(crate::Diagnostic::warning(note).hint(hint));
        }
        let c = Arc::new(Compiled { kernels, warnings, parse_us });
        let mut cache = lock(&self.kernels);
        if cache.len() >= CACHE_ENTRIES {
            cache.clear();
        }
        cache.insert(key, c.clone());
        Ok(c)
    }

    /// The geometry of `scene` (a served file; `None`: the built-in paper sphere) at `size`², parsed once per
    /// version of the file.
    fn geometry(&self, scene: Option<&Path>, size: usize) -> Result<Arc<Geometry>, ApiError> {
        let modified = scene.and_then(|p| std::fs::metadata(p).and_then(|m| m.modified()).ok());
        let key = (scene.map(Path::to_path_buf), modified, size);
        if let Some(g) = lock(&self.geometry).get(&key) {
            return Ok(g.clone());
        }
        let files = ServedFiles::new(&self.roots);
        let g = Arc::new(match scene {
            Some(p) => scene::load_geometry(p, Some((size, size)), &Files::new(files.clone())).map_err(scene_error(&files))?,
            None => scene::parse_geometry("<builtin paper_sphere.toml>", scene::PAPER_SCENE, Path::new("."), Some((size, size)), &Files::new(files))?,
        });
        let mut cache = lock(&self.geometry);
        if cache.len() >= CACHE_ENTRIES {
            cache.clear();
        }
        cache.insert(key, g.clone());
        Ok(g)
    }
}

/// The page's compile options: the JIT through the accuracy pass as [`LobeCompiler::for_commands`] runs it
/// (its search budgeted and stopped by `cancel`, its finished decisions read from and stored in the platform
/// cache), nothing baked.
fn live_options(cancel: &Cancel) -> Options {
    let pass = crate::numerics::robust::PassOptions::default();
    crate::numerics::pass_cache::command_pass_until(Options { backend: Backend::Jit, ..Options::default() }, pass, true, cancel.clone())
}

/// `lobe render`'s scene compiler ([`LobeCompiler::for_commands`]: values baked, through the accuracy pass and
/// its decision cache, so the bytes are the CLI's), its search also stopped by `cancel` (the request's deadline).
fn commands_compiler(cancel: &Cancel) -> LobeCompiler {
    let pass = crate::numerics::robust::PassOptions::default();
    let accuracy = crate::numerics::pass_cache::command_pass_until(Options::default(), pass, true, cancel.clone()).accuracy;
    LobeCompiler { backend: Backend::Jit, math: crate::Mode::Precise, accuracy }
}

/// A [`BrdfCompiler`] over the live-parameter cache: parameter values are not baked but passed at render time.
pub(crate) struct Live<'a, 'b>(&'a Job<'b>);

impl BrdfCompiler for Live<'_, '_> {
    fn declare(&self, file: &str, src: &str) -> Result<Vec<ParamDecl>, Diagnostics> {
        self.0.compiled(file, src).map(|c| c.kernel().formula.params.clone()).map_err(|e| diagnostics_of(file, src, e))
    }
    /// The page compiles precise (the `math` key of a scene material is not applied to live kernels).
    fn build(&self, file: &str, src: &str, _values: &[(String, f64)], _math: Option<crate::Mode>) -> Result<CompiledBrdf, Diagnostics> {
        let c = self.0.compiled(file, src).map_err(|e| diagnostics_of(file, src, e))?;
        Ok(CompiledBrdf::from_kernels(&c.kernels))
    }
}

/// The compile error back as diagnostics (the scene loader wants them); a size refusal becomes one item.
fn diagnostics_of(file: &str, src: &str, e: ApiError) -> Diagnostics {
    let mut ds = Diagnostics::new(file, src);
    ds.push(crate::Diagnostic::error(e.error.message.clone()));
    ds
}

/// A computation's view of the server: the shared [`State`] (it derefs to it) and the job's [`Cancel`] token,
/// which trips at the request deadline and which every long loop the job runs polls.
pub(crate) struct Job<'a> {
    st: &'a State,
    pub cancel: Cancel,
    /// The heavy slot the job took when its cost was known to be over the light cost.
    heavy: std::sync::OnceLock<Slot<'a>>,
}

impl Job<'_> {
    /// [`State::compiled`] stopped by the job's deadline.
    pub(super) fn compiled(&self, name: &str, text: &str) -> Result<Arc<Compiled>, ApiError> {
        self.st.compiled(name, text, &self.cancel)
    }
}

impl std::ops::Deref for Job<'_> {
    type Target = State;
    fn deref(&self) -> &State {
        self.st
    }
}

/// Frees a job slot when the job ends, however it ends.
struct Slot<'a>(&'a AtomicUsize);

impl Drop for Slot<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Takes a slot of `count` if fewer than `max` are taken.
fn take(count: &AtomicUsize, max: usize) -> Option<Slot<'_>> {
    if count.fetch_add(1, Ordering::SeqCst) >= max {
        count.fetch_sub(1, Ordering::SeqCst);
        return None;
    }
    Some(Slot(count))
}

fn busy(running: usize, what: &str) -> ApiError {
    ApiError::new(503, format!("the server is busy ({running} {what} running)")).hint("try again in a moment")
}

/// Runs `work` (from the calling thread: the HTTP layer's blocking pool) with a token that trips at the
/// request deadline or when the client leaves (`gone`, the request's); refuses new work with 503 while
/// `max_jobs + light_jobs` jobs run, and a job whose cost [`check_cost`] finds heavy while `max_jobs` heavy ones
/// run. A job past its deadline, or whose client has closed the connection, stops at its next poll
/// — the renderer between tiles, the integrals between incidence angles, the accuracy metrics between n, the
/// accuracy pass between candidates — and is answered 503; its slots are free again as soon as it has stopped.
/// The job's parallel work runs on worker threads of its own (as many as the machine has cores): a shared pool
/// would run each request's tiles after those of the requests before it, so a light render would wait for
/// every heavy one. With the cost budget checked before each job, a hostile request costs at most one slot for
/// about the deadline, and the page's other requests keep being served.
pub(crate) fn limited<T: Send>(st: &Arc<State>, gone: &Cancel, work: impl FnOnce(&Job) -> Result<T, ApiError> + Send) -> Result<T, ApiError> {
    let max = st.limits.max_jobs + st.limits.light_jobs;
    let Some(_slot) = take(&st.jobs, max) else { return Err(busy(max, "computations")) };
    let job = Job { st, cancel: gone.child(st.limits.deadline), heavy: std::sync::OnceLock::new() };
    let threads = std::thread::available_parallelism().map_or(2, usize::from);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .stack_size(JOB_WORKER_STACK)
        .build()
        .map_err(|e| ApiError::new(503, format!("cannot start worker threads: {e}")).hint("try again in a moment"))?;
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| pool.install(|| work(&job))))
        .unwrap_or_else(|_| Err(ApiError::new(500, "internal error in the computation")));
    // A job stopped by its token fails with whatever error its loop gave; the deadline is the reason, or the
    // client's leaving (whom no answer reaches).
    if gone.is_cancelled() {
        return Err(ApiError::new(503, "the client closed the connection; the computation was stopped"));
    }
    if job.cancel.is_cancelled() {
        let secs = st.limits.deadline.as_secs_f64();
        return Err(ApiError::new(503, format!("the computation took longer than {secs} s and was stopped"))
            .hint("use a smaller size or a simpler formula"));
    }
    r
}

/// A scene load's diagnostics as the answer: 403 when the load failed because the scene named a file outside
/// the served directories (the diagnostics name the path only), else as any scene error (422).
fn scene_error(files: &ServedFiles) -> impl Fn(Diagnostics) -> ApiError + '_ {
    move |ds| {
        let mut e = ApiError::from(ds);
        if files.refused() {
            e.status = 403;
            e.error.hints.push("the server reads only files under the directories it was started with".to_string().into());
        }
        e
    }
}

/// Stack of a job's worker threads: address space only, as the command line's workers (the library's recursive
/// passes continue on stack segments of their own).
const JOB_WORKER_STACK: usize = 256 << 20;

/// Refuses work whose estimated cost (IR nodes × evaluations) is over the budget, before it starts; work over
/// the light cost takes one of the `max_jobs` heavy slots for the rest of the job, or is refused as busy.
pub(super) fn check_cost(job: &Job, k: &Kernel, evals: f64, what: &str) -> Result<(), ApiError> {
    let st = job.st;
    let cost = k.formula.ir.len().max(1) as f64 * evals;
    if cost > st.limits.cost_budget {
        return Err(ApiError::new(422, format!(
            "{what} would take about {:.0}× the server's budget ({} IR nodes × {:.0} evaluations)",
            cost / st.limits.cost_budget,
            k.formula.ir.len(),
            evals
        ))
        .hint("use a smaller size or a simpler formula"));
    }
    if cost > st.limits.light_cost && job.heavy.get().is_none() {
        let slot = take(&st.heavy, st.limits.max_jobs).ok_or_else(|| busy(st.limits.max_jobs, "heavy computations"))?;
        let _ = job.heavy.set(slot);
    }
    Ok(())
}

/// FNV-1a of a file's bytes: the page sends it back on save to detect edits made on disk meanwhile.
pub(crate) fn content_hash(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h = (h ^ b as u64).wrapping_mul(0x100_0000_01b3);
    }
    format!("{h:016x}")
}

// ---- request fields ----

fn str_field<'a>(v: &'a Value, k: &str) -> Result<&'a str, ApiError> {
    v.get(k).and_then(Value::as_str).ok_or_else(|| ApiError::bad(format!("missing string field `{k}`")))
}

/// A formula in a request: `{"name": "…", "text": "…"}` (name optional).
pub(super) fn formula_field(v: &Value) -> Result<(String, String), ApiError> {
    let name = v.get("name").and_then(Value::as_str).unwrap_or("<page>").to_string();
    Ok((name, str_field(v, "text")?.to_string()))
}

/// `theta_i`, `phi_i` (degrees) of a request: `None` without `theta_i`; θᵢ must be in 0..90, φᵢ any finite angle.
pub(crate) fn incidence_field(v: &Value) -> Result<Option<(f64, f64)>, ApiError> {
    let Some(t) = v.get("theta_i") else { return Ok(None) };
    let t = t.as_f64().filter(|t| (0.0..90.0).contains(t));
    let t = t.ok_or_else(|| ApiError::bad("`theta_i` must be an angle in degrees in 0..90"))?;
    let p = match v.get("phi_i") {
        None => 0.0,
        Some(p) => p.as_f64().filter(|p| p.is_finite()).ok_or_else(|| ApiError::bad("`phi_i` must be a finite angle in degrees"))?,
    };
    Ok(Some((t, p)))
}

/// `{"params": {"n": 50, …}}` → a list of parameter values.
pub(super) fn params_field(v: &Value) -> Result<Vec<(String, f64)>, ApiError> {
    let Some(p) = v.get("params") else { return Ok(vec![]) };
    let obj = p.as_object().ok_or_else(|| ApiError::bad("`params` must be an object of numbers"))?;
    obj.iter()
        .map(|(k, x)| {
            let f = x.as_f64().filter(|f| f.is_finite()).ok_or_else(|| ApiError::bad(format!("params.{k} must be a finite number")))?;
            Ok((k.clone(), f))
        })
        .collect()
}

/// The square image side of a page request (default 512), capped by the server.
fn size_field(st: &State, v: &Value) -> Result<usize, ApiError> {
    let s = match v.get("size") {
        None => 512,
        Some(x) => x.as_u64().ok_or_else(|| ApiError::bad("`size` must be a whole number"))? as usize,
    };
    if !(16..=st.limits.max_size).contains(&s) {
        return Err(ApiError::bad(format!("size {s} is outside 16..={}", st.limits.max_size)).hint("the page offers 256, 512 and 1024"));
    }
    Ok(s)
}

/// Parameter values for a kernel: declared defaults, then `set` (range-checked like every parameter value given for a run).
pub(super) fn values(k: &Kernel, set: &[(String, f64)]) -> Result<Vec<f64>, ApiError> {
    crate::resolve_bake(&k.formula, set)?;
    let mut p = k.default_params();
    for (name, v) in set {
        if let Some(i) = k.formula.param_index(name) {
            p[i] = *v;
        }
    }
    Ok(p)
}

/// Every render gets its own pool of one thread per core (`threads` ≠ 0 makes [`crate::render::render`] build
/// one): on rayon's shared pool a page frame would queue behind every tile of a slow 2048² comparison. A pool
/// costs two thread spawns (tens of µs); the image does not depend on the thread count. The job's token
/// stops the render between tiles.
fn ropts(cancel: &Cancel) -> RenderOptions {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get()).min(crate::render::MAX_THREADS);
    RenderOptions { threads: cores, cancel: cancel.clone(), ..RenderOptions::default() }
}

pub(super) fn png(img: &crate::base::image::Image) -> Result<Vec<u8>, ApiError> {
    img.encode_png().map_err(|e| ApiError::new(500, e))
}

// ---- endpoints ----

/// `GET /api/session`: what the page needs to start.
pub(crate) fn session(st: &State) -> Reply {
    let scene = st.scene.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "paper_sphere.toml (built in)".into());
    Reply::ok_report(&SessionReply {
        files: list_files(&st.roots, "brdf"),
        scenes: list_files(&st.roots, "toml"),
        open: st.files.first().cloned(),
        scene,
        roots: st.roots.dirs().iter().map(|d| d.display().to_string()).collect(),
        jobs_running: st.jobs.load(Ordering::SeqCst),
        limits: LimitsReply {
            max_size: st.limits.max_size,
            formula_bytes: st.limits.formula_bytes,
            body_bytes: st.limits.body_bytes,
            deadline_s: st.limits.deadline.as_secs_f64(),
        },
    })
}

/// The `/api/session` reply.
#[derive(serde::Serialize)]
pub(crate) struct SessionReply {
    files: Vec<String>,
    scenes: Vec<String>,
    /// The file named on the command line first, if any.
    open: Option<String>,
    scene: String,
    roots: Vec<String>,
    jobs_running: usize,
    limits: LimitsReply,
}

/// The server's limits, as `/api/session` reports them.
#[derive(serde::Serialize)]
pub(crate) struct LimitsReply {
    max_size: usize,
    formula_bytes: usize,
    body_bytes: usize,
    deadline_s: f64,
}

/// The `/api/file` reply (`text` absent) and the `/api/save` reply.
#[derive(serde::Serialize)]
pub(crate) struct FileReply {
    path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    text: Option<String>,
    hash: String,
}

/// Served files with extension `ext` (sorted, at most 2000, four levels deep, hidden and `target` skipped),
/// named relative to the current directory where possible.
fn list_files(roots: &Roots, ext: &str) -> Vec<String> {
    let cwd = std::env::current_dir().ok().and_then(|c| std::fs::canonicalize(c).ok());
    let mut out = vec![];
    fn walk(dir: &Path, depth: usize, ext: &str, out: &mut Vec<PathBuf>) {
        let Ok(rd) = std::fs::read_dir(dir) else { return };
        for e in rd.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if name.starts_with('.') || name == "target" || out.len() >= 2000 {
                continue;
            }
            let Ok(t) = e.file_type() else { continue };
            let p = e.path();
            if t.is_dir() && depth > 0 {
                walk(&p, depth - 1, ext, out);
            } else if t.is_file() && p.extension().is_some_and(|x| x == ext) {
                out.push(p);
            }
        }
    }
    for d in roots.dirs() {
        walk(d, 4, ext, &mut out);
    }
    let mut names: Vec<String> = out
        .iter()
        .map(|p| match &cwd {
            Some(c) => p.strip_prefix(c).unwrap_or(p).display().to_string(),
            None => p.display().to_string(),
        })
        .collect();
    names.sort();
    names.dedup();
    names
}

/// `GET /api/file?path=…`: a served file's text and content hash.
pub(crate) fn file(st: &State, path: &str) -> Result<Reply, ApiError> {
    let p = st.roots.resolve(path)?;
    let bytes = read_limited(&p, crate::base::source::MAX_SOURCE_BYTES as u64)?;
    let hash = content_hash(&bytes);
    let text = String::from_utf8(bytes).map_err(|_| ApiError::new(422, format!("`{path}` is not UTF-8 text")))?;
    Ok(Reply::ok_report(&FileReply { path: path.to_string(), text: Some(text), hash }))
}

fn read_limited(p: &Path, max: u64) -> Result<Vec<u8>, ApiError> {
    use crate::base::source::{read_regular_file, ReadError};
    read_regular_file(p, max).map_err(|e| match e {
        ReadError::Io(e) => ApiError::new(404, format!("cannot read `{}`: {e}", p.display())),
        ReadError::NotRegular => ApiError::new(403, format!("`{}` is not a regular file", p.display())),
        ReadError::TooLarge => ApiError::new(413, format!("`{}` is larger than {} KiB", p.display(), max / 1024)),
        ReadError::Refused(why) => ApiError::new(403, format!("`{}`: {why}", p.display())),
    })
}

/// `POST /api/compile {name, text}`: parameters (with ranges), inputs, the simplified formula, warnings.
pub(crate) fn compile(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    limited(st, gone, move |st| {
        let (name, text) = formula_field(&req)?;
        let c = st.compiled(&name, &text)?;
        let f = &c.kernel().formula;
        // A parameter is read when any channel's compiled formula reads it (the page shows sliders for those only).
        let read: Vec<&str> = c
            .kernels
            .iter()
            .flat_map(|k| k.formula.ir.used_params(k.formula.root).into_iter().map(|i| k.formula.params[i as usize].name.as_str()))
            .collect();
        let params = f
            .params
            .iter()
            .map(|p| {
                let read = read.contains(&p.name.as_str());
                CompiledParam { name: p.name.clone(), default: p.default, lo: p.lo, hi: p.hi, read }
            })
            .collect();
        Ok(Reply::ok_report(&CompileReply {
            name: f.display_name().to_string(),
            params,
            used_inputs: f.used_inputs().iter().map(|i| i.name()).collect(),
            simplified: f.to_text(),
            parse_us: c.parse_us,
            compile_us: c.kernel().compile_time.as_secs_f64() * 1e6,
            warnings: c.warnings.to_json(),
        }))
    })
}

/// The `/api/compile` reply.
#[derive(serde::Serialize)]
struct CompileReply {
    name: String,
    params: Vec<CompiledParam>,
    used_inputs: Vec<&'static str>,
    simplified: String,
    parse_us: f64,
    compile_us: f64,
    warnings: Value,
}

/// A declared parameter for the page's sliders (the range's ends follow [`crate::base::json`]).
#[derive(serde::Serialize)]
struct CompiledParam {
    name: String,
    default: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    lo: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    hi: f64,
    /// Whether the compiled formula reads it (a declared parameter it never reads changes nothing).
    read: bool,
}

/// `POST /api/render {name, text, path, params, moved, size, scene, exact, spp}`: `scene` (a served `.toml`; `""`
/// for the built-in paper sphere; absent: the server's scene) with every material's formula replaced by the
/// page's, at the values [`scene_set`] picks from `params`. Parameters live unless `exact`, which compiles as
/// `lobe render` does (values baked, through the accuracy pass), so the bytes equal the CLI's: the page asks for
/// it when the sliders rest. PNG, with the server-side time in `X-Lobe-Render-Ms` and the count of NaN/inf
/// shading values in `X-Lobe-Nan`.
///
/// A scene the ray tracer renders (an `[environment]`, `shadows = true`) renders at `spp` samples per pixel
/// (1..=65536; absent: the scene's `spp`, as `lobe render`), priced per camera sample against the cost budget
/// ([`trace_evals`]: a level over it is refused with 422 before it starts); the reply then says the level in
/// `X-Lobe-Spp`, the scene's own `spp` in `X-Lobe-Scene-Spp`, and the next level of the series
/// [`crate::render::trace::levels`] of the scene's spp in `X-Lobe-Next-Spp` (absent after the last). The page
/// refines through them: live frames at 1 spp and at most 128² while the sliders move, then exact frames at 1,
/// 4, 16, … spp at the chosen size, each replacing the last, until the scene's spp, a level the budget refuses,
/// or a newer request. An exact frame at `spp` is the command
/// line's render at that many samples per pixel, byte for byte.
pub(crate) fn render(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    limited(st, gone, move |st| {
        let t = Instant::now();
        let (name, text) = formula_field(&req)?;
        let size = size_field(st, &req)?;
        let scene = scene_field(st, &req)?;
        let exact = req.get("exact").and_then(Value::as_bool).unwrap_or(false);
        let spp = spp_field(&req)?;
        let c = st.compiled(&name, &text)?;
        check_cost(st, c.kernel(), (size * size) as f64, "this render")?;
        let g = st.geometry(scene.as_deref(), size)?;
        // The ray tracer's level: priced per camera sample before it starts.
        let traced = crate::render::trace::traced(&g.scene).then(|| (spp.unwrap_or(g.scene.spp), g.scene.spp));
        if let Some((level, _)) = traced {
            check_cost(st, c.kernel(), trace_evals(c.kernel(), size * size * level), "this render at this many samples per pixel")?;
        }
        let set = scene_set(st, &req, &g)?;
        let sc = if exact {
            g.with_materials(&set, Some((&name, &text)), &commands_compiler(&st.cancel))?
        } else {
            g.with_materials(&set, Some((&name, &text)), &Live(st))?
        };
        let opts = RenderOptions { spp: traced.map(|(level, _)| level), ..ropts(&st.cancel) };
        let (frame, stats) = crate::render::render(&sc, &opts).map_err(|e| ApiError::new(500, e))?;
        let bytes = png(&frame.image)?;
        let mut reply = Reply::bytes("image/png", bytes)
            .header("X-Lobe-Render-Ms", format!("{:.3}", t.elapsed().as_secs_f64() * 1e3))
            .header("X-Lobe-Nan", stats.nan.to_string());
        if let Some((level, scene_spp)) = traced {
            reply = reply.header("X-Lobe-Spp", level.to_string()).header("X-Lobe-Scene-Spp", scene_spp.to_string());
            // The refinement's next level after this one, if any: the page follows the series it does not compute.
            if let Some(next) = crate::render::trace::levels(scene_spp).into_iter().find(|&l| l > level) {
                reply = reply.header("X-Lobe-Next-Spp", next.to_string());
            }
        }
        Ok(reply)
    })
}

/// A traced camera sample in kernel evaluations for [`check_cost`] (which multiplies by the formula's IR
/// nodes): [`TRACE_EVALS_PER_SAMPLE`] evaluations, plus the rays and the map's sampling, [`TRACE_RAY_COST`]
/// budget units whatever the formula.
fn trace_evals(k: &Kernel, samples: usize) -> f64 {
    samples as f64 * (TRACE_EVALS_PER_SAMPLE + TRACE_RAY_COST / k.formula.ir.len().max(1) as f64)
}

/// Evaluations of F (and of the sampler's density) per traced camera sample, per channel counted once: the
/// sampled direction's F and both densities, and the point lights'.
const TRACE_EVALS_PER_SAMPLE: f64 = 8.0;

/// A traced camera sample's fixed part in the budget's units (~1 ns): the camera ray and the shadow ray
/// through the BVH, the map's 2-D sampling and density, the pilot's share. Measured 2026-12-07 on
/// environment.toml (GGX, 146 IR nodes, 256², 1 to 16 spp, 2 threads on a 2-core machine at a load of 8–11):
/// 1.7–6 µs of wall time per sample in all; priced at ~3.2 µs, a 256² image affords 16 spp under the default
/// budget (about 2–6 s, inside the deadline) and 512² 4.
const TRACE_RAY_COST: f64 = 2000.0;

/// `spp` of a render request: the ray tracer's samples per pixel, 1..=[`crate::render::trace::MAX_SPP`]
/// (absent: the scene's `spp`; a rasterised scene ignores it).
fn spp_field(v: &Value) -> Result<Option<usize>, ApiError> {
    let max = crate::render::trace::MAX_SPP;
    match v.get("spp") {
        None | Some(Value::Null) => Ok(None),
        Some(x) => match x.as_u64() {
            Some(n) if (1..=max as u64).contains(&n) => Ok(Some(n as usize)),
            Some(n) => Err(ApiError::bad(format!("spp {n} is outside 1..={max}")).hint("the page refines through 1, 4, 16, … up to the scene's spp")),
            None => Err(ApiError::bad("`spp` must be a whole number of samples per pixel").hint(format!("e.g. \"spp\": 16; 1..={max}"))),
        },
    }
}

/// The scene of a page request: `scene` names a served `.toml` file, `""` the built-in paper sphere; without
/// it, the scene the server was started with.
fn scene_field(st: &State, v: &Value) -> Result<Option<PathBuf>, ApiError> {
    match v.get("scene") {
        None | Some(Value::Null) => Ok(st.scene.clone()),
        Some(Value::String(s)) if s.is_empty() => Ok(None),
        Some(Value::String(s)) => {
            let p = st.roots.resolve(s)?;
            if p.extension().is_none_or(|e| e != "toml") {
                return Err(ApiError::bad(format!("`{s}` is not a scene (.toml) file")).hint("pick a scene from the page's list"));
            }
            Ok(Some(p))
        }
        Some(_) => Err(ApiError::bad("`scene` must be a path string")),
    }
}

/// The values a scene render applies, as the render command applies a run's values. When a material's own
/// formula is the page's file (`path`), only the parameters the page has `moved`: each material keeps its scene
/// values for the others (a scene of two materials of one formula stays two materials). Otherwise every value
/// in `params`: the scene's values were written for another formula, and the page's formula renders at the
/// page's values.
fn scene_set(st: &State, req: &Value, g: &Geometry) -> Result<Vec<(String, f64)>, ApiError> {
    let set = params_field(req)?;
    let own = req.get("path").and_then(Value::as_str).and_then(|p| st.roots.resolve(p).ok());
    let shared = own.is_some_and(|own| g.material_files().iter().any(|f| std::fs::canonicalize(f).is_ok_and(|f| f == own)));
    if !shared {
        return Ok(set);
    }
    let moved: Vec<&str> =
        req.get("moved").and_then(Value::as_array).map(|a| a.iter().filter_map(Value::as_str).collect()).unwrap_or_default();
    Ok(set.into_iter().filter(|(k, _)| moved.contains(&k.as_str())).collect())
}

/// `POST /api/compare {a: {name, text}, b: {name, text}, path, params, moved, size, scene}`: A | B | heat map as PNG,
/// the figure `lobe compare` draws (headings, the heat map's labelled colour bar from 0 to the largest
/// difference); the metrics (`manhattan`,
/// `manhattan_covered`, `max_gray_diff`, `rmse`, `psnr`) as JSON in `X-Lobe-Metrics`, the gray difference
/// the bar's right end stands for in `X-Lobe-Heat-Scale`.
pub(crate) fn compare(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    limited(st, gone, move |st| {
        let a = formula_field(req.get("a").ok_or_else(|| ApiError::bad("missing `a`"))?)?;
        let b = formula_field(req.get("b").ok_or_else(|| ApiError::bad("missing `b`"))?)?;
        let size = size_field(st, &req)?;
        let scene = scene_field(st, &req)?;
        for (n, t) in [&a, &b] {
            check_cost(st, st.compiled(n, t)?.kernel(), (size * size) as f64, "this comparison")?;
        }
        let g = st.geometry(scene.as_deref(), size)?;
        let set = scene_set(st, &req, &g)?;
        let c = crate::render::compare::compare_in(&g, (&a.0, &a.1), (&b.0, &b.1), [[1.0; 3]; 2], &set, &Live(st), &ropts(&st.cancel))?;
        let scale = c.metrics.max_gray_diff.max(1.0);
        let pair = crate::render::compare::side_by_side(&c.a.image, &c.b.image, scale);
        let image = crate::report::plot::comparison_figure(&pair, ["A", "B", "|Δgray|"], &[], scale).map_err(|e| ApiError::new(500, e))?;
        let metrics = serde_json::to_string(&c.metrics).map_err(|e| ApiError::new(500, e.to_string()))?;
        Ok(Reply::bytes("image/png", png(&image)?)
            .header("X-Lobe-Metrics", metrics)
            .header("X-Lobe-Heat-Scale", format!("{scale}")))
    })
}

/// `POST /api/plot {formulas: [{name, text}…], params, polar, theta_i, phi_i}`: up to four formulas overlaid.
/// With `theta_i` (degrees, 0..90) the curves are in the plane of incidence at azimuth `phi_i` (degrees) with
/// the light there, else the lobes under the lobe convention; polar plots are to scale. All-NaN curves are a
/// 422 that says so.
pub(crate) fn plot(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    limited(st, gone, move |st| {
        let set = params_field(&req)?;
        let polar = req.get("polar").and_then(Value::as_bool).unwrap_or(false);
        let incidence = incidence_field(&req)?;
        let list = req.get("formulas").and_then(Value::as_array).ok_or_else(|| ApiError::bad("missing `formulas` array"))?;
        if list.is_empty() || list.len() > 4 {
            return Err(ApiError::bad("plot 1 to 4 formulas"));
        }
        let mut series = vec![];
        for f in list {
            let (name, text) = formula_field(f)?;
            let k = st.compiled(&name, &text)?.kernel().clone();
            let own: Vec<(String, f64)> = set.iter().filter(|(n, _)| k.formula.param_index(n).is_some()).cloned().collect();
            let params = values(&k, &own)?;
            let points = match incidence {
                Some((ti, pi)) => crate::report::plot::incidence_points_at(k.as_ref(), &params, ti, pi),
                None => crate::report::plot::lobe_points(k.as_ref(), k.used_inputs(), &params),
            };
            series.push(crate::report::plot::Series { name: k.formula.display_name(), points });
        }
        if let Some(s) = series.iter().find(|s| !s.points.iter().any(|p| p.1.is_finite())) {
            return Err(ApiError::new(422, format!("nothing to plot: `{}` is NaN or infinite at every sampled angle", s.name))
                .hint("0/0 and ∞−∞ are NaN; a sweep of the formula over its domain shows where it is undefined"));
        }
        let n = set.iter().find(|(k, _)| k == "n").map(|(_, v)| format!("n = {v}")).unwrap_or_default();
        let opts = crate::report::plot::LobeOptions { title: format!("Lobes {n}"), polar, log: false, size: (560, 400), ylim: None, value: crate::report::plot::VALUE };
        let bytes = match incidence {
            Some((ti, _)) => crate::report::plot::incidence_lobes(&series, &opts, ti, crate::report::plot::Format::Png),
            None => crate::report::plot::lobes(&series, &opts, crate::report::plot::Format::Png),
        };
        Ok(Reply::bytes("image/png", bytes.map_err(|e| ApiError::new(500, e))?))
    })
}

/// `POST /api/analyze {name, text, params, reference: {name, text}}`: the energy coefficient, ρ(θᵢ) and its maximum
/// (and the incidence angle of the maximum), the papers' error metrics against the reference, ns/eval of the compiled
/// kernel (scalar and batched JIT, interpreter) and its compile time.
pub(crate) fn analyze(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    limited(st, gone, move |st| {
        let (name, text) = formula_field(&req)?;
        let set = params_field(&req)?;
        let k = st.compiled(&name, &text)?.kernel().clone();
        // The accuracy grid (91 000 points plus fine grids per n) dominates.
        check_cost(st, &k, 2.0e6, "this analysis")?;
        let params = values(&k, &set)?;
        let mut out = AnalyzeReply::default();
        // The lobe coefficient is a one-cosine lobe's energy; of anything else it means nothing.
        match crate::numerics::one_lobe_cosine(k.used_inputs()).map(|_| crate::numerics::normalize::coefficient(k.as_ref(), k.used_inputs(), &params)) {
            Some(Ok(c)) => out.coef = Some(c),
            Some(Err(e)) => out.coef_error = Some(e.message),
            None => out.coef_error = Some("only a lobe of one cosine (NH or VR) has a lobe coefficient: see the albedo".into()),
        }
        match crate::numerics::energy::full_energy_cancellable(k.as_ref(), k.used_inputs(), &params, &st.cancel) {
            Ok(e) => {
                out.albedo_max = Some(e.albedo_max);
                out.theta_i_at_max_deg = Some(e.theta_i_at_max_deg);
                out.albedo = e.albedo;
            }
            Err(e) => out.albedo_error = Some(e.message),
        }
        if let Some(r) = req.get("reference") {
            let (rn, rt) = formula_field(r)?;
            let rk = st.compiled(&rn, &rt)?.kernel().clone();
            let rp = rk.default_params();
            out.reference = Some(rk.formula.display_name().to_string());
            if k.formula.reads_param("n") && rk.formula.reads_param("n") {
                let lobe = crate::numerics::choose_lobe_input(k.used_inputs()).0;
                let rlobe = crate::numerics::choose_lobe_input(rk.used_inputs()).0;
                let opts = crate::numerics::accuracy::AccuracyOptions { cancel: st.cancel.clone(), ..Default::default() };
                let a = crate::numerics::accuracy::accuracy(k.as_ref(), &params, lobe, rk.as_ref(), &rp, rlobe, &opts)?;
                out.mean_abs_grid = Some(a.mean_abs_grid);
                out.epicenter_max_rel_pct = Some(a.epicenter.value * 100.0);
                out.max_abs = Some(a.max_abs.value);
            } else {
                // The papers' metrics sweep n in both: without it, the measured fits' metrics over the whole
                // hemisphere (every fourth table index per axis, both formulas at their values).
                use crate::numerics::measured::{residuals, turns_with_the_frame, FormulaReference, Reference};
                let channels: Vec<Arc<dyn crate::Evaluator>> = vec![rk.clone()];
                let azimuths = !(turns_with_the_frame(k.as_ref(), &params) && turns_with_the_frame(rk.as_ref(), &rp));
                let samples = FormulaReference { name: rn, channels, params: rp, azimuths, fit_scale: false }.samples(4);
                st.cancel.check().map_err(|c| ApiError::new(503, c.to_string()))?;
                let [log, rmse, cosine] = residuals(&[k.as_ref()], &params, &samples).map(|r| r.error);
                out.hemisphere = Some(HemisphereError { entries: samples.len(), log, rmse, cosine });
            }
        }
        let m = crate::report::measure::measure_kernel(&k, &params, crate::report::measure::MeasureOptions { points: 2048, samples: 9 })
            .map_err(|e| ApiError::new(422, e.to_string()))?;
        out.jit_ns = m.scalar_jit.median_ns;
        out.jit_batch_ns = m.batched_jit.median_ns;
        out.interp_ns = m.interp.median_ns;
        out.compile_us = m.compile.as_secs_f64() * 1e6;
        Ok(Reply::ok_report(&out))
    })
}

/// The `/api/analyze` reply: each check's value, or its `_error` when it failed; the accuracy metrics only
/// with a reference. Numbers follow [`crate::base::json`].
#[derive(Default, serde::Serialize)]
struct AnalyzeReply {
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    coef: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    coef_error: Option<String>,
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    albedo_max: Option<f64>,
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    theta_i_at_max_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    albedo_error: Option<String>,
    /// ρ(θᵢ): (θᵢ in degrees, albedo) at 0°, 1°, …, 89°, 89.9° (the maximum over φᵢ for an anisotropic formula).
    albedo: Vec<(f64, f64)>,
    #[serde(skip_serializing_if = "Option::is_none")]
    reference: Option<String>,
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    mean_abs_grid: Option<f64>,
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    epicenter_max_rel_pct: Option<f64>,
    #[serde(serialize_with = "crate::base::json::opt_num", skip_serializing_if = "Option::is_none")]
    max_abs: Option<f64>,
    /// Against a reference where the formula or the reference reads no n (the papers' metrics sweep it).
    #[serde(skip_serializing_if = "Option::is_none")]
    hemisphere: Option<HemisphereError>,
    #[serde(serialize_with = "crate::base::json::num")]
    jit_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    jit_batch_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    interp_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    compile_us: f64,
}

/// The measured fits' metrics of a formula against its reference over the whole hemisphere (no colour scale).
#[derive(serde::Serialize)]
struct HemisphereError {
    entries: usize,
    #[serde(serialize_with = "crate::base::json::num")]
    log: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    rmse: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    cosine: f64,
}

/// `POST /api/save {path, text, hash, force}`: writes a served `.brdf` file atomically. Refused with 409 when
/// the file on disk no longer has the `hash` the page loaded (someone else changed it), unless `force`.
pub(crate) fn save(st: &State, req: &Value) -> Result<Reply, ApiError> {
    let path = str_field(req, "path")?;
    let text = str_field(req, "text")?;
    let force = req.get("force").and_then(Value::as_bool).unwrap_or(false);
    let p = st.roots.resolve(path)?;
    if p.extension().is_none_or(|e| e != "brdf") {
        return Err(ApiError::new(403, format!("`{path}` is not a .brdf file")).hint("the page saves formula files only"));
    }
    if text.len() > st.limits.formula_bytes {
        return Err(ApiError::new(413, format!("the formula is larger than {} KiB", st.limits.formula_bytes / 1024)));
    }
    let now = content_hash(&read_limited(&p, crate::base::source::MAX_SOURCE_BYTES as u64)?);
    if !force && req.get("hash").and_then(Value::as_str) != Some(now.as_str()) {
        return Err(ApiError::new(409, format!("`{path}` changed on disk since it was loaded"))
            .hint("reload it to see the change, or save again to overwrite it"));
    }
    crate::base::output::write_atomic(&p, text.as_bytes()).map_err(|e| ApiError::new(500, e))?;
    Ok(Reply::ok_report(&FileReply { path: path.to_string(), text: None, hash: content_hash(text.as_bytes()) }))
}

/// `GET /render.png?file=SCENE&set=n=50&size=256`: exactly what rendering SCENE with n = 50 at size 256 gives (JIT,
/// linear transfer, default tiles and threads), so the bytes equal the CLI's output file.
pub(crate) fn render_png(st: &Arc<State>, gone: &Cancel, query: &str) -> Result<Reply, ApiError> {
    let mut file = None;
    let mut set = vec![];
    let mut size = None;
    for (k, v) in http::query_pairs(query)? {
        match k.as_str() {
            "file" => file = Some(v),
            "set" => set.extend(crate::front::parse_assignments(&v).map_err(|e| ApiError::bad(format!("set: {e}")))?),
            "size" => size = Some(crate::render::parse_size(&v).map_err(|e| ApiError::bad(format!("size: {e}")))?),
            other => return Err(ApiError::bad(format!("unknown query parameter `{other}`")).hint("use file=SCENE.toml, set=n=50, size=256")),
        }
    }
    let file = file.ok_or_else(|| ApiError::bad("missing `file`").hint("/render.png?file=examples/scenes/paper_sphere.toml&size=256"))?;
    let path = st.roots.resolve(&file)?;
    let max = st.limits.max_size;
    if let Some((w, h)) = size {
        if w > max || h > max {
            return Err(ApiError::bad(format!("size {w}×{h} is over the server's {max}×{max}")).hint("rendering outside the page has no such cap"));
        }
    }
    limited(st, gone, move |st| {
        // The scene's own size when none is given: read it with the geometry, then check the cap. The scene
        // and every file it names are read through the served-files policy.
        let files = ServedFiles::new(&st.roots);
        let g = scene::load_geometry(&path, size, &Files::new(files.clone())).map_err(scene_error(&files))?;
        let (w, h) = (g.scene.width, g.scene.height);
        if w > st.limits.max_size || h > st.limits.max_size {
            return Err(ApiError::bad(format!("the scene is {w}×{h}, over the server's {max}×{max}")).hint("pass a smaller size="));
        }
        let opts = LoadOptions { size, set, formula_override: None, files: Files::new(files.clone()) };
        let sc = scene::load_scene(&path, &opts, &commands_compiler(&st.cancel)).map_err(scene_error(&files))?;
        let (frame, _) = crate::render::render(&sc, &ropts(&st.cancel)).map_err(|e| ApiError::new(500, e))?;
        Ok(Reply::bytes("image/png", png(&frame.image)?))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn state(deadline_ms: u64, max_jobs: usize, light_jobs: usize) -> Arc<State> {
        let limits = Limits { deadline: Duration::from_millis(deadline_ms), max_jobs, light_jobs, ..Limits::default() };
        Arc::new(State::new(Roots::new(&[std::env::temp_dir()]).unwrap(), None, vec![], limits))
    }

    #[test]
    fn late_jobs_are_stopped_and_free_their_slots() {
        let st = state(50, 1, 0);
        // A job that polls its token until it trips: stopped at the deadline, 503, and its slot is free at once.
        let t = std::time::Instant::now();
        let e = limited(&st, &Cancel::never(), |job| {
            while job.cancel.check().is_ok() {
                std::thread::sleep(Duration::from_millis(1));
            }
            Err::<(), _>(ApiError::new(500, "stopped"))
        })
        .unwrap_err();
        assert_eq!(e.status, 503);
        assert!(e.error.message.contains("longer than") && e.error.message.contains("stopped"), "{}", e.error);
        assert!(t.elapsed() < Duration::from_secs(20), "the job ran on past its deadline");
        assert_eq!(st.jobs.load(Ordering::SeqCst), 0);
        assert_eq!(limited(&st, &Cancel::never(), |_| Ok(8)).unwrap(), 8, "the slot is free again");
        // While a job runs, a second one is refused as busy.
        let st = state(30_000, 1, 0);
        let busy = limited(&st, &Cancel::never(), |_| Ok(limited(&st, &Cancel::never(), |_| Ok(())).unwrap_err())).unwrap();
        assert!(busy.status == 503 && busy.error.message.contains("busy"), "{}", busy.error);
        // A panicking job (the panic message below in the test output is expected) is a 500 and frees its slot.
        assert_eq!(limited(&st, &Cancel::never(), |_| -> Result<(), ApiError> { panic!("expected panic in a test job") }).unwrap_err().status, 500);
        assert_eq!(limited(&st, &Cancel::never(), |_| Ok(9)).unwrap(), 9);
    }

    #[test]
    fn formulas_over_the_cost_budget_are_refused_before_running() {
        let st = state(10_000, 2, 2);
        let heavy: String = (0..400).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0";
        let c = st.compiled("h.brdf", &heavy, &Cancel::never()).unwrap();
        assert!(c.warnings.items.iter().any(|d| d.message.contains("accuracy pass was skipped")), "the pass is priced too");
        let k = c.kernel().clone();
        assert!(limited(&st, &Cancel::never(), |job| check_cost(job, &k, 64.0 * 64.0, "a small render")).is_ok());
        let e = limited(&st, &Cancel::never(), |job| check_cost(job, &k, 2048.0 * 2048.0, "this render")).unwrap_err();
        assert_eq!(e.status, 422);
        assert_eq!(st.compiled("big.brdf", &"1+".repeat(40 << 10), &Cancel::never()).err().map(|e| e.status), Some(413));
        assert_eq!(content_hash(b"NH^n"), content_hash(b"NH^n"));
        assert_ne!(content_hash(b"NH^n"), content_hash(b"NH^m"));
    }

    #[test]
    fn heavy_jobs_leave_the_light_lane_free() {
        // One heavy slot and one light one: a heavy job holds its slot; a second heavy job is refused as busy, a
        // light job beside it runs; with both lanes full, any job is refused; slots are free after.
        let st = state(30_000, 1, 1);
        let k = st.compiled("h.brdf", &((0..300).map(|i| format!("sin(NH*{i}.5) + ")).collect::<String>() + "0"), &Cancel::never()).unwrap().kernel().clone();
        let heavy_evals = st.limits.light_cost / k.formula.ir.len() as f64 * 2.0;
        let inner = limited(&st, &Cancel::never(), |job| {
            check_cost(job, &k, heavy_evals, "a heavy render")?;
            let second = limited(&st, &Cancel::never(), |j2| check_cost(j2, &k, heavy_evals, "another heavy render")).unwrap_err();
            let light = limited(&st, &Cancel::never(), |j2| check_cost(j2, &k, 16.0, "a light render").map(|()| 7));
            Ok((second, light))
        })
        .unwrap();
        assert!(inner.0.status == 503 && inner.0.error.message.contains("heavy"), "{}", inner.0.error);
        assert_eq!(inner.1.unwrap(), 7);
        let full = limited(&st, &Cancel::never(), |_| Ok(limited(&st, &Cancel::never(), |_| Ok(limited(&st, &Cancel::never(), |_| Ok(())).unwrap_err())).unwrap())).unwrap();
        assert_eq!(full.status, 503);
        assert_eq!((st.jobs.load(Ordering::SeqCst), st.heavy.load(Ordering::SeqCst)), (0, 0));
        assert!(limited(&st, &Cancel::never(), |job| check_cost(job, &k, heavy_evals, "a heavy render")).is_ok(), "the heavy slot is free again");
    }
}
