//! `lobe energy FILE --set n=50 [--mode lobe|full] [--range 1..1000 [--against F.brdf | --against-expr E]] [--json]`
//!
//! JSON keys are documented in [`lobe::numerics`]. A colour formula is checked per channel: the text shows
//! each channel under a `channel r/g/b` heading; `--json` prints the red channel's object with one more key,
//! `"channels"`: the three channels' objects (red, green, blue), each with the keys of a scalar formula's.
//! `--mode full` on a formula that reads direction components integrates over the azimuth of L too
//! ([`lobe::numerics::energy::full_energy_for`]): `albedo` then holds max over φᵢ of ρ(θᵢ, φᵢ), and the JSON
//! adds `phi_i_at_max_deg` and `albedo_phi` (every θᵢ, φᵢ, ρ).

use super::args::{self, BackendArg, Force, FormulaSource, Json, LobeVar, LookupArg, Params};
use super::common::{self, CliError};
use lobe::base::json::Named;
use lobe::ir::Input;
use lobe::numerics::energy::{coef_range, full_energy_for, lobe_integral, score_fitted, CoefRange};
use lobe::numerics::energy::{EnergyReport, FullReport, LobeReport, PerChannel, RangeReport};
use super::args::parse_range;
use lobe::{Backend, Evaluator, Kernel};

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// The papers' coefficient: the lobe as a function of one angle, light at the normal.
    #[default]
    Lobe,
    /// Hemispherical-directional albedo over incidence angles, its maximum, and reciprocity.
    Full,
}

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values, e.g. `n=50,a=16` (n is swept instead with --range)")))]
pub struct EnergyArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// `lobe` (1/(2π∫f cosθ sinθ dθ), the papers' coefficient of a one-cosine lobe) or `full` (albedo ρ(θᵢ)
    /// from real geometry). Default: `lobe` for a formula that reads one lobe cosine (NH or VR) and nothing
    /// else, or with --range, --lobe or --against; `full` for any other formula (a microfacet model, a
    /// direction formula) and for measured tables.
    #[arg(long, value_enum)]
    pub mode: Option<Mode>,
    /// Sweep n over `lo..hi` (lobe mode) and print coef(n).
    #[arg(long)]
    pub range: Option<String>,
    /// Step of the --range sweep.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub step: f64,
    /// A .brdf whose value is a fitted coef(n, params…) to score against the exact one (needs --range).
    #[arg(long, requires = "range", conflicts_with = "against_expr")]
    pub against: Option<String>,
    /// The fitted coefficient inline, e.g. `0.125*n - 45.76/(n + 46.578) + 1.317`.
    #[arg(long, requires = "range")]
    pub against_expr: Option<String>,
    #[command(flatten)]
    pub lobe: LobeVar,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
    /// With --range: also plot coef(n) (and the fitted coefficient with --against) to this .png or .svg.
    #[arg(long, requires = "range")]
    pub plot: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub force: Force,
    #[command(flatten)]
    pub lookup: LookupArg,
}

pub fn run(a: &EnergyArgs) -> Result<(), CliError> {
    let set = a.set.list()?;
    if a.range.is_some() && set.iter().any(|(k, _)| k == "n") {
        return Err(CliError::hint("--set n conflicts with --range", "--range sweeps n; drop n from --set"));
    }
    let backend: Backend = a.backend.bulk_backend()?;
    if let Some(p) = a.formula.file.as_deref().filter(|p| lobe::measured::is_measured_path(p)) {
        print!("{}", measured_report(a, p)?);
        return Ok(());
    }
    a.lookup.only_for_tables(0)?;
    let f = a.formula.load()?;
    let ks = f
        .channels()
        .into_iter()
        .map(|c| common::compile_kernel(c, &set, backend, a.backend.math.mode))
        .collect::<Result<Vec<Kernel>, CliError>>()?;
    let against = match (&a.against, &a.against_expr) {
        (None, None) => None,
        (file, expr) => {
            // A fitted coefficient reads no input by design: its "reads no input" warning is noise here.
            let f = common::load_formula_with(file.as_deref(), expr.as_deref(), false)?;
            Some(lobe::compile_formula(f, &a.backend.options(vec![])?)?)
        }
    };
    print!("{}", report_channels(a, &ks, against.as_ref())?);
    Ok(())
}

/// One channel's output: the `--json` report, or the text.
enum Out {
    Json(EnergyReport),
    Text(String),
}

impl EnergyArgs {
    /// The mode asked for, or the one that means something for a formula reading `used` (module docs).
    fn mode_for(&self, used: lobe::ir::InputSet) -> Mode {
        let lobe_flags = self.range.is_some() || self.lobe.name.is_some() || self.against.is_some() || self.against_expr.is_some();
        let one_cosine = used.is_empty() || lobe::numerics::one_lobe_cosine(used).is_some();
        self.mode.unwrap_or(if lobe_flags || one_cosine { Mode::Lobe } else { Mode::Full })
    }
}

/// The output for a formula's channel kernels (one, or red, green, blue; see the module docs).
fn report_channels(a: &EnergyArgs, ks: &[Kernel], against: Option<&Kernel>) -> Result<String, CliError> {
    if ks.len() > 1 && a.range.is_some() {
        return Err(CliError::hint("--range works on scalar formulas only", "this formula has a colour result; drop --range"));
    }
    let used: lobe::ir::InputSet = ks.iter().map(Kernel::used_inputs).collect();
    let mode = a.mode_for(used);
    if a.mode.is_none() && mode == Mode::Full && !a.json.on {
        eprintln!("note: the formula reads {used}, not one lobe cosine: its albedo over incidence (--mode lobe gives the papers' one-angle coefficient)");
    }
    let outs = ks.iter().map(|k| report(a, k, against, mode)).collect::<Result<Vec<Out>, CliError>>()?;
    join_channels(a, outs)
}

/// One channel's output as it is, or three under `channel r/g/b` headings (JSON: [`PerChannel`]).
fn join_channels(a: &EnergyArgs, outs: Vec<Out>) -> Result<String, CliError> {
    let (mut reports, mut texts) = (vec![], vec![]);
    for o in outs {
        match o {
            Out::Json(r) => reports.push(r),
            Out::Text(t) => texts.push(t),
        }
    }
    if a.json.on {
        return Ok(format!("{}\n", common::to_json(&PerChannel::new(reports))?));
    }
    if texts.len() == 1 {
        return Ok(texts.remove(0));
    }
    Ok(["r", "g", "b"].iter().zip(&texts).map(|(c, p)| format!("channel {c}:\n{p}")).collect())
}

/// The full mode's report for one evaluator (a formula's channel kernel, or a measured table's channel).
fn full_mode(a: &EnergyArgs, name: &str, ev: &dyn Evaluator, used: Option<lobe::ir::InputSet>, params: &[f64], shown: Named) -> Result<Out, CliError> {
    let mut out = String::new();
    // `None`: a measured table's channel (its own quadrature, lobe::numerics::energy::full_energy_tabulated).
    let spinner = common::Spinner::new(!a.json.on && std::io::IsTerminal::is_terminal(&std::io::stderr()), name);
    spinner.show("the albedo over incidence (a direction formula integrates over the azimuth of L too)".to_string());
    let r = match used {
        Some(used) => full_energy_for(ev, used, params),
        None => lobe::numerics::energy::full_energy_tabulated(ev, params),
    };
    spinner.finish();
    let r = r?;
    if a.json.on {
        return Ok(Out::Json(EnergyReport::Full(FullReport::new(shown, &r))));
    }
    outln!(out, "{name}: hemispherical-directional albedo ρ(θᵢ) = ∫ f·cosθₒ dωₒ");
    match r.isotropic {
        Some(true) => outln!(
            out,
            "  (the formula reads directions, but its values turn with the frame about N at {} random pairs: ρ(θᵢ) at φᵢ = 0° stands for every φᵢ)",
            lobe::numerics::energy::ISOTROPY_PAIRS
        ),
        Some(false) => outln!(out, "  (the formula reads directions: ρ(θᵢ) is the maximum over the azimuth φᵢ = 0°, 15°, …, 345° of L)"),
        None => {}
    }
    outln!(out, "  θᵢ (deg)   ρ(θᵢ)");
    for (t, v) in &r.albedo {
        if t.fract() != 0.0 || (*t as i64) % 5 == 0 {
            outln!(out, "  {t:>8.1}   {v:.8}");
        }
    }
    let phi = r.phi_i_at_max_deg.map(|p| format!(", φᵢ = {p}°")).unwrap_or_default();
    outln!(out, "max ρ = {:.8} at θᵢ = {}°{phi}; coefficient 1/max ρ = {:.8}", r.albedo_max, r.theta_i_at_max_deg, r.coef);
    if r.albedo_max > 1.0 + 1e-9 {
        outln!(out, "  the formula reflects more energy than it receives at θᵢ = {}° (ρ > 1)", r.theta_i_at_max_deg);
    }
    let rec = &r.reciprocity;
    outln!(out, 
        "reciprocity: worst |f(L,V) − f(V,L)|/max = {:.3e} at θ_L = {}°, θ_V = {}°, φ_V = {}° ({} pairs){}",
        rec.max_rel,
        rec.theta_l_deg,
        rec.theta_v_deg,
        rec.phi_v_deg,
        rec.pairs,
        if rec.max_rel < 1e-12 { " — reciprocal" } else { "" }
    );
    Ok(Out::Text(out))
}

/// `energy --mode full` of a measured table (`lobe::measured`): each channel's albedo, as a colour formula's.
fn measured_report(a: &EnergyArgs, path: &str) -> Result<String, CliError> {
    if a.mode == Some(Mode::Lobe) || a.range.is_some() || a.lobe.name.is_some() || a.against.is_some() || a.against_expr.is_some() || !a.set.list()?.is_empty() {
        return Err(CliError::hint(
            format!("`{path}` is a measured table: it has no parameters and no one-angle lobe"),
            "its albedo is `lobe energy FILE.binary --mode full` (no --range, --lobe, --against or --set)",
        ));
    }
    let table = std::sync::Arc::new(lobe::measured::Measured::read(path)?);
    if table.measured_entries() == 0 {
        return Err(CliError::hint(format!("`{path}` has no measured entry: it has no albedo to integrate"), "check the file: every entry is negative (not measured)"));
    }
    let outs = table
        .channels_with(a.lookup.how())
        .iter()
        .map(|ev| full_mode(a, path, ev.as_ref(), None, &[], Named::new(std::iter::empty())))
        .collect::<Result<Vec<Out>, CliError>>()?;
    join_channels(a, outs)
}

/// The command's output for one already compiled kernel (the formula, and the fitted coefficient if any).
fn report(a: &EnergyArgs, k: &Kernel, against: Option<&Kernel>, mode: Mode) -> Result<Out, CliError> {
    let mut out = String::new();
    let params = common::param_values(&k.formula, &a.set.list()?);
    let name = k.formula.display_name();
    // `params` of the JSON output; under --range, n is the swept variable, not a parameter.
    let shown = k.formula.params.iter().zip(&params).filter(|(d, _)| a.range.is_none() || d.name != "n");
    let shown = Named::new(shown.map(|(d, v)| (d.name.as_str(), *v)));

    if mode == Mode::Full {
        if a.range.is_some() {
            return Err(CliError::hint("--range works in lobe mode only", "drop --mode full, or drop --range"));
        }
        // Full mode integrates over real geometry: there is no lobe variable to choose (nor a note about it).
        if a.lobe.name.is_some() {
            return Err(CliError::hint("--lobe works in lobe mode only", "drop --mode full, or drop --lobe"));
        }
        return full_mode(a, &name, k, Some(k.used_inputs()), &params, shown);
    }

    let lobe: Input = a.lobe.resolve(k.used_inputs(), a.json.on)?;
    let Some(range) = &a.range else {
        let r = lobe_integral(k, &params, lobe)?;
        if a.json.on {
            return Ok(Out::Json(EnergyReport::Lobe(LobeReport::new(shown, lobe, &r))));
        }
        let shown: Vec<String> = k.formula.params.iter().zip(&params).map(|(d, v)| format!("{}={v}", d.name)).collect();
        outln!(out, "{name} ({}): coef = 1/(2π·Int) = {:.9}", shown.join(", "), r.coef());
        outln!(out, "  Int = ∫₀¹ max(f(c),0)·c dc = {:.12e} (± {:.1e}, {} evaluations)", r.integral, r.error, r.evals);
        outln!(out, "  lobe variable {} = cos θ; NL = 1, NV = cos θ (light at the normal)", lobe.name());
        if let Some((c, bound)) = r.skipped {
            outln!(
                out,
                "  skipped: the formula is NaN (0/0 or ∞·0) for {} ≤ {c:e}; taken as its limit from the right (that piece adds ≤ {bound:.1e} to Int)",
                lobe.name()
            );
        }
        for c in &r.kinks {
            outln!(out, "  the lobe is clamped to zero beyond θ = {:.6}° ({} = {c:.9})", c.acos().to_degrees(), lobe.name());
        }
        return Ok(Out::Text(out));
    };

    let (lo, hi) = parse_range(range).map_err(|e| CliError::hint(format!("--range: {e}"), "e.g. --range 1..1000"))?;
    let CoefRange { integrals, coefs } = coef_range(k, &params, lobe, k.formula.params.first(), lo, hi, a.step)?;
    let score = against.map(|ak| score_fitted(&k.formula, &params, ak, &integrals));
    if let Some(path) = &a.plot {
        plot_range(path, &name, &coefs, score.as_ref(), a.force)?;
    }
    if a.json.on {
        return Ok(Out::Json(EnergyReport::Range(RangeReport::new(shown, lobe, &coefs, score.as_ref()))));
    }
    outln!(out, "{name}: coef(n) = 1/(2π·Int(n)), lobe variable {}", lobe.name());
    match &score {
        None => {
            outln!(out, "{:>10}  {:>16}", "n", "coef");
            for (n, c) in &coefs {
                outln!(out, "{n:>10}  {c:>16.9}");
            }
        }
        Some(s) => {
            outln!(out, "{:>10}  {:>16}  {:>16}  {:>14}", "n", "coef exact", "coef fitted", "|fit·2π·Int−1|");
            for (n, ce, cf, err) in &s.rows {
                outln!(out, "{n:>10}  {ce:>16.9}  {cf:>16.9}  {err:>14.6e}");
            }
            outln!(out, 
                "fitted coefficient: max |coef_fit·2π·Int − 1| = {:.6e} at n = {}; mean {:.6e} over {} values of n",
                s.max_abs,
                s.worst_n,
                s.mean_abs,
                s.rows.len()
            );
        }
    }
    Ok(Out::Text(out))
}

/// Writes coef(n) (exact, and fitted when scored) as a plot.
fn plot_range(
    path: &std::path::Path,
    name: &str,
    coefs: &[(f64, f64)],
    score: Option<&lobe::numerics::energy::AgainstScore>,
    force: Force,
) -> Result<(), CliError> {
    use lobe::report::plot::{self, Format, Series};
    let format = Format::from_path(path).map_err(|e| CliError::hint(e, "use --plot coef.png or coef.svg"))?;
    let mut series = vec![Series {
        name: "exact coef(n) = 1/(2π·Int)".into(),
        points: coefs.to_vec(),
    }];
    if let Some(s) = score {
        series.push(Series { name: "fitted coef(n)".into(), points: s.rows.iter().map(|r| (r.0, r.2)).collect() });
    }
    let bytes = plot::curves(&series, &format!("{name}: normalisation coefficient"), "n", "coef", format).map_err(CliError::msg)?;
    force.write(path, &bytes, common::is_lobe_output)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use lobe::builtins::Builtin;
    use lobe::numerics::twins::{self, Twin};
    use lobe::base::span::Span;
    use lobe::ir::{Formula, Ir, Meta, ParamDecl, ParamKind};
    use std::sync::Arc;

    /// `max(pow(clamp(INPUT, 0, 1), n), 0)` with the given extra parameters declared (n first).
    pub fn power_formula(input: Input, extra: &[(&str, f64, f64, f64)]) -> Formula {
        let mut ir = Ir::new();
        let s = Span::default();
        let x = ir.input(input, s);
        let z = ir.konst(0.0, s);
        let o = ir.konst(1.0, s);
        let c = ir.call(Builtin::Clamp, &[x, z, o], s);
        let n = ir.param(0, s);
        let p = ir.call(Builtin::Pow, &[c, n], s);
        let root = ir.call(Builtin::Max, &[p, z], s);
        let mut params = vec![ParamDecl { name: "n".into(), default: 50.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }];
        params.extend(extra.iter().map(|&(name, default, lo, hi)| ParamDecl { name: name.into(), default, lo, hi, span: None, kind: ParamKind::Float }));
        Formula { meta: Meta { name: Some("test".into()), citation: None }, params, ir, root, file: "t.brdf".into(), source: String::new(), rgb: None }
    }

    /// A kernel whose evaluator is a twin, with a formula declaring the twin's parameters and reading `input`.
    pub fn twin_kernel(t: Twin, input: Input, extra: &[(&str, f64, f64, f64)]) -> Kernel {
        Kernel::new(Arc::new(power_formula(input, extra)), Backend::Interp, lobe::Mode::Precise, Arc::from(t.ev), std::time::Duration::ZERO)
    }

    /// A subcommand's arguments parsed from `argv` (its name first), as clap parses them for the binary.
    pub fn parse<A: clap::Args + clap::FromArgMatches>(argv: &[&str]) -> A {
        let m = A::augment_args(clap::Command::new("lobe")).try_get_matches_from(argv).unwrap_or_else(|e| panic!("{e}"));
        A::from_arg_matches(&m).unwrap_or_else(|e| panic!("{e}"))
    }

    fn args(v: &[&str]) -> EnergyArgs {
        parse(&[&["energy"], v].concat())
    }

    fn json(s: &str) -> serde_json::Value {
        serde_json::from_str(s).unwrap()
    }

    #[test]
    fn lobe_mode_json_and_text() {
        let k = twin_kernel(twins::phong(), Input::VR, &[]);
        let v = json(&report_channels(&args(&["--set", "n=100", "--json"]), std::slice::from_ref(&k), None).unwrap());
        assert!((v["coef"].as_f64().unwrap() - 102.0 / (2.0 * std::f64::consts::PI)).abs() < 1e-9);
        assert_eq!(v["lobe_input"], "VR");
        let t = report_channels(&args(&["--set", "n=100"]), std::slice::from_ref(&k), None).unwrap();
        assert!(t.contains("coef = 1/(2π·Int) = 16.2338"), "{t}");
    }

    #[test]
    fn range_against_an_exact_fit_scores_zero() {
        let k = twin_kernel(twins::phong(), Input::VR, &[]);
        let exact = Kernel::new(
            Arc::new(power_formula(Input::NH, &[])),
            Backend::Interp,
            lobe::Mode::Precise,
            Arc::new(lobe::backend::FnEvaluator(|_: &[f64; lobe::N_INPUTS], p: &[f64]| (p[0] + 2.0) / (2.0 * std::f64::consts::PI))),
            std::time::Duration::ZERO,
        );
        let v = json(&report_channels(&args(&["--range", "1..40", "--against-expr", "x", "--json"]), std::slice::from_ref(&k), Some(&exact)).unwrap());
        assert!(v["against_max_abs"].as_f64().unwrap() < 1e-9, "{v}");
        assert_eq!(v["range"].as_array().unwrap().len(), 40);
        let e = report_channels(&args(&["--range", "0..40"]), std::slice::from_ref(&k), None).unwrap_err();
        assert!(e.render(false).contains("declared range of n"));
    }

    #[test]
    fn full_mode_json_has_the_documented_keys() {
        let k = twin_kernel(twins::phong(), Input::VR, &[]);
        let v = json(&report_channels(&args(&["--set", "n=10", "--mode", "full", "--json"]), std::slice::from_ref(&k), None).unwrap());
        for key in ["coef", "albedo_max", "theta_i_at_max_deg", "reciprocity_max_rel", "albedo"] {
            assert!(!v[key].is_null(), "missing {key}: {v}");
        }
        assert_eq!(v["theta_i_at_max_deg"].as_f64(), Some(0.0));
    }

    #[test]
    fn zero_lobe_is_a_clear_error() {
        let zero = Twin { name: "zero", params: &["n"], defaults: vec![50.0], ev: Box::new(lobe::backend::FnEvaluator(|_: &[f64; lobe::N_INPUTS], _: &[f64]| 0.0)) };
        let k = twin_kernel(zero, Input::NH, &[]);
        let e = report_channels(&args(&[]), std::slice::from_ref(&k), None).unwrap_err();
        assert!(e.render(false).contains("integral is zero; cannot normalise"));
    }
}
