//! Snapshot tests of the rendered diagnostics: every `tests/snapshots/parse_errors/NAME.brdf` goes through the
//! front end and the whole rendered text (`Diagnostics::render(false)`) is compared with `NAME.txt` beside it.
//! `LOBE_BLESS=1 cargo test parse_errors` rewrites the `.txt` files; read them by eye before committing.
//! Files named `warn_*` must parse (their snapshot holds the warnings); every other file must be rejected.

use std::fs;
use std::path::{Path, PathBuf};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots/parse_errors")
}

fn render(name: &str, src: &str) -> (bool, String) {
    match lobe::front::parse_with_warnings(name, src) {
        Ok((_, warnings)) => (true, warnings.render(false)),
        Err(d) => {
            // `parse` must reject it too, with the same report.
            let again = lobe::front::parse(name, src).err().map(|d| d.render(false));
            assert_eq!(again.as_deref(), Some(d.render(false).as_str()), "{name}: parse and parse_with_warnings differ");
            (false, d.render(false))
        }
    }
}

fn cases() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = fs::read_dir(dir())
        .expect("tests/snapshots/parse_errors exists")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "brdf"))
        .collect();
    v.sort();
    v
}

#[test]
fn rendered_diagnostics_match_snapshots() {
    let bless = std::env::var("LOBE_BLESS").is_ok_and(|v| v == "1");
    let cases = cases();
    assert!(cases.len() >= 15, "expected at least 15 snapshot cases, found {}", cases.len());
    let mut failures = vec![];
    for path in cases {
        let file = path.file_name().and_then(|s| s.to_str()).unwrap_or("?").to_string();
        let src = fs::read_to_string(&path).expect("readable case");
        let (ok, text) = render(&file, &src);
        let warn_case = file.starts_with("warn_");
        assert_eq!(ok, warn_case, "{file}: accepted = {ok}\n{text}");
        assert!(!text.trim().is_empty(), "{file}: no diagnostics at all");
        assert!(!text.contains("panicked"), "{file}");
        let snap = path.with_extension("txt");
        if bless {
            fs::write(&snap, &text).expect("write snapshot");
            continue;
        }
        match fs::read_to_string(&snap) {
            Ok(want) if want == text => {}
            Ok(want) => failures.push(format!("{file}: rendered text differs\n--- want\n{want}\n--- got\n{text}")),
            Err(_) => failures.push(format!("{file}: no snapshot {} (run with LOBE_BLESS=1)\n{text}", snap.display())),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// The substance of each message, checked independently of the snapshot text (so a careless bless that
/// loses the point of a message still fails).
#[test]
fn each_mistake_gets_its_message_and_hint() {
    let want: &[(&str, &[&str])] = &[
        ("unknown_variable", &["unknown variable `NX`; did you mean `NH`?", "2:1"]),
        ("unknown_function", &["unknown function `acoss`; did you mean `acos`?"]),
        ("wrong_arity", &["pow takes 2 arguments, found 3"]),
        ("function_as_variable", &["`cos` is a function, not a variable"]),
        ("variable_as_function", &["`c` is a variable, not a function"]),
        ("unterminated_paren", &["unterminated parenthesis", "parenthesis opened here"]),
        ("unmatched_paren", &["unmatched `)`"]),
        ("missing_operator", &["missing operator between `2` and `NH`"]),
        ("trailing_operator", &["expected an operand after `+`"]),
        ("comments_only", &["the file has no formula"]),
        ("empty", &["the file has no formula"]),
        ("let_without_formula", &["`let` without a final expression"]),
        ("two_formulas", &["more than one final expression"]),
        ("duplicate_let", &["`c` is defined twice", "first defined here"]),
        ("shadowing", &["would shadow the constant pi", "would shadow the input NH", "would shadow the function"]),
        ("param_range", &["range of `a` is empty", "default 0 of `n` is outside", "too large"]),
        ("bad_numbers", &["`.5`", "`2.`", "`1e`", "write `0.5`"]),
        ("unknown_metadata", &["unknown metadata key `@title`"]),
        ("unterminated_string", &["unterminated string"]),
        ("stray_characters", &["unexpected character `$`", "unexpected character `√`", "sqrt(x)"]),
        ("too_deep", &["nested more than 200 deep"]),
        ("several_errors", &["`NX`", "missing operator between `2` and `3`", "pow takes 2", "unterminated", "`foo`"]),
        ("warn_unused", &["unused `let unused`", "parameter `a` is never used"]),
        ("warn_no_input", &["reads no input"]),
        ("let_after_formula", &["`let` after the formula"]),
        ("used_before_let", &["`b` is used before its `let`"]),
        ("duplicate_metadata", &["`@name` is given twice"]),
        ("double_star", &["`**` is not an operator"]),
        ("malformed_statements", &["a name after `let`", "expected `=` after `a`", "after `@name`"]),
        ("self_reference", &["`c` refers to itself"]),
        ("empty_parens", &["empty parentheses"]),
        ("duplicate_param", &["parameter `a` is declared twice", "parameter `n` is declared twice"]),
        ("type_errors", &[
            "`+` needs numbers or vectors, not vec3 and bool",
            "dot needs a vec3, not float",
            "compares two floats, not vec3 and vec3",
            "a condition needs a bool, not float",
            "both branches must have one type, not vec3 and float",
            "`.w` is not a component",
        ]),
        ("bool_result", &["the formula is a bool, not a number", "c ? 1 : 0"]),
        ("recursion", &["`fact` calls itself", "`odd` is called before its definition"]),
        ("unknown_functions", &[
            "unknown function `shad`; did you mean `shade`?",
            "shade takes 2 arguments, found 1",
            "unknown function `normalise`; did you mean `normalize`?",
            "unknown variable `HZ`; did you mean `HX`?",
        ]),
        ("loop_misuse", &["`for` loops are not part of the formula language", "`sum` is defined twice"]),
        ("case_mismatch", &["did you mean `NH`?", "did you mean `cos`?", "did you mean `pi`?"]),
        ("internal_builtins", &[
            "`expmuldiv` is internal to the accuracy pass, not a function of the language",
            "internal_builtins.brdf:3:9",
            "write `exp(a) * b / c`",
            "`acoslo` is internal to the accuracy pass, not a function of the language",
            "internal_builtins.brdf:4:20",
            "write `acos(x)`",
            "`powlo` is internal to the accuracy pass, not a function of the language",
            "internal_builtins.brdf:5:22",
            "write `pow(x, y)`",
            "`sinnear` is internal to the simplifier, not a function of the language",
            "internal_builtins.brdf:5:37",
            "write `sin(x)`",
        ]),
        ("internal_name_as_param", &["`acoslo` is a variable, not a function", "internal_name_as_param.brdf:3:1"]),
        ("digit_separators", &["number `1_000` has `_` between its digits", "write `1000`", "write `0.50`"]),
        ("param_default", &["a parameter's default must be a constant number, not `NH`", "not `2 * n`", "`let a = NH`"]),
        ("unterminated_string_then_more", &["unterminated string", "expected an expression, found `=`", "then_more.brdf:2:1"]),
        ("lone_cr", &["expected an operand after `^`", "lone_cr.brdf:3:12"]),
    ];
    for (name, needles) in want {
        let path = dir().join(format!("{name}.brdf"));
        let src = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let (_, text) = render(&format!("{name}.brdf"), &src);
        for n in *needles {
            assert!(text.contains(n), "{name}: expected `{n}` in\n{text}");
        }
        // Every diagnostic carries a hint.
        let heads = text.lines().filter(|l| l.starts_with("error") || l.starts_with("warning")).count();
        let helps = text.lines().filter(|l| l.contains("= help:")).count();
        assert!(helps >= heads, "{name}: {heads} diagnostics but {helps} hints\n{text}");
    }
    assert_eq!(want.len(), cases().len(), "every snapshot case has an entry in this table");
    // No message quotes a raw line break of the source (the caret lines show the source itself, line by line).
    for path in cases() {
        let src = fs::read_to_string(&path).expect("readable case");
        let d = match lobe::front::parse_with_warnings("f.brdf", &src) {
            Ok((_, w)) => w,
            Err(d) => d,
        };
        for item in &d.items {
            let text = format!("{item}");
            assert!(!text.contains(['\n', '\r']), "{}: {text:?}", path.display());
        }
        assert!(!d.render(false).contains('\r'), "{}: a raw CR in the rendered text", path.display());
    }
}

#[test]
fn several_errors_are_all_reported() {
    let src = fs::read_to_string(dir().join("several_errors.brdf")).expect("case");
    let d = lobe::front::parse("several_errors.brdf", &src).expect_err("rejected");
    assert!(d.errors().count() >= 5, "{}", d.render(false));
}

/// The accuracy pass's internal builtins are no names of the language: user text may use them for its own
/// parameters, `let`s and functions (which are then what the name means, never the builtin), names no builtin
/// by them in a hint or suggestion, and refuses them as calls. `parse_internal` reads them back as calls — and
/// there, as every builtin's name, they are reserved.
#[test]
fn internal_builtin_names_are_free_in_user_text() {
    use lobe::builtins::Builtin;
    use lobe::ir::Node;
    let internal = |f: &lobe::Formula| f.ir.nodes().iter().any(|n| matches!(n, Node::Call(b, _) if b.is_internal()));
    for src in [
        "param acoslo = 2 in 0..4\nacoslo * NH",
        "let powlo = NH * NH\npowlo + NL",
        "fn expmuldiv(a, b, c) = exp(a) * b / c\nexpmuldiv(NH - 1, 2, NL)",
        "fn acoslo(x) = acos(x)\nacoslo(NH)",
    ] {
        let f = lobe::front::parse("free.brdf", src).unwrap_or_else(|d| panic!("{src}\n{}", d.render(false)));
        assert!(!internal(&f), "{src}: became an internal builtin");
        let d = lobe::front::parse_internal("free.brdf", src).expect_err(src).render(false);
        assert!(d.contains("would shadow the function"), "{src}: parse_internal reserves the name\n{d}");
    }
    for name in ["expmuldiv", "acoslo", "powlo"] {
        let b = Builtin::from_name(name).unwrap();
        assert!(b.is_internal());
        let args = vec!["NH"; b.arity()].join(", ");
        let call = format!("{name}({args})");
        let f = lobe::front::parse_internal("internal.brdf", &call).unwrap_or_else(|d| panic!("{}", d.render(false)));
        assert!(internal(&f), "{call}");
        let d = lobe::front::parse("user.brdf", &call).expect_err(&call).render(false);
        assert!(d.contains(&format!("`{name}` is internal to the accuracy pass")) && d.contains("user.brdf:1:1"), "{d}");
        // Named without a call, too; and never a suggestion for a near miss nor in the list of functions.
        let d = lobe::front::parse("user.brdf", &format!("NH * {name}")).expect_err(name).render(false);
        assert!(d.contains(&format!("`{name}` is internal to the accuracy pass")), "{d}");
        for typo in [format!("{name}x({args})"), format!("{}({args})", &name[..name.len() - 1])] {
            let d = lobe::front::parse("user.brdf", &typo).expect_err(&typo).render(false);
            assert!(!d.contains(&format!("`{name}`")) && !d.contains(&format!(" {name},")), "{typo}:\n{d}");
        }
    }
    let d = lobe::front::parse("user.brdf", "zzqq(NH)").expect_err("unknown").render(false);
    assert!(d.contains("the functions are pow, cos") && !d.contains("acoslo") && !d.contains("powlo") && !d.contains("expmuldiv"), "{d}");
}
