//! Sampling (`lobe::bsdf`): scratch measurement.
use lobe::bsdf::{chi2, Options, Sampler};
use lobe::frame::V3;
use lobe::{Kernel};

pub(crate) fn load(path: &str) -> (Vec<Kernel>, Vec<f64>, Vec<lobe::ir::ParamDecl>) {
    let src = std::fs::read_to_string(path).unwrap();
    let f = lobe::front::parse(path, &src).unwrap_or_else(|e| panic!("{}", e.render(false)));
    let params = f.default_params();
    let decls = f.params.clone();
    let ks = f.channels().into_iter().map(|c| lobe::compile_formula(c, &lobe::Options::default()).unwrap()).collect();
    (ks, params, decls)
}

fn dir(t: f64, p: f64) -> V3 {
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

#[test]
#[ignore]
fn scratch_measure() {
    let mut files: Vec<_> = std::fs::read_dir("examples/brdfs").unwrap().chain(std::fs::read_dir("examples/explorer").unwrap()).map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "brdf")).collect();
    files.sort();
    for p in files {
        let (ks, params, _) = load(p.to_str().unwrap());
        let s = match Sampler::build_channels(&ks, &params, &Options::default()) {
            Ok(s) => s,
            Err(e) => { println!("{}: build error {}", p.display(), e.message); continue; }
        };
        let mut line = format!("{:40} {:10} iso={} build {:6.1} ms cands {:?}", p.display(), s.report.mechanism.name(), s.report.isotropic, s.report.build.as_secs_f64()*1e3, s.report.candidates);
        for deg in [0.0f64, 30.0, 60.0, 85.0] {
            let wi = dir(deg.to_radians(), 0.0);
            let n = 1_000_000u64;
            let u: Vec<[f64;2]> = (0..n).map(|i| [lobe::base::rng::counter_unit(9, 2*i), lobe::base::rng::counter_unit(9, 2*i+1)]).collect();
            let t = std::time::Instant::now();
            let smp = s.sample_many(&[wi], &u).unwrap();
            let ns = t.elapsed().as_secs_f64()*1e9/n as f64;
            let h = chi2::histogram(&smp.wo, 101);
            let t = std::time::Instant::now();
            let probs = chi2::cell_probabilities(&|wo| s.pdf_many(&[wi], &[wo]).unwrap()[0], 101, n as usize);
            let qt = t.elapsed().as_secs_f64();
            let c = chi2::chi2(&h, &probs, n as usize);
            let eff = lobe::bsdf::efficiency((0..smp.pdf.len()).map(|i| smp.luminance(i)));
            line += &format!(" | {deg}: p={:.3e} eff={:.3} {:.0}ns q{:.1}s", c.p_value, eff, ns, qt);
        }
        println!("{line}");
    }
}

#[test]
#[ignore]
fn scratch_costs() {
    for p in ["examples/brdfs/blinn.brdf", "examples/explorer/ggx.brdf", "examples/explorer/ward_anisotropic.brdf"] {
        let (ks, params, _) = load(p);
        let s = Sampler::build_channels(&ks, &params, &Options::default()).unwrap();
        let wi = dir(0.5, 0.2);
        let n = 200_000u64;
        let u: Vec<[f64;2]> = (0..n).map(|i| [lobe::base::rng::counter_unit(9, 2*i), lobe::base::rng::counter_unit(9, 2*i+1)]).collect();
        let t = std::time::Instant::now();
        let smp = s.sample_many(&[wi], &u).unwrap();
        let ns = t.elapsed().as_secs_f64()*1e9/n as f64;
        let f = s.pdf_at(wi).unwrap();
        let t = std::time::Instant::now();
        let mut acc = 0.0;
        for w in &smp.wo { acc += f(*w); }
        let np = t.elapsed().as_secs_f64()*1e9/n as f64;
        let t = std::time::Instant::now();
        let v = s.eval_many(&[wi], &smp.wo).unwrap();
        let ne = t.elapsed().as_secs_f64()*1e9/n as f64;
        println!("{p}: build {:.1} ms sample {ns:.0} ns pdf {np:.0} ns eval {ne:.0} ns {acc} {}", s.report.build.as_secs_f64()*1e3, v.len());
    }
}
