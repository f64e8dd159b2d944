//! The comparison picture of `render::compare`'s sweep image: headings, row labels and a colour bar.

use super::*;

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
