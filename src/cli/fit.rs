//! `lobe fit FILE --reference REF --param a=1..1000[:step] [--param …] [--metric mean-abs] [--json]`
//! `lobe fit FILES… --measured TABLES|DIR|REF.brdf… --param n=1..1000 [--metric log|rmse|cosine] [-o cmp.png] [--table t.csv]`
//!
//! JSON keys are documented in [`lobe::numerics`] and, for measured fits, in docs/measured.md.

use super::common::{self, CliError};
use lobe::numerics::fit::{fit_with, FitJson, FitOptions, FreeParam, Metric, Refinement};
use lobe::numerics::grad::{Gradient, Var};
use super::fit_args::{free_specs, FitArgs};
use lobe::Kernel;
use std::io::IsTerminal;

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
}
