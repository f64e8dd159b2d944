//! JIT-specific behaviour: live parameters, the cache, memory release, length validation, diagnostics.

use lobe::builtins::Builtin;
use lobe::base::span::Span;
use lobe::backend::interp::Interp;
use lobe::ir::{BinOp, Formula, Input, Ir, Meta, NodeId, ParamDecl, ParamKind};
use lobe::backend::jit;
use lobe::{Backend, Columns, Evaluator};
use std::sync::Arc;

const S: Span = Span { start: 0, end: 0 };

fn param(name: &str, default: f64) -> ParamDecl {
    ParamDecl { name: name.into(), default, lo: 0.0, hi: 1e6, span: None, kind: ParamKind::Float }
}

fn formula(ir: Ir, root: NodeId, params: Vec<ParamDecl>) -> Formula {
    Formula { meta: Meta::default(), params, ir, root, file: "test.brdf".into(), source: String::new(), rgb: None }
}

/// The lowering's domain policy: clamp(INPUT, 0, 1).
fn clamped(ir: &mut Ir, i: Input) -> NodeId {
    let x = ir.input(i, S);
    let z = ir.konst(0.0, S);
    let o = ir.konst(1.0, S);
    ir.call(Builtin::Clamp, &[x, z, o], S)
}

/// max(pow(clamp(NH), n), 0) — Blinn as the lowering produces it.
fn blinn() -> Formula {
    let mut ir = Ir::new();
    let nh = clamped(&mut ir, Input::NH);
    let n = ir.param(0, S);
    let p = ir.call(Builtin::Pow, &[nh, n], S);
    let z = ir.konst(0.0, S);
    let root = ir.call(Builtin::Max, &[p, z], S);
    formula(ir, root, vec![param("n", 50.0)])
}

/// 2*c / (1.25*(n - n*c + 1.25*c)^2) with c = NH, the square written as a product.
fn modified_schlick(k: f64) -> Formula {
    let mut ir = Ir::new();
    let c = clamped(&mut ir, Input::NH);
    let n = ir.param(0, S);
    let two = ir.konst(2.0, S);
    let q = ir.konst(k, S);
    let num = ir.bin(BinOp::Mul, two, c, S);
    let nc = ir.bin(BinOp::Mul, n, c, S);
    let qc = ir.bin(BinOp::Mul, q, c, S);
    let a = ir.bin(BinOp::Sub, n, nc, S);
    let a = ir.bin(BinOp::Add, a, qc, S);
    let sq = ir.bin(BinOp::Mul, a, a, S);
    let den = ir.bin(BinOp::Mul, q, sq, S);
    let root = ir.bin(BinOp::Div, num, den, S);
    formula(ir, root, vec![param("n", 50.0)])
}

#[test]
fn scalar_matches_interpreter_and_closed_form() {
    let f = blinn();
    let k = jit::jit_kernel(&f, lobe::Mode::Precise).expect("compiles");
    let i = Interp::new(&f);
    for &(nh, n) in &[(0.9, 2.0), (0.5, 50.0), (1.0, 1000.0), (0.0, 1.0), (1.5, 3.0), (-0.2, 2.0)] {
        let x = lobe::from_cosines([0.0, 0.0, nh, 0.0, 0.0]);
        let want = f64::clamp(nh, 0.0, 1.0).powf(n);
        assert_eq!(k.eval(&x, &[n]).to_bits(), want.to_bits(), "NH={nh} n={n}");
        assert_eq!(k.eval(&x, &[n]).to_bits(), i.eval(&x, &[n]).to_bits());
    }
}

#[test]
fn live_parameter_change_needs_no_recompile() {
    let f = modified_schlick(1.25);
    let k = jit::jit_kernel_uncached(&f, lobe::Mode::Precise).expect("compiles");
    let x = lobe::from_cosines([0.0, 0.0, 0.8, 0.0, 0.0]);
    let closed = |n: f64| 2.0 * 0.8 / (1.25 * (n - n * 0.8 + 1.25 * 0.8) * (n - n * 0.8 + 1.25 * 0.8));
    let a = k.eval(&x, &[10.0]);
    let b = k.eval(&x, &[100.0]);
    assert_ne!(a, b);
    assert_eq!(a, closed(10.0));
    assert_eq!(b, closed(100.0));
    // Same compiled code object answered both (no recompilation happened in between).
    let (_, misses_before, _) = jit::cache_stats();
    let _ = k.eval(&x, &[5.0]);
    assert_eq!(jit::cache_stats().1, misses_before);
}

#[test]
fn batched_matches_scalar_for_every_length() {
    let f = modified_schlick(1.25);
    let k = jit::jit_kernel(&f, lobe::Mode::Precise).expect("compiles");
    for len in [0usize, 1, 2, 3, 7, 8, 1000, 1001] {
        let nh: Vec<f64> = (0..len).map(|i| i as f64 / (len.max(2) - 1) as f64).collect();
        let cols = Columns::new(std::array::from_fn(|k| if k == 2 { nh.as_slice() } else { &[] }));
        let mut out = vec![f64::NAN; len];
        k.eval_batch(&cols, &[37.0], &mut out);
        for (j, o) in out.iter().enumerate() {
            let s = k.eval(&lobe::from_cosines([0.0, 0.0, nh[j], 0.0, 0.0]), &[37.0]);
            assert_eq!(o.to_bits(), s.to_bits(), "len {len} element {j}");
        }
    }
}

#[test]
fn short_params_and_ragged_columns_follow_interpreter_semantics() {
    let f = blinn();
    let k = jit::jit_kernel(&f, lobe::Mode::Precise).expect("compiles");
    let i = Interp::new(&f);
    // Missing parameter: NaN, not an out-of-bounds read.
    assert!(k.eval(&lobe::from_cosines([0.0, 0.0, 0.5, 0.0, 0.0]), &[]).is_nan());
    // A column shorter than the output: missing elements read as 0, like the interpreter.
    let nh = [0.5, 0.25];
    let cols = Columns::new(std::array::from_fn(|k| if k == 2 { nh.as_slice() } else { &[] }));
    let (mut a, mut b) = (vec![0.0; 4], vec![0.0; 4]);
    k.eval_batch(&cols, &[2.0], &mut a);
    i.eval_batch(&cols, &[2.0], &mut b);
    assert_eq!(a, b);
    assert_eq!(a, vec![0.25, 0.0625, 0.0, 0.0]);
    let mut c = vec![0.0; 4];
    k.eval_batch(&cols, &[], &mut c);
    assert!(c.iter().all(|v| v.is_nan()));
}

#[test]
fn cache_returns_the_same_code_for_the_same_structure() {
    let a = jit::jit_kernel(&modified_schlick(1.375), lobe::Mode::Precise).expect("compiles");
    let mut other = modified_schlick(1.375);
    other.file = "elsewhere.brdf".into();
    let b = jit::jit_kernel(&other, lobe::Mode::Precise).expect("compiles");
    assert!(a.same_code(&b));
    assert!(b.cached);
    let c = jit::jit_kernel(&modified_schlick(1.5), lobe::Mode::Precise).expect("compiles");
    assert!(!a.same_code(&c));
}

#[test]
fn build_kernel_uses_the_jit() {
    let k = lobe::build_kernel(Arc::new(blinn()), Backend::Jit, lobe::Mode::Precise).expect("builds");
    assert_eq!(k.backend, Backend::Jit);
    let x = lobe::from_cosines([0.0, 0.0, 0.5, 0.0, 0.0]);
    assert_eq!(k.eval(&x, &[3.0]), 0.125);
}

fn statm_resident_pages() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    s.split_whitespace().nth(1)?.parse().ok()
}

/// Distinct formulas (a different constant each) compiled without the cache and dropped: resident memory must
/// stay flat. Without `free_memory` each module leaks its code pages (measured with the scalar kernel only:
/// +4 KiB per compile, 2000 compiles → +2003 pages; with it: +3 pages); the bound is 1 KiB per compile to leave room for allocator
/// noise. 10 000 compiles in release, 2000 in debug builds (the verifier makes each compile slower).
#[test]
fn jit_memory_is_freed_on_drop() {
    // RSS is process-wide and the other tests of this binary run in parallel, so measure in a child process
    // that runs only `memory_child` (ignored in normal runs).
    let exe = std::env::current_exe().expect("test binary path");
    let out = std::process::Command::new(exe)
        .args(["--ignored", "--exact", "jit::memory_child", "--nocapture", "--test-threads=1"])
        .output()
        .expect("child runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "memory child failed:\n{text}");
    assert!(text.contains("1 passed"), "memory child did not run:\n{text}");
}

#[test]
#[ignore = "run by jit_memory_is_freed_on_drop in a child process"]
fn memory_child() {
    let Some(_) = statm_resident_pages() else { return };
    let run = |range: std::ops::Range<u32>| {
        for i in range {
            let k = jit::jit_kernel_uncached(&modified_schlick(1.0 + f64::from(i) * 1e-6), lobe::Mode::Precise).expect("compiles");
            std::hint::black_box(k.eval(&lobe::from_cosines([0.0, 0.0, 0.5, 0.0, 0.0]), &[50.0]));
            // Also build the lazily compiled batched kernel, whose code lives in the same module.
            let nh = [0.1, 0.2, 0.3];
            let mut out = [0.0; 3];
            k.eval_batch(&Columns::new(std::array::from_fn(|k| if k == 2 { nh.as_slice() } else { &[] })), &[50.0], &mut out);
            std::hint::black_box(out);
        }
    };
    run(0..200); // warm up allocator and thread-local contexts
    let before = statm_resident_pages().unwrap_or(0);
    let n = if cfg!(debug_assertions) { 2_000 } else { 10_000 };
    run(200..200 + n);
    let after = statm_resident_pages().unwrap_or(0);
    let page_kb = 4;
    let grown_kb = after.saturating_sub(before) * page_kb;
    eprintln!("RSS {before} -> {after} pages over {n} compiles");
    let bound_kb = n as u64;
    assert!(grown_kb < bound_kb, "RSS grew by {grown_kb} KiB over {n} compiles (bound {bound_kb} KiB)");
}

/// Every nasty input in tests/corpus through `lobe::compile_source` with both backends, then evaluation on a few
/// points (scalar and batched): errors are fine, panics are not. Runs on a thread with an 8 MiB stack (the
/// CLI's main-thread size), so a front end that recurses per nesting level is held to that budget.
#[test]
fn corpus_inputs_never_panic() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus");
    let mut files: Vec<_> =
        std::fs::read_dir(&dir).expect("tests/corpus exists").filter_map(|e| e.ok()).map(|e| e.path()).collect();
    files.sort();
    assert!(files.len() >= 20, "corpus has {} files", files.len());
    let worker = std::thread::Builder::new().stack_size(8 << 20).spawn(move || {
        let pts = [[0.0; lobe::N_INPUTS], [1.0; lobe::N_INPUTS], lobe::from_cosines([0.5, 1e-8, 1.0, 0.0, 0.3]), lobe::from_cosines([2.0, -1.0, f64::NAN, f64::INFINITY, 0.5])];
        for path in files {
            let bytes = std::fs::read(&path).expect("readable");
            let src = String::from_utf8_lossy(&bytes);
            let name = path.display().to_string();
            for backend in [Backend::Jit, Backend::Interp] {
                let opts = lobe::Options { backend, ..Default::default() };
                match lobe::compile_source(&name, &src, &opts) {
                    Ok(k) => {
                        let p = k.default_params();
                        for x in &pts {
                            std::hint::black_box(k.eval(x, &p));
                            std::hint::black_box(k.eval(x, &[]));
                        }
                        let col: Vec<f64> = pts.iter().map(|x| x[2]).collect();
                        let mut out = vec![0.0; col.len()];
                        k.eval_batch(&Columns::new([&col; lobe::N_INPUTS]), &p, &mut out);
                    }
                    Err(d) => {
                        // The diagnostics must render (codespan can panic on a bad span).
                        assert!(!d.render(false).is_empty(), "{name}: empty diagnostic");
                    }
                }
            }
        }
    });
    let joined = worker.expect("spawn").join();
    assert!(joined.is_ok(), "a corpus input panicked");
}

/// Odd shapes the front end can produce: a constant formula, a bare parameter, a long chain, a far parameter
/// index, and a NaN constant — scalar and batched agree with the interpreter bit for bit.
#[test]
fn unusual_shapes_compile_and_agree() {
    let mut shapes = vec![];
    // constant
    let mut ir = Ir::new();
    let r = ir.konst(0.25, S);
    shapes.push(formula(ir, r, vec![param("n", 1.0)]));
    // bare parameter, with a far index (offset 8 * 999)
    let mut ir = Ir::new();
    let r = ir.param(999, S);
    shapes.push(formula(ir, r, (0..1000).map(|i| param(&format!("p{i}"), i as f64)).collect()));
    // NaN constant through max
    let mut ir = Ir::new();
    let a = ir.konst(f64::NAN, S);
    let b = clamped(&mut ir, Input::VH);
    let r = ir.call(Builtin::Max, &[a, b], S);
    shapes.push(formula(ir, r, vec![]));
    // a 5000-node chain mixing every input and a libm call every 100 nodes
    let mut ir = Ir::new();
    let mut acc = clamped(&mut ir, Input::NL);
    for k in 0..5000u32 {
        let x = clamped(&mut ir, Input::ALL[k as usize % 5]);
        let c = ir.konst(1.0 + f64::from(k) * 1e-7, S);
        let t = ir.bin(BinOp::Mul, x, c, S);
        acc = ir.bin(if k % 2 == 0 { BinOp::Add } else { BinOp::Sub }, acc, t, S);
        if k % 100 == 99 {
            acc = ir.call(Builtin::Sin, &[acc], S);
        }
    }
    shapes.push(formula(ir, acc, vec![]));

    let pts: Vec<[f64; lobe::N_INPUTS]> = lobe::report::measure::sample_points(9, 3);
    let cols: Vec<Vec<f64>> = (0..lobe::N_INPUTS).map(|i| pts.iter().map(|p| p[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    for f in shapes {
        let params = f.default_params();
        let k = jit::jit_kernel(&f, lobe::Mode::Precise).expect("compiles");
        let i = Interp::new(&f);
        let mut out = vec![0.0; pts.len()];
        k.eval_batch(&columns, &params, &mut out);
        for (j, x) in pts.iter().enumerate() {
            let want = i.eval(x, &params);
            let same = |a: f64| a.to_bits() == want.to_bits() || (a.is_nan() && want.is_nan());
            assert!(same(k.eval(x, &params)), "scalar {} vs {want}", k.eval(x, &params));
            assert!(same(out[j]), "batched {} vs {want}", out[j]);
        }
    }
}

/// The scalar kernel of an arithmetic formula is straight-line register code: no stack slots, no spills, no
/// calls (clamp/max are inline instructions).
#[test]
fn scalar_arithmetic_kernel_has_no_stack_traffic_or_calls() {
    let (scalar, batch) = jit::disassemble(&modified_schlick(1.25), lobe::Mode::Precise).expect("compiles");
    assert!(!scalar.is_empty() && !batch.is_empty());
    for bad in ["rsp", "call"] {
        let hits: Vec<&str> = scalar.lines().filter(|l| l.contains(bad) && !l.contains("rbp")).collect();
        assert!(hits.is_empty(), "scalar kernel mentions `{bad}`:\n{scalar}");
    }
    // The batched loop works on two lanes, and clamp against constants is one packed max and one packed min
    // (not the general NaN-fixing sequence with `cmpunordpd`).
    assert!(batch.contains("divpd") && batch.contains("maxpd") && batch.contains("minpd"), "{batch}");
    assert!(!batch.contains("cmpunordpd"), "general min/max sequence in the loop:\n{batch}");
}

/// `measure_kernel` runs all three paths and reports sane (finite, positive, ordered) statistics.
#[test]
fn measure_kernel_reports_all_paths() {
    let k = lobe::build_kernel(Arc::new(modified_schlick(1.25)), Backend::Jit, lobe::Mode::Precise).expect("builds");
    let opts = lobe::report::measure::MeasureOptions { points: 64, samples: 5 };
    let m = lobe::report::measure::measure_kernel(&k, &[50.0], opts).expect("measures");
    for t in [m.scalar_jit, m.batched_jit, m.interp] {
        assert!(t.min_ns > 0.0 && t.min_ns.is_finite(), "{t:?}");
        assert!(t.min_ns <= t.p25_ns && t.p25_ns <= t.median_ns && t.median_ns <= t.p75_ns, "{t:?}");
    }
    assert!(m.compile.as_nanos() > 0);
    assert!(m.speedup_vs_interp().is_finite());
}
