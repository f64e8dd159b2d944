//! Environment light: a constant sky or a latitude–longitude HDR map (OpenEXR through the `exr` crate, every
//! compression including DWAA/DWAB; Radiance `.hdr`, read here), with its own importance sampling.
//!
//! # Convention
//! World space has +y up (the scene's camera default and the shapes' poles). A map's pixel (x, y) of a W × H image
//! covers u = x/W .. (x+1)/W, v = y/H .. (y+1)/H; a local direction d has
//! v = acos(d.y)/π (row 0 is straight up, the last row straight down) and u = atan2(d.x, −d.z)/2π wrapped to
//! [0, 1) — Mitsuba 3's `envmap` convention: u = 0 (the map's left and right edges) looks along −z, u = ½ (the map's
//! centre) along +z, u = ¼ along +x. `rotate` (degrees) turns the map about +y, counter-clockwise seen from
//! above: the map's local direction d appears in the world as R_y(rotate)·d. `intensity` multiplies every value.
//! Lookups are nearest-pixel (the function is then exactly the piecewise-constant one the distribution samples).
//!
//! # Sampling
//! A 2-D piecewise-constant distribution over (v, u) ([`crate::bsdf`]'s `Dist2D`, the sampler's own tables) of
//! luminance·sinθ, θ at the centre of the cell's row; the density in solid angle is p(u, v)/(2π²·sinθ). A map wider
//! than [`MAX_DIST_COLS`] (or taller than [`MAX_DIST_ROWS`]) is summed into blocks of pixels first, so the table
//! stays bounded; a block of zero sum is a block of zero radiance, so the density is positive wherever the map is.
//! A constant sky samples the sphere uniformly (1/4π). A map whose every pixel is 0 has no distribution: it emits
//! nothing, and environment sampling returns no sample (documented result, not an error).
//!
//! # Bad input
//! Missing or unreadable files, files over [`MAX_MAP_BYTES`], dimensions over [`MAX_WIDTH`] × [`MAX_HEIGHT`],
//! truncated data, and NaN, infinite or negative values are errors naming the file (and the first bad pixel).
//! Negative values no larger than 10⁻³ of the map's largest value are lossy compression's ringing (DWAB
//! maps have them next to dark pixels) and are read as 0.
//!
//! Cost: building is one pass over the pixels plus the distribution's cumulative sums and their guide tables
//! (O(W·H)); a sample is two guided searches (a step or two each), a density one table read.

use crate::base::source::{Files, ReadError};
use crate::bsdf::dist::Dist2D;
use glam::DVec3;
use std::f64::consts::PI;
use std::path::Path;

/// Largest map file read.
pub const MAX_MAP_BYTES: u64 = 512 << 20;
/// Largest map width in pixels.
pub const MAX_WIDTH: usize = 16384;
/// Largest map height in pixels.
pub const MAX_HEIGHT: usize = 8192;
/// Columns of the sampling distribution at most (wider maps are summed into blocks).
pub const MAX_DIST_COLS: usize = 2048;
/// Rows of the sampling distribution at most.
pub const MAX_DIST_ROWS: usize = 1024;

/// Rec. 709 luminance.
fn luminance(c: DVec3) -> f64 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Linear RGB pixels, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Pixels {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<[f32; 3]>,
}

/// An environment: what a ray that leaves the scene sees, and how to sample it.
#[derive(Clone, Debug)]
pub struct EnvMap {
    kind: Kind,
    intensity: f64,
    /// cos and sin of `rotate`.
    rot: (f64, f64),
    /// Where it came from, for reports: the file name or "constant".
    pub source: String,
}

#[derive(Clone, Debug)]
enum Kind {
    Constant(DVec3),
    Map { pixels: Pixels, dist: Option<Dist2D>, rows: usize, cols: usize },
}

impl EnvMap {
    /// A constant sky of linear RGB `color` (finite, ≥ 0).
    pub fn constant(color: DVec3, intensity: f64, rotate_deg: f64) -> Result<EnvMap, String> {
        if !(color.is_finite() && color.min_element() >= 0.0) {
            return Err(format!("the environment colour {color} must be three finite numbers ≥ 0"));
        }
        check_scalars(intensity, rotate_deg)?;
        Ok(EnvMap { kind: Kind::Constant(color), intensity, rot: rotation(rotate_deg), source: "constant".into() })
    }

    /// A map from pixels (checked: finite, ≥ 0, within the size limits).
    pub fn from_pixels(pixels: Pixels, intensity: f64, rotate_deg: f64, source: &str) -> Result<EnvMap, String> {
        check_scalars(intensity, rotate_deg)?;
        check_size(pixels.width, pixels.height)?;
        if pixels.rgb.len() != pixels.width * pixels.height {
            return Err(format!("{} pixels for a {}×{} map", pixels.rgb.len(), pixels.width, pixels.height));
        }
        // Lossy compression (DWAA/DWAB: Blender's maps) rings slightly below 0 next to dark pixels: values down to
        // −10⁻³ of the map's largest value are taken as 0; anything more negative is an error.
        let max = pixels.rgb.iter().flatten().filter(|c| c.is_finite()).fold(0.0f32, |m, c| m.max(*c));
        let floor = -1e-3 * max;
        let mut pixels = pixels;
        for c in pixels.rgb.iter_mut().flatten() {
            if *c < 0.0 && *c >= floor {
                *c = 0.0;
            }
        }
        if let Some(i) = pixels.rgb.iter().position(|p| p.iter().any(|c| !c.is_finite() || *c < 0.0)) {
            let p = pixels.rgb[i];
            let what = if p.iter().any(|c| c.is_nan()) {
                "NaN"
            } else if p.iter().any(|c| c.is_infinite()) {
                "infinite"
            } else {
                "negative"
            };
            return Err(format!(
                "pixel ({}, {}) is {what}: ({}, {}, {}); an environment map holds finite radiance ≥ 0",
                i % pixels.width,
                i / pixels.width,
                p[0],
                p[1],
                p[2]
            ));
        }
        let (w, h) = (pixels.width, pixels.height);
        let cols = w.min(MAX_DIST_COLS);
        let rows = h.min(MAX_DIST_ROWS);
        let mut vals = vec![0.0f64; rows * cols];
        for y in 0..h {
            let r = y * rows / h;
            for x in 0..w {
                let p = pixels.rgb[y * w + x];
                vals[r * cols + x * cols / w] += luminance(DVec3::new(p[0].into(), p[1].into(), p[2].into()));
            }
        }
        for (r, row) in vals.chunks_mut(cols).enumerate() {
            let s = (PI * (r as f64 + 0.5) / rows as f64).sin();
            for v in row {
                *v *= s;
            }
        }
        let dist = Dist2D::new(&vals, rows, cols);
        Ok(EnvMap { kind: Kind::Map { pixels, dist, rows, cols }, intensity, rot: rotation(rotate_deg), source: source.into() })
    }

    /// Reads an OpenEXR (`.exr`) or Radiance (`.hdr`, `.pic`) map through `files`; the kind is told by the
    /// file's first bytes.
    pub fn load(path: &Path, files: &Files, intensity: f64, rotate_deg: f64) -> Result<EnvMap, String> {
        let name = path.display().to_string();
        let bytes = files.read(path, MAX_MAP_BYTES).map_err(|e| match e {
            ReadError::TooLarge => format!("environment map `{name}` is larger than {} MiB", MAX_MAP_BYTES >> 20),
            ReadError::NotRegular => format!("environment map `{name}` is not a regular file"),
            e => format!("cannot read environment map `{name}`: {e}"),
        })?;
        let pixels = decode(&bytes).map_err(|e| format!("environment map `{name}`: {e}"))?;
        EnvMap::from_pixels(pixels, intensity, rotate_deg, &name).map_err(|e| format!("environment map `{name}`: {e}"))
    }

    /// Whether the environment emits anything at all (a map of zeros or intensity 0 does not).
    pub fn emits(&self) -> bool {
        self.intensity > 0.0
            && match &self.kind {
                Kind::Constant(c) => c.max_element() > 0.0,
                Kind::Map { dist, .. } => dist.is_some(),
            }
    }

    /// World → the map's local frame.
    fn to_local(&self, d: DVec3) -> DVec3 {
        let (c, s) = self.rot;
        DVec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }

    /// The map's local frame → world.
    fn to_world(&self, d: DVec3) -> DVec3 {
        let (c, s) = self.rot;
        DVec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }

    /// Radiance arriving from world direction `d` (unit).
    pub fn radiance(&self, d: DVec3) -> DVec3 {
        match &self.kind {
            Kind::Constant(c) => *c * self.intensity,
            Kind::Map { pixels, .. } => {
                let (u, v) = uv_of(self.to_local(d));
                let x = ((u * pixels.width as f64) as usize).min(pixels.width - 1);
                let y = ((v * pixels.height as f64) as usize).min(pixels.height - 1);
                let p = pixels.rgb[y * pixels.width + x];
                DVec3::new(p[0].into(), p[1].into(), p[2].into()) * self.intensity
            }
        }
    }

    /// A world direction for uniforms `u` in [0, 1)² and its density in solid angle; `None` when the map emits
    /// nothing (or the sample falls on a pole, where the density is undefined).
    pub fn sample(&self, u: [f64; 2]) -> Option<(DVec3, f64)> {
        match &self.kind {
            Kind::Constant(_) => {
                let z = 1.0 - 2.0 * u[0];
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u[1];
                Some((DVec3::new(r * phi.cos(), z, r * phi.sin()), 1.0 / (4.0 * PI)))
            }
            Kind::Map { dist, .. } => {
                let dist = dist.as_ref()?;
                let (v, uu) = dist.sample(u[0], u[1]);
                let d = dir_of(uu, v);
                let pdf = self.pdf_local(uu, v);
                (pdf > 0.0).then(|| (self.to_world(d), pdf))
            }
        }
    }

    /// The density (solid angle) with which [`EnvMap::sample`] draws world direction `d` (unit).
    pub fn pdf(&self, d: DVec3) -> f64 {
        match &self.kind {
            Kind::Constant(_) => 1.0 / (4.0 * PI),
            Kind::Map { .. } => {
                let (u, v) = uv_of(self.to_local(d));
                self.pdf_local(u, v)
            }
        }
    }

    fn pdf_local(&self, u: f64, v: f64) -> f64 {
        let Kind::Map { dist: Some(dist), .. } = &self.kind else { return 0.0 };
        let s = (PI * v).sin();
        if s <= 1e-12 {
            return 0.0;
        }
        dist.pdf(v, u) / (2.0 * PI * PI * s)
    }

    /// The distribution's grid (rows, columns); (0, 0) for a constant sky.
    pub fn grid(&self) -> (usize, usize) {
        match &self.kind {
            Kind::Constant(_) => (0, 0),
            Kind::Map { rows, cols, .. } => (*rows, *cols),
        }
    }
}

fn check_scalars(intensity: f64, rotate_deg: f64) -> Result<(), String> {
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(format!("`intensity` = {intensity} must be finite and ≥ 0"));
    }
    if !rotate_deg.is_finite() {
        return Err(format!("`rotate` = {rotate_deg} must be finite (degrees about +y)"));
    }
    Ok(())
}

fn check_size(w: usize, h: usize) -> Result<(), String> {
    if w == 0 || h == 0 || w > MAX_WIDTH || h > MAX_HEIGHT {
        return Err(format!("a {w}×{h} map is outside 1..={MAX_WIDTH} × 1..={MAX_HEIGHT} pixels"));
    }
    Ok(())
}

fn rotation(deg: f64) -> (f64, f64) {
    let a = deg.to_radians();
    (a.cos(), a.sin())
}

/// (u, v) of a local unit direction (module docs).
fn uv_of(d: DVec3) -> (f64, f64) {
    let mut u = d.x.atan2(-d.z) / (2.0 * PI);
    if u < 0.0 {
        u += 1.0;
    }
    let u = if u >= 1.0 { 0.0 } else { u };
    // atan2 rather than acos(y): exact near the poles, where the density 1/sinθ is steepest.
    (u, (d.x * d.x + d.z * d.z).sqrt().atan2(d.y) / PI)
}

/// The local unit direction of (u, v).
fn dir_of(u: f64, v: f64) -> DVec3 {
    let (st, ct) = (PI * v).sin_cos();
    let (sp, cp) = (2.0 * PI * u).sin_cos();
    DVec3::new(st * sp, ct, -st * cp)
}

/// Decodes an OpenEXR or Radiance file's bytes.
pub fn decode(bytes: &[u8]) -> Result<Pixels, String> {
    if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        decode_exr(bytes)
    } else if bytes.starts_with(b"#?") {
        decode_hdr(bytes)
    } else {
        Err("neither OpenEXR nor Radiance HDR (the file's first bytes are neither format's signature)".into())
    }
}

fn decode_exr(bytes: &[u8]) -> Result<Pixels, String> {
    use exr::prelude::*;
    let meta = MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).map_err(|e| format!("not a readable OpenEXR file: {e}"))?;
    let Some(h) = meta.headers.first() else { return Err("an OpenEXR file without layers".into()) };
    check_size(h.layer_size.width(), h.layer_size.height())?;
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size, _| Pixels { width: size.width(), height: size.height(), rgb: vec![[0.0; 3]; size.width() * size.height()] },
            |p: &mut Pixels, pos, (r, g, b): (f32, f32, f32)| {
                let w = p.width;
                p.rgb[pos.y() * w + pos.x()] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| format!("cannot decode the OpenEXR data (it needs R, G and B channels): {e}"))?;
    Ok(img.layer_data.channel_data.pixels)
}

/// Radiance RGBE: a text header (`#?RADIANCE` or `#?RGBE`, `FORMAT=32-bit_rle_rgbe`, a blank line), the
/// resolution line `-Y H +X W` (the only orientation accepted: rows top to bottom), then each scanline either
/// new-style run-length encoded (2, 2, width; four channel runs) or flat RGBE quadruples. Old-style repeat runs
/// (1, 1, 1, n) are refused. Values are (m + 0.5)·2^(e−136) as Radiance's `colr_color`; `EXPOSURE` is ignored.
fn decode_hdr(bytes: &[u8]) -> Result<Pixels, String> {
    let mut pos = 0;
    let line = |pos: &mut usize| -> Result<String, String> {
        let rest = &bytes[*pos..];
        let end = rest.iter().position(|&b| b == b'\n').ok_or("truncated header (no end of line)")?;
        *pos += end + 1;
        Ok(String::from_utf8_lossy(&rest[..end]).trim_end_matches('\r').to_string())
    };
    let magic = line(&mut pos)?;
    if !(magic.starts_with("#?RADIANCE") || magic.starts_with("#?RGBE")) {
        return Err(format!("a Radiance header starts with #?RADIANCE or #?RGBE, not `{magic}`"));
    }
    loop {
        let l = line(&mut pos)?;
        if l.is_empty() {
            break;
        }
        if let Some(f) = l.strip_prefix("FORMAT=") {
            if f.trim() != "32-bit_rle_rgbe" {
                return Err(format!("format `{}` is not supported; only 32-bit_rle_rgbe", f.trim()));
            }
        }
    }
    let res = line(&mut pos)?;
    let t: Vec<&str> = res.split_whitespace().collect();
    let (h, w) = match t.as_slice() {
        ["-Y", h, "+X", w] => (h.parse::<usize>().map_err(|_| format!("bad height in `{res}`"))?, w.parse::<usize>().map_err(|_| format!("bad width in `{res}`"))?),
        _ => return Err(format!("resolution line `{res}` is not `-Y height +X width` (other orientations are not supported)")),
    };
    check_size(w, h)?;
    let mut rgb = Vec::with_capacity(w * h);
    let mut scan = vec![[0u8; 4]; w];
    let truncated = |y: usize| format!("truncated at scanline {y} of {h}");
    for y in 0..h {
        let b = &bytes[pos.min(bytes.len())..];
        if b.len() < 4 {
            return Err(truncated(y));
        }
        if (8..0x8000).contains(&w) && b[0] == 2 && b[1] == 2 && b[2] & 0x80 == 0 {
            if (usize::from(b[2]) << 8 | usize::from(b[3])) != w {
                return Err(format!("scanline {y}: its length {} is not the width {w}", usize::from(b[2]) << 8 | usize::from(b[3])));
            }
            pos += 4;
            for c in 0..4 {
                let mut x = 0;
                while x < w {
                    let n = *bytes.get(pos).ok_or_else(|| truncated(y))? as usize;
                    pos += 1;
                    if n > 128 {
                        let n = n - 128;
                        let v = *bytes.get(pos).ok_or_else(|| truncated(y))?;
                        pos += 1;
                        if x + n > w {
                            return Err(format!("scanline {y}: a run overflows the width"));
                        }
                        for p in &mut scan[x..x + n] {
                            p[c] = v;
                        }
                        x += n;
                    } else {
                        if n == 0 || x + n > w {
                            return Err(format!("scanline {y}: a bad run length"));
                        }
                        let src = bytes.get(pos..pos + n).ok_or_else(|| truncated(y))?;
                        for (p, &v) in scan[x..x + n].iter_mut().zip(src) {
                            p[c] = v;
                        }
                        pos += n;
                        x += n;
                    }
                }
            }
        } else {
            let src = bytes.get(pos..pos + 4 * w).ok_or_else(|| truncated(y))?;
            for (p, q) in scan.iter_mut().zip(src.chunks_exact(4)) {
                if q[..3] == [1, 1, 1] {
                    return Err(format!("scanline {y}: old-style run-length encoding is not supported"));
                }
                p.copy_from_slice(q);
            }
            pos += 4 * w;
        }
        rgb.extend(scan.iter().map(|&[r, g, b, e]| {
            if e == 0 {
                [0.0; 3]
            } else {
                let f = 2f32.powi(i32::from(e) - 136);
                [(f32::from(r) + 0.5) * f, (f32::from(g) + 0.5) * f, (f32::from(b) + 0.5) * f]
            }
        }));
    }
    Ok(Pixels { width: w, height: h, rgb })
}

/// Encodes linear RGB `rgb` (row-major, `width × height`) as an OpenEXR file of 32-bit float R, G, B (ZIP
/// compression), into memory (the caller writes it atomically).
pub fn encode_exr(width: usize, height: usize, rgb: &[[f32; 3]]) -> Result<Vec<u8>, String> {
    use exr::prelude::*;
    if rgb.len() != width * height || width == 0 || height == 0 {
        return Err(format!("{} pixels for a {width}×{height} image", rgb.len()));
    }
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = rgb[y * width + x];
        (p[0], p[1], p[2])
    });
    let layer = Layer::new((width, height), LayerAttributes::named("lobe"), Encoding::SMALL_LOSSLESS, channels);
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer).write().to_buffered(&mut out).map_err(|e| format!("cannot encode OpenEXR: {e}"))?;
    Ok(out.into_inner())
}

/// Encodes pixels as a Radiance `.hdr` file (flat RGBE scanlines): for tests and generated examples.
pub fn encode_hdr(p: &Pixels, rle: bool) -> Vec<u8> {
    let mut out = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {} +X {}\n", p.height, p.width).into_bytes();
    for row in p.rgb.chunks(p.width) {
        let q: Vec<[u8; 4]> = row.iter().map(|c| rgbe(*c)).collect();
        if rle && (8..0x8000).contains(&p.width) {
            out.extend([2, 2, (p.width >> 8) as u8, (p.width & 0xff) as u8]);
            for c in 0..4 {
                // Runs of equal bytes (≥ 3) as repeats, the rest as literals of up to 128.
                let ch: Vec<u8> = q.iter().map(|v| v[c]).collect();
                let mut i = 0;
                while i < ch.len() {
                    let mut run = 1;
                    while i + run < ch.len() && ch[i + run] == ch[i] && run < 127 {
                        run += 1;
                    }
                    if run >= 3 {
                        out.extend([128 + run as u8, ch[i]]);
                        i += run;
                    } else {
                        let start = i;
                        while i < ch.len() && i - start < 128 && !(i + 2 < ch.len() && ch[i] == ch[i + 1] && ch[i] == ch[i + 2]) {
                            i += 1;
                        }
                        out.push((i - start) as u8);
                        out.extend(&ch[start..i]);
                    }
                }
            }
        } else {
            for v in q {
                out.extend(v);
            }
        }
    }
    out
}

/// One RGBE quadruple (Radiance's `setcolr`: mantissas m with (m + 0.5)·2^(e−136) the decoded value).
fn rgbe(c: [f32; 3]) -> [u8; 4] {
    let m = c.iter().fold(0.0f32, |a, &b| a.max(b));
    if m < 1e-32 {
        return [0; 4];
    }
    let e = m.log2().floor() as i32 + 1;
    let scale = 256.0 / 2f32.powi(e);
    let q = |v: f32| ((v * scale).floor().clamp(0.0, 255.0)) as u8;
    [q(c[0]), q(c[1]), q(c[2]), (e + 128) as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Pixels {
        Pixels { width: w, height: h, rgb: (0..w * h).map(|i| f(i % w, i / w)).collect() }
    }

    #[test]
    fn directions_and_uv_round_trip_with_mitsubas_axes() {
        for (u, v) in [(0.1, 0.2), (0.5, 0.5), (0.75, 0.9), (0.0, 0.4)] {
            let (u2, v2) = uv_of(dir_of(u, v));
            assert!((u - u2).abs() < 1e-12 && (v - v2).abs() < 1e-12, "{u} {v} → {u2} {v2}");
        }
        assert!((dir_of(0.5, 0.5) - DVec3::Z).length() < 1e-12);
        assert!((dir_of(0.0, 0.5) + DVec3::Z).length() < 1e-12);
        assert!((dir_of(0.25, 0.5) - DVec3::X).length() < 1e-12);
        assert!((dir_of(0.3, 0.0) - DVec3::Y).length() < 1e-12);
        // rotate = 90°: the map's +z (its centre) appears at world +x.
        let e = EnvMap::constant(DVec3::ONE, 1.0, 90.0).unwrap();
        assert!((e.to_world(DVec3::Z) - DVec3::X).length() < 1e-12);
        assert!((e.to_local(e.to_world(DVec3::new(0.3, 0.4, 0.5))) - DVec3::new(0.3, 0.4, 0.5)).length() < 1e-12);
    }

    #[test]
    fn sampling_density_integrates_to_one_and_matches_the_histogram() {
        // A map with a bright spot: the density over the sphere integrates to 1 (quadrature), and samples land in
        // the bright pixel as often as its share of luminance·solid angle says.
        let (w, h) = (16, 8);
        let px = map(w, h, |x, y| if (x, y) == (3, 2) { [50.0, 40.0, 30.0] } else { [0.5, 0.5, 0.5] });
        let e = EnvMap::from_pixels(px, 2.0, 30.0, "test").unwrap();
        let n = 400;
        let mut total = 0.0;
        for i in 0..n {
            for j in 0..2 * n {
                let (v, u) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / (2 * n) as f64);
                let d = e.to_world(dir_of(u, v));
                total += e.pdf(d) * (PI * v).sin() * (PI / n as f64) * (PI / n as f64);
            }
        }
        assert!((total - 1.0).abs() < 1e-3, "∫pdf = {total}");
        let mut rng = crate::base::rng::Rng(99);
        let mut hits = 0;
        let m = 50_000;
        for _ in 0..m {
            let (d, pdf) = e.sample([rng.unit(), rng.unit()]).unwrap();
            assert!((pdf - e.pdf(d)).abs() <= 1e-9 * pdf, "{pdf} vs {}", e.pdf(d));
            let (u, v) = uv_of(e.to_local(d));
            hits += usize::from(((u * w as f64) as usize, (v * h as f64) as usize) == (3, 2));
        }
        let lum = |c: f64| c * (0.2126 + 0.7152 + 0.0722);
        let s = |y: usize| (PI * (y as f64 + 0.5) / h as f64).sin();
        let bright = (0.2126 * 50.0 + 0.7152 * 40.0 + 0.0722 * 30.0) * s(2);
        let all: f64 = (0..h).map(|y| s(y) * w as f64 * lum(0.5)).sum::<f64>() - lum(0.5) * s(2) + bright;
        let p = bright / all;
        let sigma = (p * (1.0 - p) / m as f64).sqrt();
        assert!(((hits as f64 / m as f64) - p).abs() < 5.0 * sigma, "{hits} of {m}, expected {p}");
        // Radiance follows the rotation and intensity.
        let d = e.to_world(dir_of(3.5 / 16.0, 2.5 / 8.0));
        assert!((e.radiance(d) - DVec3::new(100.0, 80.0, 60.0)).length() < 1e-4);
    }

    #[test]
    fn bad_maps_are_refused_and_zero_maps_emit_nothing() {
        for (bad, what) in [(f32::NAN, "NaN"), (-1.0, "negative"), (f32::INFINITY, "infinite")] {
            let e = EnvMap::from_pixels(map(4, 2, |x, _| if x == 2 { [bad, 0.0, 0.0] } else { [1.0; 3] }), 1.0, 0.0, "t").unwrap_err();
            assert!(e.contains(what) && e.contains("pixel (2, 0)"), "{e}");
        }
        assert!(EnvMap::from_pixels(Pixels { width: MAX_WIDTH + 1, height: 1, rgb: vec![] }, 1.0, 0.0, "t").unwrap_err().contains("outside"));
        assert!(EnvMap::from_pixels(map(2, 1, |_, _| [1.0; 3]), f64::NAN, 0.0, "t").is_err());
        assert!(EnvMap::constant(DVec3::new(1.0, -1.0, 0.0), 1.0, 0.0).is_err());
        let zero = EnvMap::from_pixels(map(8, 4, |_, _| [0.0; 3]), 1.0, 0.0, "t").unwrap();
        assert!(!zero.emits());
        assert!(zero.sample([0.3, 0.3]).is_none());
        assert_eq!(zero.pdf(DVec3::Y), 0.0);
        assert_eq!(zero.radiance(DVec3::X), DVec3::ZERO);
    }

    #[test]
    fn wide_maps_get_a_bounded_distribution_that_still_covers_every_bright_pixel() {
        let px = map(MAX_DIST_COLS * 2 + 3, 4, |x, _| if x == 4000 { [1.0; 3] } else { [0.0; 3] });
        let e = EnvMap::from_pixels(px, 1.0, 0.0, "t").unwrap();
        assert_eq!(e.grid(), (4, MAX_DIST_COLS));
        let d = e.to_world(dir_of(4000.5 / (MAX_DIST_COLS * 2 + 3) as f64, 0.3));
        assert!(e.radiance(d).x > 0.0 && e.pdf(d) > 0.0);
    }

    #[test]
    fn radiance_hdr_round_trips_flat_and_run_length_encoded_and_refuses_bad_files() {
        let px = map(20, 3, |x, y| if x < 10 { [0.25, 2.0, 7.5] } else { [x as f32 * 0.1, y as f32, 0.0] });
        for rle in [false, true] {
            let bytes = encode_hdr(&px, rle);
            let back = decode(&bytes).unwrap();
            assert_eq!((back.width, back.height), (20, 3));
            for (a, b) in px.rgb.iter().zip(&back.rgb) {
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= 0.01 * a.iter().fold(0.0f32, |m, v| m.max(*v)) + 1e-6, "{a:?} {b:?}");
                }
            }
            let cut = &bytes[..bytes.len() - 5];
            assert!(decode(cut).unwrap_err().contains("truncated"), "{}", decode(cut).unwrap_err());
        }
        assert!(decode(b"#?RADIANCE\n\n+Y 2 +X 2\n").unwrap_err().contains("orientation"));
        assert!(decode(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\0\0\0\0").unwrap_err().contains("xyze"));
        assert!(decode(b"#?RADIANCE\n\n-Y 100000 +X 2\n").unwrap_err().contains("outside"));
        assert!(decode(b"GIF89a").unwrap_err().contains("neither"));
    }

    #[test]
    fn exr_round_trips_and_truncation_is_an_error() {
        let rgb: Vec<[f32; 3]> = (0..6 * 4).map(|i| [i as f32, 0.5, 1e3]).collect();
        let bytes = encode_exr(6, 4, &rgb).unwrap();
        let back = decode(&bytes).unwrap();
        assert_eq!((back.width, back.height), (6, 4));
        assert_eq!(back.rgb, rgb);
        assert!(decode(&bytes[..bytes.len() / 2]).is_err());
    }
}
