//! The `lobe` binary end to end: bad input of every kind ends in a clear message and exit code 1 (2 for clap
//! usage errors) — never a panic, a hang, or a stack overflow — and good input prints what the README says.

use std::io::Write;
use std::process::{Command, Output, Stdio};

pub(crate) fn lobe(args: &[&str], stdin: Option<&[u8]>) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lobe"));
    c.args(args).current_dir(env!("CARGO_MANIFEST_DIR")).env("NO_COLOR", "1");
    c.stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped());
    let mut child = c.spawn().expect("spawn lobe");
    if let Some(input) = stdin {
        // The child may exit before reading everything (e.g. on an oversized input); that is fine.
        let _ = child.stdin.take().unwrap().write_all(input);
    } else {
        drop(child.stdin.take());
    }
    child.wait_with_output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts a clean failure: exit code 1 and an `error:` line, no panic or signal.
fn assert_clean_error(o: &Output, what: &str, needle: &str) {
    assert_clean_exit(o.status.code(), &stderr(o), what, needle);
}

/// [`assert_clean_error`] on an exit code and standard error (for runners that collect output themselves).
pub(crate) fn assert_clean_exit(code: Option<i32>, e: &str, what: &str, needle: &str) {
    assert_eq!(code, Some(1), "{what}: exit status {code:?}, stderr:\n{e}");
    assert!(!e.contains("panicked") && !e.contains("RUST_BACKTRACE"), "{what} panicked:\n{e}");
    assert!(e.contains("error"), "{what}: no error message:\n{e}");
    assert!(e.contains(needle), "{what}: expected `{needle}` in:\n{e}");
}

#[test]
fn eval_prints_the_value_and_json() {
    let o = lobe(&["eval", "examples/brdfs/blinn.brdf", "--set", "n=2", "--at", "NH=0.5"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "0.25");
    for backend in ["jit", "interp"] {
        let o = lobe(&["eval", "--expr", "NH^n", "--set", "n=3", "--at", "NH=0.5", "--json", "--backend", backend], None);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["value"], serde_json::json!(0.125));
    }
    let o = lobe(&["eval", "-", "--at", "VR=0.5", "--set", "n=1"], Some(b"VR^n\n"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "0.5");
}

#[test]
fn bad_input_of_every_kind_fails_cleanly() {
    let dir = std::env::temp_dir().join(format!("lobe-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p.display().to_string()
    };
    let empty = write("empty.brdf", b"");
    assert_clean_error(&lobe(&["eval", &empty], None), "empty file", "no formula");
    let garbage: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8).collect();
    let bin = write("garbage.brdf", &garbage);
    assert_clean_error(&lobe(&["eval", &bin], None), "binary garbage", "garbage.brdf");
    let deep = write("deep.brdf", &[b"(".repeat(100_000), b"NH".to_vec(), b")".repeat(100_000)].concat());
    assert_clean_error(&lobe(&["eval", &deep], None), "100 000-deep nesting", "deep");
    let mut big = b"NH".to_vec();
    while big.len() < 10 << 20 {
        big.extend_from_slice(b"+NH");
    }
    let big_path = write("big.brdf", &big);
    assert_clean_error(&lobe(&["eval", &big_path], None), "10 MB formula", "big.brdf");
    assert_clean_error(&lobe(&["eval", "-"], Some(&big)), "10 MB formula on stdin", "stdin");
    assert_clean_error(&lobe(&["eval", "no/such/file.brdf"], None), "missing file", "no/such/file.brdf");
    assert_clean_error(&lobe(&["eval", "--expr", "NX^n"], None), "unknown variable", "NX");
    assert_clean_error(&lobe(&["eval", "examples/brdfs/blinn.brdf", "--set", "q=3"], None), "unknown param", "q");
    assert_clean_error(&lobe(&["eval", "examples/brdfs/blinn.brdf", "--set", "n=5000"], None), "n out of range", "5000");
    assert_clean_error(&lobe(&["eval", "examples/brdfs/blinn.brdf", "--at", "NZ=1"], None), "unknown input", "NZ");
    let o = lobe(&["eval", "examples/brdfs/blinn.brdf", "--no-such-flag"], None);
    assert_eq!(o.status.code(), Some(2), "unknown flag: {}", stderr(&o));
    assert!(stderr(&o).contains("--no-such-flag"));
    let o = lobe(&["frobnicate"], None);
    assert_eq!(o.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn export_refuses_to_clobber_a_file_it_did_not_write() {
    let dir = std::env::temp_dir().join(format!("lobe-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let target = dir.join("mine.glsl");
    std::fs::write(&target, "// my own shader, hands off\n").unwrap();
    let t = target.display().to_string();
    let o = lobe(&["export", "--glsl", "examples/brdfs/blinn.brdf", "-o", &t], None);
    assert_clean_error(&o, "clobber", "not overwriting");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "// my own shader, hands off\n");
    let fresh = dir.join("new.glsl").display().to_string();
    assert!(lobe(&["export", "--glsl", "examples/brdfs/blinn.brdf", "-o", &fresh], None).status.success());
    // lobe may replace its own output without --force.
    assert!(lobe(&["export", "--wgsl", "examples/brdfs/blinn.brdf", "-o", &fresh], None).status.success());
    assert!(std::fs::read_to_string(&fresh).unwrap().contains("fn lobe_blinn"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn normalize_bakes_the_exact_coefficient() {
    // Phong at n = 10: coef = (n + 2) / 2π, so the normalised value at VR = 1 is exactly that.
    let o = lobe(&["eval", "examples/brdfs/phong.brdf", "--set", "n=10", "--at", "VR=1", "--normalize", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let got = v["value"].as_f64().unwrap();
    let want = 12.0 / (2.0 * std::f64::consts::PI);
    assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
    // A lobe that is zero everywhere cannot be normalised: a clear error, not a NaN.
    let o = lobe(&["eval", "--expr", "0*NH", "--normalize"], None);
    assert_clean_error(&o, "zero lobe", "cannot normalise");
}

#[test]
fn check_sweep_is_an_alias_of_sweep() {
    let o = lobe(&["check", "--sweep", "examples/brdfs/beckmann.brdf", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["nan"].as_u64().unwrap() > 0, "Beckmann is NaN at NH = 0: {v}");
    // A flag of `check` like any other: the sweep's flags with it, the accuracy report's refused beside it,
    // and the sweep's flags refused without it.
    let o = lobe(&["check", "examples/brdfs/beckmann.brdf", "--sweep", "--as-written", "--deny", "nan"], None);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    for (args, says) in [
        (&["check", "--sweep", "--points", "10", "examples/brdfs/beckmann.brdf"][..], "cannot be used with"),
        (&["check", "--deny", "nan", "examples/brdfs/beckmann.brdf"][..], "--sweep"),
    ] {
        let o = lobe(args, None);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(says), "{args:?}: {}", stderr(&o));
    }
}

/// The sweep reports the formula as written and as compiled: Beckmann as published is NaN wherever NH⁴·m²
/// underflows (NH ≤ 8.6e-77 at m = 0.01, the extent found by bisection), the accuracy pass's form only where
/// NH is exactly 0; `--deny` judges the compiled form unless `--as-written`.
#[test]
fn sweep_reports_extents_as_written_and_as_compiled() {
    let o = lobe(&["sweep", "examples/brdfs/beckmann.brdf", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["domain"], "independent cosines");
    let tiny = v["regions"].as_array().unwrap().iter().find(|r| r["region"] == "tiny").unwrap();
    let ext = tiny["extents"].as_array().unwrap().iter().find(|e| e["kind"] == "nan" && e["along"] == "NH").unwrap();
    let hi = ext["hi"].as_f64().unwrap();
    assert!(ext["lo"].as_f64() == Some(0.0) && hi > 1e-77 && hi < 1e-76, "{ext}");
    let c = &v["compiled"];
    assert!(c["nan"].as_u64().unwrap() < v["nan"].as_u64().unwrap(), "{c}");
    let ctiny = c["regions"].as_array().unwrap().iter().find(|r| r["region"] == "tiny").unwrap();
    assert_eq!(ctiny["nan"], 0, "{ctiny}");
    // A formula clean in both forms passes `--deny`; Beckmann as written fails it.
    let o = lobe(&["sweep", "--expr", "NH^n", "--deny", "nan,inf"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = lobe(&["sweep", "examples/brdfs/beckmann.brdf", "--as-written", "--deny", "nan"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("denied kinds occurred: nan"), "{}", stderr(&o));
}

/// Cosines that geometry links are swept on real (L, V) pairs, and extents follow a polar angle: Ward's
/// 1/sqrt(NL·NV) as written is NaN where NL·NV underflows with both directions grazing.
#[test]
fn sweep_of_linked_cosines_runs_on_geometry() {
    let o = lobe(&["sweep", "examples/brdfs/ward.brdf", "--as-written"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("cosines of real (L, V) pairs; inputs read: NL, NV, NH"), "{out}");
    assert!(out.contains("NaN for NL = Lz along L's polar angle in [0, "), "{out}");
    assert!(!out.contains("compiled"), "{out}");
}

#[test]
fn watch_renders_on_start_and_keeps_the_last_good_image_on_errors() {
    let dir = std::env::temp_dir().join(format!("lobe-watch-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let brdf = dir.join("w.brdf");
    let out = dir.join("w.png");
    std::fs::write(&brdf, "VR^n\n").unwrap();
    let (b, o) = (brdf.display().to_string(), out.display().to_string());
    let r = lobe(&["watch", &b, "--scene", "examples/scenes/paper_sphere.toml", "-o", &o, "--size", "48", "--count", "1"], None);
    assert!(r.status.success(), "{}", stderr(&r));
    assert!(stderr(&r).contains("reloaded in"), "{}", stderr(&r));
    let first = std::fs::read(&out).unwrap();
    assert_eq!(&first[1..4], b"PNG");
    // A broken formula: diagnostics on stderr, the image untouched; with --count the exit status says the last
    // reload failed (without --count watch keeps running).
    std::fs::write(&brdf, "VR^^n\n").unwrap();
    let r = lobe(&["watch", &b, "--scene", "examples/scenes/paper_sphere.toml", "-o", &o, "--size", "48", "--count", "1"], None);
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    assert!(stderr(&r).contains("keeping the last good image"), "{}", stderr(&r));
    assert_eq!(std::fs::read(&out).unwrap(), first);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bench_and_plot_write_what_they_say() {
    let dir = std::env::temp_dir().join(format!("lobe-bench-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plot = dir.join("se.svg").display().to_string();
    let o = lobe(
        &["bench", "examples/brdfs/schlick.brdf", "examples/brdfs/modified_schlick.brdf", "--samples", "3", "--no-albedo", "--json", "--plot", &plot],
        None,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for key in ["name", "compile_us", "jit_ns", "jit_batch_ns", "interp_ns", "mean_abs_grid", "pareto"] {
        assert!(rows[0].get(key).is_some(), "missing {key}: {v}");
    }
    // Modified Schlick is more accurate than Schlick (the papers' 0.0066 vs Schlick's ~0.029).
    let err = |name: &str| rows.iter().find(|r| r["name"] == name).unwrap()["mean_abs_grid"].as_f64().unwrap();
    assert!(err("Modified Schlick") < 0.0067 && err("Schlick") > 0.02, "{v}");
    assert!(std::fs::read_to_string(&plot).unwrap().contains("<svg"));
    let lobes = dir.join("l.png").display().to_string();
    let o = lobe(&["plot", "examples/brdfs/blinn.brdf", "examples/brdfs/scos2.brdf", "--set", "n=50", "--polar", "-o", &lobes], None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(&std::fs::read(&lobes).unwrap()[1..4], b"PNG");
    let o = lobe(&["plot", "examples/brdfs/blinn.brdf", "--set", "q=5", "-o", &lobes], None);
    assert_clean_error(&o, "plot with an unknown parameter", "no formula has a parameter `q`");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The shared flags (`cli::args`) parse alike in every command: each subcommand's help lists them, `--expr`
/// conflicts with FILE, repeated `--set` accumulates, `-o` is required where the command cannot do without
/// it, and `--force` is what the refusal to overwrite asks for.
#[test]
fn shared_flags_parse_alike_in_every_command() {
    let all = ["eval", "watch", "bench", "plot", "check", "export", "energy", "accuracy", "fit", "sweep", "render", "compare", "tabulate"];
    for cmd in all {
        let o = lobe(&[cmd, "--help"], None);
        assert!(o.status.success(), "{cmd} --help: {}", stderr(&o));
        assert!(String::from_utf8_lossy(&o.stdout).contains("--set <SET>"), "{cmd} --help lists no --set");
    }
    let o = lobe(&["check", "examples/brdfs/blinn.brdf", "--expr", "NH^n"], None);
    assert_eq!(o.status.code(), Some(2), "FILE with --expr: {}", stderr(&o));
    assert!(stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
    let o = lobe(&["eval", "--expr", "param a = 1 in 0..10\nNH^n*a", "--set", "n=2", "--set", "a=3", "--at", "NH=0.5"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "0.75");
    for cmd in [&["plot", "examples/brdfs/blinn.brdf"][..], &["watch", "examples/brdfs/blinn.brdf"]] {
        let o = lobe(cmd, None);
        assert_eq!(o.status.code(), Some(2), "{cmd:?} without -o: {}", stderr(&o));
        assert!(stderr(&o).contains("--output <OUTPUT>"), "{}", stderr(&o));
    }
    let dir = std::env::temp_dir().join(format!("lobe-shared-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mine = dir.join("mine.png");
    std::fs::write(&mine, "not a lobe image").unwrap();
    let o = lobe(&["render", "examples/scenes/paper_sphere.toml", "--size", "8", "-q", "-o", &mine.display().to_string()], None);
    assert_clean_error(&o, "render over a foreign file", "--force");
    assert_eq!(std::fs::read_to_string(&mine).unwrap(), "not a lobe image");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `eval --points`: a CSV through the batched kernel; the values equal `--at` evaluations bit for bit; a
/// parameter column stays live; both math modes; errors point at the CSV line and column.
#[test]
fn eval_points_reads_csv_and_agrees_with_single_evaluations() {
    let csv = "NH,NL,k\n0.5,0.1,1.5\n0.9,0.2,2\n1,0,3\n0.25,1,2.5\n0.999,0.5,1\n";
    let formula = "param k = 2 in 1..5\npow(NH, k) * (1 + NL)\n";
    let dir = std::env::temp_dir().join(format!("lobe-points-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("p.brdf");
    std::fs::write(&file, formula).unwrap();
    let file = file.display().to_string();
    for math in ["precise", "fast"] {
        let o = lobe(&["eval", &file, "--points", "-", "--json", "--math", math], Some(csv.as_bytes()));
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!((v["points"].as_u64(), v["math"].as_str()), (Some(5), Some(math)), "{v}");
        assert_eq!(v["values"].as_array().map(Vec::len), Some(5), "{v}");
        // Values from the text output: Rust parses floats exactly (serde_json's default parser may not).
        let o = lobe(&["eval", &file, "--points", "-", "--math", math], Some(csv.as_bytes()));
        let values: Vec<f64> = String::from_utf8_lossy(&o.stdout).lines().map(|l| l.parse().unwrap()).collect();
        let mode: lobe::Mode = math.parse().unwrap();
        for (row, got) in csv.lines().skip(1).zip(&values) {
            let c: Vec<f64> = row.split(',').map(|x| x.parse().unwrap()).collect();
            // The live k column: the library's pow in this mode, times (1 + NL), as the kernel computes it.
            let want = lobe::builtins::Builtin::Pow.eval_in(mode, &[c[0], c[2]]) * (1.0 + c[1]);
            assert_eq!(got.to_bits(), want.to_bits(), "{math} {row}: {got} vs {want}");
        }
        // Without parameter columns, --set bakes k for both paths: --points equals --at bit for bit.
        let o = lobe(&["eval", &file, "--points", "-", "--set", "k=2.7", "--math", math], Some(b"NL,NH\n0.3,0.77\n"));
        let at = lobe(&["eval", &file, "--at", "NH=0.77,NL=0.3", "--set", "k=2.7", "--math", math], None);
        assert!(o.status.success() && at.status.success(), "{}{}", stderr(&o), stderr(&at));
        assert_eq!(String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&at.stdout));
    }
    let o = lobe(&["eval", &file, "--points", "-"], Some(b"NH,q\n0.5,1\n"));
    assert_clean_error(&o, "unknown column", "<stdin>:1:4");
    let o = lobe(&["eval", &file, "--points", "-"], Some(b"NH,NL,k\n0.5,0,1\n0.5,0,x\n"));
    assert_clean_error(&o, "bad number", "<stdin>:3:7");
    let o = lobe(&["eval", &file, "--points", "-"], Some(b"NH,NL,k\n0.5,0,9\n"));
    assert_clean_error(&o, "parameter out of range", "outside its declared range");
    // A cosine the formula reads is never silently 0: a missing column or --at item is an error naming it.
    let o = lobe(&["eval", &file, "--points", "-"], Some(b"NH,k\n0.5,1\n"));
    assert_clean_error(&o, "missing column", "the CSV has no column for NL (the formula reads NL, NH)");
    assert_clean_error(&o, "missing column", "<stdin>:1:1");
    let o = lobe(&["eval", &file, "--at", "NL=0.5"], None);
    assert_clean_error(&o, "missing --at input", "--at gives no value for NH (the formula reads NL, NH)");
    let o = lobe(&["eval", &file, "--points", "-", "--set", "k=2"], Some(b"NH,k\n0.5,1\n"));
    assert_clean_error(&o, "baked and a column", "--set k: parameter `k` is both baked and a column");
    let o = lobe(&["eval", &file, "--points", "/nonexistent/p.csv"], None);
    assert_clean_error(&o, "missing file", "/nonexistent/p.csv");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `eval --truth`: the formula as written in high precision, rounded once: `(k + NH) − k` is NH exactly, where
/// f64 arithmetic as written gives 0 at NH = 1e-20. --set folds k, a parameter column stays live, the report
/// names backend `truth`; with --normalize it is a usage error.
#[test]
fn eval_truth_is_the_formula_as_written_in_high_precision() {
    let dir = std::env::temp_dir().join(format!("lobe-truth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("t.brdf");
    std::fs::write(&file, "param k = 2 in 1..4\n(k + NH) - k\n").unwrap();
    let file = file.display().to_string();
    let o = lobe(&["eval", &file, "--at", "NH=1e-20", "--set", "k=3", "--truth", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((v["backend"].as_str(), v["value"].as_f64()), (Some("truth"), Some(1e-20)), "{v}");
    let csv = "NH,k\n1e-20,2\n0.25,3.5\n1,1\n";
    let o = lobe(&["eval", &file, "--points", "-", "--truth"], Some(csv.as_bytes()));
    assert!(o.status.success(), "{}", stderr(&o));
    let values: Vec<f64> = String::from_utf8_lossy(&o.stdout).lines().map(|l| l.parse().unwrap()).collect();
    assert_eq!(values, vec![1e-20, 0.25, 1.0]);
    let o = lobe(&["eval", &file, "--points", "-", "--truth", "--json"], Some(csv.as_bytes()));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((v["backend"].as_str(), v["math"].as_str(), v["points"].as_u64()), (Some("truth"), Some("truth"), Some(3)), "{v}");
    let o = lobe(&["eval", &file, "--at", "NH=0.5", "--truth", "--normalize"], None);
    assert!(!o.status.success() && stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--tier`: `llvm` gives the LLVM tier's kernel (the same values, bit for bit, as Cranelift's, reported as
/// backend `llvm` with its lanes), or in a build without it a clean error that says how to get it; `auto` falls
/// back to Cranelift there; `--backend interp --tier llvm` is refused; an unknown tier is a usage error.
#[test]
fn tier_picks_the_jit_or_says_how_to_get_llvm() {
    let csv = b"NH,NL,VH,NV\n0.5,0.1,0.3,0.9\n0.9,0.2,0.8,0.7\n1,0,0.5,0.5\n0.25,1,0.1,0.2\n0.999,0.5,0.6,0.3\n";
    let file = "examples/brdfs/cook_torrance.brdf";
    let text = |tier: &str| {
        let o = lobe(&["eval", file, "--points", "-", "--tier", tier], Some(csv));
        (o.status.success(), String::from_utf8_lossy(&o.stdout).into_owned(), stderr(&o))
    };
    let (ok, cranelift, e) = text("cranelift");
    assert!(ok, "{e}");
    // `auto` (the default): five rows stay on Cranelift; 4096 rows move to LLVM in a build with it.
    for args in [&["eval", file, "--points", "-", "--json"][..], &["eval", file, "--points", "-", "--tier", "auto", "--json"]] {
        let o = lobe(args, Some(csv));
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["backend"].as_str(), Some("jit"), "{v}");
    }
    let mut many = String::from("NH,NL,VH,NV\n");
    for i in 0..4096 {
        let t = i as f64 / 4096.0;
        many.push_str(&format!("{},{},{},{}\n", 0.1 + 0.9 * t, 0.05 + 0.9 * t, 0.2 + 0.7 * t, 0.9 - 0.8 * t));
    }
    let auto = lobe(&["eval", file, "--points", "-", "--json"], Some(many.as_bytes()));
    assert!(auto.status.success(), "{}", stderr(&auto));
    let v: serde_json::Value = serde_json::from_slice(&auto.stdout).unwrap();
    assert_eq!(v["backend"].as_str(), Some(if cfg!(feature = "llvm") { "llvm" } else { "jit" }), "{v}");
    let crane = lobe(&["eval", file, "--points", "-", "--tier", "cranelift", "--json"], Some(many.as_bytes()));
    let w: serde_json::Value = serde_json::from_slice(&crane.stdout).unwrap();
    assert_eq!(v["values"], w["values"], "automatic tiering changed a value");
    if cfg!(feature = "llvm") {
        let (ok, llvm, e) = text("llvm");
        assert!(ok, "{e}");
        assert_eq!(llvm, cranelift, "the tiers' values differ");
        let o = lobe(&["eval", file, "--at", "NH=0.9,NL=0.2,VH=0.8,NV=0.7", "--tier", "llvm", "--json"], None);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["backend"].as_str(), Some("llvm"), "{v}");
        assert!(v["lanes"].as_u64().is_some_and(|l| [2, 4, 8].contains(&l)), "{v}");
        let o = lobe(&["bench", "examples/brdfs/blinn.brdf", "--samples", "3", "--no-albedo", "--tier", "llvm", "--json"], None);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(v[0]["llvm_batch_ns"].as_f64().is_some_and(|ns| ns > 0.0) && v[0]["cranelift_batch_ns"].as_f64().is_some(), "{v}");
    } else {
        let o = lobe(&["eval", file, "--points", "-", "--tier", "llvm"], Some(csv));
        assert_clean_error(&o, "eval --tier llvm without the feature", "--features llvm");
        let o = lobe(&["bench", "examples/brdfs/blinn.brdf", "--tier", "llvm"], None);
        assert_clean_error(&o, "bench --tier llvm without the feature", "--features llvm");
    }
    let o = lobe(&["bench", "examples/brdfs/blinn.brdf", "--samples", "3", "--no-albedo", "--tier", "cranelift", "--json"], None);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v[0].get("llvm_batch_ns").is_none(), "{v}");
    let o = lobe(&["eval", file, "--at", "NH=0.5", "--backend", "interp", "--tier", "llvm"], None);
    assert_clean_error(&o, "interp with a JIT tier", "does not apply to the interpreter backend");
    let o = lobe(&["eval", file, "--at", "NH=0.5", "--tier", "gcc"], None);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("expected `cranelift`, `llvm` or `auto`"), "{}", stderr(&o));
}

/// `bench --math both`: two rows per formula, the error against the precise interpreter measured (0 ulp in
/// precise mode, within the fast bound in fast mode).
#[test]
fn bench_measures_both_math_modes_against_the_precise_interpreter() {
    let o = lobe(&["bench", "examples/brdfs/gaussian.brdf", "--samples", "3", "--no-albedo", "--json", "--math", "both"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v.as_array().unwrap();
    let row = |m: &str| rows.iter().find(|r| r["math"] == m).unwrap_or_else(|| panic!("no {m} row: {v}"));
    assert_eq!(row("precise")["max_ulp_vs_precise"].as_f64(), Some(0.0), "{v}");
    let fast = row("fast")["max_rel_vs_precise"].as_f64().unwrap();
    assert!(fast > 0.0 && fast < 1e-5, "fast Gaussian vs precise: {fast}");
}

/// A reader that closes the pipe early (`lobe eval … | head -1`) ends lobe quietly: exit 0 or 141 (the
/// broken-pipe status), never a panic message. 200 000 output lines are far more than a pipe buffers, so the
/// child is still writing when the pipe closes.
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    use std::io::{BufRead, BufReader};
    let rows: String = std::iter::once("NH\n".to_string()).chain((0..200_000).map(|i| format!("{}\n", (i % 1000) as f64 / 1000.0))).collect();
    let points = std::env::temp_dir().join(format!("lobe-pipe-{}.csv", std::process::id()));
    std::fs::write(&points, rows).unwrap();
    let mut c = Command::new(env!("CARGO_BIN_EXE_lobe"));
    c.args(["eval", "examples/brdfs/blinn.brdf", "--set", "n=20", "--points", points.to_str().unwrap()]);
    c.current_dir(env!("CARGO_MANIFEST_DIR")).stdout(Stdio::piped()).stderr(Stdio::piped()).stdin(Stdio::null());
    let mut child = c.spawn().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    drop(out);
    let o = child.wait_with_output().unwrap();
    let _ = std::fs::remove_file(&points);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!first.trim().is_empty(), "no first line");
    assert!(matches!(o.status.code(), Some(0) | Some(141)), "status {:?}, stderr:\n{e}", o.status);
    assert!(!e.contains("panicked"), "stderr:\n{e}");
}

/// Negative numbers after a flag are its value, checked by lobe, not a flag clap refuses.
#[test]
fn negative_flag_values_get_lobes_own_errors() {
    let o = lobe(&["sweep", "examples/brdfs/blinn.brdf", "--bound", "-1"], None);
    assert_clean_error(&o, "negative bound", "--bound -1 must be a positive number");
    let o = lobe(&["energy", "examples/brdfs/blinn.brdf", "--range", "1..10", "--step", "-1"], None);
    assert_clean_error(&o, "negative step", "the step -1 of the range of n must be positive");
    assert_clean_error(&o, "negative step", "e.g. --step 1");
}

/// Tiny and huge values print in exponent form (shortest text that reads back exactly), ordinary ones as decimals.
#[test]
fn eval_prints_tiny_values_in_exponent_form() {
    let o = lobe(&["eval", "examples/brdfs/beckmann.brdf", "--set", "m=0.3", "--at", "NH=0.5"], None);
    let t = String::from_utf8_lossy(&o.stdout).trim().to_string();
    assert!(t.contains('e') && t.len() < 25, "{t}");
    let j = lobe(&["eval", "examples/brdfs/beckmann.brdf", "--set", "m=0.3", "--at", "NH=0.5", "--json"], None);
    let v: serde_json::Value = serde_json::from_slice(&j.stdout).unwrap();
    assert_eq!(t.parse::<f64>().unwrap(), v["value"].as_f64().unwrap());
    let o = lobe(&["eval", "examples/brdfs/modified_schlick.brdf", "--set", "n=50", "--at", "NH=0.95"], None);
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "0.11178397012352757");
}

/// Each of the accuracy pass's internal builtins, called from a .brdf file, ends `lobe eval` and `lobe check`
/// with the front end's error at file:line:col and its hint of what to write instead.
#[test]
fn internal_builtins_in_a_file_are_refused_by_eval_and_check() {
    let dir = crate::scratch_dir("cli", "internal");
    for (name, call, instead) in [
        ("expmuldiv", "expmuldiv(NH - 1, 2, NL)", "write `exp(a) * b / c`"),
        ("acoslo", "acoslo(NH)", "write `acos(x)`"),
        ("powlo", "powlo(NH, n)", "write `pow(x, y)`"),
    ] {
        let path = dir.join(format!("{name}.brdf"));
        std::fs::write(&path, format!("# calls {name}\nlet c = NH\nc + {call}\n")).unwrap();
        let p = path.display().to_string();
        for args in [&["eval", &p, "--at", "NH=0.5,NL=0.5"][..], &["check", &p][..]] {
            let o = lobe(args, None);
            let what = format!("{} {name}", args[0]);
            assert_clean_error(&o, &what, &format!("`{name}` is internal to the accuracy pass, not a function of the language"));
            assert_clean_error(&o, &what, &format!("{name}.brdf:3:5"));
            assert_clean_error(&o, &what, instead);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The accuracy pass's decision is stored in `$LOBE_CACHE_DIR` by the first command and replayed by the next
/// (the same value); `--no-cache` neither reads nor writes it; an unusable cache directory is not an error.
#[test]
fn the_pass_decision_cache_is_used_and_can_be_bypassed() {
    let dir = crate::scratch_dir("cli", "pass-cache");
    let run = |args: &[&str], cache: &std::path::Path| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_lobe"));
        c.args(args).current_dir(env!("CARGO_MANIFEST_DIR")).env("NO_COLOR", "1").env("LOBE_CACHE_DIR", cache);
        c.output().unwrap()
    };
    let args = ["eval", "examples/brdfs/fst.brdf", "--set", "n=16,a=16", "--at", "NH=1e-4"];
    let first = run(&args, &dir);
    assert!(first.status.success(), "{}", stderr(&first));
    let files = || std::fs::read_dir(&dir).unwrap().filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "pass")).count();
    assert!(files() >= 1, "no decision stored");
    let second = run(&args, &dir);
    assert_eq!(String::from_utf8_lossy(&first.stdout), String::from_utf8_lossy(&second.stdout));
    // The truth is 1.0000000000000008e-64 (F_ST at n = a = 16 is NH^16); the compensated chain is within 2 ulp.
    let got: f64 = String::from_utf8_lossy(&first.stdout).trim().parse().unwrap();
    assert!((got.to_bits() as i64 - 1.0000000000000008e-64f64.to_bits() as i64).abs() <= 2, "{got}");
    let other = crate::scratch_dir("cli", "pass-cache-off");
    let off = run(&["--no-cache", "eval", "examples/brdfs/fst.brdf", "--at", "NH=0.9"], &other);
    assert!(off.status.success() && std::fs::read_dir(&other).unwrap().next().is_none(), "--no-cache wrote the cache");
    let bad = run(&args, std::path::Path::new("/proc/no/such/dir"));
    assert!(bad.status.success(), "{}", stderr(&bad));
    // A usage error: clap's exit code 2, lobe's words.
    let o = lobe(&["check", "examples/brdfs/fst.brdf", "--budget", "-1"], None);
    assert!(o.status.code() == Some(2) && stderr(&o).contains("positive number of seconds"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&other);
}

/// `lobe render` shades with the accuracy pass's form, as `eval` computes: the bundled Cook–Torrance scene has no
/// NaN pixel (the plain form is 0/0 at the silhouette, where an interpolated normal makes N·V ≤ 0 beside N·L > 0:
/// thousands of NaN pixels at 2048²), and the plain kernels still show them, so the scene is the hard case.
#[test]
fn renders_shade_with_the_accuracy_pass_and_have_no_nan_pixels() {
    let dir = std::env::temp_dir().join(format!("lobe-render-pass-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("ct.png");
    let o = lobe(&["render", "examples/scenes/fill_cook_torrance.toml", "--size", "512", "--stats", "--json", "-o", out.to_str().unwrap()], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["nan"], 0, "{j}");
    assert!(j["visible_px"].as_u64().unwrap() > 100_000, "{j}");
    let plain = lobe::render::scene::LobeCompiler::plain(lobe::Backend::Jit, lobe::Mode::Precise);
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/fill_cook_torrance.toml");
    let opts = lobe::render::scene::LoadOptions { size: Some((512, 512)), ..Default::default() };
    let sc = lobe::render::scene::load_scene(&path, &opts, &plain).unwrap_or_else(|d| panic!("{}", d.render(false)));
    let (_, stats) = lobe::render::render(&sc, &lobe::render::RenderOptions::default()).unwrap();
    assert!(stats.nan > 0, "the plain form has no NaN pixel here any more: {stats:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Formulas as large as the 1 MiB source cap allows — a 300 000-term sum (600 000 nodes as written) and a
/// 10⁶-deep unary minus — go through check, eval, export and render without a stack overflow (the command runs
/// on a thread with a large stack), a quadratic export (long expressions get temporaries) or a truth measured at
/// 10⁵ points of 10⁶ nodes each (the sample shrinks with the truth's size).
#[test]
fn formulas_at_the_size_cap_go_through_every_command() {
    let dir = std::env::temp_dir().join(format!("lobe-huge-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sum = dir.join("sum.brdf");
    std::fs::write(&sum, format!("{}NH\n", "NH+".repeat(300_000))).unwrap();
    let neg = dir.join("neg.brdf");
    std::fs::write(&neg, format!("{}NH\n", "-".repeat(1_000_000))).unwrap();
    let scene = dir.join("huge.toml");
    let src = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/paper_sphere.toml")).unwrap();
    std::fs::write(&scene, src.replace("\"../brdfs/modified_schlick_vr.brdf\"", "\"sum.brdf\"").replace("params = { n = 50 }", "params = { }")).unwrap();
    let (s, n) = (sum.to_str().unwrap(), neg.to_str().unwrap());
    let png = dir.join("huge.png");
    let runs: Vec<(Vec<&str>, &str)> = vec![
        (vec!["eval", s, "--at", "NH=0.5"], "150000.5"),
        (vec!["eval", n, "--at", "NH=0.5"], "0.5"),
        (vec!["check", s, "--points", "2000"], "accuracy"),
        (vec!["check", n], "accuracy"),
        (vec!["export", s], "float lobe_sum(float NH)"),
        (vec!["export", n, "--wgsl"], "fn lobe_neg(NH: f32)"),
        (vec!["render", scene.to_str().unwrap(), "--size", "48", "-o", png.to_str().unwrap()], ""),
    ];
    for (args, want) in runs {
        let o = lobe(&args, None);
        let (out, err) = (String::from_utf8_lossy(&o.stdout), stderr(&o));
        assert!(o.status.success(), "{args:?}: {:?}\n{err}", o.status);
        assert!(out.contains(want), "{args:?}: {}", &out[..out.len().min(400)]);
    }
    assert!(png.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Outside a checkout, `bench` measures the built-in catalogue against the built-in Blinn, and `watch` renders
/// into the built-in paper scene: their defaults name files of the repository.
#[test]
fn bench_and_watch_defaults_work_outside_the_checkout() {
    let dir = crate::scratch_dir("cli", "elsewhere");
    let run = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_lobe")).args(args).current_dir(&dir).env("NO_COLOR", "1").output().unwrap();
    let o = run(&["bench", "--samples", "3", "--no-albedo", "--timing-points", "256", "--tier", "cranelift", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v.as_array().map_or(0, Vec::len);
    assert_eq!(rows, std::fs::read_dir("examples/brdfs").unwrap().filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "brdf")).count(), "{}", String::from_utf8_lossy(&o.stdout));
    std::fs::write(dir.join("w.brdf"), "VR^n\n").unwrap();
    let o = run(&["watch", "w.brdf", "-o", "w.png", "--count", "1", "--size", "32"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let png = lobe::base::image::Image::decode_png(&std::fs::read(dir.join("w.png")).unwrap()).unwrap();
    assert!(png.width == 32 && png.rgb.iter().any(|&c| c > 0));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--set` reaches the reference too (each side takes the parameters it declares) in `fit` and `accuracy` (here
/// over the whole hemisphere: Beckmann reads no n), and `--set n`, which the papers' metrics sweep where both
/// formulas read it, is refused instead of ignored.
#[test]
fn set_values_reach_the_reference_and_n_is_refused() {
    let score = |args: &[&str]| -> f64 {
        let o = lobe(args, None);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["error"].as_f64().or_else(|| v["log"].as_f64()).unwrap()
    };
    let fit = |m: &str| score(&["fit", "examples/brdfs/fst.brdf", "--reference", "examples/brdfs/beckmann.brdf", "--param", "a=1..100", "--set", m, "--stride", "6", "--quiet", "--json"]);
    assert_ne!(fit("m=0.2"), fit("m=0.5"));
    let acc = |m: &str| score(&["accuracy", "examples/brdfs/phong.brdf", "--reference", "examples/brdfs/beckmann.brdf", "--set", m, "--json"]);
    assert_ne!(acc("m=0.2"), acc("m=0.5"));
    let o = lobe(&["fit", "examples/brdfs/fst.brdf", "--reference", "examples/brdfs/blinn.brdf", "--param", "a=1..100", "--set", "n=50"], None);
    assert_clean_error(&o, "--set n in a fit", "the papers' metrics sweep n");
    let o = lobe(&["accuracy", "examples/brdfs/phong.brdf", "--reference", "examples/brdfs/beckmann.brdf", "--set", "q=1"], None);
    assert_clean_error(&o, "a name neither declares", "no formula has a parameter `q`");
}

/// `plot --incidence --log`: a log value axis in the plane of incidence (it was refused); polar stays linear.
#[test]
fn plots_at_incidence_take_a_log_axis() {
    let dir = crate::scratch_dir("cli", "plot-log");
    let png = dir.join("p.png").display().to_string();
    let o = lobe(&["plot", "examples/brdfs/blinn.brdf", "examples/brdfs/phong.brdf", "--incidence", "60", "--log", "-o", &png, "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["series"].as_array().map(Vec::len), Some(2), "{v}");
    let img = lobe::base::image::Image::decode_png(&std::fs::read(&png).unwrap()).unwrap();
    assert!(img.width > 100 && img.rgb.iter().any(|&c| c < 128));
    let o = lobe(&["plot", "examples/brdfs/blinn.brdf", "--incidence", "60", "--log", "--polar", "-o", &png, "--force"], None);
    assert_clean_error(&o, "a log radius", "cartesian plots only");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Plots name their axes (which angle, which value) in the image and in `--json`, and a pole at grazing (Ward's
/// 1/√(NL·NV) at θₒ = ±90°) does not flatten the other curves: the value axis ends below it and the legend says so.
#[test]
fn plots_name_their_axes_and_a_pole_does_not_flatten_the_others() {
    let dir = crate::scratch_dir("cli", "plot-axes");
    let ward = dir.join("ward_pole.brdf");
    std::fs::write(&ward, "param a = 0.3 in 0.01..1\nexp(-(1-NH*NH)/(NH*NH*a*a))/(4*3.14159265*a*a*sqrt(NL*NV))\n").unwrap();
    let png = dir.join("p.png").display().to_string();
    let run = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec!["plot", ward.to_str().unwrap(), "examples/brdfs/blinn.brdf", "-o", &png, "--force", "--json"];
        args.extend_from_slice(extra);
        let o = lobe(&args, None);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let v = run(&[]);
    assert!(v["x"].as_str().unwrap().contains("lobe angle θ") && v["y"] == "formula value f", "{v}");
    let v = run(&["--incidence", "60"]);
    assert!(v["x"].as_str().unwrap().contains("plane of incidence"), "{v}");
    let ys: Vec<f64> = v["series"][0]["y"].as_array().unwrap().iter().filter_map(|y| y.as_f64()).collect();
    assert!(ys.iter().cloned().fold(0.0, f64::max) > 1e6, "the formula has its pole at grazing");
    // The image: Blinn's curve (the second colour) spans a good part of the plot's height, not a line at 0.
    let img = lobe::base::image::Image::decode_png(&std::fs::read(&png).unwrap()).unwrap();
    let orange: Vec<usize> = (0..img.height).filter(|&y| (0..img.width * 2 / 3).any(|x| { let [r, g, b] = img.pixel(x, y); r > 180 && g > 60 && g < 140 && b < 60 })).collect();
    let span = orange.iter().max().unwrap() - orange.iter().min().unwrap();
    assert!(span > img.height / 20, "Blinn's curve spans {span} of {} rows", img.height);
    let v = run(&["--error", "--reference", "examples/brdfs/phong.brdf"]);
    assert_eq!(v["y"], "f − reference", "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `plot --ylim lo,hi`: the value axis a paper asks for (curves clipped to it); bad ranges are clear errors.
#[test]
fn plot_takes_a_value_range() {
    let dir = crate::scratch_dir("cli", "plot-ylim");
    let png = |n: &str| dir.join(n).display().to_string();
    let (a, b) = (png("a.png"), png("b.png"));
    for (out, lim) in [(&a, "0,2"), (&b, "0,0.5")] {
        let o = lobe(&["plot", "examples/brdfs/ward.brdf", "examples/brdfs/blinn.brdf", "--ylim", lim, "-o", out], None);
        assert!(o.status.success(), "{lim}: {}", stderr(&o));
    }
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap(), "the range changes the figure");
    let o = lobe(&["plot", "examples/brdfs/blinn.brdf", "--incidence", "30", "--log", "--ylim", "1e-6,2", "-o", &a, "--force"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    for (args, needle) in [
        (vec!["--ylim", "2,1"], "not an interval"),
        (vec!["--ylim", "0,1", "--log"], "positive values"),
        (vec!["--ylim", "0,1", "--polar"], "cartesian plots only"),
        (vec!["--ylim", "0"], "two values"),
    ] {
        let mut v = vec!["plot", "examples/brdfs/blinn.brdf", "-o", &a, "--force"];
        v.extend(args.iter().copied());
        assert_clean_error(&lobe(&v, None), needle, needle);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `lobe watch` on a traced scene refines: one JSON line per level (`spp` 1, 4, 16 of `final_spp` 16), and the
/// last image is `lobe render --spp 16` of the scene byte for byte.
#[test]
fn watch_refines_a_traced_scene_up_to_lobe_render() {
    let dir = crate::scratch_dir("watch", "traced");
    let (out, cli) = (dir.join("w.png").display().to_string(), dir.join("r.png").display().to_string());
    let scene = "examples/scenes/environment.toml";
    let r = lobe(&["watch", "examples/explorer/ggx.brdf", "--scene", scene, "-o", &out, "--size", "32", "--spp", "16", "--count", "1", "--json"], None);
    assert!(r.status.success(), "{}", stderr(&r));
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&r.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let levels: Vec<(u64, u64, u64)> = lines.iter().map(|l| (l["reload"].as_u64().unwrap(), l["spp"].as_u64().unwrap(), l["final_spp"].as_u64().unwrap())).collect();
    assert_eq!(levels, [(1, 1, 16), (1, 4, 16), (1, 16, 16)], "{lines:?}");
    assert!(lines.iter().all(|l| l["ok"] == true && l["output"] == out.as_str()));
    let o = lobe(&["render", scene, "--size", "32", "--spp", "16", "-q", "-o", &cli], None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read(&out).unwrap() == std::fs::read(&cli).unwrap(), "the last level is not lobe render --spp 16");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A change of the watched file while a traced scene refines stops the series and reloads: at 4096 spp the
/// series would take a minute, but the first reload ends below it and the second (a broken formula) follows.
/// The time from the write to the reload is printed, not asserted.
#[test]
fn watch_stops_refining_when_the_file_changes() {
    use std::io::BufRead;
    let dir = crate::scratch_dir("watch", "stop");
    let brdf = dir.join("ggx.brdf");
    std::fs::copy("examples/explorer/ggx.brdf", &brdf).unwrap();
    let out = dir.join("w.png");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lobe"))
        .args(["watch", brdf.to_str().unwrap(), "--scene", "examples/scenes/environment.toml", "-o", out.to_str().unwrap()])
        .args(["--size", "64", "--spp", "4096", "--count", "2", "--interval-ms", "20", "--json"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = vec![];
    let mut written = None;
    for line in std::io::BufReader::new(child.stdout.take().unwrap()).lines() {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        if written.is_none() {
            std::fs::write(&brdf, "NH^^\n").unwrap();
            written = Some(std::time::Instant::now());
        }
        if v["reload"] == 2 {
            println!("reload after the change in {:?}", written.unwrap().elapsed());
        }
        lines.push(v);
    }
    let status = child.wait().unwrap();
    let first: Vec<u64> = lines.iter().filter(|l| l["reload"] == 1).map(|l| l["spp"].as_u64().unwrap()).collect();
    assert!(!first.is_empty() && first.windows(2).all(|w| w[0] < w[1]) && *first.last().unwrap() < 4096, "reload 1's levels {first:?}");
    let second: Vec<&serde_json::Value> = lines.iter().filter(|l| l["reload"] == 2).collect();
    assert!(second.len() == 1 && second[0]["ok"] == false, "{lines:?}");
    assert_eq!(status.code(), Some(1), "the last reload failed");
    assert_eq!(&std::fs::read(&out).unwrap()[1..4], b"PNG", "the last good image stays");
    let _ = std::fs::remove_dir_all(&dir);
}
