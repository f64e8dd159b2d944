//! `lobe fit FILE --reference REF --param a=1..1000[:step] [--param …] [--metric mean-abs] [--json]`
//! `lobe fit FILES… --measured TABLES|DIR|REF.brdf… --param n=1..1000 [--metric log|rmse|cosine] [-o cmp.png] [--table t.csv]`
//!
//! JSON keys are documented in [`lobe::numerics`] and, for measured fits, in docs/measured.md.

use super::args::{self, AgainstReference, BackendArg, FormulaSource, Json, LobeVar, Output, Params};
use super::common::{self, CliError};
use lobe::numerics::fit::{fit_with, FitJson, FitOptions, FreeParam, Metric, Refinement};
use lobe::numerics::grad::{Gradient, Var};
use super::args::parse_range;
use lobe::Kernel;
use std::io::IsTerminal;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Fixed values of other parameters, e.g. `k=2`")))]
pub struct FitArgs {
    /// Formula file(s) (.brdf); several only with --measured (each fitted to each table).
    pub files: Vec<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "files", allow_hyphen_values = true)]
    pub expr: Option<String>,
    /// The reference lobe (normally Blinn, cos^n).
    #[arg(long, required_unless_present = "measured", conflicts_with = "measured")]
    pub reference: Option<String>,
    /// Measured tables (MERL .binary), or folders of them: fit to the measurement instead of a reference lobe. A
    /// formula file (.brdf) here is a reference over the whole hemisphere: its values (at the `--set` values of the
    /// parameters it declares) at the tables' angles, for every incidence.
    #[arg(long, num_args = 1..)]
    pub measured: Vec<String>,
    #[command(flatten)]
    pub lobe: LobeVar,
    /// A parameter to search over the interval [lo, hi]: `name=lo..hi` (a grid of 41 values, or the integers when
    /// lo and hi are integers at least 40 apart, then continuous refinement) or `name=lo..hi:step`.
    #[arg(long, required = true)]
    pub param: Vec<String>,
    #[command(flatten)]
    pub set: Params,
    /// What to minimise: mean-abs (the papers', the default), max-abs, epicenter; against --measured: log
    /// (cosine-weighted log error, the default), rmse or cosine (cosine-weighted L2).
    #[arg(long)]
    pub metric: Option<String>,
    /// --measured: use every STRIDE-th table index along each axis for the refinement and the residual.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=90))]
    pub stride: u16,
    /// --measured: the (coarser) stride of the grid stage.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=90))]
    pub grid_stride: u16,
    /// --measured against a formula: fit a colour scale too (by default a formula's values are absolute).
    #[arg(long)]
    pub fit_scale: bool,
    /// --measured: write the table of every formula × measurement fit (.csv or .json).
    #[arg(long)]
    pub table: Option<std::path::PathBuf>,
    /// --measured: the comparison image (fitted formula | measurement | difference) on the papers' sphere.
    #[command(flatten)]
    pub out: Output,
    /// How many candidates to print.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u16).range(1..))]
    pub top: u16,
    /// Skip the continuous refinement after the grid.
    #[arg(long)]
    pub no_refine: bool,
    /// Refine as before the exact Jacobian: the fine grid, then golden section or Nelder–Mead around its best
    /// point (the default is Levenberg–Marquardt from the best points of a coarse grid, for comparison).
    #[arg(long, conflicts_with = "no_refine")]
    pub derivative_free: bool,
    /// Largest n of the metric.
    #[arg(long, default_value_t = 1000)]
    pub n_max: u32,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
}

/// A `--param`: name, lo, hi and the step, if given.
pub type FreeSpec = (String, f64, f64, Option<f64>);

/// Parses `name=lo..hi[:step]`.
pub fn parse_free(s: &str) -> Result<FreeSpec, String> {
    let (name, rest) = s.split_once('=').ok_or_else(|| format!("`{s}` is not of the form name=lo..hi (e.g. a=1..1000)"))?;
    let (range, step) = match rest.split_once(':') {
        Some((r, st)) => (r, Some(st.trim().parse::<f64>().map_err(|_| format!("`{st}` is not a step in `{s}`"))?)),
        None => (rest, None),
    };
    let (lo, hi) = parse_range(range)?;
    Ok((name.trim().to_string(), lo, hi, step))
}

/// Every `--param`, parsed.
pub fn free_specs(a: &FitArgs) -> Result<Vec<FreeSpec>, CliError> {
    a.param
        .iter()
        .map(|p| parse_free(p).map_err(|e| CliError::hint(format!("--param: {e}"), "e.g. --param a=1..1000 or a=0.1..0.9:0.1")))
        .collect()
}

impl FitArgs {
    /// The refinement `--derivative-free` selects.
    pub fn refinement(&self) -> Refinement {
        if self.derivative_free {
            Refinement::DerivativeFree
        } else {
            Refinement::Lm
        }
    }

    /// The one formula measured against `--reference`.
    fn against(&self) -> Result<AgainstReference, CliError> {
        if self.files.len() > 1 {
            return Err(CliError::hint("several formulas are fitted to measured tables only", "give one formula with --reference, or use --measured"));
        }
        let formula = FormulaSource { file: self.files.first().cloned(), expr: self.expr.clone() };
        Ok(AgainstReference { formula, reference: self.reference.clone().unwrap_or_default(), lobe: self.lobe.clone() })
    }

    /// The papers' metric of a fit against a reference lobe.
    fn lobe_metric(&self) -> Result<Metric, CliError> {
        self.metric.as_deref().unwrap_or("mean-abs").parse().map_err(|e: String| CliError::hint(format!("--metric: {e}"), "log and rmse apply to --measured fits"))
    }
}

/// A fit against `--reference` (`--measured` fits are [`super::fit_measured::run`]).
pub fn run(a: &FitArgs) -> Result<(), CliError> {
    // The papers' metrics sweep n in both formulas: where one of them reads no n, the sweep would compare one
    // fixed lobe with a thousand, so the comparison is over the whole hemisphere instead.
    // (A formula on standard input is read once, by the fit itself.)
    let reference = a.reference.clone().unwrap_or_default();
    let source = a.against()?.formula;
    let on_stdin = source.file.as_deref() == Some("-") || reference == "-";
    let f = if on_stdin { None } else { Some(common::load_formula_with(source.file.as_deref(), source.expr.as_deref(), false)?) };
    let rf = if on_stdin { None } else { Some(common::load_formula_with(Some(&reference), None, false)?) };
    if let (Some(f), Some(rf)) = (f, rf) {
        if common::reads_n(&f) && common::reads_n(&rf) {
            return lobe_fit(a);
        }
        if a.metric.as_deref().is_some_and(|m| m.parse::<Metric>().is_ok()) {
            return Err(CliError::hint(
                format!("--metric {}: the papers' metrics sweep n, and {}", a.metric.as_deref().unwrap_or(""), common::which_reads_no_n(&f, &rf)),
                "compare over the whole hemisphere with --metric log, rmse or cosine",
            ));
        }
        if !a.json.on && !a.quiet {
            eprintln!("note: {}, so the papers' n-sweep does not apply: fitted over the whole hemisphere (every incidence, at the measured tables' angles)", common::which_reads_no_n(&f, &rf));
        }
        return super::fit_measured::run_against(a, std::slice::from_ref(&reference));
    }
    lobe_fit(a)
}

/// The papers' fit: the metric over n = 1..n_max of the formula against the reference lobe.
fn lobe_fit(a: &FitArgs) -> Result<(), CliError> {
    let set = a.set.list()?;
    for (name, ..) in free_specs(a)? {
        if set.iter().any(|(k, _)| *k == name) {
            return Err(CliError::hint(format!("`{name}` is both searched (--param) and fixed (--set)"), "drop one of them"));
        }
    }
    let (k, r) = a.against()?.kernels(&set, &a.backend)?;
    print!("{}", report(a, &k, &r)?);
    Ok(())
}

/// The command's output for already compiled kernels (formula `k`, reference `r`).
pub fn report(a: &FitArgs, k: &Kernel, r: &Kernel) -> Result<String, CliError> {
    let mut out = String::new();
    let set = a.set.list()?;
    let mut free = vec![];
    for (name, lo, hi, step) in free_specs(a)? {
        let Some(index) = k.formula.param_index(&name) else {
            let names: Vec<&str> = k.formula.params.iter().map(|p| p.name.as_str()).collect();
            let hint = common::did_you_mean(&name, &names, "its parameters are: ");
            return Err(CliError::hint(format!("--param: the formula has no parameter `{name}`"), hint));
        };
        let d = &k.formula.params[index];
        if lo < d.lo || hi > d.hi {
            return Err(CliError::hint(
                format!("--param {name}={lo}..{hi} leaves the declared range {}..{}", d.lo, d.hi),
                "search inside the declared range, or widen it in the file",
            ));
        }
        free.push(FreeParam { index, name, lo, hi, step });
    }
    let params = common::param_values(&k.formula, &common::set_for(&k.formula, &set));
    let metric = a.lobe_metric()?;
    let (lobe, ref_lobe) = a.against()?.lobes(k, r, a.json.on)?;
    let mut total = 1usize;
    for f in &free {
        total = total.saturating_mul(f.grid()?.len());
    }
    let bar = if a.quiet || a.json.on || !std::io::stderr().is_terminal() {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new(total as u64);
        if let Ok(s) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} candidates, {elapsed} (eta {eta})") {
            b.set_style(s);
        }
        b
    };
    let opts = FitOptions { metric, top: usize::from(a.top), refine: !a.no_refine, n_max: a.n_max };
    let t = std::time::Instant::now();
    // The value and the partials by the free parameters, for Levenberg–Marquardt (the derivative-free
    // refinement where they do not compile).
    let grad = if a.refinement() == Refinement::Lm && !a.no_refine {
        let vars: Vec<Var> = free.iter().map(|f| Var::Param(f.index as u16)).collect();
        let gopts = lobe::Options { backend: a.backend.bulk_backend()?, math: a.backend.math.mode, ..lobe::Options::default() };
        Gradient::compile_vars(&k.formula, &gopts, Some(&vars)).ok()
    } else {
        None
    };
    let rep = fit_with(k, grad.as_ref(), &params, lobe, r, &r.default_params(), ref_lobe, &free, &opts, &|| bar.inc(1))?;
    bar.finish_and_clear();
    if !rep.best.first().is_some_and(|c| c.score.is_finite()) {
        return Err(CliError::hint(
            "no candidate has a finite score: the formula or the reference is NaN or infinite on the papers' grid",
            "run `lobe sweep` on both files to see where",
        ));
    }
    let secs = t.elapsed().as_secs_f64();
    let names: Vec<&str> = free.iter().map(|f| f.name.as_str()).collect();
    if a.json.on {
        outln!(out, "{}", common::to_json(&FitJson::new(&rep, &free, metric, secs))?);
        return Ok(out);
    }
    outln!(out, 
        "{} vs {}: {} over {} ({} grid points, {} scores in {secs:.2} s, backend {})",
        k.formula.display_name(),
        r.formula.display_name(),
        metric.name(),
        names.join(", "),
        total,
        rep.evaluated,
        k.backend_used().name()
    );
    match rep.refinement {
        Refinement::Lm => outln!(
            out,
            "refinement: Levenberg–Marquardt with the exact Jacobian from {} grid points, {} iterations, {} evaluations",
            rep.lm.starts,
            rep.lm.iterations,
            rep.lm.evaluations
        ),
        Refinement::DerivativeFree if !a.no_refine => outln!(out, "refinement: derivative-free (golden section or Nelder–Mead)"),
        Refinement::DerivativeFree => {}
    }
    for (i, c) in rep.best.iter().enumerate() {
        let shown: Vec<String> = free.iter().map(|f| format!("{}={}", f.name, c.params[f.index])).collect();
        outln!(out, "  {}. {:<40} score {:.6e}{}", i + 1, shown.join(", "), c.score, if c.refined { "  (continuous refinement)" } else { "" });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lobe::numerics::twins;
    use crate::cli::energy::tests::{parse, twin_kernel};
    use lobe::ir::Input;


    #[test]
    fn finds_268_and_reports_json() {
        let a = parse::<FitArgs>(&["fit", "--reference", "b", "--param", "a=260..280", "--json", "--quiet"]);
        let k = twin_kernel(twins::f_st(), Input::NH, &[("a", 16.0, 1.0, 1000.0)]);
        let r = twin_kernel(twins::blinn(), Input::NH, &[]);
        let v: serde_json::Value = serde_json::from_str(&report(&a, &k, &r).unwrap()).unwrap();
        let best = &v["best"].as_array().unwrap();
        let grid = best.iter().find(|c| c["refined"] == false).unwrap();
        assert_eq!(grid["params"]["a"].as_f64(), Some(268.0), "{v}");
        let a = parse::<FitArgs>(&["fit", "--reference", "b", "--param", "b=1..3"]);
        assert!(report(&a, &k, &r).unwrap_err().render(false).contains("no parameter `b`"));
        let a = parse::<FitArgs>(&["fit", "--reference", "b", "--param", "a=0..3"]);
        assert!(report(&a, &k, &r).unwrap_err().render(false).contains("declared range"));
    }

    #[test]
    fn parses_free_parameters() {
        assert_eq!(super::parse_free("a=1..1000").unwrap(), ("a".into(), 1.0, 1000.0, None));
        assert_eq!(super::parse_free("Q=0.1..0.9:0.1").unwrap(), ("Q".into(), 0.1, 0.9, Some(0.1)));
        assert!(super::parse_free("a").is_err());
        assert!(super::parse_free("a=5..1").is_err());
        assert!(super::parse_free("a=1..x").is_err());
    }
}
