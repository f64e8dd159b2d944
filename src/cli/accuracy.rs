//! `lobe accuracy FILE --reference examples/brdfs/blinn.brdf [--set a=268] [--q 8] [--json]`
//!
//! JSON keys are documented in [`lobe::numerics`].

use super::args::{self, AgainstReference, BackendArg, Json, Params};
use super::common::{self, CliError};
use lobe::numerics::accuracy::{accuracy_channels, channels_json, AccuracyOptions, AccuracyReport, Worst};
use lobe::Kernel;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Values of the formula's other parameters, e.g. `a=268` (n is swept over 1..1000)")))]
pub struct AccuracyArgs {
    #[command(flatten)]
    pub against: AgainstReference,
    #[command(flatten)]
    pub set: Params,
    /// Cut-off level 2^−q for the relative-error and lobe-size metrics.
    #[arg(long, default_value_t = 8.0)]
    pub q: f64,
    /// Smallest n of the epicentre metric (the papers use 9 for F_dsh).
    #[arg(long, default_value_t = 2)]
    pub epicenter_from: u32,
    /// Largest n.
    #[arg(long, default_value_t = 1000)]
    pub n_max: u32,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
}

pub fn run(a: &AccuracyArgs) -> Result<(), CliError> {
    if lobe::measured::is_measured_path(&a.against.reference) {
        print!("{}", measured(a, None)?);
        return Ok(());
    }
    let set = a.set.list()?;
    let f = a.against.formula.load()?;
    // Each side takes the --set values of the parameters it declares.
    let rf = common::load_formula(Some(&a.against.reference), None)?;
    common::check_set_names(&[&f, &rf], &set)?;
    // The papers' metrics sweep n in both: where one reads no n, the comparison is over the whole hemisphere.
    if !(common::reads_n(&f) && common::reads_n(&rf)) {
        if !a.json.on {
            eprintln!("note: {}, so the papers' n-sweep does not apply: compared over the whole hemisphere (every incidence, at the measured tables' angles)", common::which_reads_no_n(&f, &rf));
        }
        print!("{}", measured(a, Some(&rf))?);
        return Ok(());
    }
    let own = common::set_for(&f, &set);
    let ks = f.channels().into_iter().map(|c| common::compile_kernel(c, &own, a.backend.bulk_backend()?, a.backend.math.mode)).collect::<Result<Vec<Kernel>, _>>()?;
    let r = common::compile_kernel(rf.clone(), &common::set_for(&rf, &set), a.backend.bulk_backend()?, lobe::Mode::Precise)?;
    print!("{}", report(a, &ks, &r)?);
    Ok(())
}

/// The command's output for already compiled kernels (the formula's channels `ks`, reference `r`): a colour
/// formula's channels under `channel r/g/b` headings, or in JSON the red channel's keys with `channels` (as
/// `energy` writes them).
pub fn report(a: &AccuracyArgs, ks: &[Kernel], r: &Kernel) -> Result<String, CliError> {
    let mut out = String::new();
    let set = a.set.list()?;
    if set.iter().any(|(k, _)| k == "n") {
        return Err(CliError::hint("accuracy sweeps n itself; --set n is not allowed", "set only the other parameters"));
    }
    let k = &ks[0];
    let params = common::param_values(&k.formula, &common::set_for(&k.formula, &set));
    // One lobe variable for every channel: the one the formula reads.
    let used: lobe::ir::InputSet = ks.iter().map(Kernel::used_inputs).collect();
    let (lobe, ref_lobe) = (a.against.lobe.resolve(used, a.json.on)?, lobe::numerics::choose_lobe_input(r.used_inputs()).0);
    for (f, what) in [(&k.formula, "formula"), (&r.formula, "reference")] {
        if let Some(d) = f.params.first() {
            if d.lo > 1.0 || d.hi < f64::from(a.n_max) {
                eprintln!("warning: the {what} declares n in {}..{}, but accuracy evaluates n = 1..{}", d.lo, d.hi, a.n_max);
            }
        }
    }
    let opts = AccuracyOptions { q: a.q, n_max: a.n_max, epicenter_from: a.epicenter_from, ..Default::default() };
    let channels: Vec<&dyn lobe::Evaluator> = ks.iter().map(|k| k as &dyn lobe::Evaluator).collect();
    let reps = accuracy_channels(&channels, &params, lobe, r, &r.default_params(), ref_lobe, &opts)?;
    if a.json.on {
        outln!(out, "{}", common::to_json(&channels_json(&reps, a.q))?);
        return Ok(out);
    }
    for (i, (rep, secs)) in reps.iter().enumerate() {
        if reps.len() > 1 {
            outln!(out, "channel {}:", ["r", "g", "b"][i]);
        }
        out.push_str(&text(a, &ks[i], r, lobe, rep, *secs));
    }
    Ok(out)
}

/// One channel's report as text.
fn text(a: &AccuracyArgs, k: &Kernel, r: &Kernel, lobe: lobe::ir::Input, rep: &AccuracyReport, secs: f64) -> String {
    let mut out = String::new();
    let ref_zero = rep.reference_is_zero();
    outln!(out, "{} vs {} (n = 1..{}, lobe variable {}):", k.formula.display_name(), r.formula.display_name(), a.n_max, lobe.name());
    outln!(out, "  mean |Δ| on the 91×{} grid (0°..90° step 1°):   {:.6e}", a.n_max, rep.mean_abs_grid);
    // A metric without an n where it is defined reads "undefined", not "NaN % at n = NaN".
    let rel = |m: &Worst, at: String| if m.n.is_nan() { "undefined".to_string() } else { format!("{:.4} % at n = {}{at}", m.value * 100.0, m.n) };
    outln!(out, 
        "  epicentre max rel. error, n ∈ [{}, {}]:          {}",
        a.epicenter_from, a.n_max, rel(&rep.epicenter, format!(" (x = {:.4}°)", rep.epicenter.angle_deg))
    );
    outln!(out, 
        "  inflection max rel. error, n ∈ [3, {}]:          {}",
        a.n_max, rel(&rep.inflection, format!(" (x = {:.4}°)", rep.inflection.angle_deg))
    );
    outln!(out, "  max |Δ| over angles (step 0.05°):               {:.6} at n = {}, {:.2}°", rep.max_abs.value, rep.max_abs.n, rep.max_abs.angle_deg);
    outln!(out, 
        "  max rel. error where the reference ≥ 2^−{}:       {}",
        a.q, rel(&rep.cutoff_rel, format!(", {:.2}°", rep.cutoff_rel.angle_deg))
    );
    if ref_zero {
        outln!(out, "  lobe-size ratio (cut-off angle / reference's):   undefined");
        outln!(out, "  the reference is 0 at every angle and n: relative errors and the lobe-size ratio are undefined;");
        outln!(out, "  max |Δ| above is the formula's own largest value");
    } else if rep.lobe_ratio_min.n.is_nan() {
        // No n has a finite ratio: the reference's lobe never reaches the cut-off level (its cut-off angle is 0).
        outln!(out, "  lobe-size ratio (cut-off angle / reference's):   undefined (the reference is below 2^−{} at every angle)", a.q);
    } else {
        outln!(out, 
            "  lobe-size ratio (cut-off angle / reference's):   {:.4} (n = {}) … {:.4} (n = {})",
            rep.lobe_ratio_min.value, rep.lobe_ratio_min.n, rep.lobe_ratio_max.value, rep.lobe_ratio_max.n
        );
    }
    if !ref_zero && [&rep.epicenter, &rep.inflection, &rep.cutoff_rel].iter().any(|m| m.n.is_nan()) {
        outln!(out, "  (undefined: the reference is 0 (for the cut-off metric, below 2^−{}) wherever that metric applies)", a.q);
    }
    if rep.nan_points > 0 {
        outln!(out, "  {} grid points were NaN (counted as the worst error); run `lobe sweep` on the file", rep.nan_points);
    }
    outln!(out, "  ({secs:.2} s, backend {})", k.backend_used().name());
    out
}

/// Accuracy against a measured table, or against the reference formula `rf` over the whole hemisphere at the
/// tables' angles: the formula at its parameters (defaults, then `--set`; each side the values it declares)
/// scored by the measured fit's metrics over every entry, each with its closed-form colour scale against a
/// table, at scale 1 against a formula ([`lobe::numerics::measured`]).
fn measured(a: &AccuracyArgs, rf: Option<&lobe::ir::Formula>) -> Result<String, CliError> {
    use lobe::numerics::measured::{residuals, Reference};
    let path = &a.against.reference;
    let set = a.set.list()?;
    let f = a.against.formula.load()?;
    let own = common::set_for(&f, &set);
    let params = common::param_values(&f, &own);
    let ks = f.channels().into_iter().map(|c| common::compile_kernel(c, &own, a.backend.bulk_backend()?, a.backend.math.mode)).collect::<Result<Vec<_>, _>>()?;
    let channels: Vec<&dyn lobe::Evaluator> = ks.iter().map(|k| k as &dyn lobe::Evaluator).collect();
    let reference: Box<dyn Reference> = match rf {
        None => Box::new(lobe::measured::Measured::read(path)?),
        Some(rf) => {
            let others: Vec<(&dyn lobe::Evaluator, Vec<f64>)> = channels.iter().map(|k| (*k, params.clone())).collect();
            Box::new(super::fit_measured::formula_reference(path, rf, &set, (a.backend.bulk_backend()?, lobe::Mode::Precise), false, &others)?)
        }
    };
    let s = reference.samples(1);
    if s.is_empty() {
        return Err(CliError::hint(
            format!("`{path}` has no entry measured in all three channels: there is nothing to score {} against", f.display_name()),
            "check the file: every entry is negative (not measured)",
        ));
    }
    let [log, rmse, cosine] = residuals(&channels, &params, &s);
    let mut out = String::new();
    if a.json.on {
        #[derive(serde::Serialize)]
        struct Json<'a> {
            formula: String,
            measured: &'a str,
            entries: usize,
            #[serde(serialize_with = "lobe::base::json::num")]
            log: f64,
            log_scale: [f64; 3],
            #[serde(serialize_with = "lobe::base::json::num")]
            rmse: f64,
            rmse_scale: [f64; 3],
            #[serde(serialize_with = "lobe::base::json::num")]
            cosine: f64,
            cosine_scale: [f64; 3],
        }
        let j = Json {
            formula: f.display_name(),
            measured: path,
            entries: s.len(),
            log: log.error,
            log_scale: log.scale,
            rmse: rmse.error,
            rmse_scale: rmse.scale,
            cosine: cosine.error,
            cosine_scale: cosine.scale,
        };
        outln!(out, "{}", common::to_json(&j)?);
        return Ok(out);
    }
    // The values of the parameters the formula reads (every formula declares the papers' n).
    let reads = f.channels().iter().flat_map(|c| c.ir.used_params(c.root)).collect::<Vec<u16>>();
    let shown: Vec<String> = f
        .params
        .iter()
        .zip(&params)
        .enumerate()
        .filter(|(i, _)| reads.contains(&(*i as u16)))
        .map(|(_, (d, v))| format!("{}={}", d.name, common::short_number(*v)))
        .collect();
    let what = if rf.is_some() { "entries (pairs of directions)" } else { "measured entries" };
    outln!(out, "{} ({}) vs {path}: {} {what} at the table's angles", f.display_name(), shown.join(", "), s.len());
    for (name, r) in [("cosine-weighted log error", log), ("RMSE", rmse), ("cosine-weighted L2", cosine)] {
        let [x, y, z] = r.scale;
        if s.fit_scale {
            outln!(out, "  {name:<26} {:.6e}  with colour scale ({x:.4}, {y:.4}, {z:.4})", r.error);
        } else {
            outln!(out, "  {name:<26} {:.6e}", r.error);
        }
    }
    outln!(out, "  (fit the parameters: `lobe fit FILE --measured {path} --param …`)");
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lobe::numerics::twins;
    use crate::cli::energy::tests::{parse, twin_kernel};
    use lobe::ir::Input;


    #[test]
    fn json_keys_and_published_mean() {
        let a = parse::<AccuracyArgs>(&["accuracy", "--reference", "blinn.brdf", "--json", "--n-max", "1000"]);
        let k = twin_kernel(twins::modified_schlick(), Input::NH, &[]);
        let r = twin_kernel(twins::blinn(), Input::NH, &[]);
        let v: serde_json::Value = serde_json::from_str(&report(&a, std::slice::from_ref(&k), &r).unwrap()).unwrap();
        assert!((v["mean_abs_grid"].as_f64().unwrap() - 0.006554934).abs() < 1e-8, "{v}");
        for key in ["epicenter_max_rel_pct", "inflection_max_rel_pct", "max_abs", "cutoff_max_rel_pct", "lobe_ratio_max"] {
            assert!(v[key].as_f64().is_some(), "missing {key}: {v}");
        }
        let a = parse::<AccuracyArgs>(&["accuracy", "--reference", "b", "--set", "n=3"]);
        assert!(report(&a, std::slice::from_ref(&k), &r).is_err());
    }
}
