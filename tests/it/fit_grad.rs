//! Fits with the exact Jacobian (Levenberg–Marquardt, `lobe fit --measured`) against the derivative-free search
//! (`--derivative-free`): synthetic MERL tables of four explorer models written by `lobe tabulate` at random
//! parameter values, each recovered within 1e-6 relative, and each model's first table fitted both ways in the
//! same run to compare the times (printed; run with `--nocapture` to see them).

use crate::cli::lobe;
use std::process::Output;

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `lobe fit FILE --measured TABLE --param …` at the strides the measured tests use, as JSON.
fn fit(file: &str, table: &str, params: &[String], extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["fit", file, "--measured", table, "--stride", "3", "--grid-stride", "6", "--json"];
    for p in params {
        args.extend(["--param", p.as_str()]);
    }
    args.extend(extra);
    let o = lobe(&args, None);
    assert!(o.status.success(), "fit {file}: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// A parameter to recover: its name and declared range.
type Range = (&'static str, f64, f64);

/// Each model with the parameters to recover.
const MODELS: [(&str, &[Range]); 4] = [
    ("examples/explorer/ggx.brdf", &[("alpha", 0.001, 1.0), ("f0", 0.0, 1.0)]),
    ("examples/explorer/cook_torrance.brdf", &[("m", 0.01, 1.0), ("ior", 1.0, 3.0)]),
    ("examples/explorer/ward_anisotropic.brdf", &[("alpha_x", 0.01, 1.0), ("alpha_y", 0.01, 1.0)]),
    ("examples/explorer/principled.brdf", &[("roughness", 0.02, 1.0), ("metallic", 0.0, 1.0), ("specular", 0.0, 1.0)]),
];

#[test]
fn levenberg_marquardt_recovers_four_explorer_models_from_five_random_tables_each() {
    let dir = crate::scratch_dir("fit_grad", "models");
    let mut rng = lobe::base::rng::Rng(0x5851_f42d_4c95_7f2d);
    let mut timings = vec![];
    for (file, params) in MODELS {
        let search: Vec<String> = params.iter().map(|(n, lo, hi)| format!("{n}={lo}..{hi}")).collect();
        for k in 0..5 {
            // Anywhere in the middle 80 % of each declared range (a roughness of 0.001 is a spike no table resolves).
            let truth: Vec<f64> = params.iter().map(|(_, lo, hi)| lo + (hi - lo) * (0.1 + 0.8 * rng.unit())).collect();
            let set: Vec<String> = params.iter().zip(&truth).map(|((n, ..), v)| format!("{n}={v}")).collect();
            let table = dir.join(format!("t{k}.binary")).display().to_string();
            let o = lobe(&["tabulate", file, "--set", &set.join(","), "-o", &table], None);
            assert!(o.status.success(), "tabulate {file}: {}", stderr(&o));
            let v = fit(file, &table, &search, &[]);
            assert_eq!(v["refinement"], "levenberg-marquardt", "{v}");
            assert!(v["lm"]["iterations"].as_u64().unwrap() > 0 && v["lm"]["starts"].as_u64().unwrap() >= 1, "{v}");
            for ((name, ..), want) in params.iter().zip(&truth) {
                let got = v["params"][name].as_f64().unwrap();
                assert!((got - want).abs() <= 1e-6 * want.abs(), "{file} {set:?}: {name} = {got}: {v}");
            }
            if k == 0 {
                let old = fit(file, &table, &search, &["--derivative-free"]);
                assert_eq!(old["refinement"], "derivative-free", "{old}");
                let (t_lm, t_old) = (v["seconds"].as_f64().unwrap(), old["seconds"].as_f64().unwrap());
                // Same or better: the exact Jacobian's optimum scores no worse than the derivative-free one.
                assert!(v["error"].as_f64().unwrap() <= old["error"].as_f64().unwrap().max(1e-15), "{v}\n{old}");
                timings.push((file, t_lm, t_old));
            }
            let _ = std::fs::remove_file(&table);
        }
    }
    for (file, t_lm, t_old) in &timings {
        eprintln!("{file}: Levenberg–Marquardt {t_lm:.3} s, derivative-free {t_old:.3} s ({:.1}×)", t_old / t_lm);
    }
    // The exact Jacobian is faster on every model, and an order of magnitude faster where the grid is large.
    assert!(timings.iter().all(|(_, a, b)| a < b), "{timings:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_range_of_one_value_fixes_the_parameter_and_says_so() {
    let dir = crate::scratch_dir("fit_grad", "fixed");
    let table = dir.join("ggx.binary").display().to_string();
    let o = lobe(&["tabulate", "examples/explorer/ggx.brdf", "--set", "alpha=0.3,f0=0.5", "-o", &table], None);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = fit("examples/explorer/ggx.brdf", &table, &["alpha=0.001..1".into(), "f0=0.5..0.5".into()], &[]);
    assert_eq!(v["fixed"], serde_json::json!(["f0"]), "{v}");
    assert_eq!(v["params"]["f0"].as_f64(), Some(0.5), "{v}");
    assert!((v["params"]["alpha"].as_f64().unwrap() - 0.3).abs() < 1e-9, "{v}");
    let o = lobe(&["fit", "examples/explorer/ggx.brdf", "--measured", &table, "--param", "alpha=0.001..1", "--param", "f0=0.5..0.5", "--stride", "6", "--grid-stride", "9"], None);
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("fixed: f0"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
}
