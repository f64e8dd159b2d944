//! `lobe bench [FILES…] [--reference blinn.brdf] [--set n=50] [--json] [--plot speed_error.png]`
//!
//! The command's arguments and words; the rows are measured by [`lobe::report::bench::bench_row`]. Speed
//! against error, in one run: for each formula its compile time, ns/eval on the scalar JIT, the batched
//! JIT and the interpreter (and hand-written Rust where lobe has a twin), its error against the reference on
//! the papers' grid, and its energy at the benchmark n. The table is sorted by cost with the Pareto front
//! marked; `--plot` draws cost against error. With the LLVM tier in the build (`--tier auto`, the default, or
//! `--tier llvm`), a second table times Cranelift's and LLVM's batched kernels side by side on the same points
//! (`--timing-points`), with each tier's compile time.

use super::args::{self, Force, Json, Params};
use super::common::{self, CliError};
use lobe::report::bench::{self, RowOptions};
use lobe::report::measure::MeasureOptions;
use lobe::report::plot::{self, CostError, Format};
use lobe::Backend;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values for the timing and energy columns (the error columns sweep n over 1..1000)")))]
#[command(mut_arg("json", args::help("Print a JSON list of objects instead of the table")))]
pub struct BenchArgs {
    /// Formula files (default: every examples/brdfs/*.brdf, the built-in catalogue outside a checkout).
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

    fn row_options(&self) -> Result<RowOptions, CliError> {
        let measure = MeasureOptions { points: self.timing_points as usize, samples: self.samples };
        Ok(RowOptions { measure, tiers: self.llvm()?, albedo: !self.no_albedo })
    }
}

/// The files of `examples/brdfs` under the working directory, or the built-in catalogue elsewhere.
fn catalogue() -> Result<Vec<String>, CliError> {
    let dir = Path::new("examples/brdfs");
    let Ok(rd) = std::fs::read_dir(dir) else { return Ok(super::catalogue::paths()) };
    let mut v: Vec<String> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
        .map(|p| p.display().to_string())
        .collect();
    v.sort();
    Ok(v)
}

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
    let opts = a.row_options()?;
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
            rows.push(bench::bench_row(f, path, &set, &reference, math, &opts)?);
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
