//! Grammar-based fuzzing on stable Rust: random .brdf *programs* (metadata, parameters with ranges, `let`
//! chains sharing subexpressions, every builtin and operator, numbers from denormal to 1e300, legal line
//! breaks and comments), a quarter of them then mutated at the character level (deletions, insertions of
//! stray tokens and hostile bytes, duplicated spans). Each goes text → parser → simplifier (with a random
//! subset of parameters baked) → interpreter and JIT (scalar and batched), and must:
//! - never panic, in any stage, nor when its diagnostics, its let-form text or its shader export are printed;
//! - give the same value on both backends (≤ 4 ulp, both NaN, or the same infinity) at hard inputs
//!   (0, 1, 1 ± ulp, denormals, out-of-range cosines) and at parameter values across their declared ranges.
//!
//! CI runs a short fixed-seed run. The long run (documented in README): `LOBE_FUZZ_CASES=1000000
//! LOBE_FUZZ_SEED=$RANDOM cargo test --release --test it fuzz -- --nocapture`; a failure prints the seed, the
//! case and the program, so it reproduces.

use crate::differential::agree;
use lobe::backend::glsl::{self, Dialect, GlslVersion};
use lobe::builtins::Builtin;
use lobe::{Backend, Columns, Evaluator, Kernel, Options, N_INPUTS};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::Instant;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }
    fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

const INPUTS: [&str; 5] = ["NL", "NV", "NH", "VR", "VH"];
const NUMBERS: [&str; 16] = ["0", "1", "2", "0.5", "1.25", "3", "10", "1e-3", "1e-300", "1e300", "1.5E+2", "0.0", "4", "1000", "2.5e-8", "7"];

/// One random program. `names` are what the final expression may refer to (grows with each `let`).
fn program(r: &mut Rng) -> String {
    let mut out = String::new();
    if r.chance(3) {
        out.push_str("@name \"fuzz case\"\n");
    }
    if r.chance(4) {
        out.push_str("@cite \"generated\" # with a comment\n");
    }
    let mut names: Vec<String> = vec!["n".into(), "pi".into()];
    for k in 0..r.below(4) {
        let name = format!("{}{k}", r.pick(&["a", "k", "m", "q", "rough"]));
        let (lo, hi) = *r.pick(&[(0.0, 1.0), (1.0, 1000.0), (-5.0, 5.0), (1e-3, 2.0)]);
        let def = lo + (hi - lo) * (r.below(5) as f64 / 4.0);
        if r.chance(3) {
            out.push_str(&format!("param {name} = {def}\n"));
        } else {
            out.push_str(&format!("param {name} = {def} in {lo}..{hi}\n"));
        }
        names.push(name);
    }
    if r.chance(5) {
        out.push_str("param n = 20 in 1..1000\n");
    }
    for k in 0..r.below(7) {
        let e = expr(r, &names, 3);
        let name = format!("t{k}x");
        out.push_str(&format!("let {name} = {e}"));
        out.push_str(if r.chance(4) { "; " } else { "\n" });
        names.push(name);
    }
    out.push_str(&expr(r, &names, 4));
    if r.chance(2) {
        out.push('\n');
    }
    out
}

fn expr(r: &mut Rng, names: &[String], depth: u32) -> String {
    if depth == 0 || r.chance(4) {
        return match r.below(3) {
            0 => r.pick(&NUMBERS).to_string(),
            1 => r.pick(&INPUTS).to_string(),
            _ => r.pick(names).clone(),
        };
    }
    let sub = |r: &mut Rng| expr(r, names, depth - 1);
    let brk = |r: &mut Rng| if r.chance(8) { "\n  " } else { " " };
    match r.below(10) {
        0 => format!("-{}", sub(r)),
        1 => format!("({})", sub(r)),
        2..=5 => {
            let op = r.pick(&["+", "-", "*", "/", "^"]);
            let (a, b) = (sub(r), sub(r));
            format!("({a} {op}{}{b})", brk(r))
        }
        _ => {
            let f = *r.pick(&Builtin::ALL);
            let args: Vec<String> = (0..f.arity()).map(|_| sub(r)).collect();
            format!("{}({})", f.name(), args.join(&format!(",{}", brk(r))))
        }
    }
}

/// Character-level damage: the front end must answer with diagnostics, never a panic or a hang.
fn mutate(r: &mut Rng, src: &str) -> String {
    let mut chars: Vec<char> = src.chars().collect();
    for _ in 0..1 + r.below(3) {
        let at = r.below(chars.len() + 1);
        match r.below(4) {
            0 if !chars.is_empty() => {
                let end = (at + 1 + r.below(6)).min(chars.len());
                chars.drain(at.min(end)..end);
            }
            1 => {
                let tok = r.pick(&["(", ")", ",", "^", "let ", "param ", "@name", " in ", "..", "9e999", "é", "\u{feff}", "\0", "\r", "#", ";", "NH NH", "pow(", "=", "0x10"]);
                for (k, c) in tok.chars().enumerate() {
                    chars.insert(at.min(chars.len()) + k, c);
                }
            }
            2 if chars.len() > 2 => {
                let a = r.below(chars.len() - 1);
                let b = (a + 1 + r.below(12)).min(chars.len());
                let piece: Vec<char> = chars[a..b].to_vec();
                for (k, c) in piece.into_iter().enumerate() {
                    chars.insert(at.min(chars.len()) + k, c);
                }
            }
            _ => {
                if !chars.is_empty() {
                    let i = r.below(chars.len());
                    chars[i] = *r.pick(&['(', ')', '*', '-', ' ', '\n', '1', 'x']);
                }
            }
        }
    }
    chars.into_iter().collect()
}

fn hard_points() -> Vec<[f64; N_INPUTS]> {
    let up = f64::from_bits(1f64.to_bits() + 1);
    let down = f64::from_bits(1f64.to_bits() - 1);
    vec![[0.0; N_INPUTS], [1.0; N_INPUTS], [up; N_INPUTS], [down; N_INPUTS], [5e-324; N_INPUTS], [-0.0; N_INPUTS], lobe::from_cosines([0.5, 0.25, 0.75, 0.1, 0.9]), lobe::from_cosines([1e-8, 1.0, 0.3, down, 2.0]), lobe::from_cosines([-0.5, 1.5, 0.2, -2.0, 0.6])]
}

/// Parameter vectors across the declared ranges: defaults, every parameter at its low end, at its high end.
fn param_sets(k: &Kernel) -> Vec<Vec<f64>> {
    let ps = &k.formula.params;
    let pick = |f: &dyn Fn(&lobe::ir::ParamDecl) -> f64| ps.iter().map(|p| if f(p).is_finite() { f(p) } else { p.default }).collect::<Vec<_>>();
    vec![k.default_params(), pick(&|p| p.lo), pick(&|p| p.hi)]
}

/// What happened to one case (for the summary).
#[derive(Default)]
struct Tally {
    cases: usize,
    parsed: usize,
    compared: usize,
    evaluations: usize,
}

fn run_case(src: &str, r: &mut Rng, t: &mut Tally) -> Result<(), String> {
    // The internal builtins too: the generator calls every builtin, and both backends must agree on them.
    let f = match lobe::front::parse_internal("fuzz.brdf", src) {
        Ok(f) => f,
        Err(d) => {
            let text = d.render(false);
            return if text.contains("error") { Ok(()) } else { Err(format!("rejected without an error message:\n{text}")) };
        }
    };
    t.parsed += 1;
    // A random subset of the parameters baked at random points of their ranges.
    let mut bake: Vec<(String, f64)> = Vec::new();
    for p in &f.params {
        if r.chance(2) {
            let v = if p.lo.is_finite() && p.hi.is_finite() { p.lo + (p.hi - p.lo) * (r.below(9) as f64 / 8.0) } else { p.default };
            bake.push((p.name.clone(), v));
        }
    }
    let build = |backend| lobe::compile_formula(f.clone(), &Options { backend, bake: bake.clone(), ..Options::default() });
    let (jit, interp) = match (build(Backend::Jit), build(Backend::Interp)) {
        (Ok(j), Ok(i)) => (j, i),
        (Err(a), Err(b)) => {
            let _ = (a.render(false), b.render(false));
            return Ok(());
        }
        _ => return Err("one backend compiled and the other did not".into()),
    };
    let _ = jit.formula.to_program_text();
    // An internal builtin is refused with an error (never a panic, never written); everything else exports.
    for d in [Dialect::Glsl(GlslVersion::V330), Dialect::Glsl(GlslVersion::V450), Dialect::Wgsl] {
        match glsl::export(&jit.formula, d) {
            Ok(text) if Builtin::ALL.iter().any(|b| b.is_internal() && text.contains(&format!("{b}("))) => {
                return Err(format!("{d:?} export wrote an internal builtin:\n{text}"))
            }
            Ok(_) => {}
            Err(e) if e.message.contains("internal to the accuracy pass") => {}
            // A folded constant f32 cannot hold (random constants and baked values reach 1e300 and NaN).
            Err(e) if e.message.contains("cannot be exported") && e.primary.is_some() => {}
            Err(e) => return Err(format!("{d:?} export failed: {e}")),
        }
    }
    t.compared += 1;
    let pts = hard_points();
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| pts.iter().map(|p| p[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut out = vec![0.0; pts.len()];
    for ps in param_sets(&interp) {
        jit.eval_batch(&columns, &ps, &mut out);
        for (k, x) in pts.iter().enumerate() {
            let want = interp.eval(x, &ps);
            let got = jit.eval(x, &ps);
            t.evaluations += 2;
            if !agree(want, got) || !agree(want, out[k]) {
                return Err(format!(
                    "backends disagree at x = {x:?}, params = {ps:?}, bake = {bake:?}: interp {want:e}, jit {got:e}, batched {:e}\nsimplified:\n{}",
                    out[k],
                    interp.formula.to_program_text()
                ));
            }
        }
    }
    Ok(())
}

fn env_num(key: &str, default: u64) -> u64 {
    std::env::var(key).ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

#[test]
fn fuzz_programs_through_every_stage() {
    let cases = env_num("LOBE_FUZZ_CASES", 5000) as usize;
    let seed = env_num("LOBE_FUZZ_SEED", 0x5eed_1ab0);
    let mut r = Rng(seed | 1);
    let mut t = Tally::default();
    let start = Instant::now();
    for case in 0..cases {
        let mut src = program(&mut r);
        if r.chance(4) {
            src = mutate(&mut r, &src);
        }
        t.cases += 1;
        let result = catch_unwind(AssertUnwindSafe(|| run_case(&src, &mut r, &mut t)));
        match result {
            Ok(Ok(())) => {}
            Ok(Err(e)) => panic!("seed {seed}, case {case}: {e}\nprogram:\n{src}"),
            Err(_) => panic!("seed {seed}, case {case}: panicked\nprogram:\n{src:?}"),
        }
    }
    eprintln!(
        "fuzz: seed {seed}: {} programs ({} parsed, {} compiled on both backends), {} evaluations compared, {:.1} s",
        t.cases,
        t.parsed,
        t.compared,
        t.evaluations,
        start.elapsed().as_secs_f64()
    );
    assert!(t.compared * 2 > t.cases, "the generator should mostly produce valid programs ({} of {})", t.compared, t.cases);
}
