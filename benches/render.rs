//! Renderer throughput and the split of a frame's cost (raster, shading, kernel, encode).
//!
//! First, a table measured in one run (`split`): the papers' sphere (`examples/scenes/paper_sphere.toml`,
//! modified Schlick (VR), 13 % of the frame) at 4096², and the frame-filling scenes (`examples/scenes/fill_*.toml`:
//! the sphere at a 20° field of view, ~80 % of the frame, three lights; modified Schlick, Cook–Torrance,
//! F_kutlog, and an OBJ mesh) at 2048², each rendered single-threaded with the JIT and with the interpreter,
//! alternating, best of `LOBE_SPLIT_ROUNDS` (default 5) per column — shading CPU time per visible pixel, the
//! part of it outside the kernel (geometry and colour), the kernel's time per evaluation inside the render, and
//! the same batched kernel on its own (4096-element batches). Then criterion timings of whole renders.
//!
//! Run: `cargo bench --bench render`. Targets (2 cores): 1024² ≤ 40 ms, 4096² ≤ 0.6 s.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use lobe::backend::{Columns, Evaluator};
use lobe::render::scene::{self, LoadOptions, LobeCompiler};
use lobe::render::{self, RenderOptions, RenderStats};
use lobe::{Backend, N_INPUTS};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn load(file: &str, size: usize, backend: Backend) -> render::Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/scenes").join(file);
    let opts = LoadOptions { size: Some((size, size)), ..LoadOptions::default() };
    scene::load_scene(&path, &opts, &LobeCompiler::plain(backend, lobe::Mode::Precise)).unwrap_or_else(|d| panic!("{}", d.render(false)))
}

/// The batched kernel on its own: ns per element over 4096-element batches of cosines in (0, 1].
fn batch_ns(ev: &dyn Evaluator, params: &[f64]) -> f64 {
    const N: usize = 4096;
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|_| Vec::with_capacity(N)).collect();
    for _ in 0..N {
        for c in &mut cols {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            c.push(0.05 + 0.95 * (seed >> 11) as f64 / (1u64 << 53) as f64);
        }
    }
    let columns = Columns::new(std::array::from_fn(|k| cols[k].as_slice()));
    let mut out = vec![0.0; N];
    let mut best = f64::INFINITY;
    for _ in 0..30 {
        let t = Instant::now();
        ev.eval_batch(&columns, params, &mut out);
        best = best.min(t.elapsed().as_nanos() as f64 / N as f64);
        black_box(&out);
    }
    best
}

#[derive(Default, Clone, Copy, Debug)]
struct Best {
    shade: f64,
    geometry: f64,
    kernel: f64,
    raster_ms: f64,
    encode_ms: f64,
}

fn best_of(acc: &mut Option<Best>, st: &RenderStats, encode: Duration) {
    let b = acc.get_or_insert(Best { shade: f64::INFINITY, geometry: f64::INFINITY, kernel: f64::INFINITY, raster_ms: f64::INFINITY, encode_ms: f64::INFINITY });
    b.shade = b.shade.min(st.shade_ns_per_px());
    b.geometry = b.geometry.min(st.geometry_ns_per_px());
    b.kernel = b.kernel.min(st.kernel_ns_per_eval());
    b.raster_ms = b.raster_ms.min(st.raster_cpu.as_secs_f64() * 1e3);
    b.encode_ms = b.encode_ms.min(encode.as_secs_f64() * 1e3);
}

fn split() {
    let rounds: usize = std::env::var("LOBE_SPLIT_ROUNDS").ok().and_then(|s| s.parse().ok()).unwrap_or(5);
    let only = std::env::var("LOBE_SPLIT_ONLY").unwrap_or_default();
    let program = RenderOptions { threads: 1, ..RenderOptions::default() };
    println!("render split, 1 thread, best of {rounds} alternating renders (ns per visible pixel; kernel ns per evaluation)");
    println!("  program: the compiled shading program (JIT) and the same program interpreted. prog = the program's own share.");
    println!(
        "{:<20} {:>5} {:>8} {:>8} {:>8} {:>7} {:>8} {:>8} {:>7} {:>7} {:>7}",
        "scene", "size", "visible", "jit prg", "int prg", "int/jit", "prog", "batch", "jit/bat", "raster", "encode"
    );
    for (file, size) in [
        ("paper_sphere.toml", 4096),
        ("fill_schlick.toml", 2048),
        ("fill_cook_torrance.toml", 2048),
        ("fill_kutlog.toml", 2048),
        ("fill_mesh.toml", 2048),
    ] {
        if !file.contains(only.as_str()) {
            continue;
        }
        let scenes = [load(file, size, Backend::Jit), load(file, size, Backend::Interp)];
        // JIT program, interpreted program.
        let runs = [(0, &program), (1, &program)];
        let mut best: [Option<Best>; 2] = [None; 2];
        let mut visible = 0;
        for _ in 0..rounds {
            for ((k, o), b) in runs.iter().zip(&mut best) {
                let (frame, st) = render::render(&scenes[*k], o).expect("render");
                let t = Instant::now();
                black_box(frame.image.encode_png().expect("png"));
                best_of(b, &st, t.elapsed());
                visible = st.visible_pixels;
            }
        }
        let [jp, ip] = best.map(|b| b.unwrap_or_default());
        let m = &scenes[0].materials[0];
        let batch = batch_ns(m.evaluator.as_ref(), &m.params);
        println!(
            "{:<20} {:>5} {:>8} {:>8.1} {:>8.1} {:>6.1}× {:>8.1} {:>8.2} {:>6.1}× {:>5.1}ms {:>5.1}ms",
            file.trim_end_matches(".toml"),
            size,
            visible,
            jp.shade,
            ip.shade,
            ip.shade / jp.shade,
            jp.shade - jp.geometry,
            batch,
            jp.shade / batch,
            jp.raster_ms,
            jp.encode_ms
        );
    }
}

fn sizes(c: &mut Criterion) {
    split();
    let mut g = c.benchmark_group("paper_sphere");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    for size in [512, 1024, 4096] {
        let s = load("paper_sphere.toml", size, Backend::Jit);
        g.throughput(criterion::Throughput::Elements((size * size) as u64));
        g.bench_with_input(BenchmarkId::from_parameter(size), &s, |b, s| {
            b.iter(|| black_box(render::render(s, &RenderOptions::default()).map(|r| r.1.evals)))
        });
    }
    g.finish();
}

fn fill(c: &mut Criterion) {
    let mut g = c.benchmark_group("fill_1024");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for file in ["fill_schlick", "fill_cook_torrance", "fill_kutlog", "fill_mesh"] {
        for backend in [Backend::Jit, Backend::Interp] {
            let s = load(&format!("{file}.toml"), 1024, backend);
            g.bench_with_input(BenchmarkId::new(file, backend.name()), &s, |b, s| {
                b.iter(|| black_box(render::render(s, &RenderOptions::default()).map(|r| r.1.evals)))
            });
        }
    }
    g.finish();
}

fn threads(c: &mut Criterion) {
    let mut g = c.benchmark_group("paper_sphere_1024_threads");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    let s = load("paper_sphere.toml", 1024, Backend::Jit);
    for t in [1, 2, 4] {
        g.bench_with_input(BenchmarkId::from_parameter(t), &t, |b, &t| {
            b.iter(|| black_box(render::render(&s, &RenderOptions { threads: t, ..RenderOptions::default() }).map(|r| r.1.evals)))
        });
    }
    g.finish();
}

criterion_group!(benches, sizes, fill, threads);
criterion_main!(benches);
