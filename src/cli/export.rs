//! `lobe export --glsl [--glsl-version 330|450|es300]|--wgsl|--brdf-explorer FILE [--set n=50] [-o out.glsl]`

use super::args::{self, FormulaSource, Json, Output, Params};
use super::common::CliError;
use lobe::backend::glsl::{self, Dialect, GlslVersion};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameters baked as constants, e.g. `n=50`; the others become function arguments")))]
#[command(mut_arg("output", args::help("Write to this file instead of standard output")))]
pub struct ExportArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    /// Emit GLSL (the default).
    #[arg(long, conflicts_with_all = ["wgsl", "brdf_explorer"])]
    pub glsl: bool,
    /// The GLSL the function is written for: `450` (the default), `330` or `es300` (GLSL ES 3.00, WebGL2). The
    /// last two have no `fma`: it is written `a * b + c` there.
    #[arg(long, value_name = "VERSION", default_value = "450", conflicts_with_all = ["wgsl", "brdf_explorer"])]
    pub glsl_version: GlslVersion,
    /// Emit WGSL.
    #[arg(long, conflicts_with = "brdf_explorer")]
    pub wgsl: bool,
    /// Emit a file Disney's BRDF Explorer loads (`analytic`, a parameters block, `vec3 BRDF(L, V, N, X, Y)`).
    #[arg(long)]
    pub brdf_explorer: bool,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub out: Output,
    /// Print `{"formula", "language", "output", "text"}` (the text also with -o, which still writes it).
    #[command(flatten)]
    pub json: Json,
}

fn is_ours(bytes: &[u8]) -> bool {
    String::from_utf8_lossy(&bytes[..bytes.len().min(400)]).contains("— exported by lobe")
}

/// Exports the plain simplification with the `--set` values baked: the accuracy pass's rewrites are for f64
/// (double-double tails, scalings that overflow a GPU's f32), and its internal builtins have no shader spelling.
pub fn run(a: &ExportArgs) -> Result<(), CliError> {
    let f = a.formula.plain(&a.set.list()?)?;
    let text = if a.brdf_explorer {
        glsl::brdf_explorer(&f)
    } else {
        glsl::export(&f, if a.wgsl { Dialect::Wgsl } else { Dialect::Glsl(a.glsl_version) })
    }
    .map_err(|d| lobe::Diagnostics::single_in(&f.file, &f.source, d))?;
    let language = if a.brdf_explorer {
        "brdf-explorer".to_string()
    } else if a.wgsl {
        "wgsl".to_string()
    } else {
        format!("glsl {}", a.glsl_version.name())
    };
    a.out.emit_text(&text, is_ours, a.json.on.then(|| serde_json::json!({"formula": f.display_name(), "language": language})))
}
