//! Command-line plumbing shared by the subcommands: reading sources, `--set`/`--at` lists, errors.
//!
//! Each subcommand lives in its own file as a clap `Args` struct and a `run` function that calls library
//! code; no numerical or rendering logic lives here.

/// `writeln!` into the report string (formatting into a `String` cannot fail).
macro_rules! outln {
    ($o:expr, $($t:tt)*) => {{
        use std::fmt::Write as _;
        let _ = writeln!($o, $($t)*);
    }};
}

pub mod bench;
pub mod check;
pub mod common;
pub mod compare;
pub mod eval;
pub mod export;
pub mod plot;
pub mod accuracy;
pub mod energy;
pub mod fit;
pub mod sweep;
pub mod watch;
pub mod render;
