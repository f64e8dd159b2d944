//! Cost of one exact normalisation coefficient (`numerics::energy::normalization_coef`), the feature the
//! integrator bakes into kernels (`normalize = true`), and of whole reports (accuracy, full-mode energy,
//! stability sweep). Target: ≤ 1 ms for one coefficient.
//!
//! Evaluators: the hand-written Rust twins of `lobe::numerics::twins` (what a compiled kernel approaches)
//! and the reference interpreter on the catalogue's Blinn (`examples/brdfs/blinn.brdf`, the slowest
//! backend).
//!
//! Run: `cargo bench --bench energy`.

use criterion::{criterion_group, criterion_main, Criterion};
use lobe::numerics::energy::{lobe_integral, normalization_coef};
use lobe::numerics::twins;
use lobe::ir::Input;
use lobe::{Backend, Evaluator, Kernel, Options};
use std::hint::black_box;

/// `examples/brdfs/blinn.brdf` on the interpreter.
fn blinn_interp() -> Kernel {
    let opts = Options { backend: Backend::Interp, ..Options::default() };
    lobe::compile_source("examples/brdfs/blinn.brdf", include_str!("../examples/brdfs/blinn.brdf"), &opts)
        .unwrap_or_else(|d| panic!("{}", d.render(false)))
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("normalization_coef");
    for (t, p) in [
        (twins::phong(), vec![1000.0]),
        (twins::modified_schlick(), vec![50.0]),
        (twins::f_st(), vec![1000.0, 268.0]),
        (twins::kutlog(), vec![100.0, 1.0, 0.5]),
    ] {
        let lobe = if t.name == "Phong" { Input::VR } else { Input::NH };
        let evals = lobe_integral(t.ev.as_ref(), &p, lobe).map(|r| r.evals).unwrap_or(0);
        g.bench_function(format!("{} n={} ({evals} evals)", t.name, p[0]), |b| {
            b.iter(|| normalization_coef(black_box(t.ev.as_ref()), black_box(&p), lobe))
        });
    }
    let blinn = blinn_interp();
    let interp: &dyn Evaluator = blinn.evaluator().as_ref();
    for n in [50.0, 1000.0] {
        g.bench_function(format!("interp Blinn n={n}"), |b| b.iter(|| normalization_coef(black_box(interp), black_box(&[n]), Input::NH)));
    }
    g.finish();
}

criterion_group!(benches, bench);

/// Whole-report costs (accuracy over the 91×1000 grid + fine grid, full-mode albedo, stability sweep).
fn checks(c: &mut Criterion) {
    use lobe::numerics::accuracy::{accuracy, AccuracyOptions};
    use lobe::numerics::energy::full_energy;
    use lobe::numerics::sweep::{sweep, SweepOptions};
    let mut g = c.benchmark_group("checks");
    g.sample_size(10);
    let ms = twins::modified_schlick();
    let b = twins::blinn();
    let blinn = blinn_interp();
    let interp: &dyn Evaluator = blinn.evaluator().as_ref();
    let opts = AccuracyOptions::default();
    g.bench_function("accuracy modified Schlick vs Blinn (twins)", |bch| {
        bch.iter(|| accuracy(ms.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &opts))
    });
    g.bench_function("accuracy twin Schlick vs interp Blinn", |bch| {
        bch.iter(|| accuracy(ms.ev.as_ref(), &[1.0], Input::NH, interp, &[1.0], Input::NH, &opts))
    });
    let ph = twins::phong();
    g.bench_function("full energy Phong n=50 (91 angles + reciprocity)", |bch| bch.iter(|| full_energy(ph.ev.as_ref(), &[50.0])));
    let f = &blinn.formula;
    g.bench_function("sweep interp Blinn", |bch| bch.iter(|| sweep(interp, f.used_inputs(), &f.params, &SweepOptions::default())));
    g.finish();
}

criterion_group!(check_benches, checks);
criterion_main!(benches, check_benches);
