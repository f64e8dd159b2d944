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
//!
//! One file per concern: [`style`] (font, palette, PNG/SVG encoding), [`axis`] (ticks and their labels),
//! `figure` (the cartesian figure the lobe and curve plots draw), `request` (`lobe plot`'s figure of formulas
//! and tables), [`scatter`] (the bench scatter), [`rect`] and
//! [`labels`] (boxes and label placement), [`comparison`] (the render comparison picture); the plots a caller
//! asks for are here.

mod axis;
mod comparison;
mod figure;
mod labels;
mod rect;
mod request;
mod scatter;
mod style;
#[cfg(test)]
mod tests;

pub use comparison::comparison_figure;
pub use request::{plot_lobes, LobePlot, Plotted};
pub use scatter::{speed_error, CostError};

use axis::*;
use figure::*;
use labels::*;
use rect::*;
use style::*;
// Names plotters' prelude has too: these are ours.
use rect::Rect;
use style::DrawResult;

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
    /// The value axis's range (cartesian plots), instead of one fitted to the curves; curves are clipped to it.
    pub ylim: Option<(f64, f64)>,
    /// What the values are (the value axis's description): [`VALUE`], or [`DIFFERENCE`] for error curves.
    pub value: &'static str,
}

/// The value axis of lobes.
pub const VALUE: &str = "formula value f";
/// The value axis of error curves (each formula minus the reference).
pub const DIFFERENCE: &str = "f − reference";
/// The angle axis of [`lobe_points`] curves.
pub const LOBE_ANGLE: &str = "lobe angle θ (degrees): lobe variable NH or VR = cos θ; L = N, V at θ";
/// The angle axis of [`incidence_points`] curves.
pub const INCIDENCE_ANGLE: &str = "view angle θₒ in the plane of incidence (degrees; mirror at −θᵢ)";

/// A curve's values are poles, not a lobe, beyond this many times the largest value of every curve away from
/// grazing (|angle| ≤ 90 % of the axis's extent): the value axis then ends below them ([`value_range`]).
const POLE_RATIO: f64 = 20.0;

/// The value axis for `series` on an angle axis: the finite values' extent, except that values beyond
/// [`POLE_RATIO`] times the largest magnitude away from grazing are left off the axis (a pole at grazing, as
/// Ward's 1/√(NL·NV), would otherwise flatten every curve to a line at 0). Also each curve's legend name, with
/// what was left off ("max 1.3e8 off the axis").
fn value_range(series: &[Series]) -> ((f64, f64), Vec<String>) {
    let finite = || series.iter().flat_map(|s| s.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
    let reach = finite().fold(0.0f64, |m, p| m.max(p.0.abs()));
    let core = finite().filter(|p| p.0.abs() <= 0.9 * reach).fold(0.0f64, |m, p| m.max(p.1.abs()));
    let limit = if core > 0.0 { POLE_RATIO * core } else { f64::INFINITY };
    let shown = || finite().map(|p| p.1).filter(|v| v.abs() <= limit);
    let (lo, hi) = shown().fold((0.0f64, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let names = series
        .iter()
        .map(|s| {
            let off = s.points.iter().filter(|p| p.1.is_finite() && p.1.abs() > limit).max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
            match off {
                Some(&(_, v)) => format!("{} (max {v:.1e} off the axis)", s.name),
                None => s.name.clone(),
            }
        })
        .collect();
    ((lo, hi), names)
}

impl LobeOptions {
    /// `ylim` checked against the plot's kind: cartesian only, lo < hi, finite, lo > 0 on a log axis.
    fn checked_ylim(&self) -> DrawResult<Option<(f64, f64)>> {
        let Some((lo, hi)) = self.ylim else { return Ok(None) };
        if self.polar {
            return Err("a value range applies to cartesian plots only".into());
        }
        if !(lo.is_finite() && hi.is_finite() && lo < hi) || (self.log && lo <= 0.0) {
            return Err(format!("the value range {lo}..{hi} is not an interval{}", if self.log { " of positive values (log axis)" } else { "" }));
        }
        Ok(Some((lo, hi)))
    }
}

/// Lobes (value against angle in degrees, 0..90). Polar: radius = value, drawn on both sides of the axis.
pub fn lobes(series: &[Series], o: &LobeOptions, format: Format) -> DrawResult<Vec<u8>> {
    if o.polar && o.log {
        return Err("a log scale applies to cartesian plots only (a log radius has no zero)".into());
    }
    let ylim = o.checked_ylim()?;
    let values = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|v| v.is_finite());
    if values().next().is_none() {
        return Err("nothing to plot: no curve has a finite value (is the formula NaN or infinite everywhere?)".into());
    }
    let log_desc = format!("{} (log)", o.value);
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
        let (lo, hi) = ylim.map_or((ymin_pos.log10(), (ymax * 1.5).log10()), |(a, b)| (a.log10(), b.log10()));
        let y = Axis { lo, hi, log: true, desc: &log_desc };
        Figure { title: &o.title, x: Axis { lo: 0.0, hi: 90.0, log: false, desc: LOBE_ANGLE }, y, curves, to_scale: false, light: None }
    } else {
        let ((ymin, ymax), names) = value_range(series);
        let curves = series.iter().zip(&names).map(|(s, name)| Curve::new(name, s.points.iter().map(|&p| Some(p)))).collect();
        let (lo, hi) = ylim.unwrap_or((ymin * 1.05, ymax.max(1e-12) * 1.05));
        let y = Axis { lo, hi, log: false, desc: o.value };
        Figure { title: &o.title, x: Axis { lo: 0.0, hi: 90.0, log: false, desc: LOBE_ANGLE }, y, curves, to_scale: false, light: None }
    };
    render_figure(&fig, format, o.size)
}

/// A polar figure of signed-angle series (angle from the normal in degrees, −90..90; radius = value, negative
/// values drawn at 0), with both axes to the same scale (a circle stays a circle) and, when given, the
/// direction of the light (`light_deg`, on the opposite side from the mirror direction) as a grey ray.
///
/// A pole at grazing ([`value_range`]) is drawn at the largest value kept, and named in the legend.
fn polar_figure<'a>(title: &'a str, series: &[Series], light_deg: Option<f64>) -> Figure<'a> {
    let ((_, top), names) = value_range(series);
    let xy = |&(deg, v): &(f64, f64)| {
        let r = v.clamp(0.0, top);
        (r * deg.to_radians().sin(), r * deg.to_radians().cos())
    };
    let curves: Vec<Curve> = series.iter().zip(&names).map(|(s, name)| Curve::new(name, s.points.iter().map(|p| Some(xy(p))))).collect();
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
    if o.polar && o.log {
        return Err("a log scale applies to cartesian plots only (a log radius has no zero)".into());
    }
    let ylim = o.checked_ylim()?;
    let finite = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|v| v.is_finite());
    let ymax = finite().fold(f64::NEG_INFINITY, f64::max);
    if ymax == f64::NEG_INFINITY {
        return Err("nothing to plot: no curve has a finite value (is the formula NaN or infinite everywhere?)".into());
    }
    let x_desc = INCIDENCE_ANGLE;
    let log_desc = format!("{} (log)", o.value);
    if o.log {
        let ymin_pos = finite().filter(|v| *v > 0.0).fold(f64::INFINITY, f64::min);
        if !ymin_pos.is_finite() {
            return Err("nothing to plot on a log scale: no curve has a positive finite value (use a linear scale)".into());
        }
        let ymin_pos = ymin_pos.max(ymax * 1e-12);
        let xs = || series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).filter(|x| x.is_finite());
        let (xmin, xmax) = (xs().fold(f64::INFINITY, f64::min), xs().fold(f64::NEG_INFINITY, f64::max));
        let curves = series
            .iter()
            .map(|s| Curve::new(&s.name, s.points.iter().map(|&(d, v)| (v >= ymin_pos).then(|| (d, v.log10())))))
            .collect();
        let title = format!("{}, light at θᵢ = {theta_i_deg}°", o.title);
        let fig = Figure {
            title: &title,
            x: Axis { lo: xmin, hi: if xmax > xmin { xmax } else { xmin + 1.0 }, log: false, desc: x_desc },
            y: ylim.map_or(Axis { lo: ymin_pos.log10(), hi: (ymax * 1.5).log10(), log: true, desc: &log_desc }, |(a, b)| Axis {
                lo: a.log10(),
                hi: b.log10(),
                log: true,
                desc: &log_desc,
            }),
            curves,
            to_scale: false,
            light: None,
        };
        return render_figure(&fig, format, o.size);
    }
    if !o.polar {
        let title = format!("{}, light at θᵢ = {theta_i_deg}°", o.title);
        let (range, names) = value_range(series);
        let named: Vec<Series> = series.iter().zip(names).map(|(s, name)| Series { name, points: s.points.clone() }).collect();
        return curves_sized(&named, &title, x_desc, o.value, format, o.size, ylim.or(Some(padded(range))));
    }
    let title = format!("{}, light at θᵢ = {theta_i_deg}°", o.title);
    render_figure(&polar_figure(&title, series, Some(theta_i_deg)), format, o.size)
}

/// A value range with 5 % spare on each side (a range of one value: ±1 around it).
fn padded((lo, hi): (f64, f64)) -> (f64, f64) {
    if hi > lo {
        let pad = (hi - lo) * 0.05;
        (lo - pad, hi + pad)
    } else {
        (lo - 1.0, hi + 1.0)
    }
}

/// Curves over any x range (e.g. the normalisation coefficient against n over a range of n).
pub fn curves(series: &[Series], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    curves_sized(series, title, x_desc, y_desc, format, (900, 600), None)
}

/// [`curves`] in an image of `size` pixels.
pub(crate) fn curves_sized(
    series: &[Series],
    title: &str,
    x_desc: &str,
    y_desc: &str,
    format: Format,
    size: (u32, u32),
    ylim: Option<(f64, f64)>,
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
        y: ylim.map_or(Axis { lo: ymin - pad, hi: ymax + pad, log: false, desc: y_desc }, |(lo, hi)| Axis { lo, hi, log: false, desc: y_desc }),
        curves,
        to_scale: false,
        light: None,
    };
    render_figure(&fig, format, size)
}
