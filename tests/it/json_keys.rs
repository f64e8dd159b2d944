//! The `--json` keys are a stable interface (README, "JSON keys (stable)"): every command that prints JSON runs
//! on a small input and the set of key paths of its output — nested objects joined with `.`, array elements
//! collapsed into `[]` — must equal `tests/snapshots/json_keys/CASE.keys`. Values are not compared (they are
//! timings and measurements); a key that appears, disappears or changes from `null` to an object does show.
//! `LOBE_BLESS=1` rewrites the snapshots from the current outputs.

use super::cli::lobe;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The key paths of `v` under `prefix`, into `out`.
fn key_paths(v: &serde_json::Value, prefix: &str, out: &mut BTreeSet<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                let p = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                out.insert(p.clone());
                key_paths(x, &p, out);
            }
        }
        serde_json::Value::Array(a) => {
            let p = format!("{prefix}[]");
            for x in a {
                key_paths(x, &p, out);
            }
        }
        _ => {}
    }
}

fn snapshot_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots/json_keys")
}

/// A formula with a parameter other than `n`, which `fit` can search (the metric sweeps `n` itself).
const FIT_FORMULA: &str = "param a = 2 in 1..100\nNH^(a*n) / a";
/// A small colour formula (three channels, each cheap to check).
const COLOUR: &str = "vec3(NH, NH^2, 1 - NH)";

#[test]
fn every_json_output_keeps_its_keys() {
    let dir = crate::scratch_dir("json-keys", "run");
    let points = dir.join("points.csv");
    std::fs::write(&points, "NH,NL\n0.5,0.7\n0.9,0.1\n").unwrap();
    let png = dir.join("out.png");
    let cut_scene = dir.join("cutoff.toml");
    let phong = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/brdfs/phong.brdf");
    let scene = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/paper_sphere.toml"))
        .unwrap()
        .replace("../brdfs/modified_schlick_vr.brdf", &phong.display().to_string())
        .replace("\nks = 0.5\n", "\nks = 0.5\ncutoff = 8\n");
    std::fs::write(&cut_scene, scene).unwrap();
    let (points, png, cut_scene) = (points.display().to_string(), png.display().to_string(), cut_scene.display().to_string());
    let bad = dir.join("bad.brdf");
    std::fs::write(&bad, "param k = 2 in 1..5\nNH^k +\n").unwrap();
    let (bad, table2, plot, watched) = (
        bad.display().to_string(),
        dir.join("tabulated.binary").display().to_string(),
        dir.join("plot.png").display().to_string(),
        dir.join("watched.png").display().to_string(),
    );
    let blinn = "examples/brdfs/blinn.brdf";
    // A measured table (MERL .binary) of Blinn, for the commands that read one.
    let table = dir.join("blinn20.binary").display().to_string();
    let o = lobe(&["tabulate", blinn, "--set", "n=20", "-o", &table], None);
    assert!(o.status.success(), "tabulate: {}", String::from_utf8_lossy(&o.stderr));
    let fit_measured = |more: &[&'static str]| {
        let mut v = vec!["fit", blinn];
        v.extend_from_slice(more);
        v.extend(["--measured", table.as_str(), "--param", "n=1..100", "--stride", "9", "--grid-stride", "9", "--json"]);
        v
    };
    #[allow(unused_mut)]
    let mut cases: Vec<(&str, Vec<&str>)> = vec![
        ("eval", vec!["eval", blinn, "--set", "n=2", "--at", "NH=0.5", "--json"]),
        ("eval_note", vec!["eval", "--expr", "dot(N, L)", "--at", "L=0,0,2,V=0,0,1", "--json"]),
        ("eval_points", vec!["eval", blinn, "--points", &points, "--json"]),
        ("eval_points_truth", vec!["eval", blinn, "--points", &points, "--truth", "--json"]),
        ("eval_grad", vec!["eval", blinn, "--set", "n=2", "--at", "NH=0.5", "--grad", "--json"]),
        ("eval_grad_points", vec!["eval", blinn, "--points", &points, "--grad", "--json"]),
        ("eval_colour", vec!["eval", "--expr", COLOUR, "--at", "NH=0.5", "--json"]),
        ("eval_colour_points", vec!["eval", "--expr", COLOUR, "--points", &points, "--json"]),
        ("check", vec!["check", "examples/brdfs/beckmann.brdf", "--points", "200", "--json"]),
        ("check_colour", vec!["check", "--expr", COLOUR, "--points", "200", "--json"]),
        ("sweep", vec!["sweep", "examples/brdfs/beckmann.brdf", "--max-evals", "5000", "--json"]),
        ("sweep_as_written", vec!["sweep", blinn, "--max-evals", "2000", "--as-written", "--json"]),
        ("sweep_colour", vec!["sweep", "--expr", COLOUR, "--max-evals", "2000", "--json"]),
        ("energy_lobe", vec!["energy", blinn, "--set", "n=10", "--json"]),
        ("energy_full", vec!["energy", blinn, "--set", "n=10", "--mode", "full", "--json"]),
        ("energy_full_directions", vec!["energy", "--expr", "max(dot(X, L), 0) / pi", "--mode", "full", "--json"]),
        ("energy_range", vec!["energy", blinn, "--range", "1..5", "--json"]),
        ("energy_range_against", vec!["energy", blinn, "--range", "1..5", "--against-expr", "(n+2)/(2*pi)", "--json"]),
        ("energy_colour", vec!["energy", "--expr", COLOUR, "--json"]),
        ("sample", vec!["sample", blinn, "--set", "n=10", "--incidence", "30", "--count", "2000", "--json"]),
        ("accuracy", vec!["accuracy", "examples/brdfs/phong.brdf", "--reference", blinn, "--n-max", "20", "--json"]),
        ("accuracy_colour", vec!["accuracy", "examples/vector/gold_blinn.brdf", "--reference", blinn, "--n-max", "20", "--json"]),
        ("fit", vec!["fit", "--expr", FIT_FORMULA, "--reference", blinn, "--param", "a=1..4", "--n-max", "20", "--quiet", "--json"]),
        ("compare", vec!["compare", blinn, "examples/brdfs/phong.brdf", "--size", "16", "--json"]),
        ("compare_sweep", vec!["compare", blinn, "examples/brdfs/phong.brdf", "--size", "16", "--sweep-n", "5,10", "--json"]),
        // `--tier cranelift`: the same keys whether or not the build has the LLVM tier (`bench_tiers` below).
        ("bench", vec!["bench", "examples/brdfs/gaussian.brdf", "--samples", "3", "--no-albedo", "--tier", "cranelift", "--json"]),
        ("render_stats", vec!["render", "examples/scenes/paper_sphere.toml", "--size", "16", "-q", "-o", &png, "--stats", "--json"]),
        ("render_stats_cutoff", vec!["render", &cut_scene, "--size", "16", "-q", "-o", &png, "--force", "--stats", "--json"]),
        // Measured tables: one fit, the batch (formulas × tables), the albedo, a comparison and the accuracy.
        ("fit_measured", fit_measured(&[])),
        ("fit_measured_batch", fit_measured(&["examples/brdfs/phong.brdf"])),
        ("energy_measured", vec!["energy", &table, "--mode", "full", "--json"]),
        ("compare_measured", vec!["compare", blinn, &table, "--set", "n=20", "--size", "16", "--json"]),
        ("accuracy_measured", vec!["accuracy", blinn, "--reference", &table, "--set", "n=20", "--json"]),
        ("tabulate", vec!["tabulate", blinn, "--set", "n=20", "-o", &table2, "--json"]),
        ("export", vec!["export", blinn, "--set", "n=20", "--json"]),
        ("export_mitsuba", vec!["export", "--mitsuba", blinn, "--set", "n=20", "--json"]),
        ("import", vec!["import", "examples/explorer/ggx.brdf", "--json"]),
        ("plot", vec!["plot", blinn, "examples/brdfs/phong.brdf", "--set", "n=20", "-o", &plot, "--json"]),
        ("watch", vec!["watch", blinn, "--scene", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &watched, "--count", "1", "--json"]),
        // A traced scene's line also says its level (`--spp 1`: one level, one line).
        ("watch_traced", vec!["watch", "examples/explorer/ggx.brdf", "--scene", "examples/scenes/environment.toml", "--size", "16", "--spp", "1", "-o", &watched, "--count", "1", "--json"]),
    ];
    // Errors under --json: the error object on standard output (a usage error, a message, a located diagnostic),
    // and a watch whose reload failed (its line carries the same object).
    let errors: Vec<(&str, Vec<&str>)> = vec![
        ("error_usage", vec!["eval", blinn, "--at", "NH=0.5", "--no-such-flag", "--json"]),
        ("error_message", vec!["eval", blinn, "--json"]),
        ("error_located", vec!["check", &bad, "--json"]),
        ("watch_error", vec!["watch", &bad, "--scene", "examples/scenes/paper_sphere.toml", "--size", "16", "-o", &watched, "--count", "1", "--json"]),
    ];
    // The LLVM tier's keys: bench's side-by-side columns, eval's lanes.
    #[cfg(feature = "llvm")]
    cases.extend([
        ("bench_tiers", vec!["bench", "examples/brdfs/gaussian.brdf", "--samples", "3", "--no-albedo", "--tier", "llvm", "--json"]),
        ("eval_points_llvm", vec!["eval", blinn, "--points", &points, "--tier", "llvm", "--json"]),
    ]);
    let bless = std::env::var("LOBE_BLESS").is_ok_and(|v| v == "1");
    let mut failures = vec![];
    for ((name, args), ok) in cases.iter().map(|c| (c, true)).chain(errors.iter().map(|c| (c, false))) {
        let o = lobe(args, None);
        assert_eq!(o.status.success(), ok, "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout)
            .unwrap_or_else(|e| panic!("{name}: not JSON ({e}):\n{}", String::from_utf8_lossy(&o.stdout)));
        let mut keys = BTreeSet::new();
        key_paths(&v, "", &mut keys);
        let text: String = keys.iter().map(|k| format!("{k}\n")).collect();
        let path = snapshot_dir().join(format!("{name}.keys"));
        if bless {
            std::fs::create_dir_all(snapshot_dir()).unwrap();
            std::fs::write(&path, &text).unwrap();
            continue;
        }
        let want = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e} (LOBE_BLESS=1 writes it)", path.display()));
        if want != text {
            let want: BTreeSet<&str> = want.lines().collect();
            let got: BTreeSet<&str> = text.lines().collect();
            failures.push(format!(
                "{name}: missing {:?}, new {:?}",
                want.difference(&got).collect::<Vec<_>>(),
                got.difference(&want).collect::<Vec<_>>()
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(failures.is_empty(), "--json keys changed:\n{}", failures.join("\n"));
}

/// The page's API replies keep their keys too (`lobe serve`: the page and any script that drives it read them).
#[test]
fn the_page_api_keeps_its_keys() {
    let dir = crate::scratch_dir("json-keys", "api");
    let f = dir.join("model.brdf");
    std::fs::write(&f, "NH^n\n").unwrap();
    let s = super::serve::Served::start(&[f.to_str().unwrap()]);
    let file = s.get(&format!("/api/file?path={}", f.display())).json();
    let save = serde_json::json!({"path": f, "text": "VR^n\n", "hash": file["hash"]});
    let lobe = serde_json::json!({"text": "NH^n", "params": {"n": 5}, "theta_i": 30, "n_theta": 5, "n_phi": 8});
    let cases = [
        ("api_session", s.get("/api/session")),
        ("api_file", s.get(&format!("/api/file?path={}", f.display()))),
        ("api_save", s.post("/api/save", &save)),
        ("api_lobe", s.post("/api/lobe", &lobe)),
        ("api_slice", s.post("/api/slice", &serde_json::json!({"text": "NH^n", "res": 8}))),
    ];
    let bless = std::env::var("LOBE_BLESS").is_ok_and(|v| v == "1");
    let mut failures = vec![];
    for (name, r) in cases {
        assert_eq!(r.status, 200, "{name}: {}", String::from_utf8_lossy(&r.body));
        let mut keys = BTreeSet::new();
        key_paths(&r.json(), "", &mut keys);
        let text: String = keys.iter().map(|k| format!("{k}\n")).collect();
        let path = snapshot_dir().join(format!("{name}.keys"));
        if bless {
            std::fs::write(&path, &text).unwrap();
        } else if std::fs::read_to_string(&path).ok().as_deref() != Some(text.as_str()) {
            failures.push(format!("{name}: now\n{text}"));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(failures.is_empty(), "API keys changed (LOBE_BLESS=1 rewrites the snapshots):\n{}", failures.join("\n"));
}

/// `lobe serve --json`: its first line is one JSON object with the address (scripts start it on port 0).
#[test]
fn serve_prints_its_address_as_json() {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_lobe"))
        .args(["serve", "examples/brdfs", "--port", "0", "--json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::inherit())
        .spawn()
        .expect("start lobe serve");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let _ = child.kill();
    let _ = child.wait();
    let v: serde_json::Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("not JSON ({e}): {line:?}"));
    let port = v["port"].as_u64().unwrap();
    assert!(port > 0 && v["loopback"] == true, "{v}");
    assert_eq!(v["url"].as_str().unwrap(), format!("http://{}:{port}/", v["address"].as_str().unwrap()));
}
