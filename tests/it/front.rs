//! The front end on valid input (precedence, lets, params, metadata, newline rules, line endings), evaluated
//! through the reference interpreter on the *unsimplified* formula and compared with values computed by hand
//! in Rust; and robustness on hostile input (never a panic, never a stack overflow).

use lobe::builtins::Builtin;
use lobe::front::{parse, parse_with_warnings};
use lobe::backend::interp::Interp;
use lobe::{Evaluator, Formula};

/// Inputs in NL, NV, NH, VR, VH order.
const X: [f64; lobe::N_INPUTS] = [0.3, 0.6, 0.9, 0.7, 0.8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];

fn formula(src: &str) -> Formula {
    parse("t.brdf", src).unwrap_or_else(|d| panic!("{src:?} was rejected:\n{d}"))
}

fn eval_with(src: &str, x: [f64; lobe::N_INPUTS], params: &[f64]) -> f64 {
    Interp::new(&formula(src)).eval(&x, params)
}

/// Evaluates with the default parameter values.
fn eval(src: &str) -> f64 {
    let f = formula(src);
    Interp::new(&f).eval(&X, &f.default_params())
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * b.abs().max(1.0)
}

#[track_caller]
fn check(src: &str, want: f64) {
    let got = eval(src);
    assert!(close(got, want), "{src:?}: got {got}, want {want}");
}

#[test]
fn precedence_and_associativity() {
    // The root is max(raw, 0), so negative results are shifted to stay visible.
    check("10 - 2^2", 6.0); // -x^2 = -(x^2): 10 + -(2^2)
    check("10 + -2^2", 6.0);
    check("2^3^2", 512.0); // right-assoc: 2^(3^2), not (2^3)^2 = 64
    check("10 - 4 - 3", 3.0); // (10-4)-3, not 10-(4-3) = 9
    check("64 / 4 / 2", 8.0); // (64/4)/2, not 64/(4/2) = 32
    check("1 + 2 * 3^2", 19.0);
    check("(1 + 2) * 3", 9.0);
    check("2^-1", 0.5);
    check("--3", 3.0);
    check("-2 * -3", 6.0);
    check("2 * NH^2", 2.0 * 0.9f64.powf(2.0));
}

#[test]
fn inputs_are_clamped_to_the_unit_interval_and_the_root_at_zero() {
    assert_eq!(eval_with("NH", lobe::from_cosines([0.0, 0.0, 1.5, 0.0, 0.0]), &[50.0]), 1.0);
    assert_eq!(eval_with("NH + 0.25", lobe::from_cosines([0.0, 0.0, -0.5, 0.0, 0.0]), &[50.0]), 0.25);
    assert_eq!(eval_with("NH - 1", lobe::from_cosines([0.0, 0.0, 0.5, 0.0, 0.0]), &[50.0]), 0.0);
    // Each input reads its own column.
    assert!(close(eval("NL + 10*NV + 100*NH + 1000*VR + 10000*VH"), 0.3 + 6.0 + 90.0 + 700.0 + 8000.0));
    assert!(close(eval("pi"), std::f64::consts::PI));
}

#[test]
fn builtins_evaluate() {
    let c: f64 = 0.9;
    check("exp(-n * acos(NH)^2 / 2)", (-50.0 * c.acos().powi(2) / 2.0).exp());
    check("clamp(3*NH, 0.5, 2) + min(NL, NV) + max(NL, NV)", 2.0 + 0.3 + 0.6);
    check("sqrt(NH) * abs(-2) + ln(2) + sin(1) + cos(1) + tan(0.5) + atan(1) + asin(0.5)",
        c.sqrt() * 2.0 + 2f64.ln() + 1f64.sin() + 1f64.cos() + 0.5f64.tan() + 1f64.atan() + 0.5f64.asin());
    check("pow(NH, 3)", c.powf(3.0));
}

#[test]
fn let_chains_in_order() {
    let c: f64 = 0.9;
    let n = 50.0;
    // Modified Schlick (2.3).
    check("let c = NH\n2*c / (1.25*(n - n*c + 1.25*c)^2)", 2.0 * c / (1.25 * (n - n * c + 1.25 * c).powf(2.0)));
    check("let a = NH * 2\nlet b = a + 1\nlet d = b * b\nd - a", (c * 2.0 + 1.0).powi(2) - c * 2.0);
}

#[test]
fn params_have_defaults_ranges_and_fixed_order() {
    let f = formula("param a = 16 in 1..1000\n(n/a*(NH - 1) + 1)^a");
    assert_eq!(f.params.len(), 2);
    assert_eq!((f.params[0].name.as_str(), f.params[0].default, f.params[0].lo, f.params[0].hi), ("n", 50.0, 1.0, 1000.0));
    assert_eq!(f.params[0].span, None);
    assert_eq!((f.params[1].name.as_str(), f.params[1].default, f.params[1].lo, f.params[1].hi), ("a", 16.0, 1.0, 1000.0));
    let ev = Interp::new(&f);
    let fst = |n: f64, a: f64| (n / a * (0.9 - 1.0) + 1.0f64).powf(a);
    assert!(close(ev.eval(&X, &[50.0, 16.0]), fst(50.0, 16.0)));
    assert!(close(ev.eval(&X, &[20.0, 268.0]), fst(20.0, 268.0)));

    // `param n` overrides the implicit default and range but stays parameter 0.
    let f = formula("param k = -1 in -2..0\nparam n = 100 in 2..500\nNH^n * -k");
    assert_eq!(f.params.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(), ["n", "k"]);
    assert_eq!((f.params[0].default, f.params[0].lo, f.params[0].hi), (100.0, 2.0, 500.0));
    assert!(f.params[0].span.is_some());
    assert_eq!((f.params[1].default, f.params[1].lo, f.params[1].hi), (-1.0, -2.0, 0.0));
    assert!(close(Interp::new(&f).eval(&X, &f.default_params()), 0.9f64.powf(100.0)));

    // `param n = 30` without a range keeps n's range; other params without a range are unbounded.
    let f = formula("param n = 30\nparam m = 0.2\nNH^n * m");
    assert_eq!((f.params[0].lo, f.params[0].hi), (1.0, 1000.0));
    assert_eq!((f.params[1].lo, f.params[1].hi), (f64::NEG_INFINITY, f64::INFINITY));
}

#[test]
fn metadata_is_read() {
    let f = formula("@name \"Modified Schlick\"\n@cite \"Thesis (VNTU 2022), eq. (2.3)\"\nNH");
    assert_eq!(f.meta.name.as_deref(), Some("Modified Schlick"));
    assert_eq!(f.meta.citation.as_deref(), Some("Thesis (VNTU 2022), eq. (2.3)"));
    assert_eq!(f.display_name(), "Modified Schlick");
    let f = formula("NH");
    assert_eq!(f.meta, Default::default());
    assert_eq!(f.file, "t.brdf");
    assert_eq!(f.source, "NH");
}

#[test]
fn newline_rules() {
    let c: f64 = 0.9;
    // Continuation after a binary operator, `=`, `,` and inside parentheses; blank lines and `;` separate.
    check("let a =\n  NH\nlet b = a +\n  1\n\n\nb * 2", (c + 1.0) * 2.0);
    check("max(NH,\n    NL)", 0.9);
    check("(NH\n + 1\n - 0.5)", c + 0.5);
    check("let a = NH; let b = 2; a * b", c * 2.0);
    check("\n\n# leading blank lines\n\nNH\n\n\n", c);
    // Without a continuation marker a newline ends the statement: two statements here.
    let d = parse("t", "NH\n- 1").expect_err("two statements");
    assert!(d.render(false).contains("more than one final expression"), "{d}");
}

#[test]
fn crlf_line_endings_and_unicode_comments() {
    let c: f64 = 0.9;
    check("# Blinn \u{2014} \u{3b8} = acos(NH) \u{2713}\r\nlet c = NH\r\n\r\nc^n  # \u{3c0} \u{00e9}\u{00fc}\r\n", c.powf(50.0));
    check("let a = NH +\r\n  1\r\na", c + 1.0);
    // A diagnostic after a CRLF line points at the right line and column.
    let d = parse("t.brdf", "# \u{3b8}\u{3b8}\r\nNX").expect_err("rejected");
    assert!(d.render(false).contains("t.brdf:2:1"), "{}", d.render(false));
}

#[test]
fn warnings_do_not_reject() {
    let (f, w) = parse_with_warnings("t", "let u = 1\n2").expect("accepted");
    assert_eq!(w.items.len(), 2, "{w}"); // unused let, no input
    assert!(close(Interp::new(&f).eval(&X, &[50.0]), 2.0));
    let (_, w) = parse_with_warnings("t", "let _u = 1\nNH").expect("accepted");
    assert!(w.items.is_empty(), "{w}");
}

#[test]
fn ir_spans_point_into_the_source() {
    let src = "let c = NH\n2 * acos(c)";
    let f = formula(src);
    let texts: Vec<&str> = f.ir.ids().map(|id| &src[f.ir.span(id).range()]).collect();
    assert!(texts.contains(&"acos(c)"), "{texts:?}");
    assert!(texts.contains(&"2 * acos(c)"), "{texts:?}");
}

/// Every .brdf in the catalogue must parse without errors.
#[test]
fn catalogue_parses() {
    let files = brdf_files("examples/brdfs");
    for (p, src) in &files {
        parse(&p.display().to_string(), src).unwrap_or_else(|d| panic!("{}:\n{d}", p.display()));
    }
    assert!(files.len() >= 2, "found only {} catalogue files", files.len());
}

/// The `.brdf` files of a folder of the repository, with their text.
fn brdf_files(folder: &str) -> Vec<(std::path::PathBuf, String)> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(folder);
    let mut out = vec![];
    for e in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{folder}: {e}")) {
        let p = e.expect("dir entry").path();
        if p.extension().is_some_and(|x| x == "brdf") {
            let src = std::fs::read_to_string(&p).expect("readable");
            out.push((p, src));
        }
    }
    out
}

// ---- robustness: bad input of any kind gives diagnostics, never a panic or a stack overflow ----

fn no_panic(src: &str) {
    let r = parse_with_warnings("fuzz.brdf", src);
    let text = match &r {
        Ok((_, w)) => w.render(false),
        Err(d) => {
            assert!(d.has_errors());
            d.render(false)
        }
    };
    assert!(text.len() < 64 * 1024, "report for {} bytes is {} bytes long", src.len(), text.len());
}

#[test]
fn empty_and_blank_inputs() {
    for src in ["", " ", "\n", "\r\n", ";", ";;;", "#", "# only a comment", "\t\n  \n"] {
        let d = parse("t", src).err().unwrap_or_else(|| panic!("{src:?} accepted"));
        assert!(d.render(false).contains("the file has no formula"), "{src:?}: {d}");
    }
}

#[test]
fn every_ascii_byte_anywhere() {
    for b in 0u8..128 {
        let c = b as char;
        for src in [
            format!("{c}"),
            format!("NH{c}"),
            format!("{c}NH"),
            format!("NH {c} n"),
            format!("let a = ({c}\na"),
            format!("@name \"{c}\nparam a = 1 in 0..{c}2\nNH^a"),
        ] {
            no_panic(&src);
        }
    }
}

#[test]
fn binary_garbage() {
    // A deterministic pseudo-random byte soup, read as text the way the CLI does (lossy UTF-8).
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    for len in [1usize, 7, 100, 5000, 200_000] {
        let bytes: Vec<u8> = (0..len)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 24) as u8
            })
            .collect();
        let src = String::from_utf8_lossy(&bytes);
        no_panic(&src);
        assert!(parse("g", &src).is_err());
    }
    // Token soup from the language's own alphabet.
    let alphabet = ["(", ")", "+", "-", "*", "/", "^", ",", "=", "..", "\n", ";", "let", "param", "in", "NH", "n", "2", "0.5", "@name", "\"s\"", "pow", " "];
    for _ in 0..300 {
        let mut src = String::new();
        for _ in 0..(s % 40) {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            src.push_str(alphabet[(s % alphabet.len() as u64) as usize]);
        }
        no_panic(&src);
    }
}

#[test]
fn deep_nesting_is_refused_not_overflowed() {
    let src = "(".repeat(100_000) + "NH" + &")".repeat(100_000);
    let d = parse("deep.brdf", &src).expect_err("rejected");
    assert_eq!(d.errors().count(), 1, "{d}");
    assert!(d.render(false).contains("nested more than 200 deep"));
    // Unclosed, and nested calls.
    assert!(parse("t", &"(".repeat(100_000)).is_err());
    assert!(parse("t", &("sqrt(".repeat(100_000) + "NH")).is_err());
    // 200 levels are fine.
    check(&("(".repeat(200) + "NH" + &")".repeat(200)), 0.9);
}

#[test]
fn one_mebibyte_chains_parse_and_lower() {
    // A left spine 500 000 deep: parsed, lowered and dropped without recursion.
    let terms = (1 << 20) / 2;
    let src = vec!["1"; terms].join("+");
    let f = formula(&src);
    assert_eq!(Interp::new(&f).eval(&X, &[50.0]), terms as f64);
    // A right spine (`^` is right-associative) and a unary-minus chain.
    let src = vec!["1"; terms].join("^");
    assert_eq!(eval(&src), 1.0);
    let src = "-".repeat(1 << 20) + "2";
    assert_eq!(eval(&src), 2.0);
    // Many statements.
    let mut src = String::from("let a0 = NH\n");
    for i in 1..40_000 {
        src.push_str(&format!("let a{i} = a{} * 1\n", i - 1));
    }
    src.push_str("a39999");
    check(&src, 0.9);
}

#[test]
fn many_errors_are_capped() {
    let src = "NX\n".repeat(10_000) + "NH";
    let d = parse("t", &src).expect_err("rejected");
    let text = d.render(false);
    assert!(text.contains("more errors not shown"), "{text}");
    assert!(d.errors().count() <= lobe::front::MAX_ERRORS + 1);
    // Many unknown names among many `let`s: the suggestion search stops with the display cap (quadratic
    // otherwise: 20 000 names x 20 000 candidates).
    let src: String = (0..20_000).map(|i| format!("let a{i} = q{i}\n")).collect::<String>() + "NH";
    let d = parse("t", &src).expect_err("rejected");
    assert!(d.render(false).contains("unknown variable `q0`"));
}

// ---- random expressions: printed with minimal parentheses, parsed back, compared with direct evaluation ----

use lobe::base::rng::Rng;

enum E {
    Num(f64),
    In(usize),
    Neg(Box<E>),
    Bin(char, Box<E>, Box<E>),
    Call(&'static str, Vec<E>),
}

const NAMES: [&str; 5] = ["NL", "NV", "NH", "VR", "VH"];

fn gen(r: &mut Rng, depth: u32) -> E {
    if depth == 0 || r.below(4) == 0 {
        return if r.below(2) == 0 { E::Num((r.below(40) as f64) / 8.0) } else { E::In(r.below(5) as usize) };
    }
    match r.below(10) {
        0 => E::Neg(Box::new(gen(r, depth - 1))),
        1..=6 => {
            let op = ['+', '-', '*', '/', '^', '+', '*'][r.below(7) as usize];
            E::Bin(op, Box::new(gen(r, depth - 1)), Box::new(gen(r, depth - 1)))
        }
        _ => {
            let (f, k) = [("cos", 1), ("exp", 1), ("sqrt", 1), ("acos", 1), ("min", 2), ("max", 2), ("clamp", 3)]
                [r.below(7) as usize];
            E::Call(f, (0..k).map(|_| gen(r, depth - 1)).collect())
        }
    }
}

/// Independent reference semantics, straight from `std` (inputs are already in [0, 1]).
fn value(e: &E, x: &[f64; lobe::N_INPUTS]) -> f64 {
    let nanmin = |a: f64, b: f64| if a.is_nan() || b.is_nan() { f64::NAN } else if a == b { if a.is_sign_negative() { a } else { b } } else { a.min(b) };
    let nanmax = |a: f64, b: f64| if a.is_nan() || b.is_nan() { f64::NAN } else if a == b { if a.is_sign_positive() { a } else { b } } else { a.max(b) };
    match e {
        E::Num(v) => *v,
        E::In(i) => x[*i],
        E::Neg(a) => -value(a, x),
        E::Bin(op, a, b) => {
            let (a, b) = (value(a, x), value(b, x));
            match op {
                '+' => a + b,
                '-' => a - b,
                '*' => a * b,
                '/' => a / b,
                _ => Builtin::Pow.eval(&[a, b]),
            }
        }
        E::Call(f, args) => {
            let v: Vec<f64> = args.iter().map(|a| value(a, x)).collect();
            match *f {
                // The builtins table is the reference for transcendental functions (lobe's math library).
                "cos" => Builtin::Cos.eval(&v),
                "exp" => Builtin::Exp.eval(&v),
                "sqrt" => v[0].sqrt(),
                "acos" => Builtin::Acos.eval(&v),
                "min" => nanmin(v[0], v[1]),
                "max" => nanmax(v[0], v[1]),
                _ => nanmin(nanmax(v[0], v[1]), v[2]),
            }
        }
    }
}

fn prec(e: &E) -> u8 {
    match e {
        E::Bin('+' | '-', ..) => 1,
        E::Bin('*' | '/', ..) => 2,
        E::Neg(_) => 3,
        E::Bin(..) => 4,
        _ => 5,
    }
}

/// Prints with the fewest parentheses the grammar allows; `r` sprinkles legal line breaks and spaces.
fn print(e: &E, r: &mut Rng, out: &mut String) {
    let brk = |r: &mut Rng, out: &mut String| match r.below(6) {
        0 => out.push('\n'),
        1 => out.push_str("  "),
        _ => {}
    };
    let wrap = |c: &E, need: bool, r: &mut Rng, out: &mut String| {
        if need {
            out.push('(');
            brk(r, out);
            print(c, r, out);
            out.push(')');
        } else {
            print(c, r, out);
        }
    };
    match e {
        E::Num(v) => out.push_str(&format!("{v}")),
        E::In(i) => out.push_str(NAMES[*i]),
        E::Neg(a) => {
            out.push('-');
            wrap(a, prec(a) < 3, r, out);
        }
        E::Bin(op, a, b) => {
            let p = prec(e);
            // Left-associative ops keep an equal-precedence left child bare; `^` (right-assoc) the right one.
            let (lneed, rneed) = if *op == '^' { (prec(a) <= 4, prec(b) < 4) } else { (prec(a) < p, prec(b) <= p) };
            wrap(a, lneed, r, out);
            out.push(' ');
            out.push(*op);
            brk(r, out);
            out.push(' ');
            wrap(b, rneed, r, out);
        }
        E::Call(f, args) => {
            out.push_str(f);
            out.push('(');
            for (k, a) in args.iter().enumerate() {
                if k > 0 {
                    out.push(',');
                    brk(r, out);
                    out.push(' ');
                }
                print(a, r, out);
            }
            out.push(')');
        }
    }
}

#[test]
fn random_expressions_round_trip_through_the_parser() {
    let mut r = Rng(0x2545_F491_4F6C_DD1D);
    for case in 0..400 {
        let e = gen(&mut r, 6);
        let mut src = String::new();
        print(&e, &mut r, &mut src);
        let f = parse("rand.brdf", &src).unwrap_or_else(|d| panic!("case {case}: {src:?}\n{d}"));
        let ev = Interp::new(&f);
        let want = value(&e, &X);
        let want = if want.is_nan() { f64::NAN } else if want > 0.0 { want } else { 0.0 };
        let got = ev.eval(&X, &[50.0]);
        assert!(
            (got.is_nan() && want.is_nan()) || got == want,
            "case {case}: {src:?}: interpreter {got}, direct {want}"
        );
    }
}

// ---- The vector and bool language (issue 13) ----

/// Light/view direction pairs in the local frame (N = +z), upper hemisphere, away from special cases.
fn directions() -> Vec<([f64; 3], [f64; 3])> {
    let mut out = vec![];
    for (tl, pl, tv, pv) in [(0.3, 0.4, 1.1, 2.0), (1.2, -2.5, 0.2, 0.9), (0.7, 3.0, 0.8, -1.0), (1.5, 1.0, 1.4, -2.8)] {
        out.push((lobe::numerics::dir(tl, pl), lobe::numerics::dir(tv, pv)));
    }
    out
}

/// Every channel of `src` at (l, v) with the given parameters, from the interpreter and from the JIT, which
/// must agree bit for bit.
fn channels_at(src: &str, l: [f64; 3], v: [f64; 3], set: &[(&str, f64)]) -> Vec<f64> {
    let f = formula(src);
    let x = lobe::numerics::inputs_from_dirs(l, v);
    let mut p = f.default_params();
    for (k, val) in set {
        p[f.param_index(k).unwrap_or_else(|| panic!("{src:?}: no parameter {k}"))] = *val;
    }
    f.channels()
        .iter()
        .map(|c| {
            let i = Interp::new(c).eval(&x, &p);
            let k = lobe::backend::jit::jit_kernel(c, lobe::Mode::Precise).expect("compiles").eval(&x, &p);
            assert!(i.to_bits() == k.to_bits() || (i.is_nan() && k.is_nan()), "{src:?}: interp {i}, JIT {k}");
            i
        })
        .collect()
}

#[track_caller]
fn check_dirs(src: &str, want: impl Fn([f64; 3], [f64; 3]) -> f64) {
    for (l, v) in directions() {
        let got = channels_at(src, l, v, &[]);
        let w = want(l, v);
        assert_eq!(got.len(), 1, "{src:?} is scalar");
        assert!(close(got[0], w), "{src:?} at L={l:?} V={v:?}: got {}, want {w}", got[0]);
    }
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn half(l: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    let h = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
    let n = dot3(h, h).sqrt();
    h.map(|c| c / n)
}

#[test]
fn vectors_frame_and_components_evaluate() {
    let raw = |s: &str| format!("@domain raw\n{s}");
    check_dirs(&raw("L.x + 10*V.y - 100*L.z"), |l, v| l[0] + 10.0 * v[1] - 100.0 * l[2]);
    check_dirs(&raw("rgb(1, 2, 3).g + vec3(L.z).b"), |l, _| 2.0 + l[2]);
    check_dirs(&raw("dot(L, V)"), dot3);
    check_dirs(&raw("LV + 10*Lx + 100*Vz"), |l, v| dot3(l, v) + 10.0 * l[0] + 100.0 * v[2]);
    check_dirs(&raw("HX + 10*HY"), |l, v| half(l, v)[0] + 10.0 * half(l, v)[1]);
    check_dirs(&raw("dot(normalize(L + V), N)"), |l, v| half(l, v)[2]);
    check_dirs(&raw("dot(X, L) + 10 * dot(Y, V)"), |l, v| l[0] + 10.0 * v[1]);
    check_dirs(&raw("length(L + V) + distance(L, V)"), |l, v| {
        let s = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
        let d = [l[0] - v[0], l[1] - v[1], l[2] - v[2]];
        dot3(s, s).sqrt() + dot3(d, d).sqrt()
    });
    check_dirs(&raw("cross(L, V).z + 10 * cross(X, Y).z"), |l, v| l[0] * v[1] - l[1] * v[0] + 10.0);
    check_dirs(&raw("dot(reflect(-L, N), V)"), |l, v| 2.0 * l[2] * v[2] - dot3(l, v));
    check_dirs(&raw("max(L, V).x + 10 * abs(-L).y + pow(vec3(2), vec3(1, 2, 3)).z"), |l, v| {
        l[0].max(v[0]) + 10.0 * l[1].abs() + 8.0
    });
    check_dirs(&raw("mix(1, 3, L.z) + smoothstep(0, 1, V.z) + step(0.5, L.z)"), |l, v| {
        let t = v[2].clamp(0.0, 1.0);
        1.0 + 2.0 * l[2] + t * t * (3.0 - 2.0 * t) + if l[2] < 0.5 { 0.0 } else { 1.0 }
    });
    check_dirs(&raw("sign(L.x) + 10 * fract(3 * V.z) + 100 * floor(2.5 * L.z)"), |l, v| {
        l[0].signum() + 10.0 * (3.0 * v[2] - (3.0 * v[2]).floor()) + 100.0 * (2.5 * l[2]).floor()
    });
    check_dirs(&raw("radians(180) + degrees(L.z)"), |l, _| std::f64::consts::PI + l[2].to_degrees());
    // Named cosines are clamped in the brdf domain, raw in the raw domain; direction components never.
    let (l, v) = ([0.6, 0.0, -0.8], [0.0, 0.0, 1.0]);
    assert_eq!(channels_at("NL + 2", l, v, &[]), vec![2.0]);
    assert!(close(channels_at(&raw("NL + 2"), l, v, &[])[0], 1.2));
    assert!(close(channels_at("Lz + 2", l, v, &[])[0], 1.2));
    // The brdf domain clamps the result at 0; raw does not.
    assert_eq!(channels_at("L.z", l, v, &[]), vec![0.0]);
    assert_eq!(channels_at(&raw("L.z"), l, v, &[]), vec![-0.8]);
}

#[test]
fn booleans_comparisons_and_selects_evaluate() {
    let raw = |s: &str| format!("@domain raw\n{s}");
    check_dirs(&raw("L.z > 0.5 ? 1 : 2"), |l, _| if l[2] > 0.5 { 1.0 } else { 2.0 });
    check_dirs(&raw("if L.z > 0.5 && V.z > 0.5 then 1 else 2"), |l, v| if l[2] > 0.5 && v[2] > 0.5 { 1.0 } else { 2.0 });
    check_dirs(&raw("L.z < 0.5 || V.z <= 0.5 ? 3 : 4"), |l, v| if l[2] < 0.5 || v[2] <= 0.5 { 3.0 } else { 4.0 });
    check_dirs(&raw("!(L.x >= 0) ? 5 : 6"), |l, _| if l[0] >= 0.0 { 6.0 } else { 5.0 });
    check_dirs(&raw("let b = L.y > 0\nb == (V.y > 0) ? 7 : 8"), |l, v| if (l[1] > 0.0) == (v[1] > 0.0) { 7.0 } else { 8.0 });
    check_dirs(&raw("L.x != V.x ? (true ? 9 : 10) : 11"), |l, v| if l[0] != v[0] { 9.0 } else { 11.0 });
    check_dirs(&raw("false || L.z == L.z ? 12 : 13"), |_, _| 12.0);
    check_dirs(&raw("L.z > 0.5 ? L.z : V.z"), |l, v| if l[2] > 0.5 { l[2] } else { v[2] });
    // A nested select: right-associative, `if` chains the same way.
    let three = |l: [f64; 3], _: [f64; 3]| if l[2] > 0.9 { 1.0 } else if l[2] > 0.5 { 2.0 } else { 3.0 };
    check_dirs(&raw("L.z > 0.9 ? 1 : L.z > 0.5 ? 2 : 3"), three);
    check_dirs(&raw("if L.z > 0.9 then 1\nelse if L.z > 0.5 then 2\nelse 3"), three);
    // A vector select picks whole vectors.
    check_dirs(&raw("(L.x > 0 ? L : V).y"), |l, v| if l[0] > 0.0 { l[1] } else { v[1] });
}

#[test]
fn the_untaken_branch_never_reaches_the_result() {
    // `inf` is 1/0 at run time (V.z - V.z), so no front-end folding hides it.
    let inf = "let inf = 1 / (V.z - V.z)\n";
    for (l, v) in directions() {
        assert_eq!(channels_at(&format!("@domain raw\n{inf}L.z > 0 ? 2 : inf"), l, v, &[]), vec![2.0]);
        assert_eq!(channels_at(&format!("@domain raw\n{inf}if L.z <= 0 then inf - inf else 3"), l, v, &[]), vec![3.0]);
        assert_eq!(channels_at(&format!("@domain raw\n{inf}L.z > 0 && inf - inf > 0 ? 1 : 4"), l, v, &[]), vec![4.0]);
        // The 0/1 blend the select replaces gives NaN (0 · inf).
        let blend = format!("@domain raw\n{inf}let c = L.z > 0 ? 1 : 0\nc * 2 + (1 - c) * inf");
        assert!(channels_at(&blend, l, v, &[])[0].is_nan());
    }
}

#[test]
fn bool_and_colour_parameters_and_set() {
    let src = "param base = rgb(0.8, 0.6, 0.2)\nparam shiny = true\nparam k = 2 in 0..10\n\
               shiny ? base * k * L.z : vec3(L.z)";
    let f = formula(src);
    let kinds: Vec<_> = f.params.iter().map(|p| (p.name.as_str(), p.kind, p.default, p.lo, p.hi)).collect();
    use lobe::ir::ParamKind::*;
    assert_eq!(
        kinds,
        vec![
            ("n", Float, 50.0, 1.0, 1000.0),
            ("base.r", Color(0), 0.8, 0.0, 1.0),
            ("base.g", Color(1), 0.6, 0.0, 1.0),
            ("base.b", Color(2), 0.2, 0.0, 1.0),
            ("shiny", Bool, 1.0, 0.0, 1.0),
            ("k", Float, 2.0, 0.0, 10.0),
        ]
    );
    assert!(f.is_rgb());
    let (l, v) = directions()[0];
    let got = channels_at(src, l, v, &[]);
    for (g, b) in got.iter().zip([0.8, 0.6, 0.2]) {
        assert!(close(*g, b * 2.0 * l[2]), "{got:?}");
    }
    // `--set` values, through the same parser the CLI and the server use.
    let set = lobe::front::parse_assignments("base.r=0.5, shiny=false").expect("valid");
    assert_eq!(set, vec![("base.r".to_string(), 0.5), ("shiny".to_string(), 0.0)]);
    let set: Vec<(&str, f64)> = set.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    assert_eq!(channels_at(src, l, v, &set), vec![l[2]; 3]);
    assert!(close(channels_at(src, l, v, &[("base.r", 0.5)])[0], 0.5 * 2.0 * l[2]));
    assert!(lobe::front::parse_assignments("base.w=1").is_err());
    assert!(lobe::front::parse_assignments("shiny=maybe").is_err());
}

#[test]
fn user_functions_inline_with_the_types_of_each_call() {
    let raw = |s: &str| format!("@domain raw\n{s}");
    check_dirs(&raw("fn sqr(x) = x * x\nsqr(L.z) + sqr(vec3(1, 2, 3)).z"), |l, _| l[2] * l[2] + 9.0);
    check_dirs(&raw("fn sqr(x) = x * x\nfn len2(v) = sqr(v.x) + sqr(v.y) + sqr(v.z)\nlen2(L - V)"), |l, v| {
        let d = [l[0] - v[0], l[1] - v[1], l[2] - v[2]];
        dot3(d, d)
    });
    check_dirs(&raw("param a = 2\nfn pick(c, x, y) = c ? x * a : y\npick(L.z > 0.5, L.z, V.z)"), |l, v| {
        if l[2] > 0.5 { 2.0 * l[2] } else { v[2] }
    });
    // A function called twice with the same arguments is one expansion (hash-consed, memoised).
    let f = formula("fn g(x) = acos(x) * 2\ng(NH) + g(NH)");
    let acos = f.ir.nodes().iter().filter(|n| matches!(n, lobe::ir::Node::Call(Builtin::Acos, _))).count();
    assert_eq!(acos, 1);
}

#[test]
fn examples_in_the_vector_folder_parse_and_evaluate() {
    let files = brdf_files("examples/vector");
    for (p, src) in &files {
        let (_, warnings) = parse_with_warnings(&p.display().to_string(), src).unwrap_or_else(|d| panic!("{d}"));
        assert!(warnings.items.is_empty(), "{}: {}", p.display(), warnings.render(false));
        for (l, v) in directions() {
            for c in channels_at(src, l, v, &[]) {
                assert!(c.is_finite() && c >= 0.0, "{}: {c}", p.display());
            }
        }
    }
    assert!(files.len() >= 3);
    // Anisotropic Ward by hand at one pair of directions.
    let src = &files.iter().find(|f| f.0.ends_with("ward_anisotropic.brdf")).expect("ward").1;
    let (l, v) = directions()[0];
    let h = half(l, v);
    let (ax, ay) = (0.1, 0.4);
    let want = (-2.0 * ((h[0] / ax).powi(2) + (h[1] / ay).powi(2)) / (1.0 + h[2])).exp()
        / (4.0 * std::f64::consts::PI * ax * ay * (l[2] * v[2]).sqrt());
    let got = channels_at(src, l, v, &[]);
    assert!((got[0] - want).abs() <= 1e-12 * want, "{got:?} vs {want}");
    // Stretched: rotating the directions by 90° about N changes the value (X and Y differ).
    let rot = |d: [f64; 3]| [-d[1], d[0], d[2]];
    assert!((channels_at(src, rot(l), rot(v), &[])[0] - got[0]).abs() > 1e-6 * got[0]);
}

/// Random well-typed source text in the vector/bool language: `t` is 0 float, 1 bool, 2 vec3.
fn gen_typed(r: &mut Rng, t: u32, depth: u32) -> String {
    let leaf = depth == 0 || r.below(4) == 0;
    let f = |r: &mut Rng| gen_typed(r, 0, depth.saturating_sub(1));
    let b = |r: &mut Rng| gen_typed(r, 1, depth.saturating_sub(1));
    let v = |r: &mut Rng| gen_typed(r, 2, depth.saturating_sub(1));
    match (t, leaf) {
        (0, true) => {
            let names = ["L.x", "V.y", "Lz", "NH", "VR", "LV", "HX", "k", "base.g", "0.5", "2", "3"];
            names[r.below(names.len() as u64) as usize].to_string()
        }
        (0, false) => match r.below(9) {
            0..=2 => {
                let op = ["+", "-", "*", "/"][r.below(4) as usize];
                format!("({} {op} {})", f(r), f(r))
            }
            3 => {
                let g = ["min", "max", "exp", "floor", "abs", "sqr", "fract", "sign"][r.below(8) as usize];
                if g == "min" || g == "max" { format!("{g}({}, {})", f(r), f(r)) } else { format!("{g}({})", f(r)) }
            }
            4 => format!("({} ? {} : {})", b(r), f(r), f(r)),
            5 => format!("(if {} then {} else {})", b(r), f(r), f(r)),
            6 => format!("{}.{}", v(r), ["x", "y", "z", "r", "g", "b"][r.below(6) as usize]),
            7 => format!("dot({}, {})", v(r), v(r)),
            _ => format!("step({}, {})", f(r), f(r)),
        },
        (1, true) => ["true", "false", "shiny", "(L.z > 0.5)"][r.below(4) as usize].to_string(),
        (1, false) => match r.below(5) {
            0 => {
                let op = ["<", "<=", ">", ">=", "==", "!="][r.below(6) as usize];
                format!("({} {op} {})", f(r), f(r))
            }
            1 => format!("({} && {})", b(r), b(r)),
            2 => format!("({} || {})", b(r), b(r)),
            3 => format!("!{}", b(r)),
            _ => format!("({} == {})", b(r), b(r)),
        },
        (_, true) => ["L", "V", "N", "X", "Y", "base", "vec3(0.25)"][r.below(7) as usize].to_string(),
        (_, false) => match r.below(5) {
            0 => format!("({} + {})", v(r), v(r)),
            1 => format!("({} * {})", v(r), f(r)),
            2 => format!("normalize({})", v(r)),
            3 => format!("({} ? {} : {})", b(r), v(r), v(r)),
            _ => format!("mix({}, {}, {})", v(r), v(r), f(r)),
        },
    }
}

/// The `param` lines that declare `f`'s parameters again (colour and bool kinds included).
fn param_lines(f: &Formula) -> String {
    use lobe::ir::ParamKind;
    let mut out = String::new();
    for (i, p) in f.params.iter().enumerate() {
        match p.kind {
            ParamKind::Float => out.push_str(&format!("param {} = {} in {}..{}\n", p.name, p.default, p.lo, p.hi)),
            ParamKind::Bool => out.push_str(&format!("param {} = {}\n", p.name, p.default != 0.0)),
            ParamKind::Color(0) => out.push_str(&format!(
                "param {} = rgb({}, {}, {})\n",
                p.name.trim_end_matches(".r"),
                p.default,
                f.params[i + 1].default,
                f.params[i + 2].default
            )),
            ParamKind::Color(_) => {}
        }
    }
    out
}

/// `lobe check`'s text of a formula parses back to the same values: comparisons and selects print in operator
/// form, bools and numbers convert where the printed place needs the other type.
#[test]
fn printed_formulas_with_the_new_constructs_parse_back_to_the_same_values() {
    let mut r = Rng(0x9E37_79B9_7F4A_7C15);
    let header = "param k = 1.5 in 0..4\nparam shiny = true\nparam base = rgb(0.8, 0.5, 0.25)\nfn sqr(x) = x * x\n";
    let (mut checked, mut skipped) = (0, 0);
    for case in 0..300 {
        let ty = if case % 3 == 2 { 2 } else { 0 };
        let body = gen_typed(&mut r, ty, 5);
        let src = format!("{header}{body}");
        let f = match parse_with_warnings("rand.brdf", &src) {
            Ok((f, _)) => f,
            Err(d) => panic!("case {case}: {src}\n{}", d.render(false)),
        };
        for c in f.channels() {
            for simplified in [false, true] {
                let c = if simplified { lobe::simplify::simplify(&c, &[]) } else { c.clone() };
                for text in [c.to_text(), c.to_program_text()] {
                    // Non-finite constants print as `(1/0)`, `(0/0)`, which read back; `inf`/`nan` would not.
                    if text.split(|ch: char| !ch.is_alphanumeric()).any(|w| w == "inf" || w == "nan") {
                        skipped += 1;
                    }
                    let again = format!("@domain raw\n{}{text}", param_lines(&c));
                    let g = parse("printed.brdf", &again)
                        .unwrap_or_else(|d| panic!("case {case}: {src}\nprinted:\n{again}\n{}", d.render(false)));
                    for (l, v) in directions() {
                        let x = lobe::numerics::inputs_from_dirs(l, v);
                        for shiny in [1.0, 0.0] {
                            let mut p = c.default_params();
                            p[c.param_index("shiny").expect("declared")] = shiny;
                            let (a, b) = (Interp::new(&c).eval(&x, &p), Interp::new(&g).eval(&x, &p));
                            assert!(
                                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                                "case {case}: {src}\nprinted:\n{again}\n{a} vs {b}"
                            );
                        }
                    }
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(skipped, 0, "printed texts with `inf`/`nan`, which do not parse");
    eprintln!("print → parse round trip: {checked} printed texts parse back to the same values");
}

/// About `bytes` of source in the new constructs: colour and bool parameters, a function, vectors, `if`,
/// `?:`, comparisons and `&&`, one `let` per line, each reading the previous one.
fn big_vector_source(bytes: usize) -> String {
    let mut src = String::from(
        "param base = rgb(0.8, 0.6, 0.2)\nparam shiny = true\nfn sqr(x) = x * x\nlet H = normalize(L + V)\nlet a0 = H.z\n",
    );
    let mut i = 1;
    while src.len() < bytes {
        src.push_str(&format!(
            "let a{i} = if dot(H, N) > 0.5 && shiny then sqr(a{}) * base.r else mix(a{}, L.z, 0.5)\n",
            i - 1,
            i - 1
        ));
        i += 1;
    }
    src.push_str(&format!("vec3(a{}) * base", i - 1));
    src
}

#[test]
fn one_mebibyte_of_the_new_constructs_parses_and_lowers_in_linear_time() {
    // Parse + lower time is printed (dev profile; BENCHMARKS.md has release numbers), never asserted.
    let mut times = vec![];
    for bytes in [1 << 19, 1 << 20] {
        let src = big_vector_source(bytes);
        let t = std::time::Instant::now();
        let f = formula(&src);
        times.push(t.elapsed().as_secs_f64());
        assert!(f.is_rgb());
        let (l, v) = directions()[0];
        assert!(channels_at("param base = rgb(0.8, 0.6, 0.2)\nL.z * base", l, v, &[])[0] > 0.0);
    }
    eprintln!("parse+lower: 0.5 MiB {:.3} s, 1 MiB {:.3} s, ratio {:.2}", times[0], times[1], times[1] / times[0]);
    // The print → parse round trip at this size: `lobe check`'s text of the red channel, parsed again.
    let f = formula(&big_vector_source(1 << 20));
    let red = &f.channels()[0];
    let t = std::time::Instant::now();
    let text = format!("@domain raw\n{}{}", param_lines(red), red.to_program_text());
    let printed = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let again = formula(&text);
    let reparsed = t.elapsed().as_secs_f64();
    for (l, v) in directions() {
        let x = lobe::numerics::inputs_from_dirs(l, v);
        let p = red.default_params();
        assert_eq!(Interp::new(red).eval(&x, &p).to_bits(), Interp::new(&again).eval(&x, &p).to_bits());
    }
    eprintln!("round trip of {} nodes: print {printed:.3} s ({} bytes), parse+lower {reparsed:.3} s", red.ir.len(), text.len());
}

#[test]
fn deep_selects_and_bool_chains_do_not_overflow() {
    // A right spine of `?:` 200 000 deep, an `if` chain, a left spine of `&&`, a `!` chain.
    let k = 200_000;
    let mut src = String::from("@domain raw\n");
    for i in 0..k {
        src.push_str(&format!("L.z > {} ? {i} : ", i as f64 / k as f64));
    }
    src.push_str("-1");
    let (l, v) = ([0.6, 0.0, 0.8], [0.0, 0.0, 1.0]);
    // The interpreter only: these formulas have ~10^5 nodes (the JIT is tested on real-sized ones).
    let channels_at = |src: &str, l: [f64; 3], v: [f64; 3], _: &[(&str, f64)]| {
        let f = formula(src);
        let x = lobe::numerics::inputs_from_dirs(l, v);
        f.channels().iter().map(|c| Interp::new(c).eval(&x, &c.default_params())).collect::<Vec<f64>>()
    };
    assert_eq!(channels_at(&src, l, v, &[]), vec![0.0]);
    let mut src = String::from("@domain raw\n");
    for i in 0..k {
        src.push_str(&format!("if L.z > {} then {i} else\n", 1.0 - i as f64 / k as f64));
    }
    src.push_str("-1");
    let want = (1..k).find(|&i| 0.8 > 1.0 - i as f64 / k as f64).expect("some level") as f64;
    assert_eq!(channels_at(&src, l, v, &[]), vec![want]);
    let src = format!("({}) ? 1 : 2", vec!["L.z > 0.5"; k].join(" && "));
    assert_eq!(channels_at(&src, l, v, &[]), vec![1.0]);
    let src = format!("{}true ? 3 : 4", "!".repeat(1 << 20));
    assert_eq!(eval(&src), 3.0);
    // Nested user functions: a chain deeper than the inlining limit, and an exponential expansion, are
    // refused with a message (not a stack overflow, not a hang).
    // `fn f0(x) = x * 2`, then `fn fI(x) = body(fI-1)` for I < n, then `tail`.
    let chain = |n: usize, body: &dyn Fn(&str) -> String, tail: &str| {
        let mut src = String::from("fn f0(x) = x * 2\n");
        for i in 1..n {
            src.push_str(&format!("fn f{i}(x) = {}\n", body(&format!("f{}", i - 1))));
        }
        src + tail
    };
    let src = chain(100, &|g| format!("{g}(x) + 1"), "f99(NH)");
    let Err(d) = parse("chain.brdf", &src) else { panic!("a 100-deep chain of calls was accepted") };
    assert!(d.render(false).contains("nested more than 64 deep"), "{d}");
    let src = chain(60, &|g| format!("{g}(x * 2) + {g}(x * 3)"), "f59(NH)");
    let Err(d) = parse("blowup.brdf", &src) else { panic!("2^59 distinct expansions were accepted") };
    assert!(d.render(false).contains("too large a formula"), "{d}");
    // Calls with equal arguments expand once (memoised): sixty levels of doubling are accepted.
    check(&chain(60, &|g| format!("{g}(x) + {g}(x)"), "f59(NH) / 2^60"), 0.9);
}

/// A formula that shares much (forty functions, each calling the one before twice: a tree of 2^40 nodes) prints
/// in the size of its DAG: `let` lines instead of the inlined tree; a small formula still prints inline.
#[test]
fn text_of_a_self_doubling_formula_stays_small() {
    let mut src = String::from("fn f0(x) = x*NH + NV\n");
    for i in 1..=40 {
        src += &format!("fn f{i}(x) = f{j}(x) * f{j}(x + 1)\n", j = i - 1);
    }
    src += "f40(NH)\n";
    let f = parse("chain.brdf", &src).unwrap();
    let t0 = std::time::Instant::now();
    let text = f.to_text();
    assert!(text.len() < 1 << 20 && text.contains("let "), "{} bytes", text.len());
    assert!(t0.elapsed() < std::time::Duration::from_secs(10));
    let small = parse("p.brdf", "NH * NV + NH").unwrap().to_text();
    assert!(!small.contains("let ") && small.matches("NH").count() == 2, "{small}");
}
