//! `lobe bench [FILES…] [--reference blinn.brdf] [--set n=50] [--json] [--plot speed_error.png]`
//!
//! Speed against error, in one run: for each formula its compile time, ns/eval on the scalar JIT, the batched
//! JIT and the interpreter (and hand-written Rust where lobe has a twin), its error against the reference on
//! the papers' grid, and its energy at the benchmark n. The table is sorted by cost with the Pareto front
//! marked; `--plot` draws cost against error.

use super::args::{self, Force, Json, Params};
use super::common::{self, CliError};
use crate::numerics::accuracy::{accuracy, AccuracyOptions};
use crate::numerics::{choose_lobe_input, energy};
use crate::report::measure::{measure_kernel, sample_points, MeasureOptions};
use crate::report::bench::{self, BenchRow};
use crate::report::plot::{self, CostError, Format};
use crate::{Backend, Formula, Options};
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
    #[command(flatten)]
    pub force: Force,
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
/// same `Evaluator` interface as the JIT kernel (so the comparison is of the code, not of the call path).
fn time_twin(ev: &dyn crate::Evaluator, params: &[f64], samples: usize) -> f64 {
    let pts = sample_points(4096, 0x5EED);
    let mut ns: Vec<f64> = (0..samples.max(1) + 1)
        .map(|_| {
            let t = Instant::now();
            let mut acc = 0.0;
            for p in &pts {
                acc += ev.eval(black_box(p), black_box(params));
            }
            black_box(acc);
            t.elapsed().as_nanos() as f64 / pts.len() as f64
        })
        .skip(1)
        .collect();
    ns.sort_by(f64::total_cmp);
    ns[ns.len() / 2]
}

fn row(f: &Formula, path: &str, set: &[(String, f64)], reference: &crate::Kernel, a: &BenchArgs) -> Result<BenchRow, CliError> {
    let set = common::set_for(f, set);
    let params = common::param_values(f, &set);
    let baked = crate::compile_formula(f.clone(), &Options { backend: Backend::Jit, bake: set.clone(), ..Options::default() })?;
    let live = crate::compile_formula(f.clone(), &Options { backend: Backend::Jit, ..Options::default() })?;
    let m = measure_kernel(&baked, &params, MeasureOptions { points: 4096, samples: a.samples })
        .map_err(|e| CliError::msg(format!("{path}: {e}")))?;
    let stem = Path::new(path).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let native_ns = crate::numerics::twins::by_stem(&stem).map(|t| time_twin(t.ev.as_ref(), &params, a.samples));
    let (lobe, _) = choose_lobe_input(live.used_inputs());
    let (ref_lobe, _) = choose_lobe_input(reference.used_inputs());
    let acc = accuracy(&live, &params, lobe, reference, &reference.default_params(), ref_lobe, &AccuracyOptions::default());
    let (mean_abs_grid, epi, max_abs) = match &acc {
        Ok(r) => (r.mean_abs_grid, r.epicenter.value * 100.0, r.max_abs.value),
        Err(_) => (f64::NAN, f64::NAN, f64::NAN),
    };
    let coef_n50 = energy::normalization_coef(&baked, &params, lobe).ok();
    let albedo_max = if a.no_albedo { None } else { energy::full_energy(&baked, &params).ok().map(|e| e.albedo_max) };
    let spread = (m.scalar_jit.p75_ns - m.scalar_jit.p25_ns) / 2.0 / m.scalar_jit.median_ns;
    Ok(BenchRow {
        name: f.display_name(),
        file: path.to_string(),
        compile_us: m.compile.as_secs_f64() * 1e6,
        jit_ns: m.scalar_jit.median_ns,
        jit_spread: spread,
        jit_batch_ns: m.batched_jit.median_ns,
        interp_ns: m.interp.median_ns,
        native_ns,
        mean_abs_grid,
        epicenter_max_rel_pct: epi,
        max_abs,
        coef_n50,
        albedo_max,
        pareto: false,
    })
}

pub fn run(a: &BenchArgs) -> Result<(), CliError> {
    let files = if a.files.is_empty() { catalogue()? } else { a.files.clone() };
    let set: Vec<(String, f64)> = {
        let s = a.set.list();
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
    let reference = common::load_kernel(Some(&a.reference), None, &[], Backend::Jit, crate::Mode::Precise)?;
    let mut rows = Vec::new();
    let progress = !a.json.on && std::io::IsTerminal::is_terminal(&std::io::stderr());
    for (f, path) in formulas.iter().zip(&files) {
        if progress {
            eprint!("\rmeasuring {:<40}", f.display_name());
        }
        rows.push(row(f, path, &set, &reference, a)?);
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
        println!("machine: {}; timings single-threaded, median of {} samples of 4096 points", bench::machine(), a.samples);
        print!("{}", bench::table(&rows));
    }
    if let (Some(path), Some(format)) = (&a.plot, plot_format) {
        let pts: Vec<CostError> = rows
            .iter()
            .map(|r| CostError { name: r.name.clone(), cost: r.jit_ns, error: r.mean_abs_grid, pareto: r.pareto, series: String::new() })
            .collect();
        let bytes = plot::speed_error(&pts, "Speed against error", "scalar JIT ns/eval (log)", "mean |Δ| vs reference (log)", format)
            .map_err(CliError::msg)?;
        a.force.write(path, &bytes, common::is_lobe_output)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
