//! `lobe compare A.brdf B.brdf [--scene S.toml] [--set n=50] -o cmp.png [--json] [--sweep-n 5,10,…]`
//!
//! Numbers in `--json` follow [`lobe::base::json`]: two identical images have `"psnr": "inf"`.

use super::args::{self, BackendArg, Json, Output, Params};
use super::common::{self, CliError};
use lobe::base::diag::Setting;
use lobe::render::compare::{self, CompareJob};
use lobe::render::image::{self, Transfer};
use lobe::render::RenderOptions;
use std::path::PathBuf;

pub use lobe::render::scene::PAPER_SCENE;

#[derive(clap::Args, Debug)]
#[command(mut_arg("set", args::help("Parameter values for both formulas, e.g. `n=50`")))]
#[command(mut_arg("output", args::help("Output PNG: A | B | difference heat map with its colour bar (one row per n when sweeping)")))]
#[command(mut_arg("json", args::help("Print JSON: an object with `manhattan`, `rmse`, `psnr`, … ; with --sweep-n an array of them, one per n")))]
pub struct CompareArgs {
    /// First formula (.brdf), or a measured table (MERL .binary).
    pub a: String,
    /// Second formula (.brdf), or a measured table (MERL .binary).
    pub b: String,
    /// Scene whose materials both formulas replace (default: the papers' sphere).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    #[command(flatten)]
    pub set: Params,
    /// Compare at each of these n (e.g. 5,10,15,20,50,100,250,500): one row per n.
    #[arg(long, value_delimiter = ',')]
    pub sweep_n: Vec<f64>,
    #[command(flatten)]
    pub out: Output,
    /// Image size: `N` or `WxH` (default: the scene's).
    #[arg(long, value_parser = super::render::parse_size)]
    pub size: Option<(usize, usize)>,
    #[command(flatten)]
    pub backend: BackendArg,
    /// Worker threads (default: one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Encode with the sRGB curve (the papers' metric is defined on the linear clamp; default).
    #[arg(long)]
    pub srgb: bool,
    #[command(flatten)]
    pub json: Json,
}

pub fn run(a: &CompareArgs) -> Result<(), CliError> {
    if let Some(out) = &a.out.path {
        a.out.force.check(out, image::is_lobe_png)?;
        Output::png_only(out)?;
    }
    let (fa, sa) = read_brdf(&a.a)?;
    let (fb, sb) = read_brdf(&a.b)?;
    let (scene_name, scene_src, base) = match &a.scene {
        Some(p) => {
            let src = std::fs::read_to_string(p)
                .map_err(|e| CliError::hint(format!("cannot read scene `{}`: {e}", p.display()), "check the path"))?;
            (p.display().to_string(), src, p.parent().map(|d| d.to_path_buf()).unwrap_or_default())
        }
        None => ("<builtin paper_sphere.toml>".to_string(), PAPER_SCENE.to_string(), PathBuf::from(".")),
    };
    let job = CompareJob { scene_name: &scene_name, scene_src: &scene_src, base: &base, a: (&fa, &sa), b: (&fb, &sb), size: a.size, tint: [[1.0; 3]; 2] };
    common::check_threads(a.threads)?;
    let ropts = RenderOptions {
        threads: a.threads,
        transfer: if a.srgb { Transfer::Srgb } else { Transfer::Linear },
        ..RenderOptions::default()
    };
    let lobe_compiler = super::common::scene_compiler(a.backend.backend()?, a.backend.math.mode);
    let compiler: &dyn lobe::render::scene::BrdfCompiler = &lobe_compiler;
    let base_set = a.set.list()?;
    if !a.sweep_n.is_empty() && base_set.iter().any(|(k, _)| k == "n") {
        return Err(CliError::hint("--set n conflicts with --sweep-n", "--sweep-n gives the values of n; drop n from --set"));
    }
    let sets: Vec<Vec<(String, f64)>> = if a.sweep_n.is_empty() {
        vec![base_set.clone()]
    } else {
        a.sweep_n
            .iter()
            .map(|&n| {
                let mut s = base_set.clone();
                s.push(("n".to_string(), n));
                s
            })
            .collect()
    };
    let rows = compare::compare_sweep(&job, &sets, compiler, &ropts).map_err(|mut ds| {
        // A value of n from --sweep-n is named as that flag's, not as a --set.
        for d in &mut ds.items {
            if let Some(Setting::Param { name, value: Some(v) }) = d.subject.as_deref() {
                if name == "n" && a.sweep_n.contains(v) {
                    d.message = format!("--sweep-n {v}: {}", d.message);
                    d.subject = None;
                }
            }
        }
        CliError::from(ds)
    })?;
    let scale = rows.iter().map(|c| c.metrics.max_gray_diff).fold(0.0, f64::max).max(1.0);
    if let Some(out) = &a.out.path {
        let labels: Vec<String> = if a.sweep_n.is_empty() { vec![] } else { rows.iter().map(|c| c.n.map(|n| format!("n = {n}")).unwrap_or_default()).collect() };
        let figure = lobe::report::plot::comparison_figure(&compare::sweep_image(&rows, scale), [base_name(&a.a), base_name(&a.b), "|Δgray|"], &labels, scale);
        let png = figure.and_then(|f| f.encode_png()).map_err(CliError::msg)?;
        a.out.force.write(out, &png, image::is_lobe_png)?;
    }
    if a.json.on {
        let json = if a.sweep_n.is_empty() {
            common::to_json(&rows[0].json(&a.a, &a.b))?
        } else {
            common::to_json(&rows.iter().map(|c| c.json(&a.a, &a.b)).collect::<Vec<_>>())?
        };
        println!("{json}");
    } else {
        println!("{} vs {} ({}×{}, scene {scene_name})", a.a, a.b, rows[0].a.image.width, rows[0].a.image.height);
        println!("{:>8} {:>10} {:>12} {:>8} {:>8} {:>8}", "n", "manhattan", "(covered px)", "max", "rmse", "psnr");
        for c in &rows {
            let m = &c.metrics;
            let n = c.n.map(|n| n.to_string()).unwrap_or_else(|| "-".into());
            println!("{n:>8} {:>10.4} {:>12.4} {:>8.2} {:>8.4} {:>8.2}", m.manhattan, m.manhattan_covered, m.max_gray_diff, m.rmse, m.psnr);
        }
        if let Some(out) = &a.out.path {
            println!("wrote {} (A | B | |Δgray| heat map, white = {scale:.1} gray levels)", out.display());
        }
    }
    for c in &rows {
        if c.nan != [0, 0] {
            eprintln!("warning: NaN or ±inf kernel results shaded as no light (A: {}, B: {})", c.nan[0], c.nan[1]);
        }
    }
    Ok(())
}

/// A formula's name and text, or for a measured table (`.binary`) its path and no text (the renderer reads
/// the table), checked here so a bad file fails before any render.
pub fn read_brdf(path: &str) -> Result<(String, String), CliError> {
    if lobe::measured::is_measured_path(path) {
        lobe::measured::Measured::read(path)?;
        return Ok((path.to_string(), String::new()));
    }
    Ok(common::read_source(path)?)
}

/// A file's name without its directories (the picture's column heading).
fn base_name(p: &str) -> &str {
    std::path::Path::new(p).file_name().and_then(|n| n.to_str()).unwrap_or(p)
}
