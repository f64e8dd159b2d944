//! `lobe sweep FILE [--set …] [--bound 1e6] [--deny nan,inf] [--as-written] [--json]` (also reachable as
//! `lobe check --sweep`).
//!
//! Evaluates the *unclamped* formula (root `max(raw, 0)` peeled) over the domain (see
//! [`lobe::numerics::sweep`]) twice: as written (the plain simplification) and as compiled (the accuracy
//! pass's choice, which `eval`, `energy`, `fit`, … run), so a bad region shows beside whether lobe's code still
//! has it. Exits with status 1 when a kind listed in `--deny` occurs in the compiled formula (in the formula as
//! written with `--as-written`), after printing the report.

use super::args::{self, EngineArg, FormulaSource, Json, MathArg, Params, PreferArg};
use super::common::{self, CliError};
use lobe::ir::Formula;
use lobe::numerics::sweep::{example_extents, kinds, ChannelsJson, Example, RegionStats, SweepJson, SweepOptions, SweepReport};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Fix parameters instead of sweeping their declared ranges, e.g. `a=16`")))]
pub struct SweepArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub sweep: SweepFlags,
    #[command(flatten)]
    pub prefer: PreferArg,
    #[command(flatten)]
    pub math: MathArg,
    #[command(flatten)]
    pub json: Json,
}

/// The sweep's own flags, which `lobe check --sweep` takes as well.
#[derive(clap::Args, Debug)]
pub struct SweepFlags {
    /// Values above this are counted as over the bound.
    #[arg(long, default_value_t = 1e6, allow_negative_numbers = true)]
    pub bound: f64,
    /// Evaluation budget (the full grid is subsampled above it; a budget below the sweep's minimum — every
    /// parameter combination with 64 input points — is refused).
    #[arg(long, default_value_t = 2_000_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_evals: u64,
    /// Fail (exit 1) if any of these occur in the compiled formula: nan, inf, negative, bound.
    #[arg(long, value_delimiter = ',')]
    pub deny: Vec<String>,
    /// Sweep only the formula as written (no accuracy pass); `--deny` then judges it.
    #[arg(long)]
    pub as_written: bool,
    #[command(flatten)]
    pub engine: EngineArg,
}

/// What one sweep run reads: the command's arguments, or `lobe check --sweep`'s.
pub struct Sweep<'a> {
    pub formula: &'a FormulaSource,
    pub set: &'a Params,
    pub flags: &'a SweepFlags,
    pub prefer: &'a PreferArg,
    pub math: lobe::Mode,
    pub json: bool,
}

impl<'a> From<&'a SweepArgs> for Sweep<'a> {
    fn from(a: &'a SweepArgs) -> Sweep<'a> {
        Sweep { formula: &a.formula, set: &a.set, flags: &a.sweep, prefer: &a.prefer, math: a.math.mode, json: a.json.on }
    }
}

/// The kinds `--deny` takes.
const KINDS: [&str; 4] = ["nan", "inf", "negative", "bound"];

/// A number for the text report: plain for ordinary magnitudes, scientific otherwise.
fn compact(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn example_text(e: &Example, used: lobe::ir::InputSet, names: &[String]) -> String {
    let mut parts: Vec<String> = used.iter().map(|i| format!("{}={}", i.name(), compact(e.inputs[i.index()]))).collect();
    parts.extend(names.iter().zip(&e.params).map(|(n, v)| format!("{n}={}", compact(*v))));
    format!("{} → {}", parts.join(" "), compact(e.value))
}

pub fn run(a: &SweepArgs) -> Result<(), CliError> {
    run_sweep(&a.into())
}

/// Runs the sweep `a` describes and prints its report.
pub fn run_sweep(a: &Sweep) -> Result<(), CliError> {
    let flags = a.flags;
    for d in &flags.deny {
        if !KINDS.contains(&d.as_str()) {
            return Err(CliError::hint(format!("--deny: unknown kind `{d}`"), "kinds are nan, inf, negative, bound"));
        }
    }
    if flags.bound.is_nan() || flags.bound <= 0.0 {
        return Err(CliError::hint(format!("--bound {} must be a positive number", flags.bound), "e.g. --bound 1e6 (values above it are counted)"));
    }
    let f = a.formula.load()?;
    // A colour formula is swept channel by channel (each a scalar formula); --json then gives
    // `{"channels": {"red": …, "green": …, "blue": …}}`.
    let mut denied = vec![];
    let mut channels = ChannelsJson::default();
    for c in f.named_channels() {
        let (out, d) = report(a, &c)?;
        denied.extend(d.into_iter().filter(|k| !denied.contains(k)).collect::<Vec<_>>());
        match out {
            Out::Json(j) if f.is_rgb() => {
                let channel = c.display_name().rsplit_once(" (").map_or(String::new(), |(_, ch)| ch.trim_end_matches(')').to_string());
                channels.channels.insert(channel, *j);
            }
            Out::Json(j) => println!("{}", common::to_json(&j)?),
            Out::Text(t) => print!("{t}"),
        }
    }
    if f.is_rgb() && a.json {
        println!("{}", common::to_json(&channels)?);
    }
    if !denied.is_empty() {
        eprintln!("error: denied kinds occurred: {}", denied.join(", "));
        return Err(CliError::Failed);
    }
    Ok(())
}

/// The first examples of each region and kind with their extents, as text lines.
fn examples_text(out: &mut String, k: &lobe::Kernel, rep: &SweepReport, used: lobe::ir::InputSet, names: &[String], label: &str) {
    for r in &rep.regions {
        for (kind, _, e, bad) in kinds(r, rep.bound) {
            if let Some(e) = e {
                outln!(out, "  {label}first {kind} in {}: {}", r.region, example_text(e, used, names));
                for (along, lo, hi) in example_extents(k, rep, used, e, &*bad) {
                    outln!(out, "    {kind} for {along} in [{}, {}] (the rest as in the example)", compact(lo), compact(hi));
                }
            }
        }
    }
}

/// A table cell: the count as written, and `→ compiled` when the compiled formula differs.
fn cell(a: u64, b: Option<u64>) -> String {
    match b {
        Some(b) if b != a => format!("{a} → {b}"),
        _ => a.to_string(),
    }
}

/// One formula's (or channel's) output: the `--json` report, or the text.
pub enum Out {
    Json(Box<SweepJson>),
    Text(String),
}

/// The command's output for a lowered formula, and the `--deny` kinds that occurred.
pub fn report(a: &Sweep, f: &Formula) -> Result<(Out, Vec<String>), CliError> {
    let (mut out, flags) = (String::new(), a.flags);
    let set = a.set.list()?;
    let decls = lobe::numerics::sweep::swept_decls(f, &set);
    let used = f.used_inputs();
    // Every parameter combination gets its share of points: a smaller budget cannot be kept.
    let (combos, per) = lobe::numerics::sweep::min_evals(used, &decls);
    let least = combos.saturating_mul(per);
    if flags.max_evals < least {
        return Err(CliError::hint(
            format!(
                "--max-evals {} is below this sweep's minimum of {least} evaluations ({combos} parameter combinations × {per} input points each)",
                flags.max_evals
            ),
            format!("give --max-evals {least} or more, or fix parameters with --set so fewer combinations are swept"),
        ));
    }
    let plain = flags.engine.bulk_options(set.clone(), a.math)?;
    let pass = (!flags.as_written).then(|| super::common::with_pass(plain.clone(), a.prefer.pass(lobe::numerics::robust::PassOptions::default().points)));
    let run = lobe::numerics::sweep::sweep_formula(f, &set, &plain, pass.as_ref(), &SweepOptions { bound: flags.bound, max_evals: flags.max_evals })?;
    let (k, rep, compiled, crep_changed, names) = (&run.k, &run.rep, &run.compiled, &run.crep_changed, &run.names);
    let text = lobe::numerics::sweep::Run::text;
    let changed = run.changed();
    let crep = run.crep();
    let t = &rep.total;
    let judged = crep.map_or(t, |cr| &cr.total);
    let denied: Vec<String> = flags.deny.iter().filter(|d| judged.count(d) > 0).cloned().collect();
    if a.json {
        return Ok((Out::Json(Box::new(run.json())), denied));
    }
    {
        outln!(
            out,
            "{}: unclamped formula over {} points ({} of {}; inputs read: {})",
            f.display_name(),
            t.evaluated,
            if rep.exhaustive { "exhaustive grid" } else { "subsampled grid" },
            rep.domain.describe(),
            if used.is_empty() { "none".to_string() } else { used.to_string() }
        );
        outln!(out, "  as written  {}", text(k));
        match (&compiled, changed) {
            (_, Some(c)) => {
                outln!(out, "  compiled    {}", text(c));
                outln!(out, "  counts read \"as written → compiled\" where they differ");
            }
            (Some(_), None) => outln!(out, "  compiled    the same (the accuracy pass kept no rewrite)"),
            (None, None) => {}
        }
        outln!(out, "  {:<10} {:>10} {:>12} {:>12} {:>12} {:>12}", "region", "evaluated", "NaN", "±inf", "negative", format!(">{:e}", rep.bound));
        let rows: Vec<(&RegionStats, Option<&RegionStats>)> = match crep {
            Some(cr) => rep.regions.iter().zip(cr.regions.iter().map(Some)).chain(std::iter::once((t, Some(&cr.total)))).collect(),
            None => rep.regions.iter().chain(std::iter::once(t)).map(|r| (r, None)).collect(),
        };
        for (r, c) in rows {
            let cells: Vec<String> = ["nan", "inf", "negative", "bound"].iter().map(|kind| cell(r.count(kind), c.map(|c| c.count(kind)))).collect();
            outln!(out, "  {:<10} {:>10} {:>12} {:>12} {:>12} {:>12}", r.region, r.evaluated, cells[0], cells[1], cells[2], cells[3]);
        }
        examples_text(&mut out, k, rep, used, names, "");
        if let (Some(c), Some(cr)) = (changed, crep_changed) {
            examples_text(&mut out, c, cr, used, names, "compiled: ");
        }
    }
    Ok((Out::Text(out), denied))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::energy::tests::parse;
    use crate::cli::energy::tests::power_formula;
    use lobe::ir::Input;


    #[test]
    fn clean_formula_passes_deny_and_reports_json() {
        let f = power_formula(Input::NH, &[]);
        let a = parse::<SweepArgs>(&["sweep", "--json", "--deny", "nan,inf", "--backend", "interp"]);
        let (Out::Json(j), denied) = report(&Sweep::from(&a), &f).unwrap() else { panic!("--json gives the report") };
        assert!(denied.is_empty());
        let v = serde_json::to_value(&j).unwrap();
        assert_eq!((v["nan"].as_u64(), v["inf"].as_u64(), v["negative"].as_u64()), (Some(0), Some(0), Some(0)));
        // pow(c, n) with n ≥ 1 is ≤ 1: a bound of 0.5 is exceeded, and `--deny bound` says so.
        let a = parse::<SweepArgs>(&["sweep", "--bound", "0.5", "--deny", "bound", "--backend", "interp"]);
        let (Out::Text(text), denied) = report(&Sweep::from(&a), &f).unwrap() else { panic!("text without --json") };
        assert_eq!(denied, vec!["bound".to_string()]);
        assert!(text.contains("first over bound"), "{text}");
    }
}
