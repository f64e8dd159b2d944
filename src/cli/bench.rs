//! `lobe bench [FILES…] [--reference blinn.brdf] [--set n=50] [--json] [--plot speed_error.png]`
//!
//! Speed against error, in one run: for each formula its compile time, ns/eval on the scalar JIT, the batched
//! JIT and the interpreter (and hand-written Rust where lobe has a twin), its error against the reference on
//! the papers' grid, and its energy at the benchmark n. The table is sorted by cost with the Pareto front
//! marked; `--plot` draws cost against error. With the LLVM tier in the build (`--tier auto`, the default, or
//! `--tier llvm`), a second table times Cranelift's and LLVM's batched kernels side by side on the same points
//! (`--timing-points`), with each tier's compile time.

use super::args::{self, Force, Json, Params};
use super::common::{self, CliError};
use lobe::numerics::accuracy::{accuracy, AccuracyOptions};
use lobe::numerics::robust::{self, Conditioning, Reference};
use lobe::numerics::{choose_lobe_input, energy};
use lobe::report::measure::{measure_kernel, sample_points, MeasureOptions};
use lobe::report::bench::{self, BenchRow};
use lobe::report::plot::{self, CostError, Format};
use lobe::{Backend, Formula, Options};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values for the timing and energy columns (the error columns sweep n over 1..1000)")))]
#[command(mut_arg("json", args::help("Print a JSON list of objects instead of the table")))]
pub struct BenchArgs {
    /// Formula files (default: every examples/brdfs/*.brdf).
    pub files: Vec<String>,
    /// The reference lobe for the error columns.
    #[arg(long, default_value = "examples/brdfs/blinn.brdf")]
    pub reference: String,
    #[command(flatten)]
    pub set: Params,
    /// Timed samples per path (the median and quartiles are reported).
    #[arg(long, default_value_t = 31)]
    pub samples: usize,
    #[command(flatten)]
    pub json: Json,
    /// Write a cost-versus-error scatter plot (.png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Skip the full-geometry albedo column (the slowest check).
    #[arg(long)]
    pub no_albedo: bool,
    /// Math mode of the timed kernels: `precise`, `fast`, or `both` (two rows per formula; the plot shows
    /// what fast math buys).
    #[arg(long = "math", value_name = "MODE", default_value = "precise", value_parser = ["precise", "fast", "both"])]
    pub math: String,
    #[command(flatten)]
    pub force: Force,
    /// Batched tiers to time: `auto` (Cranelift, and LLVM when this build has it), `llvm` (both; an error in a
    /// build without `--features llvm`) or `cranelift` (Cranelift only).
    #[arg(long = "tier", value_name = "TIER", default_value = "auto")]
    pub tier: lobe::Tier,
    /// Points per timed pass (every timing column).
    #[arg(long = "timing-points", value_name = "N", default_value_t = 4096, value_parser = clap::value_parser!(u64).range(1..=1 << 26))]
    pub timing_points: u64,
}

impl BenchArgs {
    /// Whether to time the LLVM tier.
    fn llvm(&self) -> Result<bool, CliError> {
        match self.tier {
            lobe::Tier::Cranelift => Ok(false),
            lobe::Tier::Auto => Ok(lobe::Tier::llvm_available()),
            lobe::Tier::Llvm if lobe::Tier::llvm_available() => Ok(true),
            lobe::Tier::Llvm => Err(CliError::Error(lobe::llvm_missing())),
        }
    }

    fn measure(&self) -> MeasureOptions {
        MeasureOptions { points: self.timing_points as usize, samples: self.samples }
    }
}

/// Cranelift's and LLVM's batched kernels of `baked`'s formula, timed on the same points, and their compile
/// times (median of three compiles each).
fn tier_columns(baked: &lobe::Kernel, params: &[f64], a: &BenchArgs) -> Result<bench::TierColumns, CliError> {
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
        let j = lobe::backend::jit::jit_kernel_uncached(f, baked.math).map_err(|e| CliError::msg(e.to_string()))?;
        lobe::Evaluator::warm_up(&j);
        cl.push(t.elapsed().as_secs_f64() * 1e3);
        let k = lobe::build_kernel(f.clone(), Backend::Llvm, baked.math)?;
        ll.push(k.compile_time.as_secs_f64() * 1e3);
        llvm = Some(k);
    }
    let llvm = llvm.ok_or_else(|| CliError::msg("no LLVM kernel"))?;
    let opts = a.measure();
    Ok(bench::TierColumns {
        cranelift_batch_ns: lobe::report::measure::time_batched(baked, params, opts).median_ns,
        llvm_batch_ns: lobe::report::measure::time_batched(&llvm, params, opts).median_ns,
        llvm_lanes: lobe::Tier::llvm_lanes().unwrap_or(0),
        cranelift_compile_ms: median(cl),
        llvm_compile_ms: median(ll),
        points: opts.points,
    })
}

fn catalogue() -> Result<Vec<String>, CliError> {
    let dir = Path::new("examples/brdfs");
    let rd = std::fs::read_dir(dir).map_err(|e| {
        CliError::hint(format!("cannot list {}: {e}", dir.display()), "run from the lobe checkout, or name the files to benchmark")
    })?;
    let mut v: Vec<String> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
        .map(|p| p.display().to_string())
        .collect();
    v.sort();
    Ok(v)
}

/// Median ns/eval of a hand-written Rust twin over the same points the JIT is timed on, called through the
/// same prepared `Evaluator` path as the JIT kernel (so the comparison is of the code, not of the call path).
fn time_twin(ev: &dyn lobe::Evaluator, params: &[f64], samples: usize) -> f64 {
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
fn error_vs_precise(kernel: &lobe::Kernel, params: &[f64]) -> (f64, f64) {
    let pts = sample_points(4096, 0x5EED);
    let cols: Vec<Vec<f64>> = (0..lobe::N_INPUTS).map(|i| pts.iter().map(|r| r[i]).collect()).collect();
    let columns = lobe::Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut got: Vec<f64> = vec![0.0; pts.len()];
    lobe::Evaluator::eval_batch(kernel, &columns, params, &mut got);
    let reference = lobe::backend::interp::Interp::with_mode(&kernel.formula, lobe::Mode::Precise);
    let mut worst = (0.0f64, 0.0f64);
    for (p, g) in pts.iter().zip(&got) {
        let want = lobe::Evaluator::eval(&reference, p, params);
        let (u, r) = if want.is_nan() && g.is_nan() || want == *g {
            (0.0, 0.0)
        } else if !want.is_finite() || !g.is_finite() {
            (f64::INFINITY, f64::INFINITY)
        } else {
            (lobe::numerics::robust::ulps(*g, want), (g - want).abs() / want.abs().max(f64::MIN_POSITIVE))
        };
        worst = (worst.0.max(u), worst.1.max(r));
    }
    worst
}

fn row(
    f: &Formula,
    path: &str,
    set: &[(String, f64)],
    reference: &lobe::Kernel,
    a: &BenchArgs,
    math: lobe::Mode,
) -> Result<BenchRow, CliError> {
    let set = common::set_for(f, set);
    let params = common::param_values(f, &set);
    let timing = |k: &lobe::Kernel| measure_kernel(k, &params, a.measure()).map_err(|e| CliError::msg(format!("{path}: {e}")));
    // The two kernels of the formula at the benchmark values: the plain simplification and the accuracy pass's
    // choice (what eval, render and the other commands compile). The row's columns describe the pass's kernel;
    // `plain_*` the plain one, each timed and measured against the truth in the row's math mode.
    let plain = lobe::compile_formula(f.clone(), &Options { backend: Backend::Jit, bake: set.clone(), math, ..Options::default() })?;
    let bake = lobe::resolve_bake(f, &set)?;
    let started = Instant::now();
    let pass = lobe::numerics::robust::improve(f, &bake, &Default::default());
    let pass_ms = started.elapsed().as_secs_f64() * 1e3;
    let kernel = lobe::build_kernel(std::sync::Arc::new(pass.formula.clone()), Backend::Jit, math)?;
    let truth_f = lobe::simplify::bake_only(f, &bake);
    let truth = Reference::new(&truth_f, robust::sample(f, &bake, ERROR_POINTS, ERROR_SEED));
    let (err, plain_err) = (truth.measure(&kernel, Conditioning::Everywhere), truth.measure(&plain, Conditioning::Everywhere));
    let m = timing(&kernel)?;
    let mp = timing(&plain)?;
    let tiers = if a.llvm()? { Some(tier_columns(&kernel, &params, a)?) } else { None };
    let stem = Path::new(path).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let native_ns = lobe::numerics::twins::by_stem(&stem).map(|t| time_twin(t.ev.as_ref(), &params, a.samples));
    // The model's distance from the reference lobe over n = 1..1000 (live n): a property of the formula.
    let live = lobe::compile_formula(f.clone(), &Options { backend: Backend::Jit, math, ..Options::default() })?;
    let (lobe, _) = choose_lobe_input(live.used_inputs());
    let (ref_lobe, _) = choose_lobe_input(reference.used_inputs());
    let acc = accuracy(&live, &params, lobe, reference, &reference.default_params(), ref_lobe, &AccuracyOptions::default());
    let (mean_abs_grid, epi, max_abs) = match &acc {
        Ok(r) => (r.mean_abs_grid, r.epicenter.value * 100.0, r.max_abs.value),
        Err(_) => (f64::NAN, f64::NAN, f64::NAN),
    };
    let coef_n50 = energy::normalization_coef(&kernel, &params, lobe).ok();
    let albedo_max = if a.no_albedo { None } else { energy::full_energy_for(&kernel, kernel.used_inputs(), &params).ok().map(|e| e.albedo_max) };
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
        plain: bench::PlainKernel {
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

/// Domain points (and their seed) on which both kernels of a row are measured against the truth.
const ERROR_POINTS: usize = 4096;
const ERROR_SEED: u64 = 0xBE4C;

pub fn run(a: &BenchArgs) -> Result<(), CliError> {
    // Before any work: `--tier llvm` in a build without the LLVM tier is an error.
    a.llvm()?;
    let files = if a.files.is_empty() { catalogue()? } else { a.files.clone() };
    let set: Vec<(String, f64)> = {
        let s = a.set.list()?;
        if s.iter().any(|(k, _)| k == "n") {
            s
        } else {
            [vec![("n".to_string(), 50.0)], s].concat()
        }
    };
    let plot_format = match &a.plot {
        Some(p) => Some(Format::from_path(p).map_err(|e| CliError::hint(e, "use --plot speed_error.png or .svg"))?),
        None => None,
    };
    let formulas = files.iter().map(|p| common::load_formula(Some(p), None)).collect::<Result<Vec<_>, _>>()?;
    common::check_set_names(&formulas.iter().collect::<Vec<_>>(), &set)?;
    let reference = common::load_kernel(Some(&a.reference), None, &[], Backend::Jit, lobe::Mode::Precise)?;
    let mut rows = Vec::new();
    let progress = !a.json.on && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let modes = match a.math.as_str() {
        "fast" => vec![lobe::Mode::Fast],
        "both" => vec![lobe::Mode::Precise, lobe::Mode::Fast],
        _ => vec![lobe::Mode::Precise],
    };
    // A colour formula is measured channel by channel: one row per channel, named `NAME (red)` etc.; its cost
    // is the sum of its rows.
    let channels: Vec<_> = formulas.iter().zip(&files).flat_map(|(f, p)| f.named_channels().into_iter().map(move |c| (c, p))).collect();
    for (f, path) in &channels {
        let (f, path) = (f, *path);
        for &math in &modes {
            if progress {
                eprint!("\rmeasuring {:<40}", format!("{} ({math})", f.display_name()));
            }
            rows.push(row(f, path, &set, &reference, a, math)?);
        }
    }
    if progress {
        eprint!("\r{:<52}\r", "");
    }
    bench::mark_pareto(&mut rows);
    if a.json.on {
        println!("{}", serde_json::to_string_pretty(&rows).map_err(|e| CliError::msg(e.to_string()))?);
    } else {
        let n = set.iter().find(|(k, _)| k == "n").map(|(_, v)| *v).unwrap_or(50.0);
        println!("lobe bench — {} formulas, timings at n = {n} (baked), errors vs {} over n = 1..1000", rows.len(), a.reference);
        println!("machine: {}; timings single-threaded, median of {} samples of {} points", bench::machine(), a.samples, a.timing_points);
        print!("{}", bench::table(&rows));
        print!("{}", bench::tiers_table(&rows));
    }
    if let (Some(path), Some(format)) = (&a.plot, plot_format) {
        let pts: Vec<CostError> = rows
            .iter()
            .map(|r| CostError {
                name: if modes.len() > 1 { format!("{} ({})", r.name, r.math) } else { r.name.clone() },
                cost: r.jit_ns,
                error: r.mean_abs_grid,
                pareto: r.pareto,
                series: r.math.clone(),
            })
            .collect();
        let bytes = plot::speed_error(&pts, "Speed against error", "scalar JIT ns/eval (log)", "mean |Δ| vs reference (log)", format)
            .map_err(CliError::msg)?;
        a.force.write(path, &bytes, common::is_lobe_output)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
