//! `lobe check FILE [--set n=50] [--json]`: what lobe made of a formula — the simplified expression, the
//! rewrites that fired, the inputs it reads (and so the ones a renderer skips), parameters baked or live, and
//! the compile time on each backend.

use super::args::{self, FormulaSource, Json, Params};
use super::common::CliError;
use crate::base::json;
use crate::ir::Input;
use crate::{Backend, Options};
use serde_json::json;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameters to bake as constants, e.g. `n=50`")))]
pub struct CheckArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub json: Json,
    #[command(flatten)]
    pub math: super::args::MathArg,
}

/// The builtins the simplified formula calls, each with its stated bound in `mode` (sorted by table order).
fn builtin_bounds(f: &crate::Formula, mode: crate::Mode) -> Vec<(&'static str, String)> {
    let mut used = vec![];
    f.ir.walk(f.root, |n| {
        if let crate::ir::Node::Call(b, _) = n {
            used.push(*b);
        }
    });
    used.sort();
    used.dedup();
    used.into_iter().map(|b| (b.name(), b.info().bound.describe(mode))).collect()
}

pub fn run(a: &CheckArgs) -> Result<(), CliError> {
    let set = a.set.list();
    let f = a.formula.load()?;
    let bake = crate::resolve_bake(&f, &set)?;
    let (simplified, report) = crate::simplify::simplify_report(&f, &bake);
    let (nodes_before, nodes_after) = (report.nodes_before, report.nodes_after);
    let used = simplified.used_inputs();
    let unused: Vec<&str> = Input::ALL.iter().filter(|i| !used.contains(**i)).map(|i| i.name()).collect();
    let live = simplified.ir.used_params(simplified.root);
    let opts = |backend| Options { backend, bake: set.clone(), math: a.math.mode, ..Options::default() };
    let bounds = builtin_bounds(&simplified, a.math.mode);
    let jit = crate::compile_formula(f.clone(), &opts(Backend::Jit))?;
    let interp = crate::compile_formula(f.clone(), &opts(Backend::Interp))?;
    let params: Vec<serde_json::Value> = f
        .params
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let baked = bake.iter().find(|(j, _)| *j == i).map(|(_, v)| *v);
            json!({
                "name": p.name, "default": json::value(p.default), "lo": json::value(p.lo), "hi": json::value(p.hi),
                "baked": baked.map(json::value), "live": live.contains(&(i as u16)),
            })
        })
        .collect();
    if a.json.on {
        let obj = json!({
            "file": f.file,
            "name": f.display_name(),
            "citation": f.meta.citation,
            "params": params,
            // The let form: printing shared `let`s as a tree grows exponentially with their depth.
            "formula": f.to_program_text(),
            "simplified": simplified.to_program_text(),
            "nodes_before": nodes_before,
            "nodes_after": nodes_after,
            "rewrites": report.fired.iter().map(|(k, v)| json!({"rule": k, "count": v})).collect::<Vec<_>>(),
            "rounding_changes": report.rounding.iter().map(|r| {
                let (line, col) = crate::base::span::line_col(&f.source, r.span.start as usize);
                json!({"rule": r.rule, "line": line, "col": col, "detail": r.detail})
            }).collect::<Vec<_>>(),
            "passes": report.passes,
            "used_inputs": used.iter().map(|i| i.name()).collect::<Vec<_>>(),
            "unused_inputs": unused,
            "math": a.math.mode.name(),
            "builtins": bounds.iter().map(|(n, b)| json!({"name": n, "bound": b})).collect::<Vec<_>>(),
            "compile_us": {
                "jit": json::value(jit.compile_time.as_secs_f64() * 1e6),
                "interp": json::value(interp.compile_time.as_secs_f64() * 1e6),
            },
        });
        println!("{obj}");
        return Ok(());
    }
    println!("{} — {}", f.file, f.display_name());
    if let Some(c) = &f.meta.citation {
        println!("  cite        {c}");
    }
    for (i, p) in f.params.iter().enumerate() {
        let state = match bake.iter().find(|(j, _)| *j == i) {
            Some((_, v)) => format!("baked = {v}"),
            None if live.contains(&(i as u16)) => "live".to_string(),
            None => "unused".to_string(),
        };
        println!("  param       {} = {} in {}..{}  ({state})", p.name, p.default, p.lo, p.hi);
    }
    println!("  formula     {}", f.to_program_text().replace('\n', "\n              "));
    println!("  simplified  {}", simplified.to_program_text().replace('\n', "\n              "));
    println!("  nodes       {nodes_before} → {nodes_after}");
    if !report.fired.is_empty() {
        let r: Vec<String> = report.fired.iter().map(|(k, v)| format!("{k} ×{v}")).collect();
        println!("  rewrites    {} ({} passes)", r.join(", "), report.passes);
    }
    for r in &report.rounding {
        let (line, col) = crate::base::span::line_col(&f.source, r.span.start as usize);
        println!("  rounding    {}:{line}:{col} {}: {}", f.file, r.rule, r.detail);
    }
    println!(
        "  reads       {}{}",
        if used.is_empty() { "no input (a constant)".to_string() } else { used.to_string() },
        if unused.is_empty() { String::new() } else { format!("   (a renderer skips {})", unused.join(", ")) }
    );
    if !bounds.is_empty() {
        let b: Vec<String> = bounds.iter().map(|(n, b)| format!("{n} {b}")).collect();
        println!("  builtins    {} ({} math)", b.join(", "), a.math.mode);
    }
    println!(
        "  compile     jit {:.0} µs, interpreter {:.0} µs",
        jit.compile_time.as_secs_f64() * 1e6,
        interp.compile_time.as_secs_f64() * 1e6
    );
    Ok(())
}
