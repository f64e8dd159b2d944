//! `lobe eval FILE --set n=50 --at NH=0.95,NL=0.7 [--normalize] [--backend jit|interp] [--tier cranelift|llvm|auto]
//! [--math precise|fast] [--json]`
//! `lobe eval FILE --at L=0.3,0.1,0.9,V=0,0,1`: directions in the local frame (N = +z, X = +x, Y = +y); every
//! input is then computed from them as the renderer does.
//! `lobe eval FILE --points PATH|- [--json]`: every row of a CSV through the batched kernel ([`super::points`]).
//!
//! A colour formula is compiled channel by channel (three kernels sharing the parameters) and prints
//! `[r, g, b]` per point.

use super::args::{self, BackendArg, FormulaSource, Json, Params, PreferArg};
use super::common::{self, CliError};
use lobe::report::eval::{EvalReport, PointValue, PointsReport, PointsTiming};
use lobe::ir::{Input, InputSet, N_INPUTS};
use lobe::{Evaluator, Kernel};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values baked into the kernel, e.g. `n=200,a=16`")))]
pub struct EvalArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// Inputs: cosines, e.g. `NH=0.95,NL=0.7` (every cosine the formula reads), or the directions `L=x,y,z,V=x,y,z` (or
    /// `Lx=…` singly) in the local frame, normalised, from which every cosine is computed.
    #[arg(long, value_parser = parse_at, action = clap::ArgAction::Append)]
    pub at: Vec<Vec<(String, Vec<f64>)>>,
    /// Evaluate every row of a CSV file (`-`: standard input) whose header names inputs (cosines, or
    /// Lx,Ly,Lz,Vx,Vy,Vz) and, optionally, parameters; prints one value per line, `[r, g, b]` for a colour
    /// formula (or `{"values": […]}` with --json).
    #[arg(long, value_name = "PATH", conflicts_with = "at")]
    pub points: Option<String>,
    /// Multiply by the exact energy normalisation coefficient 1/(2π·Int) of a one-cosine lobe, computed at
    /// compile time (bakes every parameter); for other formulas a note says it is not their energy.
    #[arg(long)]
    pub normalize: bool,
    /// Print the ground truth instead of a kernel's value: the formula as written (--set values folded)
    /// evaluated in ~104-bit precision with an unbounded exponent (more where its error bound asks) and rounded to f64, what `lobe check`
    /// measures errors against (µs per point, all threads)
    #[arg(long, conflicts_with = "normalize")]
    pub truth: bool,
    /// Also the gradient: the partial derivative by every parameter and every input the formula reads, from one
    /// compiled value-and-gradient kernel (docs/derivatives.md); with --points, a CSV column `d_NAME` per partial
    #[arg(long, conflicts_with_all = ["normalize", "truth"])]
    pub grad: bool,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub prefer: PreferArg,
    #[command(flatten)]
    pub json: Json,
}

/// Parses `--at`: `name=value` items separated by commas, where `L=` and `V=` take three values
/// (`L=0.3,0.1,0.9`). Each name once.
pub fn parse_at(s: &str) -> Result<Vec<(String, Vec<f64>)>, String> {
    let mut out: Vec<(String, Vec<f64>)> = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (name, v) = match part.split_once('=') {
            Some((k, v)) => (Some(k.trim()), v.trim()),
            None => (None, part),
        };
        let v: f64 = v.parse().map_err(|_| format!("`{v}` is not a number in `{part}`"))?;
        if !v.is_finite() {
            return Err(format!("`{part}`: the value must be finite"));
        }
        match name {
            Some(k) => {
                if out.iter().any(|(j, _)| j == k) {
                    return Err(format!("`{k}` is given twice in `{s}`; give each name once"));
                }
                out.push((k.to_string(), vec![v]));
            }
            None => match out.last_mut() {
                Some((k, vals)) if (k == "L" || k == "V") && vals.len() < 3 => vals.push(v),
                _ => return Err(format!("`{part}` is not of the form name=value (e.g. NH=0.5, or L=x,y,z for a direction)")),
            },
        }
    }
    if let Some((k, _)) = out.iter().find(|(k, v)| (k == "L" || k == "V") && v.len() != 3) {
        return Err(format!("`{k}=` takes three components, e.g. {k}=0.3,0.1,0.9"));
    }
    Ok(out)
}

/// The kernel inputs from `--at` for kernels reading `used`, and a note when a direction was normalised.
fn at_inputs(at: &[(String, Vec<f64>)], used: InputSet) -> Result<([f64; N_INPUTS], Option<String>), CliError> {
    let mut x = [0.0; N_INPUTS];
    let mut dirs = [[0.0; 3]; 2];
    let (mut cosines, mut directions) = (false, false);
    let mut given_cosines = InputSet::default();
    // Which item (its index in `at`) gave each direction component: `L=…` and `Lx=…` both give Lx.
    let item = |k: usize| format!("{}={}", at[k].0, at[k].1.iter().map(|x| number(*x)).collect::<Vec<_>>().join(","));
    let mut given: [[Option<(usize, f64)>; 3]; 2] = Default::default();
    let mut give = |d: usize, c: usize, k: usize, v: f64| -> Result<(), CliError> {
        match given[d][c] {
            Some((first, w)) if w != v => Err(CliError::hint(
                format!("--at gives {} twice: {} and {}", Input::ALL[Input::Lx.index() + 3 * d + c].name(), item(first), item(k)),
                "give each direction component once, as L=x,y,z or as Lx=…",
            )),
            _ => {
                given[d][c] = Some((k, v));
                Ok(())
            }
        }
    };
    for (k, (name, v)) in at.iter().enumerate() {
        let slot = match name.as_str() {
            "L" | "V" => {
                let d = usize::from(name == "V");
                for (c, &vc) in v.iter().enumerate() {
                    give(d, c, k, vc)?;
                }
                dirs[d].copy_from_slice(v);
                directions = true;
                continue;
            }
            n => Input::from_name(n).ok_or_else(|| {
                let mut known: Vec<&str> = Input::ALL.map(Input::name).to_vec();
                known.extend(["L", "V"]);
                CliError::hint(format!("--at: `{name}` is not an input"), common::did_you_mean(name, &known, "inputs are "))
            })?,
        };
        if slot.is_direction() {
            let i = slot.index() - Input::Lx.index();
            give(i / 3, i % 3, k, v[0])?;
            dirs[i / 3][i % 3] = v[0];
            directions = true;
        } else {
            x[slot.index()] = v[0];
            given_cosines.insert(slot);
            cosines = true;
        }
    }
    if directions && cosines {
        return Err(CliError::hint("--at: both directions and cosines", "with L and V every cosine is computed from them; drop the cosines"));
    }
    if !directions {
        if used.reads_directions() {
            return Err(CliError::hint(
                format!("the formula reads directions ({}); --at gives none", used.iter().filter(|i| i.is_direction()).map(Input::name).collect::<Vec<_>>().join(", ")),
                "give --at L=x,y,z,V=x,y,z (local frame: N = +z, X = +x, Y = +y)",
            ));
        }
        // A cosine the formula reads and --at does not give would be taken as 0: a wrong value with no word.
        let missing: Vec<&str> = used.iter().filter(|i| !given_cosines.contains(*i)).map(Input::name).collect();
        if !missing.is_empty() {
            let reads: Vec<&str> = used.iter().map(Input::name).collect();
            return Err(CliError::hint(
                format!("--at gives no value for {} (the formula reads {})", missing.join(", "), reads.join(", ")),
                format!("give {}, or the directions L=x,y,z,V=x,y,z from which every cosine is computed", missing.iter().map(|m| format!("{m}=…")).collect::<Vec<_>>().join(",")),
            ));
        }
        return Ok((x, None));
    }
    let mut notes = vec![];
    for (k, d) in dirs.iter_mut().enumerate() {
        let name = ["L", "V"][k];
        let (u, scaled) = lobe::numerics::points::unit(*d).ok_or_else(|| {
            CliError::hint(format!("--at: {name} = ({}, {}, {}) has no direction", d[0], d[1], d[2]), format!("give {name}=x,y,z, not all 0"))
        })?;
        if scaled {
            notes.push(format!("{name} normalised to ({}, {}, {})", u[0], u[1], u[2]));
        }
        *d = u;
    }
    let note = (!notes.is_empty()).then(|| notes.join("; "));
    Ok((lobe::numerics::inputs_from_dirs(dirs[0], dirs[1]), note))
}

/// The inputs every kernel reads.
fn used(ks: &[Kernel]) -> InputSet {
    ks.iter().map(Kernel::used_inputs).collect()
}

/// One point's values as text: the number, or `[r, g, b]`.
fn show(v: &[f64]) -> String {
    match v {
        [one] => number(*one),
        _ => format!("[{}]", v.iter().map(|x| number(*x)).collect::<Vec<_>>().join(", ")),
    }
}

use common::short_number as number;

pub fn run(a: &EvalArgs) -> Result<(), CliError> {
    let set = a.set.list()?;
    let at = args::merge_repeated("--at", &a.at, |v| v.iter().map(|x| number(*x)).collect::<Vec<_>>().join(","))?;
    let f = a.formula.load()?;
    let backend = a.backend.backend()?;
    let pass = |opts| super::common::with_pass(opts, a.prefer.pass(lobe::numerics::robust::PassOptions::default().points));
    if a.grad {
        let opts = pass(lobe::Options { backend, bake: set.clone(), math: a.backend.math.mode, ..Default::default() });
        let started = std::time::Instant::now();
        let g = lobe::numerics::grad::Gradient::compile(&f, &opts)?;
        return run_grad(a, &g, &set, &at, started.elapsed().as_secs_f64() * 1e6);
    }
    let ks: Vec<Kernel> = if a.normalize {
        if f.is_rgb() {
            return Err(CliError::hint(
                "--normalize: the formula has a colour result; one coefficient per channel would change its colour",
                "evaluate without --normalize, or check the albedo per channel with `lobe energy --mode full`",
            ));
        }
        let used = f.used_inputs();
        if !(used.is_empty() || lobe::numerics::one_lobe_cosine(used).is_some()) {
            eprintln!(
                "note: --normalize multiplies by the one-lobe coefficient 1/(2π∫₀¹ f(c)·c dc) (lobe variable = cos θ, light at the normal); this formula reads {used}, so that is not its energy: `lobe energy --mode full` gives its albedo"
            );
        }
        // The coefficient depends on every parameter: bake them all (--set values, declared defaults for the rest).
        let mut bake = set.clone();
        bake.extend(f.params.iter().filter(|p| !set.iter().any(|(k, _)| *k == p.name)).map(|p| (p.name.clone(), p.default)));
        let s = lobe::simplified(&f, &pass(lobe::Options { bake, ..Default::default() }))?;
        vec![lobe::build_kernel(std::sync::Arc::new(lobe::numerics::normalize::bake_coefficient(s)?), backend, a.backend.math.mode)?]
    } else {
        let pass = a.prefer.pass(lobe::numerics::robust::PassOptions::default().points);
        lobe::numerics::pass_cache::command_channels(&f, &set, backend, a.backend.math.mode, pass, common::cache_on())?
    };
    let params = common::param_values(&ks[0].formula, &set);
    let truth = if a.truth { Some(truth_channels(&f, &set)?) } else { None };
    if let Some(path) = &a.points {
        return run_points(a, &ks, truth.as_deref(), path, &params, &set);
    }
    let (x, note) = at_inputs(&at, used(&ks))?;
    let v: Vec<f64> = match &truth {
        Some(t) => t.iter().map(|g| lobe::numerics::truth::eval_settled(g, &x, &params)).collect(),
        None => ks.iter().map(|k| k.eval(&x, &params)).collect(),
    };
    if a.json.on {
        let r = EvalReport::new(&ks, v, note);
        println!("{}", common::to_json(&if truth.is_some() { r.truth() } else { r })?);
    } else {
        emit(note, &format!("{}\n", show(&v)));
    }
    Ok(())
}

/// `--grad`: the value and every partial derivative at `--at`'s point or at every row of `--points`.
fn run_grad(a: &EvalArgs, g: &lobe::numerics::grad::Gradient, set: &[(String, f64)], at: &[(String, Vec<f64>)], compile_us: f64) -> Result<(), CliError> {
    use lobe::report::eval::{GradPointsReport, GradReport, Named};
    let params = common::param_values(&g.formula, set);
    let names = g.names();
    let (backend, math) = (g.backend.name(), g.mode.name());
    if let Some(path) = &a.points {
        let text = super::points::read(path)?;
        let name = if path == "-" { "<stdin>" } else { path };
        let baked: Vec<String> = set.iter().map(|(n, _)| n.clone()).collect();
        let pts = lobe::numerics::points::parse(name, &text, &g.formula, g.used, &baked)?;
        let r = lobe::numerics::points::evaluate_grad(g, &pts, &params);
        let note = (pts.normalised > 0).then(|| format!("{} of {} rows had a non-unit L or V; they were normalised", pts.normalised, pts.len));
        let at = |ch: &[Vec<f64>], i: usize| -> Vec<f64> { ch.iter().map(|c| c[i]).collect() };
        if a.json.on {
            let values = (0..pts.len).map(|i| PointValue(at(&r.value, i))).collect();
            let grad = Named(names.iter().zip(&r.grad).map(|(n, d)| (n.clone(), (0..pts.len).map(|i| PointValue(at(d, i))).collect())).collect());
            let rep = GradPointsReport { values, grad, points: pts.len, backend, math, compile_us, note };
            println!("{}", common::to_json(&rep)?);
            return Ok(());
        }
        let suffixes: &[&str] = if g.channels == 3 { &[".r", ".g", ".b"] } else { &[""] };
        let mut header: Vec<String> = suffixes.iter().map(|s| format!("value{s}")).collect();
        for n in &names {
            header.extend(suffixes.iter().map(|s| format!("d_{n}{s}")));
        }
        let mut text = header.join(",") + "\n";
        for i in 0..pts.len {
            let mut row: Vec<String> = r.value.iter().map(|c| number(c[i])).collect();
            for d in &r.grad {
                row.extend(d.iter().map(|c| number(c[i])));
            }
            text.push_str(&row.join(","));
            text.push('\n');
        }
        emit(note, &text);
        return Ok(());
    }
    let (x, note) = at_inputs(at, g.used)?;
    let (v, d) = g.eval(&x, &params);
    if a.json.on {
        let grad = Named(names.iter().zip(&d).map(|(n, d)| (n.clone(), PointValue(d.clone()))).collect());
        let rep = GradReport { value: PointValue(v), grad, backend, math, compile_us, note };
        println!("{}", common::to_json(&rep)?);
        return Ok(());
    }
    let width = names.iter().map(|n| n.chars().count()).max().unwrap_or(0) + 2;
    let mut text = format!("{}\n", show(&v));
    for (n, d) in names.iter().zip(&d) {
        text.push_str(&format!("{:<width$} {}\n", format!("d_{n}"), show(d)));
    }
    emit(note, &text);
    Ok(())
}

/// The note (if any) on stderr, then `text` on stdout.
fn emit(note: Option<String>, text: &str) {
    if let Some(n) = note {
        eprintln!("note: {n}");
    }
    print!("{text}");
}

/// The truth's formulas (`--truth`): the formula as written with `set` folded, one per colour channel.
fn truth_channels(f: &lobe::ir::Formula, set: &[(String, f64)]) -> Result<Vec<lobe::ir::Formula>, CliError> {
    Ok(lobe::simplify::bake_only(f, &lobe::resolve_bake(f, set)?).channels())
}

/// `--points`: every row through the kernels `ks`, timed in the steady state with `--json`; or, with `truth`,
/// through the truth's formulas, in one pass (timed as it is).
fn run_points(a: &EvalArgs, ks: &[Kernel], truth: Option<&[lobe::ir::Formula]>, path: &str, params: &[f64], set: &[(String, f64)]) -> Result<(), CliError> {
    let text = super::points::read(path)?;
    let name = if path == "-" { "<stdin>" } else { path };
    let formula = &ks[0].formula;
    let mut baked: Vec<String> = set.iter().map(|(n, _)| n.clone()).collect();
    if a.normalize {
        baked.extend(formula.params.iter().map(|p| p.name.clone()));
    }
    // The truth may read an input the simplified kernels no longer do.
    let truth_inputs = truth.unwrap_or_default().iter().map(lobe::ir::Formula::used_inputs);
    let read = std::iter::once(used(ks)).chain(truth_inputs).collect();
    let pts = lobe::numerics::points::parse(name, &text, formula, read, &baked)?;
    let started = std::time::Instant::now();
    let (channels, timing) = match truth {
        Some(t) => {
            let c: Vec<Vec<f64>> = t.iter().map(|g| lobe::numerics::points::truth(g, &pts, params)).collect();
            let ns = started.elapsed().as_nanos() as f64 / pts.len.max(1) as f64;
            (c, PointsTiming::OnePass(ns))
        }
        None => {
            let mut c: Vec<Vec<f64>> = ks.iter().map(|k| lobe::numerics::points::evaluate(k, &pts, params)).collect();
            // The reported cost is the steady state (kernels warm, output buffers touched), not the first call.
            let steady = a.json.on.then(|| {
                lobe::report::measure::steady_state(pts.len, || {
                    for (k, out) in ks.iter().zip(&mut c) {
                        lobe::numerics::points::evaluate_into(k, &pts, params, std::hint::black_box(out));
                    }
                })
            });
            (c, steady.map_or(PointsTiming::OnePass(f64::NAN), PointsTiming::Steady))
        }
    };
    let point = |i: usize| -> Vec<f64> { channels.iter().map(|c| c[i]).collect() };
    let note = (pts.normalised > 0).then(|| format!("{} of {} rows had a non-unit L or V; they were normalised", pts.normalised, pts.len));
    if a.json.on {
        let values = (0..pts.len).map(|i| PointValue(point(i))).collect();
        let r = PointsReport::new(ks, values, timing, note);
        println!("{}", common::to_json(&if truth.is_some() { r.truth() } else { r })?);
        return Ok(());
    }
    let mut text = String::with_capacity(pts.len * 20 * ks.len());
    for i in 0..pts.len {
        text.push_str(&show(&point(i)));
        text.push('\n');
    }
    emit(note, &text);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_takes_directions_and_colour_prints_triples() {
        let a = parse_at("L=0.3,0.1,0.9,V=0,0,1,n=2").unwrap();
        assert_eq!(a, vec![("L".into(), vec![0.3, 0.1, 0.9]), ("V".into(), vec![0.0, 0.0, 1.0]), ("n".into(), vec![2.0])]);
        assert!(parse_at("L=1,2").is_err() && parse_at("NH=1,2").is_err() && parse_at("NH=1,NH=2").is_err());
        assert_eq!(show(&[0.5]), "0.5");
        assert_eq!(show(&[0.5, 1.0, f64::NAN]), "[0.5, 1, NaN]");
    }
}
