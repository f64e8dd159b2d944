//! Compile time per catalogue formula: JIT code generation alone (both kernels, uncached), the whole pipeline
//! (parse → simplify → JIT) with the cache disabled, and a cache hit.
//!
//! Run: `cargo bench --bench compile`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use lobe::{Backend, Options};
use std::hint::black_box;
use std::time::Duration;

fn bench_compile(c: &mut Criterion) {
    for e in common::catalogue() {
        let (k, from_text) = e.kernel(Backend::Jit);
        let mut g = c.benchmark_group(format!("compile/{}", e.name));
        g.warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1)).sample_size(30);
        g.bench_function("jit_codegen", |b| {
            b.iter(|| lobe::backend::jit::jit_kernel_uncached(black_box(&k.formula)).map(|k| k.nodes()))
        });
        if from_text {
            let opts = Options { backend: Backend::Jit, ..Options::default() };
            let old = lobe::backend::jit::set_cache_capacity(0);
            g.bench_function("pipeline_uncached", |b| {
                b.iter(|| lobe::compile_source(e.name, black_box(e.text), &opts).is_ok())
            });
            lobe::backend::jit::set_cache_capacity(old);
            g.bench_function("pipeline_cache_hit", |b| {
                b.iter(|| lobe::compile_source(e.name, black_box(e.text), &opts).is_ok())
            });
        } else {
            eprintln!("note: {}: front end not available, only code generation is timed", e.name);
        }
        g.finish();
    }
}

criterion_group!(benches, bench_compile);
criterion_main!(benches);
