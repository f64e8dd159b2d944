//! Two backends, one truth: the JIT (scalar and batched) against the reference interpreter.
//!
//! (a) random well-formed formulas (proptest over expression trees lowered into `ir::Ir`: inputs raw and
//!     clamped, live and baked parameters, special constants, every builtin, trees up to depth 7) on random
//!     and hard inputs; (b) the catalogue: every `examples/brdfs/*.brdf` through `lobe::compile_source`, and
//!     where a hand-written Rust twin exists (`lobe::numerics::twins`), the twin as a third opinion.
//!
//! Both math modes. Agreement between backends: the same bits (or both NaN) — the JIT emits the math library's
//! code the interpreter runs, and Cranelift neither reassociates nor fuses floating-point operations. Against
//! the Rust twins (which call libm): within 4 ulp, or both NaN, or the same infinity.
//!
//! With the cargo feature `llvm`, every check runs on a third tier: the LLVM kernel (`Backend::Llvm`, the
//! host's lanes), the same bits again; the catalogue also at every lane shape (2, 4, 8) and through the accuracy
//! pass's chosen form, on the files of `examples/explorer` too. Point counts are odd (19, 75), so every batch
//! ends in a partial vector.

use lobe::builtins::Builtin;
use lobe::base::span::Span;
use lobe::ir::{BinOp, Formula, Input, Ir, Meta, NodeId, ParamDecl, ParamKind, N_INPUTS};
use lobe::{compile_formula, Backend, Columns, Evaluator, Kernel, Mode, Options};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};

const S: Span = Span { start: 0, end: 0 };

/// Distance in units in the last place (0 for +0 vs −0).
pub(crate) fn ulps(a: f64, b: f64) -> u64 {
    let key = |x: f64| {
        let b = x.to_bits() as i64;
        if b < 0 {
            i64::MIN.wrapping_sub(b)
        } else {
            b
        }
    };
    key(a).abs_diff(key(b))
}

/// The agreement rule of the task: ≤ 4 ulp, both NaN, or the same infinity (shared with the fuzz test).
pub(crate) fn agree(a: f64, b: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    if a.is_infinite() || b.is_infinite() {
        return a == b;
    }
    ulps(a, b) <= 4
}

#[test]
fn agreement_rule_is_strict_enough() {
    let one = 1.0f64;
    assert!(agree(one, f64::from_bits(one.to_bits() + 4)));
    assert!(!agree(one, f64::from_bits(one.to_bits() + 5)));
    assert!(agree(0.0, -0.0));
    assert!(agree(f64::NAN, -f64::NAN));
    assert!(!agree(f64::NAN, 1.0));
    assert!(!agree(f64::INFINITY, f64::NEG_INFINITY));
    assert!(!agree(f64::MAX, f64::INFINITY));
}

/// An expression tree, lowered into the hash-consed IR (which shares equal subtrees).
#[derive(Clone, Debug)]
pub(crate) enum E {
    C(f64),
    /// An input, clamped to [0, 1] as the lowering does, or raw (to reach NaN/inf paths through builtins).
    In(Input, bool),
    P(u16),
    Neg(Box<E>),
    Bin(BinOp, Box<E>, Box<E>),
    Call(Builtin, Vec<E>),
}

impl E {
    fn lower(&self, ir: &mut Ir) -> NodeId {
        match self {
            E::C(v) => ir.konst(*v, S),
            E::In(i, clamp) => {
                let x = ir.input(*i, S);
                if *clamp {
                    let (z, o) = (ir.konst(0.0, S), ir.konst(1.0, S));
                    ir.call(Builtin::Clamp, &[x, z, o], S)
                } else {
                    x
                }
            }
            E::P(p) => ir.param(*p, S),
            E::Neg(a) => {
                let a = a.lower(ir);
                ir.neg(a, S)
            }
            E::Bin(op, a, b) => {
                let (a, b) = (a.lower(ir), b.lower(ir));
                ir.bin(*op, a, b, S)
            }
            E::Call(f, args) => {
                let ids: Vec<NodeId> = args.iter().take(f.arity()).map(|a| a.lower(ir)).collect();
                ir.call(*f, &ids, S)
            }
        }
    }
}

const N_PARAMS: u16 = 3;

fn params() -> Vec<ParamDecl> {
    ["n", "a", "m"]
        .iter()
        .map(|n| ParamDecl { name: (*n).into(), default: 2.0, lo: -f64::MAX, hi: f64::MAX, span: None, kind: ParamKind::Float })
        .collect()
}

/// A formula as the lowering would give it: the root is `max(raw, 0)` when `policy` is set.
pub(crate) fn formula(e: &E, policy: bool) -> Formula {
    let mut ir = Ir::new();
    let mut root = e.lower(&mut ir);
    if policy {
        let z = ir.konst(0.0, S);
        root = ir.call(Builtin::Max, &[root, z], S);
    }
    Formula { meta: Meta::default(), params: params(), ir, root, file: "random.brdf".into(), source: String::new(), rgb: None }
}

const SPECIAL: [f64; 19] = [
    0.0,
    -0.0,
    1.0,
    0.5,
    2.0,
    -1.0,
    1.25,
    3.0,
    1e300,
    -1e300,
    1e-300,
    5e-324,
    f64::MAX,
    std::f64::consts::PI,
    1.0 + f64::EPSILON,
    1.0 - f64::EPSILON / 2.0,
    f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
];

fn leaf() -> impl Strategy<Value = E> {
    prop_oneof![
        3 => prop::sample::select(SPECIAL.to_vec()).prop_map(E::C),
        1 => (-10.0..10.0f64).prop_map(E::C),
        5 => (prop::sample::select(Input::ALL.to_vec()), prop::bool::weighted(0.8)).prop_map(|(i, c)| E::In(i, c)),
        3 => (0..N_PARAMS).prop_map(E::P),
    ]
}

pub(crate) fn expr() -> impl Strategy<Value = E> {
    leaf().prop_recursive(7, 40, 3, |inner| {
        prop_oneof![
            1 => inner.clone().prop_map(|a| E::Neg(Box::new(a))),
            4 => (
                prop::sample::select(vec![BinOp::Add, BinOp::Sub, BinOp::Mul, BinOp::Div]),
                inner.clone(),
                inner.clone()
            )
                .prop_map(|(op, a, b)| E::Bin(op, Box::new(a), Box::new(b))),
            3 => (prop::sample::select(Builtin::ALL.to_vec()), prop::collection::vec(inner, 3))
                .prop_map(|(f, args)| E::Call(f, args)),
        ]
    })
}

/// Hard points: 0, 1, 1 ± 1 ulp, tiny, denormal, grazing NL ≈ 1e-8, out of range; plus random cosines.
fn points(random: &[[f64; N_INPUTS]]) -> Vec<[f64; N_INPUTS]> {
    let up = f64::from_bits(1f64.to_bits() + 1);
    let down = f64::from_bits(1f64.to_bits() - 1);
    let mut v = vec![
        [0.0; N_INPUTS],
        [1.0; N_INPUTS],
        [up; N_INPUTS],
        [down; N_INPUTS],
        [1e-300; N_INPUTS],
        [5e-324; N_INPUTS],
        [-0.0; N_INPUTS],
        lobe::from_cosines([1e-8, 0.5, 0.999_999_99, 1.0, 0.7]),
        lobe::from_cosines([0.3, 1e-8, 1.0, down, 0.2]),
        lobe::from_cosines([1.0, 1.0, up, -1e-17, 1e-8]),
        lobe::from_cosines([-0.5, 1.5, 2.0, -2.0, 0.5]),
    ];
    v.extend_from_slice(random);
    v
}

fn param_sets() -> Vec<Vec<f64>> {
    vec![vec![1.0, 16.0, 0.3], vec![1000.0, 268.0, 0.05], vec![50.0, 0.5, 1e-300], vec![2.0, -3.0, 0.0]]
}

/// Compares a JIT kernel (scalar and batched) with the interpreter on every point and parameter set.
fn check(jit: &Kernel, interp: &Kernel, pts: &[[f64; N_INPUTS]], sets: &[Vec<f64>]) -> Result<(), String> {
    check_tiers(std::slice::from_ref(jit), interp, pts, sets)
}

/// [`check`] for each tier's kernel (the Cranelift JIT, and with the feature `llvm` the LLVM tier).
fn check_tiers(tiers: &[Kernel], interp: &Kernel, pts: &[[f64; N_INPUTS]], sets: &[Vec<f64>]) -> Result<(), String> {
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| pts.iter().map(|p| p[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut out = vec![0.0; pts.len()];
    for ps in sets {
        let want: Vec<f64> = pts.iter().map(|x| interp.eval(x, ps)).collect();
        for jit in tiers {
            jit.eval_batch(&columns, ps, &mut out);
            for (k, x) in pts.iter().enumerate() {
                let got = jit.eval(x, ps);
                if !identical(want[k], got) || !identical(want[k], out[k]) {
                    return Err(format!(
                        "{} ({} math)\n  at x = {x:?}, params = {ps:?}: interp {:e}, {} scalar {got:e}, {} batched {:e}",
                        interp.formula.to_text(),
                        interp.math,
                        want[k],
                        jit.backend.name(),
                        jit.backend.name(),
                        out[k]
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The JIT backends of this build: Cranelift, and LLVM with the feature `llvm`.
pub(crate) fn jit_backends() -> Vec<Backend> {
    let mut v = vec![Backend::Jit];
    if cfg!(feature = "llvm") {
        v.push(Backend::Llvm);
    }
    v
}

/// The same bits, or both NaN (payloads may differ).
fn identical(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

fn pair(f: Formula, bake: Vec<(String, f64)>, math: Mode, backend: Backend) -> (Kernel, Kernel) {
    let opts = |backend| Options { backend, bake: bake.clone(), no_simplify: false, math, accuracy: None };
    let jit = compile_formula(f.clone(), &opts(backend)).unwrap_or_else(|d| panic!("{} compiles: {}", backend.name(), d.render(false)));
    let interp = compile_formula(f, &opts(Backend::Interp)).expect("interp builds");
    assert_eq!(jit.backend, backend);
    (jit, interp)
}

/// Every JIT tier's kernel of `f` and the interpreter's.
fn tiers(f: Formula, math: Mode) -> (Vec<Kernel>, Kernel) {
    let interp = compile_formula(f.clone(), &Options { backend: Backend::Interp, math, ..Options::default() }).expect("interp builds");
    (jit_backends().into_iter().map(|b| pair(f.clone(), vec![], math, b).0).collect(), interp)
}

fn cases() -> u32 {
    std::env::var("LOBE_DIFF_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(10_000)
}

/// (a) 10 000 random formulas (set LOBE_DIFF_CASES to change), each on 19 points × 4 parameter sets.
#[test]
fn random_formulas_agree() {
    random_formulas(cases(), Backend::Jit);
}

/// (a) on the LLVM tier: a tenth of the cases (each is an LLVM compile of a few milliseconds).
#[cfg(feature = "llvm")]
#[test]
fn random_formulas_agree_on_the_llvm_tier() {
    random_formulas(cases().div_ceil(10), Backend::Llvm);
}

/// `cases` random formulas, each compiled for `backend` and the interpreter and compared by [`check`].
fn random_formulas(cases: u32, backend: Backend) {
    let random = lobe::report::measure::sample_points(8, 42);
    let pts = points(&random);
    let mut runner = TestRunner::new(Config { cases, failure_persistence: None, ..Config::default() });
    // Baked values must be finite (`resolve_bake` rejects the rest, as `--set` does).
    let finite: Vec<f64> = SPECIAL.iter().copied().filter(|v| v.is_finite()).collect();
    let modes = prop::sample::select(Mode::ALL.to_vec());
    let strategy = (expr(), any::<bool>(), prop::option::of((0..N_PARAMS, prop::sample::select(finite))), modes);
    let result = runner.run(&strategy, |(e, policy, bake, math)| {
        let f = formula(&e, policy);
        let bake = bake.map(|(p, v)| vec![(f.params[p as usize].name.clone(), v)]).unwrap_or_default();
        let (jit, interp) = pair(f, bake, math, backend);
        check(&jit, &interp, &pts, &param_sets()).map_err(TestCaseError::fail)
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// min, max and clamp against every special constant in either operand position, on raw inputs that take the
/// signed zeros, NaN and the infinities: the one-instruction forms the JIT tiers use against a non-NaN constant
/// (and LLVM's IEEE-2019 intrinsics elsewhere) give the interpreter's bits.
#[test]
fn min_max_clamp_against_constants_agree_on_every_tier() {
    let mut pts = points(&[]);
    for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, 0.0, -1.0, 0.5, 2.0, -5e-324] {
        pts.push([v; N_INPUTS]);
    }
    let x = || E::In(Input::NH, false);
    let mut forms = vec![];
    for c in SPECIAL {
        forms.push(E::Call(Builtin::Min, vec![x(), E::C(c)]));
        forms.push(E::Call(Builtin::Min, vec![E::C(c), x()]));
        forms.push(E::Call(Builtin::Max, vec![x(), E::C(c)]));
        forms.push(E::Call(Builtin::Max, vec![E::C(c), x()]));
        for d in [0.0, -0.0, 1.0, f64::NAN, f64::INFINITY] {
            forms.push(E::Call(Builtin::Clamp, vec![x(), E::C(c), E::C(d)]));
        }
    }
    for e in &forms {
        let (jits, interp) = tiers(formula(e, false), Mode::Precise);
        check_tiers(&jits, &interp, &pts, &[vec![1.0, 2.0, 3.0]]).unwrap_or_else(|m| panic!("{m}"));
    }
}

/// n = 1 and n = 1000 over 1000 points (batched length 1000 and 1), every builtin of one input.
#[test]
fn every_builtin_on_dense_inputs() {
    let pts: Vec<[f64; N_INPUTS]> = (0..1000)
        .map(|i| {
            let t = i as f64 / 999.0;
            lobe::from_cosines([t, 1.0 - t, t * t, 2.0 * t - 1.0, (t * 7.0).fract()])
        })
        .collect();
    for f in Builtin::ALL {
        let args: Vec<E> = [Input::NL, Input::VR, Input::VH]
            .iter()
            .zip([false, false, true])
            .map(|(i, c)| E::Bin(BinOp::Mul, Box::new(E::In(*i, c)), Box::new(E::P(0))))
            .collect();
        for math in Mode::ALL {
            let (jits, interp) = tiers(formula(&E::Call(f, args.clone()), false), math);
            for len in [pts.len(), 1, 13] {
                check_tiers(&jits, &interp, &pts[..len], &param_sets()).unwrap_or_else(|e| panic!("{f}: {e}"));
            }
        }
    }
}

// ---- the catalogue -------------------------------------------------------------------------------------------

/// The `.brdf` files of `examples/<dir>`, sorted.
fn catalogue_files(dir: &str) -> Vec<std::path::PathBuf> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples").join(dir);
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let mut files: Vec<_> =
        entries.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "brdf")).collect();
    files.sort();
    assert!(!files.is_empty(), "{} has no .brdf files", dir.display());
    files
}

/// Every `examples/brdfs/*.brdf` compiled by `lobe::compile_source` for both backends in math mode `math`, as
/// (stem, JIT, interpreter), sorted by stem.
fn catalogue(math: Mode) -> Vec<(String, Kernel, Kernel)> {
    let files = catalogue_files("brdfs");
    files
        .iter()
        .map(|path| {
            let name = path.display().to_string();
            let src = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{name}: {e}"));
            let build = |backend| {
                lobe::compile_source(&name, &src, &Options { backend, math, ..Options::default() })
                    .unwrap_or_else(|d| panic!("{name} does not compile:\n{}", d.render(false)))
            };
            let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
            (stem, build(Backend::Jit), build(Backend::Interp))
        })
        .collect()
}

/// (b) every catalogue file, both backends: every file must compile, and the JIT (scalar and batched) agrees
/// with the interpreter at its defaults and at the random formulas' parameter sets.
#[test]
fn catalogue_files_agree() {
    let pts = points(&lobe::report::measure::sample_points(64, 5));
    for (stem, jit, interp) in Mode::ALL.into_iter().flat_map(catalogue) {
        let mut sets = param_sets();
        sets.push(jit.default_params());
        check(&jit, &interp, &pts, &sets).unwrap_or_else(|e| panic!("{stem}: {e}"));
    }
}

/// (b) on every tier: each file of `examples/brdfs` and `examples/explorer`, both math modes, as simplified and
/// as the accuracy pass chose it; the interpreter, Cranelift, and LLVM at 2, 4 and 8 lanes (whatever the host's:
/// LLVM splits wider vectors), on 75 points (odd: a partial last vector) and a 37-point prefix, at the defaults,
/// random values inside each declared range and the random formulas' sets.
#[cfg(feature = "llvm")]
#[test]
fn catalogue_files_agree_on_every_tier() {
    use lobe::numerics::robust::{self, PassOptions};
    use std::sync::Arc;
    let pts = points(&lobe::report::measure::sample_points(64, 13));
    assert_eq!(pts.len() % 2, 1);
    let mut rng = lobe::base::rng::Rng(0x2545_F491_4F6C_DD1D);
    let mut unit = move || rng.unit();
    let files: Vec<_> = catalogue_files("brdfs").into_iter().chain(catalogue_files("explorer")).collect();
    for path in &files {
        let name = path.display().to_string();
        let src = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        for math in Mode::ALL {
            let plain = Options { backend: Backend::Interp, math, ..Options::default() };
            let chosen = robust::with_pass(plain.clone(), PassOptions::default());
            for (form, opts) in [("simplified", plain), ("accuracy pass", chosen)] {
                let interp = lobe::compile_source(&name, &src, &opts).unwrap_or_else(|d| panic!("{name}: {}", d.render(false)));
                let f = interp.formula.clone();
                let mut jits = vec![lobe::build_kernel(f.clone(), Backend::Jit, math).expect("cranelift compiles")];
                for lanes in [2, 4, 8] {
                    let k = lobe::backend::llvm::llvm_kernel_with_lanes(&f, math, lanes).unwrap_or_else(|e| panic!("{name}: {e}"));
                    let t = k.compile_time;
                    jits.push(Kernel::new(f.clone(), Backend::Llvm, math, Arc::new(k), t));
                }
                jits.push(lobe::build_kernel(f.clone(), Backend::Llvm, math).expect("llvm compiles at the host's lanes"));
                let mut sets = param_sets();
                sets.push(interp.default_params());
                for _ in 0..4 {
                    sets.push(
                        f.params
                            .iter()
                            .map(|d| if (d.hi - d.lo).is_finite() { d.lo + (d.hi - d.lo) * unit() } else { d.default * (0.5 + unit()) })
                            .collect(),
                    );
                }
                for len in [pts.len(), 37] {
                    check_tiers(&jits, &interp, &pts[..len], &sets).unwrap_or_else(|e| panic!("{name} ({form}): {e}"));
                }
            }
        }
    }
}

/// (b) and the hand-written Rust twins (`lobe::numerics::twins`, the ones the benches time): every twin
/// mirrors a catalogue file with the same parameters and defaults, and JIT = interpreter = twin on every point, with each
/// parameter at its lower bound, default and upper bound (and F_ST's best fit a = 268).
#[test]
fn catalogue_files_agree_with_rust_twins() {
    let pts = points(&lobe::report::measure::sample_points(200, 9));
    let catalogue = catalogue(Mode::Precise);
    for def in lobe::numerics::twins::DEFS {
        let Some((stem, jit, interp)) = catalogue.iter().find(|(stem, ..)| stem == def.stem) else {
            panic!("twin {}: no file examples/brdfs/{}.brdf", def.name, def.stem)
        };
        let names: Vec<&str> = jit.formula.params.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, def.params, "{stem}: the twin's parameters");
        assert_eq!(jit.default_params(), def.defaults, "{stem}: the twin's defaults");
        // Every combination of each parameter's values.
        let mut sets = vec![vec![]];
        for p in &jit.formula.params {
            let mut values = vec![p.lo, p.default, p.hi];
            if p.name == "a" {
                values.push(268.0);
            }
            sets = sets.iter().flat_map(|s| values.iter().map(move |v| [s.as_slice(), &[*v]].concat())).collect();
        }
        check(jit, interp, &pts, &sets).unwrap_or_else(|e| panic!("{stem}: {e}"));
        for ps in &sets {
            for x in &pts {
                let want = (def.f)(x, ps);
                let got = jit.eval(x, ps);
                // Not 4 ulp: the simplifier rewrites n - n*c into n*(1 - c), which is *more* accurate than the
                // twin near c = 1 (the twin's cancellation costs up to ~n ulp there), so the twin is only a
                // reference to within its own conditioning.
                let close = agree(want, got) || (want - got).abs() <= 1e-12 * want.abs().max(got.abs());
                assert!(close, "{stem} at {x:?}, params {ps:?}: twin {want:e}, jit {got:e}");
            }
        }
    }
}

/// `Evaluator::prepare` (parameters bound once, no per-call lookup) gives the bits of `eval` on every catalogue
/// file, both backends, both math modes: random parameters inside each declared range, the defaults, a short
/// vector (missing parameters are NaN) and the random formulas' sets, on hard and random points.
#[test]
fn prepared_eval_matches_eval_on_the_catalogue() {
    let pts = points(&lobe::report::measure::sample_points(64, 11));
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut unit = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for math in Mode::ALL {
        for (stem, jit, interp) in catalogue(math) {
            let mut sets = param_sets();
            sets.push(jit.default_params());
            sets.push(jit.default_params()[..jit.formula.params.len() / 2].to_vec());
            for _ in 0..4 {
                sets.push(jit.formula.params.iter().map(|d| d.lo + (d.hi - d.lo) * unit()).collect());
            }
            #[allow(unused_mut)]
            let mut kernels = vec![jit, interp];
            #[cfg(feature = "llvm")]
            kernels.push(lobe::build_kernel(kernels[0].formula.clone(), Backend::Llvm, math).expect("llvm compiles"));
            for k in &kernels {
                for ps in &sets {
                    let prepared = k.prepare(ps);
                    let kind_ok = match (&prepared, k.backend) {
                        (lobe::backend::Prepared::Native(n), Backend::Jit | Backend::Llvm) => n.backend() == k.backend,
                        (lobe::backend::Prepared::Interp(_), Backend::Interp) => true,
                        _ => false,
                    };
                    assert!(kind_ok, "{stem}: {} kernel prepared as another backend", k.backend.name());
                    for x in &pts {
                        let (want, got) = (k.eval(x, ps), prepared.eval(x));
                        assert!(
                            identical(want, got),
                            "{stem} ({math} math, {}) at x = {x:?}, params = {ps:?}: eval {want:e}, prepared {got:e}",
                            k.backend.name()
                        );
                    }
                }
            }
        }
    }
}

/// Evaluators without a prepared form (closures, wrappers) keep their parameters and call `eval`.
#[test]
fn prepared_falls_back_to_eval_for_other_evaluators() {
    let twin = lobe::backend::FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| x[2].powf(p[0]) + p.len() as f64);
    let x = lobe::from_cosines([0.1, 0.2, 0.9, 0.4, 0.5]);
    let prepared = twin.prepare(&[3.0, 7.0]);
    assert!(matches!(prepared, lobe::backend::Prepared::Other(..)));
    assert_eq!(prepared.eval(&x).to_bits(), twin.eval(&x, &[3.0, 7.0]).to_bits());
    assert_eq!(prepared.eval(&x), 0.9f64.powf(3.0) + 2.0);
}

/// The value-and-gradient programs (`lobe::numerics::grad`): every output (value and each partial, per channel)
/// the same bits on the interpreter and every JIT tier, at `pts` and `sets`.
fn gradients_agree(f: &Formula, math: Mode, pts: &[[f64; N_INPUTS]], sets: &[Vec<f64>]) -> Result<(), String> {
    use lobe::numerics::grad::Gradient;
    let opts = |backend| Options { backend, math, ..Options::default() };
    let interp = Gradient::compile(f, &opts(Backend::Interp)).map_err(|d| d.render(false))?;
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| pts.iter().map(|p| p[i]).collect()).collect();
    let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| cols[i].as_slice());
    for backend in jit_backends() {
        let jit = Gradient::compile(f, &opts(backend)).map_err(|d| format!("{}: {}", backend.name(), d.render(false)))?;
        for ps in sets {
            let (want, got) = (interp.run(&cols, ps, pts.len()), jit.run(&cols, ps, pts.len()));
            let outputs = |r: &lobe::numerics::grad::GradValues| std::iter::once(&r.value).chain(&r.grad).flatten().flatten().copied().collect::<Vec<f64>>();
            for (k, (a, b)) in outputs(&want).into_iter().zip(outputs(&got)).enumerate() {
                if !identical(a, b) {
                    let (out, point) = (k / pts.len(), k % pts.len());
                    return Err(format!(
                        "{} ({math} math) output {out} at x = {:?}, params = {ps:?}: interp {a:e}, {} {b:e}",
                        f.to_text(),
                        pts[point],
                        backend.name()
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Gradients: every catalogue and explorer file, both math modes, at the defaults and the random formulas' sets.
#[test]
fn gradients_of_the_catalogue_agree_on_every_tier() {
    let pts = points(&lobe::report::measure::sample_points(8, 21));
    let files: Vec<_> = catalogue_files("brdfs").into_iter().chain(catalogue_files("explorer")).collect();
    for path in &files {
        let name = path.display().to_string();
        let src = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let f = lobe::front::parse(&name, &src).unwrap_or_else(|d| panic!("{name}: {}", d.render(false)));
        let mut sets = vec![f.default_params()];
        if f.params.len() == 3 {
            sets.extend(param_sets());
        }
        for math in Mode::ALL {
            gradients_agree(&f, math, &pts, &sets).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }
}

/// Gradients of random formulas (every builtin, internal ones included; raw and clamped inputs): 300 cases
/// (a tenth of LOBE_DIFF_CASES when that is set lower).
#[test]
fn gradients_of_random_formulas_agree_on_every_tier() {
    let pts = points(&lobe::report::measure::sample_points(8, 42));
    let mut runner = TestRunner::new(Config { cases: cases().div_ceil(10).min(300), failure_persistence: None, ..Config::default() });
    let modes = prop::sample::select(Mode::ALL.to_vec());
    let result = runner.run(&(expr(), any::<bool>(), modes), |(e, policy, math)| {
        gradients_agree(&formula(&e, policy), math, &pts, &param_sets()).map_err(TestCaseError::fail)
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}
