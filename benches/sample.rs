//! Cost of the samplers per call: `Sampler::sample_many` (a draw, its density and f for the weight),
//! `Sampler::pdf_many` and `Sampler::eval_many` (f alone, what the weight needs), at θᵢ = 30° in batches of
//! 4096 with one wi per batch, on every file of examples/brdfs and examples/explorer at its defaults, precise
//! math, the tier `lobe sample` uses (`auto`: in a build with the LLVM tier, Cranelift first and LLVM from the
//! first batch of 4096 points; `--tier` to choose), each channel through the accuracy pass as `lobe sample`
//! compiles; and each sampler's
//! build time. Each figure is the minimum over interleaved rounds
//! (`--rounds`, default 7) of this thread's CPU time per call. Targets (docs/sampling.md): sample ≤ 100 ns,
//! pdf ≤ 50 ns, build ≤ 20 ms isotropic and ≤ 200 ms anisotropic.
//!
//! Run: `cargo bench [--features llvm] --bench sample [-- --rounds 7] [--mechanism tabulated|exact|cosine]
//! [--tier auto|cranelift|llvm] [FILTER]`.

use lobe::bsdf::{Options as SamplerOptions, Sampler};
use lobe::{Kernel, Options};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

const BATCH: usize = 4096;
const CALLS: usize = 1 << 17;

fn files() -> Vec<PathBuf> {
    let mut v = vec![];
    for dir in ["examples/brdfs", "examples/explorer"] {
        let mut d: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "brdf")).collect();
        d.sort();
        v.extend(d);
    }
    v
}

/// Uniforms from a fixed linear congruential sequence (the bench's inputs, not a statistical source).
fn uniforms(n: usize) -> Vec<[f64; 2]> {
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n).map(|_| [next(), next()]).collect()
}

/// Thread CPU time per call (on a shared machine, time not scheduled is not the code's).
fn per_call(f: impl Fn()) -> f64 {
    let t = cpu_time::ThreadTime::now();
    f();
    t.elapsed().as_secs_f64() * 1e9 / CALLS as f64
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "--bench").collect();
    let rounds = args.iter().position(|a| a == "--rounds").and_then(|i| args.get(i + 1)).and_then(|r| r.parse().ok()).unwrap_or(7usize);
    let mechanism = args.iter().position(|a| a == "--mechanism").and_then(|i| args.get(i + 1)).map(|m| m.parse::<lobe::bsdf::Mechanism>().unwrap());
    let tier = args.iter().position(|a| a == "--tier").and_then(|i| args.get(i + 1)).map_or(lobe::Tier::Auto, |t| t.parse::<lobe::Tier>().unwrap());
    let backend = lobe::resolve_backend(lobe::Backend::Jit, tier).unwrap();
    let filter = args.iter().enumerate().find(|(i, a)| !a.starts_with("--") && (*i == 0 || !["--rounds", "--mechanism", "--tier"].contains(&args[i - 1].as_str()))).map(|(_, a)| a.clone());
    let choice = mechanism.map_or(lobe::bsdf::Choice::Auto, lobe::bsdf::Choice::Force);
    let wi = [30f64.to_radians().sin(), 0.0, 30f64.to_radians().cos()];
    let u = uniforms(CALLS);
    println!("tier {} (backend {backend:?})", tier.name());
    println!("{:<36} {:>10} {:>9} {:>9} {:>9} {:>9}", "file", "mechanism", "build ms", "sample ns", "pdf ns", "eval ns");
    for path in files() {
        let name = path.display().to_string();
        if filter.as_ref().is_some_and(|f| !name.contains(f.as_str())) {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        // As `lobe sample` compiles: each channel through the accuracy pass (its decision cache on).
        let f = lobe::front::parse(&name, &text).unwrap_or_else(|d| panic!("{name}: {d:?}"));
        let opts = lobe::numerics::pass_cache::command_pass(Options { backend, ..Options::default() }, Default::default(), true);
        let kernels: Vec<Kernel> = f.channels().into_iter().map(|c| lobe::compile_formula(c, &opts).unwrap_or_else(|d| panic!("{name}: {d:?}"))).collect();
        let params = kernels[0].formula.default_params();
        let mut build = f64::INFINITY;
        let mut s = None;
        for _ in 0..3 {
            let t = Instant::now();
            s = Some(Sampler::build_channels(&kernels, &params, &SamplerOptions { choice, ..SamplerOptions::default() }).unwrap());
            build = build.min(t.elapsed().as_secs_f64() * 1e3);
        }
        let s = s.unwrap();
        let wos: Vec<[f64; 3]> = u.chunks(BATCH).flat_map(|b| s.sample_many(&[wi], b).unwrap().wo).collect();
        let (mut ts, mut tp, mut te) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
        for _ in 0..rounds {
            ts = ts.min(per_call(|| {
                for b in u.chunks(BATCH) {
                    black_box(s.sample_many(&[wi], b).unwrap());
                }
            }));
            tp = tp.min(per_call(|| {
                for b in wos.chunks(BATCH) {
                    black_box(s.pdf_many(&[wi], b).unwrap());
                }
            }));
            te = te.min(per_call(|| {
                for b in wos.chunks(BATCH) {
                    black_box(s.eval_many(&[wi], b).unwrap());
                }
            }));
        }
        println!("{:<36} {:>10} {:>9.1} {:>9.1} {:>9.1} {:>9.1}", name, s.report.mechanism.name(), build, ts, tp, te);
    }
}
