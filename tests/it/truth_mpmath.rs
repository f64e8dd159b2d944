//! The truth evaluator (`lobe::numerics::truth`, ~104-bit mantissas with an unbounded exponent) against an
//! independent arbitrary-precision library: mpmath at 2 300 bits (any sum of two f64s exact), with every
//! builtin's semantics written again in Python (`truth_mpmath.py`, beside this file).
//!
//! Every builtin of the table at its domain's edges (zero, subnormals, ±1 and its neighbours, poles, overflow
//! and underflow of f64, cancelling fused products) and at random arguments agrees to 1e-25 relative wherever
//! mpmath's value is a finite non-zero number (and is exactly 0, the same infinity or NaN where mpmath's is),
//! (sin, cos and tan of every f64, huge ones by Payne–Hanek reduction), within the truth's stated reach for exp
//! (|x| ≤ 10⁶) and pow (|y·ln|x|| ≤ 10⁶): the exponent's absolute error is |x|·2⁻¹⁰⁶, and every f64 base to the
//! exponents of the language's parameters is inside. Beyond that reach they round to the same f64 as mpmath's.
//!
//! The BRDF Explorer example files at hard points (grazing, subnormal and exactly-zero direction components) and
//! random ones agree to 1e-25 as well: there the exact value can need far more than the double-double's 104 bits
//! (1 − 2⁻¹⁰⁷⁵; tan of acos(2.75e-309), which is 3.6e308, not the ±2¹⁰⁴ of π/2 to 104 bits), which the truth's
//! error bound sees and its arbitrary-precision evaluation settles. Values below every exponent the truth holds
//! (an exponential of an argument past −2⁶²: mpmath's 10^(−10⁶⁴)) are left out, both positive and below
//! 2^(−2⁵⁹).
//!
//! Needs Python with mpmath (`LOBE_MPMATH_PYTHON`, else `python3`). Without it the test prints a note and passes,
//! unless `LOBE_REQUIRE_MPMATH=1` (set by `.ci/run`).

use lobe::builtins::Builtin;
use lobe::ir::{BinOp, Formula, Node, N_INPUTS};
use lobe::numerics::truth;
use serde_json::{json, Value};
use std::io::Write;
use std::process::{Command, Stdio};

const TOLERANCE: f64 = 1e-25;

/// An f64 as text Python's `float()` reads back exactly (the shortest round trip; `inf`, `-inf`, `NaN`).
fn text(x: f64) -> String {
    format!("{x:?}")
}

fn python() -> Option<String> {
    let py = std::env::var("LOBE_MPMATH_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&py).args(["-c", "import mpmath"]).output().is_ok_and(|o| o.status.success());
    if ok {
        return Some(py);
    }
    let msg = format!("{py} with mpmath is not available: the truth's cross-check against mpmath did not run");
    assert!(std::env::var("LOBE_REQUIRE_MPMATH").map_or(true, |v| v != "1"), "{msg}; LOBE_REQUIRE_MPMATH=1 makes this a failure");
    eprintln!("note: {msg}");
    None
}

/// A formula's nodes up to its root as the Python program reads them.
fn program(f: &Formula) -> Vec<Value> {
    f.ir.ids()
        .take(f.root.0 as usize + 1)
        .map(|id| match *f.ir.node(id) {
            Node::Const(b) => json!(["const", text(f64::from_bits(b))]),
            Node::Input(i) => json!(["input", i.index()]),
            Node::Param(p) => json!(["param", p]),
            Node::Column(_) => json!(["const", "NaN"]),
            Node::Neg(a) => json!(["neg", a.0]),
            Node::Binary(op, a, b) => {
                let op = match op {
                    BinOp::Add => "add",
                    BinOp::Sub => "sub",
                    BinOp::Mul => "mul",
                    BinOp::Div => "div",
                };
                json!(["bin", op, a.0, b.0])
            }
            Node::Call(b, args) => json!(["call", b.name(), args[..b.arity()].iter().map(|a| a.0).collect::<Vec<_>>()]),
        })
        .collect()
}

fn parts(p: (f64, f64, i64)) -> Value {
    json!([text(p.0), text(p.1), p.2])
}

/// How a case is judged: to [`TOLERANCE`] relative (`true`), or beyond the truth's reach by its rounding to f64.
fn within_reach(b: Builtin, args: &[f64]) -> bool {
    match b {
        Builtin::Exp | Builtin::ExpMulDiv => args[0].abs() <= 1e6,
        Builtin::Pow => (args[1] * args[0].abs().ln()).abs() <= 1e6 || args[0] == 0.0 || args[1] == 0.0,
        _ => true,
    }
}

/// One builtin on its arguments: a program of the arguments as parameters and the call.
fn builtin_case(b: Builtin, args: &[f64]) -> Value {
    let mut nodes: Vec<Value> = (0..args.len()).map(|k| json!(["param", k])).collect();
    nodes.push(json!(["call", b.name(), (0..args.len()).collect::<Vec<_>>()]));
    json!({"what": format!("{}({})", b.name(), args.iter().map(|a| format!("{a:e}")).collect::<Vec<_>>().join(", ")),
           "nodes": nodes, "inputs": [], "params": args.iter().map(|a| text(*a)).collect::<Vec<_>>(),
           "truth": parts(truth::call_parts(b, args)), "exact": within_reach(b, args)})
}

/// Arguments at each builtin's domain edges, and random ones (log-uniform magnitudes, both signs).
fn builtin_cases(rng: &mut lobe::base::rng::Rng) -> Vec<Value> {
    let tiny = [5e-324, 1e-310, f64::MIN_POSITIVE, 1e-300, 1e-160, 1e-20, 1e-8];
    let one = [1.0, 1.0f64.next_up(), 1.0f64.next_down(), 1.0 + 1e-10, 1.0 - 1e-10, 0.5, 2.0];
    let huge = [1e8, 1e15, 1e22, 1e100, 1e300, f64::MAX];
    let half_pi = std::f64::consts::FRAC_PI_2;
    let mut edges: Vec<f64> = [0.0].iter().chain(&tiny).chain(&one).chain(&huge).copied().collect();
    edges.extend([half_pi, half_pi.next_up(), half_pi.next_down(), std::f64::consts::PI, 3.0 * half_pi, 700.0, 709.7, 745.0, 1000.0, 1e5]);
    let signed: Vec<f64> = edges.iter().flat_map(|&x| [x, -x]).collect();
    let mut random = |n: usize| -> Vec<f64> {
        (0..n).map(|_| {
            let m = 10f64.powf(rng.unit() * 40.0 - 20.0);
            if rng.unit() < 0.5 { -m } else { m }
        }).collect()
    };
    let r1 = random(300);
    let unit: Vec<f64> = (0..300).map(|_| 2.0 * (random(1)[0].abs() % 1.0) - 1.0).collect();
    let mut cases = vec![];
    for b in Builtin::ALL {
        let a = b.arity();
        let pts: Vec<Vec<f64>> = match (b, a) {
            (Builtin::Acos | Builtin::Asin | Builtin::AcosLo, _) => signed.iter().chain(&unit).filter(|x| x.abs() <= 1.0).map(|&x| vec![x]).collect(),
            (_, 1) => signed.iter().chain(&r1).map(|&x| vec![x]).collect(),
            (Builtin::Pow | Builtin::PowLo, _) => {
                let ys = [0.0, 0.5, 1.0, 2.0, 3.0, 5.0, -1.0, -2.0, -0.5, 1e-10, 1e10, 1e15, -1e15, 2.5, 1000.0, -1000.0, 1e300];
                let xs: Vec<f64> = edges.iter().copied().chain([-2.5, -1.0, -1e-300, -7.0]).collect();
                let mut v: Vec<Vec<f64>> = xs.iter().flat_map(|&x| ys.iter().map(move |&y| vec![x, y])).collect();
                v.extend(r1.iter().zip(r1.iter().rev()).map(|(&x, &y)| vec![x.abs(), y / 1e10]));
                v
            }
            (Builtin::Fma, _) => {
                // Cancelling products: fma(a, b, −round(a·b)) is the product's rounding error, exactly.
                let mut v: Vec<Vec<f64>> = r1.iter().zip(r1.iter().skip(1)).map(|(&x, &y)| vec![x, y, -(x * y)]).collect();
                v.extend(r1.iter().zip(r1.iter().skip(2)).zip(r1.iter().skip(3)).map(|((&x, &y), &z)| vec![x, y, z]));
                v
            }
            (Builtin::ExpMulDiv, _) => {
                let xs = [-1000.0, -745.0, -700.0, -1.0, 0.0, 1.0, 700.0, 745.0, 1000.0];
                let ys = [1e-300, 1e-20, 1.0, 1e20, 1e300, 5e-324];
                let mut v = vec![];
                for x in xs {
                    for y in ys {
                        for z in ys {
                            v.push(vec![x, y, z]);
                        }
                    }
                }
                v
            }
            (_, 2) => signed.iter().flat_map(|&x| [vec![x, 1.0], vec![x, -x], vec![x, x.next_up()]]).chain(r1.chunks(2).map(|c| c.to_vec())).collect(),
            (_, _) => signed.iter().flat_map(|&x| [vec![x, -1.0, 1.0], vec![1.0, x, -x], vec![0.0, x, 2.0]]).collect(),
        };
        cases.extend(pts.iter().map(|p| builtin_case(b, p)));
    }
    cases
}

/// The explorer example files at hard points (components exactly 0, subnormal, near grazing) and random ones.
fn explorer_cases(rng: &mut lobe::base::rng::Rng) -> Vec<Value> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer");
    let mut files: Vec<_> = std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "brdf")).collect();
    files.sort();
    let mut cases = vec![];
    let zs = [0.0, 5e-324, 1.2e-322, 2.75e-309, 1e-300, 6e-172, 1e-20, 1e-8, 0.05, 0.5, 1.0];
    for path in files {
        let name = path.display().to_string();
        let f = lobe::front::parse(&name, &std::fs::read_to_string(&path).unwrap()).unwrap();
        let prog: Vec<Value> = program(&f);
        let chans = f.channels();
        for k in 0..120 {
            let dir = |z: f64, u: f64| {
                let phi = std::f64::consts::TAU * u;
                let s = (1.0 - z * z).max(0.0).sqrt();
                [s * phi.cos(), s * phi.sin(), z]
            };
            let (zl, zv) = if k < 40 { (zs[k % zs.len()], zs[(k / 3) % zs.len()]) } else { (rng.unit(), rng.unit()) };
            let (l, v) = (dir(zl, rng.unit()), dir(zv, rng.unit()));
            let x: [f64; N_INPUTS] = lobe::numerics::inputs_from_dirs(l, v);
            let params: Vec<f64> = f.params.iter().map(|d| if (d.hi - d.lo).is_finite() { d.lo + (d.hi - d.lo) * rng.unit() } else { d.default }).collect();
            for chan in &chans {
                let nodes = if chans.len() == 1 { prog.clone() } else { program(chan) };
                cases.push(json!({"what": format!("{name} at L {l:?} V {v:?} params {params:?}"), "nodes": nodes,
                    "inputs": x.iter().map(|a| text(*a)).collect::<Vec<_>>(), "params": params.iter().map(|a| text(*a)).collect::<Vec<_>>(),
                    "truth": parts(truth::eval_parts(chan, &x, &params)), "exact": true}));
            }
        }
    }
    cases
}

/// Runs the cases through the Python script; per case the script's answer.
fn through_mpmath(py: &str, cases: &[Value]) -> Vec<Value> {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/it/truth_mpmath.py");
    let mut child = Command::new(py).arg(&script).stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let input = serde_json::to_vec(cases).unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || stdin.write_all(&input));
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let res: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(res.len(), cases.len());
    res
}

/// Whether a case's value lies beyond every exponent the truth holds, in both: an exponential of an argument
/// past −2⁶² (the truth's module docs) is the truth's smallest positive value, 2^(−2⁶⁰) (times what multiplies
/// it), where mpmath's is 10^(−10⁶⁴). Both round to 0 and stay positive; their ratio is not a measure of error.
fn beyond_exponents(c: &Value, r: &Value) -> bool {
    let limit = -(2f64.powi(59));
    let truth_e = c["truth"][2].as_f64().unwrap_or(0.0);
    let re = r["ref"].as_str().unwrap_or("");
    let mpmath_log2 = re.split_once('e').and_then(|(_, e)| e.parse::<f64>().ok()).map_or(0.0, |e| e * std::f64::consts::LOG2_10);
    let same_sign = re.starts_with('-') == c["truth"][0].as_str().unwrap_or("").starts_with('-');
    truth_e < limit && mpmath_log2 < limit && same_sign
}

/// The disagreements among `cases` (each judged as its `exact` says), the count judged to 1e-25 and the worst.
fn judge(cases: &[Value], res: &[Value]) -> (Vec<String>, usize, (f64, String)) {
    let (mut judged, mut worst, mut failures) = (0usize, (0.0f64, String::new()), vec![]);
    for (c, r) in cases.iter().zip(res) {
        let what = c["what"].as_str().unwrap();
        let head = c["truth"][0].as_str().unwrap();
        let same_f64 = r["same_f64"].as_bool().unwrap();
        if !c["exact"].as_bool().unwrap() {
            if !same_f64 {
                failures.push(format!("{what}: beyond the truth's reach, and not the same f64 (mpmath {}, truth {})", r["ref"], c["truth"]));
            }
            continue;
        }
        match r["rel"].as_f64() {
            Some(_) if beyond_exponents(c, r) => {}
            Some(rel) => {
                judged += 1;
                if rel > worst.0 {
                    worst = (rel, what.to_string());
                }
                if rel.is_nan() || rel > TOLERANCE {
                    failures.push(format!("{what}: relative difference {rel:e} (mpmath {}, truth {})", r["ref"], c["truth"]));
                }
            }
            None => {
                // mpmath's value is 0, ±∞ or NaN: the truth's must be that too (its head, exactly).
                let re = r["ref"].as_str().unwrap();
                let ok = match re {
                    "0" => head == "0.0" || head == "-0.0",
                    "+inf" => head == "inf",
                    "-inf" => head == "-inf",
                    _ => head == "NaN",
                };
                if !ok {
                    failures.push(format!("{what}: mpmath {re}, truth {:?}", c["truth"]));
                }
            }
        }
    }
    (failures, judged, worst)
}

/// Runs `cases` through mpmath and judges them, printing the summary line (`what`: the cases' kind); `None`
/// without a Python with mpmath.
fn compared(what: &str, cases: &[Value]) -> Option<Vec<String>> {
    let py = python()?;
    let res = through_mpmath(&py, cases);
    let (failures, judged, worst) = judge(cases, &res);
    eprintln!("{what} against mpmath: {judged} of {} judged to {TOLERANCE:e}, worst relative {:e} at {}", cases.len(), worst.0, worst.1);
    Some(failures)
}

#[test]
fn the_truth_agrees_with_mpmath_on_every_builtin() {
    let Some(failures) = compared("builtin calls", &builtin_cases(&mut lobe::base::rng::Rng(0x3A7E))) else { return };
    assert!(failures.is_empty(), "{} disagreements, e.g.\n{}", failures.len(), failures.iter().take(25).cloned().collect::<Vec<_>>().join("\n"));
}

/// The explorer example files at hard and random points agree with mpmath to 1e-25 (module docs), per file.
#[test]
fn the_truth_agrees_with_mpmath_on_the_explorer_files() {
    let Some(failures) = compared("explorer files' points", &explorer_cases(&mut lobe::base::rng::Rng(0x3A7F))) else { return };
    let mut by_file = std::collections::BTreeMap::<String, usize>::new();
    for f in &failures {
        *by_file.entry(f.split(" at ").next().unwrap_or("").to_string()).or_default() += 1;
    }
    for (file, n) in &by_file {
        eprintln!("  {file}: {n} disagreements");
    }
    for f in failures.iter().take(12) {
        eprintln!("  e.g. {}", f.chars().take(400).collect::<String>());
    }
    assert!(failures.is_empty(), "{} disagreements with mpmath (above)", failures.len());
}
