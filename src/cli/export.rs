//! `lobe export --glsl|--wgsl FILE [--set n=50] [-o out.glsl]`

use super::common::{self, CliError};
use crate::backend::glsl::{self, Dialect};

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// Formula file (.brdf), or `-` for standard input.
    pub file: Option<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "file")]
    pub expr: Option<String>,
    /// Emit GLSL (the default).
    #[arg(long, conflicts_with = "wgsl")]
    pub glsl: bool,
    /// Emit WGSL.
    #[arg(long)]
    pub wgsl: bool,
    /// Parameters baked as constants, e.g. `n=50`; the others become function arguments.
    #[arg(long, value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub set: Vec<Vec<(String, f64)>>,
    /// Write to this file instead of standard output.
    #[arg(short, long)]
    pub output: Option<std::path::PathBuf>,
    /// Replace an existing output file even if lobe did not write it.
    #[arg(long)]
    pub force: bool,
}

fn is_ours(bytes: &[u8]) -> bool {
    String::from_utf8_lossy(&bytes[..bytes.len().min(400)]).contains("— exported by lobe")
}

pub fn run(a: &ExportArgs) -> Result<(), CliError> {
    let set = a.set.concat();
    let k = common::load_kernel(a.file.as_deref(), a.expr.as_deref(), &set, crate::Backend::Interp)?;
    let d = if a.wgsl { Dialect::Wgsl } else { Dialect::Glsl };
    let text = glsl::export(&k.formula, d);
    match &a.output {
        Some(p) => common::write_output(p, text.as_bytes(), a.force, is_ours),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}
