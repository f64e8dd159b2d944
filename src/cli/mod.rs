//! The `lobe` subcommands, compiled into the binary only: one file each, holding a clap `Args` struct and a
//! `run` function that calls the library, fills its typed reports and prints them (or words them as text).
//! Flags several commands share are flattened from [`args`]; loading formulas, `--set` lists and the error
//! type are in [`common`]. The measuring, checking and drawing is the library's (a bench row is
//! `lobe::report::bench::bench_row`, a figure `lobe::report::plot`); what stays here is choosing what to run
//! from the flags and wording the result.

/// `writeln!` into the report string (formatting into a `String` cannot fail).
macro_rules! outln {
    ($o:expr, $($t:tt)*) => {{
        use std::fmt::Write as _;
        let _ = writeln!($o, $($t)*);
    }};
}

pub mod args;
pub mod bench;
pub mod catalogue;
pub mod check;
pub mod common;
pub mod compare;
pub mod eval;
pub mod export;
pub mod import;
pub mod plot;
pub mod points;
pub mod accuracy;
pub mod energy;
pub mod fit;
pub mod fit_args;
pub mod fit_measured;
pub mod tabulate;
pub mod sweep;
pub mod watch;
pub mod render;
pub mod sample;
pub mod serve;
