//! The simplifier end to end: catalogue formulas (built as s-expressions until the parser lands) and
//! differential property tests of the interpreter before and after simplification.
//!
//! Three differentials, each with the bound it can honestly claim:
//! - `exact_policy_is_bit_identical`: random trees over every builtin, constants (0, −0, 1, 2, 0.5, …), raw
//!   or clamped inputs including NaN, inf and out-of-range values, any parameter values: under
//!   [`Policy::exact`] the results are bit-identical (NaN payloads aside).
//! - `default_policy_without_rounding_is_bit_identical`: the same trees under the kernel contract (inputs not
//!   NaN, parameters in range) with all range-based rewrites on and rounding changes off: bit-identical.
//! - `default_policy_within_error_bound`: well-conditioned non-negative trees with integer powers (up to 268),
//!   pow(x, 0.5) and the a − a·x pattern, under the default policy: the two results differ by at most a
//!   first-order bound computed alongside (each chain x^k may contribute (|k|+1)u relative, propagated
//!   through the tree; a − a·x contributes its cancellation error), times 2.

use lobe::builtins::Builtin;
use lobe::backend::interp::Interp;
use lobe::ir::Node;
use lobe::simplify::sexpr::{formula, formula_literal, ParamSpec};
use lobe::simplify::{simplify, simplify_report, simplify_with, Policy};
use lobe::{Evaluator, Formula, Input};
use proptest::prelude::*;

const A: (&str, f64, f64, f64) = ("a", 0.5, 0.0, 1.0);

fn eval(f: &Formula, x: &[f64; 5], p: &[f64]) -> f64 {
    Interp::new(f).eval(x, p)
}

fn inputs(f: &Formula) -> Vec<Input> {
    f.used_inputs().iter().collect()
}

fn count(f: &Formula, pred: impl Fn(&Node) -> bool) -> usize {
    f.ir.nodes().iter().filter(|n| pred(n)).count()
}

/// Samples of the five inputs in [0, 1], hard values included (0, 1, 1 − ulp, tiny).
fn grid() -> Vec<[f64; 5]> {
    let vals = [0.0, 1.0, 1.0 - f64::EPSILON / 2.0, 1e-300, 0.25, 0.5, 0.7, 0.93, 0.999];
    let mut v = vec![];
    for (i, a) in vals.iter().enumerate() {
        for b in vals.iter().skip(i % 3) {
            v.push([*a, *b, (a + b) / 2.0, *b, 1.0 - a / 2.0]);
        }
    }
    v
}

fn close(u: f64, v: f64, rel: f64) -> bool {
    u == v || (u.is_nan() && v.is_nan()) || (u - v).abs() <= rel * u.abs().max(v.abs())
}

#[test]
fn blinn_with_baked_n_is_a_chain_without_the_root_max() {
    let f = formula("(pow NH n)", &[]).unwrap();
    let (g, r) = simplify_report(&f, &[(0, 50.0)]);
    assert_eq!(count(&g, |n| matches!(n, Node::Call(Builtin::Pow | Builtin::Max, _))), 0, "{}", g.to_text());
    assert_eq!(inputs(&g), vec![Input::NH]);
    assert!(r.count("max-redundant") == 1 && r.count("pow-int") == 1, "{r}");
    for x in grid() {
        assert!(close(eval(&f, &x, &[50.0]), eval(&g, &x, &[]), 50.0 * f64::EPSILON));
    }
}

#[test]
fn catalogue_formulas_keep_their_values() {
    let ward = ("m", 0.3, 0.05, 1.0);
    let cases: &[(&str, &[ParamSpec], &[Input])] = &[
        ("(pow VR n)", &[], &[Input::VR]),
        ("(/ NH (+ (- n (* n NH)) NH))", &[], &[Input::NH]),
        ("(/ (* 2 NH) (* 1.25 (pow (+ (- n (* n NH)) (* 1.25 NH)) 2)))", &[], &[Input::NH]),
        ("(exp (/ (* (neg n) (pow (acos NH) 2)) 2))", &[], &[Input::NH]),
        ("(pow (+ (* (/ n a) (- NH 1)) 1) a)", &[("a", 16.0, 1.0, 1000.0)], &[Input::NH]),
        ("(pow (+ (* (/ n 2) (- NH 1)) 1) 2)", &[], &[Input::NH]),
        ("(+ (* 0.786 n (pow NH 2)) (* (- 1 (* 0.786 n)) NH))", &[], &[Input::NH]),
        (
            "(* (/ 1 (sqrt (* NL NV))) (/ 1 (* 4 pi m m)) (exp (/ (- (* NH NH) 1) (* m m NH NH))))",
            &[ward],
            &[Input::NL, Input::NV, Input::NH],
        ),
        ("(pow (cos (* (/ (acos (pow 0.5 (/ 1 3))) (acos (pow 0.5 (/ 1 n)))) (acos NH))) 3)", &[], &[Input::NH]),
        (
            "(/ (* (min 1 (min (/ (* 2 NH NV) VH) (/ (* 2 NH NL) VH))) (pow NH 4)) (* pi NL NV))",
            &[],
            &[Input::NL, Input::NV, Input::NH, Input::VH],
        ),
    ];
    for (src, params, ins) in cases {
        let f = formula(src, params).unwrap();
        let p = f.default_params();
        for bake in [vec![], vec![(0usize, 50.0)], vec![(0, 268.0)]] {
            let (g, r) = simplify_report(&f, &bake);
            assert!(!r.hit_cap && r.passes <= 3, "{src}: {r}");
            assert_eq!(inputs(&g), *ins, "{src}");
            let mut q = p.clone();
            for (i, v) in &bake {
                q[*i] = *v;
            }
            // Chains up to x^268 (≤ 267u) and factoring (more accurate) are the only rounding changes; the
            // values below stay well away from cancellation except through a − a·x, which the rewrite fixes.
            for x in grid() {
                let (u, v) = (eval(&f, &x, &q), eval(&g, &x, &q));
                let tol = if r.count("factor-1-minus-x") > 0 && x[2] > 0.99 { 1e-3 } else { 1e-11 };
                assert!(close(u, v, tol), "{src} bake {bake:?} at {x:?}: {u} vs {v}\n{}", g.to_program_text());
            }
        }
    }
}

#[test]
fn dead_inputs_disappear_only_under_the_contract() {
    let f = formula("(+ (* NL 0) (* (+ VR VR) (- NV NV)) NH)", &[]).unwrap();
    assert_eq!(inputs(&simplify(&f, &[])), vec![Input::NH]);
    let (g, _) = simplify_with(&f, &[], &Policy::exact());
    assert_eq!(inputs(&g), vec![Input::NL, Input::NV, Input::NH, Input::VR]);
    // And the exact result keeps NaN from a NaN input, which the unsimplified formula also gives.
    let x = [f64::NAN, 0.5, 0.5, 0.5, 0.5];
    assert!(eval(&g, &x, &[50.0]).is_nan() && eval(&f, &x, &[50.0]).is_nan());
}

#[test]
fn report_lists_rounding_changes_with_spans() {
    let src = "(+ (pow NH 268) (pow NL 0.5))";
    let f = formula(src, &[]).unwrap();
    let (_, r) = simplify_report(&f, &[]);
    let rules: Vec<&str> = r.rounding.iter().map(|c| c.rule).collect();
    assert_eq!(rules, vec!["pow-int", "pow-half"]);
    assert_eq!(&src[r.rounding[0].span.range()], "(pow NH 268)");
    assert_eq!(&src[r.rounding[1].span.range()], "(pow NL 0.5)");
    let text = r.to_string();
    assert!(text.contains("pow-int") && text.contains("10 multiplications"), "{text}");
    let src2 = "(+ NL\n   (pow NH 3))";
    let f2 = formula(src2, &[]).unwrap();
    let (_, r2) = simplify_report(&f2, &[]);
    assert!(r2.render(&f2).contains("rounding: pow-int at sexpr:2:4: pow(x, 3) as 2 multiplications"), "{}", r2.render(&f2));
}

// ---------------------------------------------------------------------------------------------------------
// Differential property tests.

/// A random expression over every builtin, as s-expression text.
fn any_expr() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        prop::sample::select(vec!["NL", "NV", "NH", "VR", "VH", "n", "a"]).prop_map(String::from),
        prop::sample::select(vec!["0", "-0", "1", "-1", "2", "0.5", "0.25", "3", "1e-300", "1e300", "pi", "inf", "nan"])
            .prop_map(String::from),
    ];
    leaf.prop_recursive(5, 40, 3, |e| {
        let ops = ["+", "-", "*", "/", "pow", "min", "max"];
        prop_oneof![
            3 => (prop::sample::select(ops.to_vec()), e.clone(), e.clone()).prop_map(|(o, a, b)| format!("({o} {a} {b})")),
            1 => e.clone().prop_map(|a| format!("(neg {a})")),
            2 => (prop::sample::select(Builtin::ALL.iter().filter(|b| b.arity() == 1).map(|b| b.name()).collect::<Vec<_>>()), e.clone())
                .prop_map(|(f, a)| format!("({f} {a})")),
            2 => (e.clone(), prop::sample::select(vec![-3, -2, -1, 0, 1, 2, 3, 4, 5, 8, 15, 16, 50, 268]))
                .prop_map(|(a, k)| format!("(pow {a} {k})")),
            1 => (e.clone(), prop::sample::select(vec!["0.5", "1.5", "-0.5"])).prop_map(|(a, k)| format!("(pow {a} {k})")),
            1 => (e.clone(), e.clone(), e.clone()).prop_map(|(a, b, c)| format!("(clamp {a} {b} {c})")),
            // Shapes the identities look for, over random operands.
            3 => (prop::sample::select(vec![
                "(+ A (neg B))", "(+ (neg A) B)", "(- A (neg B))", "(* (neg A) (neg B))", "(- A A)", "(/ A A)",
                "(* A 0)", "(* -0 A)", "(+ A 0)", "(+ -0 A)", "(- -0 A)", "(- A 0)", "(abs (neg A))", "(abs (abs A))",
                "(* A -1)", "(/ A -1)", "(/ A 4)", "(/ 0 A)", "(neg (neg A))", "(* 1 A)", "(/ A 1)", "(max A 0)",
                "(min A 1)", "(clamp A 0 1)", "(clamp A -1 B)", "(acos (clamp A -1 1))", "(asin (clamp A -2 1))",
                "(* NL 0)", "(- NH NH)", "(* B (/ (+ 1 NL) (+ 1 NL)))", "(+ B (/ 0 (+ 0.5 NH)))",
            ]), e.clone(), e.clone()).prop_map(|(t, a, b)| t.replace('A', &a).replace('B', &b)),
        ]
    })
}

fn hard_value() -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => 0.0..=1.0f64,
        1 => prop::sample::select(vec![0.0, 1.0, 1.0 - f64::EPSILON / 2.0, 1e-300, 5e-324, 0.5]),
    ]
}

fn wild_value() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => hard_value(),
        1 => prop::sample::select(vec![f64::NAN, -0.0, -1.0, 1.5, f64::INFINITY, f64::NEG_INFINITY, 1e308, -1e-310]),
        1 => any::<f64>(),
    ]
}

fn same(u: f64, v: f64) -> bool {
    u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn exact_policy_is_bit_identical(
        src in any_expr(),
        literal in any::<bool>(),
        xs in prop::collection::vec(prop::array::uniform5(wild_value()), 4),
        ps in prop::array::uniform2(wild_value()),
    ) {
        let f = if literal { formula_literal(&src, &[A]) } else { formula(&src, &[A]) }.unwrap();
        let (g, r) = simplify_with(&f, &[], &Policy::exact());
        prop_assert!(!r.hit_cap && r.passes <= 3, "{} passes", r.passes);
        prop_assert!(r.rounding.is_empty());
        // A fixpoint: simplifying the result again changes nothing.
        let r2 = simplify_with(&g, &[], &Policy::exact()).1;
        prop_assert_eq!(r2.total(), 0, "{} fired {:?} on {}", src, r2.fired, g.to_text());
        for x in &xs {
            let (u, v) = (eval(&f, x, &ps), eval(&g, x, &ps));
            prop_assert!(same(u, v), "{src}\n→ {}\nat {x:?} {ps:?}: {u} vs {v}", g.to_text());
        }
    }

    #[test]
    fn default_policy_without_rounding_is_bit_identical(
        src in any_expr(),
        // Any input but NaN: raw cosines can be negative (back-facing) or a rounding above 1; the lowering clamps.
        xs in prop::collection::vec(prop::array::uniform5(wild_value().prop_filter("not NaN", |v| !v.is_nan())), 4),
        n in prop_oneof![1.0..=1000.0f64, Just(1.0), Just(1000.0)],
        a in prop_oneof![0.0..=1.0f64, Just(0.0), Just(1.0)],
        bake in any::<bool>(),
        literal in any::<bool>(),
    ) {
        let f = if literal { formula_literal(&src, &[A]) } else { formula(&src, &[A]) }.unwrap();
        let policy = Policy { rounding: false, ..Policy::default() };
        let baked = if bake { vec![(0, n)] } else { vec![] };
        let (g, r) = simplify_with(&f, &baked, &policy);
        prop_assert!(!r.hit_cap && r.passes <= 3, "{} passes", r.passes);
        let r2 = simplify_with(&g, &baked, &policy).1;
        prop_assert_eq!(r2.total(), 0, "{} fired {:?} on {}", src, r2.fired, g.to_text());
        for x in &xs {
            let (u, v) = (eval(&f, x, &[n, a]), eval(&g, x, &[n, a]));
            prop_assert!(same(u, v), "{src}\n→ {}\nat {x:?} n={n} a={a}: {u} vs {v}", g.to_text());
        }
    }
}

/// A well-conditioned non-negative expression, with its own evaluation carrying a first-order bound on how far
/// two evaluations can drift apart (relative), given the simplifier's rounding changes.
#[derive(Clone, Debug)]
enum P {
    In(usize),
    C(f64),
    Add(Box<P>, Box<P>),
    Mul(Box<P>, Box<P>),
    /// a / (c + b) with c ≥ 0.25
    Div(Box<P>, f64, Box<P>),
    /// pow(c + a, k) with c ≥ 0.5 and integer k (chains)
    PowI(f64, Box<P>, i32),
    /// pow(a, y), y non-integer
    PowF(Box<P>, f64),
    Sqrt(Box<P>),
    Max(Box<P>, Box<P>),
    /// a − a·x with a = c + n·input-free constant part, x a clamped input: the factoring pattern
    Factor(f64, usize),
}

const U: f64 = f64::EPSILON / 2.0;

impl P {
    fn text(&self) -> String {
        const IN: [&str; 5] = ["NL", "NV", "NH", "VR", "VH"];
        match self {
            P::In(i) => IN[*i].into(),
            P::C(c) => format!("{c}"),
            P::Add(a, b) => format!("(+ {} {})", a.text(), b.text()),
            P::Mul(a, b) => format!("(* {} {})", a.text(), b.text()),
            P::Div(a, c, b) => format!("(/ {} (+ {c} {}))", a.text(), b.text()),
            P::PowI(c, a, k) => format!("(pow (+ {c} {}) {k})", a.text()),
            P::PowF(a, y) => format!("(pow {} {y})", a.text()),
            P::Sqrt(a) => format!("(sqrt {})", a.text()),
            P::Max(a, b) => format!("(max {} {})", a.text(), b.text()),
            P::Factor(c, i) => format!("(- (+ {c} n) (* (+ {c} n) {}))", IN[*i]),
        }
    }

    /// (value, drift bound relative to the value) at inputs `x` and parameter `n`.
    fn eval(&self, x: &[f64; 5], n: f64) -> (f64, f64) {
        match self {
            P::In(i) => (x[*i], 0.0),
            P::C(c) => (*c, 0.0),
            P::Add(a, b) => {
                let ((u, da), (v, db)) = (a.eval(x, n), b.eval(x, n));
                (u + v, da.max(db) + 2.0 * U)
            }
            P::Mul(a, b) => {
                let ((u, da), (v, db)) = (a.eval(x, n), b.eval(x, n));
                (u * v, da + db + 2.0 * U)
            }
            P::Div(a, c, b) => {
                let ((u, da), (v, db)) = (a.eval(x, n), b.eval(x, n));
                (u / (c + v), da + db + 4.0 * U)
            }
            P::PowI(c, a, k) => {
                let (u, da) = a.eval(x, n);
                let k = f64::from(*k);
                ((c + u).powf(k), k.abs() * (da + 2.0 * U) + (k.abs() + 1.0) * U + 2.0 * U)
            }
            P::PowF(a, y) => {
                let (u, da) = a.eval(x, n);
                (u.powf(*y), y.abs() * da + 2.0 * U)
            }
            P::Sqrt(a) => {
                let (u, da) = a.eval(x, n);
                (u.sqrt(), da / 2.0 + 2.0 * U)
            }
            P::Max(a, b) => {
                let ((u, da), (v, db)) = (a.eval(x, n), b.eval(x, n));
                (u.max(v), da.max(db))
            }
            P::Factor(c, i) => {
                let a = c + n;
                let r = a - a * x[*i];
                // The original rounds a·x (error ≤ u·a) and cancels; the rewrite rounds twice relative to r.
                (r, if r == 0.0 { f64::INFINITY } else { 3.0 * U * a / r.abs() + 4.0 * U })
            }
        }
    }
}

fn pos_expr() -> impl Strategy<Value = P> {
    let leaf = prop_oneof![
        (0..5usize).prop_map(P::In),
        prop::sample::select(vec![0.5, 1.0, 1.25, 2.0, 3.0]).prop_map(P::C),
        ((0.0..2.0f64), 0..5usize).prop_map(|(c, i)| P::Factor(c, i)),
    ];
    leaf.prop_recursive(4, 24, 2, |e| {
        let b = |e: &BoxedStrategy<P>| e.clone().prop_map(Box::new);
        prop_oneof![
            (b(&e), b(&e)).prop_map(|(a, c)| P::Add(a, c)),
            (b(&e), b(&e)).prop_map(|(a, c)| P::Mul(a, c)),
            (b(&e), prop::sample::select(vec![0.25, 1.0, 2.0]), b(&e)).prop_map(|(a, c, d)| P::Div(a, c, d)),
            (prop::sample::select(vec![0.5, 1.0, 1.25]), b(&e), prop::sample::select(vec![-3, -2, -1, 2, 3, 4, 5, 7, 8, 15, 16, 50, 268]))
                .prop_map(|(c, a, k)| P::PowI(c, a, k)),
            (b(&e), prop::sample::select(vec![0.5, 1.5, 2.5])).prop_map(|(a, y)| P::PowF(a, y)),
            b(&e).prop_map(P::Sqrt),
            (b(&e), b(&e)).prop_map(|(a, c)| P::Max(a, c)),
        ]
        .boxed()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn default_policy_within_error_bound(
        p in pos_expr(),
        xs in prop::collection::vec(prop::array::uniform5(prop_oneof![
            3 => 0.0..=1.0f64,
            1 => prop::sample::select(vec![0.0, 1.0, 1.0 - f64::EPSILON / 2.0, 0.5]),
        ]), 4),
        n in prop_oneof![1.0..=1000.0f64, Just(1.0), Just(1000.0)],
        bake in any::<bool>(),
    ) {
        let src = p.text();
        let f = formula(&src, &[]).unwrap();
        let baked = if bake { vec![(0, n)] } else { vec![] };
        let (g, r) = simplify_report(&f, &baked);
        prop_assert!(!r.hit_cap && r.passes <= 3, "{} passes", r.passes);
        let r2 = simplify_report(&g, &baked).1;
        prop_assert_eq!(r2.total(), 0, "{} fired {:?} on {}", src, r2.fired, g.to_text());
        for x in &xs {
            let (u, v) = (eval(&f, x, &[n]), eval(&g, x, &[n]));
            let (_, d) = p.eval(x, n);
            let ok = u == v
                || (u.is_nan() && v.is_nan())
                || (u - v).abs() <= 2.0 * d * u.abs().max(v.abs()) + 1e-250;
            prop_assert!(ok, "{src}\n→ {}\nat {x:?} n={n}: {u} vs {v}, bound {d:e}", g.to_text());
        }
    }
}

/// The differentials are not vacuous: over the generated trees, the rewrites they are meant to exercise fire.
#[test]
fn generators_exercise_the_rewrites() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    use std::collections::BTreeMap;
    let mut runner = TestRunner::deterministic();
    let (mut exact, mut contract, mut rounding) = (BTreeMap::new(), BTreeMap::new(), BTreeMap::new());
    for _ in 0..300 {
        let src = any_expr().new_tree(&mut runner).unwrap().current();
        let f = formula(&src, &[A]).unwrap();
        for (k, v) in simplify_with(&f, &[], &Policy::exact()).1.fired {
            *exact.entry(k).or_insert(0) += v;
        }
        for (k, v) in simplify_with(&f, &[(0, 50.0)], &Policy { rounding: false, ..Policy::default() }).1.fired {
            *contract.entry(k).or_insert(0) += v;
        }
        let p = pos_expr().new_tree(&mut runner).unwrap().current();
        for (k, v) in simplify_report(&formula(&p.text(), &[]).unwrap(), &[]).1.fired {
            *rounding.entry(k).or_insert(0) += v;
        }
    }
    println!("exact: {exact:?}\ncontract: {contract:?}\nrounding: {rounding:?}");
    for rule in ["const-fold", "pow-one", "pow-zero", "add-neg", "sub-neg", "neg-neg", "mul-one", "max-redundant",
        "add-zero", "sub-zero", "abs-neg", "abs-abs", "mul-minus-one", "div-minus-one", "div-pow2", "trig-clamp",
        "div-one", "minmax-same"] {
        assert!(exact.contains_key(rule), "exact policy never fired {rule}");
    }
    for rule in ["mul-zero", "sub-self", "div-self", "zero-div", "add-zero", "clamp-redundant", "min-redundant",
        "abs-nonneg", "bake"] {
        assert!(contract.contains_key(rule), "contract policy never fired {rule}");
    }
    for rule in ["pow-int", "pow-half", "factor-1-minus-x", "max-redundant"] {
        assert!(rounding.contains_key(rule), "default policy never fired {rule}");
    }
}
/// Arbitrary trees with rounding changes on have no a-priori bound (a 1-ulp change from a chain or from
/// pow(x, 0.5) → sqrt(x), fed into a cancelling subtraction or asin near 1, is amplified without limit), so
/// this is a measurement with a threshold, not a bound: over 3000 deterministic random trees at three input
/// points, 96.5 % of results were bit-identical and all but 2 of 9000 within 1e-9 relative; both exceptions
/// were `asin`/`acos` of pow(1 − 2^-53, 0.5), where glibc's pow returns 1.0 and sqrt the correctly rounded
/// 1 − 2^-53 (the simplified value is the accurate one).
#[test]
fn default_policy_on_arbitrary_trees_mostly_agrees() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    let mut runner = TestRunner::deterministic();
    let (mut total, mut bit, mut close9, mut bad) = (0, 0, 0, vec![]);
    for _ in 0..3000 {
        let src = any_expr().new_tree(&mut runner).unwrap().current();
        let f = formula(&src, &[A]).unwrap();
        let g = simplify(&f, &[]);
        for x in [[0.3, 0.7, 0.9, 0.2, 0.5], [1.0, 0.0, 1.0 - f64::EPSILON / 2.0, 1e-300, 0.5], [0.99, 0.98, 0.97, 0.96, 0.95]] {
            let (u, v) = (eval(&f, &x, &[50.0, 0.5]), eval(&g, &x, &[50.0, 0.5]));
            total += 1;
            bit += usize::from(same(u, v));
            if close(u, v, 1e-9) {
                close9 += 1;
            } else {
                bad.push((src.clone(), u, v));
            }
        }
    }
    println!("{total} results: {bit} bit-identical, {close9} within 1e-9 relative");
    for b in &bad {
        println!("  {b:?}");
    }
    assert!(bit * 100 >= total * 90, "only {bit} of {total} bit-identical");
    assert!(close9 * 1000 >= total * 999, "{} of {total} beyond 1e-9: {bad:?}", total - close9);
}
