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
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/brdfs");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).expect("examples/brdfs exists") {
        let p = e.expect("dir entry").path();
        if p.extension().is_none_or(|x| x != "brdf") {
            continue;
        }
        let src = std::fs::read_to_string(&p).expect("readable");
        parse(&p.display().to_string(), &src).unwrap_or_else(|d| panic!("{}:\n{d}", p.display()));
        n += 1;
    }
    assert!(n >= 2, "found only {n} catalogue files");
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
