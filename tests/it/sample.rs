//! Sampling (`lobe::bsdf`): every formula a full BSDF.
//!
//! - χ² (Mitsuba's method, `lobe::bsdf::chi2`): 10⁶ samples at α = 0.01, Šidák-corrected over every test of the
//!   run. The full sweep (`chi2_everywhere`, ignored; `.ci/run` runs it with the other ignored tests) covers every
//!   `examples/brdfs` and `examples/explorer` file at θᵢ = 0°, 30°, 60°, 85° (and φᵢ = 0°, 45° when
//!   anisotropic), at the default parameters and two sets drawn inside the declared ranges, and 50 random
//!   formulas of the differential test's generator; `chi2_subset` runs a few of those cases every time.
//! - The sampler's own promises: pdf from sample() = pdf(wi, wo) within 1e-12, weight = f·cos/pdf within 1e-12,
//!   pdf > 0 wherever f·cos > 0 (10⁶ random pairs), the Monte-Carlo albedo within 3 standard errors and 0.5 % of
//!   the quadrature (`numerics::energy::albedo_at`) at 8 incidences.
//! - The χ² test rejects a sampler whose pdf is wrong; bad input is an error or a documented result.

use crate::differential::{self, E};
use lobe::bsdf::validate::{sample_seeded, validate};
use lobe::bsdf::{chi2, Choice, Mechanism, Options, Sampler};
use lobe::builtins::Builtin;
use lobe::frame::V3;
use lobe::Kernel;
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;
use rayon::prelude::*;

const ALPHA: f64 = 0.01;
const SAMPLES: u64 = 1_000_000;

/// A formula file's channel kernels (parameters live), its defaults and declarations.
pub(crate) fn load(path: &str) -> (Vec<Kernel>, Vec<f64>, Vec<lobe::ir::ParamDecl>) {
    let src = std::fs::read_to_string(path).unwrap();
    let f = lobe::front::parse(path, &src).unwrap_or_else(|e| panic!("{}", e.render(false)));
    (kernels(f.clone()), f.default_params(), f.params.clone())
}

fn kernels(f: lobe::Formula) -> Vec<Kernel> {
    f.channels().into_iter().map(|c| lobe::compile_formula(c, &lobe::Options::default()).unwrap()).collect()
}

fn dir(theta_deg: f64, phi_deg: f64) -> V3 {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

fn catalogue() -> Vec<String> {
    let mut files: Vec<String> = ["examples/brdfs", "examples/explorer"]
        .iter()
        .flat_map(|d| std::fs::read_dir(d).unwrap().map(|e| e.unwrap().path()))
        .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    files.sort();
    files
}

/// The default parameters and two sets drawn uniformly inside the middle 80 % of each declared range (the ends
/// of some ranges are degenerate: m = 0.01 is a mirror), from a fixed stream per file.
pub(crate) fn param_sets(file: &str, defaults: &[f64], decls: &[lobe::ir::ParamDecl]) -> Vec<Vec<f64>> {
    let seed = file.bytes().fold(17u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64));
    let mut sets = vec![defaults.to_vec()];
    for k in 0..2u64 {
        sets.push(
            decls
                .iter()
                .enumerate()
                .map(|(i, d)| {
                    let u = 0.1 + 0.8 * lobe::base::rng::counter_unit(seed, 100 * k + i as u64);
                    d.lo + u * (d.hi - d.lo)
                })
                .collect(),
        );
    }
    sets
}

/// One χ² case: a sampler at an incidence.
struct Case {
    name: String,
    sampler: Sampler,
    wi: (f64, f64),
}

/// The cases of a file: its parameter sets × incidences (× azimuths when anisotropic).
fn file_cases(file: &str, all_sets: bool) -> Vec<Case> {
    let (ks, defaults, decls) = load(file);
    let sets = if all_sets { param_sets(file, &defaults, &decls) } else { vec![defaults] };
    let mut out = vec![];
    for p in sets {
        let s = Sampler::build_channels(&ks, &p, &Options::default()).unwrap_or_else(|e| panic!("{file} {p:?}: {}", e.message));
        let phis: &[f64] = if s.report.isotropic { &[0.0] } else { &[0.0, 45.0] };
        for &t in &[0.0, 30.0, 60.0, 85.0] {
            for &ph in phis {
                out.push(Case { name: format!("{file} {p:?}"), sampler: s.clone(), wi: (t, ph) });
            }
        }
    }
    out
}

/// The cases of [`random_formulas`] at θᵢ = 0°, 30°, 60°, 85°.
fn random_cases(count: usize) -> Vec<Case> {
    let mut out = vec![];
    for (f, s) in random_formulas(count) {
        for &t in &[0.0, 30.0, 60.0, 85.0] {
            out.push(Case { name: format!("random {}", f.to_program_text()), sampler: s.clone(), wi: (t, 0.0) });
        }
    }
    out
}

/// Random formulas of the differential test's generator made BSDF-like (`min(abs(e), 100)`), the first `count`
/// whose sampler builds, with their samplers: the rest are refused for NaN, infinite or negative values, as they
/// should be.
pub(crate) fn random_formulas(count: usize) -> Vec<(lobe::Formula, Sampler)> {
    let mut runner = TestRunner::deterministic();
    let strategy = differential::expr();
    let (mut out, mut tried, mut built) = (vec![], 0, 0);
    while built < count {
        tried += 1;
        assert!(tried < 100 * count, "only {built} of {tried} random formulas gave a sampler");
        let e = strategy.new_tree(&mut runner).unwrap().current();
        let e = E::Call(Builtin::Min, vec![E::Call(Builtin::Abs, vec![e]), E::C(100.0)]);
        let f = differential::formula(&e, false);
        let params = f.default_params();
        let Ok(ks) = std::panic::catch_unwind(|| kernels(f.clone())) else { continue };
        let Ok(s) = Sampler::build_channels(&ks, &params, &Options::default()) else { continue };
        built += 1;
        out.push((f, s));
    }
    out
}

/// Runs every case in parallel at the Šidák-corrected level; panics listing the failures.
fn run_chi2(cases: &[Case]) {
    let alpha = chi2::sidak(ALPHA, cases.len());
    let failures: Vec<String> = cases
        .par_iter()
        .filter_map(|c| {
            let v = validate(&c.sampler, dir(c.wi.0, c.wi.1), SAMPLES, 7).unwrap();
            (!v.chi2.passes(alpha)).then(|| format!("{} at θᵢ {}° φᵢ {}°: {:?}", c.name, c.wi.0, c.wi.1, v.chi2))
        })
        .collect();
    assert!(failures.is_empty(), "{} of {} χ² tests fail at α = {alpha:.3e}:\n{}", failures.len(), cases.len(), failures.join("\n"));
}

/// A few cases of the sweep, every run: a one-cosine lobe, an isotropic and an anisotropic explorer file,
/// default parameters, normal and grazing incidence.
#[test]
fn chi2_subset() {
    let mut cases = vec![];
    for f in ["examples/brdfs/phong.brdf", "examples/explorer/ggx.brdf", "examples/explorer/ward_anisotropic.brdf"] {
        cases.extend(file_cases(f, false).into_iter().filter(|c| c.wi.0 == 0.0 || c.wi.0 == 85.0));
    }
    run_chi2(&cases);
}

/// The whole sweep (module docs; ~9 minutes on 2 cores, run by `.ci/run`). With `LOBE_CHI2_SCOPE=ci` it runs
/// every file at its default parameters and 20 random formulas — about 180 of the 492 tests — at the Šidák
/// level of the tests it runs: a quicker check while working on a sampler.
#[test]
#[ignore = "the full χ² sweep (minutes on 2 cores): .ci/run runs it"]
fn chi2_everywhere() {
    let ci = std::env::var("LOBE_CHI2_SCOPE").is_ok_and(|v| v == "ci");
    let mut cases: Vec<Case> = catalogue().iter().flat_map(|f| file_cases(f, !ci)).collect();
    cases.extend(random_cases(if ci { 20 } else { 50 }));
    eprintln!("χ² sweep: {} tests{}", cases.len(), if ci { " (CI scope)" } else { "" });
    run_chi2(&cases);
}

/// A sampler whose pdf is wrong (the samples of one mixture against the pdf of another) fails the test.
#[test]
fn chi2_rejects_a_mismatched_pdf() {
    let (ks, p, _) = load("examples/brdfs/blinn.brdf");
    let a = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(Mechanism::Tabulated), cosine_fraction: 0.1 }).unwrap();
    let b = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(Mechanism::Tabulated), cosine_fraction: 0.15 }).unwrap();
    let wi = dir(30.0, 0.0);
    let s = sample_seeded(&a, wi, 3, SAMPLES).unwrap();
    let h = chi2::histogram(&s.wo, 101);
    let right = chi2::chi2(&h, &chi2::cell_probabilities(&a.pdf_at(wi).unwrap(), 101, s.wo.len()), s.wo.len());
    let wrong = chi2::chi2(&h, &chi2::cell_probabilities(&b.pdf_at(wi).unwrap(), 101, s.wo.len()), s.wo.len());
    assert!(right.passes(ALPHA), "{right:?}");
    assert!(!wrong.passes(1e-9), "{wrong:?}");
}

/// sample()'s pdf is pdf(wi, wo); its weight is f·cos/pdf from eval; for every mechanism.
#[test]
fn sample_pdf_and_weight_agree_with_pdf_and_eval() {
    for (file, m) in [
        ("examples/brdfs/phong.brdf", Mechanism::Exact),
        ("examples/brdfs/blinn.brdf", Mechanism::Exact),
        ("examples/brdfs/cook_torrance.brdf", Mechanism::Tabulated),
        ("examples/explorer/ward_anisotropic.brdf", Mechanism::Tabulated),
        ("examples/explorer/oren_nayar.brdf", Mechanism::Cosine),
    ] {
        let (ks, p, _) = load(file);
        let s = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(m), ..Options::default() }).unwrap();
        for (t, ph) in [(0.0, 0.0), (40.0, 30.0), (80.0, 200.0)] {
            let wi = dir(t, ph);
            let smp = sample_seeded(&s, wi, 5, 50_000).unwrap();
            let pdf = s.pdf_many(&[wi], &smp.wo).unwrap();
            let f = s.eval_many(&[wi], &smp.wo).unwrap();
            let nch = smp.channels;
            for i in 0..smp.pdf.len() {
                let rel = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
                assert!(rel(smp.pdf[i], pdf[i]), "{file}: pdf {} vs {}", smp.pdf[i], pdf[i]);
                for c in 0..nch {
                    let want = if smp.wo[i][2] > 0.0 { f[i * nch + c] * smp.wo[i][2] / pdf[i] } else { 0.0 };
                    assert!(rel(smp.weight[i * nch + c], want), "{file}: weight {} vs {want}", smp.weight[i * nch + c]);
                    assert!(!smp.weight[i * nch + c].is_nan());
                }
            }
        }
    }
}

/// pdf > 0 wherever f·cos > 0, at 10⁶ random (wi, wo) pairs of the upper hemisphere, on every catalogue file.
#[test]
fn pdf_is_positive_wherever_f_cos_is() {
    catalogue().par_iter().for_each(|file| {
        let (ks, p, _) = load(file);
        let s = Sampler::build_channels(&ks, &p, &Options::default()).unwrap();
        let n = 1_000_000u64 / 23;
        let r = |k: u64| lobe::base::rng::counter_unit(11, k);
        let wis: Vec<V3> = (0..n).map(|i| dir(89.9 * r(4 * i), 360.0 * r(4 * i + 1))).collect();
        let wos: Vec<V3> = (0..n).map(|i| dir(90.0 * r(4 * i + 2).sqrt(), 360.0 * r(4 * i + 3))).collect();
        let pdf = s.pdf_many(&wis, &wos).unwrap();
        let f = s.eval_many(&wis, &wos).unwrap();
        let nch = s.channels();
        for i in 0..n as usize {
            let positive = (0..nch).any(|c| f[i * nch + c] * wos[i][2] > 0.0);
            assert!(!positive || pdf[i] > 0.0, "{file}: pdf {} where f·cos > 0 at wi {:?} wo {:?}", pdf[i], wis[i], wos[i]);
        }
    });
}

/// The Monte-Carlo albedo from 10⁶ samples against the quadrature, at 8 incidences per formula.
fn albedo_agrees(files: &[String]) {
    let failures: Vec<String> = files
        .par_iter()
        .flat_map(|file| {
            let (ks, p, _) = load(file);
            let s = Sampler::build_channels(&ks, &p, &Options::default()).unwrap();
            let mut bad = vec![];
            for t in [0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0, 85.0] {
                let v = validate(&s, dir(t, 0.0), SAMPLES, 13).unwrap();
                let q = lobe::bsdf::validate::albedo_quadrature(&s, t.to_radians(), 0.0).unwrap();
                let d = (v.albedo - q).abs();
                if d > 3.0 * v.albedo_stderr || d > 0.005 * q {
                    bad.push(format!("{file} θᵢ {t}°: MC {} ± {} vs quadrature {q} ({:.2} σ, {:.3} %)", v.albedo, v.albedo_stderr, d / v.albedo_stderr, 100.0 * d / q));
                }
            }
            bad
        })
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn albedo_matches_the_quadrature_on_a_subset() {
    albedo_agrees(&["examples/brdfs/beckmann.brdf".to_string(), "examples/explorer/ggx.brdf".to_string()]);
}

#[test]
#[ignore = "every catalogue and explorer file (minutes on 2 cores): .ci/run runs it"]
fn albedo_matches_the_quadrature_everywhere() {
    albedo_agrees(&catalogue());
}

/// The same seed gives the same samples on 1 and on 2 threads.
#[test]
fn seeded_samples_do_not_depend_on_the_thread_count() {
    let (ks, p, _) = load("examples/explorer/ggx.brdf");
    let s = Sampler::build_channels(&ks, &p, &Options::default()).unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| sample_seeded(&s, dir(45.0, 10.0), 99, 200_000).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert!(a.wo == b.wo && a.pdf == b.pdf && a.weight == b.weight);
    let c = pool_free(&s);
    assert_ne!(a.wo[..10], c.wo[..10]);
}

fn pool_free(s: &Sampler) -> lobe::bsdf::Samples {
    sample_seeded(s, dir(45.0, 10.0), 100, 10).unwrap()
}

fn compile(src: &str) -> Vec<Kernel> {
    kernels(lobe::front::parse("t.brdf", src).unwrap_or_else(|e| panic!("{}", e.render(false))))
}

#[test]
fn bad_directions_are_errors() {
    let ks = compile("NH^20");
    let s = Sampler::build_channels(&ks, &[], &Options::default()).unwrap();
    for (wi, needle) in [
        ([0.0, 0.0, 0.0], "zero vector"),
        ([f64::NAN, 0.0, 1.0], "not finite"),
        ([0.0, f64::INFINITY, 1.0], "not finite"),
        ([1.0, 0.0, 0.0], "not above the horizon"),
        ([0.0, 0.3, -1.0], "not above the horizon"),
    ] {
        let e = s.sample_many(&[wi], &[[0.5, 0.5]]).unwrap_err();
        assert!(e.message.contains(needle), "{wi:?}: {}", e.message);
        assert!(s.pdf_many(&[wi], &[[0.0, 0.0, 1.0]]).is_err());
    }
    assert!(s.pdf_many(&[[0.0, 0.0, 1.0]], &[[0.0, 0.0, 0.0]]).unwrap_err().message.contains("zero vector"));
    // A non-unit wi is normalised: the same samples as the unit one.
    let a = s.sample_many(&[[0.0, 0.0, 3.0]], &[[0.3, 0.7]]).unwrap();
    let b = s.sample_many(&[[0.0, 0.0, 1.0]], &[[0.3, 0.7]]).unwrap();
    assert_eq!(a.wo, b.wo);
}

/// The language clamps a formula's result at 0, so a negative value reaches the sampler only from IR built
/// without that policy (as here, the differential generator's `formula(e, false)`) or from another front end.
#[test]
fn a_negative_formula_is_refused_with_the_point() {
    use lobe::ir::{BinOp, Input};
    let minus_half = |i: Input| kernels(differential::formula(&E::Bin(BinOp::Sub, Box::new(E::In(i, true)), Box::new(E::C(0.5))), false));
    let p = [2.0; 3];
    let e = Sampler::build_channels(&minus_half(Input::NH), &p, &Options::default()).unwrap_err();
    assert!(e.message.contains("negative") && e.message.contains("NH=") && e.message.contains("wi = (θ"), "{}", e.message);
    let e = Sampler::build_channels(&minus_half(Input::VR), &p, &Options { choice: Choice::Force(Mechanism::Exact), ..Options::default() }).unwrap_err();
    assert!(e.message.contains("negative") && e.message.contains("VR = "), "{}", e.message);
}

#[test]
fn a_nan_formula_is_refused_with_the_point() {
    let e = Sampler::build_channels(&compile("sqrt(NV - 0.5)"), &[], &Options::default()).unwrap_err();
    assert!(e.message.contains("NaN") && e.message.contains("NV="), "{}", e.message);
}

/// A formula that is 0 at some incidences: those nodes' tables are empty and reported; samples there come from
/// the cosine part with weight 0, never NaN.
#[test]
fn a_formula_zero_at_some_incidence_gives_weight_zero() {
    let s = Sampler::build_channels(&compile("NL > 0.5 ? NH^20 : 0"), &[], &Options { choice: Choice::Force(Mechanism::Tabulated), ..Options::default() }).unwrap();
    assert!(!s.report.empty_nodes.is_empty());
    assert!(s.report.empty_nodes.iter().all(|&(t, _)| t.cos() <= 0.5 + 1e-12), "{:?}", s.report.empty_nodes);
    let smp = sample_seeded(&s, dir(80.0, 0.0), 1, 10_000).unwrap();
    assert!(smp.weight.iter().all(|&w| w == 0.0));
    assert!(smp.pdf.iter().all(|p| p.is_finite() && *p >= 0.0));
    // At normal incidence the lobe is sampled as usual.
    let v = validate(&s, dir(0.0, 0.0), 200_000, 1).unwrap();
    assert!(v.efficiency > 0.5 && v.albedo > 0.0, "{v:?}");
    // Zero everywhere: the cosine mechanism, every weight 0.
    let z = Sampler::build_channels(&compile("0*NH"), &[], &Options::default()).unwrap();
    assert_eq!(z.report.mechanism, Mechanism::Cosine);
    assert!(sample_seeded(&z, dir(30.0, 0.0), 1, 1000).unwrap().weight.iter().all(|&w| w == 0.0));
}

#[test]
fn exact_is_only_for_one_cosine() {
    let e = Sampler::build_channels(&compile("NH^10 * NL"), &[], &Options { choice: Choice::Force(Mechanism::Exact), ..Options::default() }).unwrap_err();
    assert!(e.message.contains("one cosine"), "{}", e.message);
}

/// `lobe sample` end to end: the summary keys, and the CSV.
#[test]
fn the_command_prints_its_summary_and_writes_csv() {
    let dir = crate::scratch_dir("sample", "cli");
    let csv = dir.join("s.csv");
    let o = crate::cli::lobe(
        &["sample", "examples/brdfs/blinn.brdf", "--set", "n=20", "--incidence", "30", "--count", "20000", "--json", "-o", csv.to_str().unwrap()],
        None,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for k in ["chi2_p", "efficiency", "albedo", "albedo_stderr", "albedo_quadrature", "build_ms", "ns_per_sample", "mechanism"] {
        assert!(!v[k].is_null(), "{k} missing: {v}");
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("ox,oy,oz,pdf,weight"));
    assert_eq!(lines.count(), 20000);
    let o = crate::cli::lobe(&["sample", "examples/brdfs/blinn.brdf", "--incidence", "95", "--count", "10"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("θ must be in [0, 90)"));
    let o = crate::cli::lobe(&["sample", "examples/explorer/principled.brdf", "--incidence", "30,45", "--count", "2000", "-o", dir.join("c.csv").to_str().unwrap()], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read_to_string(dir.join("c.csv")).unwrap().starts_with("ox,oy,oz,pdf,weight_r,weight_g,weight_b\n"));
}

/// The table of BENCHMARKS.md ("Sampling"): per catalogue file, the efficiency of each mechanism it admits at
/// θᵢ = 0°, 30°, 60°, 85° (10⁵ samples each), the automatic choice, its build time (every candidate and the probe)
/// beside the tabulated mechanism's alone, and the thread CPU time per
/// sample() and pdf() call in batches of 4096. `cargo test --release --test it sample::efficiency_table --
/// --ignored --nocapture`.
#[test]
#[ignore = "a measurement for BENCHMARKS.md"]
fn efficiency_table() {
    println!("| file | iso | chosen | build ms (auto / tabulated) | sample ns | pdf ns | tabulated 0/30/60/85° | exact | cosine |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for file in catalogue() {
        let (ks, p, _) = load(&file);
        let auto = Sampler::build_channels(&ks, &p, &Options::default()).unwrap();
        let effs = |m: Mechanism| -> String {
            let Ok(s) = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(m), ..Options::default() }) else { return "—".into() };
            [0.0, 30.0, 60.0, 85.0]
                .iter()
                .map(|&t| {
                    let smp = sample_seeded(&s, dir(t, 0.0), 21, 100_000).unwrap();
                    format!("{:.2}", lobe::bsdf::efficiency((0..smp.pdf.len()).map(|i| smp.luminance(i))))
                })
                .collect::<Vec<_>>()
                .join(" / ")
        };
        let tab = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(Mechanism::Tabulated), ..Options::default() }).unwrap();
        let v = validate(&auto, dir(30.0, 0.0), 1 << 17, 3).unwrap();
        let ns = |x: Option<f64>| x.map(|v| format!("{v:.0}")).unwrap_or_default();
        println!(
            "| {} | {} | {} | {:.1} / {:.1} | {} | {} | {} | {} | {} |",
            file.trim_start_matches("examples/"),
            if auto.report.isotropic { "yes" } else { "no" },
            auto.report.mechanism.name(),
            auto.report.build.as_secs_f64() * 1e3,
            tab.report.build.as_secs_f64() * 1e3,
            ns(v.ns_per_sample),
            ns(v.ns_per_pdf),
            effs(Mechanism::Tabulated),
            effs(Mechanism::Exact),
            effs(Mechanism::Cosine)
        );
    }
}

/// The cosine fraction's measurement (docs/sampling.md): mean efficiency over the catalogue at θᵢ = 0°, 30°, 60°,
/// 85° and the largest luminance weight relative to the albedo, for fractions 0.05, 0.1 and 0.2.
#[test]
#[ignore = "a measurement for docs/sampling.md"]
fn cosine_fraction_measurement() {
    for frac in [0.05, 0.1, 0.2] {
        let (mut eff, mut worst, mut n) = (0.0, 0.0f64, 0);
        for file in catalogue() {
            let (ks, p, _) = load(&file);
            let s = Sampler::build_channels(&ks, &p, &Options { choice: Choice::Force(Mechanism::Tabulated), cosine_fraction: frac }).unwrap();
            for t in [0.0, 30.0, 60.0, 85.0] {
                let smp = sample_seeded(&s, dir(t, 0.0), 21, 100_000).unwrap();
                let w: Vec<f64> = (0..smp.pdf.len()).map(|i| smp.luminance(i)).collect();
                let mean = w.iter().sum::<f64>() / w.len() as f64;
                eff += lobe::bsdf::efficiency(w.iter().copied());
                worst = worst.max(w.iter().cloned().fold(0.0, f64::max) / mean);
                n += 1;
            }
        }
        println!("cosine fraction {frac}: mean efficiency {:.4}, largest weight / mean {:.1}", eff / n as f64, worst);
    }
}

/// `lobe sample` of a measured table (explorer GGX written by `lobe tabulate`): sampled from its lookups, the χ²
/// test passes (α = 0.01), the Monte-Carlo albedo is within 3 standard errors and 0.5 % of the quadrature (the
/// table's midpoint rule), and both within 0.5 % of the formula's; `--set` on a table is refused.
#[test]
fn a_measured_table_samples_from_its_lookups() {
    let dir = crate::scratch_dir("sample", "table");
    let table = dir.join("ggx.binary");
    let t = table.to_str().unwrap();
    let o = crate::cli::lobe(&["tabulate", "examples/explorer/ggx.brdf", "--set", "alpha=0.3,f0=0.5", "-o", t], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = |args: &[&str]| -> serde_json::Value {
        let o = crate::cli::lobe(args, None);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let v = run(&["sample", t, "--incidence", "30", "--count", "200000", "--json"]);
    let f = run(&["sample", "examples/explorer/ggx.brdf", "--set", "alpha=0.3,f0=0.5", "--incidence", "30", "--count", "200000", "--json"]);
    let num = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k}: {v}"));
    assert!(num(&v, "chi2_p") >= 0.01, "{v}");
    assert_eq!(v["mechanism"], "tabulated");
    let (mc, se, quad) = (num(&v, "albedo"), num(&v, "albedo_stderr"), num(&v, "albedo_quadrature"));
    assert!((mc - quad).abs() <= 3.0 * se && (mc / quad - 1.0).abs() <= 0.005, "albedo {mc} ± {se}, quadrature {quad}");
    assert!((quad / num(&f, "albedo_quadrature") - 1.0).abs() <= 0.005, "table {quad}, formula {}", num(&f, "albedo_quadrature"));
    let o = crate::cli::lobe(&["sample", t, "--set", "alpha=0.2", "--incidence", "30"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("has no parameters"), "{}", String::from_utf8_lossy(&o.stderr));
}
