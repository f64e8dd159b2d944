//! Hostile but fair input, end to end through the `lobe` binary: every case runs under a timeout and must end
//! with a clear message and exit code 1 (or a correct result), write nothing it should not, and replace
//! nothing the user has. Needs `mkfifo` (coreutils) for the FIFO cases; they are skipped without it.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What a run did.
struct Run {
    code: Option<i32>,
    stdout: Vec<u8>,
    stderr: String,
    /// The largest resident set seen while it ran, KiB (0 where /proc is not available).
    peak_kib: u64,
}

/// Runs lobe with `args`, killing it (and failing the test) after `limit`. Output is read on threads so a
/// large stream cannot block the child.
fn lobe_within(limit: Duration, args: &[&str]) -> Run {
    lobe_within_env(limit, args, &[])
}

/// [`lobe_within`] with environment variables set for the run.
fn lobe_within_env(limit: Duration, args: &[&str], env: &[(&str, &str)]) -> Run {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lobe"))
        .args(args)
        .envs(env.iter().copied())
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn lobe");
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let t_out = std::thread::spawn(move || {
        let mut b = Vec::new();
        let _ = (&mut out).take(64 << 20).read_to_end(&mut b);
        b
    });
    let t_err = std::thread::spawn(move || {
        let mut b = Vec::new();
        let _ = (&mut err).take(64 << 20).read_to_end(&mut b);
        b
    });
    let start = Instant::now();
    let pid = child.id();
    let mut peak_kib = 0u64;
    let status = loop {
        if let Some(kib) = peak_rss_kib(pid) {
            peak_kib = peak_kib.max(kib);
        }
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("`lobe {}` did not finish within {limit:?}", args.join(" "));
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    Run { code: status.code(), stdout: t_out.join().unwrap(), stderr: String::from_utf8_lossy(&t_err.join().unwrap()).into_owned(), peak_kib }
}

/// The resident-set high-water mark of a running process (Linux's VmHWM), KiB; `None` elsewhere or once it ended.
pub(crate) fn peak_rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The bound every case of the work-budget set answers within: 10 s and 1 GiB of resident memory (sampled every
/// 10 ms while it runs, so a peak in the last moments can be missed; the bound is far above what a bounded run
/// uses).
fn lobe_bounded(args: &[&str]) -> Run {
    let r = lobe_within(Duration::from_secs(10), args);
    assert!(r.peak_kib < 1 << 20, "`lobe {}` used {} MiB", args.join(" "), r.peak_kib >> 10);
    r
}

fn lobe(args: &[&str]) -> Run {
    lobe_within(Duration::from_secs(20), args)
}

/// Exit code 1, an `error` line containing `needle`, no panic.
fn refused(r: &Run, what: &str, needle: &str) {
    crate::cli::assert_clean_exit(r.code, &r.stderr, what, needle);
}

fn scratch(tag: &str) -> PathBuf {
    crate::scratch_dir("hostile", tag)
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn mkfifo(p: &Path) -> bool {
    Command::new("mkfifo").arg(p).status().map(|s| s.success()).unwrap_or(false)
}

#[cfg(unix)]
#[test]
fn outputs_that_are_not_regular_files_are_refused_even_with_force() {
    use std::os::unix::fs::FileTypeExt;
    let d = scratch("nonregular");
    let fifo = d.join("pipe.png");
    let have_fifo = mkfifo(&fifo);
    let mut targets = vec!["/dev/null".to_string(), "/dev/zero".to_string(), "/dev/full".to_string()];
    if have_fifo {
        targets.push(s(&fifo));
    }
    for t in &targets {
        for force in [false, true] {
            let mut args = vec!["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", t];
            args.extend(force.then_some("--force"));
            refused(&lobe(&args), &format!("render -o {t} force={force}"), "not a regular file");
        }
    }
    if have_fifo {
        let r = lobe(&["plot", "examples/brdfs/phong.brdf", "--set", "n=5", "-o", &s(&fifo), "--force"]);
        refused(&r, "plot -o FIFO --force", "not a regular file");
    }
    assert!(std::fs::metadata("/dev/null").unwrap().file_type().is_char_device(), "/dev/null was replaced");
    if have_fifo {
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo(), "the FIFO was replaced");
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_huge_foreign_output_is_refused_after_reading_only_its_start() {
    let d = scratch("huge");
    let big = d.join("big.png");
    // 4 GiB sparse: reading it whole would take seconds and gigabytes.
    let f = std::fs::File::create(&big).unwrap();
    f.set_len(4 << 30).unwrap();
    drop(f);
    let r = lobe_within(Duration::from_secs(10), &["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &s(&big)]);
    refused(&r, "render over a 4 GiB foreign file", "nothing in it shows lobe wrote it");
    assert_eq!(std::fs::metadata(&big).unwrap().len(), 4 << 30);
    let _ = std::fs::remove_dir_all(&d);
}

#[cfg(unix)]
#[test]
fn replacing_an_output_keeps_its_link_and_its_mode() {
    use std::os::unix::fs::PermissionsExt;
    let d = scratch("link");
    let real = d.join("real.png");
    let link = d.join("link.png");
    let r = lobe(&["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &s(&real)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o600)).unwrap();
    std::os::unix::fs::symlink(&real, &link).unwrap();
    let r = lobe(&["render", "examples/scenes/paper_sphere.toml", "--size", "24", "-o", &s(&link)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link became a file");
    assert_eq!(std::fs::metadata(&real).unwrap().permissions().mode() & 0o777, 0o600, "the mode was reset");
    let png = lobe::base::image::Image::decode_png(&std::fs::read(&real).unwrap()).unwrap();
    assert_eq!(png.width, 24, "the link's target was not rewritten");
    let leftovers: Vec<_> = std::fs::read_dir(&d).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().contains("lobe-tmp")).collect();
    assert!(leftovers.is_empty(), "temporary files left behind");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn log_plots_with_nothing_positive_end_with_an_error() {
    let d = scratch("plot");
    let out = d.join("p.png");
    for (expr, log) in [("0*NH", true), ("0*NH/0", false), ("0*NH/0", true)] {
        let file = d.join("f.brdf");
        std::fs::write(&file, expr).unwrap();
        let file = s(&file);
        let mut args = vec!["plot", &file, "-o", out.to_str().unwrap()];
        args.extend(log.then_some("--log"));
        refused(&lobe_within(Duration::from_secs(10), &args), &format!("plot {expr} log={log}"), "nothing to plot");
        assert!(!out.exists(), "a failed plot wrote {}", out.display());
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn shader_export_mangles_hostile_names_and_metadata() {
    let d = scratch("export");
    let f = d.join("hostile.brdf");
    // A CR ends the line, in a string too: metadata cannot smuggle one into the shader.
    std::fs::write(&f, "@name \"x\r#define pow(a,b) 0.0\"\nNH\n").unwrap();
    refused(&lobe(&["export", "--glsl", &s(&f)]), "a CR in @name", "unterminated string");
    std::fs::write(&f, "@name \"x\u{2028}#define pow(a,b) 0.0\x0b#define exp(a) 0.0\"\nparam t0 = 1\nparam float = 2\nparam gl_Position = 3\nparam output = 4\nparam alias = 5\nparam var = 6\nparam loop = 7\nparam f32 = 8\npow(NH, n) * t0 * float * gl_Position * output * alias * var * loop * f32\n").unwrap();
    for dialect in ["--glsl", "--wgsl"] {
        let r = lobe(&["export", dialect, &s(&f)]);
        assert_eq!(r.code, Some(0), "{}", r.stderr);
        let text = String::from_utf8_lossy(&r.stdout);
        assert!(!text.contains(['\r', '\u{2028}', '\x0b']), "{text}");
        assert!(text.lines().all(|l| l.trim_start().starts_with("//") || !l.contains("#define")), "{text}");
        for name in ["t0", "float", "gl_Position", "output", "alias", "var", "loop", "f32"] {
            assert!(text.contains(&format!("p_{name}")), "{name} not mangled:\n{text}");
        }
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn obj_values_the_renderer_cannot_use_name_their_line() {
    let d = scratch("obj");
    let scene = |obj: &str| {
        std::fs::write(d.join("m.obj"), obj).unwrap();
        let toml = "[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
                    [materials.m]\nformula = \"NH^n\"\n[[object]]\nshape = \"mesh\"\npath = \"m.obj\"\nmaterial = \"m\"\n";
        std::fs::write(d.join("s.toml"), toml).unwrap();
        lobe(&["render", &s(&d.join("s.toml")), "--size", "16", "-o", &s(&d.join("o.png"))])
    };
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    refused(&scene(&format!("{tri}vn 0 0 0\nf 1//1 2//1 3//1\n")), "vn 0 0 0", "m.obj:4");
    refused(&scene(&format!("{tri}vn nan 0 1\nf 1//1 2//1 3//1\n")), "vn nan", "m.obj:4");
    refused(&scene(&format!("{tri}v 1e39 0 0\nf 1 2 3\n")), "v 1e39", "m.obj:4");
    refused(&scene(&format!("{tri}vn 0 0 1\nf 1//1 2//1 3\n")), "missing normal index", "m.obj:5");
    assert!(!d.join("o.png").exists());
    let _ = std::fs::remove_dir_all(&d);
}

/// 40 lines of `let aK = sin(aK-1) + cos(aK-1)`: printed as a tree this is 2^40 nodes. Every command prints the
/// shared form, so output stays proportional to the file.
#[test]
fn deep_shared_lets_print_and_export_in_their_let_form() {
    let d = scratch("lets");
    let mut src = String::from("let a0 = NH\n");
    for k in 1..=40 {
        src.push_str(&format!("let a{k} = sin(a{}) + cos(a{})\n", k - 1, k - 1));
    }
    src.push_str("a40\n");
    let f = d.join("chain.brdf");
    std::fs::write(&f, &src).unwrap();
    let f = s(&f);
    for args in [
        vec!["check", &f],
        vec!["check", &f, "--json"],
        vec!["export", "--glsl", &f],
        vec!["export", "--wgsl", &f],
        vec!["sweep", &f, "--max-evals", "2000"],
        vec!["eval", &f, "--at", "NH=0.5"],
    ] {
        // A hang guard, not a timing: `check` runs the accuracy pass (budget 10 s) and measures 10⁵ points of a
        // 120-node truth, ~7 s of CPU here, so the bound leaves room for a loaded machine.
        let r = lobe_within(std::time::Duration::from_secs(60), &args);
        assert_eq!(r.code, Some(0), "{args:?}: {}", r.stderr);
        assert!(r.stdout.len() < 64 * 1024, "{args:?} printed {} bytes", r.stdout.len());
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn scene_files_are_bounded_and_their_numbers_checked() {
    let r = lobe_within(Duration::from_secs(10), &["render", "/dev/zero", "-o", "/tmp/never.png"]);
    refused(&r, "scene /dev/zero", "not a regular file");
    let d = scratch("scene");
    let good = "[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
                [materials.m]\nformula = \"NH^n\"\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";
    let out = d.join("o.png");
    let run = |name: &str, toml: &str| {
        let p = d.join(name);
        std::fs::write(&p, toml).unwrap();
        lobe(&["render", &s(&p), "--size", "16", "-o", &s(&out)])
    };
    for (name, toml, needle) in [
        ("nan_light.toml", good.replace("position = [10, 0, 10]", "position = [10, 0, 10]\ncolor = [nan, 1, 1]"), "color"),
        ("inf_light.toml", good.replace("position = [10, 0, 10]", "position = [inf, 0, 10]"), "finite"),
        ("neg_ambient.toml", format!("ambient = [-1, 0, 0]\n{good}"), "ambient"),
        ("nan_background.toml", format!("background = [0, nan, 0]\n{good}"), "background"),
        ("zero_up.toml", good.replace("position = [0, 0, 6]", "position = [0, 0, 6]\nup = [0, 0, 0]"), "non-zero"),
        ("no_camera.toml", good.replace("[camera]\nposition = [0, 0, 6]\n", ""), "[camera]"),
        ("nan_colour.toml", good.replace("formula = \"NH^n\"", "formula = \"NH^n\"\ncolor = [1, nan, 1]"), "color"),
    ] {
        let r = run(name, &toml);
        refused(&r, name, needle);
        assert!(!r.stderr.contains("`width`"), "{name} blames width:\n{}", r.stderr);
    }
    assert!(!out.exists());
    let r = lobe_within(Duration::from_secs(10), &["render", "examples/scenes/paper_sphere.toml", "--size", "16", "--threads", "20000", "-o", &s(&out)]);
    refused(&r, "--threads 20000", "--threads");
    for ext in ["x.jpg", "x.svg"] {
        let r = lobe(&["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &s(&d.join(ext))]);
        refused(&r, ext, "PNG");
        assert!(!d.join(ext).exists());
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn numerical_commands_refuse_what_they_cannot_answer() {
    let d = scratch("numerics");
    let write = |name: &str, text: &str| {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        s(&p)
    };
    let nan = write("nan.brdf", "param a = 1 in 1..4\n0*NH/0 + a\n");
    // Reads n, so the papers' metrics (which sweep it) apply and must say why they are undefined.
    let zero = write("zero.brdf", "0*NH^n\n");
    let a_only = write("a_only.brdf", "param a = 16 in 1..1000\nNH^a\n");
    // fit with NaN everywhere: no "best".
    let r = lobe(&["fit", &nan, "--reference", "examples/brdfs/blinn.brdf", "--param", "a=1..4", "--n-max", "20"]);
    refused(&r, "fit NaN", "no candidate has a finite");
    // accuracy against a reference that is zero: relative errors are undefined, not -inf %.
    let r = lobe(&["accuracy", "examples/brdfs/blinn.brdf", "--reference", &zero, "--n-max", "20"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(!text.contains("-inf") && text.contains("undefined"), "{text}");
    // Nothing is "NaN % at n = NaN" or an infinite ratio: it says why the metrics are undefined.
    assert!(!text.contains("NaN") && !text.contains("inf %") && !text.contains("inf ("), "{text}");
    assert!(text.contains("the reference is 0 at every angle and n"), "{text}");
    // compare: a --set name only B declares applies to B.
    let r = lobe(&["compare", "examples/brdfs/blinn.brdf", &a_only, "--set", "a=16", "--size", "16", "--json"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let r = lobe(&["compare", "examples/brdfs/blinn.brdf", &a_only, "--set", "zz=16", "--size", "16"]);
    refused(&r, "compare --set zz", "neither formula");
    // Duplicate names in one list; zero budgets.
    for args in [["--set", "n=5,n=6", "--at", "NH=0.5"], ["--set", "n=5", "--at", "NH=0.5,NH=0.9"]] {
        let r = lobe(&[&["eval", "examples/brdfs/blinn.brdf"][..], &args[..]].concat());
        assert!(r.code == Some(2) && r.stderr.contains("twice"), "{args:?}: {:?} {}", r.code, r.stderr);
    }
    assert_eq!(lobe(&["sweep", "examples/brdfs/blinn.brdf", "--max-evals", "0"]).code, Some(2));
    let r = lobe(&["fit", &a_only, "--reference", "examples/brdfs/blinn.brdf", "--param", "a=1..4", "--top", "0"]);
    assert_eq!(r.code, Some(2));
    // A lobe scaled so small its coefficient overflows.
    refused(&lobe(&["eval", "--expr", "NH^n*1e-300*1e-10", "--normalize", "--at", "NH=1"]), "normalize tiny", "overflows");
    // watch --count 1 on a broken file: no image and a failing status.
    let broken = write("broken.brdf", "NH^^n\n");
    let out = d.join("w.png");
    let r = lobe(&["watch", &broken, "--scene", "examples/scenes/paper_sphere.toml", "-o", &s(&out), "--size", "16", "--count", "1"]);
    assert_eq!(r.code, Some(1), "{}", r.stderr);
    assert!(!out.exists());
    assert!(r.stderr.contains("no image yet") && !r.stderr.contains("keeping the last good image"), "{}", r.stderr);
    // compare on a scene without objects.
    let empty = write("empty.toml", "[camera]\nposition = [0, 0, 6]\n");
    let r = lobe(&["compare", "examples/brdfs/blinn.brdf", "examples/brdfs/phong.brdf", "--scene", &empty, "--size", "16"]);
    refused(&r, "compare without objects", "no objects");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn messages_say_what_the_user_meant() {
    let d = scratch("messages");
    let r = lobe(&["eval", "--expr", "0x10 * NH", "--at", "NH=1"]);
    refused(&r, "0x10", "write `16`");
    assert!(!r.stderr.contains("0 * x10"), "{}", r.stderr);
    let r = lobe(&["eval", "--expr", "1_0*NH", "--at", "NH=1"]);
    refused(&r, "1_0", "digit separators are not supported: write `10`");
    assert!(!r.stderr.contains("1 * _0"), "{}", r.stderr);
    let r = lobe(&["eval", "--expr", "param a = NH\nNH^a", "--at", "NH=1"]);
    refused(&r, "param a = NH", "a parameter's default must be a constant number");
    let r = lobe(&["eval", "--expr", "-NH+1", "--at", "NH=0.25"]);
    assert_eq!((r.code, String::from_utf8_lossy(&r.stdout).trim()), (Some(0), "0.75"), "{}", r.stderr);
    let bom = d.join("bom.brdf");
    std::fs::write(&bom, "\u{feff}NH^n\n").unwrap();
    let r = lobe(&["eval", &s(&bom), "--set", "n=2", "--at", "NH=0.5"]);
    assert_eq!((r.code, String::from_utf8_lossy(&r.stdout).trim()), (Some(0), "0.25"), "{}", r.stderr);
    refused(&lobe(&["eval", "examples/brdfs/blinn.brdf", "--set", "NH=5"]), "--set NH", "--at NH");
    let r = lobe(&["eval", "examples/brdfs/blinn.brdf", "--set", "n=1e300"]);
    refused(&r, "--set n=1e300", "1e300");
    assert!(!r.stderr.contains("000000000000"), "{}", r.stderr);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_long_line_is_not_echoed_whole() {
    let d = scratch("longline");
    let f = d.join("long.brdf");
    std::fs::write(&f, format!("{}NH ^^ n\n", "1 + ".repeat(100_000))).unwrap();
    let r = lobe(&["eval", &s(&f)]);
    refused(&r, "long line", "too long to show");
    assert!(r.stderr.len() < 10_000, "{} bytes of stderr", r.stderr.len());
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn an_infinite_lobe_is_no_light_and_counted() {
    let d = scratch("inf");
    let toml = "[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
                [materials.m]\nformula = \"NH/0\"\nka = 0\nkd = 0\nks = 1\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";
    std::fs::write(d.join("s.toml"), toml).unwrap();
    let out = d.join("o.png");
    let r = lobe(&["render", &s(&d.join("s.toml")), "--size", "32", "-o", &s(&out), "--stats"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(r.stderr.contains("NaN or ±inf"), "{}", r.stderr);
    let im = lobe::base::image::Image::decode_png(&std::fs::read(&out).unwrap()).unwrap();
    assert!(im.rgb.iter().all(|&c| c == 0), "an infinite lobe was drawn as light");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_flag_repeated_with_another_value_is_refused_in_every_command() {
    let d = scratch("repeat");
    let two = d.join("two.brdf");
    std::fs::write(&two, "param a = 1 in 0..10\nNH^n * a\n").unwrap();
    let two = s(&two);
    let r = lobe(&["eval", &two, "--set", "n=5", "--set", "n=6", "--at", "NH=0.5"]);
    refused(&r, "--set twice", "--set gives `n` twice: n=5 and n=6");
    assert!(r.stderr.contains("help:"), "{}", r.stderr);
    let r = lobe(&["eval", &two, "--at", "NH=0.5", "--at", "NH=0.7"]);
    refused(&r, "--at twice", "--at gives `NH` twice: NH=0.5 and NH=0.7");
    let r = lobe(&["eval", "--expr", "L.z * V.z", "--at", "L=0,0,1", "--at", "Lz=0.5,V=0,0,1"]);
    refused(&r, "L and Lz", "--at gives Lz twice: L=0,0,1 and Lz=0.5");
    // Distinct names across flags, and a repeat with the same value, still work.
    let r = lobe(&["eval", &two, "--set", "n=2", "--set", "a=3", "--at", "NH=0.5", "--at", "NH=0.5"]);
    assert_eq!((r.code, String::from_utf8_lossy(&r.stdout).trim()), (Some(0), "0.75"), "{}", r.stderr);
    // Every command takes --set through the same parsing.
    let out = s(&d.join("o.png"));
    for args in [
        vec!["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &out],
        vec!["sweep", &two],
        vec!["energy", &two],
        vec!["check", &two],
        vec!["export", "--glsl", &two],
        vec!["compare", "examples/brdfs/blinn.brdf", &two, "--size", "16"],
    ] {
        let r = lobe(&[&args[..], &["--set", "n=5", "--set", "n=6"][..]].concat());
        refused(&r, &format!("{args:?}"), "--set gives `n` twice: n=5 and n=6");
    }
    assert!(!d.join("o.png").exists());
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn sweep_keeps_to_its_budget_or_names_the_minimum() {
    let r = lobe(&["sweep", "examples/brdfs/blinn.brdf", "--max-evals", "1"]);
    refused(&r, "--max-evals 1", "minimum of 513 evaluations (19 parameter combinations × 27 input points each)");
    assert!(r.stdout.is_empty(), "{}", String::from_utf8_lossy(&r.stdout));
    let r = lobe(&["sweep", "examples/brdfs/blinn.brdf", "--max-evals", "513", "--as-written"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(String::from_utf8_lossy(&r.stdout).contains("over 513 points"), "{}", String::from_utf8_lossy(&r.stdout));
    // On geometry (3 456 pairs per combination) the grid is subsampled to the budget, for both forms.
    let r = lobe(&["sweep", "--expr", "NL * NV * NH^n", "--max-evals", "5000", "--json"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let evaluated = v["evaluated"].as_u64().unwrap();
    assert!((1216..=5000).contains(&evaluated), "{v}");
    if let Some(c) = v["compiled"]["evaluated"].as_u64() {
        assert!(c <= 5000, "{v}");
    }
}

#[test]
fn temporaries_left_by_killed_writers_go_on_the_next_write_to_the_directory() {
    let d = scratch("stale");
    // Pids beyond any real one: their writers are gone. One for the output, one for another file; pid 1 lives.
    let stale = [".o.png.lobe-tmp-4294967295", ".other.png.lobe-tmp-4294967294"].map(|n| d.join(n));
    let live = d.join(".third.png.lobe-tmp-1");
    for p in stale.iter().chain([&live]) {
        std::fs::write(p, b"half a PNG").unwrap();
    }
    let r = lobe(&["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &s(&d.join("o.png"))]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    for p in &stale {
        assert!(!p.exists(), "{} was left", p.display());
    }
    assert!(live.exists(), "a live writer's temporary was removed");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn an_out_of_range_value_gets_its_error_alone() {
    // A --sweep-n value out of range: that error alone, named after --sweep-n.
    let r = lobe(&["compare", "examples/brdfs/blinn.brdf", "examples/brdfs/phong.brdf", "--sweep-n", "0,5", "--size", "16"]);
    refused(&r, "--sweep-n 0,5", "--sweep-n 0: material `glossy`: value 0");
    assert_eq!(r.stderr.matches("error:").count(), 1, "{}", r.stderr);
    let r = lobe(&["render", "examples/scenes/paper_sphere.toml", "--set", "n=0", "--size", "16", "-o", "/tmp/never.png"]);
    refused(&r, "render --set n=0", "outside the formula's declared range");
    assert!(!r.stderr.contains("no material's formula declares"), "{}", r.stderr);
}

#[test]
fn energy_prints_only_the_notes_of_its_mode() {
    // The lobe-variable note belongs to lobe mode.
    let r = lobe(&["energy", "--expr", "NH^n * VR", "--mode", "full"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(!r.stderr.contains("note:"), "{}", r.stderr);
    let r = lobe(&["energy", "--expr", "NH^n * VR", "--mode", "lobe"]);
    assert!(r.code == Some(0) && r.stderr.contains("note: the formula reads both NH and VR"), "{}", r.stderr);
    // Without --mode, a formula that is not one lobe cosine gets its albedo, and a note says why.
    let r = lobe(&["energy", "--expr", "NH^n * VR"]);
    assert!(r.code == Some(0) && r.stderr.contains("not one lobe cosine") && String::from_utf8_lossy(&r.stdout).contains("albedo"), "{}", r.stderr);
    let r = lobe(&["energy", "--expr", "NH^n"]);
    assert!(r.code == Some(0) && String::from_utf8_lossy(&r.stdout).contains("coef = 1/(2π·Int)"), "{}", r.stderr);
    refused(&lobe(&["energy", "--expr", "NH^n", "--mode", "full", "--lobe", "NH"]), "--lobe in full mode", "lobe mode only");
}

#[test]
fn supersampling_averages_samples_and_one_sample_is_the_plain_render() {
    let d = scratch("aa");
    // Flat white (ambient only) on black: without supersampling every pixel is 0 or 255.
    let flat = "background = [0, 0, 0]\nambient = [1, 1, 1]\n[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\n\
                position = [10, 0, 10]\n[materials.m]\nformula = \"0*NH\"\nka = 1\nkd = 0\nks = 0\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";
    std::fs::write(d.join("flat.toml"), flat).unwrap();
    std::fs::write(d.join("flat2.toml"), format!("aa = 2\n{flat}")).unwrap();
    let render = |scene: &str, extra: &[&str], out: &str| -> Vec<u8> {
        let o = d.join(out);
        let r = lobe(&[&["render", &s(&d.join(scene)), "--size", "48", "-o", &s(&o)][..], extra].concat());
        assert_eq!(r.code, Some(0), "{scene} {extra:?}: {}", r.stderr);
        std::fs::read(&o).unwrap()
    };
    let plain = render("flat.toml", &[], "plain.png");
    assert_eq!(render("flat.toml", &["--aa", "1"], "aa1.png"), plain, "--aa 1 is not the plain render");
    let aa2 = render("flat.toml", &["--aa", "2"], "aa2.png");
    assert_ne!(aa2, plain);
    let levels = |png: &[u8]| lobe::base::image::Image::decode_png(png).unwrap().rgb;
    assert!(levels(&plain).iter().all(|&v| v == 0 || v == 255));
    let smooth = levels(&aa2);
    // Edge pixels take the quarter levels of 2×2 samples; the inside stays white, the outside black.
    for q in [64u8, 128, 191] {
        assert!(smooth.contains(&q), "no edge pixel at {q}");
    }
    assert!(smooth.iter().all(|&v| [0, 64, 128, 191, 255].contains(&v)), "a level no 2×2 average gives");
    assert!(smooth.contains(&255) && smooth.contains(&0));
    // The scene's `aa` is the default; the flag wins.
    assert_eq!(render("flat2.toml", &[], "s2.png"), aa2);
    assert_eq!(render("flat2.toml", &["--aa", "1"], "s1.png"), plain);
    for bad in ["0", "9", "two"] {
        let r = lobe(&["render", &s(&d.join("flat.toml")), "--aa", bad, "-o", &s(&d.join("bad.png"))]);
        assert!(r.code == Some(2) && r.stderr.contains("--aa"), "--aa {bad}: {:?} {}", r.code, r.stderr);
    }
    std::fs::write(d.join("flat9.toml"), format!("aa = 9\n{flat}")).unwrap();
    refused(&lobe(&["render", &s(&d.join("flat9.toml")), "-o", &s(&d.join("bad.png"))]), "aa = 9", "`aa` = 9 is outside 1..=8");
    assert!(!d.join("bad.png").exists());
    let _ = std::fs::remove_dir_all(&d);
}

/// Functions that each call the previous one twice with the same argument, 40 deep: the lowering shares the calls
/// (hash-consing), and the simplifier's sum flattening used to list 2⁴⁰ terms of the resulting DAG.
#[test]
fn self_doubling_functions_stay_small() {
    let dir = scratch("fn-chain");
    for (name, body) in [("same", "f{j}(x) + f{j}(x)"), ("shifted", "f{j}(x) + f{j}(x + 1)"), ("product", "f{j}(x) * f{j}(x)")] {
        let mut src = String::from("fn f0(x) = x*NH + NV\n");
        for i in 1..=40 {
            src += &format!("fn f{i}(x) = {}\n", body.replace("{j}", &(i - 1).to_string()));
        }
        src += "f40(NH)\n";
        let path = dir.join(format!("{name}.brdf"));
        std::fs::write(&path, &src).unwrap();
        let r = lobe_bounded(&["eval", &s(&path), "--at", "NH=0.5,NV=0.25", "--no-cache"]);
        assert_eq!(r.code, Some(0), "{name}: {}", r.stderr);
        let v: f64 = String::from_utf8_lossy(&r.stdout).trim().parse().unwrap_or_else(|_| panic!("{name}: {:?}", r.stdout));
        // 0.5^(2^40) underflows to 0 for the product; the sums are large and finite.
        assert!(v.is_finite() && v >= 0.0, "{name}: {v}");
    }
}

/// "Did you mean" on a misspelt name of 500 000 characters: no suggestion, and no quadratic comparison.
#[test]
fn a_huge_misspelt_name_is_answered_at_once() {
    let dir = scratch("long-name");
    let path = dir.join("long.brdf");
    std::fs::write(&path, format!("let {} = NH\n{} * 2\n", "a".repeat(500_000), "a".repeat(499_999))).unwrap();
    let r = lobe_bounded(&["eval", &s(&path), "--at", "NH=0.5"]);
    refused(&r, "a huge misspelt name", "unknown");
}

/// A scene's shading program grew with its light count (100 lights 1 s of compilation, 250 lights 40 s, 4 000
/// lights 8.7 GB): past a budget the lights are looped over around the compiled kernel.
#[test]
fn thousands_of_lights_render_in_bounded_time_and_memory() {
    let dir = scratch("lights");
    let mut src = String::from("width = 64\nheight = 64\n[camera]\nposition = [0, 0, 6]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov = 45\n");
    for k in 0..4000 {
        let a = k as f64 * std::f64::consts::TAU / 4000.0;
        src += &format!("[[light]]\nkind = \"point\"\nposition = [{}, {}, 10]\ncolor = [0.0005, 0.0005, 0.0005]\n", 10.0 * a.cos(), 10.0 * a.sin());
    }
    let brdf = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/brdfs/modified_schlick_vr.brdf");
    src += &format!("[materials.m]\nbrdf = {:?}\nka = 0.4\nkd = 0.5\nks = 0.5\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = 1\n", s(&brdf));
    let scene = dir.join("lights.toml");
    std::fs::write(&scene, src).unwrap();
    let out = dir.join("lights.png");
    let r = lobe_bounded(&["render", &s(&scene), "-o", &s(&out), "--stats"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(out.exists());
}

/// An accuracy-cache entry replaced by a FIFO, a link to /dev/zero or a 3 GB (sparse) file is a miss: the command
/// searches again and answers, instead of blocking forever or reading the whole file.
#[cfg(unix)]
#[test]
fn a_cache_entry_that_is_not_a_small_regular_file_is_a_miss() {
    let dir = scratch("cache-entries");
    let cache = dir.join("cache");
    let cache_s = s(&cache);
    let env = [("LOBE_CACHE_DIR", cache_s.as_str())];
    let args = ["eval", "examples/brdfs/beckmann.brdf", "--at", "NH=0.7"];
    let first = lobe_within_env(Duration::from_secs(60), &args, &env);
    assert_eq!(first.code, Some(0), "{}", first.stderr);
    let entries: Vec<PathBuf> = std::fs::read_dir(&cache).unwrap().flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "pass")).collect();
    assert!(!entries.is_empty(), "the first run stored no decision");
    type Make<'a> = &'a dyn Fn(&Path) -> bool;
    let replace: [(&str, Make); 3] = [
        ("FIFO", &|p| mkfifo(p)),
        ("link to /dev/zero", &|p| std::os::unix::fs::symlink("/dev/zero", p).is_ok()),
        ("3 GB file", &|p| std::fs::File::create(p).and_then(|f| f.set_len(3 << 30)).is_ok()),
    ];
    for (what, make) in replace {
        for e in &entries {
            let _ = std::fs::remove_file(e);
            assert!(make(e), "{what}: could not create it");
        }
        let t = Instant::now();
        let r = lobe_within_env(Duration::from_secs(10), &args, &env);
        assert_eq!((r.code, r.stdout.clone()), (Some(0), first.stdout.clone()), "{what}: {} after {:?}", r.stderr, t.elapsed());
        assert!(r.peak_kib < 1 << 20, "{what}: {} MiB", r.peak_kib >> 10);
    }
}

/// Output to a full device (Linux's /dev/full) is an error line and exit code 1, not a panic (exit 101).
#[cfg(target_os = "linux")]
#[test]
fn output_to_a_full_device_is_an_error() {
    let cases: [&[&str]; 3] = [
        &["eval", "examples/brdfs/phong.brdf", "--at", "VR=0.9"],
        &["export", "examples/brdfs/phong.brdf", "--glsl"],
        &["check", "examples/brdfs/phong.brdf", "--json"],
    ];
    for args in cases {
        let out = Command::new(env!("CARGO_BIN_EXE_lobe"))
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .env("NO_COLOR", "1")
            .stdout(std::fs::File::create("/dev/full").unwrap())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        refused(&Run { code: out.status.code(), stdout: vec![], stderr: err.into_owned(), peak_kib: 0 }, args[0], "No space left on device");
    }
}

/// A negative number where a positive one belongs is refused for its value, not met with clap's tip to write
/// `-- -2` (which would not help).
#[test]
fn negative_values_are_refused_for_their_value() {
    let dir = scratch("negative-values");
    let out = dir.join("x.png");
    let table = dir.join("x.binary");
    let cases: [(&[&str], &str); 3] = [
        (&["render", "examples/scenes/paper_sphere.toml", "--aa", "-2", "-o", &s(&out)], "-2 is not in 1..=8"),
        (&["tabulate", "examples/brdfs/phong.brdf", "--color", "-1,1,1", "-o", &s(&table)], "--color takes three finite factors"),
        (&["render", "examples/scenes/paper_sphere.toml", "--tile", "-64", "-o", &s(&out)], "-64 is not in"),
    ];
    for (args, needle) in cases {
        let r = lobe(args);
        assert!(r.code.is_some_and(|c| c != 0) && r.stderr.contains(needle) && !r.stderr.contains("tip:"), "{args:?}: {}", r.stderr);
        assert!(!out.exists() && !table.exists());
    }
}
