//! `lobe eval FILE --set n=50 --at NH=0.95,NL=0.7 [--backend jit|interp] [--json]`

use super::common::{self, CliError};
use crate::ir::{Input, N_INPUTS};
use crate::{Backend, Evaluator};

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Formula file (.brdf), or `-` for standard input.
    pub file: Option<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "file")]
    pub expr: Option<String>,
    /// Parameter values baked into the kernel, e.g. `n=200,a=16`.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub set: Vec<Vec<(String, f64)>>,
    /// Input cosines, e.g. `NH=0.95,NL=0.7`; unset inputs are 0.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub at: Vec<Vec<(String, f64)>>,
    /// Multiply by the exact energy normalisation coefficient 1/(2π·Int), computed at compile time (bakes
    /// every parameter).
    #[arg(long)]
    pub normalize: bool,
    /// Evaluation backend.
    #[arg(long, default_value = "jit")]
    pub backend: Backend,
    /// Print one JSON object with key `value`.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: &EvalArgs) -> Result<(), CliError> {
    let set: Vec<(String, f64)> = a.set.concat();
    let f = common::load_formula(a.file.as_deref(), a.expr.as_deref())?;
    let k = if a.normalize {
        // The coefficient depends on every parameter: bake them all (--set values, declared defaults for the rest).
        let mut bake = set.clone();
        bake.extend(f.params.iter().filter(|p| !set.iter().any(|(k, _)| *k == p.name)).map(|p| (p.name.clone(), p.default)));
        let s = crate::simplified(&f, &crate::Options { bake, ..Default::default() })?;
        crate::build_kernel(std::sync::Arc::new(crate::numerics::normalize::bake_coefficient(s)?), a.backend)?
    } else {
        crate::compile_formula(f, &crate::Options { backend: a.backend, bake: set.clone(), ..Default::default() })?
    };
    let mut x = [0.0; N_INPUTS];
    for (name, v) in a.at.concat() {
        let i = Input::from_name(&name).ok_or_else(|| {
            let hint = match crate::front::suggest(&name, Input::ALL.iter().map(|i| i.name())) {
                Some(s) => format!("did you mean `{s}`?"),
                None => "inputs are NL, NV, NH, VR, VH".to_string(),
            };
            CliError::hint(format!("--at: `{name}` is not an input"), hint)
        })?;
        x[i.index()] = v;
    }
    let params = common::param_values(&k.formula, &set);
    let v = k.eval(&x, &params);
    if a.json {
        let obj = serde_json::json!({
            "value": if v.is_finite() { serde_json::json!(v) } else { serde_json::json!(v.to_string()) },
            "backend": k.backend.name(),
            "compile_us": k.compile_time.as_secs_f64() * 1e6,
        });
        println!("{obj}");
    } else {
        println!("{v}");
    }
    Ok(())
}
