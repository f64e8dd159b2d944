//! `lobe export --glsl [--glsl-version 330|450|es300]|--wgsl|--brdf-explorer|--mitsuba FILE [--set n=50] [-o out.glsl]`
//!
//! `--mitsuba` writes a Python module registering a Mitsuba 3 BSDF plugin (`lobe::bsdf::mitsuba`): the formula
//! with every parameter baked (the `--set` values, else the defaults) and its sampler's tables, built here from
//! the formula's kernels as `lobe sample` builds them.

use super::args::{self, FormulaSource, Json, Output, Params};
use super::common::{self, CliError};
use lobe::bsdf::{Choice, Mechanism};
use lobe::backend::glsl::{self, Dialect, GlslVersion};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameters baked as constants, e.g. `n=50`; the others become function arguments")))]
#[command(mut_arg("output", args::help("Write to this file instead of standard output")))]
pub struct ExportArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    /// Emit GLSL (the default).
    #[arg(long, conflicts_with_all = ["wgsl", "brdf_explorer", "mitsuba"])]
    pub glsl: bool,
    /// The GLSL the function is written for: `450` (the default), `330` or `es300` (GLSL ES 3.00, WebGL2). The
    /// last two have no `fma`: it is written `a * b + c` there.
    #[arg(long, value_name = "VERSION", default_value = "450", conflicts_with_all = ["wgsl", "brdf_explorer", "mitsuba"])]
    pub glsl_version: GlslVersion,
    /// Emit WGSL.
    #[arg(long, conflicts_with_all = ["brdf_explorer", "mitsuba"])]
    pub wgsl: bool,
    /// Emit a file Disney's BRDF Explorer loads (`analytic`, a parameters block, `vec3 BRDF(L, V, N, X, Y)`).
    #[arg(long, conflicts_with = "mitsuba")]
    pub brdf_explorer: bool,
    /// Emit a Python module that registers a Mitsuba 3 BSDF plugin `lobe_NAME` (eval, pdf, sample in Dr.Jit,
    /// the sampler's tables embedded; every parameter baked). docs/mitsuba.md.
    #[arg(long)]
    pub mitsuba: bool,
    /// With --mitsuba: the sampler's mechanism, `auto` (the best measured, as `lobe sample`), `tabulated`,
    /// `exact` (formulas of NH alone or VR alone) or `cosine`.
    #[arg(long, value_name = "MECHANISM", default_value = "auto", requires = "mitsuba")]
    pub mechanism: String,
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
    if a.mitsuba {
        return mitsuba(a);
    }
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

/// `--mitsuba`: the module ([`lobe::bsdf::mitsuba::export`]) at every parameter's value.
fn mitsuba(a: &ExportArgs) -> Result<(), CliError> {
    let set = a.set.list()?;
    let f = a.formula.load()?;
    let choice = match a.mechanism.as_str() {
        "auto" => Choice::Auto,
        m => Choice::Force(m.parse::<Mechanism>().map_err(|e| CliError::hint(e, "--mechanism auto picks the best measured"))?),
    };
    let e = lobe::bsdf::mitsuba::export(&f, &set, choice, common::cache_on())?;
    let json = a.json.on.then(|| {
        serde_json::json!({"formula": f.display_name(), "language": "mitsuba", "plugin": e.plugin, "mechanism": e.mechanism.name(), "isotropic": e.isotropic})
    });
    a.out.emit_text(&e.text, is_ours, json)
}
