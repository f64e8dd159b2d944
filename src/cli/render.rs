//! `lobe render SCENE [-o out.png] [--size 1024] [--set n=200] [--backend jit|interp] [--threads N] [--stats [--json]]`

use super::args::{self, BackendArg, Json, Output, Params};
use super::common::{self, CliError};
use crate::render::image::{self, Transfer};
use crate::render::scene::{self, LobeCompiler, LoadOptions};
use crate::render::{self as r, CutoffEffect, RenderOptions, RenderStats};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
#[command(mut_arg("output", args::help("Output PNG (default: the scene's name with .png, in the current directory)")))]
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
    /// How materials are shaded: `program` compiles each material's whole shading (geometry, every light, F,
    /// colour) into one program that the chosen backend runs, so `--backend interp` runs the same program;
    /// `spans` runs Rust loops for the geometry and calls the backend only for F (faster today on scenes with
    /// several lights and an expensive formula; see BENCHMARKS.md). Both give the same image.
    #[arg(long, value_enum, default_value_t = Shading::Program)]
    pub shading: Shading,
}

/// `--shading`: see [`RenderArgs::shading`].
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shading {
    Program,
    Spans,
}

pub use crate::render::parse_size;

/// The default output path: `<scene stem>.png` in the current directory.
pub fn default_output(scene: &Path) -> PathBuf {
    let stem = scene.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "render".into());
    PathBuf::from(format!("{stem}.png"))
}

pub fn run(a: &RenderArgs) -> Result<(), CliError> {
    let out = a.out.path.clone().unwrap_or_else(|| default_output(&a.scene));
    // Refuse a bad output path before doing any work, and write nothing unless everything succeeds.
    a.out.force.check(&out, image::is_lobe_png)?;
    Output::png_only(&out)?;
    let opts = LoadOptions { size: a.size, set: a.set.list(), formula_override: None };
    let sc = scene::load_scene(&a.scene, &opts, &LobeCompiler { backend: a.backend.kind, math: a.backend.math.mode })?;
    let ropts = RenderOptions {
        threads: a.threads,
        tile: a.tile as usize,
        transfer: if a.srgb { Transfer::Srgb } else { Transfer::Linear },
        cutoff: true,
        program: a.shading == Shading::Program,
    };
    let t0 = Instant::now();
    common::check_threads(a.threads)?;
    let bar = TileBar::new(!a.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr()));
    let rendered = r::render_observed(&sc, &ropts, &|_, total| bar.tick(total));
    bar.finish();
    let (frame, stats) = rendered.map_err(CliError::msg)?;
    let t = Instant::now();
    let png = frame.image.encode_png().map_err(CliError::msg)?;
    let encode = t.elapsed();
    a.out.force.write(&out, &png, image::is_lobe_png)?;
    let wall = t0.elapsed();
    if stats.nan > 0 {
        eprintln!("warning: {} kernel evaluations returned NaN or ±inf and were shaded as no light", stats.nan);
    }
    if a.stats || a.json.on {
        let cut = r::cutoff_effect(&sc, &ropts, &frame, &stats).map_err(CliError::msg)?;
        let t = Times { encode, wall };
        if a.json.on {
            let mut j = stats_json(&stats, &t, a.backend.kind.name(), &math_of(&sc.materials), cut.as_ref());
            j["shading"] = serde_json::json!(if ropts.program { "program" } else { "spans" });
            println!("{j}");
        } else {
            eprint!("{}", format_stats(&stats, encode));
            eprint!("{}", format_cutoff(cut.as_ref()));
        }
    }
    if !a.quiet {
        eprintln!("wrote {} ({}×{})", out.display(), stats.width, stats.height);
    }
    Ok(())
}

/// The math modes of the scene's kernels for the report: `precise`, `fast`, or `fast+precise` when materials
/// differ (scene key `math`).
pub fn math_of(materials: &[r::Material]) -> String {
    let mut modes: Vec<&str> = materials.iter().map(|m| m.math.name()).collect();
    modes.sort_unstable();
    modes.dedup();
    modes.join("+")
}

/// Wall times the CLI measures around the render.
pub struct Times {
    pub encode: std::time::Duration,
    /// Render, encode and write.
    pub wall: std::time::Duration,
}

/// The `--stats --json` object (keys listed in README.md). Times in ms except the per-pixel/per-element ns.
pub fn stats_json(s: &RenderStats, t: &Times, backend: &str, math: &str, cut: Option<&CutoffEffect>) -> serde_json::Value {
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    let cutoff = cut.map(|c| {
        serde_json::json!({
            "skipped_evals": c.skipped,
            "max_channel_diff": c.max_channel_diff,
            "pixels_differing": c.pixels_differing,
            "manhattan": c.metrics.manhattan,
            "psnr": if c.metrics.psnr.is_finite() { serde_json::json!(c.metrics.psnr) } else { serde_json::Value::Null },
        })
    });
    serde_json::json!({
        "width": s.width,
        "height": s.height,
        "threads": s.threads,
        "backend": backend,
        "math": math,
        "triangles": s.triangles,
        "tiles_touched": s.tiles_touched,
        "visible_px": s.visible_pixels,
        "evals": s.evals,
        "kernel_calls": s.kernel_calls,
        "nan": s.nan,
        "shade_ns_per_px": s.shade_ns_per_px(),
        "geometry_ns_per_px": s.geometry_ns_per_px(),
        "kernel_ns_per_eval": s.kernel_ns_per_eval(),
        "setup_ms": ms(s.setup),
        "raster_ms": ms(s.raster_cpu),
        "shade_ms": ms(s.shade_cpu),
        "kernel_ms": ms(s.kernel_cpu),
        "program_compile_ms": ms(s.program_compile),
        "render_ms": ms(s.render_wall),
        "encode_ms": ms(t.encode),
        "wall_ms": ms(t.wall),
        "mpixels_per_s": s.mpixels_per_s(),
        "cutoff": cutoff,
    })
}

/// The `--stats` lines about the cut-off (empty without one).
pub fn format_cutoff(cut: Option<&CutoffEffect>) -> String {
    match cut {
        None => String::new(),
        Some(c) => format!(
            "  cut-off: {} evaluations skipped; against the full render: max channel difference {}, {} pixels differ, mean |Δ gray| {:.4}\n",
            c.skipped, c.max_channel_diff, c.pixels_differing, c.metrics.manhattan
        ),
    }
}

/// The `--stats` report.
pub fn format_stats(s: &RenderStats, encode: std::time::Duration) -> String {
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    format!(
        "render: {}×{} px, {} thread(s), {} triangles, {}/{} tiles touched\n\
         \x20 time: {:.2} ms wall ({:.2} Mpixel/s); setup+binning {:.2} ms; raster {:.2} ms cpu; shading {:.2} ms cpu (compiled code {:.2}); encode {:.2} ms; shading programs built in {:.2} ms\n\
         \x20 shading: {} visible px, {:.1} ns cpu per visible px ({:.1} outside compiled code), {} evaluations of F ({:.2} ns of compiled code each) in {} calls, {} NaN\n",
        s.width,
        s.height,
        s.threads,
        s.triangles,
        s.tiles_touched,
        s.tiles,
        ms(s.render_wall),
        s.mpixels_per_s(),
        ms(s.setup),
        ms(s.raster_cpu),
        ms(s.shade_cpu),
        ms(s.kernel_cpu),
        ms(encode),
        ms(s.program_compile),
        s.visible_pixels,
        s.shade_ns_per_px(),
        s.geometry_ns_per_px(),
        s.evals,
        s.kernel_ns_per_eval(),
        s.kernel_calls,
        s.nan
    )
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
}
