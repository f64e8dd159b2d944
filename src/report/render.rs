//! What the render command's statistics report about a render: the stage split as text, and [`StatsReport`],
//! its JSON object (keys listed in docs/commands.md). Times are in ms except the per-pixel and per-evaluation ns.

use crate::render::{CutoffEffect, Material, RenderStats};
use serde::Serialize;
use std::time::Duration;

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Wall times measured around the render by its caller.
pub struct Times {
    pub encode: Duration,
    /// Render, encode and write.
    pub wall: Duration,
}

/// The statistics as a JSON object.
#[derive(Serialize)]
pub struct StatsReport {
    pub width: usize,
    pub height: usize,
    pub threads: usize,
    pub backend: &'static str,
    pub math: String,
    pub triangles: usize,
    pub tiles_touched: usize,
    pub visible_px: u64,
    pub evals: u64,
    pub kernel_calls: u64,
    pub nan: u64,
    pub shade_ns_per_px: f64,
    pub geometry_ns_per_px: f64,
    pub kernel_ns_per_eval: f64,
    pub setup_ms: f64,
    pub raster_ms: f64,
    pub shade_ms: f64,
    pub kernel_ms: f64,
    pub program_compile_ms: f64,
    pub render_ms: f64,
    pub encode_ms: f64,
    pub wall_ms: f64,
    pub mpixels_per_s: f64,
    /// What the materials' cut-offs changed against the frame rendered without them; `None` without one.
    pub cutoff: Option<CutoffReport>,
    /// Always `program`: every material shades through its compiled shading program (the key stays for tools
    /// that read it).
    pub shading: &'static str,
    /// Under an environment with MIS: per material name, the probability that a camera sample draws its
    /// direction from the environment (the pilot's choice; docs/scenes.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub env_fraction: Option<std::collections::BTreeMap<String, f64>>,
}

/// [`CutoffEffect`] in the report.
#[derive(Serialize)]
pub struct CutoffReport {
    pub skipped_evals: u64,
    pub max_channel_diff: u8,
    pub pixels_differing: u64,
    pub manhattan: f64,
    /// `null` when the frames are identical (infinite PSNR).
    pub psnr: Option<f64>,
}

impl StatsReport {
    /// The report of a render on `backend` with the scene's `materials`.
    pub fn new(s: &RenderStats, t: &Times, backend: &'static str, materials: &[Material], cut: Option<&CutoffEffect>) -> Self {
        StatsReport {
            width: s.width,
            height: s.height,
            threads: s.threads,
            backend,
            math: math_of(materials),
            triangles: s.triangles,
            tiles_touched: s.tiles_touched,
            visible_px: s.visible_pixels,
            evals: s.evals,
            kernel_calls: s.kernel_calls,
            nan: s.nan,
            shade_ns_per_px: s.shade_ns_per_px(),
            geometry_ns_per_px: s.geometry_ns_per_px(),
            kernel_ns_per_eval: s.kernel_ns_per_eval(),
            setup_ms: ms(s.setup),
            raster_ms: ms(s.raster_cpu),
            shade_ms: ms(s.shade_cpu),
            kernel_ms: ms(s.kernel_cpu),
            program_compile_ms: ms(s.program_compile),
            render_ms: ms(s.render_wall),
            encode_ms: ms(t.encode),
            wall_ms: ms(t.wall),
            mpixels_per_s: s.mpixels_per_s(),
            cutoff: cut.map(|c| CutoffReport {
                skipped_evals: c.skipped,
                max_channel_diff: c.max_channel_diff,
                pixels_differing: c.pixels_differing,
                manhattan: c.metrics.manhattan,
                psnr: c.metrics.psnr.is_finite().then_some(c.metrics.psnr),
            }),
            shading: "program",
            env_fraction: (!s.env_fractions.is_empty()).then(|| materials.iter().zip(&s.env_fractions).map(|(m, c)| (m.name.clone(), *c)).collect()),
        }
    }
}

/// The math modes of the scene's kernels: `precise`, `fast`, or `fast+precise` when materials differ (scene
/// key `math`).
pub(crate) fn math_of(materials: &[Material]) -> String {
    let mut modes: Vec<&str> = materials.iter().map(|m| m.math.name()).collect();
    modes.sort_unstable();
    modes.dedup();
    modes.join("+")
}

/// The statistics as text: size, threads, the time of each stage, and the shading throughput.
pub fn stats_text(s: &RenderStats, encode: Duration) -> String {
    let mut text = format!(
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
    );
    if !s.env_fractions.is_empty() {
        let c: Vec<String> = s.env_fractions.iter().map(|c| format!("{c:.2}")).collect();
        text += &format!("  MIS: each material's share of directions drawn from the environment (the pilot's choice): {}\n", c.join(", "));
    }
    text
}

/// The statistics' lines about the cut-off (empty without one).
pub fn cutoff_text(cut: Option<&CutoffEffect>) -> String {
    match cut {
        None => String::new(),
        Some(c) => format!(
            "  cut-off: {} evaluations skipped; against the full render: max channel difference {}, {} pixels differ, mean |Δ gray| {:.4}\n",
            c.skipped, c.max_channel_diff, c.pixels_differing, c.metrics.manhattan
        ),
    }
}
