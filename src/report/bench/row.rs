//! Measuring one row of the bench table: a formula at the benchmark values in one math mode, its two kernels
//! (the accuracy pass's choice and the plain simplification) timed and measured against the truth, its
//! distance from the reference lobe, its energy, and, when asked, the two tiers' batched kernels side by side.
//! Any front end builds a row here (the `lobe` command, the Python module); the front end only chooses the
//! formulas and words the table.

use super::{BenchRow, PlainKernel, TierColumns};
use crate::base::diag::{Diagnostic, Diagnostics};
use crate::numerics::accuracy::{accuracy, AccuracyOptions};
use crate::numerics::robust::{self, Conditioning, Reference};
use crate::numerics::{choose_lobe_input, energy};
use crate::report::measure::{measure_kernel, sample_points, time_batched, MeasureOptions};
use crate::{Backend, Evaluator, Formula, Kernel, Options};
use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// What a row measures beside the formula.
#[derive(Clone, Copy, Debug)]
pub struct RowOptions {
    /// Points per timed pass and timed samples per path.
    pub measure: MeasureOptions,
    /// Time the LLVM tier's batched kernel beside Cranelift's ([`TierColumns`]); needs a build with the tier.
    pub tiers: bool,
    /// Measure the full-geometry albedo (the slowest column).
    pub albedo: bool,
}

/// Domain points (and their seed) on which both kernels of a row are measured against the truth.
const ERROR_POINTS: usize = 4096;
const ERROR_SEED: u64 = 0xBE4C;

/// One row: `f` (read from `path`, which names the row and finds its hand-written twin) with the parameter
/// values `set` (those it does not declare are ignored), in math mode `math`, against the `reference` lobe.
pub fn bench_row(f: &Formula, path: &str, set: &[(String, f64)], reference: &Kernel, math: crate::Mode, o: &RowOptions) -> Result<BenchRow, Diagnostics> {
    let set: Vec<(String, f64)> = set.iter().filter(|(k, _)| f.param_index(k).is_some()).cloned().collect();
    let mut params = f.default_params();
    for (k, v) in &set {
        if let Some(i) = f.param_index(k) {
            params[i] = *v;
        }
    }
    let fail = |what: String| Diagnostics::single(path, Diagnostic::error(what));
    let timing = |k: &Kernel| measure_kernel(k, &params, o.measure).map_err(|e| fail(e.to_string()));
    // The two kernels of the formula at the benchmark values: the plain simplification and the accuracy pass's
    // choice (what eval, render and the other commands compile). The row's columns describe the pass's kernel;
    // `plain_*` the plain one, each timed and measured against the truth in the row's math mode.
    let plain = crate::compile_formula(f.clone(), &Options { backend: Backend::Jit, bake: set.clone(), math, ..Options::default() })?;
    let bake = crate::resolve_bake(f, &set)?;
    let started = Instant::now();
    let pass = robust::improve(f, &bake, &Default::default());
    let pass_ms = started.elapsed().as_secs_f64() * 1e3;
    let kernel = crate::build_kernel(Arc::new(pass.formula.clone()), Backend::Jit, math)?;
    let truth_f = crate::simplify::bake_only(f, &bake);
    let truth = Reference::new(&truth_f, robust::sample(f, &bake, ERROR_POINTS, ERROR_SEED));
    let (err, plain_err) = (truth.measure(&kernel, Conditioning::Everywhere), truth.measure(&plain, Conditioning::Everywhere));
    let m = timing(&kernel)?;
    let mp = timing(&plain)?;
    let tiers = if o.tiers { Some(tier_columns(&kernel, &params, o.measure, path)?) } else { None };
    let stem = Path::new(path).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let native_ns = crate::numerics::twins::by_stem(&stem).map(|t| time_twin(t.ev.as_ref(), &params, o.measure.samples));
    // The model's distance from the reference lobe over n = 1..1000 (live n): a property of the formula, and
    // one only where both read n (a formula that reads none would be one fixed lobe against a thousand): NaN
    // (shown as —) otherwise, and where the sweep fails.
    let live = crate::compile_formula(f.clone(), &Options { backend: Backend::Jit, math, ..Options::default() })?;
    let (lobe, _) = choose_lobe_input(live.used_inputs());
    let (ref_lobe, _) = choose_lobe_input(reference.used_inputs());
    let swept = f.reads_param("n") && reference.formula.reads_param("n");
    let acc = swept.then(|| accuracy(&live, &params, lobe, reference, &reference.default_params(), ref_lobe, &AccuracyOptions::default()).ok()).flatten();
    let (mean_abs_grid, epi, max_abs) = match &acc {
        Some(r) => (r.mean_abs_grid, r.epicenter.value * 100.0, r.max_abs.value),
        None => (f64::NAN, f64::NAN, f64::NAN),
    };
    // The lobe normalisation coefficient: a one-cosine lobe's only (of anything else it is not the energy).
    let coef_n50 = crate::numerics::one_lobe_cosine(kernel.used_inputs()).and_then(|c| energy::normalization_coef(&kernel, &params, c).ok());
    let albedo_max = if o.albedo { energy::full_energy_for(&kernel, kernel.used_inputs(), &params).ok().map(|e| e.albedo_max) } else { None };
    let (max_ulp_vs_precise, max_rel_vs_precise) = error_vs_precise(&kernel, &params);
    Ok(BenchRow {
        name: f.display_name(),
        file: path.to_string(),
        math: math.name().to_string(),
        max_ulp_vs_precise,
        max_rel_vs_precise,
        compile_us: m.compile.as_secs_f64() * 1e6,
        pass_ms,
        jit_ns: m.scalar_jit.median_ns,
        jit_spread: m.scalar_jit.spread(),
        jit_batch_ns: m.batched_jit.median_ns,
        interp_ns: m.interp.median_ns,
        native_ns,
        mean_abs_grid,
        epicenter_max_rel_pct: epi,
        max_abs,
        coef_n50,
        albedo_max,
        bits_error_avg: err.avg_bits,
        bits_error_max: err.max_bits,
        plain: PlainKernel {
            jit_ns: mp.scalar_jit.median_ns,
            jit_spread: mp.scalar_jit.spread(),
            jit_batch_ns: mp.batched_jit.median_ns,
            bits_error_avg: plain_err.avg_bits,
            bits_error_max: plain_err.max_bits,
        },
        pareto: false,
        tiers,
    })
}

/// Cranelift's and LLVM's batched kernels of `baked`'s formula, timed on the same points, and their compile
/// times (median of three compiles each).
fn tier_columns(baked: &Kernel, params: &[f64], opts: MeasureOptions, path: &str) -> Result<TierColumns, Diagnostics> {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let f = &baked.formula;
    let mut cl = vec![];
    let mut ll = vec![];
    let mut llvm = None;
    for _ in 0..3 {
        let t = Instant::now();
        let j = crate::backend::jit::jit_kernel_uncached(f, baked.math).map_err(|e| Diagnostics::single(path, Diagnostic::error(e.to_string())))?;
        Evaluator::warm_up(&j);
        cl.push(t.elapsed().as_secs_f64() * 1e3);
        let k = crate::build_kernel(f.clone(), Backend::Llvm, baked.math)?;
        ll.push(k.compile_time.as_secs_f64() * 1e3);
        llvm = Some(k);
    }
    let llvm = llvm.ok_or_else(|| Diagnostics::single(path, Diagnostic::error("no LLVM kernel")))?;
    Ok(TierColumns {
        cranelift_batch_ns: time_batched(baked, params, opts).median_ns,
        llvm_batch_ns: time_batched(&llvm, params, opts).median_ns,
        llvm_lanes: crate::Tier::llvm_lanes().unwrap_or(0),
        cranelift_compile_ms: median(cl),
        llvm_compile_ms: median(ll),
        points: opts.points,
    })
}

/// Median ns/eval of a hand-written Rust twin over the same points the JIT is timed on, called through the
/// same prepared `Evaluator` path as the JIT kernel (so the comparison is of the code, not of the call path).
fn time_twin(ev: &dyn Evaluator, params: &[f64], samples: usize) -> f64 {
    let pts = sample_points(4096, 0x5EED);
    let ev = ev.prepare(params);
    let mut ns: Vec<f64> = (0..samples.max(1) + 1)
        .map(|_| {
            let t = Instant::now();
            let mut acc = 0.0;
            for p in &pts {
                acc += ev.eval(black_box(p));
            }
            black_box(acc);
            t.elapsed().as_nanos() as f64 / pts.len() as f64
        })
        .skip(1)
        .collect();
    ns.sort_by(f64::total_cmp);
    ns[ns.len() / 2]
}

/// The largest (ulps, relative) distance of `kernel`'s batched values from the precise interpreter's over the
/// timed points (NaN on one side only counts as infinitely far).
fn error_vs_precise(kernel: &Kernel, params: &[f64]) -> (f64, f64) {
    let pts = sample_points(4096, 0x5EED);
    let cols: Vec<Vec<f64>> = (0..crate::N_INPUTS).map(|i| pts.iter().map(|r| r[i]).collect()).collect();
    let columns = crate::Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut got: Vec<f64> = vec![0.0; pts.len()];
    Evaluator::eval_batch(kernel, &columns, params, &mut got);
    let reference = crate::backend::interp::Interp::with_mode(&kernel.formula, crate::Mode::Precise);
    let mut worst = (0.0f64, 0.0f64);
    for (p, g) in pts.iter().zip(&got) {
        let want = Evaluator::eval(&reference, p, params);
        let (u, r) = if want.is_nan() && g.is_nan() || want == *g {
            (0.0, 0.0)
        } else if !want.is_finite() || !g.is_finite() {
            (f64::INFINITY, f64::INFINITY)
        } else {
            (robust::ulps(*g, want), (g - want).abs() / want.abs().max(f64::MIN_POSITIVE))
        };
        worst = (worst.0.max(u), worst.1.max(r));
    }
    worst
}
