//! `lobe tabulate FILE [--set n=120] [--color R,G,B] -o out.binary`: a formula tabulated into a MERL table
//! ([`lobe::measured::Measured::tabulate`]: the convention's angles, values stored as MERL stores them).

use super::args::{self, BackendArg, FormulaSource, Json, Output, Params};
use super::common::CliError;
use lobe::measured::Measured;
use lobe::Evaluator;

#[derive(clap::Args, Debug)]
#[command(mut_arg("output", |a| a.required(true).help("Output MERL table (.binary)")))]
#[command(mut_arg("set", args::help("Parameter values, e.g. `n=120`")))]
pub struct TabulateArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// Multiply the red, green and blue channels by these factors (a scalar formula's colour).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0, 1.0, 1.0], allow_hyphen_values = true)]
    pub color: Vec<f64>,
    #[command(flatten)]
    pub out: Output,
    #[command(flatten)]
    pub backend: BackendArg,
    /// Print `{"output", "formula", "measured_entries", "entries", "color"}` instead of the line on stderr.
    #[command(flatten)]
    pub json: Json,
}

/// MERL tables carry no mark of who wrote them: an existing file is replaced only with `--force`.
fn never_ours(_: &[u8]) -> bool {
    false
}

pub fn run(a: &TabulateArgs) -> Result<(), CliError> {
    let path = a.out.required();
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("binary")) {
        return Err(CliError::hint(format!("`{}`: a MERL table is named .binary", path.display()), "e.g. -o gold.binary"));
    }
    a.out.force.check(path, never_ours)?;
    if a.color.len() != 3 || a.color.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
        return Err(CliError::hint("--color takes three finite factors ≥ 0", "e.g. --color 1,0.8,0.4"));
    }
    let set = a.set.list()?;
    let f = a.formula.load()?;
    let params = super::common::param_values(&f, &set);
    let ks = f.channels().into_iter().map(|c| super::common::compile_kernel(c, &set, a.backend.bulk_backend()?, a.backend.math.mode)).collect::<Result<Vec<_>, _>>()?;
    let name = f.display_name();
    let channels: Vec<&dyn Evaluator> = ks.iter().map(|k| k as &dyn Evaluator).collect();
    let t = Measured::tabulate_channels(&name, &channels, &params, [a.color[0], a.color[1], a.color[2]]);
    a.out.force.write(path, &t.to_bytes(), never_ours)?;
    if a.json.on {
        let j = serde_json::json!({"output": path.display().to_string(), "formula": name, "measured_entries": t.measured_entries(), "entries": lobe::measured::ENTRIES, "color": a.color});
        println!("{j}");
    } else {
        eprintln!("wrote {} ({name}: {} of {} entries measured)", path.display(), t.measured_entries(), lobe::measured::ENTRIES);
    }
    Ok(())
}
