//! `lobe fit`'s arguments, shared by the fit against a reference ([`super::fit`]) and the fits against measured
//! tables or a formula over the hemisphere ([`super::fit_measured`]).

use super::args::{self, AgainstReference, BackendArg, FormulaSource, Json, LobeVar, Output, Params};
use super::args::parse_range;
use super::common::CliError;
use lobe::numerics::fit::{Metric, Refinement};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Fixed values of other parameters, e.g. `k=2`")))]
pub struct FitArgs {
    /// Formula file(s) (.brdf); several only with --measured (each fitted to each table).
    pub files: Vec<String>,
    /// The formula inline instead of a file.
    #[arg(long, conflicts_with = "files", allow_hyphen_values = true)]
    pub expr: Option<String>,
    /// The reference lobe (normally Blinn, cos^n).
    #[arg(long, required_unless_present = "measured", conflicts_with = "measured")]
    pub reference: Option<String>,
    /// Measured tables (MERL .binary), or folders of them: fit to the measurement instead of a reference lobe. A
    /// formula file (.brdf) here is a reference over the whole hemisphere: its values (at the `--set` values of the
    /// parameters it declares) at the tables' angles, for every incidence.
    #[arg(long, num_args = 1..)]
    pub measured: Vec<String>,
    #[command(flatten)]
    pub lobe: LobeVar,
    /// A parameter to search over the interval [lo, hi]: `name=lo..hi` (a grid of 41 values, or the integers when
    /// lo and hi are integers at least 40 apart, then continuous refinement) or `name=lo..hi:step`.
    #[arg(long, required = true)]
    pub param: Vec<String>,
    #[command(flatten)]
    pub set: Params,
    /// What to minimise: mean-abs (the papers', the default), max-abs, epicenter; against --measured: log
    /// (cosine-weighted log error, the default), rmse or cosine (cosine-weighted L2).
    #[arg(long)]
    pub metric: Option<String>,
    /// --measured: use every STRIDE-th table index along each axis for the refinement and the residual.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=90))]
    pub stride: u16,
    /// --measured: the (coarser) stride of the grid stage.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=90))]
    pub grid_stride: u16,
    /// --measured against a formula: fit a colour scale too (by default a formula's values are absolute).
    #[arg(long)]
    pub fit_scale: bool,
    /// --measured: write the table of every formula × measurement fit (.csv or .json).
    #[arg(long)]
    pub table: Option<std::path::PathBuf>,
    /// --measured: the comparison image (fitted formula | measurement | difference) on the papers' sphere.
    #[command(flatten)]
    pub out: Output,
    /// How many candidates to print.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u16).range(1..))]
    pub top: u16,
    /// Skip the continuous refinement after the grid.
    #[arg(long)]
    pub no_refine: bool,
    /// Refine as before the exact Jacobian: the fine grid, then golden section or Nelder–Mead around its best
    /// point (the default is Levenberg–Marquardt from the best points of a coarse grid, for comparison).
    #[arg(long, conflicts_with = "no_refine")]
    pub derivative_free: bool,
    /// Largest n of the metric.
    #[arg(long, default_value_t = 1000)]
    pub n_max: u32,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub backend: BackendArg,
    #[command(flatten)]
    pub json: Json,
}

/// A `--param`: name, lo, hi and the step, if given.
pub type FreeSpec = (String, f64, f64, Option<f64>);

/// Parses `name=lo..hi[:step]`.
pub fn parse_free(s: &str) -> Result<FreeSpec, String> {
    let (name, rest) = s.split_once('=').ok_or_else(|| format!("`{s}` is not of the form name=lo..hi (e.g. a=1..1000)"))?;
    let (range, step) = match rest.split_once(':') {
        Some((r, st)) => (r, Some(st.trim().parse::<f64>().map_err(|_| format!("`{st}` is not a step in `{s}`"))?)),
        None => (rest, None),
    };
    let (lo, hi) = parse_range(range)?;
    Ok((name.trim().to_string(), lo, hi, step))
}

/// Every `--param`, parsed.
pub fn free_specs(a: &FitArgs) -> Result<Vec<FreeSpec>, CliError> {
    a.param
        .iter()
        .map(|p| parse_free(p).map_err(|e| CliError::hint(format!("--param: {e}"), "e.g. --param a=1..1000 or a=0.1..0.9:0.1")))
        .collect()
}

impl FitArgs {
    /// The refinement `--derivative-free` selects.
    pub fn refinement(&self) -> Refinement {
        if self.derivative_free {
            Refinement::DerivativeFree
        } else {
            Refinement::Lm
        }
    }

    /// The one formula measured against `--reference`.
    pub(super) fn against(&self) -> Result<AgainstReference, CliError> {
        if self.files.len() > 1 {
            return Err(CliError::hint("several formulas are fitted to measured tables only", "give one formula with --reference, or use --measured"));
        }
        let formula = FormulaSource { file: self.files.first().cloned(), expr: self.expr.clone() };
        Ok(AgainstReference { formula, reference: self.reference.clone().unwrap_or_default(), lobe: self.lobe.clone() })
    }

    /// The papers' metric of a fit against a reference lobe.
    pub(super) fn lobe_metric(&self) -> Result<Metric, CliError> {
        self.metric.as_deref().unwrap_or("mean-abs").parse().map_err(|e: String| CliError::hint(format!("--metric: {e}"), "log and rmse apply to --measured fits"))
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn parses_free_parameters() {
        assert_eq!(super::parse_free("a=1..1000").unwrap(), ("a".into(), 1.0, 1000.0, None));
        assert_eq!(super::parse_free("Q=0.1..0.9:0.1").unwrap(), ("Q".into(), 0.1, 0.9, Some(0.1)));
        assert!(super::parse_free("a").is_err());
        assert!(super::parse_free("a=5..1").is_err());
        assert!(super::parse_free("a=1..x").is_err());
    }
}
