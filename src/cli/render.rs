//! `lobe render SCENE [-o out.png|out.exr] [--size 1024] [--aa 2] [--spp N] [--strategy mis|bsdf|env] [--set n=200]
//! [--backend jit|interp] [--threads N] [--stats [--json]]`
//!
//! A scene with an `[environment]` or `shadows = true` renders through the ray tracer (`lobe::render::trace`);
//! its image can be written as linear float OpenEXR (`-o x.exr`).

use super::args::{self, BackendArg, Json, Output, Params};
use super::common::{self, CliError};
use lobe::render::image::{self, Transfer};
use lobe::render::scene::{self, LoadOptions};
use lobe::render::{self as r, RenderOptions};
use lobe::report::render as report;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
#[command(mut_arg("output", args::help("Output PNG, or .exr (linear float RGB; ray-traced scenes) (default: the scene's name with .png, in the current directory)")))]
#[command(mut_arg("set", args::help("Parameter values for every material that declares them, e.g. `n=200`")))]
pub struct RenderArgs {
    /// Scene file (.toml); see examples/scenes/.
    pub scene: PathBuf,
    #[command(flatten)]
    pub out: Output,
    /// Image size: `N` (square) or `WxH`, each at most 4096.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    #[command(flatten)]
    pub set: Params,
    #[command(flatten)]
    pub backend: BackendArg,
    /// Worker threads (default: one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Tile side in pixels.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u16).range(8..=256))]
    pub tile: u16,
    /// Supersampling: N×N samples per pixel, averaged (1..=8; default: the scene's `aa`, else 1).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(1..=lobe::render::MAX_AA as i64))]
    pub aa: Option<u8>,
    /// Samples per pixel of the ray tracer (scenes with an [environment] or shadows), 1..=65536 (default: the
    /// scene's `spp`, else 16).
    #[arg(long, value_name = "N", value_parser = parse_spp)]
    pub spp: Option<usize>,
    /// Which directions the ray tracer's environment estimator draws: `mis` (both, by the power heuristic,
    /// each material's share chosen by a pilot), `bsdf` (the material's only) or `env` (the
    /// environment's only) — the last two for measurements.
    #[arg(long, default_value = "mis", value_parser = parse_strategy)]
    pub strategy: r::trace::Strategy,
    /// Encode with the sRGB curve instead of the papers' linear clamp to 0..255.
    #[arg(long)]
    pub srgb: bool,
    /// Print throughput and time per stage (and what a material's `cutoff` changes: one more render).
    #[arg(long)]
    pub stats: bool,
    #[command(flatten)]
    pub json: Json,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
    /// How materials are shaded: `program` (the only way) compiles each material's whole shading (geometry,
    /// every light, F, colour) into one program that the chosen backend runs, so `--backend interp` runs the
    /// same program.
    #[arg(long, value_enum, default_value_t = Shading::Program)]
    pub shading: Shading,
}

/// `--shading`: see [`RenderArgs::shading`].
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shading {
    Program,
}

pub use lobe::render::parse_size;

pub(crate) fn parse_spp(s: &str) -> Result<usize, String> {
    let max = lobe::render::trace::MAX_SPP;
    match s.trim().parse::<usize>() {
        Ok(v) if (1..=max).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} samples per pixel is outside 1..={max}; a few hundred give a clean image")),
        Err(_) => Err(format!("`{s}` is not a whole number")),
    }
}

fn parse_strategy(s: &str) -> Result<r::trace::Strategy, String> {
    s.parse()
}

/// Whether `path` names an OpenEXR output.
fn is_exr_path(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// The default output path: `<scene stem>.png` in the current directory.
pub fn default_output(scene: &Path) -> PathBuf {
    let stem = scene.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "render".into());
    PathBuf::from(format!("{stem}.png"))
}

pub fn run(a: &RenderArgs) -> Result<(), CliError> {
    let out = a.out.path.clone().unwrap_or_else(|| default_output(&a.scene));
    // Refuse a bad output path before doing any work, and write nothing unless everything succeeds.
    let exr = is_exr_path(&out);
    let is_ours = if exr { r::trace::is_lobe_exr } else { image::is_lobe_png };
    a.out.force.check(&out, is_ours)?;
    if !exr {
        Output::png_only(&out)?;
    }
    let opts = LoadOptions { size: a.size, set: a.set.list()?, ..LoadOptions::default() };
    let backend = a.backend.backend()?;
    let sc = scene::load_scene(&a.scene, &opts, &super::common::scene_compiler(backend, a.backend.math.mode))?;
    let ropts = RenderOptions {
        threads: a.threads,
        tile: a.tile as usize,
        transfer: if a.srgb { Transfer::Srgb } else { Transfer::Linear },
        cutoff: true,
        aa: a.aa.map(usize::from),
        spp: a.spp,
        strategy: a.strategy,
        ..RenderOptions::default()
    };
    if exr && !r::trace::traced(&sc) {
        return Err(CliError::hint(
            format!("`{}`: OpenEXR output needs the ray tracer, and `{}` renders through the rasteriser", out.display(), a.scene.display()),
            "add an [environment] or `shadows = true` to the scene, or name the output .png",
        ));
    }
    let t0 = Instant::now();
    common::check_threads(a.threads)?;
    let bar = TileBar::new(!a.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr()));
    let (frame, stats, bytes, encode) = if exr {
        let rendered = r::trace::render_hdr_observed(&sc, &ropts, &|_, total| bar.tick(total));
        bar.finish();
        let (hdr, stats) = rendered.map_err(CliError::msg)?;
        let t = Instant::now();
        let bytes = r::trace::encode_exr(&hdr).map_err(CliError::msg)?;
        let frame = r::Frame { image: r::trace::to_image(&hdr, ropts.transfer), covered: hdr.covered };
        (frame, stats, bytes, t.elapsed())
    } else {
        let rendered = r::render_observed(&sc, &ropts, &|_, total| bar.tick(total));
        bar.finish();
        let (frame, stats) = rendered.map_err(CliError::msg)?;
        let t = Instant::now();
        let png = frame.image.encode_png().map_err(CliError::msg)?;
        (frame, stats, png, t.elapsed())
    };
    a.out.force.write(&out, &bytes, is_ours)?;
    let wall = t0.elapsed();
    if stats.nan > 0 {
        eprintln!("warning: {} kernel evaluations returned NaN or ±inf and were shaded as no light", stats.nan);
    }
    if a.stats || a.json.on {
        let cut = r::cutoff_effect(&sc, &ropts, &frame, &stats).map_err(CliError::msg)?;
        if a.json.on {
            let t = report::Times { encode, wall };
            let samples = sc.width * sc.height * ropts.aa.unwrap_or(sc.aa).pow(2);
            let tier = lobe::render::program::program_backend(backend, samples);
            let j = report::StatsReport::new(&stats, &t, tier.name(), &sc.materials, cut.as_ref());
            println!("{}", common::to_json(&j)?);
        } else {
            eprint!("{}", report::stats_text(&stats, encode));
            eprint!("{}", report::cutoff_text(cut.as_ref()));
        }
    }
    if !a.quiet {
        eprintln!("wrote {} ({}×{})", out.display(), stats.width, stats.height);
    }
    Ok(())
}

/// The render's progress on stderr: an indicatif bar that appears only once the render has run for half a
/// second (a quick render prints nothing).
struct TileBar {
    bar: Option<indicatif::ProgressBar>,
    start: Instant,
    shown: std::sync::atomic::AtomicBool,
}

impl TileBar {
    fn new(enabled: bool) -> TileBar {
        let bar = enabled.then(|| {
            let b = indicatif::ProgressBar::with_draw_target(None, indicatif::ProgressDrawTarget::hidden());
            if let Ok(style) = indicatif::ProgressStyle::with_template("rendering {bar:40} {pos}/{len} tiles {elapsed}") {
                b.set_style(style);
            }
            b
        });
        TileBar { bar, start: Instant::now(), shown: std::sync::atomic::AtomicBool::new(false) }
    }
    fn tick(&self, total: u64) {
        use std::sync::atomic::Ordering;
        let Some(b) = &self.bar else { return };
        if !self.shown.load(Ordering::Relaxed)
            && self.start.elapsed() > std::time::Duration::from_millis(500)
            && !self.shown.swap(true, Ordering::Relaxed)
        {
            b.set_length(total);
            b.set_draw_target(indicatif::ProgressDrawTarget::stderr());
        }
        b.inc(1);
    }
    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_are_bounded() {
        assert_eq!(parse_size("1024").unwrap(), (1024, 1024));
        assert_eq!(parse_size("640x480").unwrap(), (640, 480));
        assert!(parse_size("5000").is_err());
        assert!(parse_size("0").is_err());
        assert!(parse_size("axb").is_err());
    }

    #[test]
    fn spp_is_bounded_with_a_hint_and_strategies_parse() {
        assert_eq!(parse_spp("64").unwrap(), 64);
        assert!(parse_spp("0").unwrap_err().contains("outside 1..=65536"));
        assert!(parse_spp("1000000000").unwrap_err().contains("a few hundred"));
        assert!(parse_spp("x").is_err());
        assert_eq!(parse_strategy("env").unwrap(), r::trace::Strategy::Env);
        assert!(parse_strategy("light").unwrap_err().contains("mis"));
        assert!(is_exr_path(Path::new("a/b.EXR")) && !is_exr_path(Path::new("b.png")));
    }
}
