//! The command line's other features for Python, each a call into the library as the command makes it:
//! measured tables (`lobe tabulate`, `lobe fit --measured`), the exports (`lobe export`), `lobe compare`,
//! `lobe plot` and `lobe bench` rows. The Python half (`lobe/__init__.py`) names the arguments.

use super::{detached, msg_error, plain, report, Native};
use lobe::base::diag::{Diagnostic, Diagnostics};
use lobe::ir::Formula;
use lobe::measured::{Lookup, Measured};
use lobe::numerics::fit::{FreeParam, Refinement};
use lobe::numerics::pass_cache::command_channels;
use lobe::numerics::robust::PassOptions;
use lobe::{Backend, Evaluator, Kernel};
use numpy::{PyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use rayon::prelude::*;
use std::sync::Arc;

/// A MERL table (`lobe.Measured`'s native half): read from a file, or a formula tabulated.
#[pyclass(frozen, module = "lobe._lobe")]
pub struct Table {
    table: Arc<Measured>,
    /// The file it was read from (`None` for a tabulated table not saved).
    path: Option<String>,
}

#[pymethods]
impl Table {
    #[getter]
    fn name(&self) -> &str {
        &self.table.name
    }
    #[getter]
    fn path(&self) -> Option<&str> {
        self.path.as_deref()
    }
    #[getter]
    fn measured_entries(&self) -> usize {
        self.table.measured_entries()
    }
    /// The lookup ([`Measured::lookup_with`], `lookup` "linear" or "nearest") of each pair of rows of `wi`
    /// (the formula's L) and `wo` (V), both `len` × 3 in the local frame (normalised if not unit): `len` × 3
    /// values (red, green, blue per point), split over rayon's threads.
    fn values<'py>(&self, py: Python<'py>, wi: PyReadonlyArray2<'py, f64>, wo: PyReadonlyArray2<'py, f64>, lookup: &str) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let how: Lookup = lookup.parse().map_err(|e: String| msg_error(py, &self.table.name, Diagnostic::error(e).hint("lookup is \"linear\" or \"nearest\"")))?;
        let len = wi.shape()[0];
        let bad = |m: &str| msg_error(py, &self.table.name, Diagnostic::error(m.to_string()));
        if wi.shape() != [len, 3] || wo.shape() != [len, 3] {
            return Err(bad("wi and wo must have shape (len, 3) (lobe's Python side makes them so: a bug)"));
        }
        let (l, v) = (wi.as_slice().map_err(|_| bad("wi is not contiguous"))?, wo.as_slice().map_err(|_| bad("wo is not contiguous"))?);
        // A pooled buffer: every element written when no row is bad (each chunk's rows, three channels each).
        let mut buf = super::pool::Buffer::new(3 * len);
        let out = buf.as_mut_slice();
        let t = &self.table;
        let first_bad = py.detach(|| {
            out.par_chunks_mut(3 * super::CHUNK)
                .enumerate()
                .filter_map(|(c, o)| {
                    for (r, px) in o.chunks_mut(3).enumerate() {
                        let i = c * super::CHUNK + r;
                        let row = |a: &[f64]| [a[3 * i], a[3 * i + 1], a[3 * i + 2]];
                        let (Some((lu, _)), Some((vu, _))) = (lobe::numerics::points::unit(row(l)), lobe::numerics::points::unit(row(v))) else {
                            return Some(i);
                        };
                        for (ch, x) in px.iter_mut().enumerate() {
                            *x = t.lookup_with(how, ch, lu, vu);
                        }
                    }
                    None
                })
                .min()
        });
        if let Some(i) = first_bad {
            return Err(msg_error(py, &self.table.name, Diagnostic::error(format!("wi or wo at flat index {i} has no direction")).hint("directions are three finite components, not all 0")));
        }
        buf.into_pyarray(py)
    }
    /// The MERL file's bytes.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.table.to_bytes())
    }
    /// The same table, now saved as `path` (compare and plot read a table by its file).
    fn saved_as(&self, path: String) -> Table {
        Table { table: self.table.clone(), path: Some(path) }
    }
}

/// Reads a MERL `.binary` file ([`Measured::read`]: the size, header and values checked).
#[pyfunction]
pub fn load_measured(py: Python<'_>, path: String) -> PyResult<Table> {
    let t = detached(py, &path, || Measured::read(&path).map_err(|d| plain(&path, d)))?;
    Ok(Table { table: Arc::new(t), path: Some(path) })
}

/// `lobe tabulate`: `k`'s channels at `params`, times `color`, at every entry of the table convention.
#[pyfunction]
pub fn tabulate(py: Python<'_>, k: &Native, params: Vec<f64>, color: (f64, f64, f64)) -> PyResult<Table> {
    k.check_params(py, &params)?;
    let color = [color.0, color.1, color.2];
    if color.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
        return Err(k.error(py, Diagnostic::error("color takes three finite factors ≥ 0").hint("e.g. color=(1, 0.8, 0.4)")));
    }
    let name = k.whole.display_name();
    let t = detached(py, &k.file, || {
        let channels: Vec<&dyn Evaluator> = k.kernels.iter().map(|c| c as &dyn Evaluator).collect();
        Ok(Measured::tabulate_channels(&name, &channels, &params, color))
    })?;
    Ok(Table { table: Arc::new(t), path: None })
}

/// The searched parameters of `k`: (index, lo, hi, step) each inside its declared range and not baked.
pub(crate) fn free_params(py: Python<'_>, k: &Native, free: Vec<(usize, f64, f64, Option<f64>)>) -> PyResult<Vec<FreeParam>> {
    let f = k.formula();
    let mut fp = vec![];
    for (index, lo, hi, step) in free {
        let d = f.params.get(index).ok_or_else(|| k.error(py, Diagnostic::error(format!("no parameter {index}"))))?;
        if k.baked.iter().any(|(n, _)| *n == d.name) {
            return Err(k.error(py, Diagnostic::error(format!("parameter `{}` is baked into this kernel", d.name)).hint("compile without baking the parameters you fit")));
        }
        if !(lo <= hi && d.admits(lo) && d.admits(hi)) {
            return Err(k.error(
                py,
                Diagnostic::error(format!("{}: {lo}..{hi} is not a range inside the declared {}..{}", d.name, d.lo, d.hi)).hint("search inside the declared range, or widen it in the file"),
            ));
        }
        fp.push(FreeParam { index, name: d.name.clone(), lo, hi, step });
    }
    Ok(fp)
}

/// Which of a formula and its reference reads no `n`, as the command says it.
fn which_reads_no_n(f: &Formula, r: &Formula) -> String {
    match (f.reads_param("n"), r.reads_param("n")) {
        (true, _) => format!("the reference {} reads no n", r.display_name()),
        (false, true) => format!("{} reads no n", f.display_name()),
        (false, false) => format!("{} and the reference {} read no n", f.display_name(), r.display_name()),
    }
}

/// How a fit against a table or a formula runs (the command's flags), from a dict of these keys.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub struct FitHow {
    metric: Option<String>,
    fit_scale: bool,
    stride: usize,
    grid_stride: usize,
    top: usize,
    refine: bool,
    derivative_free: bool,
    n_max: u32,
}

/// `lobe fit` against a measured table or a formula (at `ref_params`): the papers'
/// n-sweep where both read n (`lobe fit --reference`), else the whole hemisphere at the tables' angles
/// (`lobe fit --measured`). `params` is `k`'s full parameter vector, `free` the searched ones. Returns the
/// command's `--json` dict.
/// What a formula is fitted to: a table or a formula.
#[derive(FromPyObject)]
pub enum Against<'py> {
    Table(PyRef<'py, Table>),
    Formula(PyRef<'py, Native>),
}

#[pyfunction]
pub fn fit_against(
    py: Python<'_>,
    k: &Native,
    against: Against<'_>,
    ref_params: Vec<f64>,
    params: Vec<f64>,
    free: Vec<(usize, f64, f64, Option<f64>)>,
    how: FitHow,
) -> PyResult<Py<PyAny>> {
    k.check_params(py, &params)?;
    let free = free_params(py, k, free)?;
    if !(1..=90).contains(&how.stride) || !(1..=90).contains(&how.grid_stride) || how.top == 0 {
        return Err(k.error(py, Diagnostic::error("stride and grid_stride are 1..=90, top at least 1")));
    }
    match against {
        Against::Formula(r) if k.whole.reads_param("n") && r.whole.reads_param("n") => lobe_fit(py, k, &r, &params, &free, &how),
        Against::Formula(r) => {
            let r: &Native = &r;
            if how.metric.as_deref().is_some_and(|m| m.parse::<lobe::numerics::fit::Metric>().is_ok()) {
                return Err(k.error(
                    py,
                    Diagnostic::error(format!("metric {}: the papers' metrics sweep n, and {}", how.metric.as_deref().unwrap_or(""), which_reads_no_n(&k.whole, &r.whole)))
                        .hint("compare over the whole hemisphere with metric \"log\", \"rmse\" or \"cosine\""),
                ));
            }
            r.check_params(py, &ref_params)?;
            // The reference's own kernels, shared with the fit's threads.
            let kernels = detached(py, &r.file, || command_channels(&r.whole, &r.baked, backend_of(r), r.math, PassOptions::default(), true))?;
            let channels: Vec<Arc<dyn Evaluator>> = kernels.into_iter().map(|c| Arc::new(c) as Arc<dyn Evaluator>).collect();
            let others: Vec<(&dyn Evaluator, Vec<f64>)> = k.kernels.iter().map(|c| (c as &dyn Evaluator, params.clone())).collect();
            let fr = py.detach(|| lobe::numerics::measured::FormulaReference::new(&r.file, channels, ref_params, &others, how.fit_scale));
            measured_fit(py, k, &params, &free, &fr, &r.file, &how)
        }
        Against::Table(t) => {
            let name = t.path.clone().unwrap_or_else(|| t.table.name.clone());
            measured_fit(py, k, &params, &free, t.table.as_ref(), &name, &how)
        }
    }
}

/// The backend a kernel's channels were compiled on.
fn backend_of(k: &Native) -> Backend {
    k.kernels[0].backend_used()
}

/// The formula's value-and-partials kernel by the `free` parameters (Levenberg–Marquardt), as the command
/// compiles it; `None` where it does not compile (the derivative-free refinement then runs).
fn gradient(k: &Native, f: &Formula, free: &[FreeParam], bake: Vec<(String, f64)>) -> Option<lobe::numerics::grad::Gradient> {
    let vars: Vec<lobe::numerics::grad::Var> = free.iter().map(|f| lobe::numerics::grad::Var::Param(f.index as u16)).collect();
    let opts = lobe::Options { backend: backend_of(k), bake, math: k.math, ..lobe::Options::default() };
    lobe::numerics::grad::Gradient::compile_vars(f, &opts, Some(&vars)).ok()
}

/// `lobe fit --reference`: the papers' metric over n = 1..n_max.
fn lobe_fit(py: Python<'_>, k: &Native, r: &Native, params: &[f64], free: &[FreeParam], how: &FitHow) -> PyResult<Py<PyAny>> {
    use lobe::numerics::fit::{fit_with, FitJson, FitOptions, Metric};
    let metric: Metric = how
        .metric
        .as_deref()
        .unwrap_or("mean-abs")
        .parse()
        .map_err(|e: String| k.error(py, Diagnostic::error(format!("metric: {e}")).hint("\"log\", \"rmse\" and \"cosine\" apply to fits against a table or over the whole hemisphere")))?;
    k.n_live(py, "the papers' fit")?;
    r.n_live(py, "the papers' fit")?;
    let lobe = lobe::numerics::choose_lobe_input(k.kernels[0].used_inputs()).0;
    let ref_lobe = lobe::numerics::choose_lobe_input(r.kernels[0].used_inputs()).0;
    let opts = FitOptions { metric, top: how.top, refine: how.refine, n_max: how.n_max };
    let t = std::time::Instant::now();
    let rep = detached(py, &k.file, || {
        let grad = if how.derivative_free || !how.refine { None } else { gradient(k, &k.kernels[0].formula, free, vec![]) };
        fit_with(&k.kernels[0], grad.as_ref(), params, lobe, &r.kernels[0], &r.param_values(), ref_lobe, free, &opts, &|| {}).map_err(|d| plain(&k.file, d))
    })?;
    if !rep.best.first().is_some_and(|c| c.score.is_finite()) {
        return Err(k.error(
            py,
            Diagnostic::error("no candidate has a finite score: the formula or the reference is NaN or infinite on the papers' grid").hint("run `lobe sweep` on both files to see where"),
        ));
    }
    report(py, &FitJson::new(&rep, free, metric, t.elapsed().as_secs_f64()))
}

/// `lobe fit --measured`: against a table or a formula over the whole hemisphere; the command's JSON row and
/// `"best"`, every candidate kept (searched parameters, error, colour scale, refined).
fn measured_fit(py: Python<'_>, k: &Native, params: &[f64], free: &[FreeParam], t: &dyn lobe::numerics::measured::Reference, name: &str, how: &FitHow) -> PyResult<Py<PyAny>> {
    use lobe::numerics::measured::{fit_row, MeasuredFitOptions, MeasuredMetric, MeasuredRowJson};
    let metric: MeasuredMetric = how
        .metric
        .as_deref()
        .unwrap_or("log")
        .parse()
        .map_err(|e: String| k.error(py, Diagnostic::error(format!("metric: {e}")).hint("fits against a table or over the whole hemisphere take metric \"log\", \"rmse\" or \"cosine\"")))?;
    // The searched parameters the formula reads (one it does not read has nothing to fit).
    let reads = k.whole.ir.used_params(k.whole.root);
    let free: Vec<FreeParam> = free.iter().filter(|f| reads.contains(&(f.index as u16))).cloned().collect();
    if free.is_empty() {
        return Err(k.error(py, Diagnostic::error("the formula reads none of the parameters to search").hint("name a parameter the formula reads, e.g. params={\"n\": (1, 1000)}")));
    }
    let refinement = if how.derivative_free { Refinement::DerivativeFree } else { Refinement::Lm };
    let opts = MeasuredFitOptions { metric, stride: how.stride, grid_stride: how.grid_stride, top: how.top, refine: how.refine, refinement };
    let start = std::time::Instant::now();
    let row = detached(py, &k.file, || {
        let grad = if refinement == Refinement::Lm && how.refine { gradient(k, &k.whole, &free, k.baked.clone()) } else { None };
        let channels: Vec<&dyn Evaluator> = k.kernels.iter().map(|c| c as &dyn Evaluator).collect();
        fit_row(&channels, grad.as_ref(), params, &free, t, &opts, &|| {}).map_err(|d| plain(&k.file, d))
    })?;
    if !row.fit.best.first().is_some_and(|b| b.residual.error.is_finite()) {
        return Err(k.error(
            py,
            Diagnostic::error(format!("no candidate has a finite error: {} is NaN or infinite at some entry of {name}", k.whole.display_name())).hint("run `lobe sweep` on the formula to see where"),
        ));
    }
    let json = MeasuredRowJson::new(k.whole.display_name(), &k.file, name, &free, &row, metric, start.elapsed().as_secs_f64());
    let mut v = serde_json::to_value(&json).map_err(|e| k.error(py, Diagnostic::error(format!("cannot write the report: {e}"))))?;
    let best: Vec<serde_json::Value> = row
        .fit
        .best
        .iter()
        .map(|c| {
            let p = lobe::base::json::Named::new(free.iter().map(|f| (f.name.as_str(), c.params[f.index])));
            serde_json::to_value(CandidateJson { params: p, error: c.residual.error, scale: c.residual.scale, refined: c.refined }).unwrap_or_default()
        })
        .collect();
    v["best"] = best.into();
    report(py, &v)
}

/// One candidate of a fit against a table or over the whole hemisphere.
#[derive(serde::Serialize)]
struct CandidateJson {
    params: lobe::base::json::Named,
    #[serde(serialize_with = "lobe::base::json::num")]
    error: f64,
    scale: [f64; 3],
    refined: bool,
}

/// `lobe export`: GLSL (`glsl_version` 450, 330 or es300), WGSL, a BRDF Explorer file or a Mitsuba module
/// (`mechanism`), of `k`'s formula with its baked values and `set` baked.
#[pyfunction]
pub fn export(py: Python<'_>, k: &Native, format: &str, set: Vec<(String, f64)>, glsl_version: &str, mechanism: &str) -> PyResult<String> {
    use lobe::backend::glsl::{self, Dialect, GlslVersion};
    let mut bake = k.baked.clone();
    bake.extend(set);
    let dialect = match format {
        "glsl" => Some(Dialect::Glsl(glsl_version.parse::<GlslVersion>().map_err(|e| k.error(py, Diagnostic::error(e).hint("glsl_version is \"450\", \"330\" or \"es300\"")))?)),
        "wgsl" => Some(Dialect::Wgsl),
        "brdf" | "mitsuba" => None,
        _ => return Err(k.error(py, Diagnostic::error(format!("unknown export format `{format}`")).hint("format is \"glsl\", \"wgsl\", \"brdf\" (BRDF Explorer) or \"mitsuba\""))),
    };
    if format == "mitsuba" {
        let choice = match mechanism {
            "auto" => lobe::bsdf::Choice::Auto,
            m => lobe::bsdf::Choice::Force(m.parse::<lobe::bsdf::Mechanism>().map_err(|e| k.error(py, Diagnostic::error(e).hint("mechanism \"auto\" picks the best measured")))?),
        };
        return detached(py, &k.file, || lobe::bsdf::mitsuba::export(&k.whole, &bake, choice, true).map(|e| e.text));
    }
    detached(py, &k.file, || {
        let f = lobe::simplified(&k.whole, &lobe::Options { bake, ..lobe::Options::default() })?;
        match dialect {
            Some(d) => glsl::export(&f, d),
            None => glsl::brdf_explorer(&f),
        }
        .map_err(|d| Diagnostics::single_in(&f.file, &f.source, d))
    })
}

/// An image's RGB bytes, width and height.
type Pixels<'py> = (Bound<'py, PyBytes>, usize, usize);

fn pixels<'py>(py: Python<'py>, i: &lobe::base::image::Image) -> Pixels<'py> {
    (PyBytes::new(py, &i.rgb), i.width, i.height)
}

/// What `compare` hands back: the images (A, B, the |Δgray| heat map), the command's picture (A | B | heat map
/// with headings and colour bar, what `-o` writes) and its `--json` dict.
type Compared<'py> = (Pixels<'py>, Pixels<'py>, Pixels<'py>, Pixels<'py>, Py<PyAny>);

/// `lobe compare A B`: each of `a` and `b` is (file, formula text), or (table path, "") for a measured table;
/// `scene` a scene file (default: the papers' sphere); `set` given to both.
#[pyfunction]
#[pyo3(signature = (a, b, scene, size, set, threads, srgb, math, backend))]
#[allow(clippy::too_many_arguments)]
pub fn compare<'py>(
    py: Python<'py>,
    a: (String, String),
    b: (String, String),
    scene: Option<String>,
    size: Option<(usize, usize)>,
    set: Vec<(String, f64)>,
    threads: usize,
    srgb: bool,
    math: &str,
    backend: &str,
) -> PyResult<Compared<'py>> {
    use lobe::render::compare::{compare_formulas, sweep_image, CompareJob};
    use lobe::render::image::Transfer;
    let mode = super::math_mode(py, math)?;
    let backend: Backend = backend.parse().map_err(|e: String| msg_error(py, "", Diagnostic::error(e).hint("backend is \"jit\" or \"interp\"")))?;
    if threads > lobe::render::MAX_THREADS {
        return Err(msg_error(py, "", Diagnostic::error(format!("threads {threads} is more than {}; 0 uses one per core", lobe::render::MAX_THREADS))));
    }
    if let Some((w, h)) = size {
        let ok = |v: usize| (1..=4096).contains(&v);
        if !ok(w) || !ok(h) {
            return Err(msg_error(py, "", Diagnostic::error(format!("image size {w}×{h}")).hint("each side is 1..=4096")));
        }
    }
    let (scene_name, scene_src, base) = match &scene {
        Some(p) => {
            let (name, src) = lobe::base::source::read_source(p).map_err(|d| msg_error(py, p, d))?;
            (name, src, std::path::Path::new(p).parent().map(|d| d.to_path_buf()).unwrap_or_default())
        }
        None => ("<builtin paper_sphere.toml>".to_string(), lobe::render::scene::PAPER_SCENE.to_string(), std::path::PathBuf::from(".")),
    };
    let (c, figure, heat) = detached(py, &scene_name, || {
        let job = CompareJob { scene_name: &scene_name, scene_src: &scene_src, base: &base, a: (&a.0, &a.1), b: (&b.0, &b.1), size, tint: [[1.0; 3]; 2] };
        let ropts = lobe::render::RenderOptions { threads, transfer: if srgb { Transfer::Srgb } else { Transfer::Linear }, ..Default::default() };
        let compiler = lobe::render::scene::LobeCompiler::for_commands(backend, mode, true);
        let c = compare_formulas(&job, &set, &compiler, &ropts)?;
        let scale = c.metrics.max_gray_diff.max(1.0);
        let name = |p: &str| std::path::Path::new(p).file_name().and_then(|n| n.to_str()).unwrap_or(p).to_string();
        let heads = [name(&a.0), name(&b.0)];
        let row = sweep_image(std::slice::from_ref(&c), scale);
        let figure = lobe::report::plot::comparison_figure(&row, [&heads[0], &heads[1], "|Δgray|"], &[], scale)
            .map_err(|e| Diagnostics::single(&scene_name, Diagnostic::error(e)))?;
        // The heat map is the row's third panel.
        let (w, h) = (c.a.image.width, c.a.image.height);
        let rgb: Vec<u8> = row.rgb.chunks(3 * 3 * w).flat_map(|line| line[3 * 2 * w..].iter().copied()).collect();
        Ok((c, figure, lobe::base::image::Image { width: w, height: h, rgb }))
    })?;
    let json = report(py, &c.json(&a.0, &b.0))?;
    Ok((pixels(py, &c.a.image), pixels(py, &c.b.image), pixels(py, &heat), pixels(py, &figure), json))
}

/// What `plot` hands back: the picture, the title, the x and y axes' meanings and each series (name, x, y).
type Plot<'py> = (Pixels<'py>, String, &'static str, &'static str, Vec<(String, Vec<f64>, Vec<f64>)>);

/// `lobe plot`: `formulas` (each with its baked values), then `tables` (legend name, table), and a
/// `reference` formula last (or each curve minus it with `error`).
#[pyfunction]
#[pyo3(signature = (formulas, tables, reference, error, set, incidence, lookup, polar, log, ylim, size))]
#[allow(clippy::too_many_arguments)]
pub fn plot<'py>(
    py: Python<'py>,
    formulas: Vec<PyRef<'py, Native>>,
    tables: Vec<(String, PyRef<'py, Table>)>,
    reference: Option<PyRef<'py, Native>>,
    error: bool,
    set: Vec<(String, f64)>,
    incidence: Option<f64>,
    lookup: &str,
    polar: bool,
    log: bool,
    ylim: Option<(f64, f64)>,
    size: (u32, u32),
) -> PyResult<Plot<'py>> {
    use lobe::report::plot::{plot_lobes, Format, LobePlot};
    let lookup: Lookup = lookup.parse().map_err(|e: String| msg_error(py, "", Diagnostic::error(e).hint("lookup is \"linear\" or \"nearest\"")))?;
    if !(100..=8192).contains(&size.0) || !(100..=8192).contains(&size.1) {
        return Err(msg_error(py, "", Diagnostic::error(format!("plot size {}×{}", size.0, size.1)).hint("each side is 100..=8192 pixels")));
    }
    let fs: Vec<Formula> = formulas.iter().map(|k| k.whole.clone()).collect();
    let rf = reference.as_ref().map(|r| r.whole.clone());
    let ts: Vec<(String, Arc<Measured>)> = tables.iter().map(|(n, t)| (n.clone(), t.table.clone())).collect();
    let (p, image) = detached(py, "", || {
        let request = LobePlot { formulas: &fs, tables: &ts, reference: rf.as_ref(), error, set: &set, incidence, lookup, polar, log, ylim, size };
        let p = plot_lobes(&request, Format::Png)?;
        let image = lobe::base::image::Image::decode_png(&p.bytes).map_err(|e| Diagnostics::single("", Diagnostic::error(e)))?;
        Ok((p, image))
    })?;
    let series = p.series.iter().map(|s| (s.name.clone(), s.points.iter().map(|q| q.0).collect(), s.points.iter().map(|q| q.1).collect())).collect();
    Ok((pixels(py, &image), p.title, p.x, p.y, series))
}

/// `lobe bench`'s rows of `k` (one per channel; the error columns against `reference`, default the
/// catalogue's Blinn lobe) at `set` (with n = 50 unless given), in math mode `math`, the batched tiers of `tier`.
#[pyfunction]
#[pyo3(signature = (k, reference, set, math, samples, timing_points, albedo, tier))]
#[allow(clippy::too_many_arguments)]
pub fn bench(py: Python<'_>, k: &Native, reference: Option<&Native>, set: Vec<(String, f64)>, math: &str, samples: usize, timing_points: usize, albedo: bool, tier: &str) -> PyResult<Py<PyAny>> {
    use lobe::report::bench::{bench_row, mark_pareto, RowOptions, CATALOGUE};
    use lobe::report::measure::MeasureOptions;
    let mode = super::math_mode(py, math)?;
    let tier: lobe::Tier = tier.parse().map_err(|e: String| msg_error(py, "", Diagnostic::error(e).hint("tier is \"cranelift\", \"llvm\" or \"auto\"")))?;
    let tiers = match tier {
        lobe::Tier::Cranelift => false,
        lobe::Tier::Auto => lobe::Tier::llvm_available(),
        lobe::Tier::Llvm if lobe::Tier::llvm_available() => true,
        lobe::Tier::Llvm => return Err(super::lobe_error(py, &Diagnostics::single("", lobe::llvm_missing()))),
    };
    if samples == 0 || !(1..=1 << 26).contains(&timing_points) {
        return Err(k.error(py, Diagnostic::error("samples must be ≥ 1 and timing_points 1..=2^26")));
    }
    let mut set = set;
    if !set.iter().any(|(n, _)| n == "n") {
        set.insert(0, ("n".to_string(), 50.0));
    }
    // Baked values are the row's values too.
    for (n, v) in &k.baked {
        if !set.iter().any(|(s, _)| s == n) {
            set.push((n.clone(), *v));
        }
    }
    let opts = RowOptions { measure: MeasureOptions { points: timing_points, samples }, tiers, albedo };
    let rows = detached(py, &k.file, || {
        let blinn;
        let r: &Kernel = match reference {
            Some(r) => &r.kernels[0],
            None => {
                let (path, text) = CATALOGUE.iter().find(|(p, _)| p.ends_with("/blinn.brdf")).copied().unwrap_or(CATALOGUE[1]);
                let f = lobe::front::parse(path, text)?;
                blinn = lobe::compile_formula(f, &lobe::numerics::pass_cache::command_pass(lobe::Options { backend: Backend::Jit, ..lobe::Options::default() }, PassOptions::default(), true))?;
                &blinn
            }
        };
        let mut rows = k.whole.named_channels().iter().map(|c| bench_row(c, &k.file, &set, r, mode, &opts)).collect::<Result<Vec<_>, _>>()?;
        mark_pareto(&mut rows);
        Ok(rows)
    })?;
    report(py, &rows)
}
