//! The plain simplifier per catalogue formula (every `examples/brdfs/*.brdf`, as shipped): parse and lower once
//! outside the timing, then time `lobe::simplify::simplify` live (no parameter baked) and with `n` baked to 50
//! where the formula declares an `n` that admits it. Hash-consing dominates this time (`simplify` module docs).
//!
//! Run: `cargo bench --bench simplify` (about a minute); `-- --quick` for a rougher, faster pass.

use criterion::{criterion_group, criterion_main, Criterion};
use lobe::Formula;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

/// Every catalogue file, sorted by stem, parsed and lowered.
fn catalogue() -> Vec<(String, Formula)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/brdfs");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("catalogue entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
        .collect();
    paths.sort();
    paths
        .into_iter()
        .map(|p| {
            let stem = p.file_stem().and_then(|s| s.to_str()).expect("utf-8 stem").to_string();
            let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            let f = lobe::front::parse(&p.display().to_string(), &text).unwrap_or_else(|d| panic!("{}", d.render(false)));
            (stem, f)
        })
        .collect()
}

fn bench_simplify(c: &mut Criterion) {
    for (stem, f) in catalogue() {
        let mut g = c.benchmark_group(format!("simplify/{stem}"));
        g.warm_up_time(Duration::from_millis(200)).measurement_time(Duration::from_millis(800)).sample_size(20);
        g.bench_function("live", |b| b.iter(|| lobe::simplify::simplify(black_box(&f), &[]).ir.len()));
        if let Some(n) = f.param_index("n").filter(|&n| f.params[n].admits(50.0)) {
            let bake = [(n, 50.0)];
            g.bench_function("n=50", |b| b.iter(|| lobe::simplify::simplify(black_box(&f), black_box(&bake)).ir.len()));
        }
        g.finish();
    }
}

criterion_group!(benches, bench_simplify);
criterion_main!(benches);
