//! ns per evaluation for each benched catalogue formula (`common/formulas.rs`; the file
//! `examples/brdfs/<stem>.brdf` compiled as shipped, at its default parameters): its hand-written Rust twin
//! (direct and behind the `Evaluator` interface), scalar and batched JIT in both math modes (`_fast`:
//! `--math fast`), a Rust loop over the same columns (ns per element), the interpreter, and fasteval — how far a compiled kernel is from hand-written
//! code and from a generic expression evaluator. Every contestant evaluates the same 1024 pseudo-random
//! points per iteration; criterion reports time per element (`Throughput::Elements`).
//!
//! Run: `cargo bench --bench eval` (or `-- schlick` for one formula).

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use lobe::{Backend, Columns, Evaluator, N_INPUTS};
use std::hint::black_box;
use std::time::Duration;

const POINTS: usize = 1024;

fn bench_eval(c: &mut Criterion) {
    let rows = lobe::report::measure::sample_points(POINTS, 0x5EED);
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| rows.iter().map(|r| r[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut out = vec![0.0; POINTS];

    for e in common::BENCHED {
        let jit = e.kernel(Backend::Jit);
        let jit_fast = e.kernel_in(Backend::Jit, lobe::Mode::Fast);
        let interp = e.kernel(Backend::Interp);
        let twin_k = e.twin_kernel(&jit);
        let defaults = jit.default_params();
        let params = defaults.as_slice();
        let twin = e.twin();
        let mut g = c.benchmark_group(format!("eval/{}", e.id));
        g.throughput(Throughput::Elements(POINTS as u64));
        g.warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1)).sample_size(20);

        g.bench_function("rust_direct", |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for r in &rows {
                    acc += twin(black_box(r), black_box(params));
                }
                acc
            })
        });
        let scalar = |ev: &dyn Evaluator| {
            let mut acc = 0.0;
            for r in &rows {
                acc += ev.eval(black_box(r), black_box(params));
            }
            acc
        };
        g.bench_function("rust_evaluator", |b| b.iter(|| scalar(&twin_k)));
        g.bench_function("jit_scalar", |b| b.iter(|| scalar(&jit)));
        g.bench_function("jit_scalar_fast", |b| b.iter(|| scalar(&jit_fast)));
        g.bench_function("interp", |b| b.iter(|| scalar(&interp)));
        g.bench_function("rust_loop", |b| {
            b.iter(|| {
                let cs = black_box(&columns);
                for (i, o) in out.iter_mut().enumerate() {
                    let x = lobe::from_cosines([cs.cols[0][i], cs.cols[1][i], cs.cols[2][i], cs.cols[3][i], cs.cols[4][i]]);
                    *o = twin(&x, params);
                }
                black_box(&out);
            })
        });
        for (name, k) in [("jit_batched", &jit), ("jit_batched_fast", &jit_fast)] {
            g.bench_function(name, |b| {
                b.iter(|| {
                    k.eval_batch(black_box(&columns), black_box(params), &mut out);
                    black_box(&out);
                })
            });
        }

        // fasteval: compiled expression, variables through a callback namespace.
        use fasteval::Evaler;
        let (slab, compiled) = e.fasteval().unwrap_or_else(|err| panic!("fasteval cannot parse {}: {err}", e.stem));
        g.bench_function("fasteval", |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for r in &rows {
                    let mut ns = |name: &str, _: Vec<f64>| common::formulas::fasteval_var(name, r, &jit, params);
                    acc += compiled.eval(&slab, &mut ns).unwrap_or(f64::NAN);
                }
                acc
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench_eval);
criterion_main!(benches);
