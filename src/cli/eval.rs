//! `lobe eval FILE --set n=50 --at NH=0.95,NL=0.7 [--normalize] [--backend jit|interp] [--json]`

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
        crate::build_kernel(std::sync::Arc::new(crate::numerics::normalize::bake_coefficient(s)?), a.backend.kind)?
    } else {
        crate::compile_formula(f, &pass(crate::Options { backend: a.backend.kind, bake: set.clone(), ..Default::default() }))?
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
