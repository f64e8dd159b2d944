//! Plots rendered in both formats and read back: ticks, labels, styles, anti-aliasing, margins.

use super::scatter::*;
use super::*;

fn cos_n(n: f64) -> Series {
    Series { name: format!("cos^{n}"), points: (0..=90).map(|d| (d as f64, (d as f64).to_radians().cos().powf(n))).collect() }
}

#[test]
fn lobe_plots_render_in_every_mode() {
    for (polar, log) in [(false, false), (true, false), (false, true)] {
        let o = LobeOptions { title: "t".into(), polar, log, size: (320, 240), ylim: None, value: VALUE };
        let png = lobes(&[cos_n(5.0), cos_n(50.0)], &o, Format::Png).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let svg = lobes(&[cos_n(5.0)], &o, Format::Svg).unwrap();
        assert!(String::from_utf8(svg).unwrap().contains("<svg"));
    }
    let o = LobeOptions { title: "t".into(), polar: true, log: true, size: (320, 240), ylim: None, value: VALUE };
    assert!(lobes(&[cos_n(5.0)], &o, Format::Png).is_err());
}

#[test]
fn polar_plots_are_to_scale() {
    // A value of 1 in every direction is a half circle: as wide (to each side) as it is tall, in pixels,
    // whatever the image's aspect, for the lobe plot and the plane-of-incidence plot alike.
    let half: Vec<(f64, f64)> = (0..=360).map(|i| (i as f64 * 0.25, 1.0)).collect();
    let signed: Vec<(f64, f64)> = (0..=720).map(|i| (-90.0 + i as f64 * 0.25, 1.0)).collect();
    for size in [(560, 400), (400, 500)] {
        let o = LobeOptions { title: "t".into(), polar: true, log: false, size, ylim: None, value: VALUE };
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
    let log = LobeOptions { title: "t".into(), polar: false, log: true, size: (320, 240), ylim: None, value: VALUE };
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
        let o = LobeOptions { title: "t".into(), polar: false, log: true, size, ylim: None, value: VALUE };
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
    let o = LobeOptions { title: "t".into(), polar: false, log: false, size: (600, 400), ylim: None, value: VALUE };
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
    let png = curves_sized(std::slice::from_ref(&line), "t", "x", "y", Format::Png, (500, 400), None).unwrap();
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
    let svg = String::from_utf8(curves_sized(&[line], "t", "x", "y", Format::Svg, (500, 400), None).unwrap()).unwrap();
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
            pngs.push(lobes(&many, &LobeOptions { title: "Lobes".into(), polar, log, size, ylim: None, value: VALUE }, Format::Png).unwrap());
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

/// A pole at grazing (1/cos θ, 6e16 at 90°) leaves the value axis where the other curves and the pole's own
/// finite stretch are readable, and its legend says what is off the axis; a narrow lobe's peak at 0° (cos¹⁰⁰⁰),
/// a Fresnel-like rise to grazing and random smooth curves keep their whole extent.
#[test]
fn a_pole_at_grazing_does_not_set_the_value_axis() {
    let pole = Series { name: "pole".into(), points: (0..=360).map(|i| (i as f64 * 0.25, 1.0 / (i as f64 * 0.25).to_radians().cos())).collect() };
    let ((lo, hi), names) = value_range(&[pole.clone(), cos_n(5.0)]);
    assert!(lo == 0.0 && hi < POLE_RATIO * 1.0 / 81f64.to_radians().cos() && hi > 10.0, "{lo} {hi}");
    assert!(names[0].contains("off the axis") && names[1] == "cos^5", "{names:?}");
    let fresnel = Series { name: "F".into(), points: (0..=90).map(|d| (d as f64, 0.04 + 0.96 * (1.0 - (d as f64).to_radians().cos()).powi(5))).collect() };
    let mut rng = crate::base::rng::Rng(0x9013);
    let mut all = vec![cos_n(1000.0), fresnel];
    for k in 0..5 {
        let (a, b) = (rng.unit() * 10.0, rng.unit() * 3.0);
        all.push(Series { name: format!("r{k}"), points: (0..=90).map(|d| (d as f64, a * (d as f64 / 30.0 * b).sin() + a)).collect() });
    }
    for s in &all {
        let ((lo, hi), names) = value_range(std::slice::from_ref(s));
        let (min, max) = s.points.iter().fold((0.0f64, 0.0f64), |(a, b), p| (a.min(p.1), b.max(p.1)));
        assert!(lo == min && hi == max && names[0] == s.name, "{}: {lo} {hi} vs {min} {max}", s.name);
    }
    // The plot draws (the pole clipped, not flattening the other curve).
    let o = LobeOptions { title: "t".into(), polar: false, log: false, size: (320, 240), ylim: None, value: VALUE };
    for polar in [false, true] {
        assert_eq!(&lobes(&[pole.clone(), cos_n(5.0)], &LobeOptions { polar, ..o.clone() }, Format::Png).unwrap()[1..4], b"PNG");
    }
}
