//! lobe's math library (`lobe::builtins::math`) against the C library and across backends.
//!
//! For every transcendental builtin, ≥ 10^5 points: uniform and log-uniform over the whole domain (both
//! signs, every binade from subnormal to near overflow), plus every edge class (±0, ±inf, NaN, the smallest
//! subnormal, 1 ± ulp, −1 ± ulp, multiples of π/2 and their neighbours, the overflow and underflow thresholds
//! of exp and pow, integer and half-integer exponents of negative bases).
//! - precise mode: within the table's stated ulp bound (against the correctly rounded result) less one of the
//!   C library (Rust's `f64` methods: glibc here, itself within 1 ulp of the correctly rounded result), and
//!   the same special values;
//! - fast mode: within the table's relative bound (absolute where |result| < 1, for the functions bounded
//!   by 1 or with zeros at finite arguments);
//! - the JIT, scalar and batched (F64X2 lanes, batch tail), returns the interpreter's bits in both modes.
//! - and against lobe's double-double evaluator (`numerics::truth`): precise mode within the stated bound itself.

use lobe::base::span::Span;
use lobe::builtins::{Builtin, Mode};
use lobe::ir::{Formula, Input, Ir, Meta, ParamDecl, ParamKind};
use lobe::{Backend, Columns, Evaluator};
use crate::differential::{jit_backends, ulps};
use std::sync::Arc;

const S: Span = Span { start: 0, end: 0 };

/// A small deterministic generator (splitmix64).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// |x| log-uniform in [2^lo, 2^hi], random sign.
    fn log(&mut self, lo: f64, hi: f64) -> f64 {
        let m = self.range(lo, hi).exp2();
        if self.next() & 1 == 0 {
            m
        } else {
            -m
        }
    }
}

fn nudge(x: f64, k: i64) -> f64 {
    f64::from_bits((x.to_bits() as i64 + k) as u64)
}

/// Edge classes every function meets.
fn edges() -> Vec<f64> {
    let mut v = vec![
        0.0,
        -0.0,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        f64::MIN_POSITIVE,
        -f64::MIN_POSITIVE,
        5e-324,
        -5e-324,
        f64::MAX,
        -f64::MAX,
        0.5,
        -0.5,
        2.0,
        709.782712893384,
        709.79,
        -708.39,
        -745.13,
        -745.2,
        -1000.0,
        1e-300,
        823549.0,
        823550.0,
        1e6,
        1e22,
        2f64.powi(66),
    ];
    for base in [1.0f64, -1.0, 0.5, 0.975, -0.975, std::f64::consts::SQRT_2, std::f64::consts::FRAC_1_SQRT_2] {
        for k in -3..=3 {
            v.push(nudge(base, k));
        }
    }
    for k in -40i32..=40 {
        let m = f64::from(k) * std::f64::consts::FRAC_PI_2;
        v.extend([m, nudge(m, 1), nudge(m, -1)]);
        v.push(f64::from(k) * std::f64::consts::PI);
    }
    v
}

fn points(f: Builtin, n: usize) -> Vec<f64> {
    let mut r = Rng(0x5EED ^ (f as u64));
    let mut v = edges();
    if f == Builtin::Exp {
        // Around the ends of the normal range (e^x = 2^-1022, DBL_MAX), of the subnormals and of the scalings'
        // exponent ranges (2^q with q = −1021, 1023, 1024): where a coding of the final scaling may change.
        for c in [-708.3964185322641, 709.782712893384, -745.1332191019412, -707.7, -708.1, 709.09, 709.5, 709.75] {
            v.extend((-40..=40).map(|i| c + f64::from(i) * 0.0173));
        }
    }
    let (lo, hi): (f64, f64) = match f {
        Builtin::Exp => (-760.0, 720.0),
        Builtin::Acos | Builtin::Asin => (-1.05, 1.05),
        Builtin::Sin | Builtin::Cos | Builtin::Tan => (-40.0, 40.0),
        // Mostly where its polynomial runs, and beyond on both sides (its fallback to sin).
        Builtin::SinNear => (-2.2, 2.2),
        _ => (-100.0, 100.0),
    };
    while v.len() < n {
        let x = match v.len() % 3 {
            0 => r.range(lo, hi),
            1 => r.log(-1074.0, 1024.0),
            _ => match f {
                Builtin::Ln => r.range(0.0, 4.0),
                Builtin::Sin | Builtin::Cos | Builtin::Tan => r.log(-30.0, 20.0),
                Builtin::SinNear => r.log(-30.0, 0.81),
                _ => r.log(-30.0, 10.0),
            },
        };
        v.push(x);
    }
    v
}

/// (x, y) pairs for pow: general ones, hard ones (large |y·ln x|, x near 1, negative bases with integer and
/// non-integer y) and every special pairing of the edge classes.
fn pow_points(n: usize) -> Vec<(f64, f64)> {
    let mut r = Rng(0xB0B);
    let specials = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.5,
        -0.5,
        2.0,
        -2.0,
        3.0,
        -3.0,
        2.5,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        5e-324,
        f64::MAX,
        1e300,
        2f64.powi(53) + 2.0,
        2f64.powi(52) + 1.0,
        1e-20,
        nudge(1.0, 1),
        nudge(1.0, -1),
    ];
    let mut v = vec![];
    for &x in &specials {
        for &y in &specials {
            v.push((x, y));
        }
    }
    while v.len() < n {
        let p = match v.len() % 5 {
            0 => (r.range(0.0, 1.0), r.range(0.0, 1000.0)),
            1 => {
                // |y·ln x| up to ~745: where an unguarded exp(y·ln x) loses ~500 ulp.
                let x = r.log(-1074.0, 1023.0).abs();
                let t = r.range(-745.0, 709.0);
                (x, t / x.ln())
            }
            2 => (1.0 + r.range(-1e-6, 1e-6), r.log(0.0, 40.0)),
            3 => (-r.log(-20.0, 20.0).abs(), (r.range(-60.0, 60.0)).round()),
            _ => (r.log(-1074.0, 1024.0), r.log(-20.0, 12.0)),
        };
        v.push(p);
    }
    v
}

fn same_class(a: f64, b: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    if a.is_infinite() || b.is_infinite() || a == 0.0 || b == 0.0 {
        return a == b && a.is_sign_negative() == b.is_sign_negative();
    }
    true
}

const TRANSCENDENTAL: [Builtin; 10] = [
    Builtin::Exp,
    Builtin::Ln,
    Builtin::Pow,
    Builtin::Sin,
    Builtin::SinNear,
    Builtin::Cos,
    Builtin::Tan,
    Builtin::Acos,
    Builtin::Asin,
    Builtin::Atan,
];

fn args_of(f: Builtin, n: usize) -> Vec<Vec<f64>> {
    if f == Builtin::Pow {
        pow_points(n).into_iter().map(|(x, y)| vec![x, y]).collect()
    } else {
        points(f, n).into_iter().map(|x| vec![x]).collect()
    }
}

/// Worst ulp distance from libm, and the argument where it happens.
fn worst_ulps(f: Builtin, mode: Mode, pts: &[Vec<f64>]) -> (u64, Vec<f64>) {
    let mut worst = (0, vec![]);
    for a in pts {
        let (got, want) = (f.eval_in(mode, a), f.libm(a));
        assert!(same_class(got, want), "{}({a:?}) in {mode} mode: {got:e}, libm {want:e}", f.name());
        if got.is_finite() && want.is_finite() {
            let u = ulps(got, want);
            if u > worst.0 {
                worst = (u, a.clone());
            }
        }
    }
    worst
}

#[test]
fn precise_builtins_are_within_their_stated_ulp_of_libm() {
    for f in TRANSCENDENTAL {
        let pts = args_of(f, 100_000);
        let (u, at) = worst_ulps(f, Mode::Precise, &pts);
        let bound = f.info().bound.ulp;
        // The stated bound is against the correctly rounded result; libm is itself within 1 ulp of it, so
        // lobe must be within bound − 1 of libm for the bound to hold.
        assert!(u as f64 + 1.0 <= bound, "{}: {u} ulp from libm at {at:?} (stated ≤ {bound} ulp of the truth)", f.name());
        println!("{:>5}: max {u} ulp from libm over {} points (worst at {at:?})", f.name(), pts.len());
    }
}

/// Fast-mode error: relative, measured against max(|libm|, floor) — floor 1 for functions whose values are
/// bounded or cross zero at finite arguments (absolute error there), 2^-1000 for exp and pow (whose fast mode
/// flushes results below e^-708 to zero).
fn fast_error(f: Builtin, got: f64, want: f64) -> f64 {
    let floor = if matches!(f, Builtin::Exp | Builtin::Pow) { 2f64.powi(-1000) } else { 1.0 };
    (got - want).abs() / want.abs().max(floor)
}

#[test]
fn fast_builtins_are_within_their_stated_relative_error() {
    for f in TRANSCENDENTAL {
        let pts = args_of(f, 100_000);
        let mut worst = (0.0, vec![]);
        for a in &pts {
            let (got, want) = (f.eval_in(Mode::Fast, a), f.libm(a));
            if !want.is_finite() || !got.is_finite() {
                // Overflow and NaN classes must match; near-overflow values may round to inf in fast mode only
                // if libm's value is within the bound of f64::MAX.
                let near_max = want.is_finite() && want.abs() > f64::MAX * (1.0 - 1e-6);
                assert!(same_class(got, want) || near_max, "fast {}({a:?}) = {got:e}, libm {want:e}", f.name());
                continue;
            }
            let e = fast_error(f, got, want);
            if e > worst.0 {
                worst = (e, a.clone());
            }
        }
        let bound = f.info().bound.fast_rel;
        assert!(worst.0 <= bound, "fast {}: error {:e} at {:?} (stated ≤ {bound:e})", f.name(), worst.0, worst.1);
        println!("fast {:>5}: max error {:.2e} (worst at {:?})", f.name(), worst.0, worst.1);
    }
}

/// `f(NH, NV)` over raw (unclamped) input columns, so every lane value reaches the builtin.
fn raw_formula(f: Builtin) -> Formula {
    let mut ir = Ir::new();
    let x = ir.input(Input::NH, S);
    let y = ir.input(Input::NV, S);
    let args = if f.arity() == 2 { vec![x, y] } else { vec![x] };
    let root = ir.call(f, &args, S);
    Formula {
        meta: Meta::default(),
        params: vec![ParamDecl { name: "n".into(), default: 1.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }],
        ir,
        root,
        file: format!("{}.brdf", f.name()),
        source: String::new(),
        rgb: None,
    }
}

#[test]
fn jit_returns_the_interpreters_bits_in_both_modes() {
    for f in TRANSCENDENTAL {
        let pts = args_of(f, 20_001); // odd: the batch tail runs too
        let formula = Arc::new(raw_formula(f));
        let x: Vec<f64> = pts.iter().map(|a| a[0]).collect();
        let y: Vec<f64> = pts.iter().map(|a| a.get(1).copied().unwrap_or(0.0)).collect();
        // Both JIT tiers: the LLVM tier's lanes take other codings of the same bits (exp's scaling, its table).
        for (backend, mode) in jit_backends().into_iter().flat_map(|b| Mode::ALL.map(move |m| (b, m))) {
            let jit = lobe::build_kernel(formula.clone(), backend, mode).expect("compiles");
            let interp = lobe::build_kernel(formula.clone(), Backend::Interp, mode).expect("builds");
            let cols = Columns::new(std::array::from_fn(|k| match k { 1 => y.as_slice(), 2 => x.as_slice(), _ => &[] }));
            let mut batch = vec![0.0; x.len()];
            jit.eval_batch(&cols, &[1.0], &mut batch);
            for (i, a) in pts.iter().enumerate() {
                let want = f.eval_in(mode, a);
                let inputs = lobe::from_cosines([0.0, y[i], x[i], 0.0, 0.0]);
                let si = interp.eval(&inputs, &[1.0]);
                let sj = jit.eval(&inputs, &[1.0]);
                let same = |v: f64| v.to_bits() == want.to_bits() || (v.is_nan() && want.is_nan());
                assert!(same(si), "{} {mode} interp({a:?}) = {si:e}, library {want:e}", f.name());
                assert!(same(sj), "{} {mode} scalar {backend:?}({a:?}) = {sj:e}, library {want:e}", f.name());
                assert!(same(batch[i]), "{} {mode} batched {backend:?}({a:?})[{i}] = {:e}, library {want:e}", f.name(), batch[i]);
            }
        }
    }
}

/// The builtin on `args` in lobe's higher-precision evaluator (`numerics::truth`, ~104 bits), rounded once.
fn truth(f: Builtin, a: &[f64]) -> f64 {
    use lobe::numerics::truth::Xf;
    let x = Xf::from_f64(a[0]);
    let clamp = |v: Xf| v.max(Xf::from_f64(-1.0)).min(Xf::ONE);
    let v = match f {
        Builtin::Exp => x.exp(),
        Builtin::Ln => x.ln(),
        Builtin::Pow => x.pow(Xf::from_f64(a[1])),
        Builtin::Sin | Builtin::SinNear => x.sin_cos().0,
        Builtin::Cos => x.sin_cos().1,
        Builtin::Tan => {
            let (s, c) = x.sin_cos();
            s / c
        }
        Builtin::Acos => clamp(x).acos(),
        Builtin::Asin => clamp(x).asin(),
        Builtin::Atan => x.atan(),
        _ => unreachable!("transcendental builtins only"),
    };
    v.to_f64()
}

/// The stated bounds against the truth itself: every precise builtin within its table bound (in ulps of the
/// correctly rounded result) of lobe's double-double evaluator, on 20 000 points per function (a subset of the
/// libm test's points, edge classes first). Results in the subnormal range are skipped (the truth rounds them
/// twice), as are arguments where the truth falls back to libm (trigonometric |x| ≥ 2^40).
#[test]
fn precise_builtins_are_within_their_stated_ulp_of_the_truth() {
    for f in TRANSCENDENTAL {
        let bound = f.info().bound.ulp;
        let mut worst = (0u64, vec![]);
        for a in args_of(f, 20_000) {
            if matches!(f, Builtin::Sin | Builtin::SinNear | Builtin::Cos | Builtin::Tan) && a[0].abs() >= 2f64.powi(40) {
                continue;
            }
            let (got, want) = (f.eval_in(Mode::Precise, &a), truth(f, &a));
            if !got.is_finite() || !want.is_finite() || want.abs() < f64::MIN_POSITIVE {
                continue;
            }
            let u = ulps(got, want);
            if u > worst.0 {
                worst = (u, a.clone());
            }
        }
        assert!(worst.0 as f64 <= bound, "{}: {} ulp from the truth at {:?} (stated ≤ {bound})", f.name(), worst.0, worst.1);
        println!("{:>5}: max {} ulp from the truth (worst at {:?})", f.name(), worst.0, worst.1);
    }
}

/// A formula with more math call sites than the JIT inlines (`OUTLINE_AT`) calls the compiled library
/// instead, and still returns the interpreter's bits, scalar and batched, in both modes.
#[test]
fn outlined_library_calls_return_the_interpreters_bits() {
    let mut ir = Ir::new();
    let x = ir.input(Input::NH, S);
    let y = ir.input(Input::NV, S);
    let mut sum = ir.konst(0.0, S);
    let n = lobe::backend::native::OUTLINE_AT + 8;
    for i in 0..n {
        let f = TRANSCENDENTAL[i % TRANSCENDENTAL.len()];
        let k = ir.konst(1.0 + i as f64 / 8.0, S);
        let xi = ir.bin(lobe::ir::BinOp::Mul, x, k, S);
        let args = if f.arity() == 2 { vec![xi, y] } else { vec![xi] };
        let c = ir.call(f, &args, S);
        sum = ir.bin(lobe::ir::BinOp::Add, sum, c, S);
    }
    let formula = Arc::new(Formula {
        meta: Meta::default(),
        params: vec![ParamDecl { name: "n".into(), default: 1.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }],
        ir,
        root: sum,
        file: "many.brdf".into(),
        source: String::new(),
        rgb: None,
    });
    let pts = args_of(Builtin::Pow, 2_001);
    let xs: Vec<f64> = pts.iter().map(|a| a[0]).collect();
    let ys: Vec<f64> = pts.iter().map(|a| a[1]).collect();
    for mode in Mode::ALL {
        let jit = lobe::build_kernel(formula.clone(), Backend::Jit, mode).expect("compiles");
        let interp = lobe::build_kernel(formula.clone(), Backend::Interp, mode).expect("builds");
        let mut batch = vec![0.0; xs.len()];
        jit.eval_batch(&Columns::new(std::array::from_fn(|k| match k { 1 => ys.as_slice(), 2 => xs.as_slice(), _ => &[] })), &[1.0], &mut batch);
        for i in 0..xs.len() {
            let inputs = lobe::from_cosines([0.0, ys[i], xs[i], 0.0, 0.0]);
            let want = interp.eval(&inputs, &[1.0]);
            for got in [jit.eval(&inputs, &[1.0]), batch[i]] {
                assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{mode} at {:?}: {got:e} vs {want:e}", pts[i]);
            }
        }
    }
}

/// The checked-in table of precise exp (`builtins::math_tables`), re-derived with lobe's double-double
/// evaluator: each head is the f64 rounding of 2^(j/16), each tail agrees with the evaluator's to 2^-98 (the
/// evaluator's exp is good to ~2^-101; exp needs ~2^-70).
#[test]
fn math_tables_rederive() {
    use lobe::builtins::math_tables::{EXP_T_HI, EXP_T_TAIL};
    use lobe::numerics::truth::Xf;
    let ln2 = Xf::from_f64(2.0).ln();
    for j in 0..16 {
        let v = (ln2 * Xf::from_f64(j as f64 / 16.0)).exp();
        let hi = v.to_f64();
        assert_eq!(EXP_T_HI[j], hi, "EXP_T_HI[{j}]");
        let tail = ((v - Xf::from_f64(hi)) / Xf::from_f64(hi)).to_f64();
        assert!((EXP_T_TAIL[j] - tail).abs() <= 2f64.powi(-98), "EXP_T_TAIL[{j}] = {:e}, derived {tail:e}", EXP_T_TAIL[j]);
    }
}

/// expmuldiv (the accuracy pass's scaled exponential) in fast mode: within the fast bound of the precise one
/// over exponents past both ends of e^a's range and b, c over every binade and sign (zeros and infinities
/// too), the same class of value (0, ∞, NaN) everywhere, and the JIT's bits in fast mode. Relative error with
/// a floor of 2^-1000: below it the results are subnormals, each rounded once.
#[test]
fn fast_expmuldiv_is_within_the_fast_bound_of_the_precise_one() {
    let mut r = Rng(0xE4D1);
    let special = [0.0, -0.0, f64::INFINITY, f64::MIN_POSITIVE, 5e-324, 1.0, f64::MAX];
    let mut pts = vec![];
    for i in 0..100_000 {
        let a = if i % 2 == 0 { r.range(-1500.0, 1500.0) } else { r.range(-30.0, 5.0) };
        let mut bc = || if r.unit() < 0.02 { special[(r.next() % 7) as usize] } else { r.log(-1074.0, 1023.0) };
        let (b, c) = (bc(), bc());
        pts.push([a, b, c]);
    }
    let bound = Builtin::ExpMulDiv.info().bound.fast_rel;
    let mut worst = (0.0f64, [0.0; 3]);
    for p in &pts {
        let (fast, precise) = (Builtin::ExpMulDiv.eval_in(Mode::Fast, p), Builtin::ExpMulDiv.eval_in(Mode::Precise, p));
        if !fast.is_finite() || !precise.is_finite() || precise == 0.0 {
            let near_max = precise.is_finite() && precise.abs() > f64::MAX * (1.0 - 1e-6);
            let near_zero = precise.abs() < 2f64.powi(-1000) && fast.abs() < 2f64.powi(-1000);
            assert!(same_class(fast, precise) || near_max || near_zero, "expmuldiv{p:?}: fast {fast:e}, precise {precise:e}");
            continue;
        }
        let e = (fast - precise).abs() / precise.abs().max(2f64.powi(-1000));
        if e > worst.0 {
            worst = (e, *p);
        }
    }
    assert!(worst.0 <= bound, "fast expmuldiv: error {:e} at {:?} (stated ≤ {bound:e})", worst.0, worst.1);
    println!("fast expmuldiv: max error {:.2e} (worst at {:?})", worst.0, worst.1);
    // The JIT computes the interpreter's fast-mode bits.
    let src = "expmuldiv(NH, NL, NV)";
    let mut ir = Ir::new();
    let args: Vec<_> = [Input::NH, Input::NL, Input::NV].iter().map(|i| ir.input(*i, S)).collect();
    let root = ir.call(Builtin::ExpMulDiv, &args, S);
    let formula = Arc::new(Formula { ir, root, source: src.into(), ..raw_formula(Builtin::Exp) });
    let jit = lobe::build_kernel(formula, Backend::Jit, Mode::Fast).expect("compiles");
    let col = |k: usize| pts.iter().map(|p| p[k]).collect::<Vec<f64>>();
    let (a, b, c) = (col(0), col(1), col(2));
    let cols = Columns::new(std::array::from_fn(|k| match k { 0 => b.as_slice(), 1 => c.as_slice(), 2 => a.as_slice(), _ => &[] }));
    let mut got = vec![0.0; pts.len()];
    jit.eval_batch(&cols, &[1.0], &mut got);
    for (p, g) in pts.iter().zip(&got) {
        let want = Builtin::ExpMulDiv.eval_in(Mode::Fast, p);
        assert!(g.to_bits() == want.to_bits() || g.is_nan() && want.is_nan(), "JIT expmuldiv{p:?} = {g:e}, interpreter {want:e}");
    }
}
