//! Drawing: the bundled font, the line palette and dash patterns, and the one place PNG and SVG bytes are
//! made ([`render_with`]: supersampled, then averaged down or kept as a `viewBox`).

use super::*;

pub(super) static FONT: Once = Once::new();

pub(super) fn register_font() {
    FONT.call_once(|| {
        // The bundled font is valid; if registration failed, text would be missing but plotting still works.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../../../assets/fonts/DejaVuSans.ttf"),
        );
    });
}

/// Line colours: the Okabe–Ito colour-blind-safe set (its yellow left out, too pale on white; its black
/// softened) and four of Paul Tol's, in an order that keeps neighbours far apart.
pub(super) const PALETTE: [RGBColor; 12] = [
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
pub(super) const DASHES: [&[f64]; 5] = [&[], &[7.0, 4.0], &[1.5, 3.0], &[7.0, 3.0, 1.5, 3.0], &[14.0, 4.0]];

pub(super) fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// How series `i` of `n` is drawn: colour, dash pattern and width in pixels. Earlier series are wider (3.5 px
/// down to 1.5 px) and drawn first, so a curve exactly under a later one still shows along both its edges.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct LineStyle {
    pub(super) color: RGBColor,
    pub(super) dash: &'static [f64],
    pub(super) width: f64,
}

pub(super) fn line_style(i: usize, n: usize) -> LineStyle {
    let width = if n <= 1 { 2.0 } else { 1.5 + 2.0 * (n - 1 - i.min(n - 1)) as f64 / (n - 1) as f64 };
    LineStyle { color: color(i), dash: DASHES[i % DASHES.len()], width }
}

pub(super) type DrawResult<T> = Result<T, String>;

pub(super) fn err<E: std::fmt::Display>(e: E) -> String {
    format!("plotting failed: {e}")
}

/// Plots drawn through [`figure`] are drawn at this many times their size: the PNG is then averaged down
/// k × k (anti-aliased lines and text), the SVG keeps the k× user units under a 1× `width`/`height` with a
/// `viewBox`, so its coordinates have 1/k-pixel precision.
pub(super) const SUPERSAMPLE: u32 = 4;
/// The PNG drawing buffer is kept under this many pixels: big images are drawn at a smaller factor.
pub(super) const MAX_DRAW_PIXELS: u64 = 40_000_000;


/// Draws a plot at `supersample`× its `size` and encodes it: the one place PNG and SVG are made (plotters'
/// backends are different types, hence two closures, each given the drawing area and the scale k). PNG: drawn
/// at k× (k lowered for big images so the buffer stays under [`MAX_DRAW_PIXELS`]), then each k × k block
/// averaged into one pixel. SVG: the k× drawing under `width`/`height` of the 1× size and a k× `viewBox`.
pub(super) fn render_with<A, B>(format: Format, size: (u32, u32), supersample: u32, png: A, svg: B) -> DrawResult<Vec<u8>>
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
pub(super) fn box_down(big: &[u8], w: usize, h: usize, k: usize) -> Vec<u8> {
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
