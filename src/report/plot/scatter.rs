//! The speed-versus-error scatter of a bench table, laid out by hand in pixels: 1-2-5 log ticks, the "0"
//! band for exact rows, the Pareto staircase, labels placed by [`place_labels`] and a footnote for what
//! cannot be shown.

use super::*;

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
pub(super) const SCATTER_SIZE: (u32, u32) = (1200, 820);
pub(super) const TITLE_PX: f64 = 22.0;
pub(super) const LEGEND_PX: f64 = 14.0;
pub(super) const TICK_PX: f64 = 14.0;
pub(super) const DESC_PX: f64 = 16.0;
pub(super) const LABEL_PX: f64 = 13.0;
pub(super) const NOTE_PX: f64 = 12.0;
/// Half the side of a marker's box.
pub(super) const MARKER: f64 = 5.0;
/// Height of the band that holds the error = 0 rows, and the gap between it and the log area.
pub(super) const BAND: f64 = 40.0;
pub(super) const BAND_GAP: f64 = 12.0;
/// Footnotes never take more than this many lines from the plot (a long list is cut with "…").
pub(super) const MAX_NOTE_LINES: usize = 4;

/// Cost (x, log) against error (y, log), with a "0" band below for exact rows, the Pareto front as a
/// staircase, a legend per series and labels placed by [`place_labels`] so that none overlaps another, a point
/// or the frame; labels that find no room, and rows that cannot be placed at all, are named in a footnote.
pub fn speed_error(points: &[CostError], title: &str, x_desc: &str, y_desc: &str, format: Format) -> DrawResult<Vec<u8>> {
    let s = Scatter::new(points, title, x_desc, y_desc)?;
    // ab_glyph in the bitmap backend puts the baseline ~0.17 em higher than an SVG viewer does for the same
    // anchor; the shift re-centres bitmap text in the boxes the labels were placed with.
    render_with(format, SCATTER_SIZE, 1, |r, _| s.draw(r, 0.17), |r, _| s.draw(r, 0.0))
}

/// The scatter's data, checked and grouped once, drawn by either backend.
pub(super) struct Scatter<'a> {
    pub(super) points: &'a [CostError],
    pub(super) title: &'a str,
    pub(super) x_desc: &'a str,
    pub(super) y_desc: &'a str,
    /// Series names in order of first appearance; index = marker shape and colour.
    pub(super) series: Vec<&'a str>,
    /// Indices of rows with a positive finite cost and a finite error ≥ 0.
    pub(super) shown: Vec<usize>,
    /// Rows that cannot be placed on the axes.
    pub(super) unplaceable: Vec<usize>,
    /// log10 ranges of the axes.
    pub(super) x: (f64, f64),
    pub(super) y: (f64, f64),
    pub(super) has_zero: bool,
}

/// Pads a log10 range by 6 % of its span each side and widens it to at least one decade. The ends are not
/// snapped to 1-2-5 values: that costs up to 0.4 decade of room the labels need.
pub(super) fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = if hi - lo < 1.0 { ((lo + hi) / 2.0 - 0.5, (lo + hi) / 2.0 + 0.5) } else { (lo, hi) };
    let pad = (hi - lo) * 0.06;
    (lo - pad, hi + pad)
}

impl<'a> Scatter<'a> {
    pub(super) fn new(points: &'a [CostError], title: &'a str, x_desc: &'a str, y_desc: &'a str) -> DrawResult<Scatter<'a>> {
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

    pub(super) fn color(&self, p: &CostError) -> RGBColor {
        color(self.series.iter().position(|s| *s == p.series).unwrap_or(0))
    }

    pub(super) fn shape(&self, p: &CostError) -> usize {
        self.series.iter().position(|s| *s == p.series).unwrap_or(0)
    }

    /// Lays out and draws the figure. `ink_shift` (em) moves text down to centre it in its box (backend quirk).
    pub(super) fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, ink_shift: f64) -> DrawResult<()> {
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
    pub(super) fn y_tick_labels(&self) -> Vec<String> {
        log_ticks(self.y.0, self.y.1, 1e6, 0.0).iter().map(tick_label).collect()
    }

    /// The longest x tick label, to keep the last one inside the figure.
    pub(super) fn x_ticks_sample(&self) -> String {
        log_ticks(self.x.0, self.x.1, 1e6, 0.0).iter().map(tick_label).max_by_key(|s| s.chars().count()).unwrap_or_default()
    }

    /// The Pareto front as a staircase through the flagged points sorted by cost (error steps down at each).
    pub(super) fn front(&self, geo: &Geometry) -> Vec<[(f64, f64); 2]> {
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
pub(super) struct Geometry {
    pub(super) main: Rect,
    pub(super) band: Option<Rect>,
    pub(super) x: (f64, f64),
    pub(super) y: (f64, f64),
}

impl Geometry {
    pub(super) fn x_px(&self, v: f64) -> f64 {
        self.main.x0 + (v.log10() - self.x.0) / (self.x.1 - self.x.0) * (self.main.x1 - self.main.x0)
    }
    pub(super) fn y_px(&self, v: f64) -> f64 {
        self.main.y0 + (self.y.1 - v.log10()) / (self.y.1 - self.y.0) * (self.main.y1 - self.main.y0)
    }
    pub(super) fn at(&self, p: &CostError) -> (f64, f64) {
        let y = match self.band {
            Some(b) if p.error == 0.0 => (b.y0 + b.y1) / 2.0,
            _ => self.y_px(p.error),
        };
        (self.x_px(p.cost), y)
    }
}

/// `prefix` then the items joined by "; ", broken into lines no wider than `width`.
pub(super) fn wrap(prefix: &str, items: &[String], width: f64, measure: impl Fn(&str) -> f64) -> Vec<String> {
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
pub(super) fn marker<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, shape: usize, (x, y): (f64, f64), c: RGBColor, outline: bool) -> DrawResult<()> {
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
