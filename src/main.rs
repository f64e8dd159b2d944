//! The `lobe` command: clap subcommands only; each one's logic lives in the library.

use clap::{Parser, Subcommand};
use lobe::cli;
use std::io::IsTerminal;

#[derive(Parser)]
#[command(name = "lobe", version, about = "Compile, check, benchmark and render BRDF formulas", long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Evaluate a formula at one point.
    Eval(cli::eval::EvalArgs),
    /// Render a scene (TOML) to a PNG with the tile-based software renderer.
    Render(cli::render::RenderArgs),
    /// Render two formulas in the same scene and measure the difference (the papers' table 4.2).
    Compare(cli::compare::CompareArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match &cli.cmd {
        Cmd::Eval(a) => cli::eval::run(a),
        Cmd::Render(a) => cli::render::run(a),
        Cmd::Compare(a) => cli::compare::run(a),
    };
    if let Err(e) = result {
        let color = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
        eprint!("{}", e.render(color));
        std::process::exit(e.exit_code());
    }
}
