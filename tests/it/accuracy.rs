//! Accuracy, fit and sweep through the public API on interpreter kernels, twins, and the catalogue files.

use crate::energy::power_lobe;
use lobe::numerics::accuracy::{accuracy, AccuracyOptions};
use lobe::numerics::sweep::{sweep, SweepOptions};
use crate::fixtures::published;
use lobe::numerics::twins;
use lobe::ir::Input;
use lobe::{build_kernel, Backend};
use std::sync::Arc;

#[test]
fn batched_interpreter_matches_scalar_twin() {
    // Interp::eval_batch (the batched path) against the Rust twin: identical metrics.
    let k = build_kernel(Arc::new(power_lobe(Input::NH)), Backend::Interp, lobe::Mode::Precise).unwrap();
    let s = twins::schlick();
    let opts = AccuracyOptions { n_max: 60, ..Default::default() };
    let a = accuracy(s.ev.as_ref(), &[1.0], Input::NH, &k, &[1.0], Input::NH, &opts).unwrap();
    let b = accuracy(s.ev.as_ref(), &[1.0], Input::NH, twins::blinn().ev.as_ref(), &[1.0], Input::NH, &opts).unwrap();
    // The kernel's pow is lobe's (≤ 1 ulp), the twin's libm's: the metrics agree to rounding, at the same places.
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-13 * y.abs().max(1e-300);
    assert!(close(a.mean_abs_grid, b.mean_abs_grid) && close(a.max_abs.value, b.max_abs.value));
    assert_eq!((a.max_abs.n, a.max_abs.angle_deg, a.epicenter.n), (b.max_abs.n, b.max_abs.angle_deg, b.epicenter.n));
    for (x, y) in a.max_abs_per_n.iter().zip(&b.max_abs_per_n) {
        assert!(x.0 == y.0 && close(x.1, y.1) && x.2 == y.2, "{x:?} vs {y:?}");
    }
}

#[test]
fn published_error_rows_keep_their_verdicts() {
    for row in published::TABLE.iter().filter(|r| !matches!(r.quantity, published::Quantity::Coef(..))) {
        let c = published::compute(&row.quantity).unwrap();
        assert_eq!(published::verdict(row.published, row.kind, c), row.verdict, "{}: computed {c}", row.what);
    }
}

#[test]
fn sweep_of_the_clamped_kernel_is_clean() {
    // Blinn with the lowering's clamps: no NaN, inf or negative anywhere, including negative and >1 cosines.
    let f = power_lobe(Input::NH);
    let k = build_kernel(Arc::new(f.clone()), Backend::Interp, lobe::Mode::Precise).unwrap();
    let r = sweep(&k, f.used_inputs(), &f.params, &SweepOptions::default());
    assert_eq!((r.total.nan, r.total.inf, r.total.negative), (0, 0, 0));
    assert!(r.regions.iter().any(|s| s.region == "negative" && s.evaluated > 0));
}

#[test]
fn catalogue_modified_schlick_reproduces_mean_error() {
    let dir = format!("{}/examples/brdfs", env!("CARGO_MANIFEST_DIR"));
    let load = |name: &str| {
        let path = format!("{dir}/{name}.brdf");
        let src = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        lobe::compile_source(&path, &src, &lobe::Options { backend: Backend::Jit, ..Default::default() })
            .unwrap_or_else(|d| panic!("{}", d.render(false)))
    };
    let (ms, b) = (load("modified_schlick"), load("blinn"));
    let r = accuracy(&ms, &ms.default_params(), Input::NH, &b, &b.default_params(), Input::NH, &AccuracyOptions::default()).unwrap();
    assert!((r.mean_abs_grid - 0.006554934).abs() < 1e-8, "{}", r.mean_abs_grid);
}
