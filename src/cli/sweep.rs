//! `lobe sweep FILE [--set …] [--bound 1e6] [--deny nan,inf] [--json]` (also reachable as `lobe check --sweep`).
//!
//! Evaluates the *unclamped* formula (root `max(raw, 0)` peeled) over the domain; see [`crate::numerics::sweep`].
//! Exits with status 1 when a kind listed in `--deny` occurs (after printing the report).

use super::args::{self, BackendArg, FormulaSource, Json, Params};
use super::common::{self, CliError};
use crate::base::json;
use crate::ir::Formula;
use crate::numerics::sweep::{extent, sweep, Example, RegionStats, SweepOptions};

use serde::Serialize;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Fix parameters instead of sweeping their declared ranges, e.g. `a=16`")))]
pub struct SweepArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// Values above this are counted as over the bound.
    #[arg(long, default_value_t = 1e6)]
    pub bound: f64,
    /// Evaluation budget (the full grid is subsampled above it).
    #[arg(long, default_value_t = 2_000_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_evals: u64,
    /// Fail (exit 1) if any of these occur: nan, inf, negative, bound.
    #[arg(long, value_delimiter = ',')]
    pub deny: Vec<String>,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
}

/// The `--json` object: the total counts, then each region's counts with its first examples.
#[derive(Serialize)]
struct SweepJson<'a> {
    #[serde(flatten)]
    total: &'a RegionStats,
    #[serde(serialize_with = "json::num")]
    bound: f64,
    exhaustive: bool,
    regions: Vec<RegionJson<'a>>,
}

#[derive(Serialize)]
struct RegionJson<'a> {
    region: &'static str,
    #[serde(flatten)]
    counts: &'a RegionStats,
    first: serde_json::Value,
}

const KINDS: [&str; 4] = ["nan", "inf", "negative", "bound"];

fn example_json(e: &Option<Example>, names: &[String]) -> serde_json::Value {
    match e {
        None => serde_json::Value::Null,
        Some(e) => serde_json::json!({
            "inputs": json::named(crate::Input::ALL.iter().map(|i| (i.name(), e.inputs[i.index()]))),
            "params": json::named(names.iter().map(String::as_str).zip(e.params.iter().copied())),
            "value": json::value(e.value),
        }),
    }
}

/// A number for the text report: plain for ordinary magnitudes, scientific otherwise.
fn compact(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn example_text(e: &Example, used: crate::ir::InputSet, names: &[String]) -> String {
    let mut parts: Vec<String> = used.iter().map(|i| format!("{}={}", i.name(), compact(e.inputs[i.index()]))).collect();
    parts.extend(names.iter().zip(&e.params).map(|(n, v)| format!("{n}={}", compact(*v))));
    format!("{} → {}", parts.join(" "), compact(e.value))
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
    let f = a.formula.load()?;
    // A colour formula is swept channel by channel (each a scalar formula); --json then gives
    // `{"channels": {"red": …, "green": …, "blue": …}}`.
    let mut denied = vec![];
    let mut objects = serde_json::Map::new();
    for c in common::named_channels(&f) {
        let (text, d) = report(a, &c)?;
        denied.extend(d.into_iter().filter(|k| !denied.contains(k)).collect::<Vec<_>>());
        match (f.is_rgb(), a.json.on) {
            (true, true) => {
                let channel = c.display_name().rsplit_once(" (").map_or(String::new(), |(_, ch)| ch.trim_end_matches(')').to_string());
                objects.insert(channel, serde_json::from_str(&text).map_err(|e| CliError::msg(e.to_string()))?);
            }
            _ => print!("{text}"),
        }
    }
    if f.is_rgb() && a.json.on {
        println!("{}", serde_json::json!({ "channels": objects }));
    }
    if !denied.is_empty() {
        eprintln!("error: denied kinds occurred: {}", denied.join(", "));
        return Err(CliError::Failed);
    }
    Ok(())
}

/// The command's output for a lowered formula, and the `--deny` kinds that occurred.
pub fn report(a: &SweepArgs, f: &Formula) -> Result<(String, Vec<String>), CliError> {
    let mut out = String::new();
    let set = a.set.list();
    let mut decls = f.params.clone();
    let u = f.unclamped();
    let k = crate::compile_formula(u, &a.backend.options(set.clone()))?;
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
    if a.json.on {
        let regions = rep
            .regions
            .iter()
            .map(|r| RegionJson {
                region: r.region,
                counts: r,
                first: serde_json::json!({
                    "nan": example_json(&r.first_nan, &names),
                    "inf": example_json(&r.first_inf, &names),
                    "negative": example_json(&r.first_negative, &names),
                    "over_bound": example_json(&r.first_over_bound, &names),
                }),
            })
            .collect();
        let obj = SweepJson { total: t, bound: rep.bound, exhaustive: rep.exhaustive, regions };
        outln!(out, "{}", common::to_json(&obj)?);
    } else {
        outln!(out, 
            "{}: unclamped formula {} over {} points ({}; inputs read: {})",
            f.display_name(),
            k.formula.to_program_text().replace('\n', "; "),
            t.evaluated,
            if rep.exhaustive { "exhaustive grid" } else { "subsampled grid" },
            if used.is_empty() { "none".to_string() } else { used.to_string() }
        );
        outln!(out, "  {:<10} {:>10} {:>8} {:>8} {:>9} {:>9}", "region", "evaluated", "NaN", "±inf", "negative", format!(">{:e}", rep.bound));
        for r in rep.regions.iter().chain(std::iter::once(t)) {
            outln!(out, "  {:<10} {:>10} {:>8} {:>8} {:>9} {:>9}", r.region, r.evaluated, r.nan, r.inf, r.negative, r.over_bound);
        }
        let bound = rep.bound;
        for r in &rep.regions {
            for (kind, e) in [("NaN", &r.first_nan), ("inf", &r.first_inf), ("negative", &r.first_negative), ("over bound", &r.first_over_bound)] {
                if let Some(e) = e {
                    outln!(out, "  first {kind} in {}: {}", r.region, example_text(e, used, &names));
                    // How far the region reaches along each input, the rest as in the example.
                    let bad = |y: f64| match kind {
                        "NaN" => y.is_nan(),
                        "inf" => y.is_infinite(),
                        "negative" => y < 0.0,
                        _ => y > bound,
                    };
                    // Along one input at a time is not a path through real geometry: no extents for directions.
                    for i in used.iter().filter(|_| !used.reads_directions()) {
                        if let Some((lo, hi)) = extent(&k, &e.inputs, &e.params, i.index(), bad) {
                            outln!(out, "    {kind} for {} in [{}, {}] (the rest as in the example)", i.name(), compact(lo), compact(hi));
                        }
                    }
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
