//! The `lobe` command: clap subcommands only; each one's logic lives in the library.

mod cli;

use clap::{Parser, Subcommand};
use std::io::IsTerminal;

#[derive(Parser)]
#[command(name = "lobe", version, about = "Compile, check, benchmark and render BRDF formulas", long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    /// Do not read or store the accuracy pass's decisions in the cache directory (`$LOBE_CACHE_DIR`, else the
    /// platform's, e.g. ~/.cache/lobe): search again.
    #[arg(long, global = true)]
    no_cache: bool,
}

#[derive(Subcommand)]
enum Cmd {
    /// Evaluate a formula at one point.
    Eval(cli::eval::EvalArgs),
    /// Recompile and re-render whenever a .brdf file changes.
    Watch(cli::watch::WatchArgs),
    /// Speed against error for several formulas: ns/eval per backend, error vs a reference, energy, Pareto front.
    Bench(cli::bench::BenchArgs),
    /// Overlay lobes of several formulas against angle (cartesian or polar), optionally as error curves.
    Plot(cli::plot::PlotArgs),
    /// Show the simplified formula, the inputs it reads and its compile time.
    Check(cli::check::CheckArgs),
    /// Export a formula as a GLSL or WGSL function.
    Export(cli::export::ExportArgs),
    /// Write a formula file (a BRDF Explorer .brdf) as lobe's own language.
    Import(cli::import::ImportArgs),
    /// Energy: the exact normalisation coefficient (lobe mode) or the albedo over incidence angles (full mode).
    Energy(cli::energy::EnergyArgs),
    /// Importance sampling: draw wo for an incidence, test the samples against the pdf (χ²), efficiency, albedo.
    Sample(cli::sample::SampleArgs),
    /// Accuracy against a reference lobe (mean |Δ|, epicentre, inflection, cut-off metrics).
    Accuracy(cli::accuracy::AccuracyArgs),
    /// Fit parameters to a reference lobe or to measured tables (exhaustive grid + continuous refinement).
    Fit(cli::fit::FitArgs),
    /// Tabulate a formula into a measured table (MERL .binary), e.g. a synthetic measurement to fit.
    Tabulate(cli::tabulate::TabulateArgs),
    /// Stability sweep: NaN, ±inf, negative and huge values over the whole domain.
    Sweep(cli::sweep::SweepArgs),
    /// Render a scene (TOML) to a PNG with the tile-based software renderer.
    Render(cli::render::RenderArgs),
    /// Render two formulas in the same scene and measure the difference (the papers' table 4.2).
    Compare(cli::compare::CompareArgs),
    /// A local web page: edit a formula, move parameter sliders, compare two models live, save.
    Serve(cli::serve::ServeArgs),
}

/// A reader that stops early (`lobe check … | head -1`) closes the pipe, and the next write to it fails with
/// EPIPE, which `print!` reports by panicking. The command did nothing wrong: end quietly with the shell's status
/// for a broken pipe (128 + SIGPIPE), as a C program killed by SIGPIPE would.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let p = info.payload();
        let msg = p.downcast_ref::<String>().map(String::as_str).or_else(|| p.downcast_ref::<&str>().copied()).unwrap_or("");
        if msg.contains("failed printing to std") && msg.contains("os error 32") {
            std::process::exit(141);
        }
        default(info);
    }));
}

/// Stack reserved for the command's thread. Formulas are trees up to the 1 MiB source cap (a 600 000-node chain
/// such as `NH+NH+…`); the library's recursive passes continue on stack segments of their own (`base::stack`),
/// so this is a second guard, for any recursion their tests do not reach: address space only, the pages a
/// command touches are all it uses.
const COMMAND_STACK: usize = 1 << 30;
/// The same for rayon's workers (the pass measures candidates and the renderer shades tiles on them).
const WORKER_STACK: usize = 256 << 20;

fn main() {
    // Without the pool (a platform that refuses the reservation) rayon builds its default one on first use.
    let _ = rayon::ThreadPoolBuilder::new().stack_size(WORKER_STACK).build_global();
    let run = std::thread::Builder::new().name("lobe".into()).stack_size(COMMAND_STACK).spawn(command);
    match run.map(|t| t.join()) {
        Ok(Ok(())) => {}
        // The panic hook has printed the message.
        Ok(Err(_)) => std::process::exit(101),
        // No thread with that stack (address space refused): run on this one.
        Err(_) => command(),
    }
}

fn command() {
    // A killed write must not leave `.NAME.lobe-tmp-PID` files behind.
    lobe::base::output::clean_up_on_signals();
    quiet_on_broken_pipe();
    // `lobe check --sweep FILE` is the spelling of `lobe sweep FILE`.
    let mut args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if args.get(1).is_some_and(|a| a == "check") && args.iter().any(|a| a == "--sweep") {
        args[1] = "sweep".into();
        args.retain(|a| a != "--sweep");
    }
    let cli = Cli::parse_from(args);
    cli::common::use_cache(!cli.no_cache);
    let result = match &cli.cmd {
        Cmd::Eval(a) => cli::eval::run(a),
        Cmd::Watch(a) => cli::watch::run(a),
        Cmd::Bench(a) => cli::bench::run(a),
        Cmd::Plot(a) => cli::plot::run(a),
        Cmd::Export(a) => cli::export::run(a),
        Cmd::Import(a) => cli::import::run(a),
        Cmd::Check(a) => cli::check::run(a),
        Cmd::Energy(a) => cli::energy::run(a),
        Cmd::Sample(a) => cli::sample::run(a),
        Cmd::Accuracy(a) => cli::accuracy::run(a),
        Cmd::Fit(a) if !a.measured.is_empty() => cli::fit_measured::run(a),
        Cmd::Fit(a) => cli::fit::run(a),
        Cmd::Sweep(a) => cli::sweep::run(a),
        Cmd::Tabulate(a) => cli::tabulate::run(a),
        Cmd::Render(a) => cli::render::run(a),
        Cmd::Compare(a) => cli::compare::run(a),
        Cmd::Serve(a) => cli::serve::run(a),
    };
    if let Err(e) = result {
        let color = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
        eprint!("{}", e.render(color));
        std::process::exit(e.exit_code());
    }
}
