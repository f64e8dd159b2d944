//! `lobe fit FILE --reference REF --param a=1..1000[:step] [--param …] [--metric mean-abs] [--json]`
//!
//! JSON keys are documented in [`crate::numerics`].

use super::common::{self, CliError};
use super::energy::resolve_lobe;
use crate::numerics::fit::{fit, FitOptions, FreeParam, Metric};
use crate::numerics::{json_num, parse_range};
use crate::{Backend, Kernel};
use serde_json::json;
use std::io::IsTerminal;

#[derive(clap::Args, Debug)]
pub struct FitArgs {
    /// Formula file (.brdf), or `-` for standard input.
    pub file: Option<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "file")]
    pub expr: Option<String>,
    /// The reference lobe (normally Blinn, cos^n).
    #[arg(long)]
    pub reference: String,
    /// A parameter to search: `name=lo..hi` (integers when lo and hi are) or `name=lo..hi:step`.
    #[arg(long, required = true)]
    pub param: Vec<String>,
    /// Fixed values of other parameters, e.g. `k=2`.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub set: Vec<Vec<(String, f64)>>,
    /// What to minimise: mean-abs (the papers'), max-abs, epicenter.
    #[arg(long, default_value = "mean-abs")]
    pub metric: Metric,
    /// How many candidates to print.
    #[arg(long, default_value_t = 5)]
    pub top: usize,
    /// Skip the continuous refinement after the grid.
    #[arg(long)]
    pub no_refine: bool,
    /// Largest n of the metric.
    #[arg(long, default_value_t = 1000)]
    pub n_max: u32,
    /// The lobe variable (NH or VR); default: the one the formula reads.
    #[arg(long)]
    pub lobe: Option<String>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[arg(long, default_value = "jit")]
    pub backend: Backend,
    /// Print one JSON object (keys documented in the crate docs of `check`).
    #[arg(long)]
    pub json: bool,
}

/// Parses `name=lo..hi[:step]`.
pub fn parse_free(s: &str) -> Result<(String, f64, f64, Option<f64>), String> {
    let (name, rest) = s.split_once('=').ok_or_else(|| format!("`{s}` is not of the form name=lo..hi (e.g. a=1..1000)"))?;
    let (range, step) = match rest.split_once(':') {
        Some((r, st)) => (r, Some(st.trim().parse::<f64>().map_err(|_| format!("`{st}` is not a step in `{s}`"))?)),
        None => (rest, None),
    };
    let (lo, hi) = parse_range(range)?;
    Ok((name.trim().to_string(), lo, hi, step))
}

pub fn run(a: &FitArgs) -> Result<(), CliError> {
    let set: Vec<(String, f64)> = a.set.concat();
    let mut free_spec = vec![];
    for p in &a.param {
        free_spec.push(parse_free(p).map_err(|e| CliError::hint(format!("--param: {e}"), "e.g. --param a=1..1000 or a=0.1..0.9:0.1"))?);
    }
    for (name, ..) in &free_spec {
        if set.iter().any(|(k, _)| k == name) {
            return Err(CliError::hint(format!("`{name}` is both searched (--param) and fixed (--set)"), "drop one of them"));
        }
    }
    let k = common::load_kernel(a.file.as_deref(), a.expr.as_deref(), &set, a.backend)?;
    let r = common::load_kernel(Some(&a.reference), None, &[], a.backend)?;
    print!("{}", report(a, &k, &r)?);
    Ok(())
}

/// The command's output for already compiled kernels (formula `k`, reference `r`).
pub fn report(a: &FitArgs, k: &Kernel, r: &Kernel) -> Result<String, CliError> {
    let mut out = String::new();
    let set: Vec<(String, f64)> = a.set.concat();
    let mut free_spec = vec![];
    for p in &a.param {
        free_spec.push(parse_free(p).map_err(|e| CliError::hint(format!("--param: {e}"), "e.g. --param a=1..1000 or a=0.1..0.9:0.1"))?);
    }
    let mut free = vec![];
    for (name, lo, hi, step) in free_spec {
        let Some(index) = k.formula.param_index(&name) else {
            let names: Vec<&str> = k.formula.params.iter().map(|p| p.name.as_str()).collect();
            let hint = match crate::front::suggest(&name, names.iter().copied()) {
                Some(s) => format!("did you mean `{s}`?"),
                None => format!("its parameters are: {}", names.join(", ")),
            };
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
    let params = common::param_values(&k.formula, &set);
    let (lobe, note) = resolve_lobe(a.lobe.as_deref(), k.used_inputs())?;
    let (ref_lobe, _) = resolve_lobe(None, r.used_inputs())?;
    if let (Some(n), false) = (&note, a.json) {
        eprintln!("note: {n}");
    }
    let mut total = 1usize;
    for f in &free {
        total = total.saturating_mul(f.grid()?.len());
    }
    let bar = if a.quiet || a.json || !std::io::stderr().is_terminal() {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new(total as u64);
        if let Ok(s) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} candidates, {elapsed} (eta {eta})") {
            b.set_style(s);
        }
        b
    };
    let opts = FitOptions { metric: a.metric, top: a.top.max(1), refine: !a.no_refine, n_max: a.n_max };
    let t = std::time::Instant::now();
    let rep = fit(k, &params, lobe, r, &r.default_params(), ref_lobe, &free, &opts, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let secs = t.elapsed().as_secs_f64();
    let names: Vec<&str> = free.iter().map(|f| f.name.as_str()).collect();
    if a.json {
        let best: Vec<_> = rep
            .best
            .iter()
            .map(|c| {
                let p: serde_json::Map<String, serde_json::Value> =
                    free.iter().map(|f| (f.name.clone(), json_num(c.params[f.index]))).collect();
                json!({"params": p, "score": json_num(c.score), "refined": c.refined})
            })
            .collect();
        outln!(out, "{}", json!({"best": best, "metric": a.metric.name(), "evaluated": rep.evaluated, "seconds": secs}));
        return Ok(out);
    }
    outln!(out, 
        "{} vs {}: {} over {} ({} grid points, {} scores in {secs:.2} s, backend {})",
        k.formula.display_name(),
        r.formula.display_name(),
        a.metric.name(),
        names.join(", "),
        total,
        rep.evaluated,
        k.backend.name()
    );
    for (i, c) in rep.best.iter().enumerate() {
        let shown: Vec<String> = free.iter().map(|f| format!("{}={}", f.name, c.params[f.index])).collect();
        outln!(out, "  {}. {:<40} score {:.6e}{}", i + 1, shown.join(", "), c.score, if c.refined { "  (continuous refinement)" } else { "" });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::twins;
    use crate::cli::energy::tests::twin_kernel;
    use crate::ir::Input;
    use clap::Parser;

    #[derive(Parser)]
    struct T {
        #[command(flatten)]
        a: FitArgs,
    }

    #[test]
    fn finds_268_and_reports_json() {
        let a = T::try_parse_from(["fit", "--reference", "b", "--param", "a=260..280", "--json", "--quiet"]).unwrap().a;
        let k = twin_kernel(twins::f_st(), Input::NH, &[("a", 16.0, 1.0, 1000.0)]);
        let r = twin_kernel(twins::blinn(), Input::NH, &[]);
        let v: serde_json::Value = serde_json::from_str(&report(&a, &k, &r).unwrap()).unwrap();
        let best = &v["best"].as_array().unwrap();
        let grid = best.iter().find(|c| c["refined"] == false).unwrap();
        assert_eq!(grid["params"]["a"].as_f64(), Some(268.0), "{v}");
        let a = T::try_parse_from(["fit", "--reference", "b", "--param", "b=1..3"]).unwrap().a;
        assert!(report(&a, &k, &r).unwrap_err().render(false).contains("no parameter `b`"));
        let a = T::try_parse_from(["fit", "--reference", "b", "--param", "a=0..3"]).unwrap().a;
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
