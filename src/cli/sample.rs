//! `lobe sample FILE [--set k=v…] --incidence θ[,φ] --count N [--seed S] [--mechanism M] [-o samples.csv] [--json]`
//!
//! Builds the formula's sampler ([`lobe::bsdf`]; FILE may also be a measured table, MERL `.binary`, sampled from
//! its lookups, whose quadrature is `energy --mode full`'s rule for tables), draws N seeded samples at the
//! incidence (degrees; φ defaults to 0), tests them against the sampler's own pdf (χ², Mitsuba's method), and prints the summary: `chi2_p`,
//! `efficiency`, `albedo`, `albedo_stderr`, `albedo_quadrature`, `build_ms`, `ns_per_sample`, `mechanism` and
//! the rest of [`lobe::bsdf::validate::SampleReport`]. `-o` writes one CSV row per sample: `ox,oy,oz,pdf,weight`
//! (colour: `weight_r,weight_g,weight_b`), directions in the local frame (N = +z, X = +x).

use super::args::{BackendArg, Force, FormulaSource, Json, Params};
use super::common::{self, CliError};
use lobe::base::json::Named;
use lobe::bsdf::validate::{albedo_quadrature, albedo_quadrature_tabulated, validate, SampleReport};
use lobe::bsdf::{Choice, Mechanism, Options, Sampler};
use lobe::Kernel;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct SampleArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub set: Params,
    /// The incident direction (the formula's L): θ, or θ,φ, in degrees (θ in [0, 90), φ about N from X).
    #[arg(long, value_name = "THETA[,PHI]", allow_hyphen_values = true)]
    pub incidence: String,
    /// Number of samples.
    #[arg(long, default_value_t = 1_000_000)]
    pub count: u64,
    /// Seed of the counter-based random stream (the same samples for any number of threads).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// `auto` (the best measured), `tabulated`, `exact` (formulas of NH alone or VR alone) or `cosine`.
    #[arg(long, default_value = "auto")]
    pub mechanism: String,
    /// Write the samples as CSV to this file.
    #[arg(short = 'o', long = "output", value_name = "OUTPUT")]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub force: Force,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
}

/// θ,φ in degrees from `--incidence`.
fn incidence(s: &str) -> Result<(f64, f64), CliError> {
    let bad = |why: &str| CliError::hint(format!("--incidence `{s}`: {why}"), "give θ or θ,φ in degrees, e.g. --incidence 30 or --incidence 60,45");
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.is_empty() || parts.len() > 2 {
        return Err(bad("expected one or two numbers"));
    }
    let num = |p: &str| p.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| bad(&format!("`{p}` is not a finite number")));
    let t = num(parts[0])?;
    let p = if parts.len() == 2 { num(parts[1])? } else { 0.0 };
    if !(0.0..90.0).contains(&t) {
        return Err(bad("θ must be in [0, 90) degrees: wi is above the horizon"));
    }
    Ok((t, p))
}

/// Recognises a CSV this command wrote (its header).
fn is_sample_csv(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ox,oy,oz,pdf,weight")
}

pub fn run(a: &SampleArgs) -> Result<(), CliError> {
    let set = a.set.list()?;
    let (theta, phi) = incidence(&a.incidence)?;
    if a.count == 0 {
        return Err(CliError::hint("--count 0: nothing to sample", "give --count 1000000 (the χ² test wants about a million)"));
    }
    let choice = match a.mechanism.as_str() {
        "auto" => Choice::Auto,
        m => Choice::Force(m.parse::<Mechanism>().map_err(|e| CliError::hint(e, "--mechanism auto picks the best measured"))?),
    };
    if let Some(p) = &a.output {
        a.force.check(p, is_sample_csv)?;
    }
    let backend = a.backend.backend()?;
    let opts = Options { choice, ..Options::default() };
    let (tr, pr) = (theta.to_radians(), phi.to_radians());
    let table = a.formula.file.as_deref().filter(|p| lobe::measured::is_measured_path(p));
    let (s, name, shown, quad) = match table {
        Some(path) => {
            if !set.is_empty() {
                return Err(CliError::hint(format!("--set: the measured table {path} has no parameters"), "drop --set"));
            }
            let channels = std::sync::Arc::new(lobe::measured::Measured::read(path)?).channels_with(Default::default());
            let s = Sampler::build_evaluators(&channels, lobe::measured::used_inputs(), &[], &opts)?;
            let quad = albedo_quadrature_tabulated(&s, tr);
            (s, path.to_string(), Named::new(std::iter::empty::<(&str, f64)>()), quad)
        }
        None => {
            let f = a.formula.load()?;
            let ks = f.channels().into_iter().map(|c| common::compile_kernel(c, &set, backend, a.backend.math.mode)).collect::<Result<Vec<Kernel>, CliError>>()?;
            let params = common::param_values(&ks[0].formula, &set);
            let s = Sampler::build_channels(&ks, &params, &opts)?;
            let shown = Named::new(ks[0].formula.params.iter().zip(&params).map(|(d, v)| (d.name.as_str(), *v)));
            let quad = albedo_quadrature(&s, tr, pr)?;
            (s, ks[0].formula.display_name(), shown, quad)
        }
    };
    let wi = [tr.sin() * pr.cos(), tr.sin() * pr.sin(), tr.cos()];
    let v = validate(&s, wi, a.count, a.seed)?;
    if let Some(p) = &a.output {
        a.force.write(p, csv(&v.samples).as_bytes(), is_sample_csv)?;
        eprintln!("wrote {} samples to {}", v.samples.pdf.len(), p.display());
    }
    let r = SampleReport::new(&s, &v, shown, (theta, phi), a.count, a.seed, quad);
    if a.json.on {
        println!("{}", common::to_json(&r)?);
        return Ok(());
    }
    print!("{}", text(&name, &r));
    Ok(())
}

/// One row per sample.
fn csv(s: &lobe::bsdf::Samples) -> String {
    let mut out = String::with_capacity(s.pdf.len() * 80);
    out.push_str(if s.channels == 3 { "ox,oy,oz,pdf,weight_r,weight_g,weight_b\n" } else { "ox,oy,oz,pdf,weight\n" });
    for i in 0..s.pdf.len() {
        let w = &s.weight[i * s.channels..(i + 1) * s.channels];
        let ws: Vec<String> = w.iter().map(|x| x.to_string()).collect();
        outln!(out, "{},{},{},{},{}", s.wo[i][0], s.wo[i][1], s.wo[i][2], s.pdf[i], ws.join(","));
    }
    out
}

/// The summary as text.
fn text(name: &str, r: &SampleReport) -> String {
    let mut o = String::new();
    outln!(o, "{name}: {} samples at θᵢ = {}°, φᵢ = {}° (seed {})", r.count, r.theta_i_deg, r.phi_i_deg, r.seed);
    let probe: Vec<String> = r.candidates.0.iter().map(|(m, e)| format!("{m} {e:.3}")).collect();
    outln!(o, "  mechanism   {} ({}; cosine fraction {}){}", r.mechanism, if r.isotropic { "isotropic" } else { "anisotropic" }, r.cosine_fraction,
        if probe.is_empty() { String::new() } else { format!("; probe efficiency: {}", probe.join(", ")) });
    let verdict = match &r.chi2_failure {
        Some(f) => format!("FAILED: {f}"),
        None if r.chi2_p < 0.01 => "below α = 0.01".to_string(),
        None => "passes at α = 0.01".to_string(),
    };
    outln!(o, "  χ²          {:.1} on {} degrees of freedom ({} cells pooled): p = {:.4} — {verdict}", r.chi2_statistic, r.chi2_dof, r.chi2_pooled, r.chi2_p);
    outln!(o, "  efficiency  {:.4} (E[w]²/E[w²]; 1 is perfect importance sampling)", r.efficiency);
    outln!(o, "  albedo      {:.6} ± {:.6} (Monte Carlo); quadrature {:.6}", r.albedo, r.albedo_stderr, r.albedo_quadrature);
    let ns = |v: Option<f64>| v.map(|x| format!("{x:.0} ns")).unwrap_or_else(|| "n/a".into());
    outln!(o, "  cost        build {:.1} ms; sample {} and pdf {} per call (thread CPU time, batches of 4096)", r.build_ms, ns(r.ns_per_sample), ns(r.ns_per_pdf));
    if !r.empty_nodes.is_empty() {
        let list: Vec<String> = r.empty_nodes.iter().map(|(t, p)| format!("θᵢ {t:.2}° φᵢ {p:.1}°")).collect();
        outln!(o, "  note        the formula is 0 at every table point of {} incidence node(s) ({}): cosine sampling there, weight 0", list.len(), list.join(", "));
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn incidence_parses_and_refuses() {
        assert_eq!(incidence("30").unwrap(), (30.0, 0.0));
        assert_eq!(incidence("60, 45").unwrap(), (60.0, 45.0));
        for bad in ["90", "-1", "a", "1,2,3", "nan"] {
            assert!(incidence(bad).is_err(), "{bad}");
        }
    }
}
