//! Plots: lobes against angle (cartesian or polar, like the papers' figures 2.2/3.3 and BRDF Explorer), error
//! curves against a reference, and the speed-versus-error scatter of `lobe bench`.
//!
//! Design: plotters draws into memory (an RGB buffer for PNG, a string for SVG), the bytes are encoded here
//! and handed to the caller, which writes them atomically — a failed plot never leaves a broken file. The font
//! (DejaVu Sans, assets/fonts, free licence) is compiled in, so plots look the same on a machine with no fonts.

use plotters::coord::Shift;
use plotters::prelude::*;
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

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Draws every series as a labelled line with a legend; `points` maps a series to what is drawn.
macro_rules! draw_lines {
    ($chart:expr, $series:expr, $points:expr) => {{
        let points = $points;
        for (i, s) in $series.iter().enumerate() {
            let c = color(i);
            $chart
                .draw_series(LineSeries::new(points(s), c.stroke_width(2)))
                .map_err(err)?
                .label(&s.name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        }
        $chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
    }};
}

type DrawResult<T> = Result<T, String>;

fn err<E: std::fmt::Display>(e: E) -> String {
    format!("plotting failed: {e}")
}

/// Lobes (value against angle in degrees, 0..90). Polar: radius = value, drawn on both sides of the axis.
pub fn lobes(series: &[Series], o: &LobeOptions, format: Format) -> DrawResult<Vec<u8>> {
    if o.polar && o.log {
        return Err("--log applies to cartesian plots only (a log radius has no zero)".into());
    }
    let values = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).filter(|v| v.is_finite());
    if values().next().is_none() {
        return Err("nothing to plot: no curve has a finite value (is the formula NaN or infinite everywhere?)".into());
    }
    let ymax = values().fold(0.0f64, f64::max).max(1e-12);
    let ymin_pos = values().filter(|v| *v > 0.0).fold(f64::INFINITY, f64::min);
    if o.log && !ymin_pos.is_finite() {
        return Err("nothing to plot on a log scale: no curve has a positive finite value (drop --log)".into());
    }
    let ymin_pos = ymin_pos.max(ymax * 1e-12);
    macro_rules! body {
        ($root:expr) => {{
            let root = $root;
            if o.polar {
                let r = ymax * 1.05;
                let mut chart = ChartBuilder::on(root)
                    .caption(&o.title, ("sans-serif", 22))
                    .margin(12)
                    .x_label_area_size(30)
                    .y_label_area_size(50)
                    .build_cartesian_2d(-r..r, 0.0..r)
                    .map_err(err)?;
                chart.configure_mesh().x_desc("value · sin θ").y_desc("value · cos θ").draw().map_err(err)?;
                draw_lines!(chart, series, |s: &Series| -> Vec<(f64, f64)> { s
                        .points
                        .iter()
                        .rev()
                        .map(|&(deg, v)| (-v.max(0.0) * deg.to_radians().sin(), v.max(0.0) * deg.to_radians().cos()))
                        .chain(s.points.iter().map(|&(deg, v)| (v.max(0.0) * deg.to_radians().sin(), v.max(0.0) * deg.to_radians().cos())))
                        .filter(|p| p.0.is_finite() && p.1.is_finite())
                        .collect() });
            } else if o.log {
                let mut chart = ChartBuilder::on(root)
                    .caption(&o.title, ("sans-serif", 22))
                    .margin(12)
                    .x_label_area_size(35)
                    .y_label_area_size(60)
                    .build_cartesian_2d(0.0..90.0, (ymin_pos..ymax * 1.5).log_scale())
                    .map_err(err)?;
                chart.configure_mesh().x_desc("angle (degrees)").y_desc("value (log)").draw().map_err(err)?;
                draw_lines!(chart, series, |s: &Series| -> Vec<(f64, f64)> { s.points.iter().copied().filter(|p| p.1.is_finite() && p.1 > 0.0).collect() });
            } else {
                let ymin = series
                    .iter()
                    .flat_map(|s| s.points.iter().map(|p| p.1))
                    .filter(|v| v.is_finite())
                    .fold(0.0f64, f64::min);
                let mut chart = ChartBuilder::on(root)
                    .caption(&o.title, ("sans-serif", 22))
                    .margin(12)
                    .x_label_area_size(35)
                    .y_label_area_size(60)
                    .build_cartesian_2d(0.0..90.0, ymin * 1.05..ymax * 1.05)
                    .map_err(err)?;
                chart.configure_mesh().x_desc("angle (degrees)").y_desc("value").draw().map_err(err)?;
                draw_lines!(chart, series, |s: &Series| -> Vec<(f64, f64)> { s.points.iter().copied().filter(|p| p.1.is_finite()).collect() });
            }
            Ok(())
        }};
    }
    render_with(format, o.size, |r| body!(r), |r| body!(r))
}

/// Curves over any x range (e.g. coef(n) against n for `lobe energy --range … --plot`).
pub fn curves(series: &[Series], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    let pts = || series.iter().flat_map(|s| s.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
    let (xmin, xmax) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (ymin, ymax) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if !(xmin.is_finite() && ymin.is_finite()) {
        return Err("nothing to plot: no finite points".into());
    }
    let (xmax, ymax) = (if xmax > xmin { xmax } else { xmin + 1.0 }, if ymax > ymin { ymax } else { ymin + 1.0 });
    let pad = (ymax - ymin) * 0.05;
    macro_rules! body {
        ($root:expr) => {{
            let mut chart = ChartBuilder::on($root)
                .caption(title, ("sans-serif", 22))
                .margin(12)
                .x_label_area_size(35)
                .y_label_area_size(70)
                .build_cartesian_2d(xmin..xmax, (ymin - pad)..(ymax + pad))
                .map_err(err)?;
            chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(err)?;
            draw_lines!(chart, series, |s: &Series| -> Vec<(f64, f64)> { s.points.iter().copied().filter(|p| p.0.is_finite() && p.1.is_finite()).collect() });
            Ok(())
        }};
    }
    render_with(format, (900, 600), |r| body!(r), |r| body!(r))
}

/// One point of the speed-versus-error scatter.
#[derive(Clone, Debug)]
pub struct CostError {
    pub name: String,
    /// Cost, e.g. ns per evaluation.
    pub cost: f64,
    /// Error against the reference, e.g. mean |Δ| on the papers' grid.
    pub error: f64,
    pub pareto: bool,
    /// Which series the point belongs to (e.g. the math mode).
    pub series: String,
}

/// Cost (x, log) against error (y, log), labelled, with the Pareto front joined by a line.
pub fn speed_error(points: &[CostError], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    let finite: Vec<&CostError> = points.iter().filter(|p| p.cost > 0.0 && p.error > 0.0 && p.cost.is_finite() && p.error.is_finite()).collect();
    if finite.is_empty() {
        return Err("nothing to plot: every point has zero or non-finite cost or error".into());
    }
    let (xmin, xmax) = finite.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| (a.min(p.cost), b.max(p.cost)));
    let (ymin, ymax) = finite.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| (a.min(p.error), b.max(p.error)));
    let mut front: Vec<(f64, f64)> = finite.iter().filter(|p| p.pareto).map(|p| (p.cost, p.error)).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    macro_rules! body {
        ($root:expr) => {{
            let mut chart = ChartBuilder::on($root)
                .caption(title, ("sans-serif", 22))
                .margin(16)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d((xmin / 1.5..xmax * 1.5).log_scale(), (ymin / 2.0..ymax * 2.0).log_scale())
                .map_err(err)?;
            chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(err)?;
            chart.draw_series(LineSeries::new(front.clone(), RED.mix(0.5).stroke_width(2))).map_err(err)?;
            for p in &finite {
                let c = if p.pareto { RED } else { RGBColor(31, 119, 180) };
                chart
                    .draw_series(std::iter::once(Circle::new((p.cost, p.error), 5, c.filled())))
                    .map_err(err)?;
                chart
                    .draw_series(std::iter::once(Text::new(p.name.clone(), (p.cost, p.error), ("sans-serif", 14))))
                    .map_err(err)?;
            }
            Ok(())
        }};
    }
    render_with(format, (1000, 700), |r| body!(r), |r| body!(r))
}

/// `render` with two closures (plotters' backends are different types).
fn render_with<A, B>(format: Format, size: (u32, u32), png: A, svg: B) -> DrawResult<Vec<u8>>
where
    A: FnOnce(&DrawingArea<BitMapBackend, Shift>) -> DrawResult<()>,
    B: FnOnce(&DrawingArea<SVGBackend, Shift>) -> DrawResult<()>,
{
    register_font();
    match format {
        Format::Png => {
            let mut buf = vec![0u8; (size.0 as usize) * (size.1 as usize) * 3];
            {
                let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
                root.fill(&WHITE).map_err(err)?;
                png(&root)?;
                root.present().map_err(err)?;
            }
            // The renderer's encoder: same `Software: lobe` marker, so lobe may later replace its own plot.
            crate::render::image::Image { width: size.0 as usize, height: size.1 as usize, rgb: buf }.encode_png()
        }
        Format::Svg => {
            let mut s = String::new();
            {
                let root = SVGBackend::with_string(&mut s, size).into_drawing_area();
                root.fill(&WHITE).map_err(err)?;
                svg(&root)?;
                root.present().map_err(err)?;
            }
            // The marker lets lobe recognise (and later replace) its own SVGs.
            Ok([b"<!-- made by lobe -->\n".as_slice(), s.as_bytes()].concat())
        }
    }
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
    fn scatter_needs_positive_points() {
        let p = vec![
            CostError { name: "a".into(), cost: 2.0, error: 0.01, pareto: true, series: String::new() },
            CostError { name: "b".into(), cost: 5.0, error: 0.1, pareto: false, series: String::new() },
        ];
        assert!(speed_error(&p, "t", "ns", "err", Format::Png).is_ok());
        let z = vec![CostError { name: "z".into(), cost: 0.0, error: 0.0, pareto: false, series: String::new() }];
        assert!(speed_error(&z, "t", "ns", "err", Format::Svg).is_err());
    }
}
