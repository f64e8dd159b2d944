//! `lobe plot FILES… --set n=50 -o lobes.png [--polar] [--log] [--reference REF [--error]]`

use super::args::{self, Json, LookupArg, Output, Params};
use super::common::{self, CliError};
use lobe::report::plot::{self, Format, LobePlot};

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values, e.g. `n=50,a=16` (each formula takes the ones it declares)")))]
#[command(mut_arg("output", |a| a.required(true).help("Output image (.png or .svg)")))]
pub struct PlotArgs {
    /// Formula files (.brdf) and measured tables (MERL .binary) to overlay.
    #[arg(required = true)]
    pub files: Vec<String>,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub out: Output,
    /// Polar plot (radius = value) instead of value against angle.
    #[arg(long)]
    pub polar: bool,
    /// Logarithmic value axis (cartesian only).
    #[arg(long)]
    pub log: bool,
    /// A reference formula drawn with the others (e.g. examples/brdfs/blinn.brdf).
    #[arg(long)]
    pub reference: Option<String>,
    /// With --reference: plot F − reference instead of the lobes.
    #[arg(long, requires = "reference")]
    pub error: bool,
    /// Plot in the plane of incidence with the light at this angle from the normal (degrees, 0..90): value
    /// against the signed view angle, mirror direction at −θᵢ (with --polar: to scale, the light drawn). Measured tables (.binary) plot one curve per
    /// channel.
    #[arg(long)]
    pub incidence: Option<f64>,
    /// The value axis's range `lo,hi` (cartesian plots; positive on a log axis), instead of one fitted to the
    /// curves (a pole, e.g. Ward at grazing, otherwise flattens the others); curves are clipped to it.
    #[arg(long, value_name = "LO,HI", value_delimiter = ',', num_args = 1, allow_hyphen_values = true)]
    pub ylim: Vec<f64>,
    /// Image size in pixels, WxH.
    #[arg(long, default_value = "900x600", value_parser = parse_size)]
    pub size: (u32, u32),
    #[command(flatten)]
    pub lookup: LookupArg,
    /// Print `{"output", "format", "title", "x", "series": [{"name", "x", "y"}]}`: the plotted numbers.
    #[command(flatten)]
    pub json: Json,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once('x').ok_or("size is WxH, e.g. 900x600")?;
    let w: u32 = w.parse().map_err(|_| format!("`{w}` is not a width"))?;
    let h: u32 = h.parse().map_err(|_| format!("`{h}` is not a height"))?;
    if !(100..=8192).contains(&w) || !(100..=8192).contains(&h) {
        return Err("plot size must be between 100 and 8192 pixels per side".into());
    }
    Ok((w, h))
}

pub fn run(a: &PlotArgs) -> Result<(), CliError> {
    let output = a.out.required();
    let format = Format::from_path(output).map_err(|e| CliError::hint(e, "use -o lobes.png or -o lobes.svg"))?;
    let set = a.set.list()?;
    if let Some(t) = a.incidence.filter(|t| !(0.0..=90.0).contains(t)) {
        return Err(CliError::hint(format!("--incidence {t} is outside 0..90 degrees"), "e.g. --incidence 30"));
    }
    let (tables, formula_files): (Vec<&String>, Vec<&String>) = a.files.iter().partition(|p| lobe::measured::is_measured_path(p));
    let reference_table = a.reference.as_ref().is_some_and(|r| lobe::measured::is_measured_path(r));
    a.lookup.only_for_tables(tables.len() + usize::from(reference_table))?;
    let formulas = formula_files.iter().map(|p| common::load_formula(Some(p), None)).collect::<Result<Vec<_>, _>>()?;
    let reference = match &a.reference {
        Some(_) if reference_table => return Err(CliError::hint("--reference takes a formula here", "plot the measured table beside the formulas: list it with them")),
        Some(r) => Some(common::load_formula(Some(r), None)?),
        None => None,
    };
    common::check_set_names(&formulas.iter().chain(&reference).collect::<Vec<_>>(), &set)?;
    let tables = tables.iter().map(|p| Ok(((*p).clone(), std::sync::Arc::new(lobe::measured::Measured::read(p)?)))).collect::<Result<Vec<_>, CliError>>()?;
    if a.polar && a.log {
        return Err(CliError::msg("--log applies to cartesian plots only (a log radius has no zero)"));
    }
    let ylim = match a.ylim.as_slice() {
        [] => None,
        [lo, hi] => Some((*lo, *hi)),
        _ => return Err(CliError::hint("--ylim takes two values, lo,hi", "e.g. --ylim 0,2")),
    };
    let request = LobePlot {
        formulas: &formulas,
        tables: &tables,
        reference: reference.as_ref(),
        error: a.error,
        set: &set,
        incidence: a.incidence,
        lookup: a.lookup.how(),
        polar: a.polar,
        log: a.log,
        ylim,
        size: a.size,
    };
    let p = plot::plot_lobes(&request, format)?;
    a.out.force.write(output, &p.bytes, common::is_lobe_output)?;
    if a.json.on {
        let series: Vec<serde_json::Value> = p
            .series
            .iter()
            .map(|s| serde_json::json!({"name": s.name, "x": s.points.iter().map(|p| p.0).collect::<Vec<_>>(), "y": s.points.iter().map(|p| p.1).collect::<Vec<_>>()}))
            .collect();
        let format = if matches!(format, Format::Svg) { "svg" } else { "png" };
        println!("{}", serde_json::json!({"output": output.display().to_string(), "format": format, "title": p.title, "x": p.x, "y": p.y, "series": series}));
    } else {
        eprintln!("wrote {}", output.display());
    }
    Ok(())
}
