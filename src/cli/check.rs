//! `lobe check FILE [--set n=50] [--json]`: what lobe made of a formula — the simplified expression, the
//! rewrites that fired, the inputs it reads (and so the ones a renderer skips), parameters baked or live, and
//! the compile time on each backend; and the accuracy pass's report (`numerics::robust`): bits of error
//! against the higher-precision truth over the formula's domain before and after the pass, with the worst
//! input, which rewrite bought what, and where the formula is ill-conditioned by nature. `--sweep` runs the
//! stability sweep instead, with `lobe sweep`'s flags ([`super::sweep`]).

use super::args::{self, FormulaSource, Json, Params, PreferArg};
use super::common::{self, CliError, Spinner};
use lobe::ir::Formula;
use lobe::numerics::robust::{self, ErrorStats, Worst};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameters to bake as constants, e.g. `n=50`")))]
#[command(mut_arg("bound", |a| a.requires("sweep")), mut_arg("max_evals", |a| a.requires("sweep")))]
#[command(mut_arg("deny", |a| a.requires("sweep")), mut_arg("as_written", |a| a.requires("sweep")))]
#[command(mut_arg("backend", |a| a.requires("sweep")), mut_arg("tier", |a| a.requires("sweep")))]
pub struct CheckArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub prefer: PreferArg,
    /// Domain points the accuracy report measures (inputs in [0, 1] with edge classes, parameters over
    /// their ranges).
    #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=100_000_000), conflicts_with = "sweep")]
    pub points: u64,
    /// Seconds the accuracy pass may search before it keeps the best form found so far (the report says so).
    #[arg(long, value_name = "SECONDS", default_value_t = 10.0, value_parser = args::parse_seconds, allow_negative_numbers = true, conflicts_with = "sweep")]
    pub budget: f64,
    #[command(flatten)]
    pub json: Json,
    #[command(flatten)]
    pub math: super::args::MathArg,
    /// Run the stability sweep instead (`lobe sweep`, with its flags below): NaN, ±inf, negative and huge
    /// values over the whole domain.
    #[arg(long)]
    pub sweep: bool,
    #[command(flatten, next_help_heading = "With --sweep")]
    pub sweeping: super::sweep::SweepFlags,
}

/// A point as `NH=…, NL=… (n=…)`: the inputs the formula reads and its live parameters.
fn point_text(f: &Formula, w: &Worst) -> String {
    let used = f.used_inputs();
    let live = f.ir.used_params(f.root);
    let mut parts: Vec<String> = used.iter().map(|i| format!("{}={:e}", i.name(), w.point.x[i.index()])).collect();
    parts.extend(live.iter().map(|&k| format!("{}={}", f.params[k as usize].name, w.point.p[k as usize])));
    format!("{} → {:e} (true {:e})", parts.join(", "), w.got, w.truth)
}

fn stats_line(f: &Formula, s: &ErrorStats) -> String {
    let mut out = format!("avg {:.2} bits, max {:.2} bits", s.avg_bits, s.max_bits);
    if let Some(w) = &s.worst {
        out.push_str(&format!(" at {}", point_text(f, w)));
    }
    if s.ill_conditioned > 0 {
        out.push_str(&format!("; max {:.2} bits where well conditioned", s.max_bits_well));
    }
    for (n, first, what) in [
        (s.nonfinite, &s.first_nonfinite, "NaN/inf where the true value is finite"),
        (s.wrong_sign, &s.first_wrong_sign, "the wrong sign"),
        (s.pole_misses, &s.first_pole_miss, "not the exact infinity at a pole"),
    ] {
        if n > 0 {
            out.push_str(&format!("; {what} at {n} points"));
            if let Some(w) = first {
                out.push_str(&format!(", e.g. {}", point_text(f, w)));
            }
        }
    }
    out
}

pub fn run(a: &CheckArgs) -> Result<(), CliError> {
    if a.sweep {
        let sweep = super::sweep::Sweep { formula: &a.formula, set: &a.set, flags: &a.sweeping, prefer: &a.prefer, math: a.math.mode, json: a.json.on };
        return super::sweep::run_sweep(&sweep);
    }
    let set = a.set.list()?;
    let whole = a.formula.load()?;
    // A colour formula: the red channel is checked and shown, and the output says so (`lobe check --sweep`
    // and `lobe bench` report every channel).
    // The search as the commands run it (their points, seed and options; a longer budget), so the form shown
    // is the one they compile; the report is measured on --points.
    let opts = robust::PassOptions { math: a.math.mode, budget: std::time::Duration::from_secs_f64(a.budget), ..a.prefer.pass(robust::PassOptions::default().points) };
    let store = lobe::numerics::pass_cache::platform_store(common::cache_on());
    let spinner = Spinner::new(!a.json.on && std::io::IsTerminal::is_terminal(&std::io::stderr()), "accuracy pass");
    let c = lobe::numerics::check::check(&whole, &set, &opts, a.points as usize, store.as_deref(), &|stage| {
        spinner.show(match stage {
            robust::Stage::Truth { points } => format!("the truth at {points} points"),
            robust::Stage::Candidate { name, tried } => format!("candidate {tried} ({name})"),
            robust::Stage::Report => "the report (conditioning at every point)".to_string(),
        })
    });
    spinner.finish();
    let c = c?;
    if a.json.on {
        println!("{}", common::to_json(&c.json())?);
        return Ok(());
    }
    let (f, report, pass) = (&c.formula, &c.report, &c.pass);
    println!("{} — {}", f.file, f.display_name());
    if c.channel.is_some() {
        println!("  colour      an RGB formula: the red channel is shown (check --sweep and bench report all three)");
    }
    if let Some(cite) = &f.meta.citation {
        println!("  cite        {cite}");
    }
    for (i, p) in f.params.iter().enumerate() {
        let state = match c.bake.iter().find(|(j, _)| *j == i) {
            Some((_, v)) => format!("baked = {v}"),
            None if c.live.contains(&(i as u16)) => "live".to_string(),
            None => "unused".to_string(),
        };
        println!("  param       {} = {} in {}..{}  ({state})", p.name, p.default, p.lo, p.hi);
    }
    println!("  formula     {}", f.to_program_text().replace('\n', "\n              "));
    println!("  simplified  {}", c.simplified.to_program_text().replace('\n', "\n              "));
    println!("  nodes       {} → {}", report.nodes_before, report.nodes_after);
    if !report.fired.is_empty() {
        let r: Vec<String> = report.fired.iter().map(|(k, v)| format!("{k} ×{v}")).collect();
        println!("  rewrites    {} ({} passes)", r.join(", "), report.passes);
    }
    for r in &report.rounding {
        let (line, col) = lobe::base::span::line_col(&f.source, r.span.start as usize);
        println!("  rounding    {}:{line}:{col} {}: {}", f.file, r.rule, r.detail);
    }
    println!(
        "  reads       {}{}",
        if c.used.is_empty() { "no input (a constant)".to_string() } else { c.used.to_string() },
        if c.unused.is_empty() { String::new() } else { format!("   (a renderer skips {})", c.unused.join(", ")) }
    );
    if !c.bounds.is_empty() {
        let b: Vec<String> = c.bounds.iter().map(|(n, b)| format!("{n} {b}")).collect();
        println!("  builtins    {} ({} math)", b.join(", "), a.math.mode);
    }
    print_accuracy(f, pass, a.points as usize, c.pass_ms, c.cond_well);
    if let Some(d) = &c.fast_vs_precise {
        let at = d.at.as_ref().map_or(String::new(), |(pt, fast, precise)| {
            let w = robust::Worst { point: pt.clone(), got: *fast, truth: *precise, bits: 0.0 };
            format!(" at {}", point_text(f, &w).replace("(true ", "(precise "))
        });
        println!(
            "  fast math   vs precise over {} points (parameters over their declared ranges): max {:.2e} relative where |precise| ≥ {:e}{at}; max {:.2e} of the largest value absolute",
            d.points,
            d.max_rel,
            lobe::numerics::check::FastVsPrecise::REL_FLOOR,
            d.max_abs_vs_peak
        );
        if d.nonfinite > 0 {
            println!("              NaN/∞ in one mode and finite in the other at {} points", d.nonfinite);
        }
    }
    println!("  compile     jit {:.0} µs, interpreter {:.0} µs", c.jit_us, c.interp_us);
    Ok(())
}

/// The accuracy section of the text report.
fn print_accuracy(f: &Formula, pass: &robust::Outcome, asked: usize, ms: f64, cond_well: Option<f64>) {
    let reduced = if pass.points < asked { format!(", fewer than the {asked} asked: the formula is costly") } else { String::new() };
    println!(
        "  accuracy    bits of error vs the truth (~104-bit, unbounded exponent) at {} domain points{reduced} ({ms:.0} ms)",
        pass.points
    );
    println!("    before    {}", stats_line(f, &pass.before));
    if !pass.trials.is_empty() {
        println!("    search    on the commands' {} points (the trials' numbers are there)", pass.searched.points);
    }
    for t in &pass.trials {
        println!(
            "    {:<9} {} — {}: {}; avg {:.2} → {:.2}, max {:.2} → {:.2} bits{}",
            if t.kept { "kept" } else { "dropped" },
            t.rule,
            t.rule.doc(),
            t.reason,
            pass.searched.avg_bits,
            t.stats.avg_bits,
            pass.searched.max_bits,
            t.stats.max_bits,
            if t.stats.nonfinite != pass.searched.nonfinite {
                format!(", NaN/inf where finite {} → {}", pass.searched.nonfinite, t.stats.nonfinite)
            } else {
                String::new()
            }
        );
    }
    if pass.truncated {
        println!("    stopped   the search reached its time budget; the best form found so far is kept (raise it with --budget)");
    }
    println!("    after     {}", stats_line(f, &pass.after));
    if pass.trials.iter().any(|t| t.kept) {
        println!("    compiled  {}", pass.formula.to_program_text().replace('\n', "\n              "));
        println!("    cost      {:.2}× the fastest form (static cost model)", pass.cost_after / pass.cost_before);
    }
    let a = &pass.after;
    if let (Some(w), Some(c)) = (&a.worst_well, cond_well) {
        println!(
            "    worst well-conditioned point {} bits at {}; there a 1-ulp change of an input moves the true value by {c:.1} ulps",
            format_args!("{:.2}", w.bits),
            point_text(f, w)
        );
    }
    if a.poles > 0 {
        println!("    at {} points the exact value is infinite (a pole); {} of them get that infinity", a.poles, a.poles - a.pole_misses);
    }
    if a.ill_conditioned > 0 {
        let pct = 100.0 * a.ill_conditioned as f64 / a.points.max(1) as f64;
        println!(
            "    ill-conditioned by nature at {} points ({pct:.1} %): there a 1-ulp change of an input moves the true value by more than {} ulps, so no f64 evaluation is accurate; the error there is the formula's, not lobe's",
            a.ill_conditioned,
            robust::ILL_CONDITIONED_ULPS
        );
    }
    if a.limits > 0 {
        println!(
            "    at {} points the exact value is 0/0 or ∞·0 because an input is exactly 0 or 1; there the limit along that input is the truth (counted above)",
            a.limits
        );
    }
    if a.undefined > 0 {
        println!(
            "    not finite in exact arithmetic (0/0, ∞·0, or a pole such as an input exactly 0), and no limit along an input, at {} points; not counted",
            a.undefined
        );
    }
}

