//! The LLVM tier (cargo feature `llvm`): a simplified [`Formula`] → kernels and multi-output programs compiled
//! by LLVM 19 (through inkwell), the batch loop 8 `f64` lanes per step where the host has 256-bit vectors or
//! wider (one AVX-512 register, or two AVX2 ones), 2 otherwise.
//!
//! Same IR, same math, same bits as the interpreter and the Cranelift tier ([`crate::backend::jit`]): only the
//! primitives are this tier's. The generator ([`codegen`]) implements the math library's `Emit` and the native
//! layer's `Lower`, so the node dispatch, the inline builtins and every builtin are the code both tiers share
//! ([`crate::backend::native::lower`]); the plan (parameter-only work in a prepared block, computed by a
//! prepare function), the rule for calling the library instead of inlining it, the four function signatures,
//! the safe wrappers that call them ([`NativeKernel`], [`ShadeCode`]), the caches and the errors are the
//! native layer's. The module is optimised with LLVM's `default<O2>` pipeline; no instruction carries
//! fast-math flags and none is `llvm.fmuladd`, so nothing is reassociated, contracted into an FMA or replaced
//! by an estimate (the tests read the machine code to check).
//!
//! A kernel's module holds the scalar function (one lane), the batched loop and the prepare function, compiled
//! at once; kernels are compiled on every call of [`llvm_kernel`] (the `auto` tier asks for them for big
//! work), programs through an in-process cache.
//!
//! Ownership: one [`Code`] per compiled module holds the LLVM context and the MCJIT execution engine that owns
//! the machine code; dropping it frees both. `unsafe` here: turning the engine's addresses into the native
//! layer's function-pointer types, and the lifetime and `Send`/`Sync` of [`Code`] (each with its `# Safety`
//! note); calling the code is [`crate::backend::native::abi`]'s.

// Owning generated code and turning its addresses into function pointers (each block has its `# Safety` note).
#![allow(unsafe_code)]

mod codegen;

use super::native::abi::{BatchFn, KernelCode, NativeCode, PrepareFn, ProgramFn, ScalarFn, Shape};
use super::native::cache::{Cache, Key};
use super::native::plan::program_outlines;
use super::native::{outlines, NativeError, NativeKernel, Plan, ShadeCode};
use super::program::Program;
use super::Backend;
use crate::builtins::Mode;
use crate::ir::{Formula, Ir, NodeId};
use inkwell::context::Context;
use inkwell::execution_engine::ExecutionEngine;
use inkwell::passes::PassBuilderOptions;
use inkwell::targets::{CodeModel, FileType, InitializationConfig, RelocMode, Target, TargetMachine};
use inkwell::OptimizationLevel;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

/// The host as LLVM sees it.
#[derive(Clone, Debug)]
pub struct Host {
    /// LLVM's name of the host CPU (`znver4`, `skylake-avx512`, …).
    pub cpu: String,
    /// Its feature string (`+avx2,+fma,…`), given to every function.
    pub features: String,
    /// `f64` lanes of the batch loop: 8 with AVX-512 or AVX2, 2 otherwise.
    pub lanes: u32,
    /// A native fused multiply-add.
    pub fma: bool,
    /// AVX-512 (`+avx512f`): tables of up to 16 rows (exp's, sin's quadrants) are looked up by register
    /// permutation instead of gathers.
    pub avx512: bool,
}

/// The host, detected once (and LLVM's native target initialised).
pub fn host() -> Result<&'static Host, NativeError> {
    static HOST: OnceLock<Result<Host, String>> = OnceLock::new();
    HOST.get_or_init(|| {
        Target::initialize_native(&InitializationConfig::default())?;
        let cpu = TargetMachine::get_host_cpu_name().to_string();
        let features = TargetMachine::get_host_cpu_features().to_string();
        let has = |f: &str| features.split(',').any(|x| x == f);
        // With AVX2 a step is two 4-lane registers, which LLVM interleaves: the two independent halves hide the
        // latency of the divider and of the math library's FMA chains (1.1–1.5× faster than one register per
        // step on the transcendental catalogue formulas on Zen 3; BENCHMARKS.md §15).
        let avx512 = has("+avx512f");
        let lanes = if avx512 || has("+avx2") { 8 } else { 2 };
        let fma = has("+fma") || cfg!(target_arch = "aarch64");
        Ok(Host { cpu, features, lanes, fma, avx512 })
    })
    .as_ref()
    .map_err(|e| NativeError::Host(e.clone()))
}

/// Whether the LLVM tier can compile for this host (what the `auto` tier asks).
pub fn available() -> bool {
    host().is_ok()
}

/// A target machine for the host (the optimiser's cost model, and the listing in tests).
fn target_machine(h: &Host) -> Result<TargetMachine, NativeError> {
    let triple = TargetMachine::get_default_triple();
    let target = Target::from_triple(&triple).map_err(|e| NativeError::Host(e.to_string()))?;
    target
        .create_target_machine(&triple, &h.cpu, &h.features, OptimizationLevel::Aggressive, RelocMode::Default, CodeModel::JITDefault)
        .ok_or_else(|| NativeError::Host(format!("LLVM has no target machine for {}", h.cpu)))
}

/// One compiled module's LLVM context and execution engine (which owns the module and its machine code).
/// Dropping it frees the code, then the context (fields drop in declaration order).
///
/// Function pointers into the engine's memory are handed out only to the struct that holds this `Code`.
pub(crate) struct Code {
    _engine: ExecutionEngine<'static>,
    _context: Context,
}

// Safety: after `compile_module` returns, nothing reads or changes the engine or the context: they are only
// kept to be dropped, which takes `&mut self` (so never concurrently with anything). The generated code they
// own is pure (it reads its arguments, writes its output) and may run on any thread at once.
unsafe impl Send for Code {}
// Safety: as above, `&Code` gives access to nothing.
unsafe impl Sync for Code {}

/// A kernel's code: the batched loop compiled with the scalar function, and what owns both.
struct KernelEngine {
    batch: BatchFn,
    _code: Code,
}

// Safety: `batch` is `lobe_batch` of the module `_code` owns (codegen::build_batch: `BatchFn`'s signature,
// reading `len` elements of the used inputs' columns by full or masked loads, the parameters and the block,
// writing `len` elements of `out`), valid while `_code` lives.
unsafe impl KernelCode for KernelEngine {
    fn batch(&self) -> Result<BatchFn, NativeError> {
        Ok(self.batch)
    }
}

/// The function-pointer types are exactly the C signatures `codegen` declares.
fn address(engine: &ExecutionEngine, name: &str) -> Result<usize, NativeError> {
    match engine.get_function_address(name) {
        Ok(0) | Err(_) => Err(NativeError::Internal(format!("no address for {name}"))),
        Ok(a) => Ok(a),
    }
}

/// What one compile produced besides the code (for reports and tests).
pub struct Stats {
    pub lanes: u32,
    pub compile_time: Duration,
    /// The optimised module's machine code, when asked for.
    pub listing: Option<String>,
}

/// A module compiled and loaded: what owns its code, the addresses of the functions `build` named and of the
/// prepare function (when something is carried), and the compile's statistics.
struct Loaded {
    code: Code,
    main: Vec<usize>,
    prepare: Option<usize>,
    stats: Stats,
}

/// Builds one module over `ir` with `plan` (the prepare function when something is carried, then `build`'s
/// functions, whose names it returns), optimises it with `default<O2>` and loads it.
fn compile_module(ir: &Ir, plan: &Plan, mode: Mode, outline: bool, lanes: u32, listing: bool, build: impl FnOnce(&codegen::Unit) -> Result<Vec<&'static str>, NativeError>) -> Result<Loaded, NativeError> {
    if !lanes.is_power_of_two() || lanes > 16 {
        return Err(NativeError::Internal(format!("{lanes} lanes")));
    }
    let t = Instant::now();
    let h = host()?;
    let tm = target_machine(h)?;
    let context = Context::create();
    let module = context.create_module("lobe");
    module.set_triple(&tm.get_triple());
    module.set_data_layout(&tm.get_target_data().get_data_layout());
    let u = codegen::Unit { cx: &context, module: &module, ir, plan, mode, fma: h.fma, avx512: h.avx512, outline, cpu: &h.cpu, features: &h.features };
    if !plan.carried.is_empty() {
        codegen::build_prepare(&u)?;
    }
    let names = build(&u)?;
    module.verify().map_err(|e| NativeError::Internal(format!("LLVM rejected the module: {e}")))?;
    module.run_passes("default<O2>", &tm, PassBuilderOptions::create()).map_err(|e| NativeError::Module(e.to_string()))?;
    let listing = if listing {
        let buf = tm.write_to_memory_buffer(&module, FileType::Assembly).map_err(|e| NativeError::Module(e.to_string()))?;
        Some(String::from_utf8_lossy(buf.as_slice()).into_owned())
    } else {
        None
    };
    let engine = module.create_jit_execution_engine(OptimizationLevel::Aggressive).map_err(|e| NativeError::Module(e.to_string()))?;
    let main = names.iter().map(|n| address(&engine, n)).collect::<Result<Vec<_>, _>>()?;
    let prepare = if plan.carried.is_empty() { None } else { Some(address(&engine, codegen::PREPARE)?) };
    // The module is owned by the engine from here on; dropping the handle only releases its share.
    drop(module);
    // Safety: the engine borrows `context` only in its type (inkwell's lifetime ties it to the context's
    // borrow); `Code` keeps both and drops the engine first, so the context outlives every use of the engine.
    let engine = unsafe { std::mem::transmute::<ExecutionEngine<'_>, ExecutionEngine<'static>>(engine) };
    Ok(Loaded { code: Code { _engine: engine, _context: context }, main, prepare, stats: Stats { lanes, compile_time: t.elapsed(), listing } })
}

/// Compiles a compacted IR (root last) to a kernel whose batch loop has `lanes` lanes.
fn compile(ir: &Ir, root: NodeId, mode: Mode, lanes: u32, listing: bool) -> Result<(NativeCode, Stats), NativeError> {
    if root.index() >= ir.len() {
        return Err(NativeError::internal("root outside the arena"));
    }
    let plan = Plan::new(ir, root);
    let l = compile_module(ir, &plan, mode, outlines(ir), lanes, listing, |u| {
        codegen::build_scalar(u)?;
        codegen::build_batch(u, lanes)?;
        Ok(vec![codegen::SCALAR, codegen::BATCH])
    })?;
    let [scalar, batch] = l.main[..] else { return Err(NativeError::internal("a kernel module has two entries")) };
    // Safety: each address is the entry of a function `codegen` just defined from `ir` and `plan` with exactly
    // the C signature of the type it becomes; it stays valid while `l.code` (the engine that owns the machine
    // code) lives, which the returned `NativeCode` owns.
    let code = unsafe {
        let (scalar, batch) = (std::mem::transmute::<usize, ScalarFn>(scalar), std::mem::transmute::<usize, BatchFn>(batch));
        let prepare = l.prepare.map(|p| std::mem::transmute::<usize, PrepareFn>(p));
        NativeCode::new(scalar, prepare, Shape::of(ir, &plan), (Backend::Llvm, lanes), l.stats.compile_time, Box::new(KernelEngine { batch, _code: l.code }))
    };
    Ok((code, l.stats))
}

/// The compiled programs, by the IR's structure (the host's lanes).
static PROGRAMS: Cache<ShadeCode> = Cache::new();

/// Compiles a multi-output program ([`crate::backend::program`]) in the host's lanes, through an in-process
/// cache keyed as the Cranelift tier's (the IR's structure, its roots, the math mode).
pub(crate) fn program_code(p: &Program, mode: Mode) -> Result<Arc<ShadeCode>, NativeError> {
    let lanes = host()?.lanes;
    PROGRAMS.get_or_compile(Key::of_program(p, mode), || program_uncached(p, mode, lanes)).map(|(c, _)| c)
}

/// [`program_code`] without the cache, in `lanes` lanes.
pub(crate) fn program_uncached(p: &Program, mode: Mode, lanes: u32) -> Result<ShadeCode, NativeError> {
    let plan = Plan::of_program(p)?;
    let l = compile_module(&p.ir, &plan, mode, program_outlines(p), lanes, false, |u| codegen::build_program(u, lanes, p).map(|()| vec![codegen::PROGRAM]))?;
    let [run] = l.main[..] else { return Err(NativeError::internal("a program module has one entry")) };
    // Safety: `codegen::build_program` and `build_prepare` defined these functions with exactly the C
    // signatures of `ProgramFn` and `PrepareFn`; the loop reads at most `p.columns` columns, the parameters
    // the program reads and the block's `carried.len()` slots, and writes every output, `len` elements each
    // (masked on the last partial vector); the prepare function writes exactly the block. The addresses stay
    // valid while `l.code` lives, which the `ShadeCode` owns.
    unsafe {
        let run = std::mem::transmute::<usize, ProgramFn>(run);
        let prepare = l.prepare.map(|q| std::mem::transmute::<usize, PrepareFn>(q));
        Ok(ShadeCode::new(run, prepare, p, &plan, Backend::Llvm, l.stats.compile_time, Box::new(l.code)))
    }
}

/// Compiles a simplified formula with the host's lane count.
pub fn llvm_kernel(f: &Formula, mode: Mode) -> Result<NativeKernel, NativeError> {
    llvm_kernel_with_lanes(f, mode, host()?.lanes)
}

/// Compiles a simplified formula with `lanes` lanes (a power of two ≤ 16; LLVM splits a vector wider than the
/// host's registers), for tests of every lane shape on one host.
pub fn llvm_kernel_with_lanes(f: &Formula, mode: Mode, lanes: u32) -> Result<NativeKernel, NativeError> {
    let (ir, root) = f.ir.compact(f.root);
    let (code, _) = compile(&ir, root, mode, lanes, false)?;
    Ok(NativeKernel::new(Arc::new(code), f.params.len(), false))
}

/// The machine code LLVM emits for `f`'s kernel (host lanes), for checking what it compiles to.
pub fn assembly(f: &Formula, mode: Mode) -> Result<String, NativeError> {
    let (ir, root) = f.ir.compact(f.root);
    let (_, stats) = compile(&ir, root, mode, host()?.lanes, true)?;
    Ok(stats.listing.unwrap_or_default())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::{Columns, Evaluator};
    use crate::ir::N_INPUTS;

    fn formula(src: &str) -> Formula {
        let f = crate::front::parse("t.brdf", src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        crate::simplify::simplify(&f, &[])
    }

    #[test]
    fn host_lanes_follow_the_features() {
        let h = host().expect("LLVM knows the host");
        assert!([2, 4, 8].contains(&h.lanes), "{h:?}");
        if h.features.contains("+avx512f") {
            assert_eq!(h.lanes, 8);
        }
    }

    /// `a·b + c` stays a multiply and an add (LLVM contracts only `llvm.fmuladd` or `contract` flags, and
    /// there are none); an explicit `fma` is one fused operation; no reciprocal or square-root estimate.
    #[test]
    fn no_contraction_no_estimates() {
        // Inputs are clamped to [0, 1]: a = b = 1 − 2^-30, c = −(1 − 2^-29); a·b + c is 0 unfused, 2^-60 fused.
        let f = formula("param c = -1 in -2..2\nNL * NV + c");
        let k = llvm_kernel(&f, Mode::Precise).expect("compiles");
        let (a, c) = (1.0 - 2f64.powi(-30), -(1.0 - 2f64.powi(-29)));
        assert_eq!(a * a + c, 0.0, "the unfused result");
        assert_eq!(a.mul_add(a, c), 2f64.powi(-60), "the fused result");
        let n = 13;
        let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| vec![if i < 2 { a } else { 0.0 }; n]).collect();
        let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
        let mut out = vec![1.0; n];
        // Parameters in declaration order: `n` (every formula has it), then `c`.
        k.eval_batch(&columns, &[1.0, c], &mut out);
        assert!(out.iter().all(|o| o.to_bits() == 0), "{out:?}");
        let asm = assembly(&f, Mode::Precise).expect("listing");
        assert!(!asm.contains("fmadd") && !asm.contains("fmla"), "contracted:\n{asm}");
        let fused = assembly(&formula("fma(NL, NV, NH)"), Mode::Precise).expect("listing");
        if host().expect("host").fma && cfg!(target_arch = "x86_64") {
            assert!(fused.contains("vfmadd"), "no fma:\n{fused}");
        }
        let divs = assembly(&formula("1 / NL + 1 / sqrt(NV)"), Mode::Fast).expect("listing");
        for estimate in ["rcp", "rsqrt", "frecpe", "frsqrte"] {
            assert!(!divs.contains(estimate), "{estimate}:\n{divs}");
        }
        let pow = assembly(&formula("param n = 20 in 1..100\npow(NH, n) * exp(NL) / acos(NV)"), Mode::Precise).expect("listing");
        assert!(!pow.contains("rcp") && !pow.contains("rsqrt"), "estimate in the library's code");
        // exp's 16-row table: permutations of registers in eight AVX-512 lanes, no gather (pow's ln table,
        // 64 rows, still gathers).
        let exp = assembly(&formula("exp(-50 * NH)"), Mode::Precise).expect("listing");
        if host().expect("host").avx512 {
            assert!(exp.contains("vpermi2pd") || exp.contains("vpermt2pd"), "no permutation:\n{exp}");
            assert!(!exp.contains("gather"), "a gather:\n{exp}");
        }
    }

    #[test]
    fn bad_root_is_an_error_not_a_panic() {
        let ir = Ir::new();
        let e = compile(&ir, NodeId(3), Mode::Precise, 4, false).err().map(|e| e.to_string());
        assert_eq!(e.as_deref(), Some("internal JIT error: root outside the arena"));
    }

    /// Every length from 0 to 3·lanes + 1 (full vectors, a partial one, none), every lane shape.
    #[test]
    fn every_length_and_lane_shape_matches_the_interpreter() {
        let f = formula("param n = 20 in 1..100\npow(NH, n) * (n + 2) / (8 * pi) + sin(VH * 40)");
        let interp = crate::backend::interp::Interp::with_mode(&f, Mode::Precise);
        for lanes in [2, 4, 8, 16] {
            let k = llvm_kernel_with_lanes(&f, Mode::Precise, lanes).expect("compiles");
            for len in 0..=(3 * lanes as usize + 1) {
                let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|c| (0..len).map(|i| ((i * 7 + c * 3) % 11) as f64 / 10.0).collect()).collect();
                let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
                let mut out = vec![f64::NAN; len + 1];
                let last = out[len];
                k.eval_batch(&columns, &[37.0], &mut out[..len]);
                assert!(out[len].is_nan() && last.is_nan(), "wrote past the end");
                for (i, o) in out[..len].iter().enumerate() {
                    let x: [f64; N_INPUTS] = std::array::from_fn(|c| cols[c][i]);
                    let want = interp.eval(&x, &[37.0]);
                    assert_eq!(o.to_bits(), want.to_bits(), "lanes {lanes}, len {len}, element {i}");
                    assert_eq!(k.eval(&x, &[37.0]).to_bits(), want.to_bits());
                }
            }
        }
    }

    /// A program with two guarded regions (one of them reading a parameter-only value, both transcendental),
    /// at every lane shape and every length from 0 to 3·lanes + 1: the interpreter's bits in every output, and
    /// nothing written past `len`.
    #[test]
    fn programs_match_the_interpreter_at_every_length_and_lane_shape() {
        use crate::backend::interp::ProgramInterp;
        use crate::base::span::Span;
        use crate::builtins::Builtin;
        use crate::ir::BinOp;
        let s = Span::default();
        let mut ir = Ir::new();
        let (x, y) = (ir.column(0, s), ir.column(1, s));
        let (zero, half) = (ir.konst(0.0, s), ir.konst(0.5, s));
        let n = ir.param(0, s);
        let lit1 = ir.call(Builtin::Lt, &[zero, x], s);
        let p1 = ir.call(Builtin::Pow, &[x, n], s);
        let s1 = ir.call(Builtin::Sin, &[y], s);
        let f1 = ir.bin(BinOp::Mul, p1, s1, s);
        let g1 = ir.call(Builtin::Select, &[lit1, f1, zero], s);
        let lit2 = ir.call(Builtin::Lt, &[y, half], s);
        let xy = ir.bin(BinOp::Mul, x, y, s);
        let e = ir.call(Builtin::Exp, &[xy], s);
        let a = ir.call(Builtin::Acos, &[y], s);
        let n2 = ir.bin(BinOp::Mul, n, n, s);
        let f2 = ir.bin(BinOp::Add, e, a, s);
        let f2 = ir.bin(BinOp::Mul, f2, n2, s);
        let g2 = ir.call(Builtin::Select, &[lit2, f2, zero], s);
        let sum = ir.bin(BinOp::Add, x, y, s);
        let o1 = ir.bin(BinOp::Add, sum, g1, s);
        let o2 = ir.bin(BinOp::Sub, g2, g1, s);
        let p = Program::new(&ir, &[o1, o2, lit2], &[(lit1, vec![g1]), (lit2, vec![g2])], 1).expect("a program");
        assert_eq!(p.regions.len(), 2, "both regions are guarded");
        let interp = ProgramInterp::new(&p, Mode::Precise);
        let params = [2.5];
        for lanes in [2, 4, 8, 16] {
            let c = program_uncached(&p, Mode::Precise, lanes).expect("compiles");
            let block = c.prepare(&params);
            for len in 0..=(3 * lanes as usize + 1) {
                let cols: Vec<Vec<f64>> = (0..2).map(|k| (0..len).map(|i| ((i * 7 + k * 5) % 13) as f64 / 6.0 - 1.0).collect()).collect();
                let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
                let mut want = vec![vec![f64::NAN; len]; 3];
                let mut got = vec![vec![f64::NAN; len + 1]; 3];
                {
                    let mut w: Vec<&mut [f64]> = want.iter_mut().map(|v| v.as_mut_slice()).collect();
                    interp.run(&refs, &params, &mut w, len);
                    let mut g: Vec<&mut [f64]> = got.iter_mut().map(|v| v.as_mut_slice()).collect();
                    c.run(&refs, &params, &block, &mut g, len).expect("runs");
                }
                for (o, (w, g)) in want.iter().zip(&got).enumerate() {
                    assert!(g[len].is_nan(), "lanes {lanes}, len {len}: output {o} written past the end");
                    for (i, (a, b)) in w.iter().zip(g).enumerate() {
                        assert_eq!(a.to_bits(), b.to_bits(), "lanes {lanes}, len {len}, output {o}, element {i}");
                    }
                }
            }
        }
    }
}
