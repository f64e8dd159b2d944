//! Plots: lobes against angle (cartesian or polar, like the papers' figures 2.2/3.3 and BRDF Explorer), error
//! curves against a reference, and the speed-versus-error scatter of `lobe bench`.
//!
//! Design: plotters draws into memory (an RGB buffer for PNG, a string for SVG), the bytes are encoded here
//! and handed to the caller, which writes them atomically — a failed plot never leaves a broken file. The font
//! (DejaVu Sans, assets/fonts, free licence) is compiled in, so plots look the same on a machine with no fonts.
//!
//! The speed-versus-error scatter is laid out by hand in pixels rather than through plotters' chart mesh: its
//! 1-2-5 log ticks, the "0" band for exact rows and the label placement all need to know where every point and
//! text box lands. Text is measured with the backend's own font metrics, placement ([`place_labels`]) is a pure
//! function of those boxes (tested without rendering), and whatever cannot be shown is named in a footnote.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::sync::Once;

/// One curve: a label and (x, y) points.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Output format, chosen from the file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Png,
    Svg,
}

impl Format {
    pub fn from_path(p: &std::path::Path) -> Result<Format, String> {
        match p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
            Some("png") => Ok(Format::Png),
            Some("svg") => Ok(Format::Svg),
            _ => Err(format!("`{}`: plots are written as .png or .svg", p.display())),
        }
    }
}

/// Samples a kernel as a one-dimensional lobe: value against the angle (degrees, 0..90 in steps of 0.25) from
/// the lobe axis, under the lobe convention of [`crate::numerics::lobe_inputs`].
pub fn lobe_points(ev: &dyn crate::Evaluator, used: crate::ir::InputSet, params: &[f64]) -> Vec<(f64, f64)> {
    let (lobe, _) = crate::numerics::choose_lobe_input(used);
    (0..=360)
        .map(|i| {
            let deg = i as f64 * 0.25;
            (deg, ev.eval(&crate::numerics::lobe_inputs(deg.to_radians().cos(), lobe), params))
        })
        .collect()
}

/// Samples a kernel in the plane of incidence: L at `theta_i_deg` from N (azimuth 0), V at the signed angle
/// θₒ ∈ [−90°, 90°] from N in the same plane (V = (sin θₒ, 0, cos θₒ); the mirror direction is θₒ = −θᵢ), in
/// steps of 0.25°, through [`crate::frame::inputs_from_dirs`] (so a formula and a measured table see the same
/// geometry).
pub fn incidence_points(ev: &dyn crate::Evaluator, params: &[f64], theta_i_deg: f64) -> Vec<(f64, f64)> {
    incidence_points_at(ev, params, theta_i_deg, 0.0)
}

/// [`incidence_points`] with the plane of incidence turned by `phi_i_deg` about N (L at azimuth φᵢ, V in the
/// same plane): the same curve for an isotropic formula, another for one that reads the tangent frame.
pub(crate) fn incidence_points_at(ev: &dyn crate::Evaluator, params: &[f64], theta_i_deg: f64, phi_i_deg: f64) -> Vec<(f64, f64)> {
    let ti = theta_i_deg.to_radians();
    let (sp, cp) = phi_i_deg.to_radians().sin_cos();
    // At φᵢ = 0 the y components are +0 exactly (no −0 from a negative sine times 0).
    let turn = |x: f64, z: f64| if phi_i_deg == 0.0 { [x, 0.0, z] } else { [x * cp, x * sp, z] };
    let l = turn(ti.sin(), ti.cos());
    (0..=720)
        .map(|i| {
            let deg = -90.0 + i as f64 * 0.25;
            let t = deg.to_radians();
            (deg, ev.eval(&crate::frame::inputs_from_dirs(l, turn(t.sin(), t.cos())), params))
        })
        .collect()
}

/// How to draw lobes.
#[derive(Clone, Debug)]
pub struct LobeOptions {
    pub title: String,
    pub polar: bool,
    pub log: bool,
    pub size: (u32, u32),
}

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        // The bundled font is valid; if registration failed, text would be missing but plotting still works.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../../assets/fonts/DejaVuSans.ttf"),
        );
    });
}

/// Line colours: the Okabe–Ito colour-blind-safe set (its yellow left out, too pale on white; its black
/// softened) and four of Paul Tol's, in an order that keeps neighbours far apart.
const PALETTE: [RGBColor; 12] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(51, 51, 51),
    RGBColor(136, 34, 85),
    RGBColor(153, 153, 51),
    RGBColor(51, 34, 136),
    RGBColor(68, 170, 153),
    RGBColor(140, 140, 140),
];

/// Dash patterns (on, off, on, off, … in pixels): solid, dashed, dotted, dash-dot, long dash. Five is prime
/// to the twelve colours, so series i gets (colour i mod 12, dash i mod 5) and the first 60 are all distinct.
const DASHES: [&[f64]; 5] = [&[], &[7.0, 4.0], &[1.5, 3.0], &[7.0, 3.0, 1.5, 3.0], &[14.0, 4.0]];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// How series `i` of `n` is drawn: colour, dash pattern and width in pixels. Earlier series are wider (3.5 px
/// down to 1.5 px) and drawn first, so a curve exactly under a later one still shows along both its edges.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LineStyle {
    color: RGBColor,
    dash: &'static [f64],
    width: f64,
}

fn line_style(i: usize, n: usize) -> LineStyle {
    let width = if n <= 1 { 2.0 } else { 1.5 + 2.0 * (n - 1 - i.min(n - 1)) as f64 / (n - 1) as f64 };
    LineStyle { color: color(i), dash: DASHES[i % DASHES.len()], width }
}

type DrawResult<T> = Result<T, String>;

fn err<E: std::fmt::Display>(e: E) -> String {
    format!("plotting failed: {e}")
}

/// Plots drawn through [`figure`] are drawn at this many times their size: the PNG is then averaged down
/// k × k (anti-aliased lines and text), the SVG keeps the k× user units under a 1× `width`/`height` with a
/// `viewBox`, so its coordinates have 1/k-pixel precision.
const SUPERSAMPLE: u32 = 4;
/// The PNG drawing buffer is kept under this many pixels: big images are drawn at a smaller factor.
const MAX_DRAW_PIXELS: u64 = 40_000_000;

const FIG_TITLE_PX: f64 = 20.0;
const FIG_TICK_PX: f64 = 14.0;
const FIG_DESC_PX: f64 = 15.0;
const FIG_LEGEND_PX: f64 = 14.0;

/// An axis in plotted units: log10 of the value on a log axis.
#[derive(Clone, Debug)]
struct Axis<'a> {
    lo: f64,
    hi: f64,
    log: bool,
    desc: &'a str,
}

/// One tick: position in plotted units, and its label if it has one (an unlabelled tick is a minor grid line).
#[derive(Clone, Debug, PartialEq)]
struct AxisTick {
    at: f64,
    label: Option<String>,
}

impl Axis<'_> {
    /// Ticks whose labels lie at least `min_px` apart on an axis `len_px` long: 1-2-5 steps on a linear axis
    /// (labels written from integers, so no 0.30000000000000004), [`log_ticks`] on a log axis.
    fn ticks(&self, len_px: f64, min_px: f64) -> Vec<AxisTick> {
        if self.log {
            let ticks = log_ticks(self.lo, self.hi, len_px, min_px);
            // One style per axis: when some label needs a power of ten, every label is written as one.
            let powers = ticks.iter().any(|t| t.labelled && !(-4..=4).contains(&t.exp));
            let label = |t: &Tick| if powers { power_label(t) } else { tick_label(t) };
            return ticks.iter().map(|t| AxisTick { at: t.value().log10(), label: t.labelled.then(|| label(t)) }).collect();
        }
        linear_ticks(self.lo, self.hi, len_px, min_px)
    }
}

/// Labelled ticks at multiples of the smallest 1-2-5 step that keeps them `min_px` apart.
fn linear_ticks(lo: f64, hi: f64, len_px: f64, min_px: f64) -> Vec<AxisTick> {
    let span = hi - lo;
    if !(span > 0.0 && span.is_finite() && len_px > 0.0) {
        return vec![];
    }
    let mut e = (span * min_px.max(1.0) / len_px).log10().floor() as i32 - 1;
    loop {
        for m in [1i64, 2, 5] {
            let step = m as f64 * 10f64.powi(e);
            if step * len_px / span >= min_px || e > 300 {
                let (i0, i1) = ((lo / step - 1e-9).ceil() as i64, (hi / step + 1e-9).floor() as i64);
                // One style per axis: when some label needs d.dd×10ⁿ, every label is written so.
                let sci = (i0..=i1).any(|i| decimal(i * m, e, false).contains('×'));
                return (i0..=i1).map(|i| AxisTick { at: i as f64 * step, label: Some(decimal(i * m, e, sci)) }).collect();
            }
        }
        e += 1;
    }
}

/// q·10^e written exactly: plain decimals while they stay short (at most 6 digits), d.dd×10ⁿ otherwise or
/// when `sci`; minus as U+2212.
fn decimal(q: i64, e: i32, sci: bool) -> String {
    if q == 0 {
        return "0".into();
    }
    let (mut q, mut e) = (q, e);
    while q % 10 == 0 {
        q /= 10;
        e += 1;
    }
    let sign = if q < 0 { "−" } else { "" };
    let digits = q.unsigned_abs().to_string();
    let n = digits.len() as i32;
    let plain = if sci {
        None
    } else if e >= 0 {
        (n + e <= 6).then(|| format!("{digits}{}", "0".repeat(e as usize)))
    } else if n > -e {
        let (a, b) = digits.split_at((n + e) as usize);
        Some(format!("{a}.{b}"))
    } else {
        (-e <= 6).then(|| format!("0.{}{digits}", "0".repeat((-e - n) as usize)))
    };
    plain.map(|p| format!("{sign}{p}")).unwrap_or_else(|| {
        let mantissa = if n > 1 { format!("{}.{}", &digits[..1], &digits[1..]) } else { digits.clone() };
        format!("{sign}{mantissa}×10{}", superscript(e + n - 1))
    })
}

fn superscript(e: i32) -> String {
    const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    e.to_string().chars().map(|c| c.to_digit(10).map_or('⁻', |d| SUP[d as usize])).collect()
}

/// One curve in plotted units, broken where a value cannot be drawn (NaN, or ≤ 0 on a log axis).
struct Curve {
    name: String,
    runs: Vec<Vec<(f64, f64)>>,
}

impl Curve {
    fn new(name: &str, points: impl Iterator<Item = Option<(f64, f64)>>) -> Curve {
        let mut runs: Vec<Vec<(f64, f64)>> = vec![vec![]];
        for p in points {
            match p.filter(|p| p.0.is_finite() && p.1.is_finite()) {
                Some(p) => runs.last_mut().expect("one run at least").push(p),
                None if runs.last().is_some_and(|r| !r.is_empty()) => runs.push(vec![]),
                None => {}
            }
        }
        runs.retain(|r| !r.is_empty());
        Curve { name: name.to_string(), runs }
    }
}

/// A cartesian figure: title, axes, curves (series i drawn in [`line_style`] i) and a legend to the right of
/// the plot. `to_scale` (a polar plot): one unit gets as many pixels across as up, the x range widened about
/// its middle or the y range upwards (y = 0 is the surface) to fill the plot. `light`: a grey ray from the origin, named in the legend.
struct Figure<'a> {
    title: &'a str,
    x: Axis<'a>,
    y: Axis<'a>,
    curves: Vec<Curve>,
    to_scale: bool,
    light: Option<(f64, f64)>,
}

/// Where a figure's parts go, in drawing pixels (k× the image's).
struct Layout<'a> {
    plot: Rect,
    x: Axis<'a>,
    y: Axis<'a>,
    xt: Vec<AxisTick>,
    yt: Vec<AxisTick>,
    legend: Vec<(String, Option<LineStyle>)>,
    legend_cols: usize,
    legend_col_w: f64,
    legend_px: f64,
}

/// Draws a [`Figure`] on `root` at scale `k` (drawing pixels per image pixel); `ink_shift` (em) moves text
/// down to centre it on its anchor (the bitmap backend's baseline sits higher than an SVG viewer's).
fn figure<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, f: &Figure, k: f64, ink_shift: f64) -> DrawResult<()> {
    let (w, h) = root.dim_in_pixel();
    let (w, h) = (w as f64, h as f64);
    let measure = |s: &str, px: f64| -> f64 {
        root.estimate_text_size(s, &("sans-serif", px * k).into_font().into_text_style(root)).map_or(0.0, |t| t.0 as f64)
    };
    let text = |s: &str, px: f64, (x, y): (f64, f64), hpos: HPos, c: RGBColor| -> DrawResult<()> {
        let style = ("sans-serif", px * k).into_font().color(&c).pos(Pos::new(hpos, VPos::Center));
        root.draw_text(s, &style, (x.round() as i32, (y + ink_shift * px * k).round() as i32)).map_err(err)
    };
    let l = layout(f, (w, h), k, &measure);
    let ink = RGBColor(30, 30, 30);
    let p = l.plot;
    let to_px = |(x, y): (f64, f64)| {
        (p.x0 + (x - l.x.lo) / (l.x.hi - l.x.lo) * (p.x1 - p.x0), p.y1 - (y - l.y.lo) / (l.y.hi - l.y.lo) * (p.y1 - p.y0))
    };
    let ipt = |(x, y): (f64, f64)| (x.round() as i32, y.round() as i32);
    let line = |a: (f64, f64), b: (f64, f64), c: RGBColor, width: f64| -> DrawResult<()> {
        root.draw(&PathElement::new(vec![ipt(a), ipt(b)], c.stroke_width((width * k).round().max(1.0) as u32))).map_err(err)
    };

    // Grid, then curves (clipped to the plot), then the frame, ticks and labels over them.
    for t in &l.xt {
        let x = to_px((t.at, l.y.lo)).0;
        let c = if t.label.is_some() { RGBColor(218, 218, 218) } else { RGBColor(238, 238, 238) };
        line((x, p.y0), (x, p.y1), c, 1.0)?;
    }
    for t in &l.yt {
        let y = to_px((l.x.lo, t.at)).1;
        let c = if t.label.is_some() { RGBColor(218, 218, 218) } else { RGBColor(238, 238, 238) };
        line((p.x0, y), (p.x1, y), c, 1.0)?;
    }
    if let Some(dir) = f.light {
        let grey = RGBColor(150, 150, 150);
        for run in clip_polyline(&[to_px((0.0, 0.0)), to_px(dir)], &p) {
            stroke(root, &run, grey, 1.0, &[], k)?;
        }
    }
    let n = f.curves.len();
    for (i, c) in f.curves.iter().enumerate() {
        let s = line_style(i, n);
        for run in &c.runs {
            let px: Vec<(f64, f64)> = run.iter().map(|&q| to_px(q)).collect();
            for piece in clip_polyline(&px, &p) {
                stroke(root, &piece, s.color, s.width, s.dash, k)?;
            }
        }
    }
    root.draw(&Rectangle::new([ipt((p.x0, p.y0)), ipt((p.x1, p.y1))], ink.stroke_width(k.round() as u32))).map_err(err)?;
    let tick = 5.0 * k;
    for t in &l.xt {
        let x = to_px((t.at, l.y.lo)).0;
        let len = if t.label.is_some() { tick } else { tick * 0.6 };
        line((x, p.y1), (x, p.y1 + len), ink, 1.0)?;
        if let Some(s) = &t.label {
            text(s, FIG_TICK_PX, (x, p.y1 + tick + 4.0 * k + FIG_TICK_PX * k * 0.5), HPos::Center, ink)?;
        }
    }
    for t in &l.yt {
        let y = to_px((l.x.lo, t.at)).1;
        let len = if t.label.is_some() { tick } else { tick * 0.6 };
        line((p.x0 - len, y), (p.x0, y), ink, 1.0)?;
        if let Some(s) = &t.label {
            text(s, FIG_TICK_PX, (p.x0 - tick - 4.0 * k, y), HPos::Right, ink)?;
        }
    }
    let x_desc_y = p.y1 + tick + 4.0 * k + FIG_TICK_PX * k * 1.2 + 6.0 * k + FIG_DESC_PX * k * 0.5;
    text(l.x.desc, FIG_DESC_PX, ((p.x0 + p.x1) / 2.0, x_desc_y), HPos::Center, ink)?;
    let rotated = ("sans-serif", FIG_DESC_PX * k).into_font().transform(FontTransform::Rotate270).color(&ink).pos(Pos::new(HPos::Center, VPos::Center));
    let y_desc_x = 12.0 * k + FIG_DESC_PX * k * (0.6 + ink_shift);
    root.draw_text(l.y.desc, &rotated, ipt((y_desc_x, (p.y0 + p.y1) / 2.0))).map_err(err)?;
    text(f.title, FIG_TITLE_PX, (w / 2.0, 12.0 * k + FIG_TITLE_PX * k * 0.6), HPos::Center, ink)?;

    // Legend: a column (or several) right of the plot, each sample drawn as its curve is.
    let row = l.legend_px * k * 1.5;
    let rows = l.legend.len().div_ceil(l.legend_cols.max(1));
    for (j, (name, style)) in l.legend.iter().enumerate() {
        let x = p.x1 + 14.0 * k + (j / rows.max(1)) as f64 * l.legend_col_w;
        let y = p.y0 + 4.0 * k + (j % rows.max(1)) as f64 * row + row / 2.0;
        let s = style.unwrap_or(LineStyle { color: RGBColor(150, 150, 150), dash: &[], width: 1.0 });
        stroke(root, &[(x, y), (x + 30.0 * k, y)], s.color, s.width, s.dash, k)?;
        text(name, l.legend_px, (x + 36.0 * k, y), HPos::Left, ink)?;
    }
    Ok(())
}

/// Sizes the plot area from what must fit around it: title above; tick labels, axis descriptions and half the
/// widest x label (so the last is not cut) around; the legend to the right, in as many columns as its height
/// needs. With `to_scale`, the ranges are widened to equal units and the ticks measured again.
fn layout<'a>(f: &Figure<'a>, (w, h): (f64, f64), k: f64, measure: &dyn Fn(&str, f64) -> f64) -> Layout<'a> {
    let margin = 12.0 * k;
    let top = margin + FIG_TITLE_PX * k * 1.2 + 8.0 * k;
    let tick_gap = 5.0 * k + 4.0 * k;
    let bottom = margin + FIG_DESC_PX * k * 1.2 + 6.0 * k + FIG_TICK_PX * k * 1.2 + tick_gap;
    let mut legend: Vec<(String, Option<LineStyle>)> =
        f.curves.iter().enumerate().map(|(i, c)| (c.name.clone(), Some(line_style(i, f.curves.len())))).collect();
    if f.light.is_some() {
        legend.push(("light".into(), None));
    }
    // The legend takes at most 45 % of the width: a smaller font (down to 8 px) and more columns if need be,
    // then names shortened with "…".
    let plot_h = (h - top - bottom).max(10.0 * k);
    let fit = |px: f64| {
        let per_col = ((plot_h - 4.0 * k) / (px * k * 1.5)).floor().max(1.0) as usize;
        let cols = legend.len().div_ceil(per_col).max(1);
        let col_w = 36.0 * k + legend.iter().map(|e| measure(&e.0, px)).fold(0.0, f64::max) + 16.0 * k;
        (cols, col_w, cols as f64 * col_w + 14.0 * k)
    };
    let max_legend_w = w * 0.45;
    let legend_px = (8..=FIG_LEGEND_PX as usize).rev().map(|p| p as f64).find(|&p| fit(p).2 <= max_legend_w).unwrap_or(8.0);
    let (legend_cols, mut legend_col_w, mut legend_w) = fit(legend_px);
    if legend_w > max_legend_w {
        legend_col_w = (max_legend_w - 14.0 * k) / legend_cols as f64;
        let room = legend_col_w - 52.0 * k;
        for e in &mut legend {
            while measure(&e.0, legend_px) > room && e.0.chars().count() > 1 {
                e.0.pop();
                while e.0.ends_with('…') {
                    e.0.pop();
                }
                e.0.pop();
                e.0.push('…');
            }
        }
        legend_w = max_legend_w;
    }
    let (mut x, mut y) = (f.x.clone(), f.y.clone());
    let widest = |t: &[AxisTick]| t.iter().filter_map(|t| t.label.as_deref()).map(|s| measure(s, FIG_TICK_PX)).fold(0.0, f64::max);
    // Two rounds: label widths set the plot's size, which sets the ticks (and, to scale, the ranges).
    let mut left = margin + FIG_DESC_PX * k * 1.3 + tick_gap + measure("0.0000", FIG_TICK_PX);
    let mut right = margin.max(legend_w);
    let mut plot = Rect { x0: left, y0: top, x1: w - right, y1: h - bottom };
    let (mut xt, mut yt) = (vec![], vec![]);
    for _ in 0..3 {
        plot = Rect { x0: left, y0: top, x1: (w - right).max(left + 10.0 * k), y1: (h - bottom).max(top + 10.0 * k) };
        let (pw, ph) = (plot.x1 - plot.x0, plot.y1 - plot.y0);
        if f.to_scale {
            let xc = (f.x.lo + f.x.hi) / 2.0;
            let unit = ((f.x.hi - f.x.lo) / pw).max((f.y.hi - f.y.lo) / ph);
            (x.lo, x.hi) = (xc - unit * pw / 2.0, xc + unit * pw / 2.0);
            y.hi = y.lo + unit * ph;
        }
        // x labels need their width: measure a dense set, then space by the widest.
        let x_min = widest(&x.ticks(pw, 0.0)[..]).min(pw / 3.0) + 16.0 * k;
        xt = x.ticks(pw, x_min);
        yt = y.ticks(ph, FIG_TICK_PX * k * 2.2);
        left = margin + FIG_DESC_PX * k * 1.3 + tick_gap + widest(&yt);
        let last_half = xt.iter().rev().find_map(|t| t.label.as_deref()).map_or(0.0, |s| measure(s, FIG_TICK_PX) / 2.0);
        right = (margin + last_half).max(legend_w);
    }
    Layout { plot, x, y, xt, yt, legend, legend_cols, legend_col_w, legend_px }
}

/// The parts of a polyline inside `r` (Liang–Barsky on each segment), as separate runs.
fn clip_polyline(pts: &[(f64, f64)], r: &Rect) -> Vec<Vec<(f64, f64)>> {
    let mut runs: Vec<Vec<(f64, f64)>> = vec![];
    let mut open = false;
    let inside = |p: (f64, f64)| r.x0 <= p.0 && p.0 <= r.x1 && r.y0 <= p.1 && p.1 <= r.y1;
    if pts.len() == 1 && inside(pts[0]) {
        return vec![pts.to_vec()];
    }
    for s in pts.windows(2) {
        let (a, b) = (s[0], s[1]);
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        let mut visible = true;
        for (p, q) in [(-dx, a.0 - r.x0), (dx, r.x1 - a.0), (-dy, a.1 - r.y0), (dy, r.y1 - a.1)] {
            if p == 0.0 {
                visible &= q >= 0.0;
            } else if p < 0.0 {
                t0 = t0.max(q / p);
            } else {
                t1 = t1.min(q / p);
            }
        }
        if !visible || t0 > t1 {
            open = false;
            continue;
        }
        let at = |t: f64| (a.0 + dx * t, a.1 + dy * t);
        if !(open && t0 == 0.0) {
            runs.push(vec![at(t0)]);
        }
        runs.last_mut().expect("a run was opened").push(at(t1));
        open = t1 == 1.0;
    }
    runs
}

/// Draws a polyline (drawing pixels) `width` image pixels wide with a dash pattern (image pixels; empty:
/// solid) that runs on across vertices.
fn stroke<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, pts: &[(f64, f64)], c: RGBColor, width: f64, dash: &[f64], k: f64) -> DrawResult<()> {
    let style = c.stroke_width((width * k).round().max(1.0) as u32);
    let draw = |piece: &[(f64, f64)]| -> DrawResult<()> {
        let mut v: Vec<(i32, i32)> = piece.iter().map(|p| (p.0.round() as i32, p.1.round() as i32)).collect();
        v.dedup();
        if v.len() == 1 {
            v.push(v[0]);
        }
        root.draw(&PathElement::new(v, style)).map_err(err)
    };
    if dash.is_empty() {
        return draw(pts);
    }
    let mut piece: Vec<(f64, f64)> = vec![];
    let (mut j, mut left) = (0usize, dash[0] * k);
    if let Some(&p) = pts.first() {
        piece.push(p);
    }
    for s in pts.windows(2) {
        let (mut a, b) = (s[0], s[1]);
        let mut len = (b.0 - a.0).hypot(b.1 - a.1);
        while len > left {
            let t = left / len;
            a = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
            len -= left;
            if j % 2 == 0 {
                piece.push(a);
                draw(&piece)?;
                piece.clear();
            } else {
                piece.push(a);
            }
            j = (j + 1) % dash.len();
            left = dash[j] * k;
        }
        left -= len;
        if j % 2 == 0 {
            piece.push(b);
        }
    }
    if j % 2 == 0 && piece.len() > 1 {
        draw(&piece)?;
    }
    Ok(())
}

/// Lobes (value against angle in degrees, 0..90). Polar: radius = value, drawn on both sides of the axis.
pub fn lobes(series: &[Series], o: &LobeOptions, format: Format) -> DrawResult<Vec<u8>> {
    if o.polar && o.log {
        return Err("a log scale applies to cartesian plots only (a log radius has no zero)".into());
    }
    let values = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|v| v.is_finite());
    if values().next().is_none() {
        return Err("nothing to plot: no curve has a finite value (is the formula NaN or infinite everywhere?)".into());
    }
    let ymax = values().fold(0.0f64, f64::max).max(1e-12);
    let ymin_pos = values().filter(|v| *v > 0.0).fold(f64::INFINITY, f64::min);
    if o.log && !ymin_pos.is_finite() {
        return Err("nothing to plot on a log scale: no curve has a positive finite value (use a linear scale)".into());
    }
    let ymin_pos = ymin_pos.max(ymax * 1e-12);
    let fig = if o.polar {
        // Both sides of the axis: θ → −θ mirrored, in the signed-angle form `polar_figure` draws.
        let signed: Vec<Series> = series
            .iter()
            .map(|s| Series { name: s.name.clone(), points: s.points.iter().rev().map(|&(d, v)| (-d, v)).chain(s.points.iter().copied()).collect() })
            .collect();
        polar_figure(&o.title, &signed, None)
    } else if o.log {
        let curves = series
            .iter()
            .map(|s| Curve::new(&s.name, s.points.iter().map(|&(d, v)| (v >= ymin_pos).then(|| (d, v.log10())))))
            .collect();
        let y = Axis { lo: ymin_pos.log10(), hi: (ymax * 1.5).log10(), log: true, desc: "value (log)" };
        Figure { title: &o.title, x: Axis { lo: 0.0, hi: 90.0, log: false, desc: "angle (degrees)" }, y, curves, to_scale: false, light: None }
    } else {
        let ymin = values().fold(0.0f64, f64::min);
        let curves = series.iter().map(|s| Curve::new(&s.name, s.points.iter().map(|&p| Some(p)))).collect();
        let y = Axis { lo: ymin * 1.05, hi: ymax * 1.05, log: false, desc: "value" };
        Figure { title: &o.title, x: Axis { lo: 0.0, hi: 90.0, log: false, desc: "angle (degrees)" }, y, curves, to_scale: false, light: None }
    };
    render_figure(&fig, format, o.size)
}

/// A polar figure of signed-angle series (angle from the normal in degrees, −90..90; radius = value, negative
/// values drawn at 0), with both axes to the same scale (a circle stays a circle) and, when given, the
/// direction of the light (`light_deg`, on the opposite side from the mirror direction) as a grey ray.
fn polar_figure<'a>(title: &'a str, series: &[Series], light_deg: Option<f64>) -> Figure<'a> {
    let xy = |&(deg, v): &(f64, f64)| (v.max(0.0) * deg.to_radians().sin(), v.max(0.0) * deg.to_radians().cos());
    let curves: Vec<Curve> = series.iter().map(|s| Curve::new(&s.name, s.points.iter().map(|p| Some(xy(p))))).collect();
    // The lobes' own extent with the origin (5 % spare), not the largest value's circle: a narrow lobe fills
    // the height, a lobe to one side the width.
    // The light's direction is shown as long as the longest lobe.
    let radius = curves.iter().flat_map(|c| c.runs.iter().flatten()).fold(0.0f64, |m, p| m.max(p.0.hypot(p.1)));
    let light_end = light_deg.map(|t| (radius * t.to_radians().sin(), radius * t.to_radians().cos()));
    let pts = || curves.iter().flat_map(|c| c.runs.iter().flatten()).chain(light_end.iter());
    let (x0, x1) = pts().fold((0.0f64, 0.0f64), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let y1 = pts().fold(0.0f64, |m, p| m.max(p.1)).max(1e-12);
    let pad = (x1 - x0).max(y1) * 0.05;
    // The light is on the +x side (the mirror direction at −θᵢ), as far out as the plot can reach.
    let reach = 4.0 * (x1 - x0).max(y1);
    let light = light_deg.map(|t| (reach * t.to_radians().sin(), reach * t.to_radians().cos()));
    Figure {
        title,
        x: Axis { lo: x0 - pad, hi: x1 + pad, log: false, desc: "value · sin θ" },
        y: Axis { lo: 0.0, hi: y1 + pad, log: false, desc: "value · cos θ" },
        curves,
        to_scale: true,
        light,
    }
}

/// Lobes in the plane of incidence ([`incidence_points_at`] series) with the light at `theta_i_deg`: polar (to
/// scale, the light drawn) or cartesian against the signed view angle.
pub fn incidence_lobes(series: &[Series], o: &LobeOptions, theta_i_deg: f64, format: Format) -> DrawResult<Vec<u8>> {
    if o.log {
        return Err("the plane-of-incidence plot has a linear scale".into());
    }
    let finite = series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|v| v.is_finite());
    let ymax = finite.fold(f64::NEG_INFINITY, f64::max);
    if ymax == f64::NEG_INFINITY {
        return Err("nothing to plot: no curve has a finite value (is the formula NaN or infinite everywhere?)".into());
    }
    if !o.polar {
        let title = format!("{}, light at θᵢ = {theta_i_deg}°", o.title);
        let x_desc = "view angle θₒ in the plane of incidence (degrees; mirror at −θᵢ)";
        return curves_sized(series, &title, x_desc, "value", format, o.size);
    }
    let title = format!("{}, light at θᵢ = {theta_i_deg}°", o.title);
    render_figure(&polar_figure(&title, series, Some(theta_i_deg)), format, o.size)
}

/// Curves over any x range (e.g. the normalisation coefficient against n over a range of n).
pub fn curves(series: &[Series], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    curves_sized(series, title, x_desc, y_desc, format, (900, 600))
}

/// [`curves`] in an image of `size` pixels.
pub(crate) fn curves_sized(
    series: &[Series],
    title: &str,
    x_desc: &str,
    y_desc: &str,
    format: Format,
    size: (u32, u32),
) -> DrawResult<Vec<u8>> {
    let pts = || series.iter().flat_map(|s| s.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
    let (xmin, xmax) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (ymin, ymax) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if !(xmin.is_finite() && ymin.is_finite()) {
        return Err("nothing to plot: no finite points".into());
    }
    let (xmax, ymax) = (if xmax > xmin { xmax } else { xmin + 1.0 }, if ymax > ymin { ymax } else { ymin + 1.0 });
    let pad = (ymax - ymin) * 0.05;
    let curves = series.iter().map(|s| Curve::new(&s.name, s.points.iter().map(|&p| Some(p)))).collect();
    let fig = Figure {
        title,
        x: Axis { lo: xmin, hi: xmax, log: false, desc: x_desc },
        y: Axis { lo: ymin - pad, hi: ymax + pad, log: false, desc: y_desc },
        curves,
        to_scale: false,
        light: None,
    };
    render_figure(&fig, format, size)
}

fn render_figure(fig: &Figure, format: Format, size: (u32, u32)) -> DrawResult<Vec<u8>> {
    render_with(format, size, SUPERSAMPLE, |r, k| figure(r, fig, k, 0.17), |r, k| figure(r, fig, k, 0.0))
}

/// A comparison picture (columns A | B | |Δgray| heat map, `rows.len()` rows stacked, as
/// [`crate::render::compare::sweep_image`] makes it) with a heading over each column, a label beside each row
/// (e.g. "n = 50"; none when `rows` is empty or all empty) and to the right a colour bar of the heat map's ramp
/// from 0 (bottom) to `scale` gray levels (top), labelled. The pictures' pixels are copied as they are.
pub fn comparison_figure(img: &crate::base::image::Image, headings: [&str; 3], rows: &[String], scale: f64) -> DrawResult<crate::base::image::Image> {
    register_font();
    const PX: f64 = 13.0;
    let mut probe = [0u8; 3];
    let measure = {
        let root = BitMapBackend::with_buffer(&mut probe, (1, 1)).into_drawing_area();
        move |s: &str| root.estimate_text_size(s, &("sans-serif", PX).into_font().into_text_style(&root)).map_or(0, |t| t.0) as usize
    };
    let col = img.width / 3;
    let labelled = rows.iter().any(|r| !r.is_empty());
    let left = if labelled { rows.iter().map(|r| measure(r)).max().unwrap_or(0) + 16 } else { 8 };
    let ticks = [0.0, scale / 2.0, scale].map(short);
    let bar_title = "gray levels";
    let right = 12 + 14 + 6 + ticks.iter().map(|t| measure(t)).max().unwrap_or(0) + 10;
    let right = right.max(measure(bar_title) + 14);
    let (top, bottom) = (26usize, 8usize);
    let (w, h) = (left + img.width + right, top + img.height + bottom);
    let mut out = crate::base::image::Image::new(w, h);
    out.rgb.iter_mut().for_each(|v| *v = 255);
    for y in 0..img.height {
        let (src, dst) = (y * img.width * 3, ((top + y) * w + left) * 3);
        out.rgb[dst..dst + img.width * 3].copy_from_slice(&img.rgb[src..src + img.width * 3]);
    }
    // The bar: as tall as the picture, 0 at the bottom.
    let bar_x = left + img.width + 12;
    let bar_h = img.height.max(2);
    for y in 0..img.height {
        let c = crate::render::compare::heat(1.0 - y as f64 / (bar_h - 1) as f64);
        for x in bar_x..bar_x + 14 {
            out.set(x, top + y, c);
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut out.rgb, (w as u32, h as u32)).into_drawing_area();
        let ink = RGBColor(30, 30, 30);
        let text = |s: &str, x: usize, y: usize, hpos: HPos| -> DrawResult<()> {
            let style = ("sans-serif", PX).into_font().color(&ink).pos(Pos::new(hpos, VPos::Center));
            root.draw_text(s, &style, (x as i32, (y as f64 + 0.17 * PX).round() as i32)).map_err(err)
        };
        for (i, name) in headings.iter().enumerate() {
            // Shortened with "…" to its column's width.
            let mut s = name.to_string();
            while measure(&s) + 4 > col && s.chars().count() > 2 {
                let mut t = s.trim_end_matches('…').to_string();
                t.pop();
                s = format!("{t}…");
            }
            text(&s, left + i * col + col / 2, top / 2, HPos::Center)?;
        }
        if labelled {
            let row_h = img.height / rows.len().max(1);
            for (r, label) in rows.iter().enumerate() {
                text(label, left - 8, top + r * row_h + row_h / 2, HPos::Right)?;
            }
        }
        text(bar_title, bar_x + 7, top / 2, HPos::Center)?;
        for (j, t) in ticks.iter().enumerate() {
            let y = top + (img.height.saturating_sub(1) as f64 * (1.0 - j as f64 / 2.0)).round() as usize;
            root.draw(&PathElement::new(vec![((bar_x + 14) as i32, y as i32), ((bar_x + 18) as i32, y as i32)], ink.stroke_width(1))).map_err(err)?;
            text(t, bar_x + 21, y, HPos::Left)?;
        }
        root.present().map_err(err)?;
    }
    Ok(out)
}

/// One point of the speed-versus-error scatter.
#[derive(Clone, Debug)]
pub struct CostError {
    pub name: String,
    /// Cost, e.g. ns per evaluation.
    pub cost: f64,
    /// Error against the reference, e.g. mean |Δ| on the papers' grid; exactly 0 goes on the "0" band.
    pub error: f64,
    /// On the Pareto front (computed by the caller over all points, every series together).
    pub pareto: bool,
    /// Which run the point belongs to (e.g. "precise" or "fast" math): one marker shape and colour each.
    pub series: String,
}

/// Figure size of the scatter (pixels; the SVG uses the same user units).
const SCATTER_SIZE: (u32, u32) = (1200, 820);
const TITLE_PX: f64 = 22.0;
const LEGEND_PX: f64 = 14.0;
const TICK_PX: f64 = 14.0;
const DESC_PX: f64 = 16.0;
const LABEL_PX: f64 = 13.0;
const NOTE_PX: f64 = 12.0;
/// Half the side of a marker's box.
const MARKER: f64 = 5.0;
/// Height of the band that holds the error = 0 rows, and the gap between it and the log area.
const BAND: f64 = 40.0;
const BAND_GAP: f64 = 12.0;
/// Footnotes never take more than this many lines from the plot (a long list is cut with "…").
const MAX_NOTE_LINES: usize = 4;

/// Cost (x, log) against error (y, log), with a "0" band below for exact rows, the Pareto front as a
/// staircase, a legend per series and labels placed by [`place_labels`] so that none overlaps another, a point
/// or the frame; labels that find no room, and rows that cannot be placed at all, are named in a footnote.
pub fn speed_error(points: &[CostError], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    let s = Scatter::new(points, title, x_desc, y_desc)?;
    // ab_glyph in the bitmap backend puts the baseline ~0.17 em higher than an SVG viewer does for the same
    // anchor; the shift re-centres bitmap text in the boxes the labels were placed with.
    render_with(format, SCATTER_SIZE, 1, |r, _| s.draw(r, 0.17), |r, _| s.draw(r, 0.0))
}

/// An axis-aligned box in pixels (y grows downwards).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    /// Open intersection: boxes that only touch do not intersect.
    pub(crate) fn intersects(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
    pub(crate) fn contains(&self, o: &Rect) -> bool {
        self.x0 <= o.x0 && o.x1 <= self.x1 && self.y0 <= o.y0 && o.y1 <= self.y1
    }
    fn grow(&self, d: f64) -> Rect {
        Rect { x0: self.x0 - d, y0: self.y0 - d, x1: self.x1 + d, y1: self.y1 + d }
    }
    fn around(p: (f64, f64), r: f64) -> Rect {
        Rect { x0: p.0 - r, y0: p.1 - r, x1: p.0 + r, y1: p.1 + r }
    }
    fn nearest(&self, p: (f64, f64)) -> (f64, f64) {
        (p.0.clamp(self.x0, self.x1), p.1.clamp(self.y0, self.y1))
    }
    /// Whether the segment a–b passes through the box's interior (Liang–Barsky clipping).
    fn hit_by(&self, a: (f64, f64), b: (f64, f64)) -> bool {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for (p, q) in [(-dx, a.0 - self.x0), (dx, self.x1 - a.0), (-dy, a.1 - self.y0), (dy, self.y1 - a.1)] {
            if p == 0.0 {
                if q <= 0.0 {
                    return false;
                }
            } else {
                let t = q / p;
                if p < 0.0 {
                    t0 = t0.max(t);
                } else {
                    t1 = t1.min(t);
                }
            }
        }
        t1 - t0 > 1e-9
    }
}

fn segments_cross(a: [(f64, f64); 2], b: [(f64, f64); 2]) -> bool {
    let orient = |p: (f64, f64), q: (f64, f64), r: (f64, f64)| (q.0 - p.0) * (r.1 - p.1) - (q.1 - p.1) * (r.0 - p.0);
    let (d1, d2) = (orient(b[0], b[1], a[0]), orient(b[0], b[1], a[1]));
    let (d3, d4) = (orient(a[0], a[1], b[0]), orient(a[0], a[1], b[1]));
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

/// Where a label went: its text box and, when it sits away from its point, a leader line (point → box).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PlacedLabel {
    pub rect: Rect,
    pub leader: Option<[(f64, f64); 2]>,
}

/// What [`place_labels`] places: one label of `sizes[i]` (width, height) per point `anchors[i]`, whose
/// marker covers a square of half-side `marker`; every box stays inside `bounds`, off `obstacles`, and off
/// the `avoid` segments (e.g. the Pareto line) when some other position allows.
pub(crate) struct LabelProblem<'a> {
    pub anchors: &'a [(f64, f64)],
    pub sizes: &'a [(f64, f64)],
    pub marker: f64,
    pub bounds: Rect,
    pub obstacles: &'a [Rect],
    pub avoid: &'a [[(f64, f64); 2]],
}

/// Clear space kept around each label box, and the farthest a label may sit from its point.
const LABEL_PAD: f64 = 1.5;
const MAX_LEADER: f64 = 400.0;

/// Greedy, deterministic label placement. Points are taken most crowded first; each tries candidate boxes on
/// square rings of growing distance around its point (the 8 touching positions first, then rings with a leader
/// line), right/left before up/down, and takes the first box that leaves the bounds, the obstacles, every
/// marker, every placed box and every placed leader alone (its own leader crossing none of them) — preferring,
/// within two rings, one that also stays off the `avoid` segments and, if beside its point, is nearer to it
/// than to any other point. `None` only when no ring up to `MAX_LEADER` has room.
/// Cost: O(n² · candidates) box tests; 33 bench labels take milliseconds, far less than drawing them.
pub(crate) fn place_labels(p: &LabelProblem) -> Vec<Option<PlacedLabel>> {
    let n = p.anchors.len();
    let markers: Vec<Rect> = p.anchors.iter().map(|&a| Rect::around(a, p.marker + 1.0)).collect();
    let crowd = |i: usize| {
        let r = 3.0 * p.sizes[i].1.max(p.marker * 2.0);
        p.anchors.iter().filter(|a| (a.0 - p.anchors[i].0).hypot(a.1 - p.anchors[i].1) < r).count()
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(crowd(i)), i));
    let mut placed: Vec<Option<PlacedLabel>> = vec![None; n];
    for &i in &order {
        placed[i] = best_spot(p, i, &markers, &placed);
    }
    placed
}

/// Candidate directions of one ring, preferred first: near-horizontal (beside the point) before vertical.
fn ring_dirs(ring: usize) -> Vec<(f64, f64)> {
    if ring == 0 {
        return vec![(1.0, 0.0), (-1.0, 0.0), (1.0, -1.0), (1.0, 1.0), (-1.0, -1.0), (-1.0, 1.0), (0.0, -1.0), (0.0, 1.0)];
    }
    let k = if ring < 4 { 16 } else { 32 };
    let mut dirs: Vec<(usize, f64, f64)> = (0..k)
        .map(|j| {
            let a = j as f64 * std::f64::consts::TAU / k as f64;
            // Rank by distance from the horizontal; j breaks ties so the order is fixed.
            let rank = (a.sin().abs() * 1000.0) as usize * k + j;
            (rank, a.cos(), -a.sin())
        })
        .collect();
    dirs.sort_by_key(|d| d.0);
    dirs.into_iter().map(|d| (d.1, d.2)).collect()
}

fn best_spot(p: &LabelProblem, i: usize, markers: &[Rect], placed: &[Option<PlacedLabel>]) -> Option<PlacedLabel> {
    let (ax, ay) = p.anchors[i];
    let (w, h) = p.sizes[i];
    let gap = p.marker + 1.0 + LABEL_PAD + 1.0;
    let step = (h * 0.75).max(4.0);
    let others: Vec<&PlacedLabel> = placed.iter().flatten().collect();
    let mut fallback: Option<(usize, PlacedLabel)> = None;
    for ring in 0.. {
        let d = gap + ring as f64 * step;
        if d > MAX_LEADER {
            break;
        }
        if let Some((r, f)) = fallback {
            if ring > r + 2 {
                return Some(f);
            }
        }
        for (cx, cy) in ring_dirs(ring) {
            // Attach point on the square of half-side d; the box hangs off it away from the point.
            let s = d / cx.abs().max(cy.abs());
            let (tx, ty) = (ax + cx * s, ay + cy * s);
            let x0 = if cx > 0.38 { tx } else if cx < -0.38 { tx - w } else { tx - w / 2.0 };
            let y0 = if cy > 0.38 { ty } else if cy < -0.38 { ty - h } else { ty - h / 2.0 };
            let rect = Rect { x0, y0, x1: x0 + w, y1: y0 + h };
            let padded = rect.grow(LABEL_PAD);
            if !p.bounds.contains(&padded)
                || p.obstacles.iter().any(|o| o.intersects(&padded))
                || markers.iter().any(|m| m.intersects(&padded))
                || others.iter().any(|o| o.rect.grow(LABEL_PAD).intersects(&padded) || o.leader.is_some_and(|l| padded.hit_by(l[0], l[1])))
            {
                continue;
            }
            let leader = (ring > 0).then(|| {
                let q = rect.nearest((ax, ay));
                let len = (q.0 - ax).hypot(q.1 - ay).max(1e-9);
                let r = p.marker + 1.5;
                [(ax + (q.0 - ax) * r / len, ay + (q.1 - ay) * r / len), q]
            });
            if let Some(l) = leader {
                let blocked = others.iter().any(|o| o.rect.grow(LABEL_PAD).hit_by(l[0], l[1]) || o.leader.is_some_and(|m| segments_cross(l, m)))
                    || markers.iter().enumerate().any(|(j, m)| {
                        // A marker overlapping this one cannot be cleared; any other is passed with 2 px to spare.
                        let m = m.grow(2.0);
                        j != i && !m.contains(&Rect::around(l[0], 0.0)) && m.hit_by(l[0], l[1])
                    });
                if blocked {
                    continue;
                }
            }
            let spot = PlacedLabel { rect, leader };
            // Soft: off the avoided segments, and closer to its own point than to any other (no misreading).
            let dist = |a: (f64, f64)| {
                let q = rect.nearest(a);
                (q.0 - a.0).hypot(q.1 - a.1)
            };
            let own = if leader.is_some() { f64::INFINITY } else { dist((ax, ay)) };
            let soft_clear = !p.avoid.iter().any(|s| padded.hit_by(s[0], s[1]) || leader.is_some_and(|l| segments_cross(l, *s)))
                && !p.anchors.iter().enumerate().any(|(j, &a)| j != i && dist(a) < own + 2.0 && leader.is_none());
            if soft_clear {
                return Some(spot);
            }
            if fallback.is_none() {
                fallback = Some((ring, spot));
            }
        }
    }
    fallback.map(|f| f.1)
}

/// A tick of a log axis: mantissa·10^exp, labelled or a minor (unlabelled) grid line.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Tick {
    mantissa: u32,
    exp: i32,
    labelled: bool,
}

impl Tick {
    fn value(&self) -> f64 {
        self.mantissa as f64 * 10f64.powi(self.exp)
    }
}

/// Ticks at 1-2-5 steps inside [lo, hi] (10^lo..10^hi in log10 units), labelled while neighbouring labels are
/// at least `min_px` apart on an axis of `len_px`; otherwise only powers of ten are labelled (2 and 5 stay as
/// minor grid lines), and for very long ranges only every k-th power.
fn log_ticks(lo: f64, hi: f64, len_px: f64, min_px: f64) -> Vec<Tick> {
    let px_per_decade = len_px / (hi - lo).max(1e-9);
    // The closest 1-2-5 neighbours are 5→10 (log10 2 = 0.301 decades).
    let all125 = px_per_decade * 2f64.log10() >= min_px;
    let every = if all125 { 1 } else { (min_px / px_per_decade).ceil().max(1.0) as i32 };
    let mut out = Vec::new();
    for exp in (lo.floor() as i32 - 1)..=(hi.ceil() as i32) {
        for mantissa in [1u32, 2, 5] {
            let v = (mantissa as f64).log10() + exp as f64;
            if v < lo - 1e-9 || v > hi + 1e-9 {
                continue;
            }
            let labelled = if all125 { true } else { mantissa == 1 && exp.rem_euclid(every) == 0 };
            if labelled || every == 1 {
                out.push(Tick { mantissa, exp, labelled });
            }
        }
    }
    out
}

/// Plain decimals for ordinary magnitudes (0.0001 … 50000), m×10ⁿ outside.
fn tick_label(t: &Tick) -> String {
    if (-4..=4).contains(&t.exp) {
        if t.exp >= 0 {
            (t.mantissa as u64 * 10u64.pow(t.exp as u32)).to_string()
        } else {
            format!("0.{}{}", "0".repeat((-t.exp - 1) as usize), t.mantissa)
        }
    } else {
        const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
        let e: String = t.exp.to_string().chars().map(|c| c.to_digit(10).map_or('⁻', |d| SUP[d as usize])).collect();
        if t.mantissa == 1 {
            format!("10{e}")
        } else {
            format!("{}×10{e}", t.mantissa)
        }
    }
}

/// m×10ⁿ, or 10ⁿ for m = 1, at any exponent.
fn power_label(t: &Tick) -> String {
    if t.mantissa == 1 {
        format!("10{}", superscript(t.exp))
    } else {
        format!("{}×10{}", t.mantissa, superscript(t.exp))
    }
}

/// Three significant digits, for footnotes.
fn short(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    if (1e-3..1e5).contains(&v.abs()) {
        let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("{v:.2e}")
    }
}

/// The scatter's data, checked and grouped once, drawn by either backend.
struct Scatter<'a> {
    points: &'a [CostError],
    title: &'a str,
    x_desc: &'a str,
    y_desc: &'a str,
    /// Series names in order of first appearance; index = marker shape and colour.
    series: Vec<&'a str>,
    /// Indices of rows with a positive finite cost and a finite error ≥ 0.
    shown: Vec<usize>,
    /// Rows that cannot be placed on the axes.
    unplaceable: Vec<usize>,
    /// log10 ranges of the axes.
    x: (f64, f64),
    y: (f64, f64),
    has_zero: bool,
}

/// Pads a log10 range by 6 % of its span each side and widens it to at least one decade. The ends are not
/// snapped to 1-2-5 values: that costs up to 0.4 decade of room the labels need.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = if hi - lo < 1.0 { ((lo + hi) / 2.0 - 0.5, (lo + hi) / 2.0 + 0.5) } else { (lo, hi) };
    let pad = (hi - lo) * 0.06;
    (lo - pad, hi + pad)
}

impl<'a> Scatter<'a> {
    fn new(points: &'a [CostError], title: &'a str, x_desc: &'a str, y_desc: &'a str) -> DrawResult<Scatter<'a>> {
        let ok = |p: &CostError| p.cost.is_finite() && p.cost > 0.0 && p.error.is_finite() && p.error >= 0.0;
        let (shown, unplaceable): (Vec<usize>, Vec<usize>) = (0..points.len()).partition(|&i| ok(&points[i]));
        if shown.is_empty() {
            return Err("nothing to plot: no row has a positive finite cost and a finite error ≥ 0".into());
        }
        let mut series: Vec<&str> = Vec::new();
        for p in points {
            if !series.contains(&p.series.as_str()) {
                series.push(&p.series);
            }
        }
        let range = |v: &mut dyn Iterator<Item = f64>| v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v.log10()), b.max(v.log10())));
        let (x0, x1) = range(&mut shown.iter().map(|&i| points[i].cost));
        let (y0, y1) = range(&mut shown.iter().map(|&i| points[i].error).filter(|&e| e > 0.0));
        // Only exact rows: an empty log area of a few decades above the band.
        let (y0, y1) = if y0.is_finite() { (y0, y1) } else { (-4.0, 0.0) };
        let has_zero = shown.iter().any(|&i| points[i].error == 0.0);
        Ok(Scatter { points, title, x_desc, y_desc, series, shown, unplaceable, x: padded(x0, x1), y: padded(y0, y1), has_zero })
    }

    fn color(&self, p: &CostError) -> RGBColor {
        color(self.series.iter().position(|s| *s == p.series).unwrap_or(0))
    }

    fn shape(&self, p: &CostError) -> usize {
        self.series.iter().position(|s| *s == p.series).unwrap_or(0)
    }

    /// Lays out and draws the figure. `ink_shift` (em) moves text down to centre it in its box (backend quirk).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, ink_shift: f64) -> DrawResult<()> {
        let (w, h) = (SCATTER_SIZE.0 as f64, SCATTER_SIZE.1 as f64);
        let measure = |s: &str, px: f64| -> (f64, f64) {
            let (tw, _) = root.estimate_text_size(s, &("sans-serif", px).into_font().into_text_style(root)).unwrap_or((0, 0));
            (tw as f64, px)
        };
        let text = |s: &str, px: f64, (x, y): (f64, f64), h: HPos, c: RGBColor| -> DrawResult<()> {
            let style = ("sans-serif", px).into_font().color(&c).pos(Pos::new(h, VPos::Center));
            root.draw_text(s, &style, (x.round() as i32, (y + ink_shift * px).round() as i32)).map_err(err)
        };
        let ink = RGBColor(30, 30, 30);
        let margin = 16.0;

        // Vertical layout, top down: title, legend, log area, band, x ticks, x description, footnotes.
        let title_y = margin + TITLE_PX * 0.6;
        let legend_y = title_y + TITLE_PX * 0.6 + 8.0 + LEGEND_PX * 0.6;
        let top = legend_y + LEGEND_PX + 6.0;
        let x_ticks = self.x_ticks_sample();
        let y_label_w = self.y_tick_labels().iter().map(|s| measure(s, TICK_PX).0).fold(measure("0", TICK_PX).0, f64::max);
        let left = margin + DESC_PX * 1.3 + y_label_w + 10.0;
        let right = w - margin - measure(&x_ticks, TICK_PX).0 / 2.0;
        let note_w = w - 2.0 * margin;
        let mut unplaced_note = Vec::new();
        if !self.unplaceable.is_empty() {
            let rows: Vec<String> = self
                .unplaceable
                .iter()
                .map(|&i| format!("{} (cost {}, error {})", self.points[i].name, short(self.points[i].cost), short(self.points[i].error)))
                .collect();
            unplaced_note = wrap("Not plotted (cost not positive and finite, or error not finite ≥ 0): ", &rows, note_w, |s| measure(s, NOTE_PX).0);
        }
        let mut note_lines = unplaced_note.len().min(MAX_NOTE_LINES);
        let mut result = None;
        // Footnote room depends on which labels are dropped, which depends on the room left: settle in a few rounds.
        for _ in 0..4 {
            let notes_h = if note_lines > 0 { 6.0 + note_lines as f64 * NOTE_PX * 1.35 } else { 0.0 };
            let axis_bottom = h - margin - notes_h - DESC_PX * 1.4 - TICK_PX * 1.4 - 6.0;
            let band = self.has_zero.then_some(Rect { x0: left, y0: axis_bottom - BAND, x1: right, y1: axis_bottom });
            let main = Rect { x0: left, y0: top, x1: right, y1: band.map_or(axis_bottom, |b| b.y0 - BAND_GAP) };
            let geo = Geometry { main, band, x: self.x, y: self.y };
            let anchors: Vec<(f64, f64)> = self.shown.iter().map(|&i| geo.at(&self.points[i])).collect();
            let sizes: Vec<(f64, f64)> = self.shown.iter().map(|&i| (measure(&self.points[i].name, LABEL_PX).0 + 2.0, LABEL_PX + 3.0)).collect();
            let front = self.front(&geo);
            let bounds = Rect { x0: main.x0 + 1.0, y0: main.y0 + 1.0, x1: main.x1 - 1.0, y1: band.map_or(main.y1, |b| b.y1) - 1.0 };
            let gap = band.map(|b| vec![Rect { x0: main.x0, y0: main.y1, x1: main.x1, y1: b.y0 }]).unwrap_or_default();
            let placed = place_labels(&LabelProblem { anchors: &anchors, sizes: &sizes, marker: MARKER, bounds, obstacles: &gap, avoid: &front });
            let dropped: Vec<String> = self
                .shown
                .iter()
                .zip(&placed)
                .filter(|(_, p)| p.is_none())
                .map(|(&i, _)| format!("{} (cost {}, error {})", self.points[i].name, short(self.points[i].cost), short(self.points[i].error)))
                .collect();
            let mut notes = unplaced_note.clone();
            if !dropped.is_empty() {
                notes.extend(wrap("Labels left out for lack of room: ", &dropped, note_w, |s| measure(s, NOTE_PX).0));
            }
            let fits = notes.len() <= note_lines;
            result = Some((geo, anchors, placed, front, notes));
            if fits {
                break;
            }
            if note_lines == MAX_NOTE_LINES {
                break;
            }
            note_lines = result.as_ref().map_or(0, |r| r.4.len()).min(MAX_NOTE_LINES);
        }
        let Some((geo, anchors, placed, front, mut notes)) = result else { return Ok(()) };
        if notes.len() > note_lines {
            notes.truncate(note_lines.max(1));
            if let Some(last) = notes.last_mut() {
                last.push_str(" …");
            }
        }

        // Frames and grid.
        let px = |x: f64| x.round() as i32;
        let grid = RGBColor(225, 225, 225);
        let frames: Vec<Rect> = std::iter::once(geo.main).chain(geo.band).collect();
        let xt = log_ticks(self.x.0, self.x.1, geo.main.x1 - geo.main.x0, 0.0);
        let yt = log_ticks(self.y.0, self.y.1, geo.main.y1 - geo.main.y0, TICK_PX * 1.6);
        // x labels need their width: choose 1-2-5 or decades from the widest label.
        let x_min_px = xt.iter().map(|t| measure(&tick_label(t), TICK_PX).0).fold(0.0, f64::max) + 12.0;
        let xt = log_ticks(self.x.0, self.x.1, geo.main.x1 - geo.main.x0, x_min_px);
        for f in &frames {
            for t in &xt {
                let x = geo.x_px(t.value());
                root.draw(&PathElement::new(vec![(px(x), px(f.y0)), (px(x), px(f.y1))], grid.stroke_width(1))).map_err(err)?;
            }
        }
        for t in &yt {
            let y = geo.y_px(t.value());
            root.draw(&PathElement::new(vec![(px(geo.main.x0), px(y)), (px(geo.main.x1), px(y))], grid.stroke_width(1))).map_err(err)?;
        }
        for f in &frames {
            root.draw(&Rectangle::new([(px(f.x0), px(f.y0)), (px(f.x1), px(f.y1))], ink.stroke_width(1))).map_err(err)?;
        }
        let axis_bottom = frames.last().map_or(geo.main.y1, |f| f.y1);
        for t in &xt {
            let x = geo.x_px(t.value());
            let len = if t.labelled { 6.0 } else { 3.0 };
            root.draw(&PathElement::new(vec![(px(x), px(axis_bottom)), (px(x), px(axis_bottom + len))], ink.stroke_width(1))).map_err(err)?;
            if t.labelled {
                text(&tick_label(t), TICK_PX, (x, axis_bottom + 8.0 + TICK_PX * 0.6), HPos::Center, ink)?;
            }
        }
        for t in &yt {
            let y = geo.y_px(t.value());
            let len = if t.labelled { 6.0 } else { 3.0 };
            root.draw(&PathElement::new(vec![(px(geo.main.x0 - len), px(y)), (px(geo.main.x0), px(y))], ink.stroke_width(1))).map_err(err)?;
            if t.labelled {
                text(&tick_label(t), TICK_PX, (geo.main.x0 - 9.0, y), HPos::Right, ink)?;
            }
        }
        if let Some(b) = geo.band {
            let y = (b.y0 + b.y1) / 2.0;
            root.draw(&PathElement::new(vec![(px(b.x0 - 6.0), px(y)), (px(b.x0), px(y))], ink.stroke_width(1))).map_err(err)?;
            text("0", TICK_PX, (b.x0 - 9.0, y), HPos::Right, ink)?;
        }
        // Axis descriptions and title.
        text(self.x_desc, DESC_PX, ((geo.main.x0 + geo.main.x1) / 2.0, axis_bottom + 10.0 + TICK_PX * 1.2 + DESC_PX * 0.7), HPos::Center, ink)?;
        let y_mid = (geo.main.y0 + axis_bottom) / 2.0;
        let rotated = ("sans-serif", DESC_PX).into_font().transform(FontTransform::Rotate270).color(&ink).pos(Pos::new(HPos::Center, VPos::Center));
        root.draw_text(self.y_desc, &rotated, (px(margin + DESC_PX * 0.6 + ink_shift * DESC_PX), px(y_mid))).map_err(err)?;
        text(self.title, TITLE_PX, (w / 2.0, title_y), HPos::Center, ink)?;

        // Pareto front, leaders, markers, labels.
        let front_color = RGBColor(90, 90, 90);
        for s in &front {
            root.draw(&PathElement::new(vec![(px(s[0].0), px(s[0].1)), (px(s[1].0), px(s[1].1))], front_color.stroke_width(2))).map_err(err)?;
        }
        for l in placed.iter().flatten().filter_map(|p| p.leader) {
            root.draw(&PathElement::new(vec![(px(l[0].0), px(l[0].1)), (px(l[1].0), px(l[1].1))], RGBColor(150, 150, 150).stroke_width(1))).map_err(err)?;
        }
        for (k, &i) in self.shown.iter().enumerate() {
            let p = &self.points[i];
            marker(root, self.shape(p), anchors[k], self.color(p), p.pareto)?;
        }
        for (k, spot) in placed.iter().enumerate() {
            if let Some(s) = spot {
                let c = ((s.rect.x0 + s.rect.x1) / 2.0, (s.rect.y0 + s.rect.y1) / 2.0);
                text(&self.points[self.shown[k]].name, LABEL_PX, c, HPos::Center, ink)?;
            }
        }

        // Legend: one entry per named series, then the front.
        let mut entries: Vec<(Option<usize>, String)> = self.series.iter().enumerate().filter(|(_, s)| !s.is_empty()).map(|(i, s)| (Some(i), s.to_string())).collect();
        if !front.is_empty() {
            entries.push((None, "Pareto front".into()));
        }
        let widths: Vec<f64> = entries.iter().map(|e| 26.0 + measure(&e.1, LEGEND_PX).0).collect();
        let total = widths.iter().sum::<f64>() + 24.0 * entries.len().saturating_sub(1) as f64;
        let mut x = (w - total) / 2.0;
        for (e, ew) in entries.iter().zip(&widths) {
            match e.0 {
                Some(i) => marker(root, i, (x + 8.0, legend_y), color(i), false)?,
                None => root.draw(&PathElement::new(vec![(px(x), px(legend_y)), (px(x + 18.0), px(legend_y))], front_color.stroke_width(2))).map_err(err)?,
            }
            text(&e.1, LEGEND_PX, (x + 24.0, legend_y), HPos::Left, ink)?;
            x += ew + 24.0;
        }
        for (k, line) in notes.iter().enumerate() {
            let y = h - margin - (notes.len() - 1 - k) as f64 * NOTE_PX * 1.35 - NOTE_PX * 0.5;
            text(line, NOTE_PX, (margin, y), HPos::Left, RGBColor(70, 70, 70))?;
        }
        Ok(())
    }

    /// Labels of the y ticks for the widest-label estimate (the real ticks depend on the height left).
    fn y_tick_labels(&self) -> Vec<String> {
        log_ticks(self.y.0, self.y.1, 1e6, 0.0).iter().map(tick_label).collect()
    }

    /// The longest x tick label, to keep the last one inside the figure.
    fn x_ticks_sample(&self) -> String {
        log_ticks(self.x.0, self.x.1, 1e6, 0.0).iter().map(tick_label).max_by_key(|s| s.chars().count()).unwrap_or_default()
    }

    /// The Pareto front as a staircase through the flagged points sorted by cost (error steps down at each).
    fn front(&self, geo: &Geometry) -> Vec<[(f64, f64); 2]> {
        let mut f: Vec<&CostError> = self.shown.iter().map(|&i| &self.points[i]).filter(|p| p.pareto).collect();
        f.sort_by(|a, b| a.cost.total_cmp(&b.cost).then(b.error.total_cmp(&a.error)));
        let mut segs = Vec::new();
        for pair in f.windows(2) {
            let (a, b) = (geo.at(pair[0]), geo.at(pair[1]));
            segs.push([a, (b.0, a.1)]);
            segs.push([(b.0, a.1), b]);
        }
        segs.retain(|s| s[0] != s[1]);
        segs
    }
}

/// Data → pixels.
struct Geometry {
    main: Rect,
    band: Option<Rect>,
    x: (f64, f64),
    y: (f64, f64),
}

impl Geometry {
    fn x_px(&self, v: f64) -> f64 {
        self.main.x0 + (v.log10() - self.x.0) / (self.x.1 - self.x.0) * (self.main.x1 - self.main.x0)
    }
    fn y_px(&self, v: f64) -> f64 {
        self.main.y0 + (self.y.1 - v.log10()) / (self.y.1 - self.y.0) * (self.main.y1 - self.main.y0)
    }
    fn at(&self, p: &CostError) -> (f64, f64) {
        let y = match self.band {
            Some(b) if p.error == 0.0 => (b.y0 + b.y1) / 2.0,
            _ => self.y_px(p.error),
        };
        (self.x_px(p.cost), y)
    }
}

/// `prefix` then the items joined by "; ", broken into lines no wider than `width`.
fn wrap(prefix: &str, items: &[String], width: f64, measure: impl Fn(&str) -> f64) -> Vec<String> {
    let mut lines = vec![prefix.trim_end().to_string()];
    for (k, item) in items.iter().enumerate() {
        let piece = if k + 1 < items.len() { format!("{item};") } else { format!("{item}.") };
        let last = lines.last_mut().expect("starts with one line");
        let joined = format!("{last} {piece}");
        if measure(&joined) <= width || last.is_empty() {
            *last = joined;
        } else {
            lines.push(piece);
        }
    }
    lines
}

/// Marker shapes by series: circle, square, triangle, diamond, down-triangle, then again.
fn marker<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, shape: usize, (x, y): (f64, f64), c: RGBColor, outline: bool) -> DrawResult<()> {
    let r = MARKER;
    let pts: Vec<(f64, f64)> = match shape % 5 {
        0 => (0..20).map(|k| k as f64 * std::f64::consts::TAU / 20.0).map(|a| (x + r * a.cos(), y + r * a.sin())).collect(),
        1 => vec![(x - r * 0.9, y - r * 0.9), (x + r * 0.9, y - r * 0.9), (x + r * 0.9, y + r * 0.9), (x - r * 0.9, y + r * 0.9)],
        2 => vec![(x, y - r * 1.15), (x + r * 1.1, y + r * 0.8), (x - r * 1.1, y + r * 0.8)],
        3 => vec![(x, y - r * 1.2), (x + r * 1.2, y), (x, y + r * 1.2), (x - r * 1.2, y)],
        _ => vec![(x, y + r * 1.15), (x + r * 1.1, y - r * 0.8), (x - r * 1.1, y - r * 0.8)],
    };
    let ipts: Vec<(i32, i32)> = pts.iter().map(|p| (p.0.round() as i32, p.1.round() as i32)).collect();
    root.draw(&Polygon::new(ipts.clone(), c.filled())).map_err(err)?;
    // Points on the front get a dark outline, so they read as "on the line" even where the line is short.
    let edge = if outline { RGBColor(20, 20, 20).stroke_width(2) } else { c.stroke_width(1) };
    let mut closed = ipts;
    closed.push(closed[0]);
    root.draw(&PathElement::new(closed, edge)).map_err(err)?;
    Ok(())
}

/// Draws a plot at `supersample`× its `size` and encodes it: the one place PNG and SVG are made (plotters'
/// backends are different types, hence two closures, each given the drawing area and the scale k). PNG: drawn
/// at k× (k lowered for big images so the buffer stays under [`MAX_DRAW_PIXELS`]), then each k × k block
/// averaged into one pixel. SVG: the k× drawing under `width`/`height` of the 1× size and a k× `viewBox`.
fn render_with<A, B>(format: Format, size: (u32, u32), supersample: u32, png: A, svg: B) -> DrawResult<Vec<u8>>
where
    A: FnOnce(&DrawingArea<BitMapBackend, Shift>, f64) -> DrawResult<()>,
    B: FnOnce(&DrawingArea<SVGBackend, Shift>, f64) -> DrawResult<()>,
{
    register_font();
    let (w, h) = (size.0 as usize, size.1 as usize);
    match format {
        Format::Png => {
            let k = (1..=supersample.max(1)).rev().find(|&k| (w * h) as u64 * (k * k) as u64 <= MAX_DRAW_PIXELS).unwrap_or(1);
            let big = (size.0 * k, size.1 * k);
            let mut buf = vec![0u8; (big.0 as usize) * (big.1 as usize) * 3];
            {
                let root = BitMapBackend::with_buffer(&mut buf, big).into_drawing_area();
                root.fill(&WHITE).map_err(err)?;
                png(&root, k as f64)?;
                root.present().map_err(err)?;
            }
            let rgb = if k == 1 { buf } else { box_down(&buf, w, h, k as usize) };
            // The renderer's encoder: same `Software: lobe` marker, so lobe may later replace its own plot.
            crate::base::image::Image { width: w, height: h, rgb }.encode_png()
        }
        Format::Svg => {
            let k = supersample.max(1);
            let big = (size.0 * k, size.1 * k);
            let mut s = String::new();
            {
                let root = SVGBackend::with_string(&mut s, big).into_drawing_area();
                root.fill(&WHITE).map_err(err)?;
                svg(&root, k as f64)?;
                root.present().map_err(err)?;
            }
            // Shown at the 1× size; the viewBox keeps the k× user units (1/k-pixel coordinates).
            let head = format!("<svg width=\"{}\" height=\"{}\"", big.0, big.1);
            let s = s.replacen(&head, &format!("<svg width=\"{}\" height=\"{}\"", size.0, size.1), 1);
            // The marker lets lobe recognise (and later replace) its own SVGs.
            Ok([b"<!-- made by lobe -->\n".as_slice(), s.as_bytes()].concat())
        }
    }
}

/// Averages each k × k block of an RGB image of (w·k) × (h·k) pixels into one of w × h.
fn box_down(big: &[u8], w: usize, h: usize, k: usize) -> Vec<u8> {
    let bw = w * k;
    let mut out = vec![0u8; w * h * 3];
    let mut row = vec![0u32; w * 3];
    for y in 0..h {
        row.iter_mut().for_each(|v| *v = 0);
        for sy in 0..k {
            let line = &big[(y * k + sy) * bw * 3..(y * k + sy + 1) * bw * 3];
            for (x, px) in line.chunks_exact(3).enumerate() {
                let o = (x / k) * 3;
                row[o] += px[0] as u32;
                row[o + 1] += px[1] as u32;
                row[o + 2] += px[2] as u32;
            }
        }
        let n = (k * k) as u32;
        for (o, v) in out[y * w * 3..(y + 1) * w * 3].iter_mut().zip(&row) {
            *o = ((v + n / 2) / n) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cos_n(n: f64) -> Series {
        Series { name: format!("cos^{n}"), points: (0..=90).map(|d| (d as f64, (d as f64).to_radians().cos().powf(n))).collect() }
    }

    #[test]
    fn lobe_plots_render_in_every_mode() {
        for (polar, log) in [(false, false), (true, false), (false, true)] {
            let o = LobeOptions { title: "t".into(), polar, log, size: (320, 240) };
            let png = lobes(&[cos_n(5.0), cos_n(50.0)], &o, Format::Png).unwrap();
            assert_eq!(&png[1..4], b"PNG");
            let svg = lobes(&[cos_n(5.0)], &o, Format::Svg).unwrap();
            assert!(String::from_utf8(svg).unwrap().contains("<svg"));
        }
        let o = LobeOptions { title: "t".into(), polar: true, log: true, size: (320, 240) };
        assert!(lobes(&[cos_n(5.0)], &o, Format::Png).is_err());
    }

    #[test]
    fn polar_plots_are_to_scale() {
        // A value of 1 in every direction is a half circle: as wide (to each side) as it is tall, in pixels,
        // whatever the image's aspect, for the lobe plot and the plane-of-incidence plot alike.
        let half: Vec<(f64, f64)> = (0..=360).map(|i| (i as f64 * 0.25, 1.0)).collect();
        let signed: Vec<(f64, f64)> = (0..=720).map(|i| (-90.0 + i as f64 * 0.25, 1.0)).collect();
        for size in [(560, 400), (400, 500)] {
            let o = LobeOptions { title: "t".into(), polar: true, log: false, size };
            let one = |points: &[(f64, f64)]| [Series { name: "1".into(), points: points.to_vec() }];
            let pngs = [lobes(&one(&half), &o, Format::Png), incidence_lobes(&one(&signed), &o, 30.0, Format::Png)];
            for png in pngs.map(Result::unwrap) {
                let img = crate::base::image::Image::decode_png(&png).unwrap();
                let c = color(0);
                // The curve's pixels (and the legend's sample line): the ends of the half circle on its lowest
                // rows, its top straight above their midpoint.
                let curve: Vec<(usize, usize)> = (0..img.height)
                    .flat_map(|y| (0..img.width).map(move |x| (x, y)))
                    .filter(|&(x, y)| img.pixel(x, y) == [c.0, c.1, c.2])
                    .collect();
                let bottom = curve.iter().map(|p| p.1).max().unwrap();
                let foot = || curve.iter().filter(|p| p.1 + 3 >= bottom).map(|p| p.0);
                let (x0, x1) = (foot().min().unwrap(), foot().max().unwrap());
                let top = curve.iter().filter(|p| p.0.abs_diff((x0 + x1) / 2) <= 2).map(|p| p.1).min().unwrap();
                let (across, up) = ((x1 - x0) as f64 / 2.0, (bottom - top) as f64);
                assert!((across - up).abs() <= 3.0, "{size:?}: the half circle is {across} px to each side and {up} px tall");
            }
        }
    }

    #[test]
    fn curves_with_nothing_to_show_are_refused_not_looped_on() {
        let zero = Series { name: "0".into(), points: (0..=90).map(|d| (d as f64, 0.0)).collect() };
        let nan = Series { name: "nan".into(), points: (0..=90).map(|d| (d as f64, f64::NAN)).collect() };
        let log = LobeOptions { title: "t".into(), polar: false, log: true, size: (320, 240) };
        assert!(lobes(&[zero.clone(), nan.clone()], &log, Format::Png).unwrap_err().contains("log"));
        let lin = LobeOptions { log: false, ..log };
        assert!(lobes(&[nan], &lin, Format::Png).unwrap_err().contains("finite"));
        assert!(lobes(&[zero], &lin, Format::Png).is_ok());
    }

    #[test]
    fn curves_take_any_x_range() {
        let s = Series { name: "coef".into(), points: (1..=1000).map(|n| (n as f64, 0.255 * n as f64)).collect() };
        assert_eq!(&curves(&[s], "t", "n", "coef", Format::Png).unwrap()[1..4], b"PNG");
        let empty = Series { name: "none".into(), points: vec![(1.0, f64::NAN)] };
        assert!(curves(&[empty], "t", "n", "coef", Format::Svg).is_err());
    }

    #[test]
    fn scatter_needs_a_placeable_point() {
        let pt = |name: &str, cost, error, pareto| CostError { name: name.into(), cost, error, pareto, series: "precise".into() };
        let p = vec![pt("a", 2.0, 0.01, true), pt("b", 5.0, 0.1, false)];
        assert!(speed_error(&p, "t", "ns", "err", Format::Png).is_ok());
        let z = vec![pt("z", 0.0, 0.0, false), pt("n", f64::NAN, 0.1, false), pt("i", 1.0, f64::INFINITY, false)];
        assert!(speed_error(&z, "t", "ns", "err", Format::Svg).unwrap_err().contains("nothing to plot"));
        // Only exact rows: still a plot (the band), not a refusal.
        assert!(speed_error(&[pt("ref", 3.0, 0.0, true)], "t", "ns", "err", Format::Png).is_ok());
    }

    /// 16 formulas × 2 series as the benchmark's plot sees them: costs 0.4–80 ns, errors 1e-4–2, fast math
    /// cheaper on transcendental formulas at almost the same error (so pairs sit side by side), a zero-error
    /// reference and a NaN row.
    fn bench_like() -> Vec<CostError> {
        let rows = [
            ("Modified cosine-quadratic F_SCOS2", 0.9, 2.1e-3, false), ("Schlick F_S", 0.45, 4.0e-2, false),
            ("Modified Schlick F_MS", 1.3, 1.1e-3, false), ("Gaussian", 18.0, 3.0e-3, true), ("Beckmann", 12.0, 2.6e-3, true),
            ("Ward", 12.5, 5.1e-3, true), ("Cook–Torrance", 14.0, 1.9e-3, true), ("F_ST", 15.0, 1.2e-3, true),
            ("F_kutlog", 78.0, 1.0e-4, true), ("Blinn–Phong", 0.8, 2.2e-3, false), ("Phong", 2.9, 0.35, true),
            ("Lafortune", 3.4, 0.21, true), ("Ashikhmin–Shirley", 21.0, 4.4e-3, true), ("GGX", 2.2, 1.3e-3, false),
            ("Oren–Nayar", 30.0, 1.9, true), ("Minnaert", 9.5, 0.6, true),
        ];
        let mut v = Vec::new();
        for (n, cost, error, transcendental) in rows {
            v.push(CostError { name: format!("{n} (precise)"), cost, error, pareto: false, series: "precise".into() });
            let fast = if transcendental { 0.55 } else { 0.93 };
            v.push(CostError { name: format!("{n} (fast)"), cost: cost * fast, error: error * 1.002, pareto: false, series: "fast".into() });
        }
        v.push(CostError { name: "Blinn (reference)".into(), cost: 1.1, error: 0.0, pareto: false, series: "precise".into() });
        v.push(CostError { name: "Broken".into(), cost: f64::NAN, error: 0.1, pareto: false, series: "fast".into() });
        // The front as a caller computes it: no other point is both cheaper and at most as wrong.
        let front: Vec<bool> = v
            .iter()
            .map(|p| p.cost.is_finite() && !v.iter().any(|q| q.cost.is_finite() && q.cost <= p.cost && q.error <= p.error && (q.cost < p.cost || q.error < p.error)))
            .collect();
        for (p, f) in v.iter_mut().zip(front) {
            p.pareto = f;
        }
        v
    }

    /// The text of every `<text>` element of an SVG.
    fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text").skip(1).filter_map(|t| Some(t.split_once('>')?.1.split("</text>").next()?.trim().to_string())).collect()
    }

    #[test]
    fn scatter_renders_bench_like_data_in_both_formats() {
        let v = bench_like();
        let png = speed_error(&v, "Speed against error", "scalar JIT ns/eval (log)", "mean |Δ| vs reference (log)", Format::Png).unwrap();
        let img = crate::base::image::Image::decode_png(&png).unwrap();
        assert_eq!((img.width, img.height), (SCATTER_SIZE.0 as usize, SCATTER_SIZE.1 as usize));
        if let Some(path) = std::env::var_os("LOBE_PLOT_EXAMPLE") {
            std::fs::write(path, &png).unwrap();
        }
        let svg = String::from_utf8(speed_error(&v, "t", "ns", "err", Format::Svg).unwrap()).unwrap();
        if let Some(path) = std::env::var_os("LOBE_PLOT_EXAMPLE_SVG") {
            std::fs::write(path, &svg).unwrap();
        }
        let texts = svg_texts(&svg);
        // The exact row is on the band, the NaN row in the footnote, the series and the front in the legend.
        for needle in ["0", "precise", "fast", "Pareto front", "0.001", "0.5", "20", "Blinn (reference)"] {
            assert!(texts.iter().any(|t| t == needle), "{needle} missing from the SVG's texts {texts:?}");
        }
        assert!(texts.iter().any(|t| t.contains("Broken (cost NaN")), "the NaN row is named in a footnote");
        assert!(!texts.iter().any(|t| t.parse::<f64>().is_ok() && t.contains('e')), "no 1e0-style tick labels");
    }

    #[test]
    fn a_crowd_of_points_keeps_its_plot_and_cuts_the_footnote() {
        let v: Vec<CostError> = (0..200)
            .map(|k| CostError {
                name: format!("Formula number {k} (fast)"),
                cost: 0.4 * 1.03f64.powi(k),
                error: 1e-4 * 1.05f64.powi((k * 37) % 200),
                pareto: k % 17 == 0,
                series: if k % 2 == 0 { "precise".into() } else { "fast".into() },
            })
            .collect();
        let texts = svg_texts(&String::from_utf8(speed_error(&v, "t", "ns", "err", Format::Svg).unwrap()).unwrap());
        let notes: Vec<&String> = texts.iter().filter(|t| t.contains("(cost ")).collect();
        assert!(!notes.is_empty() && notes.len() <= MAX_NOTE_LINES, "{} footnote lines", notes.len());
        assert!(notes.last().unwrap().ends_with('…'));
        assert!(texts.iter().any(|t| t == "0.001") && texts.iter().any(|t| t == "10"), "the axes are still there");
    }

    #[test]
    fn log_ticks_step_1_2_5_and_read_as_plain_numbers() {
        let labels = |lo: f64, hi: f64, len, min| -> Vec<String> {
            log_ticks(lo, hi, len, min).iter().filter(|t| t.labelled).map(tick_label).collect()
        };
        assert_eq!(labels(-0.5, 1.8, 800.0, 20.0), ["0.5", "1", "2", "5", "10", "20", "50"]);
        assert_eq!(labels(-4.0, 0.4, 600.0, 20.0)[..4], ["0.0001", "0.0002", "0.0005", "0.001"]);
        // Crowded: decades only, 2 and 5 kept as unlabelled grid lines.
        let t = log_ticks(-9.0, 3.0, 300.0, 20.0);
        assert!(t.iter().filter(|t| t.labelled).all(|t| t.mantissa == 1));
        assert!(t.iter().any(|t| !t.labelled));
        assert_eq!(tick_label(&Tick { mantissa: 5, exp: -7, labelled: true }), "5×10⁻⁷");
        assert_eq!(tick_label(&Tick { mantissa: 1, exp: 6, labelled: true }), "10⁶");
    }

    /// `(text-anchor, text)` of every `<text>` element of an SVG.
    fn svg_anchored_texts(svg: &str) -> Vec<(String, String)> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| {
                let (attrs, rest) = t.split_once('>')?;
                let anchor = attrs.split("text-anchor=\"").nth(1)?.split('"').next()?.to_string();
                Some((anchor, rest.split("</text>").next()?.trim().to_string()))
            })
            .collect()
    }

    /// A tick label as a number: plain decimals, 10ⁿ or m×10ⁿ, minus written as U+2212.
    fn parse_label(s: &str) -> Option<f64> {
        const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
        let s = s.replace('−', "-");
        let Some(at) = s.find(|c: char| SUP.contains(&c) || c == '⁻') else { return s.parse().ok() };
        let (base, exp) = s.split_at(at);
        let mantissa = base.strip_suffix("10")?.trim_end_matches('×');
        let m: f64 = if mantissa.is_empty() { 1.0 } else { mantissa.parse().ok()? };
        let e: String = exp.chars().map(|c| if c == '⁻' { Some('-') } else { SUP.iter().position(|d| *d == c).map(|d| (b'0' + d as u8) as char) }).collect::<Option<_>>()?;
        Some(m * 10f64.powi(e.parse().ok()?))
    }

    /// A small deterministic generator for random cases.
    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn log_axis_labels_are_clean_1_2_5_numbers_on_random_lobes() {
        let mut seed = 7u64;
        for case in 0..30 {
            let k = 1 + (lcg(&mut seed) * 4.0) as usize;
            let series: Vec<Series> = (0..k)
                .map(|j| {
                    let n = 10f64.powf(lcg(&mut seed) * 3.3);
                    let scale = 10f64.powf(lcg(&mut seed) * 16.0 - 8.0);
                    let mut s = cos_n(n);
                    s.name = format!("s{j}");
                    s.points.iter_mut().for_each(|p| p.1 *= scale);
                    s
                })
                .collect();
            let size = (300 + (lcg(&mut seed) * 1100.0) as u32, 200 + (lcg(&mut seed) * 800.0) as u32);
            let o = LobeOptions { title: "t".into(), polar: false, log: true, size };
            let svg = String::from_utf8(lobes(&series, &o, Format::Svg).unwrap()).unwrap();
            let texts = svg_anchored_texts(&svg);
            // The value axis's labels are the right-aligned texts.
            let y: Vec<&String> = texts.iter().filter(|t| t.0 == "end").map(|t| &t.1).collect();
            assert!(y.len() >= 2, "case {case} {size:?}: labels {y:?}");
            for l in &y {
                let v = parse_label(l).unwrap_or_else(|| panic!("case {case}: `{l}` is not a number"));
                let m = v / 10f64.powf(v.log10().floor() + 1e-12);
                assert!([1.0, 2.0, 5.0].iter().any(|d| (m - d).abs() < 1e-6), "case {case}: `{l}` = {v} is not 1, 2 or 5 × 10ⁿ");
                assert!(l.chars().count() <= 7, "case {case}: `{l}` is long");
            }
            // The angle axis: plain numbers, evenly spaced.
            let x: Vec<f64> = texts.iter().filter(|t| t.0 == "middle").filter_map(|t| parse_label(&t.1)).collect();
            assert!(x.len() >= 2 && x.windows(3).all(|w| ((w[2] - w[1]) - (w[1] - w[0])).abs() < 1e-9), "case {case}: {x:?}");
        }
    }

    #[test]
    fn linear_labels_are_short_exact_and_evenly_spaced() {
        let labels = |lo, hi| -> Vec<String> { linear_ticks(lo, hi, 600.0, 60.0).into_iter().filter_map(|t| t.label).collect() };
        assert_eq!(labels(0.0, 0.3), ["0", "0.05", "0.1", "0.15", "0.2", "0.25", "0.3"]);
        assert_eq!(labels(-2e-7, 3e-7)[..3], ["−2×10⁻⁷", "−1.5×10⁻⁷", "−1×10⁻⁷"]);
        assert_eq!(labels(0.0, 3.2e7)[1], "5×10⁶");
        let mut seed = 11u64;
        for case in 0..500 {
            let span = 10f64.powf(lcg(&mut seed) * 24.0 - 12.0);
            let mid = (lcg(&mut seed) - 0.5) * 6.0 * span;
            let (lo, hi) = (mid - span * lcg(&mut seed), mid + span);
            let len = 100.0 + lcg(&mut seed) * 2000.0;
            let t = linear_ticks(lo, hi, len, 40.0);
            // A range shorter than two steps may hold a single tick.
            assert!(!t.is_empty() && (t.len() as f64) <= len / 40.0 + 1.0, "case {case}: {lo}..{hi}: {} ticks", t.len());
            let vals: Vec<f64> = t.iter().map(|t| parse_label(t.label.as_deref().unwrap()).unwrap()).collect();
            let step = if vals.len() > 1 { vals[1] - vals[0] } else { 1.0 };
            for (i, (t, v)) in t.iter().zip(&vals).enumerate() {
                let l = t.label.as_deref().unwrap();
                assert!(l.chars().count() <= if l.contains('×') { 11 } else { 9 }, "case {case}: `{l}`");
                assert!((v - t.at).abs() <= 1e-9 * step.abs().max(t.at.abs()), "case {case}: `{l}` read {v}, drawn at {}", t.at);
                assert!(i == 0 || ((v - vals[i - 1]) - step).abs() <= 1e-6 * step, "case {case}: uneven {vals:?}");
                assert!(lo - 1e-9 * span <= t.at && t.at <= hi + 1e-9 * span);
            }
        }
    }

    #[test]
    fn twenty_four_series_are_all_told_apart() {
        let styles: Vec<LineStyle> = (0..24).map(|i| line_style(i, 24)).collect();
        let keys: std::collections::HashSet<String> = styles.iter().map(|s| format!("{:?} {:?}", s.color, s.dash)).collect();
        assert_eq!(keys.len(), 24, "(colour, dash) pairs repeat");
        assert_eq!(styles.iter().map(|s| format!("{:?}", s.color)).collect::<std::collections::HashSet<_>>().len(), 12);
        // The twelve colours stay apart from each other and from the white page.
        for (i, a) in PALETTE.iter().enumerate() {
            let d = |b: &RGBColor| ((a.0 as f64 - b.0 as f64).powi(2) + (a.1 as f64 - b.1 as f64).powi(2) + (a.2 as f64 - b.2 as f64).powi(2)).sqrt();
            assert!(d(&WHITE) > 100.0, "colour {i} is too pale");
            for (j, b) in PALETTE.iter().enumerate().skip(i + 1) {
                assert!(d(b) > 60.0, "colours {i} and {j} are close");
            }
        }
        // Earlier series are wider, so one drawn exactly under a later one shows.
        assert!(styles.windows(2).all(|w| w[0].width > w[1].width));
    }

    /// Pixels of `img` left of `x_max` within `tol` of colour `c` in every channel.
    fn count_near(img: &crate::base::image::Image, c: RGBColor, tol: u8, x_max: usize) -> usize {
        (0..img.height).flat_map(|y| (0..x_max).map(move |x| (x, y))).filter(|&(x, y)| img.pixel(x, y).iter().zip([c.0, c.1, c.2]).all(|(p, q)| p.abs_diff(q) <= tol)).count()
    }

    #[test]
    fn a_curve_exactly_under_another_still_shows() {
        let (mut a, mut b) = (cos_n(20.0), cos_n(20.0));
        (a.name, b.name) = ("Phong".into(), "Blinn".into());
        let o = LobeOptions { title: "t".into(), polar: false, log: false, size: (600, 400) };
        for polar in [false, true] {
            let png = lobes(&[a.clone(), b.clone()], &LobeOptions { polar, ..o.clone() }, Format::Png).unwrap();
            let img = crate::base::image::Image::decode_png(&png).unwrap();
            // Left of the legend: the curves only.
            let plot_w = img.width * 3 / 5;
            let (first, second) = (count_near(&img, color(0), 12, plot_w), count_near(&img, color(1), 12, plot_w));
            assert!(first >= 100 && second >= 100, "polar {polar}: {first} px of the first curve, {second} of the second");
        }
    }

    #[test]
    fn png_lines_are_anti_aliased_and_svg_coordinates_carry_fractions() {
        let line = Series { name: "x".into(), points: (0..=90).map(|d| (d as f64, d as f64 * 0.37)).collect() };
        let png = curves_sized(std::slice::from_ref(&line), "t", "x", "y", Format::Png, (500, 400)).unwrap();
        let img = crate::base::image::Image::decode_png(&png).unwrap();
        // Pixels part way from the page's white to the line's colour: its anti-aliased edge.
        let c = color(0);
        let edge = (0..img.height)
            .flat_map(|y| (0..img.width * 3 / 5).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let p = img.pixel(x, y);
                let t = (255.0 - p[0] as f64) / (255.0 - c.0 as f64);
                let on = |ch: usize, q: u8| (p[ch] as f64 - (255.0 - t * (255.0 - q as f64))).abs() <= 4.0;
                (0.15..0.85).contains(&t) && on(1, c.1) && on(2, c.2)
            })
            .count();
        assert!(edge >= 100, "{edge} edge pixels between white and the line's colour");
        let svg = String::from_utf8(curves_sized(&[line], "t", "x", "y", Format::Svg, (500, 400)).unwrap()).unwrap();
        let k = SUPERSAMPLE;
        assert!(svg.contains(&format!("<svg width=\"500\" height=\"400\" viewBox=\"0 0 {} {}\"", 500 * k, 400 * k)), "{}", &svg[..200]);
        assert!(svg.starts_with("<!-- made by lobe -->"));
        let hex = format!("stroke=\"#{:02X}{:02X}{:02X}\"", c.0, c.1, c.2);
        let coords: Vec<i64> = svg
            .lines()
            .filter(|l| l.starts_with("<polyline") && l.contains(&hex))
            .flat_map(|l| l.split("points=\"").nth(1).unwrap_or("").split(['"', ' ', ',']).filter_map(|v| v.parse::<i64>().ok()).collect::<Vec<_>>())
            .collect();
        let fractional = coords.iter().filter(|v| *v % k as i64 != 0).count();
        assert!(coords.len() > 100 && fractional * 2 > coords.len(), "{fractional} of {} coordinates between whole pixels", coords.len());
    }

    #[test]
    fn nothing_is_drawn_to_the_image_edge() {
        let wide = Series { name: "coef".into(), points: (1..=1000).map(|n| (n as f64, 0.255 * n as f64)).collect() };
        let many: Vec<Series> = (0..16).map(|i| Series { name: format!("formula number {i}"), ..cos_n(1.0 + i as f64 * 20.0) }).collect();
        let mut pngs = vec![curves(&[wide], "coefficient", "n", "coef", Format::Png).unwrap()];
        for (polar, log) in [(false, false), (true, false), (false, true)] {
            for size in [(900, 600), (400, 300)] {
                pngs.push(lobes(&many, &LobeOptions { title: "Lobes".into(), polar, log, size }, Format::Png).unwrap());
            }
        }
        for (i, png) in pngs.iter().enumerate() {
            let img = crate::base::image::Image::decode_png(png).unwrap();
            let (w, h) = (img.width, img.height);
            let border = (0..w).flat_map(|x| [(x, 0), (x, 1), (x, h - 2), (x, h - 1)]).chain((0..h).flat_map(|y| [(0, y), (1, y), (w - 2, y), (w - 1, y)]));
            let inked: Vec<(usize, usize)> = border.filter(|&(x, y)| img.pixel(x, y) != [255, 255, 255]).collect();
            assert!(inked.is_empty(), "plot {i}: ink at the edge, e.g. {:?}", &inked[..inked.len().min(5)]);
        }
    }

    #[test]
    fn comparison_figures_have_headings_row_labels_and_a_colour_bar() {
        let mut img = crate::base::image::Image::new(3 * 40, 2 * 30);
        img.rgb.iter_mut().enumerate().for_each(|(i, v)| *v = (i * 7 % 251) as u8);
        let rows = ["n = 5".to_string(), "n = 50".to_string()];
        let f = comparison_figure(&img, ["a.brdf", "b.brdf", "|Δgray|"], &rows, 42.0).unwrap();
        let (w, h) = (f.width, f.height);
        // The picture is copied unchanged; find its offset by its first row.
        let at = (0..w - img.width).flat_map(|x| (0..h - img.height).map(move |y| (x, y))).find(|&(x, y)| (0..img.width).all(|i| f.pixel(x + i, y) == img.pixel(i, 0))).unwrap();
        assert!((0..img.height).all(|y| (0..img.width).all(|x| f.pixel(at.0 + x, at.1 + y) == img.pixel(x, y))));
        let inked = |x0: usize, x1: usize, y0: usize, y1: usize| (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| f.pixel(x, y) != [255, 255, 255]).count();
        // Headings above each column, labels left of the rows.
        for c in 0..3 {
            assert!(inked(at.0 + c * 40, at.0 + (c + 1) * 40, 0, at.1) > 10, "heading {c}");
        }
        assert!(inked(0, at.0, at.1, at.1 + 30) > 10 && inked(0, at.0, at.1 + 30, at.1 + 60) > 10, "row labels");
        // The bar: white at the top (the scale), black at the bottom, brighter upwards; its labels beside it.
        let bar_x = (at.0 + img.width..w).find(|&x| f.pixel(x, at.1) == [255, 255, 255] && f.pixel(x, at.1 + img.height - 1) == [0, 0, 0]).unwrap();
        let lum = |y: usize| f.pixel(bar_x, y).iter().map(|&v| v as u32).sum::<u32>();
        assert!((at.1..at.1 + img.height - 1).all(|y| lum(y) >= lum(y + 1)));
        assert!(inked(bar_x + 16, w, at.1, at.1 + img.height) > 20, "bar labels");
        // No rows named: no label column.
        let plain = comparison_figure(&img, ["a", "b", "c"], &[], 1.0).unwrap();
        assert!(plain.width < w);
    }

    /// DejaVu Sans 13 px metrics, rounded up (5.7 px per character measured), so placement is tested without a renderer.
    fn label_size(name: &str) -> (f64, f64) {
        (name.chars().count() as f64 * 6.2 + 2.0, 16.0)
    }

    #[test]
    fn close_labels_never_overlap_points_each_other_or_the_frame() {
        let v = bench_like();
        // The figure's log area (1200 × 820 minus title, legend, ticks and the "0" band) and its axis ranges.
        let bounds = Rect { x0: 90.0, y0: 80.0, x1: 1175.0, y1: 680.0 };
        let s = Scatter::new(&v, "t", "x", "y").unwrap();
        let to_px = |p: &CostError| {
            let x = bounds.x0 + (p.cost.log10() - s.x.0) / (s.x.1 - s.x.0) * (bounds.x1 - bounds.x0);
            let y = bounds.y0 + (s.y.1 - p.error.max(1e-4).log10()) / (s.y.1 - s.y.0) * (bounds.y1 - bounds.y0);
            (x, y)
        };
        let shown: Vec<&CostError> = v.iter().filter(|p| p.cost.is_finite()).collect();
        let anchors: Vec<(f64, f64)> = shown.iter().map(|p| to_px(p)).collect();
        let sizes: Vec<(f64, f64)> = shown.iter().map(|p| label_size(&p.name)).collect();
        let avoid = [[(300.0, 600.0), (900.0, 600.0)]];
        let problem = LabelProblem { anchors: &anchors, sizes: &sizes, marker: MARKER, bounds, obstacles: &[], avoid: &avoid };
        let placed = place_labels(&problem);
        assert_eq!(placed, place_labels(&problem), "placement is deterministic");
        let boxes: Vec<(usize, Rect)> = placed.iter().enumerate().filter_map(|(i, p)| p.map(|p| (i, p.rect))).collect();
        assert!(boxes.len() >= shown.len() - 2, "only {} of {} labels placed", boxes.len(), shown.len());
        for (k, (i, r)) in boxes.iter().enumerate() {
            assert!(bounds.contains(r), "label {i} leaves the area: {r:?}");
            assert!((r.x1 - r.x0 - sizes[*i].0).abs() < 1e-9 && (r.y1 - r.y0 - sizes[*i].1).abs() < 1e-9, "label {i} has the size asked for");
            for (j, s) in &boxes[k + 1..] {
                assert!(!r.intersects(s), "labels {i} and {j} overlap: {r:?} {s:?}");
            }
            for a in &anchors {
                assert!(!r.intersects(&Rect::around(*a, MARKER)), "label {i} covers a point at {a:?}");
            }
            assert!(!r.hit_by(avoid[0][0], avoid[0][1]), "label {i} sits on the line although there is room");
        }
        // Leaders run from their own point to their own box and cross no other box.
        for (i, p) in placed.iter().enumerate() {
            if let Some(PlacedLabel { rect, leader: Some([a, b]) }) = p {
                assert!((a.0 - anchors[i].0).hypot(a.1 - anchors[i].1) <= MARKER + 2.0);
                assert_eq!(rect.nearest(*b), *b);
                for (j, r) in &boxes {
                    assert!(*j == i || !r.hit_by(*a, *b), "leader of {i} crosses label {j}");
                }
            }
        }
    }

    #[test]
    fn labels_without_room_are_dropped_not_forced() {
        let anchors = [(50.0, 50.0), (52.0, 50.0)];
        let sizes = [(300.0, 16.0), (300.0, 16.0)];
        let bounds = Rect { x0: 0.0, y0: 0.0, x1: 100.0, y1: 100.0 };
        let placed = place_labels(&LabelProblem { anchors: &anchors, sizes: &sizes, marker: MARKER, bounds, obstacles: &[], avoid: &[] });
        assert_eq!(placed, [None, None]);
        let small = [(20.0, 10.0), (20.0, 10.0)];
        let placed = place_labels(&LabelProblem { anchors: &anchors, sizes: &small, marker: MARKER, bounds, obstacles: &[], avoid: &[] });
        let (a, b) = (placed[0].unwrap().rect, placed[1].unwrap().rect);
        assert!(!a.intersects(&b) && bounds.contains(&a) && bounds.contains(&b));
    }
}
