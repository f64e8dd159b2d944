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
    Fit(cli::fit_args::FitArgs),
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

/// Writing the command's output can fail after the work is done: `print!` then panics with "failed printing to
/// stdout: …". A reader that stops early (`lobe check … | head -1`) closes the pipe (EPIPE): the command did
/// nothing wrong, so it ends quietly with the shell's status for a broken pipe (128 + SIGPIPE), as a C program
/// killed by SIGPIPE would. Any other failure (a full device, an I/O error) is the user's to know: an error line
/// and exit code 1, not a panic.
fn output_failures_are_errors() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let p = info.payload();
        let msg = p.downcast_ref::<String>().map(String::as_str).or_else(|| p.downcast_ref::<&str>().copied()).unwrap_or("");
        if let Some(why) = msg.strip_prefix("failed printing to ") {
            if msg.contains("os error 32") {
                std::process::exit(141);
            }
            let (stream, why) = why.split_once(": ").unwrap_or(("stdout", why));
            let stream = if stream == "stderr" { "standard error" } else { "standard output" };
            eprintln!("error: cannot write the output to {stream}: {why}\n  = help: the output goes to a full or failing device: send it elsewhere");
            std::process::exit(1);
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

/// The command line, with negative numbers taken as values in every subcommand: `--aa -2` is then refused by its
/// range ("-2 is not in 1..=8") instead of clap's "unexpected argument '-2'" and its tip to write `-- -2`.
fn parse(args: Vec<std::ffi::OsString>) -> Cli {
    use clap::{CommandFactory, FromArgMatches};
    let mut cmd = Cli::command();
    let names: Vec<String> = cmd.get_subcommands().map(|s| s.get_name().to_string()).collect();
    for n in names {
        cmd = cmd.mut_subcommand(n, |s| s.allow_negative_numbers(true));
    }
    let json = args.iter().any(|a| a == "--json");
    let usage = |e: clap::Error| -> ! {
        // A usage error under --json is an error object too (help and --version are not errors).
        if json && e.use_stderr() {
            let text = e.render().to_string();
            let first = text.lines().next().unwrap_or_default();
            let message = first.strip_prefix("error: ").unwrap_or(first);
            let hint = text.lines().find_map(|l| l.trim().strip_prefix("tip: ")).map(str::to_string);
            println!("{}", serde_json::json!({"error": message, "file": null, "line": null, "column": null, "hint": hint, "diagnostics": [], "usage": text}));
        }
        e.exit()
    };
    let matches = cmd.try_get_matches_from(args).unwrap_or_else(|e| usage(e));
    Cli::from_arg_matches(&matches).unwrap_or_else(|e| usage(e))
}

fn command() {
    // A killed write must not leave `.NAME.lobe-tmp-PID` files behind.
    lobe::base::output::clean_up_on_signals();
    output_failures_are_errors();
    let cli = parse(std::env::args_os().collect());
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
        // Under --json the error is a JSON object on standard output too, where the report would have been.
        if let Some(j) = e.to_json().filter(|_| cli.cmd.json()) {
            println!("{j}");
        }
        let color = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
        eprint!("{}", e.render(color));
        std::process::exit(e.exit_code());
    }
}

impl Cmd {
    /// Whether the command was asked for JSON (`--json`).
    fn json(&self) -> bool {
        match self {
            Cmd::Eval(a) => a.json.on,
            Cmd::Watch(a) => a.json.on,
            Cmd::Bench(a) => a.json.on,
            Cmd::Plot(a) => a.json.on,
            Cmd::Check(a) => a.json.on,
            Cmd::Export(a) => a.json.on,
            Cmd::Import(a) => a.json.on,
            Cmd::Energy(a) => a.json.on,
            Cmd::Accuracy(a) => a.json.on,
            Cmd::Fit(a) => a.json.on,
            Cmd::Tabulate(a) => a.json.on,
            Cmd::Sweep(a) => a.json.on,
            Cmd::Render(a) => a.json.on,
            Cmd::Compare(a) => a.json.on,
            Cmd::Serve(a) => a.json.on,
            Cmd::Sample(a) => a.json.on,
        }
    }
}
