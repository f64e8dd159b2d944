//! `lobe sweep FILE [--set …] [--bound 1e6] [--deny nan,inf] [--json]` (also reachable as `lobe check --sweep`).
//!
//! Evaluates the *unclamped* formula (root `max(raw, 0)` peeled) over the domain; see [`crate::numerics::sweep`].
//! Exits with status 1 when a kind listed in `--deny` occurs (after printing the report).

use super::common::{self, CliError};
use crate::numerics::json_num;
use crate::numerics::sweep::{sweep, Example, RegionStats, SweepOptions};
use crate::ir::Formula;
use crate::{Backend, Options};
use serde_json::json;

#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// Formula file (.brdf), or `-` for standard input.
    pub file: Option<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "file")]
    pub expr: Option<String>,
    /// Fix parameters instead of sweeping their declared ranges, e.g. `a=16`.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub set: Vec<Vec<(String, f64)>>,
    /// Values above this are counted as over the bound.
    #[arg(long, default_value_t = 1e6)]
    pub bound: f64,
    /// Evaluation budget (the full grid is subsampled above it).
    #[arg(long, default_value_t = 2_000_000)]
    pub max_evals: u64,
    /// Fail (exit 1) if any of these occur: nan, inf, negative, bound.
    #[arg(long, value_delimiter = ',')]
    pub deny: Vec<String>,
    #[arg(long, default_value = "jit")]
    pub backend: Backend,
    /// Print one JSON object (keys documented in the crate docs of `check`).
    #[arg(long)]
    pub json: bool,
}

const KINDS: [&str; 4] = ["nan", "inf", "negative", "bound"];

fn example_json(e: &Option<Example>, names: &[String]) -> serde_json::Value {
    match e {
        None => serde_json::Value::Null,
        Some(e) => {
            let inputs: serde_json::Map<_, _> = crate::Input::ALL.iter().map(|i| (i.name().to_string(), json_num(e.inputs[i.index()]))).collect();
            let params: serde_json::Map<_, _> = names.iter().cloned().zip(e.params.iter().map(|v| json_num(*v))).collect();
            json!({"inputs": inputs, "params": params, "value": json_num(e.value)})
        }
    }
}

/// A compact number: plain for ordinary magnitudes, scientific otherwise.
fn num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn example_text(e: &Example, used: crate::ir::InputSet, names: &[String]) -> String {
    let mut parts: Vec<String> = used.iter().map(|i| format!("{}={}", i.name(), num(e.inputs[i.index()]))).collect();
    parts.extend(names.iter().zip(&e.params).map(|(n, v)| format!("{n}={}", num(*v))));
    format!("{} → {}", parts.join(" "), num(e.value))
}

pub fn run(a: &SweepArgs) -> Result<(), CliError> {
    for d in &a.deny {
        if !KINDS.contains(&d.as_str()) {
            return Err(CliError::hint(format!("--deny: unknown kind `{d}`"), "kinds are nan, inf, negative, bound"));
        }
    }
    if !(a.bound.is_finite() || a.bound == f64::INFINITY) {
        return Err(CliError::hint("--bound must be a number", "e.g. --bound 1e6"));
    }
    let f = common::load_formula(a.file.as_deref(), a.expr.as_deref())?;
    let (text, denied) = report(a, &f)?;
    print!("{text}");
    if !denied.is_empty() {
        eprintln!("error: denied kinds occurred: {}", denied.join(", "));
        return Err(CliError::Failed);
    }
    Ok(())
}

/// The command's output for a lowered formula, and the `--deny` kinds that occurred.
pub fn report(a: &SweepArgs, f: &Formula) -> Result<(String, Vec<String>), CliError> {
    let mut out = String::new();
    let set: Vec<(String, f64)> = a.set.concat();
    let mut decls = f.params.clone();
    let u = f.unclamped();
    let k = crate::compile_formula(u, &Options { backend: a.backend, bake: set.clone(), ..Options::default() })?;
    // Baked parameters are fixed: sweep them at their value only.
    for (name, v) in &set {
        if let Some(i) = f.param_index(name) {
            decls[i].lo = *v;
            decls[i].hi = *v;
            decls[i].default = *v;
        }
    }
    let used = f.used_inputs();
    let rep = sweep(&k, used, &decls, &SweepOptions { bound: a.bound, max_evals: a.max_evals });
    let names: Vec<String> = decls.iter().map(|d| d.name.clone()).collect();
    let t = &rep.total;
    let count = |kind: &str, s: &RegionStats| match kind {
        "nan" => s.nan,
        "inf" => s.inf,
        "negative" => s.negative,
        _ => s.over_bound,
    };
    if a.json {
        let regions: Vec<_> = rep
            .regions
            .iter()
            .map(|r| {
                json!({"region": r.region, "evaluated": r.evaluated, "nan": r.nan, "inf": r.inf, "negative": r.negative,
                       "over_bound": r.over_bound,
                       "first": {"nan": example_json(&r.first_nan, &names), "inf": example_json(&r.first_inf, &names),
                                 "negative": example_json(&r.first_negative, &names),
                                 "over_bound": example_json(&r.first_over_bound, &names)}})
            })
            .collect();
        outln!(out, 
            "{}",
            json!({"nan": t.nan, "inf": t.inf, "negative": t.negative, "over_bound": t.over_bound, "evaluated": t.evaluated,
                   "bound": json_num(rep.bound), "exhaustive": rep.exhaustive, "regions": regions})
        );
    } else {
        outln!(out, 
            "{}: unclamped formula {} over {} points ({}; inputs read: {})",
            f.display_name(),
            k.formula.to_text(),
            t.evaluated,
            if rep.exhaustive { "exhaustive grid" } else { "subsampled grid" },
            if used.is_empty() { "none".to_string() } else { used.to_string() }
        );
        outln!(out, "  {:<10} {:>10} {:>8} {:>8} {:>9} {:>9}", "region", "evaluated", "NaN", "±inf", "negative", format!(">{:e}", rep.bound));
        for r in rep.regions.iter().chain(std::iter::once(t)) {
            outln!(out, "  {:<10} {:>10} {:>8} {:>8} {:>9} {:>9}", r.region, r.evaluated, r.nan, r.inf, r.negative, r.over_bound);
        }
        for r in &rep.regions {
            for (kind, e) in [("NaN", &r.first_nan), ("inf", &r.first_inf), ("negative", &r.first_negative), ("over bound", &r.first_over_bound)] {
                if let Some(e) = e {
                    outln!(out, "  first {kind} in {}: {}", r.region, example_text(e, used, &names));
                }
            }
        }
    }
    let denied: Vec<String> = a.deny.iter().filter(|d| count(d, t) > 0).cloned().collect();
    Ok((out, denied))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::energy::tests::power_formula;
    use crate::ir::Input;
    use clap::Parser;

    #[derive(Parser)]
    struct T {
        #[command(flatten)]
        a: SweepArgs,
    }

    #[test]
    fn clean_formula_passes_deny_and_reports_json() {
        let f = power_formula(Input::NH, &[]);
        let a = T::try_parse_from(["sweep", "--json", "--deny", "nan,inf", "--backend", "interp"]).unwrap().a;
        let (text, denied) = report(&a, &f).unwrap();
        assert!(denied.is_empty());
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!((v["nan"].as_u64(), v["inf"].as_u64(), v["negative"].as_u64()), (Some(0), Some(0), Some(0)));
        // pow(c, n) with n ≥ 1 is ≤ 1: a bound of 0.5 is exceeded, and `--deny bound` says so.
        let a = T::try_parse_from(["sweep", "--bound", "0.5", "--deny", "bound", "--backend", "interp"]).unwrap().a;
        let (text, denied) = report(&a, &f).unwrap();
        assert_eq!(denied, vec!["bound".to_string()]);
        assert!(text.contains("first over bound"), "{text}");
    }
}
