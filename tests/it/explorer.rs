//! BRDF Explorer files against a C++ reference of their own GLSL.
//!
//! Each file's shader runs as C++: a small GLSL-emulation header (vec3 with + − × ÷ and scalar broadcasting,
//! the GLSL functions the corpus uses, `float` as double, acos/asin arguments clamped to [−1, 1] as lobe's are,
//! min/max propagating NaN as lobe's do), the file's parameters as globals at their defaults, the shader text
//! verbatim except that its helper functions are renamed `u_NAME` (C++ would otherwise clash them with the
//! header's `reflect`/`smoothstep`, or with a local variable of the same name), and a `main` that reads
//! directions and prints `BRDF(L, V, N, X, Y)`. lobe's interpreter, scalar JIT and batched JIT must equal it
//! to ≤ 1e-9 relative (absolute below 1) on random upper-hemisphere pairs plus grazing and mirror ones, with
//! the same NaN/inf classes, and the three backends must agree bit for bit.
//!
//! Needs `g++`. Without it the reference test prints a note and passes, unless `LOBE_REQUIRE_GXX=1`. It always
//! runs on `examples/explorer/*.brdf`; set `LOBE_BRDF_EXPLORER_DIR` to a directory of BRDF Explorer's own
//! files (github wdas/brdf `src/brdfs`) to run it on those too (`cargo test --test it explorer -- --nocapture`
//! prints each file's maximum error).

use lobe::base::rng::Rng;
use lobe::{Backend, Columns, Evaluator, Input, Options, N_INPUTS};
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

const TOL: f64 = 1e-9;

const HEADER: &str = r#"
#include <cstdio>
extern "C" {
double pow(double, double); double exp(double); double log(double); double sqrt(double); double cos(double);
double sin(double); double tan(double); double acos(double); double asin(double); double atan(double);
double floor(double); double exp2(double); double log2(double);
}
struct vec3 {
    union { double v[3]; struct { double x, y, z; }; struct { double r, g, b; }; };
    vec3() : v{0, 0, 0} {}
    explicit vec3(double s) : v{s, s, s} {}
    vec3(double x, double y, double z) : v{x, y, z} {}
    double &operator[](int i) { return v[i]; }
    double operator[](int i) const { return v[i]; }
};
#define VOP(op) \
    inline vec3 operator op(vec3 a, vec3 b) { return vec3(a[0] op b[0], a[1] op b[1], a[2] op b[2]); } \
    inline vec3 operator op(vec3 a, double s) { return vec3(a[0] op s, a[1] op s, a[2] op s); } \
    inline vec3 operator op(double s, vec3 a) { return vec3(s op a[0], s op a[1], s op a[2]); } \
    inline vec3 &operator op##=(vec3 &a, vec3 b) { a = a op b; return a; } \
    inline vec3 &operator op##=(vec3 &a, double s) { a = a op s; return a; }
VOP(+) VOP(-) VOP(*) VOP(/)
inline vec3 operator-(vec3 a) { return vec3(-a[0], -a[1], -a[2]); }
inline bool isnan_(double x) { return x != x; }
// IEEE 754-2019 maximum/minimum, as lobe's min/max: NaN propagates, -0 < +0.
inline double max(double a, double b) {
    if (isnan_(a) || isnan_(b)) return a + b;
    if (a == b) return __builtin_signbit(a) ? b : a;
    return a > b ? a : b;
}
inline double min(double a, double b) {
    if (isnan_(a) || isnan_(b)) return a + b;
    if (a == b) return __builtin_signbit(a) ? a : b;
    return a < b ? a : b;
}
inline double clamp(double x, double lo, double hi) { return min(max(x, lo), hi); }
inline double glsl_acos(double x) { return acos(clamp(x, -1, 1)); }
inline double glsl_asin(double x) { return asin(clamp(x, -1, 1)); }
#define acos glsl_acos
#define asin glsl_asin
inline double abs(double x) { return __builtin_fabs(x); }
inline double dot(vec3 a, vec3 b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline vec3 cross(vec3 a, vec3 b) {
    return vec3(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]);
}
inline double length(vec3 a) { return sqrt(dot(a, a)); }
inline double length(double a) { return abs(a); }
inline vec3 normalize(vec3 a) { double l = length(a); return vec3(a[0] / l, a[1] / l, a[2] / l); }
inline vec3 reflect(vec3 i, vec3 n) { return i - (2 * dot(n, i)) * n; }
inline double distance(vec3 a, vec3 b) { return length(a - b); }
inline double mix(double a, double b, double t) { return a * (1 - t) + b * t; }
inline vec3 mix(vec3 a, vec3 b, double t) { return a * (1 - t) + b * t; }
inline vec3 mix(vec3 a, vec3 b, vec3 t) { return a * (1.0 - t) + b * t; }
inline double smoothstep(double e0, double e1, double x) {
    double t = clamp((x - e0) / (e1 - e0), 0, 1);
    return (t * t) * (3 - 2 * t);
}
inline double step(double e, double x) { return x < e ? 0 : 1; }
inline double sign(double x) { return (double)(0 < x) - (double)(x < 0); }
inline double fract(double x) { return x - floor(x); }
inline double ceil_(double x) { return -floor(-x); }
#define ceil ceil_
inline double mod(double x, double y) { return x - y * floor(x / y); }
inline double inversesqrt(double x) { return 1 / sqrt(x); }
inline double radians(double x) { return x * (3.14159265358979323846 / 180); }
inline double degrees(double x) { return x * (180 / 3.14159265358979323846); }
#define V1(f) inline vec3 f(vec3 a) { return vec3(f(a[0]), f(a[1]), f(a[2])); }
V1(exp) V1(log) V1(sqrt) V1(abs) V1(floor) V1(fract) V1(sin) V1(cos)
inline vec3 pow(vec3 a, vec3 b) { return vec3(pow(a[0], b[0]), pow(a[1], b[1]), pow(a[2], b[2])); }
inline vec3 pow(vec3 a, double b) { return vec3(pow(a[0], b), pow(a[1], b), pow(a[2], b)); }
inline vec3 max(vec3 a, double b) { return vec3(max(a[0], b), max(a[1], b), max(a[2], b)); }
inline vec3 min(vec3 a, double b) { return vec3(min(a[0], b), min(a[1], b), min(a[2], b)); }
inline vec3 clamp(vec3 a, double lo, double hi) { return vec3(clamp(a[0], lo, hi), clamp(a[1], lo, hi), clamp(a[2], lo, hi)); }
#define float double
"#;

const MAIN: &str = r#"
#undef float
static void put(double x) { if (x != x) std::printf("nan"); else std::printf("%.17g", x); }
int main() {
    double d[6];
    while (std::scanf("%lf %lf %lf %lf %lf %lf", &d[0], &d[1], &d[2], &d[3], &d[4], &d[5]) == 6) {
        vec3 r = shader::BRDF(vec3(d[0], d[1], d[2]), vec3(d[3], d[4], d[5]), vec3(0, 0, 1), vec3(1, 0, 0), vec3(0, 1, 0));
        put(r[0]); std::printf(" "); put(r[1]); std::printf(" "); put(r[2]); std::printf("\n");
    }
}
"#;

fn has_gxx() -> bool {
    Command::new("g++").arg("--version").output().is_ok_and(|o| o.status.success())
}

/// The file's parameter values, read independently of lobe's parser: `variant` 0 is the defaults; any other
/// draws each float uniformly from its range, each bool and colour channel at random. Names as lobe's
/// parameters are named (`NAME`, or `NAME.r`/`.g`/`.b`), with the C++ declaration of each file parameter.
fn param_values(src: &str, variant: u64) -> (Vec<(String, f64)>, String) {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d ^ variant.wrapping_mul(0x9e37_79b9));
    let (mut vals, mut cpp) = (Vec::new(), String::new());
    let mut inside = false;
    for line in src.lines() {
        let t = line.split('#').next().unwrap_or("").trim();
        match t {
            "::begin parameters" => inside = true,
            "::end parameters" => inside = false,
            _ if inside && !t.is_empty() => {
                let w: Vec<&str> = t.split_whitespace().collect();
                let num = |k: usize| -> f64 { w[k].parse().unwrap() };
                let name = w[1].to_string();
                match w[0] {
                    "float" => {
                        let v = if variant == 0 { num(4) } else { num(2) + (num(3) - num(2)) * rng.unit() };
                        cpp.push_str(&format!("double {name} = {v:e};\n"));
                        vals.push((name, v));
                    }
                    "bool" => {
                        let v = if variant == 0 { num(2) } else { rng.below(2) as f64 };
                        cpp.push_str(&format!("bool {name} = {};\n", v != 0.0));
                        vals.push((name, v));
                    }
                    "color" => {
                        let c: Vec<f64> = (2..5).map(|k| if variant == 0 { num(k) } else { rng.unit() }).collect();
                        cpp.push_str(&format!("vec3 {name}({:e}, {:e}, {:e});\n", c[0], c[1], c[2]));
                        for (k, ch) in ["r", "g", "b"].iter().enumerate() {
                            vals.push((format!("{name}.{ch}"), c[k]));
                        }
                    }
                    other => panic!("unknown parameter type {other}"),
                }
            }
            _ => {}
        }
    }
    (vals, cpp)
}

/// The shader block with every helper function renamed `u_NAME` (definitions and calls; `BRDF` stays).
fn cpp_shader(src: &str) -> String {
    let start = src.find("::begin shader").expect("a shader block") + "::begin shader".len();
    let end = src.find("::end shader").expect("the shader block ends");
    let text = &src[start..end];
    let mut helpers: Vec<String> = Vec::new();
    // `TYPE NAME (` defines a function.
    let toks = tokens(text);
    for w in toks.windows(3) {
        if ["float", "vec3", "bool", "void"].contains(&w[0].as_str()) && w[2] == "(" && w[1] != "BRDF" && w[1].starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') {
            helpers.push(w[1].clone());
        }
    }
    let mut out = String::new();
    let toks_sp = tokens_with_space(text);
    for (i, t) in toks_sp.iter().enumerate() {
        let next = toks_sp[i + 1..].iter().find(|s| !s.trim().is_empty());
        if helpers.contains(t) && next.is_some_and(|n| n == "(") {
            out.push_str("u_");
        }
        out.push_str(t);
    }
    out
}

fn tokens(text: &str) -> Vec<String> {
    tokens_with_space(text).into_iter().filter(|t| !t.trim().is_empty()).collect()
}

/// Identifiers, single other characters and whitespace runs, concatenating back to `text`.
fn tokens_with_space(text: &str) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    let mut cur = String::new();
    let mut kind = 0; // 1 identifier, 2 space
    for c in text.chars() {
        let k = if c.is_ascii_alphanumeric() || c == '_' || c == '.' && kind == 1 && cur.chars().all(|d| d.is_ascii_digit() || d == '.') {
            1
        } else if c.is_whitespace() {
            2
        } else {
            3
        };
        if k != kind || k == 3 {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            kind = k;
        }
        cur.push(c);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// Direction pairs: random over the upper hemisphere, grazing ones (z from 0 to 1e-4), mirror pairs (H = N)
/// and L = V.
fn directions() -> Vec<([f64; 3], [f64; 3])> {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut dir = |z: Option<f64>| {
        let z = z.unwrap_or_else(|| 1.0 - rng.unit());
        let phi = rng.unit() * std::f64::consts::TAU;
        let s = (1.0 - z * z).max(0.0).sqrt();
        [s * phi.cos(), s * phi.sin(), z]
    };
    let mut v = Vec::new();
    for _ in 0..2000 {
        v.push((dir(None), dir(None)));
    }
    for z in [0.0, 1e-12, 1e-8, 1e-6, 1e-4] {
        for _ in 0..20 {
            v.push((dir(Some(z)), dir(None)));
            v.push((dir(None), dir(Some(z))));
            v.push((dir(Some(z)), dir(Some(z))));
        }
    }
    for _ in 0..100 {
        let l = dir(None);
        v.push((l, [-l[0], -l[1], l[2]]));
        v.push((l, l));
    }
    v.push(([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]));
    v
}

/// Runs the C++ reference of `src` on `dirs`; one `[r, g, b]` a direction pair.
fn reference(name: &str, src: &str, params: &str, dirs: &[([f64; 3], [f64; 3])], work: &Path) -> Vec<[f64; 3]> {
    let stem = name.trim_end_matches(".brdf");
    let cpp = work.join(format!("{stem}.cpp"));
    let exe = work.join(stem);
    let text = format!("{HEADER}\nnamespace shader {{\n{}\n{}\n}}\n{MAIN}", params, cpp_shader(src));
    fs::write(&cpp, text).unwrap();
    let out = Command::new("g++")
        .args(["-O0", "-ffp-contract=off", "-std=c++17", "-w", "-o"])
        .arg(&exe)
        .arg(&cpp)
        .output()
        .expect("run g++");
    assert!(out.status.success(), "{name}: the C++ reference does not compile:\n{}", String::from_utf8_lossy(&out.stderr));
    let mut input = String::new();
    for (l, v) in dirs {
        input.push_str(&format!("{:e} {:e} {:e} {:e} {:e} {:e}\n", l[0], l[1], l[2], v[0], v[1], v[2]));
    }
    let inp = work.join(format!("{stem}.in"));
    fs::write(&inp, input).unwrap();
    let out = Command::new(&exe).stdin(fs::File::open(&inp).unwrap()).output().expect("run the reference");
    assert!(out.status.success(), "{name}: the reference failed");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap_or_else(|_| panic!("bad number {x}"))).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

/// The error of `got` against `want`: 0 when both are NaN or the same infinity, `inf` for different classes,
/// else relative (absolute below 1).
fn error(got: f64, want: f64) -> f64 {
    if got.is_nan() || want.is_nan() {
        return if got.is_nan() && want.is_nan() { 0.0 } else { f64::INFINITY };
    }
    if got.is_infinite() || want.is_infinite() {
        return if got == want { 0.0 } else { f64::INFINITY };
    }
    (got - want).abs() / want.abs().max(1.0)
}

/// Checks one file: lobe (interpreter, JIT scalar, JIT batched) against the reference; returns the max error
/// ([`error`]) and the max purely relative error over nonzero finite reference values (for the report).
fn check_file(name: &str, src: &str, variant: u64, work: &Path) -> Result<(f64, f64), String> {
    let dirs = directions();
    let (values, cpp) = param_values(src, variant);
    let want = reference(name, src, &cpp, &dirs, work);
    assert_eq!(want.len(), dirs.len(), "{name}: the reference printed too few rows");
    let f = lobe::front::parse(name, src).map_err(|d| format!("{name} does not load:\n{}", d.render(false)))?;
    // lobe's parameters by name; the implicit `n` (not in the file) at its default.
    let params: Vec<f64> =
        f.params.iter().map(|p| values.iter().find(|(k, _)| *k == p.name).map_or(p.default, |(_, v)| *v)).collect();
    let name = &format!("{name} (parameters {})", if variant == 0 { "at their defaults".to_string() } else { format!("drawn, variant {variant}") });
    let inputs: Vec<[f64; N_INPUTS]> = dirs.iter().map(|(l, v)| lobe::numerics::inputs_from_dirs(*l, *v)).collect();
    let channels = f.channels();
    let (mut worst, mut worst_rel): (f64, f64) = (0.0, 0.0);
    for (c, ch) in channels.iter().enumerate() {
        let compile = |backend| lobe::compile_formula(ch.clone(), &Options { backend, ..Default::default() }).expect("compiles");
        let (interp, jit) = (compile(Backend::Interp), compile(Backend::Jit));
        let cols: Vec<Vec<f64>> = Input::ALL.iter().map(|i| inputs.iter().map(|x| x[i.index()]).collect()).collect();
        let mut batch = vec![0.0; inputs.len()];
        jit.eval_batch(&Columns::new(std::array::from_fn(|k| cols[k].as_slice())), &params, &mut batch);
        for (k, x) in inputs.iter().enumerate() {
            let (a, b) = (interp.eval(x, &params), jit.eval(x, &params));
            let same = |p: f64, q: f64| p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan());
            if !same(a, b) || !same(a, batch[k]) {
                return Err(format!("{name} channel {c} at {:?}: interpreter {a:e}, JIT {b:e}, batched {:e}", dirs[k], batch[k]));
            }
            // A scalar formula is all three reference channels.
            let refs = if channels.len() == 1 { want[k].to_vec() } else { vec![want[k][c]] };
            for r in refs {
                let e = error(a, r);
                if e > TOL {
                    return Err(format!("{name} channel {c} at L={:?} V={:?}: lobe {a:e}, GLSL (C++) {r:e}, error {e:e}", dirs[k].0, dirs[k].1));
                }
                worst = worst.max(e);
                if r != 0.0 && r.is_finite() {
                    worst_rel = worst_rel.max((a - r).abs() / r.abs());
                }
            }
        }
    }
    Ok((worst, worst_rel))
}

fn examples() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer");
    let mut v: Vec<PathBuf> = fs::read_dir(dir).expect("examples/explorer").filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|e| e == "brdf")).collect();
    v.sort();
    v
}

fn run_reference(files: &[PathBuf], tag: &str) {
    if !has_gxx() {
        assert!(std::env::var("LOBE_REQUIRE_GXX").map_or(true, |v| v != "1"), "g++ is required (LOBE_REQUIRE_GXX=1) but missing");
        eprintln!("note: g++ not found; the BRDF Explorer C++ reference test is skipped");
        return;
    }
    let work = crate::scratch_dir("explorer", tag);
    let mut failures = vec![];
    for p in files {
        let name = p.file_name().and_then(|s| s.to_str()).unwrap_or("?").to_string();
        let src = fs::read_to_string(p).expect("readable");
        // The defaults, then two random draws of every parameter within its range.
        let mut worst = (0.0f64, 0.0f64);
        for variant in 0..3 {
            match check_file(&name, &src, variant, &work) {
                Ok((e, rel)) => worst = (worst.0.max(e), worst.1.max(rel)),
                Err(m) => failures.push(m),
            }
        }
        eprintln!("{name:32} max error {:.2e} (relative {:.2e})", worst.0, worst.1);
    }
    let _ = fs::remove_dir_all(&work);
    assert!(failures.is_empty(), "{} of {} files differ from their GLSL:\n{}", failures.len(), files.len(), failures.join("\n"));
}

#[test]
fn examples_equal_their_glsl() {
    let files = examples();
    assert!(files.len() >= 6, "examples/explorer holds at least six models");
    run_reference(&files, "examples");
}

#[test]
fn corpus_equals_its_glsl_when_given() {
    let Ok(dir) = std::env::var("LOBE_BRDF_EXPLORER_DIR") else {
        eprintln!("note: set LOBE_BRDF_EXPLORER_DIR to a directory of BRDF Explorer .brdf files to check them");
        return;
    };
    let mut files: Vec<PathBuf> = fs::read_dir(&dir).expect("LOBE_BRDF_EXPLORER_DIR is a directory").filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|e| e == "brdf")).collect();
    files.sort();
    assert!(!files.is_empty(), "no .brdf files in {dir}");
    run_reference(&files, "corpus");
}

fn snapshot_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots/explorer_errors")
}

/// Every `tests/snapshots/explorer_errors/NAME.brdf` is refused with exactly the diagnostics in `NAME.txt`
/// (carets at the GLSL inside the .brdf file). `LOBE_BLESS=1` rewrites the `.txt` files; read them first.
#[test]
fn unsupported_glsl_gets_caret_diagnostics() {
    let bless = std::env::var("LOBE_BLESS").is_ok_and(|v| v == "1");
    let mut cases: Vec<PathBuf> = fs::read_dir(snapshot_dir()).unwrap().filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|e| e == "brdf")).collect();
    cases.sort();
    assert!(cases.len() >= 10, "expected at least 10 cases");
    let mut failures = vec![];
    for path in cases {
        let file = path.file_name().and_then(|s| s.to_str()).unwrap_or("?").to_string();
        let src = fs::read_to_string(&path).unwrap();
        let text = match lobe::front::parse(&file, &src) {
            Ok(_) => panic!("{file} was accepted"),
            Err(d) => d.render(false),
        };
        assert!(text.contains("error") && text.contains("help:"), "{file}: an error with a hint\n{text}");
        let snap = path.with_extension("txt");
        if bless {
            fs::write(&snap, &text).unwrap();
            continue;
        }
        match fs::read_to_string(&snap) {
            Ok(want) if want == text => {}
            Ok(want) => failures.push(format!("{file}: rendered text differs\n--- want\n{want}\n--- got\n{text}")),
            Err(_) => failures.push(format!("{file}: no snapshot (run with LOBE_BLESS=1)\n{text}")),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// The substance of a few messages, independent of the snapshot text.
#[test]
fn diagnostics_name_the_construct_and_its_line() {
    let read = |n: &str| fs::read_to_string(snapshot_dir().join(n)).unwrap();
    let msg = |n: &str| lobe::front::parse(n, &read(n)).err().map(|d| d.render(false)).unwrap_or_default();
    assert!(msg("loop.brdf").contains("loops are not supported") && msg("loop.brdf").contains("loop.brdf:10:5"));
    assert!(msg("unknown_function.brdf").contains("did you mean `fresnel`?"));
    assert!(msg("type_error.brdf").contains("is a vec3, but a float is expected"));
    assert!(msg("struct.brdf").contains("structs are not supported"));
    let internal = msg("internal_builtin.brdf");
    assert!(internal.contains("`acoslo` is internal to the accuracy pass") && internal.contains("internal_builtin.brdf:9:27"), "{internal}");
    assert!(internal.contains("write `acos(x)`"), "{internal}");
}

/// Runs `lobe ARGS` and fails if it takes longer than `secs`; returns (exit code, stderr).
fn lobe_within(secs: u64, args: &[&str]) -> (Option<i32>, String) {
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_lobe"))
        .args(args)
        .env("NO_COLOR", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn lobe");
    let mut err = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut err, &mut s);
        s
    });
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed().as_secs() > secs {
            let _ = child.kill();
            let _ = child.wait();
            panic!("`lobe {}` did not finish within {secs} s", args.join(" "));
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    (status.code(), reader.join().unwrap())
}

/// Hostile shaders end with a clear error (exit 1, no panic) within a timeout: deep parentheses, a deep
/// `if`/`else` chain, a long sum, helpers that double their work at every level, stray bytes; a big but fair
/// file is accepted in time.
#[test]
fn hostile_shaders_are_refused_quickly() {
    let dir = crate::scratch_dir("explorer", "hostile");
    let wrap = |body: &str| format!("analytic\n::begin shader\n{body}\n::end shader\n");
    let brdf = |e: &str| wrap(&format!("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) {{ return vec3({e}); }}"));
    let mut doubling = String::from("float f0(float x) { return x * 1.5; }\n");
    for k in 1..60 {
        doubling.push_str(&format!("float f{k}(float x) {{ return f{}(x) + f{}(x + 1.0); }}\n", k - 1, k - 1));
    }
    doubling.push_str("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { return vec3(f59(L.z)); }");
    let mut stacked = String::from("float g0(float x) { return x; }\n");
    for k in 1..60 {
        stacked.push_str(&format!("float g{k}(float x) {{ return {}g{}(x); }}\n", "- ".repeat(150), k - 1));
    }
    stacked.push_str("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { return vec3(g59(L.z)); }");
    let mut chain = String::from("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { float a = 0.0;\n");
    chain.push_str(&"if (L.z > 0.5) a = 1.0; else ".repeat(20_000));
    chain.push_str("a = 2.0; return vec3(a); }");
    let mut huge = String::from("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { float a = L.z;\n");
    for _ in 0..40_000 {
        huge.push_str("a = a * 0.999 + V.z;\n");
    }
    huge.push_str("return vec3(a); }");
    let cases: Vec<(&str, String, &str)> = vec![
        ("parens", brdf(&format!("{}1.0{}", "(".repeat(200_000), ")".repeat(200_000))), "nests deeper than"),
        ("unary", brdf(&format!("{}1.0", "- ".repeat(200_000))), "nests deeper than"),
        ("sum", brdf(&vec!["L.z"; 100_000].join(" + ")), "nests deeper than"),
        ("chain", wrap(&chain), "nests deeper than"),
        ("doubling", wrap(&doubling), "operations once its helper functions are inlined"),
        ("stacked", wrap(&stacked), "go deeper than"),
        // Big but fair (under the 1 MiB file limit): accepted.
        ("huge", wrap(&huge), ""),
        ("bytes", wrap("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { return vec3(\u{7f}é); }"), "unexpected character"),
        ("comment", wrap("/* never closed"), "unterminated"),
    ];
    for (name, text, needle) in cases {
        let p = dir.join(format!("{name}.brdf"));
        fs::write(&p, text).unwrap();
        let (code, stderr) = lobe_within(30, &["import", p.to_str().unwrap()]);
        assert_eq!(code, Some(if needle.is_empty() { 0 } else { 1 }), "{name}: exit code\n{stderr}");
        assert!(stderr.contains(needle) && !stderr.contains("panicked"), "{name}: expected `{needle}`\n{stderr}");
    }
    let _ = fs::remove_dir_all(&dir);
}

/// `lobe import` writes lobe source (parameters of every kind, `@domain raw`, an RGB result) and never
/// replaces a file it did not write.
#[test]
fn import_writes_lobe_source_and_keeps_foreign_files() {
    let dir = crate::scratch_dir("explorer", "import");
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer/principled.brdf");
    let out = dir.join("principled.brdf");
    let (code, err) = lobe_within(30, &["import", src.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    let text = fs::read_to_string(&out).unwrap();
    for needle in ["@name \"principled\"", "param baseColor = rgb(0.82, 0.67, 0.16)", "param metallic = 0.2 in 0..1", "@domain raw\n", "\nrgb(", "baseColor.r"] {
        assert!(text.contains(needle), "missing `{needle}` in\n{text}");
    }
    let cook = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer/cook_torrance.brdf");
    let (code, _) = lobe_within(30, &["import", cook.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "replacing its own output is allowed");
    assert!(fs::read_to_string(&out).unwrap().contains("param use_fresnel = true"));
    let foreign = dir.join("mine.brdf");
    fs::write(&foreign, "NH^n\n").unwrap();
    let (code, err) = lobe_within(30, &["import", cook.to_str().unwrap(), "-o", foreign.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(fs::read_to_string(&foreign).unwrap(), "NH^n\n");
    let _ = fs::remove_dir_all(&dir);
}

/// import → lobe source → lobe's parser → the same values, bit for bit, on every example.
#[test]
fn import_round_trips_through_the_lobe_language() {
    let dirs = directions();
    for p in examples() {
        let name = p.file_name().and_then(|s| s.to_str()).unwrap().to_string();
        let f = lobe::front::parse(&name, &fs::read_to_string(&p).unwrap()).unwrap();
        let text = lobe::ir::print::source(&f, "round trip");
        let g = lobe::front::parse("imported.brdf", &text).unwrap_or_else(|d| panic!("{name}:\n{}\n{text}", d.render(false)));
        let (fc, gc) = (f.channels(), g.channels());
        assert_eq!(fc.len(), gc.len(), "{name}: channels");
        assert_eq!(f.default_params().len(), g.default_params().len(), "{name}: parameters");
        for (a, b) in fc.iter().zip(&gc) {
            let ka = lobe::compile_formula(a.clone(), &Options { backend: Backend::Interp, no_simplify: true, ..Default::default() }).unwrap();
            let kb = lobe::compile_formula(b.clone(), &Options { backend: Backend::Interp, no_simplify: true, ..Default::default() }).unwrap();
            for (l, v) in &dirs {
                let x = lobe::numerics::inputs_from_dirs(*l, *v);
                let (p, q) = (ka.eval(&x, &f.default_params()), kb.eval(&x, &g.default_params()));
                assert!(p.to_bits() == q.to_bits() || p.is_nan() && q.is_nan(), "{name} at {l:?} {v:?}: {p} vs {q}");
            }
        }
    }
}
