//! `lobe fit FILES… --measured TABLES|DIR|REF.brdf… --param n=1..1000 [--metric log|rmse|cosine] [-o cmp.png]
//! [--table t.csv]`: formulas fitted to measured tables ([`lobe::numerics::measured`]), or to another formula
//! over the whole hemisphere at the same angles, one fit or every formula × reference in parallel into a table
//! (Ngan et al.'s experiment). The format, metrics and keys: docs/measured.md.

use super::args::Output;
use super::common::{self, CliError, Spinner};
use super::fit_args::{free_specs, FitArgs};
use lobe::ir::Formula;
use lobe::measured::{is_measured_path, Measured};
use lobe::numerics::fit::{FreeParam, Refinement};
use lobe::numerics::grad::{Gradient, Var};
use lobe::numerics::measured::{fit_row, FormulaReference, MeasuredFitOptions, MeasuredMetric, MeasuredRow, MeasuredRowJson, Reference};
use lobe::{Evaluator, Kernel};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;

/// A formula to fit: its name for reports, its file (or `<expr>`) and source, the loaded formula.
struct Model {
    file: String,
    src: String,
    formula: Formula,
    kernels: Vec<Kernel>,
    /// The value and the partials by the free parameters, for Levenberg–Marquardt (`None`: the derivative-free
    /// refinement, by `--derivative-free` or because the formula's gradient did not compile).
    grad: Option<Gradient>,
    set: Vec<(String, f64)>,
    free: Vec<FreeParam>,
}

/// What a formula is fitted to: a measured table, or a formula (`src` its text, `set` its own values).
struct Against {
    path: String,
    src: String,
    set: Vec<(String, f64)>,
    reference: Arc<dyn Reference>,
}

/// One formula × reference fit.
struct Row<'a> {
    model: &'a Model,
    against: &'a Against,
    table: &'a str,
    row: MeasuredRow,
    seconds: f64,
}

/// The references named by `--measured`: files as given (tables, or formula files), folders as their
/// `.binary` files (sorted).
fn table_paths(args: &[String]) -> Result<Vec<String>, CliError> {
    let mut out = vec![];
    for a in args {
        let p = Path::new(a);
        if p.is_dir() {
            let rd = std::fs::read_dir(p).map_err(|e| CliError::hint(format!("--measured: cannot list `{a}`: {e}"), "check the folder"))?;
            let mut found: Vec<String> =
                rd.filter_map(|e| e.ok()).map(|e| e.path().display().to_string()).filter(|f| is_measured_path(f)).collect();
            if found.is_empty() {
                return Err(CliError::hint(format!("--measured: the folder `{a}` holds no .binary file"), "give MERL .binary files or a folder of them"));
            }
            found.sort();
            out.extend(found);
        } else {
            out.push(a.clone());
        }
    }
    Ok(out)
}

/// The searched parameters of `f`: each `--param` it declares and reads, inside its declared range (a single
/// fit refuses a range beyond it; a batch fits the overlap, as each model has its own ranges).
fn free_of(a: &FitArgs, f: &Formula, batch: bool) -> Result<Vec<FreeParam>, CliError> {
    let reads = f.ir.used_params(f.root);
    let mut free = vec![];
    for (name, lo, hi, step) in free_specs(a)? {
        let Some(index) = f.param_index(&name) else {
            if batch {
                continue;
            }
            let names: Vec<&str> = f.params.iter().map(|p| p.name.as_str()).collect();
            return Err(CliError::hint(format!("--param: the formula has no parameter `{name}`"), common::did_you_mean(&name, &names, "its parameters are: ")));
        };
        if !reads.contains(&(index as u16)) {
            continue;
        }
        let d = &f.params[index];
        let (lo, hi) = if batch { (lo.max(d.lo), hi.min(d.hi)) } else { (lo, hi) };
        if lo < d.lo || hi > d.hi || lo > hi {
            if batch {
                continue;
            }
            return Err(CliError::hint(
                format!("--param {name}={lo}..{hi} leaves the declared range {}..{}", d.lo, d.hi),
                "search inside the declared range, or widen it in the file",
            ));
        }
        free.push(FreeParam { index, name, lo, hi, step });
    }
    if free.is_empty() && !batch {
        return Err(CliError::hint("--param: the formula reads none of the parameters to search", "name a parameter the formula reads, e.g. --param n=1..1000"));
    }
    Ok(free)
}

pub fn run(a: &FitArgs) -> Result<(), CliError> {
    run_against(a, &a.measured)
}

/// [`run`] against the references `against` (tables, folders of them, formula files).
pub fn run_against(a: &FitArgs, against: &[String]) -> Result<(), CliError> {
    let metric: MeasuredMetric =
        a.metric.as_deref().unwrap_or("log").parse().map_err(|e: String| CliError::hint(format!("--metric: {e}"), "--measured fits take --metric log, rmse or cosine"))?;
    let tables = table_paths(against)?;
    if let Some(o) = &a.out.path {
        a.out.force.check(o, lobe::render::image::is_lobe_png)?;
        Output::png_only(o)?;
    }
    if let Some(t) = &a.table {
        match t.extension().and_then(|e| e.to_str()) {
            Some("csv" | "json") => {}
            _ => return Err(CliError::hint(format!("--table `{}`: write a .csv or .json table", t.display()), "e.g. --table fits.csv")),
        }
        a.out.force.check(t, common::is_lobe_output)?;
    }
    let set = a.set.list()?;
    let searched: Vec<String> = free_specs(a)?.into_iter().map(|s| s.0).collect();
    let sources: Vec<(String, String)> = match &a.expr {
        Some(e) => vec![("<expr>".to_string(), e.clone())],
        None if a.files.is_empty() => return Err(CliError::hint("no formula given", "pass .brdf files, or --expr '…'")),
        None => a.files.iter().map(|p| common::read_source(p).map_err(CliError::from)).collect::<Result<_, _>>()?,
    };
    let batch = sources.len() > 1 || tables.len() > 1 || a.table.is_some();
    let mut models = vec![];
    for (file, src) in sources {
        let formula = common::load_formula(if file == "<expr>" { None } else { Some(&file) }, if file == "<expr>" { Some(&src) } else { None })?;
        models.push((file, src, formula));
    }
    // A formula reference declares its own parameters; `--set` gives each side the values of those it declares.
    let ref_formulas: Vec<(String, String, Formula)> = tables
        .iter()
        .filter(|t| !lobe::measured::is_measured_path(t))
        .map(|t| {
            let (file, src) = common::read_source(t)?;
            let f = common::load_formula(Some(&file), None)?;
            Ok((file, src, f))
        })
        .collect::<Result<_, CliError>>()?;
    common::check_set_names(&models.iter().map(|m| &m.2).chain(ref_formulas.iter().map(|r| &r.2)).collect::<Vec<_>>(), &set)?;
    // A name both searched and set is the fitted formula's search and a reference formula's value (fitting a
    // formula to itself at other values); without a reference formula declaring it, a contradiction.
    for name in &searched {
        if set.iter().any(|(k, _)| k == name) && !ref_formulas.iter().any(|r| r.2.param_index(name).is_some()) {
            return Err(CliError::hint(format!("`{name}` is both searched (--param) and fixed (--set)"), "drop one of them"));
        }
    }
    let models: Vec<Model> = models
        .into_iter()
        .map(|(file, src, formula)| {
            let own: Vec<(String, f64)> = common::set_for(&formula, &set).into_iter().filter(|(k, _)| !searched.contains(k)).collect();
            let free = free_of(a, &formula, batch)?;
            let kernels = formula.channels().into_iter().map(|c| common::compile_kernel(c, &own, a.backend.bulk_backend()?, a.backend.math.mode)).collect::<Result<Vec<_>, _>>()?;
            let grad = if a.refinement() == Refinement::Lm && !a.no_refine && !free.is_empty() {
                let vars: Vec<Var> = free.iter().map(|f| Var::Param(f.index as u16)).collect();
                let opts = lobe::Options { backend: a.backend.bulk_backend()?, bake: own.clone(), math: a.backend.math.mode, ..lobe::Options::default() };
                Gradient::compile_vars(&formula, &opts, Some(&vars)).ok()
            } else {
                None
            };
            Ok(Model { file, src, formula, kernels, grad, set: own, free })
        })
        .collect::<Result<_, CliError>>()?;
    // Every table is read (and checked), every reference formula compiled, before any fit runs.
    let mut refs = ref_formulas.into_iter();
    let loaded: Vec<Against> = tables
        .iter()
        .map(|t| {
            if lobe::measured::is_measured_path(t) {
                let table: Arc<dyn Reference> = Arc::new(Measured::read(t)?);
                return Ok(Against { path: t.clone(), src: String::new(), set: vec![], reference: table });
            }
            let (path, src, f) = refs.next().expect("a formula per formula path");
            fit_reference(a, path, src, f, &set, &models)
        })
        .collect::<Result<_, CliError>>()?;
    let opts = MeasuredFitOptions {
        metric,
        stride: usize::from(a.stride),
        grid_stride: usize::from(a.grid_stride),
        top: usize::from(a.top),
        refine: !a.no_refine,
        refinement: a.refinement(),
    };
    let pairs: Vec<(usize, usize)> = (0..models.len()).flat_map(|m| (0..loaded.len()).map(move |t| (m, t))).collect();
    // After a second on a terminal: pairs done (a batch) or candidates scored (one fit).
    let spinner = Spinner::new(!a.json.on && !a.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr()), "fitting");
    let (done, scored) = (std::sync::atomic::AtomicUsize::new(0), std::sync::atomic::AtomicUsize::new(0));
    let tick = || {
        let k = scored.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        if pairs.len() == 1 && k % 16 == 0 {
            spinner.show(format!("{k} candidates scored"));
        }
    };
    let rows: Result<Vec<Row>, CliError> = pairs
        .par_iter()
        .map(|&(m, t)| {
            let row = fit_one(&models[m], &loaded[t], &opts, &tick);
            let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if pairs.len() > 1 {
                spinner.show(format!("{d}/{} formula × table pairs", pairs.len()));
            }
            row
        })
        .collect();
    spinner.finish();
    let rows = rows?;
    if !batch {
        return single(a, &rows[0], metric);
    }
    let text = table_text(&rows, metric);
    if let Some(t) = &a.table {
        let bytes = if t.extension().is_some_and(|e| e == "json") { table_json(&rows, metric)? } else { table_csv(&rows, metric) };
        a.out.force.write(t, bytes.as_bytes(), common::is_lobe_output)?;
    }
    if a.json.on {
        println!("{}", table_json(&rows, metric)?);
    } else {
        print!("{text}");
        if let Some(t) = &a.table {
            println!("wrote {}", t.display());
        }
    }
    Ok(())
}

/// The formula `f` (file `path`) as a reference at the `--set` values it declares, compiled on `backend` in
/// `math`: compared at φ_h turns too unless it and every formula compared with it (`others`: kernels and their
/// parameter values) are isotropic; a colour scale fitted only when `fit_scale`.
pub fn formula_reference(
    path: &str,
    f: &Formula,
    set: &[(String, f64)],
    (backend, math): (lobe::Backend, lobe::Mode),
    fit_scale: bool,
    others: &[(&dyn Evaluator, Vec<f64>)],
) -> Result<FormulaReference, CliError> {
    let own = common::set_for(f, set);
    let params = common::param_values(f, &own);
    let kernels = f
        .channels()
        .into_iter()
        .map(|c| common::compile_kernel(c, &own, backend, math).map(|k| Arc::new(k) as Arc<dyn Evaluator>))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(FormulaReference::new(path, kernels, params, others, fit_scale))
}

/// [`formula_reference`] for a fit: against every fitted formula at its fixed values.
fn fit_reference(a: &FitArgs, path: String, src: String, f: Formula, set: &[(String, f64)], models: &[Model]) -> Result<Against, CliError> {
    let others: Vec<(&dyn Evaluator, Vec<f64>)> =
        models.iter().flat_map(|m| m.kernels.iter().map(|k| (k as &dyn Evaluator, common::param_values(&m.formula, &m.set)))).collect();
    let reference = formula_reference(&path, &f, set, (a.backend.bulk_backend()?, a.backend.math.mode), a.fit_scale, &others)?;
    Ok(Against { path, src, set: common::set_for(&f, set), reference: Arc::new(reference) })
}

fn fit_one<'a>(model: &'a Model, against: &'a Against, opts: &MeasuredFitOptions, progress: &(dyn Fn() + Sync)) -> Result<Row<'a>, CliError> {
    let start = std::time::Instant::now();
    let channels: Vec<&dyn Evaluator> = model.kernels.iter().map(|k| k as &dyn Evaluator).collect();
    let params = common::param_values(&model.formula, &model.set);
    let row = fit_row(&channels, model.grad.as_ref(), &params, &model.free, against.reference.as_ref(), opts, progress)?;
    Ok(Row { model, against, table: &against.path, row, seconds: start.elapsed().as_secs_f64() })
}

/// The searched parameters of a candidate, `name=value` joined by `sep`.
fn shown(model: &Model, params: &[f64], sep: &str) -> String {
    let v: Vec<String> = model.free.iter().map(|f| format!("{}={}", f.name, common::short_number(params[f.index]))).collect();
    if v.is_empty() { "-".into() } else { v.join(sep) }
}

fn single(a: &FitArgs, row: &Row, metric: MeasuredMetric) -> Result<(), CliError> {
    let (m, fit) = (row.model, &row.row.fit);
    let Some(best) = fit.best.first().filter(|b| b.residual.error.is_finite()) else {
        return Err(CliError::hint(
            format!("no candidate has a finite error: {} is NaN or infinite at some entry of {}", m.formula.display_name(), row.table),
            "run `lobe sweep` on the formula to see where",
        ));
    };
    if let Some(o) = &a.out.path {
        let png = comparison_png(a, row)?;
        a.out.force.write(o, &png, lobe::render::image::is_lobe_png)?;
    }
    if a.json.on {
        println!("{}", common::to_json(&row_json(row, metric))?);
        return Ok(());
    }
    println!(
        "{} vs {}: {} error over {} entries (grid on {}), {} residuals in {:.2} s, backend {}",
        m.formula.display_name(),
        row.table,
        metric.name(),
        fit.entries,
        fit.grid_entries,
        fit.evaluated,
        row.seconds,
        m.kernels[0].backend_used().name()
    );
    match fit.refinement {
        Refinement::Lm => println!(
            "refinement: Levenberg–Marquardt with the exact Jacobian from {} grid points, {} iterations, {} evaluations",
            fit.lm.starts, fit.lm.iterations, fit.lm.evaluations
        ),
        Refinement::DerivativeFree => println!("refinement: derivative-free (golden section or Nelder–Mead)"),
    }
    for name in &fit.fixed {
        println!("fixed: {name} (its range is one value)");
    }
    for (i, c) in fit.best.iter().enumerate() {
        let [r, g, b] = c.residual.scale;
        println!(
            "  {}. {:<30} error {:.6e}  scale ({r:.4}, {g:.4}, {b:.4}){}",
            i + 1,
            shown(m, &c.params, ", "),
            c.residual.error,
            if c.refined { "  (continuous refinement)" } else { "" }
        );
    }
    let [log, rmse, cosine] = row.row.all;
    println!("best: {}; log error {log:.6e}, rmse {rmse:.6e}, cosine {cosine:.6e}", shown(m, &best.params, ", "));
    if let Some(o) = &a.out.path {
        println!("wrote {} (fitted formula | measurement | |Δgray| heat map)", o.display());
    }
    Ok(())
}

/// The fitted formula (its colour scale as the specular tint) beside the measurement on the papers' sphere.
fn comparison_png(a: &FitArgs, row: &Row) -> Result<Vec<u8>, CliError> {
    use lobe::render::compare::{compare_formulas, sweep_image, CompareJob};
    let (m, best) = (row.model, &row.row.fit.best[0]);
    let mut set = m.set.clone();
    set.extend(m.free.iter().map(|f| (f.name.clone(), best.params[f.index])));
    set.extend(row.against.set.iter().filter(|(k, _)| !set.iter().any(|(s, _)| s == k)).cloned().collect::<Vec<_>>());
    let scene = lobe::render::scene::PAPER_SCENE;
    let job = CompareJob {
        scene_name: "<builtin paper_sphere.toml>",
        scene_src: scene,
        base: Path::new("."),
        a: (&m.file, &m.src),
        b: (row.table, &row.against.src),
        size: None,
        tint: [best.residual.scale, [1.0; 3]],
    };
    let compiler = common::scene_compiler(a.backend.backend()?, a.backend.math.mode);
    let c = compare_formulas(&job, &set, &compiler, &lobe::render::RenderOptions::default())?;
    let scale = c.metrics.max_gray_diff.max(1.0);
    let headings = [m.file.as_str(), row.table, "|Δgray|"];
    lobe::report::plot::comparison_figure(&sweep_image(std::slice::from_ref(&c), scale), headings, &[], scale)
        .and_then(|f| f.encode_png())
        .map_err(CliError::msg)
}

/// One fit in `--json` and `--table` JSON (keys in docs/measured.md).
fn row_json<'a>(r: &'a Row, metric: MeasuredMetric) -> MeasuredRowJson<'a> {
    MeasuredRowJson::new(r.model.formula.display_name(), &r.model.file, r.table, &r.model.free, &r.row, metric, r.seconds)
}

fn table_json(rows: &[Row], metric: MeasuredMetric) -> Result<String, CliError> {
    #[derive(serde::Serialize)]
    struct Doc<'a> {
        generator: &'static str,
        fits: Vec<MeasuredRowJson<'a>>,
    }
    common::to_json(&Doc { generator: "made by lobe fit --measured", fits: rows.iter().map(|r| row_json(r, metric)).collect() })
}

/// The CSV table: a `#` comment line naming lobe, then a header and one row per fit.
fn table_csv(rows: &[Row], metric: MeasuredMetric) -> String {
    let q = |s: &str| if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() };
    let mut out = format!("# made by lobe fit --measured (metric {})\n", metric.name());
    out.push_str("formula,file,measured,params,error,log,rmse,cosine,scale_r,scale_g,scale_b,entries,seconds\n");
    for r in rows {
        let b = &r.row.fit.best[0];
        let [sr, sg, sb] = b.residual.scale;
        out.push_str(&format!(
            "{},{},{},{},{:e},{:e},{:e},{:e},{sr},{sg},{sb},{},{:.3}\n",
            q(&r.model.formula.display_name()),
            q(&r.model.file),
            q(r.table),
            q(&shown(r.model, &b.params, ";")),
            b.residual.error,
            r.row.all[0],
            r.row.all[1],
            r.row.all[2],
            r.row.fit.entries,
            r.seconds
        ));
    }
    out
}

/// The table as text: one row per formula, one column per measured file (the error), best per column marked.
fn table_text(rows: &[Row], metric: MeasuredMetric) -> String {
    let mut tables: Vec<&str> = vec![];
    for r in rows {
        if !tables.contains(&r.table) {
            tables.push(r.table);
        }
    }
    let name = |t: &str| Path::new(t).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let mut out = format!("{} error of each formula's best fit (fitted parameters below each error)\n", metric.name());
    out.push_str(&format!("{:<28}", "formula"));
    for t in &tables {
        out.push_str(&format!(" {:>22}", name(t)));
    }
    out.push('\n');
    let mut seen: Vec<&str> = vec![];
    for r in rows {
        if seen.contains(&r.model.file.as_str()) {
            continue;
        }
        seen.push(&r.model.file);
        let mine: Vec<&Row> = rows.iter().filter(|x| x.model.file == r.model.file).collect();
        out.push_str(&format!("{:<28}", r.model.formula.display_name()));
        for t in &tables {
            let cell = mine.iter().find(|x| x.table == *t).map(|x| format!("{:.4e}", x.row.fit.best[0].residual.error)).unwrap_or_default();
            out.push_str(&format!(" {cell:>22}"));
        }
        out.push('\n');
        out.push_str(&format!("{:<28}", ""));
        for t in &tables {
            let cell = mine.iter().find(|x| x.table == *t).map(|x| shown(x.model, &x.row.fit.best[0].params, " ")).unwrap_or_default();
            out.push_str(&format!(" {cell:>22}"));
        }
        out.push('\n');
    }
    out
}
