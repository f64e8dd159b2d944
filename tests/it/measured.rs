//! Measured materials end to end: synthetic MERL tables written by `lobe tabulate` into a scratch folder at run
//! time (never checked in: 33 MB each), then fitted (Blinn's n and Beckmann's m recovered within 1 %), rendered
//! and compared (golden images), integrated (`energy --mode full`), and hostile files refused with the file
//! named, exit 1 and nothing written.

use crate::cli::lobe;
use lobe::base::image::Image;
use lobe::measured::{Measured, ENTRIES, FILE_BYTES};
use std::path::{Path, PathBuf};
use std::process::Output;

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A table of `formula` with `set`, written by `lobe tabulate` into `dir`.
fn tabulate(dir: &Path, name: &str, formula: &str, set: &str, color: &str) -> String {
    let out = dir.join(name).display().to_string();
    let o = lobe(&["tabulate", formula, "--set", set, "--color", color, "-o", &out], None);
    assert!(o.status.success(), "tabulate {formula}: {}", stderr(&o));
    assert_eq!(std::fs::metadata(&out).unwrap().len(), FILE_BYTES as u64);
    out
}

/// `lobe fit … --json` on a measured table, at strides that keep the test fast (1/27 of the entries for the
/// refinement, 1/216 for the grid); the fitted value of `param`.
fn fitted(formula: &str, table: &str, param: &str, range: &str) -> (f64, serde_json::Value) {
    let p = format!("{param}={range}");
    let o = lobe(&["fit", formula, "--measured", table, "--param", &p, "--stride", "3", "--grid-stride", "6", "--json"], None);
    assert!(o.status.success(), "fit {formula}: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    (v["params"][param].as_f64().unwrap(), v)
}

/// `0..1` is the interval [0, 1]: a two-parameter fit of GGX to its own table recovers alpha and f0 (the
/// issue's values and two pairs drawn at random), with both ranges written as integers.
#[test]
fn integer_looking_ranges_are_intervals_and_a_two_parameter_fit_recovers_ggx() {
    let dir = crate::scratch_dir("measured", "ggx");
    let mut rng = lobe::base::rng::Rng(0x2545_f491_4f6c_dd1d);
    let mut draw = |lo: f64, hi: f64| lo + (hi - lo) * rng.unit();
    let mut truths = vec![(0.35, 0.6)];
    truths.extend((0..2).map(|_| (draw(0.15, 0.8), draw(0.1, 0.9))));
    for (k, (alpha, f0)) in truths.into_iter().enumerate() {
        let table = tabulate(&dir, &format!("ggx{k}.binary"), "examples/explorer/ggx.brdf", &format!("alpha={alpha},f0={f0}"), "1,1,1");
        let args = ["fit", "examples/explorer/ggx.brdf", "--measured", &table, "--param", "alpha=0.01..1", "--param", "f0=0..1", "--stride", "3", "--grid-stride", "6", "--json"];
        let o = lobe(&args, None);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        let (a, f) = (v["params"]["alpha"].as_f64().unwrap(), v["params"]["f0"].as_f64().unwrap());
        assert!((a - alpha).abs() < 0.01 * alpha && (f - f0).abs() < 0.01, "alpha {alpha} f0 {f0}: {v}");
    }
}

/// A formula against another over the whole hemisphere (`--measured REF.brdf`, no table written): GGX fitted to
/// itself at random values (a name searched in the fitted formula is set in the reference) and the anisotropic
/// Ward to itself at random alphas (compared at every azimuth), under each metric, with no colour scale unless
/// `--fit-scale`. Where a formula reads no n, `fit --reference` and `accuracy` compare over the hemisphere
/// instead of sweeping the papers' n at NL = 1 (they swept a fixed GGX against a thousand Blinn lobes), and
/// `bench` leaves the sweep's columns empty.
#[test]
fn formulas_are_compared_over_the_whole_hemisphere() {
    let mut rng = lobe::base::rng::Rng(0x4e6a_0b1d);
    let mut draw = |lo: f64, hi: f64| lo + (hi - lo) * rng.unit();
    let fit = |args: &[&str]| -> serde_json::Value {
        let mut all = vec!["fit"];
        all.extend_from_slice(args);
        all.extend_from_slice(&["--stride", "3", "--grid-stride", "6", "--json"]);
        let o = lobe(&all, None);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        serde_json::from_str(&stdout(&o)).unwrap()
    };
    for metric in ["log", "rmse", "cosine"] {
        let (alpha, f0) = (draw(0.1, 0.8), draw(0.05, 0.9));
        let (sa, sf) = (format!("alpha={alpha}"), format!("f0={f0}"));
        let v = fit(&["examples/explorer/ggx.brdf", "--measured", "examples/explorer/ggx.brdf", "--param", "alpha=0.01..1", "--param", "f0=0..1", "--set", &sa, "--set", &sf, "--metric", metric]);
        let (a, f) = (v["params"]["alpha"].as_f64().unwrap(), v["params"]["f0"].as_f64().unwrap());
        assert!((a - alpha).abs() < 1e-3 * alpha && (f - f0).abs() < 1e-3, "{metric}: alpha {alpha} f0 {f0}: {v}");
        assert_eq!(v["scale"], serde_json::json!([1.0, 1.0, 1.0]), "{v}");
        let (ax, ay) = (draw(0.05, 0.5), draw(0.05, 0.5));
        let (sx, sy) = (format!("alpha_x={ax}"), format!("alpha_y={ay}"));
        let w = "examples/explorer/ward_anisotropic.brdf";
        let v = fit(&[w, "--measured", w, "--param", "alpha_x=0.01..1", "--param", "alpha_y=0.01..1", "--set", &sx, "--set", &sy, "--metric", metric]);
        let (x, y) = (v["params"]["alpha_x"].as_f64().unwrap(), v["params"]["alpha_y"].as_f64().unwrap());
        assert!((x - ax).abs() < 1e-3 * ax && (y - ay).abs() < 1e-3 * ay, "{metric}: {ax} {ay}: {v}");
    }
    // With --fit-scale a reference at twice the value is matched by a scale of 2 (Blinn's own n recovered).
    let v = fit(&["examples/brdfs/blinn.brdf", "--measured", "examples/brdfs/blinn.brdf", "--param", "n=1..1000", "--set", "n=64", "--fit-scale"]);
    assert!((v["params"]["n"].as_f64().unwrap() - 64.0).abs() < 0.1 && v["error"].as_f64().unwrap() < 1e-9, "{v}");
    // GGX reads no n: against Blinn, over the hemisphere (Blinn at the --set n), not the papers' sweep.
    let o = lobe(&["fit", "examples/explorer/ggx.brdf", "--reference", "examples/brdfs/blinn.brdf", "--param", "alpha=0.01..1", "--set", "n=200", "--stride", "6", "--grid-stride", "9"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("ggx reads no n") && stdout(&o).contains("log error over"), "{}{}", stderr(&o), stdout(&o));
    let o = lobe(&["fit", "examples/explorer/ggx.brdf", "--reference", "examples/brdfs/blinn.brdf", "--param", "alpha=0.01..1", "--metric", "mean-abs"], None);
    assert!(!o.status.success() && stderr(&o).contains("reads no n") && stderr(&o).contains("--metric log"), "{}", stderr(&o));
    let o = lobe(&["accuracy", "examples/explorer/ggx.brdf", "--reference", "examples/brdfs/blinn.brdf", "--set", "n=200", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert!(v["cosine"].as_f64().unwrap() > 0.0 && v["log"].as_f64().unwrap() > 0.0 && v["entries"].as_u64().unwrap() > 1_000_000, "{v}");
    assert!(v.get("mean_abs_grid").is_none(), "{v}");
    let o = lobe(&["bench", "examples/explorer/ggx.brdf", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let row = &v[0];
    assert!(!row["mean_abs_grid"].is_number() && !row["coef_n50"].is_number(), "{row}");
}

#[test]
fn fits_recover_blinns_n_and_beckmanns_m() {
    let dir = crate::scratch_dir("measured", "fit");
    let blinn = tabulate(&dir, "blinn120.binary", "examples/brdfs/blinn.brdf", "n=120", "1,1,1");
    let (n, v) = fitted("examples/brdfs/blinn.brdf", &blinn, "n", "1..1000");
    assert!((n - 120.0).abs() < 1.2, "n = {n}: {v}");
    assert!(v["error"].as_f64().unwrap() < 1e-6 && v["metric"] == "log", "{v}");
    let beckmann = tabulate(&dir, "beckmann.binary", "examples/brdfs/beckmann.brdf", "m=0.23", "0.9,0.6,0.3");
    for metric in ["log", "rmse"] {
        let o = lobe(&["fit", "examples/brdfs/beckmann.brdf", "--measured", &beckmann, "--param", "m=0.01..1", "--metric", metric, "--stride", "3", "--grid-stride", "6", "--json"], None);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        let m = v["params"]["m"].as_f64().unwrap();
        assert!((m - 0.23).abs() < 0.0023, "{metric}: m = {m}: {v}");
        let scale: Vec<f64> = v["scale"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        for (s, want) in scale.iter().zip([0.9, 0.6, 0.3]) {
            assert!((s - want).abs() < 0.01 * want, "{metric}: {v}");
        }
    }
    // The batch: two formulas × both tables into a CSV table in one command.
    let csv = dir.join("fits.csv");
    let o = lobe(
        &["fit", "examples/brdfs/blinn.brdf", "examples/brdfs/phong.brdf", "--measured", &dir.display().to_string(), "--param", "n=1..1000", "--stride", "6", "--grid-stride", "9", "--table", &csv.display().to_string()],
        None,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows.len(), 5, "{text}");
    assert!(rows[0].starts_with("formula,file,measured,params,error"), "{text}");
    let blinn_row = rows.iter().find(|r| r.starts_with("Blinn,") && r.contains("blinn120")).unwrap();
    // n = 120 up to rounding (Levenberg–Marquardt lands within an ulp of it, not on the grid point).
    let n: f64 = blinn_row.split(",n=").nth(1).and_then(|r| r.split(',').next()).and_then(|v| v.parse().ok()).unwrap();
    assert!((n - 120.0).abs() < 1e-9, "{blinn_row}");
    assert!(stdout(&o).contains("Phong"), "{}", stdout(&o));
    // A second run replaces the table lobe wrote.
    let o = lobe(&["fit", "examples/brdfs/blinn.brdf", "--measured", &blinn, "--param", "n=1..1000", "--stride", "9", "--grid-stride", "9", "--table", &csv.display().to_string()], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

fn golden(name: &str, im: &Image) {
    crate::render::golden(name, im)
}

#[test]
fn renders_compares_and_integrates_a_measured_material() {
    let dir = crate::scratch_dir("measured", "render");
    let table = tabulate(&dir, "gold.binary", "examples/brdfs/blinn.brdf", "n=60", "1,0.8,0.4");
    let scene = dir.join("gold.toml");
    let scene_src = std::fs::read_to_string("examples/scenes/paper_sphere.toml")
        .unwrap()
        .replace("brdf = \"../brdfs/modified_schlick_vr.brdf\"\nparams = { n = 50 }", "brdf = \"gold.binary\"");
    assert!(scene_src.contains("gold.binary"));
    std::fs::write(&scene, &scene_src).unwrap();
    // Through the library, for the golden image.
    let opts = lobe::render::scene::LoadOptions { size: Some((96, 96)), ..Default::default() };
    let compiler = lobe::render::scene::LobeCompiler::plain(lobe::Backend::Jit, lobe::Mode::Precise);
    let s = lobe::render::scene::load_scene(&scene, &opts, &compiler).unwrap_or_else(|d| panic!("{}", d.render(false)));
    let (frame, stats) = lobe::render::render(&s, &lobe::render::RenderOptions { threads: 2, tile: 32, ..Default::default() }).unwrap();
    assert!(stats.evals > 0 && stats.nan == 0);
    golden("measured_gold.png", &frame.image);
    // One thread gives the same bytes.
    let (one, _) = lobe::render::render(&s, &lobe::render::RenderOptions { threads: 1, tile: 32, ..Default::default() }).unwrap();
    assert_eq!(one.image.rgb, frame.image.rgb);
    // `lookup = "nearest"` reads the table MERL's way: the highlight moves a little; a bad value, or the key
    // on a formula material, is an error at its place.
    let with = |extra: &str, brdf: &str| {
        let p = dir.join("lookup.toml");
        std::fs::write(&p, scene_src.replace("brdf = \"gold.binary\"", &format!("brdf = \"{brdf}\"\n{extra}"))).unwrap();
        lobe::render::scene::load_scene(&p, &opts, &compiler)
    };
    let near = with("lookup = \"nearest\"", "gold.binary").unwrap_or_else(|d| panic!("{}", d.render(false)));
    let (near, _) = lobe::render::render(&near, &lobe::render::RenderOptions { threads: 2, tile: 32, ..Default::default() }).unwrap();
    assert_ne!(near.image.rgb, frame.image.rgb);
    let bad = with("lookup = \"cubic\"", "gold.binary").unwrap_err().render(false);
    assert!(bad.contains("materials.") && bad.contains("lookup: unknown lookup `cubic`") && bad.contains("lookup.toml:"), "{bad}");
    let formula = dir.join("blinn.brdf");
    std::fs::copy("examples/brdfs/blinn.brdf", &formula).unwrap();
    let bad = with("lookup = \"nearest\"", "blinn.brdf").unwrap_err().render(false);
    assert!(bad.contains("this material is a formula; `lookup` reads measured tables"), "{bad}");
    // The command line.
    let png = dir.join("gold.png");
    let o = lobe(&["render", &scene.display().to_string(), "--size", "96", "-o", &png.display().to_string()], None);
    assert!(o.status.success() && png.exists(), "{}", stderr(&o));
    // The formula against its own table: the measured render is the formula's up to the table's bins.
    let cmp = dir.join("cmp.png");
    let o = lobe(&["compare", "examples/brdfs/blinn.brdf", &table, "--set", "n=60", "--size", "96", "-o", &cmp.display().to_string(), "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let covered = v["manhattan_covered"].as_f64().unwrap();
    assert!(covered > 0.0 && covered < 3.0, "{v}");
    golden("measured_compare_blinn.png", &Image::decode_png(&std::fs::read(&cmp).unwrap()).unwrap());
    // The albedo of the table is the formula's within 1 % under the default (linear) lookup; the nearest
    // entry is the one below the angle, so `--lookup nearest` reads high (+5.8 % here, measured).
    let o = lobe(&["energy", &table, "--mode", "full", "--json"], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let red = v["albedo_max"].as_f64().unwrap();
    let o = lobe(&["energy", "examples/brdfs/blinn.brdf", "--set", "n=60", "--mode", "full", "--json"], None);
    let f: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let want = f["albedo_max"].as_f64().unwrap();
    assert!((red - want).abs() < 0.01 * want, "table {red} vs formula {want}");
    let o = lobe(&["energy", &table, "--mode", "full", "--lookup", "nearest", "--json"], None);
    let near: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let near = near["albedo_max"].as_f64().unwrap();
    assert!(near > 1.03 * want, "nearest {near} vs formula {want}");
    let o = lobe(&["energy", "examples/brdfs/blinn.brdf", "--mode", "full", "--lookup", "nearest"], None);
    assert!(!o.status.success() && stderr(&o).contains("--lookup nearest reads measured tables"), "{}", stderr(&o));
    let blue = v["channels"][2]["albedo_max"].as_f64().unwrap();
    assert!((blue - 0.4 * red).abs() < 1e-9 * red, "{blue} vs {red}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Random directions, parameters and tables: a lookup never panics, is finite and never negative.
#[test]
fn random_lookups_never_panic() {
    let mut rng = lobe::base::rng::Rng(0x5eed);
    let n = 1.0 + rng.unit() * 500.0;
    let t = Measured::tabulate("random", &|l, v| {
        let x = lobe::frame::inputs_from_dirs(l, v);
        [x[2].powf(n), if rng_like(l[0]) { f64::NAN } else { 1.0 }, -1.0]
    });
    let mut r = lobe::base::rng::Rng(9);
    for _ in 0..50_000 {
        let mut d = || {
            let (z, phi) = (r.unit() * 2.2 - 1.1, r.unit() * 7.0 - 0.3);
            let s = (1.0 - z * z).max(0.0).sqrt();
            [s * phi.cos(), s * phi.sin(), z]
        };
        let (l, v) = (d(), d());
        for c in 0..3 {
            let y = t.lookup(c, l, v);
            assert!(y.is_finite() && y >= 0.0, "{l:?} {v:?}: {y}");
        }
    }
    assert!(t.measured_entries() == 0 && ENTRIES > 0);
}

/// Part of the table not finite: a stand-in for a noisy formula.
fn rng_like(x: f64) -> bool {
    (x * 1e6).fract().abs() < 0.01
}

#[test]
fn hostile_tables_are_clear_errors_and_write_nothing() {
    let dir = crate::scratch_dir("measured", "hostile");
    let good = Measured::tabulate("one", &|_, _| [1.0; 3]).to_bytes();
    let mut cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty.binary", vec![], "shorter than the 12-byte header"),
        ("short.binary", good[..1000].to_vec(), "truncated: 1000 bytes"),
        ("cut.binary", good[..good.len() - 8].to_vec(), "1 values missing"),
    ];
    let mut dims = good.clone();
    dims[..12].copy_from_slice(&[90i32, 180, 90].iter().flat_map(|d| d.to_le_bytes()).collect::<Vec<u8>>());
    cases.push(("dims.binary", dims, "dimensions 90 × 180 × 90"));
    let mut huge = good[..12].to_vec();
    huge[..12].copy_from_slice(&[i32::MAX, i32::MAX, i32::MAX].iter().flat_map(|d| d.to_le_bytes()).collect::<Vec<u8>>());
    cases.push(("huge.binary", huge, "dimensions 2147483647"));
    let mut nan = good.clone();
    let at = nan.len() - 8;
    nan[at..].copy_from_slice(&f64::NAN.to_le_bytes());
    cases.push(("nan.binary", nan, "the blue block holds 1 non-finite"));
    for (name, bytes, needle) in &cases {
        let p = dir.join(name).display().to_string();
        std::fs::write(&p, bytes).unwrap();
        let out = dir.join("out.png").display().to_string();
        let runs: Vec<Vec<&str>> = vec![
            vec!["fit", "examples/brdfs/blinn.brdf", "--measured", &p, "--param", "n=1..10", "-o", &out],
            vec!["compare", "examples/brdfs/blinn.brdf", &p, "-o", &out],
            vec!["energy", &p, "--mode", "full"],
        ];
        for args in runs {
            let o = lobe(&args, None);
            crate::cli::assert_clean_exit(o.status.code(), &stderr(&o), &format!("{args:?}"), needle);
            assert!(stderr(&o).contains(name), "{args:?}: the file is not named:\n{}", stderr(&o));
            assert!(!Path::new(&out).exists(), "{args:?} wrote {out}");
        }
    }
    // A folder where a table should be, and a scene whose material is a broken table.
    let o = lobe(&["energy", &dir.display().to_string(), "--mode", "full"], None);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let scene = dir.join("s.toml");
    let src = std::fs::read_to_string("examples/scenes/paper_sphere.toml").unwrap().replace("../brdfs/modified_schlick_vr.brdf", "cut.binary").replace("[materials.glossy]", "[materials.m]").replace("material = \"glossy\"", "material = \"m\"").replace("params = { n = 50 }\n", "");
    std::fs::write(&scene, src).unwrap();
    let out: PathBuf = dir.join("s.png");
    let o = lobe(&["render", &scene.display().to_string(), "-o", &out.display().to_string()], None);
    crate::cli::assert_clean_exit(o.status.code(), &stderr(&o), "render", "cut.binary");
    assert!(stderr(&o).contains("materials.m.brdf") && !out.exists(), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Tables of catalogue formulas at named and random parameters: the table's albedo (default, linear lookup)
/// is the formula's own within 1 % at every θᵢ ≤ 80°, and so is its maximum where that lies there. (Past
/// θᵢ = 89° the specular directions have θ_d past the last entry, 89°, where a table holds nothing: Cook–
/// Torrance's grazing maximum at 89.9°, its Fresnel term rising to 1, is 5 % off, and not asserted.) The
/// nearest lookup, MERL's reference, misses by more than 2 % somewhere on every table (its entry is its
/// bin's lower edge: a falling lobe reads high).
#[test]
fn table_albedo_is_the_formulas() {
    use lobe::measured::Lookup;
    use lobe::numerics::energy::{full_energy_for, full_energy_tabulated};
    let mut rng = lobe::base::rng::Rng(0xa1bed0);
    let mut r = |lo: f64, hi: f64| lo + (hi - lo) * rng.unit();
    let cases = [
        ("blinn", "n", 10.0),
        ("blinn", "n", 120.0),
        ("blinn", "n", r(2.0, 800.0)),
        ("phong", "n", r(2.0, 300.0)),
        ("gaussian", "n", r(5.0, 500.0)),
        ("beckmann", "m", 0.2),
        ("ward", "m", r(0.08, 0.5)),
        ("cook_torrance", "m", 0.3),
        ("cook_torrance", "m", r(0.1, 0.6)),
    ];
    let mut failed = vec![];
    for (stem, name, value) in cases {
        let path = format!("{}/examples/brdfs/{stem}.brdf", env!("CARGO_MANIFEST_DIR"));
        let src = std::fs::read_to_string(&path).unwrap();
        let k = lobe::compile_source(&path, &src, &lobe::Options { backend: lobe::Backend::Jit, ..Default::default() }).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let mut params = k.default_params();
        let at = k.formula.params.iter().position(|p| p.name == name).unwrap();
        params[at] = value;
        let want = full_energy_for(&k, k.used_inputs(), &params).unwrap();
        let table = std::sync::Arc::new(Measured::tabulate(stem, &|l, v| [lobe::Evaluator::eval(&k, &lobe::frame::inputs_from_dirs(l, v), &params); 3]));
        let off = |how: Lookup| {
            let got = full_energy_tabulated(table.channels_with(how)[0].as_ref(), &[]).unwrap();
            let worst = got.albedo.iter().zip(&want.albedo).filter(|(_, w)| w.0 <= 80.0).map(|(g, w)| (g.1 / w.1 - 1.0).abs()).fold(0.0, f64::max);
            (worst, (got.albedo_max / want.albedo_max - 1.0).abs())
        };
        let (curve, max) = off(Lookup::Linear);
        let (near, near_max) = off(Lookup::Nearest);
        let grazing = want.theta_i_at_max_deg > 80.0;
        let line = format!("{stem} {name} = {value}: ρ(θᵢ ≤ 80°) off by {curve:.4}, max (at {}°) by {max:.4}; nearest {near:.4}, max {near_max:.4}", want.theta_i_at_max_deg);
        eprintln!("{line}");
        if !(curve < 0.01 && (grazing || max < 0.01) && near > 0.02) {
            failed.push(line);
        }
    }
    assert!(failed.is_empty(), "{failed:#?}");
}

/// A formula whose values are finite but over the metrics' range (`MAX_VALUE`) or beyond the format's (stored =
/// value ÷ SCALE overflows): those entries are not measured, and lobe reads back the table it wrote (it used to
/// store +inf and then refuse it). A table file that holds such values is refused with the value and the entry,
/// not fitted to silently wrong numbers.
#[test]
fn values_beyond_the_formats_range_are_not_measured_and_the_table_reads_back() {
    let t = Measured::tabulate("huge", &|l, v| {
        let x = lobe::frame::inputs_from_dirs(l, v);
        [1e151 * x[2], 1e149, 1e308]
    });
    let back = Measured::from_bytes("huge", &t.to_bytes()).unwrap_or_else(|d| panic!("{}", d.message));
    for e in (0..ENTRIES).step_by(997) {
        for c in 0..3 {
            let s = back.stored(c, e);
            assert!(s.is_finite(), "entry {e} channel {c}: {s}");
        }
    }
    // Red is measured where 1e151·NH ≤ 1e150 only; green (1e149) fits; blue (1e308) never does.
    let measured = |c: usize| (0..ENTRIES).filter(|&e| back.value(c, e).is_some()).count();
    assert!(measured(0) > 0 && measured(0) < measured(1), "{} {}", measured(0), measured(1));
    assert_eq!(measured(2), 0);
    // A file whose values reach 1e300 (written by hand: lobe does not write them) is refused, naming them.
    let mut bytes = t.to_bytes();
    let at = 12 + 8 * (ENTRIES + 4321);
    bytes[at..at + 8].copy_from_slice(&1e300f64.to_le_bytes());
    let Err(e) = Measured::from_bytes("hand.binary", &bytes) else { panic!("a table of 1e300 was read") };
    assert!(e.message.contains("green block holds 1 values over 1e150") && e.message.contains("(θ_h 0, θ_d 24, φ_d 1)"), "{}", e.message);
}

/// A table with no measured entry is named as such by every command that scores or integrates it (the formula
/// is not blamed, and no inf or NaN is printed as a result).
#[test]
fn an_all_unmeasured_table_is_said_to_be_one() {
    let dir = crate::scratch_dir("measured", "none");
    let table = dir.join("none.binary").display().to_string();
    let o = lobe(&["tabulate", "--expr", "0/0 + NH", "-o", &table], None);
    assert!(o.status.success(), "{}", stderr(&o));
    for args in [
        vec!["fit", "examples/brdfs/blinn.brdf", "--measured", table.as_str(), "--param", "n=1..100"],
        vec!["accuracy", "examples/brdfs/blinn.brdf", "--reference", table.as_str()],
        vec!["energy", table.as_str()],
    ] {
        let o = lobe(&args, None);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert!(e.contains("measured") && e.contains("every entry is negative") && !e.contains("formula is"), "{args:?}: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
