//! Compile time per benched catalogue formula (`common/formulas.rs`; the file `examples/brdfs/<stem>.brdf` as
//! shipped, comments and metadata included): JIT code generation alone (both kernels, uncached), the whole
//! pipeline (parse → simplify → JIT) with the cache disabled, and a cache hit.
//!
//! Run: `cargo bench --bench compile`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use lobe::{Backend, Options};
use std::hint::black_box;
use std::time::Duration;

fn bench_compile(c: &mut Criterion) {
    for e in common::BENCHED {
        let k = e.kernel(Backend::Jit);
        let (file, text) = (e.path().display().to_string(), e.source());
        let mut g = c.benchmark_group(format!("compile/{}", e.id));
        g.warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1)).sample_size(30);
        g.bench_function("jit_codegen", |b| {
            b.iter(|| lobe::backend::jit::jit_kernel_uncached(black_box(&k.formula), lobe::Mode::Precise).map(|k| k.nodes()))
        });
        let opts = Options { backend: Backend::Jit, ..Options::default() };
        let old = lobe::backend::jit::set_cache_capacity(0);
        g.bench_function("pipeline_uncached", |b| b.iter(|| lobe::compile_source(&file, black_box(&text), &opts).is_ok()));
        lobe::backend::jit::set_cache_capacity(old);
        g.bench_function("pipeline_cache_hit", |b| b.iter(|| lobe::compile_source(&file, black_box(&text), &opts).is_ok()));
        g.finish();
    }
}

criterion_group!(benches, bench_compile);
criterion_main!(benches);
