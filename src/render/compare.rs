//! Image comparison: the papers' mean Manhattan distance on grayscale, RMSE, PSNR, and a side-by-side
//! picture A | B | difference heat map.
//!
//! The papers' metric: grayscale g = 0.299R + 0.587G + 0.114B of each 8-bit pixel (0..255 scale, not
//! rounded), then the mean of |g_A − g_B| over every pixel of the window — background included. Because
//! background pixels are equal in both images, the value scales with the fraction of the window the object
//! covers; [`Metrics::manhattan_covered`] divides by the covered pixels only, which does not depend on framing.
//!
//! Formula comparisons ([`compare_formulas`], [`compare_sweep`]) render one scene with every material's formula
//! replaced by A, then by B. A sweep over n parses the scene and builds its meshes once
//! ([`super::scene::Geometry`]) and recompiles only the two formulas per n.

use super::image::Image;

/// Differences between two images of the same size.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// Mean |Δ gray| over all pixels (the papers' number), 0..255 scale.
    #[serde(serialize_with = "crate::base::json::num")]
    pub manhattan: f64,
    /// Mean |Δ gray| over the pixels an object covers in either image.
    #[serde(serialize_with = "crate::base::json::num")]
    pub manhattan_covered: f64,
    /// Largest |Δ gray|.
    #[serde(serialize_with = "crate::base::json::num")]
    pub max_gray_diff: f64,
    /// Root mean square of the per-channel differences, 0..255 scale.
    #[serde(serialize_with = "crate::base::json::num")]
    pub rmse: f64,
    /// 20·log10(255 / rmse); infinite for identical images.
    #[serde(serialize_with = "crate::base::json::num")]
    pub psnr: f64,
}

pub(crate) fn gray(p: [u8; 3]) -> f64 {
    0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
}

/// Compares `a` and `b` (same size); `covered` marks object pixels (empty slice: all pixels count).
pub fn metrics(a: &Image, b: &Image, covered: &[bool]) -> Result<Metrics, String> {
    if a.width != b.width || a.height != b.height {
        return Err(format!("image sizes differ: {}×{} vs {}×{}", a.width, a.height, b.width, b.height));
    }
    let n = a.width * a.height;
    if n == 0 {
        return Err("empty images".into());
    }
    let (mut sum, mut sum_cov, mut n_cov, mut max, mut sq) = (0.0, 0.0, 0usize, 0.0f64, 0.0);
    for i in 0..n {
        let pa = [a.rgb[3 * i], a.rgb[3 * i + 1], a.rgb[3 * i + 2]];
        let pb = [b.rgb[3 * i], b.rgb[3 * i + 1], b.rgb[3 * i + 2]];
        let d = (gray(pa) - gray(pb)).abs();
        sum += d;
        if covered.get(i).copied().unwrap_or(true) {
            sum_cov += d;
            n_cov += 1;
        }
        max = max.max(d);
        for k in 0..3 {
            let e = pa[k] as f64 - pb[k] as f64;
            sq += e * e;
        }
    }
    let rmse = (sq / (3 * n) as f64).sqrt();
    Ok(Metrics {
        manhattan: sum / n as f64,
        manhattan_covered: if n_cov > 0 { sum_cov / n_cov as f64 } else { 0.0 },
        max_gray_diff: max,
        rmse,
        psnr: if rmse > 0.0 { 20.0 * (255.0 / rmse).log10() } else { f64::INFINITY },
    })
}

/// A heat-map colour for t ∈ [0, 1]: black → red → yellow → white.
pub(crate) fn heat(t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * 3.0;
    let c = |x: f64| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    [c(t), c(t - 1.0), c(t - 2.0)]
}

/// A | B | heat map of |Δ gray|, scaled so that `scale` (0..255 gray levels) is white. Returns the image.
pub(crate) fn side_by_side(a: &Image, b: &Image, scale: f64) -> Image {
    let (w, h) = (a.width, a.height);
    let mut out = Image::new(3 * w, h);
    for y in 0..h {
        for x in 0..w {
            let (pa, pb) = (a.pixel(x, y), b.pixel(x, y));
            out.set(x, y, pa);
            out.set(w + x, y, pb);
            out.set(2 * w + x, y, heat((gray(pa) - gray(pb)).abs() / scale.max(1e-9)));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_match_hand_computation() {
        let mut a = Image::new(2, 1);
        let mut b = Image::new(2, 1);
        a.set(0, 0, [10, 20, 30]);
        b.set(0, 0, [10, 20, 30]);
        a.set(1, 0, [100, 0, 0]);
        // pixel 1: Δgray = 0.299·100 = 29.9; mean over 2 pixels 14.95; over the covered pixel 29.9.
        let m = metrics(&a, &b, &[false, true]).unwrap();
        assert!((m.manhattan - 14.95).abs() < 1e-12);
        assert!((m.manhattan_covered - 29.9).abs() < 1e-12);
        // RMSE over 6 channels: sqrt(100²/6).
        assert!((m.rmse - (10000.0f64 / 6.0).sqrt()).abs() < 1e-12);
        assert!((m.psnr - 20.0 * (255.0 / m.rmse).log10()).abs() < 1e-12);
        assert!(metrics(&a, &a, &[]).unwrap().psnr.is_infinite());
        assert!(metrics(&a, &Image::new(1, 1), &[]).is_err());
    }

    #[test]
    fn heat_ramp_ends() {
        assert_eq!(heat(0.0), [0, 0, 0]);
        assert_eq!(heat(1.0), [255, 255, 255]);
        assert_eq!(heat(1.0 / 3.0), [255, 0, 0]);
    }

}

/// One comparison of two formulas in one scene.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// The `n` used (from `set`), if any.
    pub n: Option<f64>,
    pub metrics: Metrics,
    pub a: super::Frame,
    pub b: super::Frame,
    pub nan: [u64; 2],
}

/// One comparison in the compare command's JSON report: the two files, the n it ran at (with a sweep over n), the metrics,
/// the image size and the NaN counts of A and B (numbers follow [`crate::base::json`]).
#[derive(serde::Serialize)]
pub struct ComparisonJson<'a> {
    pub a: &'a str,
    pub b: &'a str,
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub n: Option<f64>,
    #[serde(flatten)]
    pub metrics: &'a Metrics,
    pub width: usize,
    pub height: usize,
    pub nan: [u64; 2],
}

impl Comparison {
    /// The report of this comparison of the files `a` and `b`.
    pub fn json<'a>(&'a self, a: &'a str, b: &'a str) -> ComparisonJson<'a> {
        ComparisonJson { a, b, n: self.n, metrics: &self.metrics, width: self.a.image.width, height: self.a.image.height, nan: self.nan }
    }
}

/// What [`compare_formulas`] and [`compare_sweep`] render: a scene (name, TOML text, base directory for
/// relative paths) and two formulas (file name, source).
pub struct CompareJob<'a> {
    pub scene_name: &'a str,
    pub scene_src: &'a str,
    pub base: &'a std::path::Path,
    pub a: (&'a str, &'a str),
    pub b: (&'a str, &'a str),
    pub size: Option<(usize, usize)>,
    /// Multiplies every material's specular colour in A's and in B's render (1, 1, 1: the scene's own); a
    /// measured fit shows its fitted colour scale this way.
    pub tint: [[f64; 3]; 2],
}

/// Renders the scene with every material's formula replaced by A, then by B (same ka/kd/ks, colours,
/// parameters), and compares the two images. `set` applies to both (e.g. `n=50`).
pub fn compare_formulas(
    job: &CompareJob,
    set: &[(String, f64)],
    compiler: &dyn super::scene::BrdfCompiler,
    ropts: &super::RenderOptions,
) -> Result<Comparison, crate::Diagnostics> {
    let geometry = super::scene::parse_geometry_deferred(job.scene_name, job.scene_src, job.base, job.size)?;
    compare_in(&geometry, job.a, job.b, job.tint, set, compiler, ropts)
}

/// [`compare_formulas`] at each of `sets` (one comparison per set, in order). The
/// scene is parsed and its meshes built once; each comparison only compiles the two formulas with its values.
/// Errors are those of the first set's comparison, as if each had been run alone.
pub fn compare_sweep(
    job: &CompareJob,
    sets: &[Vec<(String, f64)>],
    compiler: &dyn super::scene::BrdfCompiler,
    ropts: &super::RenderOptions,
) -> Result<Vec<Comparison>, crate::Diagnostics> {
    let geometry = super::scene::parse_geometry_deferred(job.scene_name, job.scene_src, job.base, job.size)?;
    sets.iter().map(|set| compare_in(&geometry, job.a, job.b, job.tint, set, compiler, ropts)).collect()
}

/// One comparison in already loaded geometry: materials with formula A, render; formula B, render; metrics.
/// A `.binary` file name is a measured table ([`crate::measured`]; its text is unused): it declares nothing.
pub(crate) fn compare_in(
    geometry: &super::scene::Geometry,
    a: (&str, &str),
    b: (&str, &str),
    tint: [[f64; 3]; 2],
    set: &[(String, f64)],
    compiler: &dyn super::scene::BrdfCompiler,
    ropts: &super::RenderOptions,
) -> Result<Comparison, crate::Diagnostics> {
    let fail = |m: String| crate::Diagnostics::single(geometry.name(), crate::Diagnostic::error(m));
    // `set` applies to both formulas: each takes the names it declares; a name neither declares is a typo. (A
    // formula that does not parse keeps the whole set; its own diagnostics come from `with_materials`.)
    let declare = |(f, src): (&str, &str)| if crate::measured::is_measured_path(f) { Some(vec![]) } else { compiler.declare(f, src).ok() };
    let declared = [declare(a), declare(b)];
    if let [Some(da), Some(db)] = &declared {
        if let Some((k, _)) = set.iter().find(|(k, _)| !da.iter().chain(db).any(|p| p.name == *k)) {
            return Err(crate::Diagnostics::single(
                geometry.name(),
                crate::Diagnostic::error(format!("neither formula declares a parameter `{k}`"))
                    .about(crate::base::diag::Setting::Param { name: k.clone(), value: None })
                    .hint("every formula has `n`; see each file's `param` lines"),
            ));
        }
    }
    let mut frames = vec![];
    let mut nan = [0u64; 2];
    for (k, formula) in [a, b].into_iter().enumerate() {
        let own: Vec<(String, f64)> = match &declared[k] {
            Some(d) => set.iter().filter(|(name, _)| d.iter().any(|p| p.name == *name)).cloned().collect(),
            None => set.to_vec(),
        };
        let mut scene = geometry.with_materials(&own, Some(formula), compiler)?;
        for m in &mut scene.materials {
            m.specular *= glam::DVec3::from_array(tint[k]);
        }
        if scene.objects.is_empty() {
            return Err(crate::Diagnostics::single(
                geometry.name(),
                crate::Diagnostic::error("the scene has no objects: there is nothing to compare").hint("add an [[object]] table"),
            ));
        }
        let (frame, stats) = super::render(&scene, ropts).map_err(fail)?;
        nan[k] = stats.nan;
        frames.push(frame);
    }
    let (fb, fa) = (frames.pop(), frames.pop());
    let (Some(a), Some(b)) = (fa, fb) else { unreachable!("two frames were rendered") };
    let covered: Vec<bool> = a.covered.iter().zip(&b.covered).map(|(x, y)| *x || *y).collect();
    let metrics = metrics(&a.image, &b.image, &covered).map_err(fail)?;
    let n = set.iter().rev().find(|(k, _)| k == "n").map(|(_, v)| *v);
    Ok(Comparison { n, metrics, a, b, nan })
}

/// Stacks side-by-side rows (one per comparison) into one image, with a common heat-map scale.
pub fn sweep_image(rows: &[Comparison], scale: f64) -> Image {
    let Some(first) = rows.first() else { return Image::new(1, 1) };
    let (w, h) = (first.a.image.width, first.a.image.height);
    let mut out = Image::new(3 * w, h * rows.len());
    for (r, c) in rows.iter().enumerate() {
        let row = side_by_side(&c.a.image, &c.b.image, scale);
        out.rgb[r * row.rgb.len()..(r + 1) * row.rgb.len()].copy_from_slice(&row.rgb);
    }
    out
}
