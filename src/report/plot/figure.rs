//! The cartesian figure every lobe and curve plot is drawn as: title, axes, curves broken where a value
//! cannot be drawn, a legend to the right, lines clipped to the plot; [`layout`] places the parts, [`figure`]
//! draws them.

use super::*;

pub(super) const FIG_TITLE_PX: f64 = 20.0;
pub(super) const FIG_TICK_PX: f64 = 14.0;
pub(super) const FIG_DESC_PX: f64 = 15.0;
pub(super) const FIG_LEGEND_PX: f64 = 14.0;


pub(super) struct Curve {
    pub(super) name: String,
    pub(super) runs: Vec<Vec<(f64, f64)>>,
}

impl Curve {
    pub(super) fn new(name: &str, points: impl Iterator<Item = Option<(f64, f64)>>) -> Curve {
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
pub(super) struct Figure<'a> {
    pub(super) title: &'a str,
    pub(super) x: Axis<'a>,
    pub(super) y: Axis<'a>,
    pub(super) curves: Vec<Curve>,
    pub(super) to_scale: bool,
    pub(super) light: Option<(f64, f64)>,
}

/// Where a figure's parts go, in drawing pixels (k× the image's).
pub(super) struct Layout<'a> {
    pub(super) plot: Rect,
    pub(super) x: Axis<'a>,
    pub(super) y: Axis<'a>,
    pub(super) xt: Vec<AxisTick>,
    pub(super) yt: Vec<AxisTick>,
    pub(super) legend: Vec<(String, Option<LineStyle>)>,
    pub(super) legend_cols: usize,
    pub(super) legend_col_w: f64,
    pub(super) legend_px: f64,
}

/// Draws a [`Figure`] on `root` at scale `k` (drawing pixels per image pixel); `ink_shift` (em) moves text
/// down to centre it on its anchor (the bitmap backend's baseline sits higher than an SVG viewer's).
pub(super) fn figure<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, f: &Figure, k: f64, ink_shift: f64) -> DrawResult<()> {
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
    // Centred under the plot, in a smaller size where it is wider than the image (a long axis description on
    // a small plot), never past the image's edges.
    let room = w - 16.0 * k;
    let wide = measure(l.x.desc, FIG_DESC_PX);
    let desc_px = if wide > room { FIG_DESC_PX * room / wide } else { FIG_DESC_PX };
    let half = measure(l.x.desc, desc_px) / 2.0;
    let centre = ((p.x0 + p.x1) / 2.0).clamp(8.0 * k + half, (w - 8.0 * k - half).max(8.0 * k + half));
    text(l.x.desc, desc_px, (centre, x_desc_y), HPos::Center, ink)?;
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
pub(super) fn layout<'a>(f: &Figure<'a>, (w, h): (f64, f64), k: f64, measure: &dyn Fn(&str, f64) -> f64) -> Layout<'a> {
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
pub(super) fn clip_polyline(pts: &[(f64, f64)], r: &Rect) -> Vec<Vec<(f64, f64)>> {
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
pub(super) fn stroke<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, pts: &[(f64, f64)], c: RGBColor, width: f64, dash: &[f64], k: f64) -> DrawResult<()> {
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


pub(super) fn render_figure(fig: &Figure, format: Format, size: (u32, u32)) -> DrawResult<Vec<u8>> {
    render_with(format, size, SUPERSAMPLE, |r, k| figure(r, fig, k, 0.17), |r, k| figure(r, fig, k, 0.0))
}
