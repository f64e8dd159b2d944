//! `lobe eval FILE --set n=50 --at NH=0.95,NL=0.7 [--normalize] [--backend jit|interp] [--math precise|fast] [--json]`
//! `lobe eval FILE --points PATH|- [--json]`: every row of a CSV through the batched kernel ([`super::points`]).

use super::args::{self, BackendArg, FormulaSource, Json, Params, PreferArg};
use super::common::{self, CliError};
use crate::base::json;
use crate::ir::{Input, N_INPUTS};
use crate::Evaluator;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values baked into the kernel, e.g. `n=200,a=16`")))]
pub struct EvalArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// Input cosines, e.g. `NH=0.95,NL=0.7`; unset inputs are 0.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub at: Vec<Vec<(String, f64)>>,
    /// Evaluate every row of a CSV file (`-`: standard input) whose header names inputs and, optionally,
    /// parameters; prints one value per line (or `{"values": […]}` with --json).
    #[arg(long, value_name = "PATH", conflicts_with = "at")]
    pub points: Option<String>,
    /// Multiply by the exact energy normalisation coefficient 1/(2π·Int), computed at compile time (bakes
    /// every parameter).
    #[arg(long)]
    pub normalize: bool,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub prefer: PreferArg,
    #[command(flatten)]
    pub json: Json,
}

pub fn run(a: &EvalArgs) -> Result<(), CliError> {
    let set = a.set.list();
    let f = a.formula.load()?;
    let pass = |opts| crate::numerics::robust::with_pass(opts, a.prefer.pass(crate::numerics::robust::PassOptions::default().points));
    let k = if a.normalize {
        // The coefficient depends on every parameter: bake them all (--set values, declared defaults for the rest).
        let mut bake = set.clone();
        bake.extend(f.params.iter().filter(|p| !set.iter().any(|(k, _)| *k == p.name)).map(|p| (p.name.clone(), p.default)));
        let s = crate::simplified(&f, &pass(crate::Options { bake, ..Default::default() }))?;
        crate::build_kernel(std::sync::Arc::new(crate::numerics::normalize::bake_coefficient(s)?), a.backend.kind, a.backend.math.mode)?
    } else {
        crate::compile_formula(f, &pass(a.backend.options(set.clone())))?
    };
    let mut x = [0.0; N_INPUTS];
    for (name, v) in a.at.concat() {
        let i = Input::from_name(&name).ok_or_else(|| {
            let hint = common::did_you_mean(&name, &Input::ALL.map(Input::name), "inputs are ");
            CliError::hint(format!("--at: `{name}` is not an input"), hint)
        })?;
        x[i.index()] = v;
    }
    let params = common::param_values(&k.formula, &set);
    if let Some(path) = &a.points {
        return run_points(a, &k, path, &params, &set);
    }
    let v = k.eval(&x, &params);
    if a.json.on {
        let obj = serde_json::json!({
            "value": json::value(v),
            "backend": k.backend.name(),
            "compile_us": json::value(k.compile_time.as_secs_f64() * 1e6),
        });
        println!("{obj}");
    } else {
        println!("{v}");
    }
    Ok(())
}

fn run_points(a: &EvalArgs, k: &crate::Kernel, path: &str, params: &[f64], set: &[(String, f64)]) -> Result<(), CliError> {
    let text = super::points::read(path)?;
    let name = if path == "-" { "<stdin>" } else { path };
    let mut baked: Vec<String> = set.iter().map(|(n, _)| n.clone()).collect();
    if a.normalize {
        baked.extend(k.formula.params.iter().map(|p| p.name.clone()));
    }
    let pts = super::points::parse(name, &text, &k.formula, &baked)?;
    k.warm_up();
    let t = std::time::Instant::now();
    let values = super::points::evaluate(k, &pts, params);
    let elapsed = t.elapsed();
    if a.json.on {
        let obj = serde_json::json!({
            "values": values.iter().map(|v| json::value(*v)).collect::<Vec<_>>(),
            "points": values.len(),
            "backend": k.backend.name(),
            "math": k.math.name(),
            "compile_us": json::value(k.compile_time.as_secs_f64() * 1e6),
            "eval_ns_per_point": json::value(elapsed.as_nanos() as f64 / values.len().max(1) as f64),
        });
        println!("{obj}");
    } else {
        let mut out = String::with_capacity(values.len() * 20);
        for v in &values {
            out.push_str(&format!("{v}\n"));
        }
        print!("{out}");
    }
    Ok(())
}
