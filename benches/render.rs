//! Renderer throughput: the papers' sphere (`examples/scenes/paper_sphere.toml`, its catalogue material
//! JIT-compiled and evaluated in batches, as `lobe render examples/scenes/paper_sphere.toml --size 1024
//! --stats` does) at 512², 1024² and 4096², and thread scaling at 1024².
//!
//! Run: `cargo bench --bench render`. Targets (2 cores): 1024² ≤ 40 ms, 4096² ≤ 0.6 s.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use lobe::render::scene::{self, LoadOptions, LobeCompiler};
use lobe::render::{self, RenderOptions};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

fn paper(size: usize) -> render::Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/paper_sphere.toml");
    let opts = LoadOptions { size: Some((size, size)), ..LoadOptions::default() };
    scene::load_scene(&path, &opts, &LobeCompiler { backend: lobe::Backend::Jit }).unwrap_or_else(|d| panic!("{}", d.render(false)))
}

fn sizes(c: &mut Criterion) {
    let mut g = c.benchmark_group("paper_sphere");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    for size in [512, 1024, 4096] {
        let s = paper(size);
        g.throughput(criterion::Throughput::Elements((size * size) as u64));
        g.bench_with_input(BenchmarkId::from_parameter(size), &s, |b, s| {
            b.iter(|| black_box(render::render(s, &RenderOptions::default()).map(|r| r.1.evals)))
        });
    }
    g.finish();
}

fn threads(c: &mut Criterion) {
    let mut g = c.benchmark_group("paper_sphere_1024_threads");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    let s = paper(1024);
    for t in [1, 2, 4] {
        g.bench_with_input(BenchmarkId::from_parameter(t), &t, |b, &t| {
            b.iter(|| black_box(render::render(&s, &RenderOptions { threads: t, ..RenderOptions::default() }).map(|r| r.1.evals)))
        });
    }
    g.finish();
}

criterion_group!(benches, sizes, threads);
criterion_main!(benches);
