//! Measured reflectance: MERL `.binary` tables (Matusik et al. 2003) read, looked up, written, and evaluated
//! as three [`Evaluator`]s (red, green, blue), so a measurement goes wherever a formula's kernel goes.
//!
//! # The format
//! Three little-endian `i32` dimensions, which must be 90, 90, 180; then the red, green and blue blocks,
//! each 90·90·180 little-endian `f64`, stored ×1500, ×1500/1.15 and ×1500/1.66 ([`SCALE`] is what a stored
//! value is multiplied by). Entry `(i, j, k)` of a block is at `(i·90 + j)·180 + k`: θ_h index `i`, θ_d index
//! `j`, φ_d index `k`. A negative entry means "not measured". A file is exactly 34 992 012 bytes; it is read in
//! one go after the header and the length are checked, so a hostile header costs nothing.
//!
//! # The lookup (from directions L, V in the local frame)
//! H = norm(L + V); D is L seen in H's frame (Rusinkiewicz 1998: rotated by −φ_h about N, then by −θ_h about
//! the bitangent). The angles' index coordinates are `x_i = √(θ_h/(π/2))·90`, `x_j = θ_d/(π/2)·90`,
//! `x_k = φ_d'/π·180` with φ_d folded by reciprocity into [0, π) (φ_d + π where φ_d < 0); entry (i, j, k) sits
//! at (i, j, k) (the convention below). Two ways to read the table ([`Lookup`]):
//! - [`Lookup::Linear`] (lobe's default): multilinear in (x_i, x_j, x_k) between the 8 entries around the
//!   point — linear in √θ_h, so the steps are finest at the peak as the table's are; x_k wraps (entry 179's
//!   upper neighbour is entry 0, φ_d = π being φ_d = 0 under the fold); x_i, x_j past entry 89 take entry 89.
//!   An unmeasured neighbour drops out and the others' weights are renormalised; all 8 unmeasured gives 0.
//! - [`Lookup::Nearest`]: the entry whose bin holds the point, as MERL's reference code reads it:
//!   `i = ⌊x_i⌋`, `j = ⌊x_j⌋`, `k = ⌊x_k⌋`, clamped. Since entry i stands for its bin's lower edge, this is
//!   biased: a falling lobe reads high across each bin (albedo of a Blinn n = 60 table +5.8 %, measured).
//!
//! Two choices of lobe's in both: a coordinate within [`EDGE`] of an integer counts as that integer, so the
//! convention's own angles, rebuilt through directions with rounding, find their entry exactly; and x_k that
//! lands on 180 (φ_d = π) wraps to 0 rather than clamping to 179 (θ_d = 0 has no φ_d: its directions are
//! those of k = 0). L or V at or below the surface or a non-finite direction gives 0 (no light), and so does an
//! unmeasured entry under `Nearest`.
//!
//! # The convention for synthetic files and fits
//! Entry `(i, j, k)` stands for θ_h = (i/90)²·π/2, θ_d = j/90·π/2, φ_d = k/180·π (the inverse of the lookup);
//! [`entry_dirs`] builds its L and V (φ_h = 0). [`Measured::tabulate`] fills a table at those angles, storing
//! "not measured" where L or V is below the surface or the value is not finite, as MERL's files do.

use crate::backend::Evaluator;
use crate::base::diag::{Diagnostic, Hint};
use crate::frame::V3;
use crate::ir::{Input, InputSet, N_INPUTS};
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;
use std::sync::Arc;

/// θ_h, θ_d and φ_d entries.
pub(crate) const DIMS: [usize; 3] = [90, 90, 180];
/// Entries per channel block.
pub const ENTRIES: usize = DIMS[0] * DIMS[1] * DIMS[2];
/// What a stored value is multiplied by, per channel (red, green, blue).
pub(crate) const SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];
/// The largest physical value a table may hold: the metrics square values (RMSE, the closed-form colour scale's
/// Σ w·a²), and past √(f64::MAX) ≈ 1.3·10¹⁵⁴ those overflow. Measured BRDFs stay below about 10⁴.
pub const MAX_VALUE: f64 = 1e150;
/// Header bytes (three i32).
const HEADER: usize = 12;
/// The size of a MERL file.
pub const FILE_BYTES: usize = HEADER + 3 * ENTRIES * 8;
/// How close to a bin's lower edge (in bins) an angle still counts as that bin.
pub(crate) const EDGE: f64 = 1e-6;
const CHANNEL: [&str; 3] = ["red", "green", "blue"];

/// A MERL table: the stored values (as the file holds them, before [`SCALE`]) of the three channels.
#[derive(Clone, PartialEq)]
pub struct Measured {
    /// The file it came from (or a name for a synthetic table), for reports.
    pub name: String,
    /// Red, green, blue blocks, each [`ENTRIES`] long.
    stored: Vec<f64>,
}

impl std::fmt::Debug for Measured {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Measured({:?}, {} entries measured)", self.name, self.measured_entries())
    }
}

/// Whether a path names a measured file (by its extension, `.binary`, as the MERL database names them).
pub fn is_measured_path(p: &str) -> bool {
    Path::new(p).extension().is_some_and(|e| e.eq_ignore_ascii_case("binary"))
}

/// The index of entry `(i, j, k)` in a block.
pub fn index(i: usize, j: usize, k: usize) -> usize {
    (i * DIMS[1] + j) * DIMS[2] + k
}

/// The angles (θ_h, θ_d, φ_d) entry `(i, j, k)` stands for (module docs).
pub(crate) fn entry_angles(i: usize, j: usize, k: usize) -> [f64; 3] {
    let u = i as f64 / DIMS[0] as f64;
    [u * u * FRAC_PI_2, j as f64 / DIMS[1] as f64 * FRAC_PI_2, k as f64 / DIMS[2] as f64 * PI]
}

/// L and V in the local frame for half/difference angles (φ_h = 0): D = (sinθ_d cosφ_d, sinθ_d sinφ_d,
/// cosθ_d) in H's frame turned by θ_h about the bitangent is L; V is L mirrored about H.
pub(crate) fn dirs_from_angles([th, td, pd]: [f64; 3]) -> (V3, V3) {
    dirs_from_sin_cos(th.sin_cos(), td.sin_cos(), pd.sin_cos())
}

/// [`dirs_from_angles`] from the sines and cosines of θ_h, θ_d and φ_d (for tables of them per index).
pub(crate) fn dirs_from_sin_cos((s, c): (f64, f64), (sd, cd): (f64, f64), (sp, cp): (f64, f64)) -> (V3, V3) {
    let d = [sd * cp, sd * sp, cd];
    let l = [c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]];
    let h = [s, 0.0, c];
    let lh = l[0] * h[0] + l[1] * h[1] + l[2] * h[2];
    let v = [2.0 * lh * h[0] - l[0], 2.0 * lh * h[1] - l[1], 2.0 * lh * h[2] - l[2]];
    (l, v)
}

/// L and V of entry `(i, j, k)` under the convention.
pub(crate) fn entry_dirs(i: usize, j: usize, k: usize) -> (V3, V3) {
    dirs_from_angles(entry_angles(i, j, k))
}

/// [`entry_dirs`] of many entries: the sines and cosines of each axis's angles computed once.
pub(crate) struct EntryDirs {
    axes: [Vec<(f64, f64)>; 3],
}

impl EntryDirs {
    pub(crate) fn new() -> EntryDirs {
        EntryDirs {
            axes: std::array::from_fn(|a| (0..DIMS[a]).map(|n| entry_angles(if a == 0 { n } else { 0 }, if a == 1 { n } else { 0 }, if a == 2 { n } else { 0 })[a].sin_cos()).collect()),
        }
    }

    /// [`entry_dirs`]`(i, j, k)`, bit for bit.
    pub(crate) fn at(&self, i: usize, j: usize, k: usize) -> (V3, V3) {
        dirs_from_sin_cos(self.axes[0][i], self.axes[1][j], self.axes[2][k])
    }
}

/// (θ_h, θ_d, φ_d ∈ (−π, π]) of unit L and V in the local frame; `None` where L + V = 0.
pub(crate) fn half_diff(l: V3, v: V3) -> Option<[f64; 3]> {
    let h = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
    let len = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
    if len.is_nan() || len <= 0.0 {
        return None;
    }
    let h = h.map(|x| x / len);
    let th = h[2].clamp(-1.0, 1.0).acos();
    let ph = h[1].atan2(h[0]);
    // L turned by −φ_h about N, then by −θ_h about the bitangent.
    let (sp, cp) = ph.sin_cos();
    let a = [cp * l[0] + sp * l[1], -sp * l[0] + cp * l[1], l[2]];
    let (st, ct) = th.sin_cos();
    let d = [ct * a[0] - st * a[2], a[1], st * a[0] + ct * a[2]];
    Some([th, d[2].clamp(-1.0, 1.0).acos(), d[1].atan2(d[0])])
}

/// How a table is read between its entries (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Lookup {
    /// Multilinear between the 8 surrounding entries in index coordinates (lobe's default).
    #[default]
    Linear,
    /// The entry whose bin holds the angles (MERL's reference code).
    Nearest,
}

impl Lookup {
    pub fn name(self) -> &'static str {
        match self {
            Lookup::Linear => "linear",
            Lookup::Nearest => "nearest",
        }
    }
}

impl std::str::FromStr for Lookup {
    type Err = String;
    fn from_str(s: &str) -> Result<Lookup, String> {
        match s {
            "linear" => Ok(Lookup::Linear),
            "nearest" => Ok(Lookup::Nearest),
            _ => Err(format!("unknown lookup `{s}` for a measured table; expected linear or nearest")),
        }
    }
}

/// The index coordinates (x_i, x_j, x_k) of half/difference angles (module docs): φ_d folded into [0, π),
/// negative or NaN coordinates taken as 0; not clamped.
pub(crate) fn angles_coords([th, td, pd]: [f64; 3]) -> [f64; 3] {
    let pd = if pd < 0.0 { pd + PI } else { pd };
    let x = [(th / FRAC_PI_2).max(0.0).sqrt() * DIMS[0] as f64, td / FRAC_PI_2 * DIMS[1] as f64, pd / PI * DIMS[2] as f64];
    // `max` takes the number over NaN.
    x.map(|x| x.max(0.0))
}

/// The entry indices of half/difference angles (module docs: nearest entry, φ_d folded).
pub(crate) fn angles_index(a: [f64; 3]) -> (usize, usize, usize) {
    let [xi, xj, xk] = angles_coords(a);
    let bin = |x: f64, n: usize| ((x + EDGE).floor() as usize).min(n - 1);
    // φ_d on π is 0 again (the fold's period is π).
    (bin(xi, DIMS[0]), bin(xj, DIMS[1]), ((xk + EDGE).floor() as usize) % DIMS[2])
}

/// The two entries along one axis around coordinate `x` ≥ 0 with their weights (module docs): wrapping
/// around `n` (φ_d) or taking entry n − 1 past it; a fraction within [`EDGE`] of 0 or 1 snaps to the entry.
fn corners(x: f64, n: usize, wrap: bool) -> [(usize, f64); 2] {
    let x = x.min(2.0 * n as f64);
    let lo = (x + EDGE).floor();
    let t = x - lo;
    let t = if t < EDGE { 0.0 } else { t };
    let lo = lo as usize;
    if wrap {
        [(lo % n, 1.0 - t), ((lo + 1) % n, t)]
    } else if lo >= n - 1 {
        [(n - 1, 1.0), (n - 1, 0.0)]
    } else {
        [(lo, 1.0 - t), (lo + 1, t)]
    }
}

/// A read failure: the file, what is wrong, and a hint.
fn bad(path: &str, what: impl std::fmt::Display, hint: impl Into<Hint>) -> Diagnostic {
    Diagnostic::error(format!("`{path}`: {what}")).hint(hint)
}

/// What to give instead of a file that is not a MERL table, worded by each front end
/// ([`crate::base::diag::Advice`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MeasuredAdvice {
    /// A MERL table is wanted: one from the database, or one tabulated from a formula ([`Measured::tabulate`]).
    GiveMerlTable,
}

impl crate::base::diag::Advice for MeasuredAdvice {
    fn plain(&self) -> String {
        match self {
            MeasuredAdvice::GiveMerlTable => "give a MERL BRDF database .binary file (90×90×180 entries), or tabulate a formula into one".into(),
        }
    }
}

const NOT_MERL: MeasuredAdvice = MeasuredAdvice::GiveMerlTable;

impl Measured {
    /// Reads a MERL file (module docs); every failure names the file and what is wrong.
    pub fn read(path: &str) -> Result<Measured, Diagnostic> {
        use std::io::Read;
        let mut file = std::fs::File::open(path).map_err(|e| bad(path, format!("cannot open it: {e}"), "check the path"))?;
        let meta = file.metadata().map_err(|e| bad(path, format!("cannot inspect it: {e}"), "check the path"))?;
        if !meta.is_file() {
            return Err(bad(path, "is not a regular file", NOT_MERL));
        }
        let mut header = [0u8; HEADER];
        let got = read_up_to(&mut file, &mut header).map_err(|e| bad(path, format!("cannot read it: {e}"), "check the file"))?;
        if got < HEADER {
            return Err(bad(path, format!("truncated: {got} bytes, shorter than the 12-byte header of three int32 dimensions"), NOT_MERL));
        }
        check_header(path, &header)?;
        check_length(path, meta.len())?;
        let mut bytes = header.to_vec();
        bytes.reserve_exact(FILE_BYTES - HEADER);
        file.take((FILE_BYTES - HEADER) as u64 + 1).read_to_end(&mut bytes).map_err(|e| bad(path, format!("cannot read it: {e}"), "check the file"))?;
        Measured::from_bytes(path, &bytes)
    }

    /// [`Measured::read`], the file read through `files` (a scene's file-access policy) in one piece.
    pub fn read_through(path: &str, files: &crate::base::source::Files) -> Result<Measured, Diagnostic> {
        use crate::base::source::ReadError;
        let bytes = files.read(std::path::Path::new(path), FILE_BYTES as u64).map_err(|e| match e {
            ReadError::Io(e) => bad(path, format!("cannot open it: {e}"), "check the path"),
            ReadError::NotRegular => bad(path, "is not a regular file", NOT_MERL),
            ReadError::TooLarge => bad(path, format!("more than a 90 × 90 × 180 table's {FILE_BYTES} bytes"), NOT_MERL),
            ReadError::Refused(why) => bad(path, why, "name a file under the directories being served"),
        })?;
        Measured::from_bytes(path, &bytes)
    }

    /// Parses a whole file's bytes (`name` for messages).
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<Measured, Diagnostic> {
        if bytes.len() < HEADER {
            return Err(bad(name, format!("truncated: {} bytes, shorter than the 12-byte header of three int32 dimensions", bytes.len()), NOT_MERL));
        }
        check_header(name, &bytes[..HEADER])?;
        check_length(name, bytes.len() as u64)?;
        let stored: Vec<f64> = bytes[HEADER..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8]))).collect();
        for (c, block) in stored.chunks_exact(ENTRIES).enumerate() {
            if let Some(e) = block.iter().position(|v| !v.is_finite()) {
                let (i, j, k) = (e / (DIMS[1] * DIMS[2]), e / DIMS[2] % DIMS[1], e % DIMS[2]);
                let bad_count = block.iter().filter(|v| !v.is_finite()).count();
                return Err(bad(
                    name,
                    format!("the {} block holds {bad_count} non-finite values (NaN or ±inf), the first at entry (θ_h {i}, θ_d {j}, φ_d {k})", CHANNEL[c]),
                    "the file is damaged or not a MERL table; unmeasured entries are negative numbers, not NaN",
                ));
            }
        }
        for (c, block) in stored.chunks_exact(ENTRIES).enumerate() {
            let over = |v: &f64| v * SCALE[c] > MAX_VALUE;
            if let Some(e) = block.iter().position(over) {
                let (i, j, k) = (e / (DIMS[1] * DIMS[2]), e / DIMS[2] % DIMS[1], e % DIMS[2]);
                let top = block.iter().fold(0.0f64, |m, v| m.max(v * SCALE[c]));
                return Err(bad(
                    name,
                    format!(
                        "the {} block holds {} values over {MAX_VALUE:e} (up to {top:e}), the first at entry (θ_h {i}, θ_d {j}, φ_d {k}): every metric squares them past f64's range",
                        CHANNEL[c],
                        block.iter().filter(|v| over(v)).count()
                    ),
                    "a measured BRDF's values are below about 10⁴ per steradian (MERL's reach ~10³): rescale the table",
                ));
            }
        }
        Ok(Measured { name: name.to_string(), stored })
    }

    /// The file's bytes: the header, then the stored values.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for d in DIMS {
            out.extend_from_slice(&(d as i32).to_le_bytes());
        }
        for v in &self.stored {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// A table of `f(L, V)` (red, green, blue; physical values, stored ÷ [`SCALE`]) at every entry's
    /// convention directions; an entry whose L or V is below the surface, or whose value is not finite or over
    /// [`MAX_VALUE`], is stored as −1 (not measured). `f` is called from several threads.
    pub fn tabulate(name: &str, f: &(dyn Fn(V3, V3) -> [f64; 3] + Sync)) -> Measured {
        use rayon::prelude::*;
        let rows: Vec<Vec<[f64; 3]>> = (0..DIMS[0] * DIMS[1])
            .into_par_iter()
            .map(|ij| {
                (0..DIMS[2])
                    .map(|k| {
                        let (l, v) = entry_dirs(ij / DIMS[1], ij % DIMS[1], k);
                        if !(l[2] > 0.0 && v[2] > 0.0) {
                            return [-1.0; 3];
                        }
                        let x = f(l, v);
                        // A value over MAX_VALUE (or beyond the format's range, which would store ±inf) is one
                        // no reader (lobe's included) takes: not measured, like a non-finite one.
                        std::array::from_fn(|c| Some(x[c] / SCALE[c]).filter(|s| s.is_finite() && s * SCALE[c] <= MAX_VALUE).unwrap_or(-1.0))
                    })
                    .collect()
            })
            .collect();
        let mut stored = vec![0.0; 3 * ENTRIES];
        for (e, x) in rows.iter().flatten().enumerate() {
            for c in 0..3 {
                stored[c * ENTRIES + e] = x[c];
            }
        }
        Measured { name: name.to_string(), stored }
    }

    /// [`Measured::tabulate`] of a formula's kernels at `params` (one kernel for every channel, or red, green,
    /// blue), each channel multiplied by its factor of `color` (a scalar formula's colour): what
    /// `lobe tabulate` writes.
    pub fn tabulate_channels(name: &str, channels: &[&dyn Evaluator], params: &[f64], color: [f64; 3]) -> Measured {
        Measured::tabulate(name, &|l, v| {
            let x = crate::frame::inputs_from_dirs(l, v);
            std::array::from_fn(|c| channels[c.min(channels.len() - 1)].eval(&x, params) * color[c])
        })
    }

    /// The stored value of channel `c` at entry `e` (as the file holds it).
    pub fn stored(&self, c: usize, e: usize) -> f64 {
        self.stored[c * ENTRIES + e]
    }

    /// The physical value of channel `c` at entry `e`; `None` where it was not measured.
    pub fn value(&self, c: usize, e: usize) -> Option<f64> {
        let s = self.stored(c, e);
        (s >= 0.0).then(|| s * SCALE[c])
    }

    /// Entries measured in all three channels.
    pub fn measured_entries(&self) -> usize {
        (0..ENTRIES).filter(|&e| (0..3).all(|c| self.stored(c, e) >= 0.0)).count()
    }

    /// The physical value of channel `c` for L and V in the local frame, read the default way
    /// ([`Lookup::Linear`]; module docs).
    pub fn lookup(&self, c: usize, l: V3, v: V3) -> f64 {
        self.lookup_with(Lookup::default(), c, l, v)
    }

    /// The physical value of channel `c` for L and V in the local frame, read as `how` says (module docs); 0
    /// where nothing reflects (L or V at or below the surface, non-finite directions, not measured).
    pub fn lookup_with(&self, how: Lookup, c: usize, l: V3, v: V3) -> f64 {
        if !(l[2] > 0.0 && v[2] > 0.0) {
            return 0.0;
        }
        let Some(a) = half_diff(l, v) else { return 0.0 };
        match how {
            Lookup::Nearest => {
                let (i, j, k) = angles_index(a);
                self.value(c, index(i, j, k)).unwrap_or(0.0)
            }
            Lookup::Linear => {
                let [xi, xj, xk] = angles_coords(a);
                let (ci, cj, ck) = (corners(xi, DIMS[0], false), corners(xj, DIMS[1], false), corners(xk, DIMS[2], true));
                let (mut sum, mut weight, mut missing) = (0.0, 0.0, false);
                for (i, wi) in ci.into_iter().filter(|c| c.1 > 0.0) {
                    for (j, wj) in cj.into_iter().filter(|c| c.1 > 0.0) {
                        for (k, wk) in ck.into_iter().filter(|c| c.1 > 0.0) {
                            let w = wi * wj * wk;
                            match self.value(c, index(i, j, k)) {
                                Some(x) => {
                                    sum += w * x;
                                    weight += w;
                                }
                                None => missing = true,
                            }
                        }
                    }
                }
                match (missing, weight > 0.0) {
                    (false, _) => sum,
                    (true, true) => sum / weight,
                    (true, false) => 0.0,
                }
            }
        }
    }

    /// The three channels as evaluators (red, green, blue), read the default way.
    pub fn channels(self: &Arc<Self>) -> [Arc<dyn Evaluator>; 3] {
        self.channels_with(Lookup::default())
    }

    /// The three channels as evaluators (red, green, blue), read as `how` says.
    pub fn channels_with(self: &Arc<Self>, how: Lookup) -> [Arc<dyn Evaluator>; 3] {
        std::array::from_fn(|c| Arc::new(Channel { table: self.clone(), c, how }) as Arc<dyn Evaluator>)
    }
}

/// Reads until `buf` is full or the file ends; returns the bytes read.
fn read_up_to(r: &mut impl std::io::Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

fn check_header(name: &str, h: &[u8]) -> Result<(), Diagnostic> {
    let d: Vec<i32> = h.chunks_exact(4).map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if d != DIMS.map(|x| x as i32) {
        return Err(bad(name, format!("dimensions {} × {} × {} in the header; a MERL table is 90 × 90 × 180", d[0], d[1], d[2]), NOT_MERL));
    }
    Ok(())
}

fn check_length(name: &str, len: u64) -> Result<(), Diagnostic> {
    let want = FILE_BYTES as u64;
    if len < want {
        let missing = (want - len).div_ceil(8);
        return Err(bad(name, format!("truncated: {len} bytes, a 90 × 90 × 180 table needs {want} ({missing} values missing)"), "the file was cut short; download or write it again"));
    }
    if len > want {
        return Err(bad(name, format!("{len} bytes, {} more than a 90 × 90 × 180 table's {want}", len - want), NOT_MERL));
    }
    Ok(())
}

/// The inputs a measured channel reads: the direction components of L and V.
pub fn used_inputs() -> InputSet {
    let mut s = InputSet::default();
    for i in [Input::Lx, Input::Ly, Input::Lz, Input::Vx, Input::Vy, Input::Vz] {
        s.insert(i);
    }
    s
}

/// One channel of a table as an evaluator of the kernel inputs (it reads L and V, ignores parameters).
pub(crate) struct Channel {
    pub table: Arc<Measured>,
    pub c: usize,
    pub how: Lookup,
}

impl Evaluator for Channel {
    fn eval(&self, x: &[f64; N_INPUTS], _params: &[f64]) -> f64 {
        let g = |i: Input| x[i.index()];
        self.table.lookup_with(self.how, self.c, [g(Input::Lx), g(Input::Ly), g(Input::Lz)], [g(Input::Vx), g(Input::Vy), g(Input::Vz)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entry_dirs_from_tables_of_sines_are_entry_dirs() {
        let dirs = EntryDirs::new();
        for i in 0..DIMS[0] {
            for j in (0..DIMS[1]).step_by(7) {
                for k in 0..DIMS[2] {
                    let (a, b) = (dirs.at(i, j, k), entry_dirs(i, j, k));
                    assert_eq!([a.0, a.1].map(|d| d.map(f64::to_bits)), [b.0, b.1].map(|d| d.map(f64::to_bits)), "{i} {j} {k}");
                }
            }
        }
    }
    use crate::base::rng::Rng;

    /// A table whose every stored value names its entry and channel.
    fn labelled() -> Measured {
        let stored = (0..3 * ENTRIES).map(|e| e as f64 + 0.25).collect();
        Measured { name: "labelled".into(), stored }
    }

    #[test]
    fn write_then_read_is_exact() {
        let m = labelled();
        let bytes = m.to_bytes();
        assert_eq!(bytes.len(), FILE_BYTES);
        let back = Measured::from_bytes("labelled", &bytes).unwrap();
        assert!(back == m);
    }

    #[test]
    fn the_conventions_angles_find_their_entry() {
        let m = labelled();
        let mut rng = Rng(7);
        // Every θ_h and θ_d index with a spread of φ_d (every one of them for a few rows).
        for i in 0..DIMS[0] {
            for j in 0..DIMS[1] {
                let ks: Vec<usize> = if (i + j) % 17 == 0 { (0..DIMS[2]).collect() } else { (0..6).map(|_| rng.below(180) as usize).collect() };
                for k in ks {
                    let (l, v) = entry_dirs(i, j, k);
                    let got = half_diff(l, v).map(angles_index);
                    // θ_d = 0 has no φ_d: every k of it is the same pair of directions, found as k = 0.
                    let want = (i, j, if j == 0 { 0 } else { k });
                    assert_eq!(got, Some(want), "{l:?} {v:?}");
                    if l[2] > 0.0 && v[2] > 0.0 {
                        for (c, scale) in SCALE.iter().enumerate() {
                            for how in [Lookup::Nearest, Lookup::Linear] {
                                assert_eq!(m.lookup_with(how, c, l, v), m.stored(c, index(want.0, want.1, want.2)) * scale, "{how:?}");
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn reciprocity_and_random_directions() {
        let m = labelled();
        let mut rng = Rng(11);
        let dir = |rng: &mut Rng| {
            let v = [rng.unit() * 2.0 - 1.0, rng.unit() * 2.0 - 1.0, rng.unit() * 2.0 - 1.0];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-300);
            v.map(|x| x / n)
        };
        for _ in 0..20_000 {
            let (l, v) = (dir(&mut rng), dir(&mut rng));
            let a = m.lookup(0, l, v);
            assert!(a.is_finite() && a >= 0.0);
            // Swapping L and V turns φ_d by π: the same bin away from the bins' edges.
            let (x, y) = (half_diff(l, v).map(angles_index), half_diff(v, l).map(angles_index));
            if let (Some(p), Some(q)) = (half_diff(l, v), half_diff(v, l)) {
                let frac = |a: f64| (a.rem_euclid(PI) / PI * 180.0).fract();
                if (0.01..0.99).contains(&frac(p[2])) && (0.01..0.99).contains(&frac(q[2])) {
                    assert_eq!(x, y, "{l:?} {v:?}");
                }
            }
        }
        // Grazing, below the surface, opposite, degenerate and non-finite directions.
        let odd = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1e-300], [0.0, 0.0, -1.0], [f64::NAN, 0.0, 1.0], [0.0; 3], [f64::INFINITY, 0.0, 1.0], [-1.0, -0.0, 1e-17]];
        for l in odd {
            for v in odd {
                assert!(m.lookup(2, l, v).is_finite(), "{l:?} {v:?}");
            }
        }
        assert_eq!(m.lookup(0, [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]), 0.0);
    }

    /// A table whose entries are an affine function of the index coordinates (i, j, k): the linear lookup
    /// reads it back exactly between entries, the nearest one only at them.
    #[test]
    fn linear_lookup_is_exact_on_affine_tables_and_wraps() {
        let affine = |i: f64, j: f64, k: f64| 3.0 + 2.0 * i + 0.5 * j + 0.25 * k;
        let mut stored = vec![0.0; 3 * ENTRIES];
        for i in 0..DIMS[0] {
            for j in 0..DIMS[1] {
                for k in 0..DIMS[2] {
                    stored[index(i, j, k)] = affine(i as f64, j as f64, k as f64) / SCALE[0];
                }
            }
        }
        let m = Measured { name: "affine".into(), stored };
        let mut rng = Rng(5);
        let (mut checked, mut nearest_off) = (0, 0);
        while checked < 5000 {
            // Index coordinates inside the table, away from the φ_d seam; their angles and directions.
            let x = [rng.unit() * 88.0 + 0.5, rng.unit() * 88.0 + 0.5, rng.unit() * 178.0 + 0.5];
            let u = x[0] / 90.0;
            let (l, v) = dirs_from_angles([u * u * FRAC_PI_2, x[1] / 90.0 * FRAC_PI_2, x[2] / 180.0 * PI]);
            if !(l[2] > 0.0 && v[2] > 0.0) {
                continue;
            }
            checked += 1;
            let want = affine(x[0], x[1], x[2]);
            let got = m.lookup_with(Lookup::Linear, 0, l, v);
            assert!((got - want).abs() < 1e-8 * want, "{x:?}: {got} vs {want}");
            let near = m.lookup_with(Lookup::Nearest, 0, l, v);
            nearest_off += usize::from((near - want).abs() > 1e-3);
            // The default is the linear lookup.
            assert_eq!(m.lookup(0, l, v), got);
        }
        assert!(nearest_off > 4900, "{nearest_off}");
        // φ_d between entry 179 and π (= entry 0 under the fold): between their values.
        let a = [0.3, 0.5, PI * 179.5 / 180.0];
        let (l, v) = dirs_from_angles(a);
        let [xi, xj, _] = angles_coords(half_diff(l, v).unwrap());
        let got = m.lookup_with(Lookup::Linear, 0, l, v);
        let want = 0.5 * (affine(xi, xj, 179.0) + affine(xi, xj, 0.0));
        assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
    }

    #[test]
    fn linear_lookup_skips_unmeasured_neighbours() {
        let mut m = labelled();
        let (l, v) = dirs_from_angles([(20.5f64 / 90.0).powi(2) * FRAC_PI_2, 30.0 / 90.0 * FRAC_PI_2, 40.0 / 180.0 * PI]);
        let (a, b) = (index(20, 30, 40), index(21, 30, 40));
        let mid = m.lookup_with(Lookup::Linear, 0, l, v);
        assert!((mid - 0.5 * (m.stored(0, a) + m.stored(0, b)) * SCALE[0]).abs() < 1e-9 * mid, "{mid}");
        // One of the two unmeasured: the other's value; both: no light.
        m.stored[b] = -1.0;
        assert!((m.lookup_with(Lookup::Linear, 0, l, v) - m.stored(0, a) * SCALE[0]).abs() < 1e-9 * mid);
        m.stored[a] = -1.0;
        assert_eq!(m.lookup_with(Lookup::Linear, 0, l, v), 0.0);
        assert_eq!(m.lookup_with(Lookup::Nearest, 0, l, v), 0.0);
        assert!(m.lookup_with(Lookup::Linear, 1, l, v) > 0.0);
        assert_eq!("nearest".parse(), Ok(Lookup::Nearest));
        assert!("cubic".parse::<Lookup>().unwrap_err().contains("linear or nearest"));
    }

    #[test]
    fn phi_d_on_pi_wraps_to_zero() {
        assert_eq!(angles_index([0.3, 0.4, PI]).2, 0);
        assert_eq!(angles_index([0.3, 0.4, -1e-17]).2, 0);
        assert_eq!(angles_index([0.3, 0.4, PI - 0.01]).2, 179);
        assert_eq!(angles_index([0.3, 0.4, -PI / 2.0]).2, 90);
        assert_eq!(angles_index([f64::NAN, f64::NAN, f64::NAN]), (0, 0, 0));
        assert_eq!(angles_index([10.0, 10.0, 10.0]).0, 89);
    }

    #[test]
    fn hostile_bytes_are_clear_errors() {
        let good = labelled().to_bytes();
        let msg = |b: &[u8]| Measured::from_bytes("x.binary", b).unwrap_err().to_string();
        assert!(msg(&good[..5]).contains("shorter than the 12-byte header"), "{}", msg(&good[..5]));
        let t = msg(&good[..good.len() - 9]);
        assert!(t.contains("`x.binary`: truncated") && t.contains("2 values missing"), "{t}");
        let mut huge = good.clone();
        huge[..4].copy_from_slice(&i32::MAX.to_le_bytes());
        assert!(msg(&huge).contains("dimensions 2147483647 × 90 × 180"), "{}", msg(&huge));
        let mut neg = good.clone();
        neg[4..8].copy_from_slice(&(-90i32).to_le_bytes());
        assert!(msg(&neg).contains("-90"));
        let mut long = good.clone();
        long.push(0);
        assert!(msg(&long).contains("1 more than"));
        let mut nan = good.clone();
        let at = HEADER + (ENTRIES + index(3, 4, 5)) * 8;
        nan[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        let t = msg(&nan);
        assert!(t.contains("green block holds 1 non-finite") && t.contains("(θ_h 3, θ_d 4, φ_d 5)"), "{t}");
    }

    #[test]
    fn tabulate_stores_as_merl_does() {
        let m = Measured::tabulate("blinn", &|l, v| {
            let x = crate::frame::inputs_from_dirs(l, v);
            [x[Input::NH.index()].powf(20.0); 3]
        });
        let e = index(10, 20, 30);
        let (l, v) = entry_dirs(10, 20, 30);
        let nh = crate::frame::inputs_from_dirs(l, v)[Input::NH.index()];
        for (c, scale) in SCALE.iter().enumerate() {
            assert_eq!(m.stored(c, e), nh.powf(20.0) / scale);
        }
        // θ_h near 90° with θ_d near 90°: V is below the surface, not measured.
        assert_eq!(m.value(0, index(89, 89, 0)), None);
        assert!(m.measured_entries() > ENTRIES / 2 && m.measured_entries() < ENTRIES);
        let ch = Arc::new(m).channels();
        let x = crate::frame::inputs_from_dirs(l, v);
        assert_eq!(ch[1].eval(&x, &[]), nh.powf(20.0) / SCALE[1] * SCALE[1]);
    }
}

