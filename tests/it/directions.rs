//! Direction inputs end to end: `lobe eval --at L=…,V=…` and `--points` with `Lx,Ly,Lz,Vx,Vy,Vz` columns
//! (interpreter and JIT agree bit for bit; a cosine formula evaluated from directions equals its value from the
//! cosines `numerics::inputs_from_dirs` gives), colour formulas channel by channel, and clear errors for
//! directions that are missing or zero.

use crate::cli::lobe;
use lobe::numerics::{dir, inputs_from_dirs};
use lobe::Input;

/// A formula reading directions through a select, exp and a cosine: the branches differ, so a wrong select or
/// a wrong direction component changes the value.
const DIRECTIONAL: &str = "select(lt(Lx, Vy), exp(-(Lx*Lx+Ly*Ly)/max(Lz, 0.001)), sqrt(abs(Vx*Vy) + Vz)) + Lz*NH^n";

/// Upper-hemisphere pairs (θ, φ) for L and V, with grazing and normal-incidence rows.
fn pairs() -> Vec<([f64; 3], [f64; 3])> {
    let mut out = vec![];
    let edge = std::f64::consts::FRAC_PI_2 - 1e-9;
    for (tl, pl) in [(0.0, 0.0), (0.3, 0.5), (0.9, 2.0), (1.4, -1.0), (edge, 0.7)] {
        for (tv, pv) in [(0.0, 0.0), (0.6, -2.5), (1.2, 1.0), (edge, 3.0)] {
            out.push((dir(tl, pl), dir(tv, pv)));
        }
    }
    out
}

fn stdout(o: &std::process::Output) -> String {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn numbers(text: &str) -> Vec<u64> {
    text.lines().map(|l| l.trim().parse::<f64>().unwrap_or_else(|_| panic!("`{l}`")).to_bits()).collect()
}

fn direction_csv() -> String {
    let mut csv = String::from("Lx,Ly,Lz,Vx,Vy,Vz\n");
    for (l, v) in pairs() {
        csv.push_str(&format!("{:?},{:?},{:?},{:?},{:?},{:?}\n", l[0], l[1], l[2], v[0], v[1], v[2]));
    }
    csv
}

#[test]
fn eval_points_on_directions_agrees_between_interpreter_and_jit() {
    let csv = direction_csv();
    for (what, args) in [
        ("directional", vec!["eval", "--expr", DIRECTIONAL, "--set", "n=7"]),
        ("ward", vec!["eval", "examples/brdfs/ward.brdf"]),
        ("cook_torrance", vec!["eval", "examples/brdfs/cook_torrance.brdf"]),
    ] {
        let run = |backend: &str| {
            let mut a = args.clone();
            a.extend(["--points", "-", "--backend", backend]);
            numbers(&stdout(&lobe(&a, Some(csv.as_bytes()))))
        };
        let (i, j) = (run("interp"), run("jit"));
        assert_eq!(i.len(), pairs().len(), "{what}");
        assert_eq!(i, j, "{what}: interpreter and JIT differ");
        // --at with the same directions gives the same bits as the batched path.
        let (l, v) = pairs()[7];
        let mut a = args.clone();
        let at = format!("L={:?},{:?},{:?},V={:?},{:?},{:?}", l[0], l[1], l[2], v[0], v[1], v[2]);
        a.extend(["--at", &at]);
        assert_eq!(numbers(&stdout(&lobe(&a, None))), vec![i[7]], "{what}: --at");
    }
}

#[test]
fn a_cosine_formula_from_directions_equals_it_from_the_cosines() {
    let mut cosines = String::from("NL,NV,NH,VR,VH\n");
    for (l, v) in pairs() {
        let x = inputs_from_dirs(l, v);
        let c: Vec<String> = [Input::NL, Input::NV, Input::NH, Input::VR, Input::VH].iter().map(|i| format!("{:?}", x[i.index()])).collect();
        cosines.push_str(&(c.join(",") + "\n"));
    }
    for file in ["blinn", "phong", "cook_torrance", "ward", "kutlog"] {
        let path = format!("examples/brdfs/{file}.brdf");
        let from = |csv: &str| numbers(&stdout(&lobe(&["eval", &path, "--points", "-"], Some(csv.as_bytes()))));
        let (a, b) = (from(&direction_csv()), from(&cosines));
        assert_eq!(a.len(), pairs().len());
        assert_eq!(a, b, "{file}: directions and their cosines give different values");
    }
}

#[test]
fn non_unit_directions_are_normalised_and_said_so() {
    let o = lobe(&["eval", "--expr", DIRECTIONAL, "--points", "-", "--json"], Some(b"Lx,Ly,Lz,Vx,Vy,Vz\n0,0,2,0,3,4\n0,0,1,0,0.6,0.8\n"));
    let j: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let v = j["values"].as_array().unwrap();
    assert_eq!(v[0], v[1], "{j}");
    assert!(j["note"].as_str().unwrap().contains("1 of 2 rows"), "{j}");
    let o = lobe(&["eval", "--expr", DIRECTIONAL, "--at", "L=0,0,2,V=0,3,4", "--json"], None);
    let j: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert!(j["note"].as_str().unwrap().contains("L normalised"), "{j}");
    assert_eq!(j["value"], v[1], "{j}");
}

#[test]
fn missing_or_zero_directions_are_clear_errors() {
    let e = |o: std::process::Output| {
        assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let s = e(lobe(&["eval", "--expr", DIRECTIONAL, "--points", "-"], Some(b"NL,NH\n0.5,0.5\n")));
    assert!(s.contains("reads directions") && s.contains("Lx,Ly,Lz,Vx,Vy,Vz") && s.contains("<stdin>:1:1"), "{s}");
    let s = e(lobe(&["eval", "--expr", DIRECTIONAL, "--points", "-"], Some(b"Lx,Ly,Lz,Vx,Vy,Vz\n0,0,1,0,0,1\n0,0,1,0,0,0\n")));
    assert!(s.contains("V = (0, 0, 0) has no direction") && s.contains("<stdin>:3:7"), "{s}");
    let s = e(lobe(&["eval", "examples/brdfs/blinn.brdf", "--points", "-"], Some(b"Lx,Ly,Lz\n0,0,1\n")));
    assert!(s.contains("without Vx, Vy, Vz"), "{s}");
    let s = e(lobe(&["eval", "examples/brdfs/blinn.brdf", "--points", "-"], Some(b"Lx,Ly,Lz,Vx,Vy,Vz,NH\n0,0,1,0,0,1,1\n")));
    assert!(s.contains("both directions and the cosine column NH"), "{s}");
    let s = e(lobe(&["eval", "--expr", DIRECTIONAL, "--at", "NH=1"], None));
    assert!(s.contains("reads directions") && s.contains("--at L=x,y,z"), "{s}");
    let s = e(lobe(&["eval", "--expr", DIRECTIONAL, "--at", "L=0,0,0,V=0,0,1"], None));
    assert!(s.contains("L = (0, 0, 0) has no direction"), "{s}");
    let o = lobe(&["eval", "--expr", DIRECTIONAL, "--at", "L=1,2"], None);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("three components"));
}

/// A colour formula: each channel compiled on both backends and evaluated on direction points through the same
/// parser and batched path `lobe eval --points` uses; the channels agree bit for bit across backends and equal
/// the scalar evaluation at each point.
#[test]
fn colour_formulas_evaluate_per_channel_on_both_backends() {
    use lobe::numerics::points;
    use lobe::{Backend, Evaluator};
    let f = crate::export::aniso_colour();
    let csv = direction_csv();
    let mut per_backend = vec![];
    for backend in [Backend::Interp, Backend::Jit] {
        let ks: Vec<lobe::Kernel> = f
            .channels()
            .into_iter()
            .map(|c| lobe::compile_formula(c, &lobe::Options { backend, ..Default::default() }).unwrap())
            .collect();
        let used = lobe::ir::InputSet(ks.iter().map(|k| k.used_inputs().0).fold(0, |a, b| a | b));
        assert!(used.reads_directions());
        let pts = points::parse("t.csv", &csv, &ks[0].formula, used, &[]).unwrap_or_else(|e| panic!("{e:?}"));
        let params = ks[0].default_params();
        let vals: Vec<Vec<u64>> = ks.iter().map(|k| points::evaluate(k, &pts, &params).iter().map(|v| v.to_bits()).collect()).collect();
        for (i, (l, v)) in pairs().into_iter().enumerate() {
            for (c, k) in ks.iter().enumerate() {
                assert_eq!(k.eval(&inputs_from_dirs(l, v), &params).to_bits(), vals[c][i], "{backend:?} channel {c} point {i}");
            }
        }
        // The colour differs between channels where the diffuse term dominates.
        assert!(vals[0] != vals[2]);
        per_backend.push(vals);
    }
    assert_eq!(per_backend[0], per_backend[1], "interpreter and JIT differ on a colour formula");
}

/// The stability sweep of a colour direction formula, channel by channel on real geometry: the anisotropic lobe
/// divides by sqrt(N·L · N·V), so it is infinite exactly in the horizon plane and finite on the interior of the
/// hemisphere — which independent samples of Lx..Vz would not show.
#[test]
fn sweep_of_a_colour_direction_formula_runs_per_channel_on_geometry() {
    use lobe::numerics::sweep::{sweep, SweepOptions};
    let f = crate::export::aniso_colour();
    let chans = f.named_channels();
    assert_eq!(chans.iter().map(|c| c.display_name()).collect::<Vec<_>>(), ["aniso_colour (red)", "aniso_colour (green)", "aniso_colour (blue)"]);
    for c in chans {
        let k = lobe::compile_formula(c.unclamped(), &lobe::Options::default()).unwrap();
        let r = sweep(&k, c.used_inputs(), &c.params, &SweepOptions { max_evals: 300_000, ..Default::default() });
        let region = |name: &str| r.regions.iter().find(|s| s.region == name).unwrap_or_else(|| panic!("no {name} region"));
        let zero = region("zero");
        assert!(zero.inf > 0, "{}: {zero:?}", c.display_name());
        let interior = region("interior");
        assert_eq!((interior.nan, interior.inf), (0, 0), "{}: {interior:?}", c.display_name());
    }
}
