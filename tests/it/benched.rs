//! The benches time the shipped catalogue: every formula of `benches/common/formulas.rs` is a file
//! `examples/brdfs/<stem>.brdf` with a Rust twin, and its bench-only fasteval spelling evaluates to the
//! compiled file, so that the fasteval contestant cannot drift from the function the others compute.

#[path = "../../benches/common/formulas.rs"]
mod bench_formulas;

use bench_formulas::BENCHED;
use lobe::{Backend, Evaluator, N_INPUTS};

#[test]
fn every_bench_formula_is_a_catalogue_file_with_a_twin() {
    for e in BENCHED {
        assert!(e.path().is_file(), "bench formula {}: no file {}", e.stem, e.path().display());
        assert!(lobe::numerics::twins::def(e.stem).is_some(), "bench formula {}: no Rust twin", e.stem);
    }
    let mut ids: Vec<&str> = BENCHED.iter().map(|e| e.id).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), BENCHED.len(), "two bench formulas share a criterion id");
}

/// On a grid of cosines in [0, 1] (every input, so an input the spelling reads by the wrong name shows) and
/// each parameter at its lower bound, default and upper bound: within 1e-12 relative (so exactly 0 where the
/// catalogue formula is 0, as beyond the zero of F_SCOS2 and F_ST).
#[test]
fn fasteval_spellings_evaluate_to_the_catalogue_formulas() {
    use fasteval::Evaler;
    const STEPS: usize = 24;
    let grid: Vec<[f64; N_INPUTS]> = (0..=STEPS)
        .map(|i| {
            let t = i as f64 / STEPS as f64;
            lobe::from_cosines([t, 1.0 - t, t, (t * 3.0).fract(), (t * 7.0).fract()])
        })
        .chain((0..=STEPS).map(|i| lobe::from_cosines([0.5, 0.5, 1.0 - (i as f64 / STEPS as f64).powi(4), 1.0 - i as f64 / STEPS as f64, 0.5])))
        .collect();
    for e in BENCHED {
        let k = e.kernel(Backend::Interp);
        let (slab, compiled) = e.fasteval().unwrap_or_else(|err| panic!("{}: fasteval cannot parse: {err}", e.stem));
        let defaults = k.default_params();
        let mut sets = vec![defaults.clone()];
        for (i, p) in k.formula.params.iter().enumerate() {
            for v in [p.lo, p.hi] {
                let mut s = defaults.clone();
                s[i] = v;
                sets.push(s);
            }
        }
        for ps in &sets {
            for x in &grid {
                let want = k.eval(x, ps);
                let mut ns = |name: &str, _: Vec<f64>| bench_formulas::fasteval_var(name, x, &k, ps);
                let got = compiled.eval(&slab, &mut ns).unwrap_or_else(|err| panic!("{}: {err}", e.stem));
                assert!(
                    (got - want).abs() <= 1e-12 * want.abs().max(got.abs()),
                    "{} at {x:?}, params {ps:?}: fasteval {got:e}, catalogue {want:e}",
                    e.stem
                );
            }
        }
    }
}
