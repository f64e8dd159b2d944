//! Numerical robustness (issue 12): the defects an independent audit measured become regression tests, and the
//! accuracy pass is checked over every catalogue formula against the higher-precision truth.

use lobe::ir::Formula;
use lobe::numerics::robust::{self, improve, measure, sample, ulps, PassOptions, Prefer};
use lobe::numerics::truth;
use lobe::{Backend, Evaluator, Kernel, Options};
use std::sync::Arc;

fn load(stem: &str) -> Formula {
    let path = format!("{}/examples/brdfs/{stem}.brdf", env!("CARGO_MANIFEST_DIR"));
    let src = std::fs::read_to_string(&path).unwrap();
    lobe::front::parse(&path, &src).unwrap()
}

/// The catalogue's file stems (`examples/brdfs/*.brdf`), sorted.
fn catalogue_stems() -> Vec<String> {
    let dir = format!("{}/examples/brdfs", env!("CARGO_MANIFEST_DIR"));
    let mut stems: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| {
            let p = e.ok()?.path();
            (p.extension()? == "brdf").then(|| p.file_stem().unwrap().to_string_lossy().into_owned())
        })
        .collect();
    stems.sort();
    stems
}

fn jit_options(set: &[(&str, f64)]) -> Options {
    Options { backend: Backend::Jit, bake: set.iter().map(|(k, v)| (k.to_string(), *v)).collect(), ..Default::default() }
}

/// The catalogue file compiled on the JIT through the accuracy pass at its defaults.
fn robust_kernel(stem: &str, set: &[(&str, f64)]) -> Kernel {
    lobe::compile_formula(load(stem), &robust::with_pass(jit_options(set), PassOptions::default())).unwrap()
}

/// A BRDF Explorer example file, compiled on the JIT as is and through the accuracy pass with `pass`.
fn explorer(stem: &str, pass: PassOptions) -> (Formula, Kernel, Kernel) {
    let path = format!("{}/examples/explorer/{stem}.brdf", env!("CARGO_MANIFEST_DIR"));
    let f = lobe::front::parse(&path, &std::fs::read_to_string(&path).unwrap()).unwrap();
    let plain = lobe::compile_formula(f.clone(), &jit_options(&[])).unwrap();
    let k = lobe::compile_formula(f.clone(), &robust::with_pass(jit_options(&[]), pass)).unwrap();
    (f, plain, k)
}

fn plain_kernel(stem: &str, set: &[(&str, f64)]) -> Kernel {
    lobe::compile_formula(load(stem), &jit_options(set)).unwrap()
}

/// Inputs NL, NV, NH, VR, VH.
fn at(nl: f64, nv: f64, nh: f64, vh: f64) -> [f64; lobe::N_INPUTS] {
    lobe::from_cosines([nl, nv, nh, nh, vh])
}

#[test]
fn beckmann_and_cook_torrance_are_zero_not_nan_at_tiny_nh() {
    for stem in ["beckmann", "cook_torrance"] {
        let plain = plain_kernel(stem, &[]);
        let k = robust_kernel(stem, &[]);
        let p = k.default_params();
        let f = load(stem);
        // The defect: NaN for every NH ≤ ~1e-77 as written (NH⁴ underflows: 1/0 · exp(−∞)).
        assert!(plain.eval(&at(0.5, 0.5, 1e-77, 0.7), &p).is_nan(), "{stem}: the unrewritten form is no longer NaN");
        for nh in [1e-77, 1e-100, 1e-160, 1e-200, 1e-300, 1e-310, 5e-324] {
            let x = at(0.5, 0.5, nh, 0.7);
            let v = k.eval(&x, &p);
            assert_eq!(v, 0.0, "{stem} at NH = {nh:e}: {v}");
            assert_eq!(truth::eval(&f, &x, &p), 0.0, "{stem}: the truth at NH = {nh:e}");
        }
        // And the peak is unchanged to a few ulps.
        let x = at(0.9, 0.8, 0.99, 0.95);
        assert!(ulps(k.eval(&x, &p), plain.eval(&x, &p)) <= 4.0, "{stem}");
    }
    // At NH = 0 exactly Beckmann is exp(−∞)/0 (0/0 as written; its limit is 0): the default pass keeps
    // scaled-exp, whose vanished exponential times an infinite quotient is 0.
    let (plain, k) = (plain_kernel("beckmann", &[]), robust_kernel("beckmann", &[]));
    let p = k.default_params();
    assert!(plain.eval(&at(0.5, 0.5, 0.0, 0.7), &p).is_nan(), "the unrewritten Beckmann is no longer NaN at NH = 0");
    assert_eq!(k.eval(&at(0.5, 0.5, 0.0, 0.7), &p), 0.0, "Beckmann at NH = 0");
    // Cook–Torrance at NH = 0 exactly, whatever VH, NL and NV (0 included: G·F/(NL·NV) is then 0/0 as well): the
    // exponential vanishes faster than any power, so the limit is 0, on every tier and at random parameters.
    let f = load("cook_torrance");
    let mut r = lobe::base::rng::Rng(0xc7);
    for backend in [Backend::Interp, Backend::Jit] {
        let k = lobe::compile_formula(f.clone(), &robust::with_pass(Options { backend, ..Default::default() }, PassOptions::default())).unwrap();
        for _ in 0..200 {
            let mut pick = || [0.0, 5e-324, 1e-300, r.unit(), 1.0][r.below(5) as usize];
            let x = at(pick(), pick(), 0.0, pick());
            let p = [k.default_params()[0], 0.01 + r.unit() * 0.99, r.unit()];
            assert_eq!(k.eval(&x, &p), 0.0, "Cook–Torrance on {backend:?} at NH = 0, {x:?}, {p:?}");
        }
    }
}

/// Ward (1/√(NL·NV)) and Cook–Torrance (/(π·NL·NV)) where NL·NV underflows but the true value is finite;
/// the unrewritten forms give inf (Ward) and NaN or inf (Cook–Torrance) there.
#[test]
fn ward_and_cook_torrance_are_finite_when_nl_nv_underflows() {
    for (stem, c) in [("ward", 1.5e-162), ("cook_torrance", 1e-170)] {
        let k = robust_kernel(stem, &[]);
        let p = k.default_params();
        let x = at(c, c, 0.95, 0.9);
        let t = truth::eval(&load(stem), &x, &p);
        assert!(t.is_finite() && t > 1e100, "{stem}: truth {t}");
        assert!(!plain_kernel(stem, &[]).eval(&x, &p).is_finite(), "{stem}: the unrewritten form is finite now");
        // A dozen roundings (the exponent's five feed exp): within the 16 ulp.
        let v = k.eval(&x, &p);
        assert!(ulps(v, t) <= 16.0, "{stem}: {v:e} vs {t:e}");
    }
}

/// Ward at NL = 0 or NV = 0 is a pole, 1/√0 times a positive exponential, whatever NH: +∞ (the pass's
/// expmuldiv took the infinite b/c for an overflowed factor and gave 0 where e^E underflowed, 1 810 of 4 003
/// pole points on 10⁵). Live and baked, at random NH (tiny ones included) and m.
#[test]
fn ward_is_infinite_at_its_poles_whatever_the_exponential() {
    let mut r = lobe::base::rng::Rng(77);
    let live = robust_kernel("ward", &[]);
    let k = load("ward").param_index("m").unwrap();
    for i in 0..400 {
        let m = 0.01 + 0.99 * r.unit();
        let mut p = live.default_params();
        p[k] = m;
        let nh = if i % 4 == 0 { 5e-324 } else { r.unit().powi(1 + (i % 200)) };
        let other = r.unit().max(1e-300);
        let x = if i % 2 == 0 { at(0.0, other, nh, 0.5) } else { at(other, 0.0, nh, 0.5) };
        let t = truth::eval(&load("ward"), &x, &p);
        assert_eq!(t, f64::INFINITY, "truth at {x:?}, m = {m}");
        assert_eq!(live.eval(&x, &p), f64::INFINITY, "live at NH = {nh:e}, m = {m}");
        if i % 40 == 0 {
            let baked = robust_kernel("ward", &[("m", m)]);
            assert_eq!(baked.eval(&x, &baked.default_params()), f64::INFINITY, "baked m = {m} at NH = {nh:e}");
        }
    }
}

/// Blinn at n = 1000: the plain chain loses hundreds of ulps; the pow call stays within an ulp and the compensated
/// chain (the pass's default choice) within its 3u bound (< 3 ulp), so baked and live agree within 4 ulp.
#[test]
fn blinn_n1000_chain_loses_hundreds_of_ulps_and_the_compensated_chain_does_not() {
    let f = load("blinn");
    let bake = [(0usize, 1000.0)];
    let chain = lobe::build_kernel(Arc::new(lobe::simplify::simplify(&f, &bake)), Backend::Jit, lobe::Mode::Precise).unwrap();
    let calls = lobe::simplify::simplify_with(&f, &bake, &lobe::simplify::accuracy::pow_call_policy()).0;
    let call = lobe::build_kernel(Arc::new(calls.clone()), Backend::Jit, lobe::Mode::Precise).unwrap();
    let comp = lobe::simplify::accuracy::compensated_powers(&calls).unwrap();
    let comp_jit = lobe::build_kernel(Arc::new(comp.clone()), Backend::Jit, lobe::Mode::Precise).unwrap();
    let comp_interp = lobe::build_kernel(Arc::new(comp), Backend::Interp, lobe::Mode::Precise).unwrap();
    let baked = robust_kernel("blinn", &[("n", 1000.0)]);
    let live = plain_kernel("blinn", &[]);
    let (mut worst_chain, mut worst_call, mut worst_comp, mut worst_live) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for i in 0..20_000 {
        let c = 0.3 + 0.7 * (i as f64 + 0.5) / 20_000.0;
        let x = at(1.0, 1.0, c, 1.0);
        let t = truth::eval(&f, &x, &[1000.0]);
        if t < f64::MIN_POSITIVE {
            continue;
        }
        worst_chain = worst_chain.max(ulps(chain.eval(&x, &[1000.0]), t));
        worst_call = worst_call.max(ulps(call.eval(&x, &[1000.0]), t));
        let v = comp_jit.eval(&x, &[1000.0]);
        assert_eq!(v.to_bits(), comp_interp.eval(&x, &[1000.0]).to_bits(), "JIT and interpreter differ at NH = {c}");
        worst_comp = worst_comp.max(ulps(v, t));
        worst_live = worst_live.max(ulps(live.eval(&x, &[1000.0]), baked.eval(&x, &[1000.0])));
    }
    assert!(worst_chain > 100.0, "the chain's error was measured at 449 ulp; now {worst_chain}");
    assert!(worst_call <= 1.0 && worst_comp <= 3.0, "pow {worst_call}, compensated {worst_comp}");
    assert!(worst_live <= 4.0, "baked (the pass's choice) and live differ by {worst_live} ulp");
    // The default pass bakes what the live kernel computes (the pow call), then takes the compensated chain,
    // as accurate and cheaper; speed keeps the plain chain.
    let o = improve(&f, &bake, &PassOptions { points: 4000, ..Default::default() });
    let kept: Vec<&str> = o.trials.iter().filter(|t| t.kept).map(|t| t.rule.name()).collect();
    assert_eq!(kept, ["live-choice", "compensated-power"], "{:?}", o.trials);
    // log2(3 + 1) = 2 bits: the compensated chain's bound.
    assert!(o.after.max_bits <= 2.0 && o.before.max_bits > 3.0, "{:?}", o.trials);
    let speed = improve(&f, &bake, &PassOptions { prefer: Prefer::Speed, points: 4000, ..Default::default() });
    assert!(!speed.trials.iter().any(|t| t.kept));
}

/// Baked integer powers over the range of k: the plain chain loses more than 3 ulp against the truth, the
/// compensated chain stays within its 3u bound (< 3 ulp), on [0.3, 1) and near 1, bit-identical on the JIT and
/// the interpreter; below x₀ = 2^(−1076/k), where x^k rounds to +0, it gives +0 (large k: without an underflow).
#[test]
fn compensated_chains_stay_within_three_ulps_for_every_k() {
    use lobe::simplify::accuracy::{compensated_powers, pow_call_policy};
    let f = load("blinn");
    for k in [9u32, 10, 16, 50, 100, 268, 500, 1000, lobe::simplify::MAX_POW_CHAIN] {
        let (bake, p) = ([(0usize, f64::from(k))], [f64::from(k)]);
        let chain = lobe::build_kernel(Arc::new(lobe::simplify::simplify(&f, &bake)), Backend::Interp, lobe::Mode::Precise).unwrap();
        let calls = lobe::simplify::simplify_with(&f, &bake, &pow_call_policy()).0;
        let comp = compensated_powers(&calls).unwrap();
        let jit = lobe::build_kernel(Arc::new(comp.clone()), Backend::Jit, lobe::Mode::Precise).unwrap();
        let interp = lobe::build_kernel(Arc::new(comp), Backend::Interp, lobe::Mode::Precise).unwrap();
        let (mut worst_chain, mut worst_comp) = (0.0f64, 0.0f64);
        for i in 0..6000 {
            let u = (i / 2) as f64 / 3000.0;
            let c = if i % 2 == 0 { 0.3 + 0.7 * u } else { 1.0 - 10f64.powf(-16.0 * u) };
            let x = at(1.0, 1.0, c, 1.0);
            let t = truth::eval(&f, &x, &p);
            if t < f64::MIN_POSITIVE {
                continue;
            }
            let v = jit.eval(&x, &p);
            assert_eq!(v.to_bits(), interp.eval(&x, &p).to_bits(), "k = {k}: JIT and interpreter differ at NH = {c}");
            worst_comp = worst_comp.max(ulps(v, t));
            worst_chain = worst_chain.max(ulps(chain.eval(&x, &p), t));
        }
        assert!(worst_chain > 3.0, "k = {k}: the plain chain is within {worst_chain} ulp");
        assert!(worst_comp <= 3.0, "k = {k}: the compensated chain is {worst_comp} ulp off");
        let x0 = (-1076.0 / f64::from(k)).exp2();
        for c in [0.0, 1e-300, 0.5 * x0, 0.999 * x0] {
            assert_eq!(jit.eval(&at(1.0, 1.0, c, 1.0), &p).to_bits(), 0, "k = {k} at NH = {c:e}");
            assert_eq!(truth::eval(&f, &at(1.0, 1.0, c, 1.0), &p), 0.0);
        }
    }
}

#[test]
fn quadratic_near_one_is_correctly_rounded_after_factoring() {
    let f = load("quadratic");
    let plain = plain_kernel("quadratic", &[("n", 1000.0)]);
    let k = robust_kernel("quadratic", &[("n", 1000.0)]);
    let x = at(1.0, 1.0, 1.0 - 2f64.powi(-53), 1.0);
    let t = truth::eval(&lobe::simplify::bake_only(&f, &[(0, 1000.0)]), &x, &[1000.0]);
    assert!(ulps(plain.eval(&x, &[1000.0]), t) > 100.0, "the cancellation (237 ulp) is gone from the plain form?");
    assert!(ulps(k.eval(&x, &[1000.0]), t) <= 1.0, "{} vs {t}", k.eval(&x, &[1000.0]));
}

/// The "must show" on every catalogue formula, 10⁵ domain points each (a quarter from the edge classes:
/// 0, 1 − 2⁻⁵³, denormals, 10⁻³⁰⁰ …), at defaults (n live) and with n = 50 and n = 1000 baked: no NaN/∞ where
/// the truth is finite; at most 4 bits (15 ulp) of error where the formula is well conditioned; and the baked kernel within 4 ulp of the live one at every point where both are finite
/// (where the formula reads n: a compensated power chain against pow; elsewhere the pass must choose the same).
#[test]
fn catalogue_must_show_on_100k_points() {
    let dir = format!("{}/examples/brdfs", env!("CARGO_MANIFEST_DIR"));
    let mut stems: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok()?.path().file_stem().map(|s| s.to_string_lossy().into_owned()))
        .filter(|s| !s.is_empty())
        .collect();
    stems.retain(|s| std::path::Path::new(&format!("{dir}/{s}.brdf")).exists());
    stems.sort();
    assert!(stems.len() >= 16, "{stems:?}");
    let mut power_formulas = 0;
    let mut limit_points = 0;
    for stem in &stems {
        let f = load(stem);
        let n = f.param_index("n").unwrap();
        let reads_n = lobe::simplify::simplify(&f, &[]).ir.used_params(lobe::simplify::simplify(&f, &[]).root).contains(&(n as u16));
        let live = robust_kernel(stem, &[]);
        for bake in [vec![], vec![(n, 50.0)], vec![(n, 1000.0)]] {
            let set: Vec<(&str, f64)> = bake.iter().map(|(_, v)| ("n", *v)).collect();
            let k = robust_kernel(stem, &set);
            let pts = sample(&f, &bake, 100_000, 7);
            let s = measure(&k, &lobe::simplify::bake_only(&f, &bake), &pts);
            assert_eq!(s.points, 100_000);
            // Points whose exact value is 0/0 at an input exactly 0 or 1 count, with their limit as the truth.
            assert_eq!(s.nonfinite, 0, "{stem} {bake:?}: {:?}", s.first_nonfinite);
            // ≤ 15 ulp wherever a 1-ulp input change moves the truth by at most 16 ulp; Beckmann with every
            // m live is 17 ulp off at a few of these 10⁵ points (4.09 bits at NH = 0.41, m = 0.72, where
            // the compensated exponent is over the default budget), within it at 20 parameter sets of 10⁴
            // points (tests/it/everywhere.rs).
            // F_kutlog with its parameters live reaches 7.9 bits where its value is flat in NH (NH = 10⁻³¹⁰,
            // Q = 0.1, k = 5): open; with them baked it is within the target.
            let bound = match stem.as_str() {
                "beckmann" => robust::TARGET_BITS + 0.1,
                "kutlog" if bake.is_empty() => 8.0,
                _ => robust::TARGET_BITS,
            };
            assert!(s.max_bits_well <= bound, "{stem} {bake:?}: {} bits at {:?}", s.max_bits_well, s.worst_well);
            limit_points += s.limits;
            if stem == "cook_torrance" {
                assert!(s.limits > 20_000, "Cook–Torrance at NL or NV = 0: {} limit points", s.limits);
            }
            if !bake.is_empty() {
                let worst = pts
                    .iter()
                    .map(|pt| (live.eval(&pt.x, &pt.p), k.eval(&pt.x, &pt.p), pt))
                    .filter(|(a, b, _)| a.is_finite() && b.is_finite())
                    .map(|(a, b, pt)| (ulps(a, b), pt.x))
                    .fold((0.0, [0.0; lobe::N_INPUTS]), |w, d| if d.0 > w.0 { d } else { w });
                assert!(worst.0 <= 4.0, "{stem} {bake:?}: baked and live differ by {} ulp at {:?}", worst.0, worst.1);
            }
        }
        power_formulas += usize::from(reads_n);
    }
    assert!(power_formulas >= 10, "{power_formulas}");
    // Cook–Torrance, Beckmann (NH = 0) and Ward (NL·NV at 0 beside a vanishing exp).
    assert!(limit_points > 3 * (20_000 + 1_000), "{limit_points}");
}

/// Bake-consistency (`numerics::robust`, module docs): with every parameter baked at its default, and with n = 50
/// alone, the pass's kernel agrees with the live one within 4 ulp at each of 10⁵ domain points where both are
/// finite. A pass deciding on the baked domain alone dropped rewrites the live one kept (Beckmann's
/// `compensated-exp` at m = 0.3, Ward's second quotient chain), so the kernels differed by the correction.
#[test]
fn catalogue_baked_at_defaults_agrees_with_live() {
    let stems = catalogue_stems();
    assert!(stems.len() >= 16, "{stems:?}");
    for stem in &stems {
        let f = load(stem);
        let live = robust_kernel(stem, &[]);
        let all: Vec<(usize, f64)> = f.params.iter().enumerate().map(|(i, p)| (i, p.default)).collect();
        for bake in [all, vec![(f.param_index("n").unwrap(), 50.0)]] {
            let set: Vec<(&str, f64)> = bake.iter().map(|&(i, v)| (f.params[i].name.as_str(), v)).collect();
            let k = robust_kernel(stem, &set);
            let worst = sample(&f, &bake, 100_000, 7)
                .iter()
                .map(|pt| (live.eval(&pt.x, &pt.p), k.eval(&pt.x, &pt.p), pt))
                .filter(|(a, b, _)| a.is_finite() && b.is_finite())
                .map(|(a, b, pt)| (ulps(a, b), pt.x))
                .fold((0.0, [0.0; lobe::N_INPUTS]), |w, d| if d.0 > w.0 { d } else { w });
            assert!(worst.0 <= 4.0, "{stem} {set:?}: baked and live differ by {} ulp at {:?}", worst.0, worst.1);
        }
    }
    // The live choice is the baked one's first trial, kept: Beckmann with m baked computes what the live
    // kernel computes, every rule the live pass kept included.
    let f = load("beckmann");
    let o = improve(&f, &[(f.param_index("m").unwrap(), 0.3)], &PassOptions::default());
    let live = improve(&f, &[], &PassOptions::default());
    assert!(o.trials[0].kept && o.trials[0].rule.name() == "live-choice", "{:?}", o.trials);
    for step in &live.decision.live {
        assert!(o.trials[0].reason.contains(step.rule.name()), "{:?} lacks {}", o.trials[0], step.rule.name());
    }
}

/// F_dsh's worst well-conditioned point (NH = 0.3127, n = 1.24, condition 15) was c/(n(1 − c) + c) − 0.25
/// cancelling (0.266 − 0.25) beside the c⁸ term: 4.25 bits. `rational-form` regroups that sub-sum as one
/// linear-fractional form, within the 4 bits live and with n baked, at the default budget.
#[test]
fn dsh_within_16_ulp_live_and_baked() {
    let f = load("dsh");
    let n = f.param_index("n").unwrap();
    let seed = PassOptions::default().seed;
    let pts = sample(&f, &[], 100_000, seed);
    let plain = measure(&plain_kernel("dsh", &[]), &f, &pts);
    assert!(plain.max_bits_well > robust::TARGET_BITS, "the written form is within the target now: {:?}", plain.worst_well);
    for bake in [vec![], vec![(n, 50.0)], vec![(n, 1000.0)]] {
        let set: Vec<(&str, f64)> = bake.iter().map(|(_, v)| ("n", *v)).collect();
        let pts = sample(&f, &bake, 100_000, seed);
        let s = measure(&robust_kernel("dsh", &set), &lobe::simplify::bake_only(&f, &bake), &pts);
        assert!(s.max_bits_well <= robust::TARGET_BITS, "{bake:?}: {:?}", s.worst_well);
        assert_eq!(s.nonfinite, 0, "{bake:?}");
    }
}

/// Cook–Torrance at NL = 0 or NV = 0 exactly: G/(NL·NV) is 0/0 as written, but G = 2·NH·NL/VH there, so the
/// value has a limit (the truth's, along NL), which `cancel-min` computes: G/(NL·NV) as
/// min(VH/min(NL, NV), 2·NH)/VH/max(NL, NV). The written form, and the branch start's pass, gave NaN.
#[test]
fn cook_torrance_is_its_limit_at_nl_or_nv_zero() {
    let f = load("cook_torrance");
    let plain = plain_kernel("cook_torrance", &[]);
    let k = robust_kernel("cook_torrance", &[]);
    let p = k.default_params();
    for (nl, nv, nh, vh) in [(0.0, 0.25, 0.9, 0.5), (0.4, 0.0, 0.7, 0.6), (0.0, 1e-300, 0.95, 0.8), (0.0, 0.9, 0.99, 0.999)] {
        let x = at(nl, nv, nh, vh);
        assert!(truth::eval(&f, &x, &p).is_nan() && plain.eval(&x, &p).is_nan(), "not 0/0 at {x:?}");
        let t = truth::limit(&f, &x, &p).unwrap_or_else(|| panic!("no limit at {x:?}"));
        let v = k.eval(&x, &p);
        assert!(t.is_finite() && ulps(v, t) <= 16.0, "at {x:?}: {v:e} vs the limit {t:e}");
    }
    let o = improve(&f, &[], &PassOptions::default());
    assert!(o.trials.iter().any(|t| t.kept && t.rule.name() == "cancel-min"), "{:?}", o.trials);
    assert_eq!(o.after.nonfinite, 0, "{:?}", o.after.first_nonfinite);
    assert!(o.before.limits > 0 && o.before.nonfinite >= o.before.limits, "{:?}", o.before);
}

/// Cook–Torrance where its value is subnormal: at NL = 0 (a limit point) with NV ~ 1e-155 and VH = 1e-154 the
/// limit is 1.4e-310, but VH·max(NL, NV) ~ 1e-310 fits no f64 beside e^E, and the branch start divided by
/// max(NL, NV) after expmuldiv had rounded the rest below the subnormals: 0 (44.7 bits). `scaled-exp` now takes
/// the two divisors apart inside one expmuldiv; over the harness's sample every well-conditioned point is within
/// 16 ulp (live and with the unused n baked).
#[test]
fn cook_torrance_is_within_16_ulp_where_its_value_is_subnormal() {
    let f = load("cook_torrance");
    let k = robust_kernel("cook_torrance", &[]);
    let mut p = k.default_params();
    p[f.param_index("m").unwrap()] = 0.6867935575134458;
    p[f.param_index("F0").unwrap()] = 0.0;
    let x = at(0.0, 7.680844610156389e-156, 3.840422305078195e-2, 1e-154);
    let t = truth::limit(&f, &x, &p).unwrap();
    assert!(t > 0.0 && t < f64::MIN_POSITIVE, "{t:e}");
    let v = k.eval(&x, &p);
    assert!(ulps(v, t) <= 16.0, "{v:e} vs the limit {t:e}");
    let n = f.param_index("n").unwrap();
    for bake in [vec![], vec![(n, 50.0)]] {
        let set: Vec<(&str, f64)> = bake.iter().map(|(_, v)| ("n", *v)).collect();
        let k = robust_kernel("cook_torrance", &set);
        let s = measure(&k, &lobe::simplify::bake_only(&f, &bake), &sample(&f, &bake, 100_000, 7));
        assert_eq!(s.nonfinite, 0, "{:?}", s.first_nonfinite);
        assert!(s.max_bits_well <= robust::TARGET_BITS, "{bake:?}: {:.2} bits at {:?}", s.max_bits_well, s.worst_well);
    }
}

/// Cook–Torrance where VH is subnormal (L nearly perpendicular to H): G = 1 there, and the pass once chose the
/// min's branch through the quotient VH/min(NL, NV), which rounds into the subnormals before VH divides it again
/// (the audit's point: 1.3465·10⁻¹⁵, true 1.8172·10⁻¹⁵, 26 % low). Now the audit's point is within its condition,
/// and random points with VH anywhere in the subnormals (and m, F0 random, live and baked) are within 4 bits
/// wherever a 1-ulp move of an input moves the truth by ≤ 16 ulp.
#[test]
fn cook_torrance_is_exact_where_vh_is_subnormal() {
    let f = load("cook_torrance");
    let (mi, fi) = (f.param_index("m").unwrap(), f.param_index("F0").unwrap());
    let live = robust_kernel("cook_torrance", &[]);
    let p = live.default_params();
    let x = at(0.7359828375025015, 0.9999991871922227, 0.47322972161775645, 5e-324);
    let t = truth::eval(&f, &x, &p);
    assert!(ulps(t, 1.8171990412213856e-15) <= 1.0, "lobe's truth {t:e}, the audit's 1.8171990412213856e-15");
    let pt = robust::Point { x, p: p.clone() };
    let kappa = robust::condition_ulps(&f, &pt, t);
    let v = live.eval(&x, &p);
    assert!(ulps(v, t) <= 16.0f64.max(kappa), "{v:e} vs {t:e} (κ = {kappa})");
    let mut r = lobe::base::rng::Rng(29);
    let mut well = 0;
    for i in 0..4000 {
        let mut p = live.default_params();
        p[mi] = 0.3 + 0.7 * r.unit();
        p[fi] = r.unit();
        // VH log-uniform over the subnormals (and f64::MIN_POSITIVE's neighbourhood), the rest anywhere.
        let vh = (5e-324f64).max(f64::MIN_POSITIVE * 2f64.powf(-53.0 * r.unit()));
        let x = at(r.unit().max(1e-3), r.unit().max(1e-3), 0.4 + 0.6 * r.unit(), vh);
        let t = truth::eval(&f, &x, &p);
        let pt = robust::Point { x, p: p.clone() };
        if !t.is_finite() || robust::condition_ulps(&f, &pt, t) > robust::ILL_CONDITIONED_ULPS {
            continue;
        }
        well += 1;
        let v = live.eval(&x, &p);
        assert!(ulps(v, t) <= 16.0, "live at {x:?}, {p:?}: {v:e}, true {t:e}");
        if i % 400 == 0 {
            let baked = robust_kernel("cook_torrance", &[("m", p[mi]), ("F0", p[fi])]);
            let b = baked.eval(&x, &baked.default_params());
            assert!(ulps(b, t) <= 16.0, "baked at {x:?}, {p:?}: {b:e}, true {t:e}");
        }
    }
    assert!(well > 1000, "only {well} well-conditioned points");
}

#[test]
fn energy_has_a_coefficient_for_every_catalogue_file() {
    let dir = format!("{}/examples/brdfs", env!("CARGO_MANIFEST_DIR"));
    for e in std::fs::read_dir(&dir).unwrap() {
        let path = e.unwrap().path();
        if path.extension().and_then(|x| x.to_str()) != Some("brdf") {
            continue;
        }
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        for k in [robust_kernel(&stem, &[]), plain_kernel(&stem, &[])] {
            let (lobe, _) = lobe::numerics::choose_lobe_input(k.used_inputs());
            let r = lobe::numerics::energy::lobe_integral(&k, &k.default_params(), lobe);
            let r = r.unwrap_or_else(|e| panic!("{stem}: {e}"));
            assert!(r.coef().is_finite() && r.coef() > 0.0, "{stem}");
            if stem == "beckmann" {
                assert!((r.coef() * std::f64::consts::PI - 1.0).abs() < 1e-9, "Beckmann: {}", r.coef());
            }
        }
    }
}

/// An explorer BRDF's `sqrt(NdotL * NdotV)` under its `if (NdotL <= 0.0 || NdotV <= 0.0) return` guard: the
/// product underflows at grazing light and view (0/0 = NaN as written); the guarded split-sqrt keeps it finite.
/// (At Lz = Vz = 5e-324 the constant factors still underflow the product √Lz·√Vz: NaN; not yet fixed.)
#[test]
fn explorer_ward_is_finite_at_grazing_light_and_view() {
    let (f, plain, k) = explorer("ward_anisotropic", PassOptions::default());
    let p = k.default_params();
    for z in [1e-170f64, 1e-200, 1e-300] {
        let s = (1.0 - z * z).sqrt();
        let x = lobe::numerics::inputs_from_dirs([s, 0.0, z], [0.0, s, z]);
        let t = truth::eval(&f, &x, &p);
        assert!(t.is_finite() && t > 0.0, "truth {t} at Lz = Vz = {z:e}");
        assert!(plain.eval(&x, &p).is_nan(), "the unrewritten form is no longer NaN at {z:e}");
        let v = k.eval(&x, &p);
        assert!(ulps(v, t) <= 4.0, "at Lz = Vz = {z:e}: {v} vs {t}");
    }
}

/// `expmuldiv(a, b, c)` = e^a·b/c within its stated 2 ulp of the truth where e^a alone under- or overflows but
/// the result is a normal or denormal number, and the JIT gives the interpreter's bits (vector lanes:
/// `differential::every_builtin_on_dense_inputs`).
#[test]
fn expmuldiv_keeps_the_bits_exp_loses_to_underflow() {
    let src = "param a = 0 in -3000..3000\nparam b = 1 in -1e308..1e308\nparam c = 1 in -1e308..1e308\n@domain raw\nexpmuldiv(a, b, c)";
    let f = lobe::front::parse_internal("e.brdf", src).unwrap();
    let jit = lobe::compile_formula(f.clone(), &jit_options(&[])).unwrap();
    let interp = lobe::compile_formula(f.clone(), &Options { backend: Backend::Interp, ..Default::default() }).unwrap();
    let x = [0.5; lobe::N_INPUTS];
    let mut r = lobe::base::rng::Rng(11);
    let (mut worst, mut naive_worst) = (0.0f64, 0.0f64);
    for i in 0..20_000 {
        // Mostly exponents where e^a alone is out of range, scaled back by b/c (normal and denormal results).
        let a = if i % 4 == 0 { -3000.0 + 6000.0 * r.unit() } else { -1500.0 + 800.0 * r.unit() };
        let b = 10f64.powf(-320.0 + 628.0 * r.unit()) * if r.unit() < 0.1 { -1.0 } else { 1.0 };
        let c = 10f64.powf(-300.0 + 600.0 * r.unit());
        // The implicit `n` comes first.
        let p = [50.0, a, b, c];
        let (t, v) = (truth::eval(&f, &x, &p), interp.eval(&x, &p));
        assert_eq!(jit.eval(&x, &p).to_bits(), v.to_bits(), "JIT vs interpreter at {p:?}");
        if t.is_finite() {
            worst = worst.max(ulps(v, t));
            naive_worst = naive_worst.max(ulps(a.exp() * b / c, t));
        } else {
            assert!(v.is_infinite() && v.signum() == t.signum(), "{p:?}: {v} vs {t}");
        }
    }
    assert!(worst <= 2.0, "expmuldiv: {worst} ulp from the truth");
    assert!(naive_worst > 1e6, "the sample no longer reaches exp's underflow ({naive_worst} ulp)");
    // Special values follow exp(a)*b/c, except that a vanished e^a times an overflowed b/c is 0.
    let e = |a: f64, b: f64, c: f64| lobe::builtins::Builtin::ExpMulDiv.eval(&[a, b, c]);
    assert!(e(f64::NAN, 1.0, 1.0).is_nan() && e(0.0, f64::NAN, 1.0).is_nan() && e(0.0, 1.0, f64::NAN).is_nan());
    assert_eq!(e(-1e6, f64::INFINITY, 1.0), 0.0);
    assert_eq!(e(-1e6, 1.0, 0.0), 0.0);
    assert_eq!(e(1.0, f64::INFINITY, 1.0), f64::INFINITY);
    assert_eq!(e(800.0, 0.0, 1.0).is_nan(), (800f64.exp() * 0.0).is_nan());
    assert!((e(-800.0, 1e300, 1.0) / (-800.0 + 300.0 * std::f64::consts::LN_10).exp() - 1.0).abs() < 1e-12);
    assert_eq!(e(f64::NEG_INFINITY, 1e300, 1e-300), 0.0);
    assert_eq!(e(f64::INFINITY, 1e-300, 1e300), f64::INFINITY);
    assert_eq!(e(2.0, 3.0, 5.0), (2f64.exp() * 3.0 / 5.0));
}

/// The denormal-result class: exp underflows before the divisions rescale it (the points were the pass's worst
/// well-conditioned ones before `scaled-exp`: Beckmann 18.9 bits, Ward 42.4 bits (→ 0)). Within 16 ulp at the
/// default budget: expmuldiv's common case is one range test (~1.15× these kernels, measured 2026-12-01), so the default 1.3× keeps it; with its cost model back at 40 this fails.
#[test]
fn scaled_exp_keeps_denormal_results() {
    for (stem, nl, nv, nh, m) in [
        ("beckmann", 0.5, 0.5, 3.773371444627538e-2, 0.9772191696069679),
        ("ward", 1.2276886869217682e-284, 5.740923431144541e-1, 4.420180284241315e-2, 0.7007159467187803),
    ] {
        let k = robust_kernel(stem, &[]);
        let f = load(stem);
        let mut p = k.default_params();
        p[f.param_index("m").unwrap()] = m;
        let x = at(nl, nv, nh, 0.7);
        let (v, t) = (k.eval(&x, &p), truth::eval(&f, &x, &p));
        assert!(t > 0.0 && t < 1e-300, "{stem}: the point no longer has a tiny true value: {t:e}");
        assert!(ulps(v, t) <= 16.0, "{stem}: {v:e} vs the truth {t:e}: {} ulp", ulps(v, t));
        assert!(ulps(plain_kernel(stem, &[]).eval(&x, &p), t) > 1000.0, "{stem}: the unrewritten form is no longer off here");
    }
}

/// GGX as BRDF Explorer users write it: Smith's G1 through tan² is ∞/∞ at grazing NL or NV (`smith-g1`), and
/// normalize(L + V) has a zero length when L ≈ −V at the horizon (`scaled-norm`). The unrewritten form is NaN at
/// both points (7,788 of 10⁵ domain points before); the pass's kernel is within 16 ulp of the truth.
#[test]
fn explorer_ggx_is_finite_at_grazing_angles() {
    let (f, plain, k) = explorer("ggx", PassOptions::default());
    let unit = |x: f64, y: f64, z: f64| {
        let s = ((1.0 - z * z) / (x * x + y * y)).sqrt();
        [x * s, y * s, z]
    };
    for (l, v, alpha, f0) in [
        (unit(-1.0, 0.0, 2.2250738585072014e-308), unit(0.14857266125057206, 0.9889014937439031, 6.789709752559824e-253), 0.001, 0.28),
        (unit(0.0, -1.0, 4.21490016269414e-309), unit(0.0, 1.0, 2.2250738585072014e-308), 0.8456125034439829, 0.83),
    ] {
        let x = lobe::numerics::inputs_from_dirs(l, v);
        let mut p = k.default_params();
        p[f.param_index("alpha").unwrap()] = alpha;
        p[f.param_index("f0").unwrap()] = f0;
        let t = truth::eval(&f, &x, &p);
        assert!(t.is_finite() && t > 0.0, "truth {t} at L = {l:?}, V = {v:?}");
        assert!(plain.eval(&x, &p).is_nan(), "the unrewritten form is no longer NaN at L = {l:?}, V = {v:?}");
        let got = k.eval(&x, &p);
        assert!(ulps(got, t) <= 16.0, "at L = {l:?}, V = {v:?}: {got} vs {t}");
    }
}

/// Cook–Torrance as BRDF Explorer users write it, at a facing pair (L ≈ −V, both a hair above the horizon):
/// normalize(L + V) has a zero length unless `scaled-norm` rescales it, and 1/(NL·NV) underflows unless a quotient
/// chain divides by each factor. With ior = 1 the Fresnel factor is 0 and so is the true value (with ior > 1 it
/// overflows there). Neither rule alone removes the NaN, so the pass keeps the quotient chains first and
/// scaled-norm on its second round (28 NaN-where-finite points of 10⁵ before that round, 0 after).
#[test]
#[ignore = "the truth's ~106 bits cannot see F = 0 at ior = 1 here (its 2⁻²¹² residue times 1/(NL·NV) ~ 10⁴⁸⁰ is ∞), so the pass keeps a form that is ∞ there; open until the truth carries more precision"]
fn explorer_cook_torrance_is_finite_at_facing_pairs() {
    // `lobe check`'s 10⁵ points: the compile step's default 4096 draw too few facing pairs to see the NaN.
    let (f, plain, k) = explorer("cook_torrance", PassOptions { points: 100_000, ..Default::default() });
    let (l, v) = ([9.09496204422576e-1, -4.157122251521212e-1, 1.2746267800070171e-222], [-9.09496204422576e-1, 4.157122251521212e-1, 1.3569653304466212e-259]);
    let x = lobe::numerics::inputs_from_dirs(l, v);
    for (m, ior, fresnel, masking) in [(0.4627329777033496, 1.0, 1.0, 0.0), (0.4627329777033496, 1.0, 1.0, 1.0), (0.05, 1.0, 1.0, 0.0)] {
        let mut p = k.default_params();
        for (name, val) in [("m", m), ("ior", ior), ("use_fresnel", fresnel), ("use_masking", masking)] {
            p[f.param_index(name).unwrap()] = val;
        }
        let t = truth::eval(&f, &x, &p);
        assert!(t.is_finite(), "truth {t} at m = {m}, ior = {ior}");
        assert!(!plain.eval(&x, &p).is_finite(), "the unrewritten form is no longer NaN/inf at m = {m}, ior = {ior}");
        let got = k.eval(&x, &p);
        assert!(ulps(got, t) <= 16.0, "m = {m}, ior = {ior}: {got} vs the truth {t}");
    }
}

/// The cancellation class, F_ST: pow(1 + n/a·(c − 1), a) amplifies its base's error a times. `compensated-base`
/// corrects the base by the rounding errors of the sum, of n/a·(c − 1) and of n/a and c − 1 (first order), so the
/// worst well-conditioned point (a = 640: 164 ulp as written, 16 ulp with the sum's error alone) is within a few
/// ulp, at the default budget.
#[test]
fn fst_base_errors_are_compensated_at_the_default_budget() {
    let f = load("fst");
    let k = robust_kernel("fst", &[]);
    let mut p = k.default_params();
    p[f.param_index("n").unwrap()] = 30.211601689291086;
    p[f.param_index("a").unwrap()] = 639.5475332731982;
    let x = at(0.5, 0.5, 2.4098850169856967e-1, 0.7);
    let t = truth::eval(&f, &x, &p);
    assert!(ulps(plain_kernel("fst", &[]).eval(&x, &p), t) > 100.0, "the written form is no longer off here");
    assert!(ulps(k.eval(&x, &p), t) <= 2.0, "{} vs the truth {t}", k.eval(&x, &p));
    let o = improve(&f, &[], &PassOptions { points: 20_000, ..Default::default() });
    assert!(o.trials.iter().any(|t| t.kept && t.rule.name() == "compensated-base"), "{:?}", o.trials);
    assert!(o.after.max_bits_well <= robust::TARGET_BITS && o.before.max_bits_well > 6.0, "{:?}", o.after);
}

/// `compensated-sum` on the quadratic model as written, A·c² + (1 − A)·c with A = 0.786·n: at n = 1000 and
/// c = 0.99874 the two terms (~786) cancel to 0.0066, and the written sum is ~80 000 ulp off (16.3 bits); with the
/// error terms of the sum and the products below it, within 2 ulp. (`factor-quadratic` is the cheaper fix the
/// pass takes; this checks the general rule on a known cancellation.)
#[test]
fn compensated_sum_removes_the_cancellation_error() {
    let sum = lobe::simplify::accuracy::rule("compensated-sum").unwrap();
    let f = lobe::simplify::simplify(&load("quadratic"), &[]);
    let x = at(0.5, 0.5, 9.987361468870581e-1, 0.7);
    let mut p = f.default_params();
    p[f.param_index("n").unwrap()] = 1000.0;
    let t = truth::eval(&f, &x, &p);
    let ev = |f: &Formula| lobe::backend::interp::Interp::new(f).eval(&x, &p);
    assert!(ulps(ev(&f), t) > 1000.0, "the written sum is no longer off here: {}", ulps(ev(&f), t));
    // The pass tries every site; the one at the cancelling sum is what fixes it.
    let best = (0..).map_while(|k| sum.apply_to(&f, Some(k))).map(|g| ulps(ev(&g), t)).fold(f64::INFINITY, f64::min);
    assert!(best <= 2.0, "compensated-sum leaves {best} ulp");
}

/// `lobe check --set` and `lobe eval --set` describe the same kernel: the check searches on the commands' sample
/// with their options, so the form it prints is the one a compile chooses — searched again without a cache, or
/// replayed from the decision the check stored. F_dsh at the value an audit found it differing at, and random
/// catalogue and explorer files at random parameter values (seeded), baked and live.
#[test]
fn check_and_eval_describe_the_same_kernel() {
    use lobe::numerics::pass_cache::Cache;
    let dir = std::env::temp_dir().join(format!("lobe-check-eval-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cache = Arc::new(Cache::at(&dir));
    let mut cases: Vec<(String, Vec<(String, f64)>)> = vec![("brdfs/dsh".into(), vec![("n".into(), 44.157180060974795)])];
    let mut r = lobe::base::rng::Rng(0x0c0e);
    for stem in ["brdfs/kutlog", "brdfs/fst", "brdfs/cook_torrance", "explorer/ggx", "explorer/ward_anisotropic"] {
        let path = format!("{}/examples/{stem}.brdf", env!("CARGO_MANIFEST_DIR"));
        let f = lobe::front::parse(&path, &std::fs::read_to_string(&path).unwrap()).unwrap();
        let mut set = vec![];
        for d in &f.params {
            let (pick, u) = (r.unit(), r.unit());
            if pick < 0.7 {
                set.push((d.name.clone(), d.lo + u * (d.hi - d.lo)));
            }
        }
        cases.push((stem.into(), set));
        cases.push((stem.into(), vec![]));
    }
    for (stem, set) in cases {
        let path = format!("{}/examples/{stem}.brdf", env!("CARGO_MANIFEST_DIR"));
        let f = lobe::front::parse(&path, &std::fs::read_to_string(&path).unwrap()).unwrap();
        let pass = PassOptions::default();
        let c = lobe::numerics::check::check(&f, &set, &pass, 2000, Some(&*cache), &|_| {}).unwrap();
        assert!(!c.pass.truncated, "{stem}");
        let opts = Options { backend: Backend::Interp, bake: set.clone(), ..Default::default() };
        let searched = lobe::compile_formula(f.clone(), &robust::with_pass(opts.clone(), pass)).unwrap();
        let replayed = lobe::compile_formula(f.clone(), &robust::with_pass_cached(opts, pass, Some(cache.clone()))).unwrap();
        let shown = c.pass.formula.to_program_text();
        assert_eq!(searched.formula.to_program_text(), shown, "{stem} {set:?}: searched again");
        assert_eq!(replayed.formula.to_program_text(), shown, "{stem} {set:?}: replayed");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Baked = live within 4 ulp wherever the value is well conditioned (κ ≤ 16), at random parameter values of
/// every catalogue file (seeded, uniform and log-uniform over the declared ranges) and at the F_dsh value an
/// audit found the baked pass dropping the live choice at (n = 44.157180060974795, 5.6e14 ulp apart).
#[test]
fn baked_equals_live_at_random_values() {
    let stems = catalogue_stems();
    let mut r = lobe::base::rng::Rng(0xba4ed);
    let mut sets: Vec<(String, Vec<(usize, f64)>)> = vec![("dsh".into(), vec![(0, 44.157180060974795)])];
    for stem in &stems {
        let f = load(stem);
        for _ in 0..3 {
            let set = f.params.iter().enumerate().map(|(i, d)| {
                let (u, v) = (r.unit(), r.unit());
                let x = if u < 0.5 || d.lo <= 0.0 { d.lo + v * (d.hi - d.lo) } else { d.lo * (d.hi / d.lo).powf(v) };
                (i, if d.kind == lobe::ir::ParamKind::Bool { x.round() } else { x })
            });
            sets.push((stem.clone(), set.collect()));
        }
    }
    for (stem, bake) in sets {
        let f = load(&stem);
        assert_eq!(f.params[0].name, "n", "{stem}");
        let live = robust_kernel(&stem, &[]);
        let set: Vec<(&str, f64)> = bake.iter().map(|&(i, v)| (f.params[i].name.as_str(), v)).collect();
        let k = robust_kernel(&stem, &set);
        let truth_f = lobe::simplify::bake_only(&f, &bake);
        for pt in sample(&f, &bake, 10_000, 3) {
            let (a, b) = (live.eval(&pt.x, &pt.p), k.eval(&pt.x, &pt.p));
            if a.is_finite() && b.is_finite() && ulps(a, b) > 4.0 {
                let t = truth::eval(&truth_f, &pt.x, &pt.p);
                let kappa = robust::condition_ulps(&truth_f, &pt, t);
                assert!(kappa > robust::ILL_CONDITIONED_ULPS, "{stem} {set:?}: baked {b} and live {a} differ by {} ulp at {pt:?} (condition {kappa} ulps)", ulps(a, b));
            }
        }
    }
}

/// `lobe check --math fast` states fast math's error per formula over the declared parameter ranges, not at the
/// defaults only: Gaussian's exp(−n·acos²/2) amplifies fast acos's error with n, so over n ∈ 1..1000 it exceeds
/// what n = 50 gives; precise math reports nothing; an arithmetic formula differs nowhere.
#[test]
fn fast_math_error_is_measured_over_the_declared_ranges() {
    let fast = PassOptions { math: lobe::Mode::Fast, ..PassOptions::default() };
    let gauss = load("gaussian");
    let over_ranges = lobe::numerics::check::check(&gauss, &[], &fast, 20_000, None, &|_| {}).unwrap().fast_vs_precise.unwrap();
    let at_50 = lobe::numerics::check::check(&gauss, &[("n".into(), 50.0)], &fast, 20_000, None, &|_| {}).unwrap().fast_vs_precise.unwrap();
    assert!(over_ranges.max_rel > 4.0 * at_50.max_rel && over_ranges.max_rel < 1e-4, "{over_ranges:?} vs {at_50:?}");
    let (pt, _, _) = over_ranges.at.clone().unwrap();
    assert!(pt.p[0] > 100.0, "the worst point is at a large n: {pt:?}");
    assert_eq!(over_ranges.nonfinite, 0);
    assert!(lobe::numerics::check::check(&gauss, &[], &PassOptions::default(), 2000, None, &|_| {}).unwrap().fast_vs_precise.is_none());
    let arith = lobe::numerics::check::check(&load("schlick"), &[], &fast, 5000, None, &|_| {}).unwrap().fast_vs_precise.unwrap();
    assert_eq!((arith.max_rel, arith.max_abs_vs_peak), (0.0, 0.0));
}
