//! `lobe._lobe`: the native half of the Python package `lobe` (the Python half, `lobe/__init__.py`, does the
//! numpy broadcasting and the Pythonic surface). Everything here is a thin layer over the `lobe` crate:
//! formulas compile as `lobe eval` compiles them ([`lobe::numerics::pass_cache::command_channels`]), so values
//! are the command's bits; the reports are the commands' JSON types, built by the same library functions.
//!
//! Errors are `lobe.LobeError` carrying the diagnostics; a panic anywhere below is caught and raised as a
//! `LobeError` too, never an abort of the interpreter. Evaluation releases the GIL and splits large batches over
//! rayon's threads.

use lobe::base::diag::{Diagnostic, Diagnostics};
use lobe::ir::{Formula, Input, N_INPUTS};
use lobe::numerics::points::evaluate_varying;
use lobe::numerics::robust::PassOptions;
use lobe::{Backend, Columns, Evaluator, Kernel, Mode, Tier};
use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2, PyReadwriteArray1, PyUntypedArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyList};
use rayon::prelude::*;
use lobe::bsdf::Sampler;
use std::borrow::Cow;
use std::sync::{Arc, Mutex};
use std::panic::{catch_unwind, AssertUnwindSafe};

mod pool;
mod tools;

create_exception!(lobe, LobeError, PyValueError, "A formula, a scene or an argument lobe cannot take: `.diagnostics` says where and why.");

/// Points per batched call when a batch is split over threads.
const CHUNK: usize = 1 << 14;

/// An error with no place in a source, from a message.
fn plain(file: &str, d: Diagnostic) -> Diagnostics {
    Diagnostics::single(file, d)
}

/// `LobeError` for `ds`: the message is the rendered caret text; `.diagnostics` is one dict per item with
/// `severity`, `message`, `file`, `line`, `column`, `end_line`, `end_column` (None without a place), `label`,
/// `hint` (the hints joined, or None), `hints` and `rendered`.
fn lobe_error(py: Python<'_>, ds: &Diagnostics) -> PyErr {
    let rendered = ds.render(false);
    let mut items = ds.to_json();
    if let Some(a) = items.as_array_mut() {
        for o in a.iter_mut().filter_map(serde_json::Value::as_object_mut) {
            let col = o.remove("col").unwrap_or(serde_json::Value::Null);
            let end_col = o.remove("end_col").unwrap_or(serde_json::Value::Null);
            o.insert("column".into(), col);
            o.insert("end_column".into(), end_col);
            for k in ["line", "end_line", "label"] {
                o.entry(k).or_insert(serde_json::Value::Null);
            }
            let hints: Vec<String> = o["hints"].as_array().map(|h| h.iter().filter_map(|x| x.as_str().map(String::from)).collect()).unwrap_or_default();
            o.insert("hint".into(), if hints.is_empty() { serde_json::Value::Null } else { hints.join("; ").into() });
        }
    }
    let err = LobeError::new_err(rendered.trim_end().to_string());
    let diags = json_to_py(py, &items.to_string()).unwrap_or_else(|_| PyList::empty(py).into_any().unbind());
    // Setting an attribute on a fresh exception does not fail; if it did, the message still says it all.
    let _ = err.value(py).setattr("diagnostics", diags);
    err
}

/// `d` naming the flat index of the point it is about.
fn at_index(mut d: Diagnostic, at: usize) -> Diagnostic {
    d.message = format!("{} (at flat index {at})", d.message);
    d
}

/// A `LobeError` for a message without a place.
fn msg_error(py: Python<'_>, file: &str, d: impl Into<Diagnostic>) -> PyErr {
    lobe_error(py, &plain(file, d.into()))
}

/// JSON text as Python objects (dicts, lists, floats…).
fn json_to_py(py: Python<'_>, text: &str) -> PyResult<Py<PyAny>> {
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

/// A report type as the plain dict of the CLI's `--json`.
fn report<T: serde::Serialize>(py: Python<'_>, v: &T) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(v).map_err(|e| msg_error(py, "", format!("cannot write the report: {e}")))?;
    json_to_py(py, &text)
}

/// The panic's message, for the `LobeError` that replaces it.
fn panic_text(p: Box<dyn std::any::Any + Send>) -> String {
    let what = p.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| p.downcast_ref::<String>().cloned()).unwrap_or_default();
    format!("internal error in lobe (a bug; please report it with the formula): {what}")
}

/// Runs `f` without the GIL, a panic in it caught and turned into a `LobeError`.
fn detached<T: Send>(py: Python<'_>, file: &str, f: impl FnOnce() -> Result<T, Diagnostics> + Send) -> PyResult<T> {
    match py.detach(|| catch_unwind(AssertUnwindSafe(f))) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(ds)) => Err(lobe_error(py, &ds)),
        Err(p) => Err(msg_error(py, file, panic_text(p))),
    }
}

fn math_mode(py: Python<'_>, math: &str) -> PyResult<Mode> {
    match math {
        "precise" => Ok(Mode::Precise),
        "fast" => Ok(Mode::Fast),
        _ => Err(msg_error(py, "", Diagnostic::error(format!("unknown math mode `{math}`")).hint("math is \"precise\" or \"fast\""))),
    }
}

/// A compiled formula: one kernel per channel, and what it was compiled from (which pickling keeps).
#[pyclass(frozen, module = "lobe._lobe")]
pub struct Native {
    /// The formula as lowered, before simplification (the checks start from it).
    whole: Formula,
    kernels: Vec<Kernel>,
    file: String,
    source: String,
    math: Mode,
    baked: Vec<(String, f64)>,
    /// Samplers built for `sample`/`pdf` (parameter vector, sampler), the most recent last; building one takes
    /// milliseconds, so calls at the same parameters reuse it.
    samplers: Mutex<Vec<(Vec<f64>, Arc<Sampler>)>>,
    /// The value-and-gradient kernel ([`lobe::numerics::grad::Gradient`]), compiled on the first `grad` call as
    /// `lobe eval --grad` compiles it.
    gradient: std::sync::OnceLock<Arc<lobe::numerics::grad::Gradient>>,
}

/// Samplers a kernel keeps (per parameter vector).
const SAMPLER_CACHE: usize = 4;

/// Points from Python: cosine columns (index in `Input::ALL`, values), L and V (`len` × 3), and `len`.
type Points<'py> = (Vec<(usize, PyReadonlyArray1<'py, f64>)>, Option<PyReadonlyArray2<'py, f64>>, Option<PyReadonlyArray2<'py, f64>>, usize);

/// `grad`'s result: the variables' names, the values and the partials (flat; see `Native::grad`).
type Gradients<'py> = (Vec<String>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// `sample`'s result: wo (`len` × 3), pdf, weights (`len` × channels) and the sampler's mechanism.
type Drawn<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, &'static str);

/// One fit candidate for Python: the full parameter vector, its score, and whether the refinement found it.
type FitCandidate = (Vec<f64>, f64, bool);

/// Batch columns: borrowed from numpy where given, computed from L and V otherwise.
struct Inputs<'a> {
    cols: [Cow<'a, [f64]>; N_INPUTS],
    len: usize,
}

impl Inputs<'_> {
    fn columns(&self) -> Columns<'_> {
        Columns::new(std::array::from_fn(|i| &*self.cols[i]))
    }
}

/// `k`'s batched kernel over every point of `cols` with parameters `params`, except those in `varying` (index,
/// one value per point), in `CHUNK`s over rayon's threads when there are many. Per-point parameters are
/// evaluated as `lobe eval --points` evaluates parameter columns ([`evaluate_varying`]): one batched call per
/// run of equal values, so each value is that point's, bit for bit.
fn eval_into(k: &Kernel, cols: &Columns, params: &[f64], varying: &[(usize, &[f64])], out: &mut [f64]) {
    if out.len() <= CHUNK {
        return evaluate_varying(k, cols, params, varying, out);
    }
    out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, o)| {
        let r = c * CHUNK..c * CHUNK + o.len();
        let part = cols.cols.map(|col| if col.is_empty() { col } else { &col[r.clone()] });
        let vary: Vec<(usize, &[f64])> = varying.iter().map(|(i, v)| (*i, &v[r.clone()])).collect();
        evaluate_varying(k, &Columns::new(part), params, &vary, o);
    });
}

/// The kernel inputs from unit (or normalised, as `lobe eval --points` does) L and V rows of `l` and `v`
/// (`len` × 3, row-major), for the inputs in `used`; `Err(i)`: row `i` has a zero or non-finite L or V.
fn from_directions(l: &[f64], v: &[f64], len: usize, used: lobe::ir::InputSet) -> Result<[Vec<f64>; N_INPUTS], usize> {
    let mut cols: [Vec<f64>; N_INPUTS] = std::array::from_fn(|i| if used.contains(Input::ALL[i]) { vec![0.0; len] } else { vec![] });
    let mut chunks: Vec<Vec<(usize, &mut [f64])>> = (0..len.div_ceil(CHUNK)).map(|_| vec![]).collect();
    for (i, col) in cols.iter_mut().enumerate() {
        for (c, part) in col.chunks_mut(CHUNK).enumerate() {
            chunks[c].push((i, part));
        }
    }
    let bad = chunks.into_par_iter().enumerate().filter_map(|(c, mut parts)| {
        for r in c * CHUNK..((c + 1) * CHUNK).min(len) {
            let row = |a: &[f64]| [a[3 * r], a[3 * r + 1], a[3 * r + 2]];
            let (Some((lu, _)), Some((vu, _))) = (lobe::numerics::points::unit(row(l)), lobe::numerics::points::unit(row(v))) else {
                return Some(r);
            };
            let x = lobe::Frame::LOCAL.inputs(lu, vu);
            for (i, part) in parts.iter_mut() {
                part[r - c * CHUNK] = x[*i];
            }
        }
        None
    });
    match bad.min() {
        Some(r) => Err(r),
        None => Ok(cols),
    }
}

impl Native {
    /// Every point through every channel's batched kernel into `out` (`len` values per channel, channel after
    /// channel): what `eval` and `eval_out` share.
    fn fill<'py>(&self, py: Python<'py>, points: Points<'py>, params: Vec<f64>, varying: Vec<(usize, PyReadonlyArray1<'py, f64>)>, out: &mut [f64]) -> PyResult<()> {
        self.check_params(py, &params)?;
        let (cos, l, v, len) = points;
        let inputs = self.batch(py, &cos, l.as_ref(), v.as_ref(), len)?;
        let varying = self.varying(py, &varying, len)?;
        detached(py, &self.file, || {
            let cols = inputs.columns();
            for (k, o) in self.kernels.iter().zip(out.chunks_mut(len.max(1))) {
                eval_into(k, &cols, &params, &varying, o);
            }
            Ok(())
        })
    }

    fn formula(&self) -> &Formula {
        &self.kernels[0].formula
    }

    /// The value-and-gradient kernel, compiled the first time (the accuracy pass and its cache as `compile`).
    fn gradient(&self, py: Python<'_>) -> PyResult<Arc<lobe::numerics::grad::Gradient>> {
        if let Some(g) = self.gradient.get() {
            return Ok(g.clone());
        }
        let g = detached(py, &self.file, || {
            let opts = lobe::Options { backend: Backend::Jit, bake: self.baked.clone(), math: self.math, ..lobe::Options::default() };
            let opts = lobe::numerics::pass_cache::command_pass(opts, PassOptions::default(), true);
            lobe::numerics::grad::Gradient::compile(&self.whole, &opts).map(Arc::new)
        })?;
        Ok(self.gradient.get_or_init(|| g).clone())
    }

    fn used(&self) -> lobe::ir::InputSet {
        self.kernels.iter().map(Kernel::used_inputs).collect()
    }

    fn error(&self, py: Python<'_>, d: Diagnostic) -> PyErr {
        msg_error(py, &self.file, d)
    }

    /// The batch columns from cosine arrays (`cos`: index in `Input::ALL` and values) or L and V arrays.
    fn batch<'a>(
        &self,
        py: Python<'_>,
        cos: &'a [(usize, PyReadonlyArray1<'a, f64>)],
        l: Option<&'a PyReadonlyArray2<'a, f64>>,
        v: Option<&'a PyReadonlyArray2<'a, f64>>,
        len: usize,
    ) -> PyResult<Inputs<'a>> {
        let used = self.used();
        let contiguous = |py: Python<'_>| self.error(py, Diagnostic::error("an input array is not contiguous float64 (lobe's Python side makes it so: a bug)"));
        let mut cols: [Cow<'a, [f64]>; N_INPUTS] = Default::default();
        for (i, a) in cos {
            let s = a.as_slice().map_err(|_| contiguous(py))?;
            if s.len() != len {
                return Err(self.error(py, Diagnostic::error(format!("{} has {} values for {len} points", Input::ALL[*i].name(), s.len()))));
            }
            if used.contains(Input::ALL[*i]) {
                cols[*i] = Cow::Borrowed(s);
            }
        }
        match (l, v) {
            (Some(l), Some(v)) => {
                if !cos.is_empty() {
                    return Err(self.error(py, Diagnostic::error("both directions (L, V) and cosines").hint("with L and V every cosine is computed from them; drop the cosines")));
                }
                let (ls, vs) = (l.as_slice().map_err(|_| contiguous(py))?, v.as_slice().map_err(|_| contiguous(py))?);
                if l.shape() != [len, 3] || v.shape() != [len, 3] {
                    return Err(self.error(py, Diagnostic::error("L and V must have shape (..., 3)")));
                }
                let dirs = py.detach(|| from_directions(ls, vs, len, used));
                let computed = dirs.map_err(|r| {
                    self.error(py, Diagnostic::error(format!("L or V at flat index {r} has no direction")).hint("L and V are directions: three finite components, not all 0"))
                })?;
                for (i, c) in computed.into_iter().enumerate() {
                    if !c.is_empty() {
                        cols[i] = Cow::Owned(c);
                    }
                }
            }
            (None, None) => {
                if used.reads_directions() {
                    let reads: Vec<&str> = used.iter().filter(|i| i.is_direction()).map(Input::name).collect();
                    return Err(self.error(py, Diagnostic::error(format!("the formula reads directions ({})", reads.join(", "))).hint("give L and V, arrays of shape (..., 3) in the local frame (N = +z)")));
                }
                let missing: Vec<&str> = used.iter().filter(|i| cols[i.index()].is_empty()).map(Input::name).collect();
                if !missing.is_empty() && len > 0 {
                    return Err(self.error(py, Diagnostic::error(format!("the formula reads {}, which was not given", missing.join(", "))).hint(format!("give {} (or L and V)", missing.join(", ")))));
                }
            }
            _ => return Err(self.error(py, Diagnostic::error("L without V, or V without L").hint("give both directions"))),
        }
        Ok(Inputs { cols, len })
    }

    /// A full parameter vector from Python: the right length, each value in its declared range.
    fn check_params(&self, py: Python<'_>, params: &[f64]) -> PyResult<()> {
        let f = self.formula();
        if params.len() != f.params.len() {
            return Err(self.error(py, Diagnostic::error(format!("{} parameter values for {} parameters", params.len(), f.params.len()))));
        }
        for (d, v) in f.params.iter().zip(params) {
            if !d.admits(*v) && !self.baked.iter().any(|(k, _)| *k == d.name) {
                return Err(self.error(py, Diagnostic::error(format!("{} = {v} is outside its declared range {}..{}", d.name, d.lo, d.hi)).hint(format!("choose a value in {}..{}", d.lo, d.hi))));
            }
        }
        Ok(())
    }

    /// Per-point parameter arrays from Python (index, `len` values): contiguous, one value per point, each
    /// inside its parameter's declared range.
    fn varying<'a>(&self, py: Python<'_>, arrays: &'a [(usize, PyReadonlyArray1<'a, f64>)], len: usize) -> PyResult<Vec<(usize, &'a [f64])>> {
        let f = self.formula();
        let mut out = vec![];
        for (i, a) in arrays {
            let d = f.params.get(*i).ok_or_else(|| self.error(py, Diagnostic::error(format!("no parameter {i}"))))?;
            let s = a.as_slice().map_err(|_| self.error(py, Diagnostic::error("a parameter array is not contiguous float64 (lobe's Python side makes it so: a bug)")))?;
            if s.len() != len {
                return Err(self.error(py, Diagnostic::error(format!("{} has {} values for {len} points", d.name, s.len()))));
            }
            if let Some(at) = py.detach(|| s.iter().position(|v| !d.admits(*v))) {
                let (lo, hi) = (d.lo, d.hi);
                return Err(self.error(py, Diagnostic::error(format!("{} = {} (at flat index {at}) is outside its declared range {lo}..{hi}", d.name, s[at])).hint(format!("choose values in {lo}..{hi}"))));
            }
            out.push((*i, s));
        }
        Ok(out)
    }

    /// Refuses a check that sweeps n (the first parameter) on a kernel with n baked: the sweep would not move it.
    fn n_live(&self, py: Python<'_>, what: &str) -> PyResult<()> {
        match self.formula().params.first() {
            Some(d) if self.baked.iter().any(|(k, _)| *k == d.name) => Err(self.error(
                py,
                Diagnostic::error(format!("{what} sweeps {}, which is baked into this kernel", d.name)).hint(format!("compile without baking {}", d.name)),
            )),
            _ => Ok(()),
        }
    }

    /// The sampler at `params` (checked), from the cache or built ([`Sampler::build_channels`]).
    fn sampler(&self, py: Python<'_>, params: &[f64]) -> PyResult<Arc<Sampler>> {
        self.check_params(py, params)?;
        let cached = self.samplers.lock().unwrap_or_else(|e| e.into_inner()).iter().find(|(p, _)| p == params).map(|(_, s)| s.clone());
        if let Some(s) = cached {
            return Ok(s);
        }
        let s = Arc::new(detached(py, &self.file, || {
            Sampler::build_channels(&self.kernels, params, &lobe::bsdf::Options::default()).map_err(|d| plain(&self.file, d))
        })?);
        let mut cache = self.samplers.lock().unwrap_or_else(|e| e.into_inner());
        if cache.len() == SAMPLER_CACHE {
            cache.remove(0);
        }
        cache.push((params.to_vec(), s.clone()));
        Ok(s)
    }

    /// The declared default of every parameter, baked ones at their baked value.
    fn param_values(&self) -> Vec<f64> {
        let f = self.formula();
        let mut p = f.default_params();
        for (k, v) in &self.baked {
            if let Some(i) = f.param_index(k) {
                p[i] = *v;
            }
        }
        p
    }

    /// One channel's lobe variable: the one named, else the one the formula reads.
    fn lobe_input(&self, py: Python<'_>, k: &Kernel, name: Option<&str>) -> PyResult<Input> {
        let Some(name) = name else { return Ok(lobe::numerics::choose_lobe_input(k.used_inputs()).0) };
        Input::from_name(name).ok_or_else(|| {
            self.error(py, Diagnostic::error(format!("lobe variable `{name}` is not an input")).hint("the lobe variable is NH (Blinn-style) or VR (Phong-style)"))
        })
    }
}

#[pymethods]
impl Native {
    #[getter]
    fn file(&self) -> &str {
        &self.file
    }
    #[getter]
    fn source(&self) -> &str {
        &self.source
    }
    #[getter]
    fn math(&self) -> &'static str {
        self.math.name()
    }
    #[getter]
    fn baked(&self) -> Vec<(String, f64)> {
        self.baked.clone()
    }
    #[getter]
    fn name(&self) -> String {
        self.whole.display_name()
    }
    #[getter]
    fn channels(&self) -> usize {
        self.kernels.len()
    }
    /// (name, default, lo, hi) per declared parameter, in order (`n` first); a baked one at its baked value.
    #[getter]
    fn params(&self) -> Vec<(String, f64, f64, f64)> {
        self.formula().params.iter().zip(self.param_values()).map(|(d, v)| (d.name.clone(), v, d.lo, d.hi)).collect()
    }
    /// The inputs the compiled kernels read, in lobe's input order.
    #[getter]
    fn inputs(&self) -> Vec<&'static str> {
        self.used().iter().map(Input::name).collect()
    }
    /// The compiled (simplified, accuracy pass applied) formula of each channel, as program text.
    #[getter]
    fn compiled(&self) -> Vec<String> {
        self.kernels.iter().map(|k| k.formula.to_program_text()).collect()
    }

    /// [`Native::eval`] of a scalar formula into `out` (`len` values, contiguous), which the caller reuses:
    /// no allocation, and pages already touched.
    fn eval_out<'py>(&self, py: Python<'py>, points: Points<'py>, params: Vec<f64>, varying: Vec<(usize, PyReadonlyArray1<'py, f64>)>, mut out: PyReadwriteArray1<'py, f64>) -> PyResult<()> {
        let len = points.3;
        if self.kernels.len() != 1 || out.len() != len {
            return Err(self.error(py, Diagnostic::error(format!("out holds {} values for {len} points of {} channel(s)", out.len(), self.kernels.len()))));
        }
        let o = out.as_slice_mut().map_err(|_| self.error(py, Diagnostic::error("out is not contiguous").hint("pass a C-contiguous float64 array")))?;
        self.fill(py, points, params, varying, o)
    }

    /// One point through every channel's kernel: `x` the cosine inputs by index in `Input::ALL` (those not read
    /// are ignored), `params` the full vector. The per-call path of a call with numbers only: the same bits as
    /// the batched kernel (the scalar and batched entries of one compiled formula agree bit for bit).
    fn eval_one(&self, py: Python<'_>, x: Vec<(usize, f64)>, params: Vec<f64>) -> PyResult<Vec<f64>> {
        self.check_params(py, &params)?;
        let mut xs = [0.0; N_INPUTS];
        for (i, v) in x {
            if let Some(slot) = xs.get_mut(i) {
                *slot = v;
            }
        }
        Ok(self.kernels.iter().map(|k| k.eval(&xs, &params)).collect())
    }

    /// What each keyword names: ("input", index), ("L", 0), ("V", 0) or ("param", index).
    fn resolve(&self, py: Python<'_>, names: Vec<String>) -> PyResult<Vec<(&'static str, usize)>> {
        let f = self.formula();
        names
            .iter()
            .map(|n| {
                if n == "L" || n == "V" {
                    return Ok(if n == "L" { ("L", 0) } else { ("V", 0) });
                }
                match (Input::from_name(n), f.param_index(n)) {
                    (Some(i), _) if i.is_direction() => Err(self.error(py, Diagnostic::error(format!("`{n}` is one direction component")).hint(format!("give the whole direction: {}=array of shape (..., 3)", &n[..1])))),
                    (Some(i), _) => Ok(("input", i.index())),
                    (None, Some(_)) if self.baked.iter().any(|(k, _)| k == n) => Err(self.error(py, Diagnostic::error(format!("parameter `{n}` is baked into this kernel")).hint("compile without baking it to vary it per call"))),
                    (None, Some(p)) => Ok(("param", p)),
                    (None, None) => {
                        let mut known: Vec<&str> = ["NL", "NV", "NH", "VR", "VH", "L", "V"].to_vec();
                        known.extend(f.params.iter().map(|p| p.name.as_str()));
                        let hint = lobe::front::did_you_mean(n, &known, "inputs and parameters are: ");
                        Err(self.error(py, Diagnostic::error(format!("`{n}` is neither an input nor a parameter of the formula")).hint(hint)))
                    }
                }
            })
            .collect()
    }

    /// The value and gradient at every point (`lobe eval --grad`'s bits): the variables' names (every declared
    /// parameter, then every input read), the values (`len` per channel, channel after channel) and the partials
    /// (`len` per channel, channel after channel, variable after variable). `params` is the full vector.
    fn grad<'py>(&self, py: Python<'py>, points: Points<'py>, params: Vec<f64>) -> PyResult<Gradients<'py>> {
        self.check_params(py, &params)?;
        let g = self.gradient(py)?;
        let (cos, l, v, len) = points;
        let inputs = self.batch(py, &cos, l.as_ref(), v.as_ref(), len)?;
        if let Some(i) = g.used.iter().find(|i| inputs.cols[i.index()].is_empty() && len > 0) {
            return Err(self.error(py, Diagnostic::error(format!("the gradient reads {}, which was not given", i.name())).hint("give every input the formula reads (or L and V)")));
        }
        let r = detached(py, &self.file, || {
            let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| &*inputs.cols[i]);
            Ok(g.run(&cols, &params, len))
        })?;
        // Copied into pooled buffers: every element written (each channel's and variable's `len` values).
        let mut values = pool::Buffer::new(r.value.len() * len);
        let mut grads = pool::Buffer::new(r.grad.iter().map(Vec::len).sum::<usize>() * len);
        let parts = r.grad.iter().flatten();
        for (dst, src) in values.as_mut_slice().chunks_mut(len.max(1)).zip(&r.value).chain(grads.as_mut_slice().chunks_mut(len.max(1)).zip(parts)) {
            dst.copy_from_slice(src);
        }
        Ok((g.names(), values.into_pyarray(py)?, grads.into_pyarray(py)?))
    }

    /// Every point through every channel's batched kernel: `len` values per channel, channel after channel.
    /// `params` is the full parameter vector; `varying` (index, `len` values) overrides some per point.
    fn eval<'py>(&self, py: Python<'py>, points: Points<'py>, params: Vec<f64>, varying: Vec<(usize, PyReadonlyArray1<'py, f64>)>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        // A warm buffer from the pool for large batches; `fill` writes every element (each channel's runs cover
        // its `len` points).
        let mut out = pool::Buffer::new(points.3 * self.kernels.len());
        self.fill(py, points, params, varying, out.as_mut_slice())?;
        out.into_pyarray(py)
    }

    /// Fits `free` = [(param index, lo, hi, step or None)] to `target` (len values per channel, channel after
    /// channel) at the points, by [`lobe::numerics::fit::fit_points`]. Returns the best candidates (full
    /// parameter vector, score, refined) and how many scores were computed.
    #[allow(clippy::too_many_arguments)]
    fn fit<'py>(
        &self,
        py: Python<'py>,
        points: Points<'py>,
        target: PyReadonlyArray1<'py, f64>,
        weights: Option<PyReadonlyArray1<'py, f64>>,
        params: Vec<f64>,
        free: Vec<(usize, f64, f64, Option<f64>)>,
        loss: &str,
        top: usize,
        refine: bool,
    ) -> PyResult<(Vec<FitCandidate>, usize)> {
        use lobe::numerics::fit::{fit_points, Loss, PointsTarget};
        self.check_params(py, &params)?;
        let loss: Loss = loss.parse().map_err(|e: String| self.error(py, Diagnostic::error(e)))?;
        let fp = tools::free_params(py, self, free)?;
        let (cos, l, v, len) = points;
        let inputs = self.batch(py, &cos, l.as_ref(), v.as_ref(), len)?;
        let contiguous = || self.error(py, Diagnostic::error("target and weights must be contiguous float64"));
        let target = target.as_slice().map_err(|_| contiguous())?;
        let weights = match &weights {
            Some(w) => Some(w.as_slice().map_err(|_| contiguous())?),
            None => None,
        };
        let rep = detached(py, &self.file, || {
            let pts = PointsTarget { cols: inputs.columns(), len: inputs.len, target, weights };
            let chans: Vec<&dyn Evaluator> = self.kernels.iter().map(|k| k as &dyn Evaluator).collect();
            fit_points(&chans, &params, &pts, loss, &fp, top, refine).map_err(|d| plain(&self.file, d))
        })?;
        Ok((rep.best.into_iter().map(|c| (c.params, c.score, c.refined)).collect(), rep.evaluated))
    }

    /// `len` samples of wo ([`Sampler::sample_many`]): `wi` and `u` are `len` × 3 and `len` × 2 (row-major,
    /// one incident direction per sample); returns wo (`len` × 3), pdf (`len`) and the weights (`len` ×
    /// channels), split over rayon's threads for large batches, and the sampler's mechanism.
    fn sample<'py>(
        &self,
        py: Python<'py>,
        wi: PyReadonlyArray2<'py, f64>,
        u: PyReadonlyArray2<'py, f64>,
        params: Vec<f64>,
    ) -> PyResult<Drawn<'py>> {
        let s = self.sampler(py, &params)?;
        let len = wi.shape()[0];
        if wi.shape() != [len, 3] || u.shape() != [len, 2] {
            return Err(self.error(py, Diagnostic::error("wi must have shape (len, 3) and u (len, 2) (lobe's Python side makes them so: a bug)")));
        }
        let contiguous = || self.error(py, Diagnostic::error("wi and u must be contiguous float64 (lobe's Python side makes them so: a bug)"));
        let (wi, u) = (wi.as_slice().map_err(|_| contiguous())?, u.as_slice().map_err(|_| contiguous())?);
        let nch = s.channels();
        // Pooled buffers, every element written (`copy_from_slice` of each chunk's samples, of equal lengths).
        let (mut wo_buf, mut pdf_buf, mut weight_buf) = (pool::Buffer::new(3 * len), pool::Buffer::new(len), pool::Buffer::new(nch * len));
        let (wo, pdf, weight) = (wo_buf.as_mut_slice(), pdf_buf.as_mut_slice(), weight_buf.as_mut_slice());
        detached(py, &self.file, || {
            let parts = wo.par_chunks_mut(3 * CHUNK).zip(pdf.par_chunks_mut(CHUNK)).zip(weight.par_chunks_mut(nch * CHUNK)).enumerate();
            parts.try_for_each(|(c, ((wo, pdf), weight))| {
                let r = c * CHUNK..c * CHUNK + pdf.len();
                let wis: Vec<[f64; 3]> = r.clone().map(|i| [wi[3 * i], wi[3 * i + 1], wi[3 * i + 2]]).collect();
                let us: Vec<[f64; 2]> = r.clone().map(|i| [u[2 * i], u[2 * i + 1]]).collect();
                let smp = s.sample_many(&wis, &us).map_err(|d| {
                    let at = wis.iter().position(|w| s.sample_many(&[*w], &[[0.5, 0.5]]).is_err()).map_or(0, |k| r.start + k);
                    plain(&self.file, at_index(d, at))
                })?;
                for (o, v) in wo.chunks_mut(3).zip(&smp.wo) {
                    o.copy_from_slice(v);
                }
                pdf.copy_from_slice(&smp.pdf);
                weight.copy_from_slice(&smp.weight);
                Ok(())
            })
        })?;
        Ok((wo_buf.into_pyarray(py)?, pdf_buf.into_pyarray(py)?, weight_buf.into_pyarray(py)?, s.report.mechanism.name()))
    }

    /// The sampler's density of each wo given wi ([`Sampler::pdf_many`]): both `len` × 3, row-major.
    fn pdf<'py>(&self, py: Python<'py>, wi: PyReadonlyArray2<'py, f64>, wo: PyReadonlyArray2<'py, f64>, params: Vec<f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let s = self.sampler(py, &params)?;
        let len = wi.shape()[0];
        if wi.shape() != [len, 3] || wo.shape() != [len, 3] {
            return Err(self.error(py, Diagnostic::error("wi and wo must have shape (len, 3) (lobe's Python side makes them so: a bug)")));
        }
        let contiguous = || self.error(py, Diagnostic::error("wi and wo must be contiguous float64 (lobe's Python side makes them so: a bug)"));
        let (wi, wo) = (wi.as_slice().map_err(|_| contiguous())?, wo.as_slice().map_err(|_| contiguous())?);
        // A pooled buffer, every element written (`copy_from_slice` of each chunk's densities).
        let mut out = pool::Buffer::new(len);
        let slice = out.as_mut_slice();
        detached(py, &self.file, || {
            slice.par_chunks_mut(CHUNK).enumerate().try_for_each(|(c, o)| {
                let r = c * CHUNK..c * CHUNK + o.len();
                let row = |a: &[f64], i: usize| [a[3 * i], a[3 * i + 1], a[3 * i + 2]];
                let wis: Vec<[f64; 3]> = r.clone().map(|i| row(wi, i)).collect();
                let wos: Vec<[f64; 3]> = r.clone().map(|i| row(wo, i)).collect();
                let p = s.pdf_many(&wis, &wos).map_err(|d| {
                    let at = (0..wis.len()).position(|k| s.pdf_many(&[wis[k]], &[wos[k]]).is_err()).map_or(0, |k| r.start + k);
                    plain(&self.file, at_index(d, at))
                })?;
                o.copy_from_slice(&p);
                Ok(())
            })
        })?;
        out.into_pyarray(py)
    }

    /// `lobe check --json` ([`lobe::numerics::check`]).
    fn check(&self, py: Python<'_>, points: usize, budget: f64) -> PyResult<Py<PyAny>> {
        if !(budget > 0.0 && budget.is_finite()) || points == 0 {
            return Err(self.error(py, Diagnostic::error("points must be ≥ 1 and budget a positive number of seconds")));
        }
        // The search as the kernels were compiled (the same points and options), its report on `points`.
        let opts = PassOptions { math: self.math, budget: std::time::Duration::from_secs_f64(budget), ..PassOptions::default() };
        let store = lobe::numerics::pass_cache::platform_store(true);
        let c = detached(py, &self.file, || lobe::numerics::check::check(&self.whole, &self.baked, &opts, points, store.as_deref(), &|_| {}))?;
        report(py, &c.json())
    }

    /// `lobe energy --json` in lobe or full mode, per channel; with `range` = (lo, hi), coef(n) over n = lo,
    /// lo + step, … ≤ hi (`--range`, `--step`), scored against the fitted coefficient `against` if given.
    #[allow(clippy::too_many_arguments)]
    fn energy(&self, py: Python<'_>, mode: &str, lobe: Option<&str>, params: Vec<f64>, range: Option<(f64, f64)>, step: f64, against: Option<&Native>) -> PyResult<Py<PyAny>> {
        use lobe::numerics::energy::{coef_range, full_energy_for, lobe_integral, score_fitted, EnergyReport, FullReport, LobeReport, PerChannel, RangeReport};
        self.check_params(py, &params)?;
        let full = match mode {
            "lobe" => false,
            "full" => true,
            _ => return Err(self.error(py, Diagnostic::error(format!("unknown energy mode `{mode}`")).hint("mode is \"lobe\" or \"full\""))),
        };
        if full && lobe.is_some() {
            return Err(self.error(py, Diagnostic::error("the lobe variable applies to mode \"lobe\" only")));
        }
        if range.is_none() && against.is_some() {
            return Err(self.error(py, Diagnostic::error("`against` scores a coefficient over a range of n").hint("give range=(lo, hi) too")));
        }
        if range.is_some() {
            if full {
                return Err(self.error(py, Diagnostic::error("a range of n works in mode \"lobe\" only").hint("drop mode=\"full\", or drop range")));
            }
            if self.kernels.len() > 1 {
                return Err(self.error(py, Diagnostic::error("a range of n works on scalar formulas only").hint("this formula has a colour result; drop range")));
            }
            self.n_live(py, "a range")?;
        }
        let f = self.formula();
        // Under a range, n is the swept variable, not a parameter (the command's `params`).
        let shown = f.params.iter().zip(&params).enumerate().filter(|(i, _)| range.is_none() || *i != 0).map(|(_, (d, v))| (d.name.as_str(), *v));
        let shown = lobe::base::json::Named::new(shown);
        let mut reports = vec![];
        for k in &self.kernels {
            let lobe = self.lobe_input(py, k, lobe)?;
            let r = detached(py, &self.file, || {
                let wrap = |d| plain(&self.file, d);
                Ok(match range {
                    _ if full => EnergyReport::Full(FullReport::new(shown.clone(), &full_energy_for(k, k.used_inputs(), &params).map_err(wrap)?)),
                    None => EnergyReport::Lobe(LobeReport::new(shown.clone(), lobe, &lobe_integral(k, &params, lobe).map_err(wrap)?)),
                    Some((lo, hi)) => {
                        let r = coef_range(k, &params, lobe, f.params.first(), lo, hi, step).map_err(wrap)?;
                        let score = against.map(|a| score_fitted(f, &params, &a.kernels[0], &r.integrals));
                        EnergyReport::Range(RangeReport::new(shown.clone(), lobe, &r.coefs, score.as_ref()))
                    }
                })
            })?;
            reports.push(r);
        }
        report(py, &PerChannel::new(reports))
    }

    /// `lobe accuracy --json` against `reference` (its first channel), n = 1..n_max: every channel of this
    /// formula, in the lobe variable the formula reads.
    fn accuracy(&self, py: Python<'_>, reference: &Native, params: Vec<f64>, q: f64, n_max: u32, epicenter_from: u32) -> PyResult<Py<PyAny>> {
        use lobe::numerics::accuracy::{accuracy_channels, channels_json, AccuracyOptions};
        self.check_params(py, &params)?;
        self.n_live(py, "accuracy")?;
        reference.n_live(py, "accuracy")?;
        let r = &reference.kernels[0];
        let (lobe, ref_lobe) = (lobe::numerics::choose_lobe_input(self.used()).0, reference.lobe_input(py, r, None)?);
        let opts = AccuracyOptions { q, n_max, epicenter_from, ..Default::default() };
        let chans: Vec<&dyn Evaluator> = self.kernels.iter().map(|k| k as &dyn Evaluator).collect();
        let reps = detached(py, &self.file, || accuracy_channels(&chans, &params, lobe, r, &reference.param_values(), ref_lobe, &opts).map_err(|d| plain(&self.file, d)))?;
        report(py, &channels_json(&reps, q))
    }

    /// `lobe sweep --json`: the unclamped formula over its domain, as written and as compiled.
    fn sweep(&self, py: Python<'_>, bound: f64, max_evals: u64, as_written: bool) -> PyResult<Py<PyAny>> {
        use lobe::numerics::sweep::{sweep_formula, ChannelsJson, SweepOptions};
        if bound.is_nan() || bound <= 0.0 {
            return Err(self.error(py, Diagnostic::error(format!("bound {bound} must be a positive number"))));
        }
        let plain_opts = lobe::Options { math: self.math, ..lobe::Options::default() };
        let pass = (!as_written).then(|| lobe::numerics::pass_cache::command_pass(plain_opts.clone(), PassOptions::default(), true));
        let opts = SweepOptions { bound, max_evals };
        let mut channels = ChannelsJson::default();
        for c in self.whole.named_channels() {
            let run = detached(py, &self.file, || sweep_formula(&c, &self.baked, &plain_opts, pass.as_ref(), &opts))?;
            if !self.whole.is_rgb() {
                return report(py, &run.json());
            }
            let name = c.display_name().rsplit_once(" (").map_or(String::new(), |(_, ch)| ch.trim_end_matches(')').to_string());
            channels.channels.insert(name, run.json());
        }
        report(py, &channels)
    }

    /// `(file, source, math, baked)`: what `compile` rebuilds this kernel from (pickling).
    fn state(&self) -> (String, String, &'static str, Vec<(String, f64)>) {
        (self.file.clone(), self.source.clone(), self.math.name(), self.baked.clone())
    }
}

/// Compiles formula text (named `file` in diagnostics) as `lobe eval` does, `baked` baked in, in `math`.
/// Warnings are returned as rendered text.
#[pyfunction]
#[pyo3(signature = (file, source, math, baked))]
fn compile(py: Python<'_>, file: String, source: String, math: &str, baked: Vec<(String, f64)>) -> PyResult<(Native, String)> {
    let mode = math_mode(py, math)?;
    let (whole, warnings) = detached(py, &file, || lobe::front::parse_with_warnings(&file, &source))?;
    let warn = if warnings.items.is_empty() { String::new() } else { warnings.render(false) };
    let pass = PassOptions::default();
    let kernels = detached(py, &file, || {
        // Automatic tiering: Cranelift, and LLVM for big arrays in a module built with the LLVM tier.
        let backend = Tier::Auto.resolve(Backend::Jit).unwrap_or(Backend::Jit);
        let ks = lobe::numerics::pass_cache::command_channels(&whole, &baked, backend, mode, pass, true)?;
        ks.iter().for_each(Kernel::warm_up);
        Ok(ks)
    })?;
    Ok((Native { whole, kernels, file, source, math: mode, baked, samplers: Mutex::default(), gradient: std::sync::OnceLock::new() }, warn))
}

/// A formula file's name and text, read as the command line reads it (size limit, UTF-8 checked).
#[pyfunction]
fn read_source(py: Python<'_>, path: &str) -> PyResult<(String, String)> {
    lobe::base::source::read_source(path).map_err(|d| msg_error(py, path, d))
}

/// Renders a scene file as `lobe render` does (its `--math`, `--backend` and `--tier` as `math`, `backend`,
/// `tier`); returns the RGB bytes, width and height.
#[pyfunction]
#[pyo3(signature = (scene, size, set, aa, srgb, threads, math, backend, tier))]
#[allow(clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    scene: &str,
    size: Option<(usize, usize)>,
    set: Vec<(String, f64)>,
    aa: Option<usize>,
    srgb: bool,
    threads: usize,
    math: &str,
    backend: &str,
    tier: &str,
) -> PyResult<(Bound<'py, PyBytes>, usize, usize)> {
    use lobe::render::image::Transfer;
    use lobe::render::scene::{load_scene, LoadOptions};
    if let Some((w, h)) = size {
        let ok = |v: usize| (1..=4096).contains(&v);
        if !ok(w) || !ok(h) {
            return Err(msg_error(py, scene, Diagnostic::error(format!("image size {w}×{h}")).hint("each side is 1..=4096")));
        }
    }
    let mode = math_mode(py, math)?;
    let bad = |e: String, hint: &str| msg_error(py, scene, Diagnostic::error(e).hint(hint.to_string()));
    let backend: Backend = backend.parse().map_err(|e| bad(e, "backend is \"jit\" or \"interp\""))?;
    let tier: Tier = tier.parse().map_err(|e| bad(e, "tier is \"cranelift\", \"llvm\" or \"auto\""))?;
    let backend = lobe::resolve_backend(backend, tier).map_err(|d| msg_error(py, scene, d))?;
    let image = detached(py, scene, || {
        let compiler = lobe::render::scene::LobeCompiler::for_commands(backend, mode, true);
        let sc = load_scene(std::path::Path::new(scene), &LoadOptions { size, set, ..LoadOptions::default() }, &compiler)?;
        let opts = lobe::render::RenderOptions { threads, transfer: if srgb { Transfer::Srgb } else { Transfer::Linear }, aa, ..Default::default() };
        let (frame, _) = lobe::render::render(&sc, &opts).map_err(|e| plain(scene, Diagnostic::error(e)))?;
        Ok(frame.image)
    })?;
    Ok((PyBytes::new(py, &image.rgb), image.width, image.height))
}

/// PNG bytes of `width` × `height` RGB pixels (row-major), by lobe's encoder.
#[pyfunction]
fn encode_png<'py>(py: Python<'py>, rgb: numpy::PyReadonlyArray1<'py, u8>, width: usize, height: usize) -> PyResult<Bound<'py, PyBytes>> {
    let rgb = rgb.as_slice().map_err(|_| msg_error(py, "", Diagnostic::error("image data must be contiguous")))?;
    if rgb.len() != width * height * 3 || width == 0 || height == 0 {
        return Err(msg_error(py, "", Diagnostic::error(format!("{} bytes for a {width}×{height} RGB image", rgb.len()))));
    }
    let image = lobe::base::image::Image { width, height, rgb: rgb.to_vec() };
    let png = image.encode_png().map_err(|e| msg_error(py, "", Diagnostic::error(e)))?;
    Ok(PyBytes::new(py, &png))
}

/// Panics inside lobe, on purpose: the tests check that a panic (here in a rayon worker, as in a batch split over
/// threads) reaches Python as a `LobeError`, not an abort.
#[pyfunction]
fn _panic_for_tests(py: Python<'_>) -> PyResult<()> {
    detached(py, "<test>", || {
        (0..4).into_par_iter().for_each(|i| assert!(i < 2, "a deliberate panic in worker {i}"));
        Ok(())
    })
}

#[pymodule]
fn _lobe(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("LobeError", m.py().get_type::<LobeError>())?;
    m.add_class::<Native>()?;
    m.add_function(wrap_pyfunction!(compile, m)?)?;
    m.add_function(wrap_pyfunction!(read_source, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(encode_png, m)?)?;
    m.add_class::<tools::Table>()?;
    m.add_function(wrap_pyfunction!(tools::load_measured, m)?)?;
    m.add_function(wrap_pyfunction!(tools::tabulate, m)?)?;
    m.add_function(wrap_pyfunction!(tools::fit_against, m)?)?;
    m.add_function(wrap_pyfunction!(tools::export, m)?)?;
    m.add_function(wrap_pyfunction!(tools::compare, m)?)?;
    m.add_function(wrap_pyfunction!(tools::plot, m)?)?;
    m.add_function(wrap_pyfunction!(tools::bench, m)?)?;
    m.add_function(wrap_pyfunction!(_panic_for_tests, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
