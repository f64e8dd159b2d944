//! Every formula a full BSDF: `sample()` and `pdf()` that agree with `eval()`, built from the compiled kernel.
//!
//! A [`Sampler`] draws the outgoing direction `wo` for an incident `wi` (the formula's L; `wo` is its V; the local
//! frame N = +z, X = +x) with a density that follows f(wi, wo)·cosθₒ (for a colour formula, the luminance
//! 0.2126 r + 0.7152 g + 0.0722 b of the channels), and returns `(wo, pdf, weight)` with weight = f·cosθₒ/pdf
//! from the same kernels ([`Sampler::sample_many`]); [`Sampler::pdf_many`] is the density of any `wo`. It
//! consumes [`Kernel`]s (batched evaluation over [`Columns`], inputs from directions through
//! [`crate::frame::inputs_from_dirs`]), never source text.
//!
//! # Mechanisms ([`Mechanism`])
//! - **Tabulated** (any formula): the half-vector parameterisation. For `wi` and a half vector h with
//!   θₕ = (π/2)·x₁² (Dupuy and Jakob's warp, as Mitsuba's `measured` plugin) and φₕ = 2π·x₂ (+ wi's azimuth for an
//!   isotropic formula), wo = 2(wi·h)h − wi; the map h ↔ wo is a bijection (h = ±norm(wi + wo), the sign making
//!   h.z ≥ 0) with dωₒ = 4|wi·h| dωₕ. Per incidence node a [`ROWS`] × [`COLS`] grid over (x₁, x₂) holds at each
//!   cell corner the maximum over the 3 × 3 sub-grid points (corners and centres) within half a cell of it of
//!   g = lum(f)·max(cosθₒ, 0)·4|wi·h| — pbrt-v4's `FromFuncLInfinity` rule for corners, so a cell with g > 0 at
//!   one of its points has a positive corner. Within a cell the density in ωₕ is bilinear in (sin²(θₕ/2), φₕ),
//!   coordinates uniform in solid angle, between its corners: continuous, and bounded everywhere, the mirror
//!   direction (h = N, the warp's pole, whose corners share one value) included. A cell is chosen by its mass
//!   (a marginal and conditional inverse CDF), the point in it by the bilinear density's linear marginal and
//!   conditional. Every catalogue lobe peaks at h = N, which the x₁² warp resolves with small cells.
//! - **Exact** (a formula whose only input is NH, or only VR — one cosine, nothing else): a 1-D table over
//!   θ ∈ [0, θmax] (θmax = π for VR, π/2 for NH) in [`EXACT_CELLS`] cells, each cell its solid angle about the
//!   axis times the maximum of lum(f(cos θ)) at its ends and middle, inverted by binary search; within a cell θ is
//!   uniform in sin²(θ/2), so the density in solid angle is constant over each ring of a cell and bounded on the
//!   axis. NH: one table; φ uniform about N; the sampled h gives wo = 2(wi·h)h − wi with the Jacobian
//!   1/(4 wo·h). VR: the lobe about R, the mirror of wi, with the cosine: one table per isotropic incidence node
//!   (the tabulated mechanism's θₖ, the same mixture rule), its cells weighted by the mean of max(cosθₒ, 0) over
//!   the ring at θ from R at θₖ ([`ring`], closed form), and φ about R drawn for the actual wi with density
//!   ∝ max(cosθₒ, 0) on the ring ([`ring_azimuth`]), so the part the horizon cuts is not sampled and
//!   pdfₖ = tableₖ(θ)/measure(θ)·π·max(cosθₒ, 0)/H(θ, θᵢ).
//! - **Cosine**: cosθₒ/π, for formulas neither of the above beats (and for a formula that is 0 everywhere).
//!
//! [`Choice::Auto`] (the default) builds every mechanism the formula admits and keeps the one of highest mean
//! efficiency E\[w\]²/E\[w²\] over θᵢ = 0°, 30°, 60°, 85° (1024 samples each, a fixed seed); [`Report`] says which
//! and what each measured.
//!
//! # The mixture rule (why sample and pdf agree exactly)
//! Every sampler is a mixture: with probability [`COSINE_FRACTION`] the cosine density, else the mechanism's.
//! Tabulated incidence nodes: an isotropic formula (one that reads only cosines, or whose values pass
//! [`turns_with_the_frame`]) has [`ISO_NODES`] nodes over θᵢ, θₖ = 89.5°·(1 − (1 − k/23)²) — dense toward grazing,
//! where the horizon cuts the lobe and its shape changes fastest (spacing 7.8° at the normal, 0.17° at the last
//! node) — with φₕ measured from wi's azimuth; an anisotropic one a grid of [`ANISO_THETA_NODES`] θᵢ (the same
//! rule) × [`ANISO_PHI_NODES`] φᵢ with φₕ absolute. Between nodes the sampler picks a node with probability equal
//! to its linear (bilinear) interpolation weight, re-using x₁ (rescaled), and pdf(wi, wo) = Σₖ wₖ·pdfₖ(wo) over
//! the same nodes and weights. Each node's table is applied with the actual wi (the h-map uses the real wi), so
//! each pdfₖ is an exact density of the directions it produces and so is the mixture, wherever wi falls between
//! nodes (beyond the last node, its table alone). A node whose table is empty (the formula is 0 for every wo at
//! that incidence) samples the cosine density in its place: its pdfₖ is cosθₒ/π.
//!
//! `sample` draws wo and then computes its density with the very function `pdf` runs, so the pdf a sample
//! reports equals pdf(wi, wo) bit for bit; the weight is f·cosθₒ/pdf with f from the kernels, a batch at a time.
//!
//! # The horizon and bad input
//! - A sampled wo below the horizon (wo.z ≤ 0: a table cell that straddles the horizon, an NH lobe's reflection
//!   cut by it, or a VR ring wholly below it) keeps its direction and density and has weight 0; the cosine
//!   fraction keeps pdf > 0 wherever cosθₒ > 0, so f·cos > 0 implies pdf > 0.
//! - wi zero or not finite is an error; wi is normalised; wi below or on the horizon (wi.z ≤ 0) is an error (the
//!   formula's L is an incident direction of the upper hemisphere). A wo given to `pdf` must be finite and
//!   non-zero; it is normalised unless already unit to 10⁻⁹.
//! - While building, a negative value of a channel at a table point (with cosθₒ > 0) refuses the formula, naming
//!   the directions and the input values there; so does a NaN or an infinite value. A formula 0 at every table
//!   point of an incidence node gives that node an empty table ([`Report::empty_nodes`]); 0 everywhere gives
//!   the cosine mechanism and weight 0 for every sample, never NaN.
//!
//! # Export
//! [`mitsuba`] writes a sampler and its formula as a Mitsuba 3 BSDF plugin (Python, Dr.Jit), the tables
//! embedded; docs/mitsuba.md.
//!
//! # Cost
//! Measured numbers are in BENCHMARKS.md ("Sampling"): build time, ns per sample and per pdf, efficiency per
//! catalogue formula beside cosine sampling's.

pub mod chi2;
pub(crate) mod dist;
pub mod mitsuba;
pub mod validate;

use crate::backend::{Columns, Evaluator, Kernel};
use crate::base::diag::Diagnostic;
use crate::frame::{inputs_from_dirs, V3};
use crate::ir::{Input, InputSet, N_INPUTS};
use crate::numerics::energy::turns_with_the_frame;
use dist::{Dist1D, Dist2D};
use std::f64::consts::{FRAC_PI_2, PI};
use std::time::{Duration, Instant};

/// Rec. 709 luminance of (r, g, b): the target density of a colour formula.
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];
/// The probability of the cosine part of every mixture, chosen by measurement (docs/sampling.md,
/// `sample::cosine_fraction_measurement`): over the catalogue at θᵢ = 0°, 30°, 60°, 85°, 5 % gives mean efficiency
/// 0.956 and largest weight 2.5× the mean, 10 % 0.931 and 2.7×, 20 % 0.875 and 3.2×.
pub const COSINE_FRACTION: f64 = 0.05;
/// Rows of a node's table (x₁, the warped θₕ).
pub const ROWS: usize = 64;
/// Columns of a node's table (x₂, φₕ).
pub const COLS: usize = 32;
/// Incidence nodes over θᵢ for an isotropic formula.
pub const ISO_NODES: usize = 24;
/// Incidence nodes over θᵢ for an anisotropic formula.
pub const ANISO_THETA_NODES: usize = 12;
/// Incidence nodes over φᵢ for an anisotropic formula.
pub const ANISO_PHI_NODES: usize = 16;
/// The last node's θᵢ (degrees); wi beyond it uses that node's table.
pub const LAST_NODE_DEG: f64 = 89.5;
/// Cells of the exact path's 1-D table.
pub const EXACT_CELLS: usize = 4096;
/// Samples per incidence of the automatic choice's efficiency probe.
const PROBE_SAMPLES: usize = 1024;
/// Points evaluated per kernel batch.
const BATCH: usize = 4096;

/// How a sampler draws wo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mechanism {
    Tabulated,
    Exact,
    Cosine,
}

impl Mechanism {
    pub fn name(self) -> &'static str {
        match self {
            Mechanism::Tabulated => "tabulated",
            Mechanism::Exact => "exact",
            Mechanism::Cosine => "cosine",
        }
    }
}

impl std::str::FromStr for Mechanism {
    type Err = String;
    fn from_str(s: &str) -> Result<Mechanism, String> {
        match s {
            "tabulated" => Ok(Mechanism::Tabulated),
            "exact" => Ok(Mechanism::Exact),
            "cosine" => Ok(Mechanism::Cosine),
            _ => Err(format!("unknown mechanism `{s}`; expected `auto`, `tabulated`, `exact` or `cosine`")),
        }
    }
}

/// Which mechanism to build.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Choice {
    /// The best measured of those the formula admits (module docs).
    #[default]
    Auto,
    /// This one (`Exact` on a formula that is not one cosine is an error).
    Force(Mechanism),
}

/// How to build a sampler.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    pub choice: Choice,
    /// The cosine part of the mixture, in (0, 1).
    pub cosine_fraction: f64,
}

impl Default for Options {
    fn default() -> Options {
        Options { choice: Choice::Auto, cosine_fraction: COSINE_FRACTION }
    }
}

/// What a build did.
#[derive(Clone, Debug)]
pub struct Report {
    pub mechanism: Mechanism,
    /// Whether the formula was taken as isotropic (nodes over θᵢ only).
    pub isotropic: bool,
    /// Wall time of the build, the automatic choice included.
    pub build: Duration,
    /// Incidence nodes (θᵢ, φᵢ in radians) whose tables are empty: the formula is 0 there for every wo.
    pub empty_nodes: Vec<(f64, f64)>,
    /// The mean probe efficiency of each mechanism built (automatic choice only).
    pub candidates: Vec<(Mechanism, f64)>,
}

/// A batch of samples: `wo[i]`, `pdf[i]`, and `weight[i·channels + c]` for channel c.
#[derive(Clone, Debug, Default)]
pub struct Samples {
    pub wo: Vec<V3>,
    pub pdf: Vec<f64>,
    pub weight: Vec<f64>,
    pub channels: usize,
}

impl Samples {
    /// Sample i's weight as luminance (the weight itself for a scalar formula).
    pub fn luminance(&self, i: usize) -> f64 {
        let w = &self.weight[i * self.channels..(i + 1) * self.channels];
        if self.channels == 1 {
            w[0]
        } else {
            w.iter().zip(LUMINANCE).map(|(a, b)| a * b).sum()
        }
    }
}

/// The formula's channels as one target: kernels, their luminance weights, the parameters.
#[derive(Clone)]
struct Target {
    kernels: Vec<Kernel>,
    lum: Vec<f64>,
    params: Vec<f64>,
    used: InputSet,
}

impl Target {
    fn channels(&self) -> usize {
        self.kernels.len()
    }

    /// Channel values at each (wi, wo), `out[i·channels + c]`, evaluated in batches.
    fn eval_pairs(&self, pairs: &[(V3, V3)], out: &mut Vec<f64>) {
        self.eval_inputs(pairs.len(), |i| inputs_from_dirs(pairs[i].0, pairs[i].1), out)
    }

    /// Channel values at `n` input points given by `at`.
    fn eval_inputs(&self, n: usize, at: impl Fn(usize) -> [f64; N_INPUTS], out: &mut Vec<f64>) {
        let nch = self.channels();
        out.clear();
        out.resize(n * nch, 0.0);
        let mut cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|_| Vec::with_capacity(BATCH.min(n))).collect();
        let mut tmp = vec![0.0; BATCH.min(n)];
        for start in (0..n).step_by(BATCH) {
            let end = (start + BATCH).min(n);
            for c in cols.iter_mut() {
                c.clear();
            }
            for i in start..end {
                let x = at(i);
                for (k, c) in cols.iter_mut().enumerate() {
                    if self.used.contains(Input::ALL[k]) {
                        c.push(x[k]);
                    }
                }
            }
            let refs: [&[f64]; N_INPUTS] = std::array::from_fn(|k| cols[k].as_slice());
            let t = &mut tmp[..end - start];
            for (ch, k) in self.kernels.iter().enumerate() {
                k.eval_batch(&Columns::new(refs), &self.params, t);
                for (i, v) in t.iter().enumerate() {
                    out[(start + i) * nch + ch] = *v;
                }
            }
        }
    }

    fn luminance(&self, vals: &[f64]) -> f64 {
        vals.iter().zip(&self.lum).map(|(a, b)| a * b).sum()
    }
}

/// Checks one point's channel values; the error names the point.
fn check_point(vals: &[f64], at: impl Fn() -> String) -> Result<(), Diagnostic> {
    for (c, &v) in vals.iter().enumerate() {
        let ch = if vals.len() > 1 { format!(" (channel {})", ["r", "g", "b"][c.min(2)]) } else { String::new() };
        if v.is_nan() {
            return Err(Diagnostic::error(format!("the formula is NaN{ch} at {}", at()))
                .hint("a sampler needs a value everywhere on the hemisphere")
                .hint(crate::numerics::NumericsAdvice::SweepForUndefined));
        }
        if v.is_infinite() {
            return Err(Diagnostic::error(format!("the formula is infinite{ch} at {}", at()))
                .hint("a sampler tabulates f·cosθₒ: a pole on the hemisphere has no finite table; choose parameters without it"));
        }
        if v < 0.0 {
            return Err(Diagnostic::error(format!("the formula is negative{ch} ({}) at {}", v, at()))
                .hint("a BSDF is ≥ 0: clamp the formula with max(…, 0), or choose parameters where it is non-negative"));
        }
    }
    Ok(())
}

/// "wi = (θ, φ), wo = (θ, φ): NL=… NV=… NH=… VR=… VH=…" for an error.
fn describe_pair(wi: V3, wo: V3) -> String {
    let x = inputs_from_dirs(wi, wo);
    let polar = |w: V3| format!("(θ {:.3}°, φ {:.3}°)", w[2].clamp(-1.0, 1.0).acos().to_degrees(), w[1].atan2(w[0]).to_degrees());
    format!(
        "wi = {}, wo = {}: NL={:.6} NV={:.6} NH={:.6} VR={:.6} VH={:.6}",
        polar(wi),
        polar(wo),
        x[0],
        x[1],
        x[2],
        x[3],
        x[4]
    )
}

#[inline]
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn reflect(wi: V3, h: V3) -> V3 {
    let d = 2.0 * dot(wi, h);
    [d * h[0] - wi[0], d * h[1] - wi[1], d * h[2] - wi[2]]
}

fn dir(theta: f64, phi: f64) -> V3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    [st * cp, st * sp, ct]
}

/// An azimuth as its (cos, sin): the frame a table's φₕ is measured in (wi's azimuth for an isotropic formula,
/// 0 for an anisotropic one).
type Turn = (f64, f64);

/// No turn: φₕ absolute.
const NO_TURN: Turn = (1.0, 0.0);

/// wi's azimuth as a [`Turn`] ((1, 0) at the normal, where every azimuth is the same wi).
#[inline]
fn azimuth_of(wi: V3) -> Turn {
    let r = (wi[0] * wi[0] + wi[1] * wi[1]).sqrt();
    if r > 0.0 {
        (wi[0] / r, wi[1] / r)
    } else {
        NO_TURN
    }
}

/// The half vector at polar angle θₕ (its cosine and sine) and azimuth φₕ = 2πx₂ measured in the frame turned
/// by `turn`.
#[inline]
fn half_at(ct: f64, st: f64, x2: f64, turn: Turn) -> V3 {
    let (sp, cp) = (2.0 * PI * x2).sin_cos();
    let (c, s) = turn;
    [st * (cp * c - sp * s), st * (sp * c + cp * s), ct]
}

/// The half vector of table coordinates (x₁, x₂) (θₕ = (π/2)·x₁²) in the frame turned by `turn`.
#[inline]
fn half_from(x1: f64, x2: f64, turn: Turn) -> V3 {
    let (st, ct) = (FRAC_PI_2 * x1 * x1).sin_cos();
    half_at(ct, st, x2, turn)
}

/// sin²(θ/2) = (1 − cosθ)/2 at the edges `theta(0)`, …, `theta(n)` of n bands in θ: the solid angle of the band
/// between edges a and b about an axis is 4π·(s_b − s_a), and s is uniform in solid angle. Computed without
/// the cancellation of 1 − cosθ near the axis.
fn band_edges(n: usize, theta: impl Fn(usize) -> f64) -> Vec<f64> {
    (0..=n)
        .map(|a| {
            let h = (0.5 * theta(a)).sin();
            h * h
        })
        .collect()
}

/// The θ edges of the tabulated mechanism's rows: θₕ = (π/2)·(i/[`ROWS`])².
fn row_theta(i: usize) -> f64 {
    let x = i as f64 / ROWS as f64;
    FRAC_PI_2 * x * x
}

/// Table coordinates of the half vector of (wi, wo) (azimuth in the frame turned by `turn`): the row among
/// [`ROWS`] and the position in it (a, in [0, 1], linear in sin²(θₕ/2) between the row's edges `bands`), the
/// column among [`COLS`] and the position in it (b, in [0, 1], linear in φₕ), and dωₒ/dωₕ = 4|wi·h|; `None`
/// when wo = −wi (no half vector).
///
/// No trigonometry: from the unnormalised sum s = wi + wo (turned into the table's frame, sign chosen so
/// h.z ≥ 0), sin²(θₕ/2) = (1 − cosθₕ)/2 = |sₓᵧ|²/(2|s|(|s| + |s_z|)), without the cancellation of 1 − cosθₕ near
/// the normal where the lobes are; the row by [`row_of`]; the column and the angle within it by
/// [`column_and_position`].
#[inline]
fn table_coords(wi: V3, wo: V3, turn: Turn, bands: &[f64], guide: &[u8]) -> Option<(usize, f64, usize, f64, f64)> {
    let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
    let len2 = dot(s, s);
    if len2.is_nan() || len2 <= 0.0 {
        return None;
    }
    let (c, sn) = turn;
    let sign = if s[2] < 0.0 { -1.0 } else { 1.0 };
    let (hx, hy) = (sign * (s[0] * c + s[1] * sn), sign * (s[1] * c - s[0] * sn));
    let len = len2.sqrt();
    let sh = (hx * hx + hy * hy) / (2.0 * len * (len + s[2].abs()));
    let row = row_of(sh, bands, guide);
    let (s0, s1) = (bands[row], bands[row + 1]);
    let a = ((sh - s0) / (s1 - s0)).clamp(0.0, 1.0);
    let jac = 4.0 * dot(wi, s).abs() / len;
    let (col, b) = column_and_position(hx, hy);
    Some((row, a, col, b, jac))
}

/// The guide's resolution: sin²(θₕ/2) in [2⁻²⁴, 1) by its binary exponent and first [`GUIDE_BITS`] mantissa
/// bits (16 steps per octave; a row spans more than 1/16 octave, the narrowest, next to 0.5, about 0.07).
const GUIDE_BITS: u32 = 4;
const GUIDE_OCTAVES: u64 = 24;
const GUIDE: usize = (GUIDE_OCTAVES as usize) << GUIDE_BITS;
/// The key of 2⁻²⁴: the guide's entry 0, which also takes every smaller value.
const GUIDE_BASE: u64 = (1023 - GUIDE_OCTAVES) << GUIDE_BITS;

/// The guide entry of sh ≥ 0: its f64 bits (monotone in a non-negative value) above the first [`GUIDE_BITS`]
/// mantissa bits, from [`GUIDE_BASE`], clamped into the guide.
#[inline]
fn guide_index(sh: f64) -> usize {
    let key = sh.max(0.0).to_bits() >> (52 - GUIDE_BITS);
    (key.saturating_sub(GUIDE_BASE) as usize).min(GUIDE - 1)
}

/// The row guide: entry g is the row holding the least sin²(θₕ/2) of that entry (row 0 for entry 0).
fn row_guide(bands: &[f64]) -> Vec<u8> {
    (0..GUIDE)
        .map(|g| {
            if g == 0 {
                return 0;
            }
            let sh = f64::from_bits((GUIDE_BASE + g as u64) << (52 - GUIDE_BITS));
            (bands.partition_point(|&b| b <= sh).max(1) - 1).min(ROWS - 1) as u8
        })
        .collect()
}

/// The row whose band [bands\[row\], bands\[row + 1\]) holds sh = sin²(θₕ/2) (the last row from 0.5 on): the
/// guide's entry, then up while the next edge is ≤ sh.
#[inline]
fn row_of(sh: f64, bands: &[f64], guide: &[u8]) -> usize {
    let mut row = usize::from(guide[guide_index(sh)]);
    while row + 1 < ROWS && bands[row + 1] <= sh {
        row += 1;
    }
    row
}

/// atan z for |z| ≤ tan(π/16) ≈ 0.199 (an angle within one column): the Taylor series to z²¹, whose remainder
/// is below z²³/23 < 4e-18.
#[inline]
fn atan_small(z: f64) -> f64 {
    // p(y) = 1 − y/3 + y²/5 − … + y¹⁰/21 at y = z², by Estrin's scheme (a shallow dependency chain).
    const C: [f64; 11] = [1.0, -1.0 / 3.0, 1.0 / 5.0, -1.0 / 7.0, 1.0 / 9.0, -1.0 / 11.0, 1.0 / 13.0, -1.0 / 15.0, 1.0 / 17.0, -1.0 / 19.0, 1.0 / 21.0];
    let y = z * z;
    let (y2, y4) = (y * y, y * y * (y * y));
    let q0 = (C[0] + C[1] * y) + (C[2] + C[3] * y) * y2;
    let q1 = (C[4] + C[5] * y) + (C[6] + C[7] * y) * y2;
    let q2 = (C[8] + C[9] * y) + C[10] * y2;
    z * (q0 + (q1 + q2 * y4) * y4)
}

/// The column of azimuth atan2(y, x) among [`COLS`] equal sectors of [0, 2π) — the quadrant, then the number of
/// column edges inside it that the direction lies beyond — and the position in it, in [0, 1]: the angle past
/// the column's first edge by [`atan_small`] of the direction turned back by that edge (0 for the zero vector).
#[inline]
fn column_and_position(x: f64, y: f64) -> (usize, f64) {
    let (q, a, b) = quadrant(x, y);
    let beyond: usize = EDGES.iter().map(|&(ce, se)| usize::from(b * ce > a * se)).sum();
    let (ce, se) = if beyond == 0 { (1.0, 0.0) } else { EDGES[beyond - 1] };
    let (u, v) = (a * ce + b * se, b * ce - a * se);
    let pos = if u > 0.0 { atan_small(v / u) * (COLS as f64 / (2.0 * PI)) } else { 0.0 };
    (q * (COLS / 4) + beyond, pos.clamp(0.0, 1.0))
}

/// (cos, sin) of the column edges k·2π/[`COLS`] inside the first quadrant, k = 1 … COLS/4 − 1.
const EDGES: [(f64, f64); COLS / 4 - 1] = {
    // cos and sin of kπ/16 (COLS = 32), to 17 digits.
    [
        (0.980_785_280_403_230_4, 0.195_090_322_016_128_26),
        (0.923_879_532_511_286_7, 0.382_683_432_365_089_8),
        (0.831_469_612_302_545_2, 0.555_570_233_019_602_2),
        (std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2),
        (0.555_570_233_019_602_2, 0.831_469_612_302_545_2),
        (0.382_683_432_365_089_8, 0.923_879_532_511_286_7),
        (0.195_090_322_016_128_26, 0.980_785_280_403_230_4),
    ]
};

/// The quadrant of (x, y) and (a, b): (x, y) turned back by the quadrant's multiple of 90°, so a > 0, b ≥ 0
/// (a = b = 0 for the zero vector, quadrant 1).
#[inline]
fn quadrant(x: f64, y: f64) -> (usize, f64, f64) {
    if y >= 0.0 {
        if x > 0.0 { (0, x, y) } else { (1, y, -x) }
    } else if x <= 0.0 {
        (2, -x, -y)
    } else {
        (3, -y, x)
    }
}

/// θᵢ of incidence node k of `count`: 89.5°·(1 − (1 − k/(count − 1))²).
fn node_theta(k: usize, count: usize) -> f64 {
    let s = k as f64 / (count - 1) as f64;
    LAST_NODE_DEG.to_radians() * (1.0 - (1.0 - s) * (1.0 - s))
}

/// The nodes around θ among `thetas` (ascending) with linear weights: one node outside the range.
fn theta_weights(thetas: &[f64], t: f64) -> [(usize, f64); 2] {
    let last = thetas.len() - 1;
    if t <= thetas[0] {
        return [(0, 1.0), (0, 0.0)];
    }
    if t >= thetas[last] {
        return [(last, 1.0), (last, 0.0)];
    }
    let k = thetas.partition_point(|&x| x <= t) - 1;
    let f = (t - thetas[k]) / (thetas[k + 1] - thetas[k]);
    [(k, 1.0 - f), (k + 1, f)]
}

/// The tabulated mechanism: a table per incidence node.
#[derive(Clone, Debug)]
struct Tabulated {
    isotropic: bool,
    thetas: Vec<f64>,
    /// φᵢ nodes (anisotropic only; one node at 0 for an isotropic formula).
    phis: usize,
    /// Node (θ index t, φ index p) at t·phis + p; `None`: an empty table.
    nodes: Vec<Option<Node>>,
    /// sin²(θₕ/2) at the row edges ([`band_edges`]).
    bands: Vec<f64>,
    /// [`row_guide`] of `bands`.
    guide: Vec<u8>,
}

/// One incidence node's table: the density in ωₕ at the cell corners, bilinear within each cell in
/// (sin²(θₕ/2), φₕ) — coordinates uniform in solid angle — so continuous and bounded; and the cells' masses to
/// choose a cell by.
#[derive(Clone, Debug)]
pub(crate) struct Node {
    /// The cells' masses (row-major [`ROWS`] × [`COLS`]), as a distribution.
    pub(crate) cells: Dist2D,
    /// The density in ωₕ at corner (row edge i, column edge j) at i·[`COLS`] + j, i ≤ [`ROWS`] (column edge
    /// [`COLS`] is column edge 0); ∫ over the hemisphere of h = 1.
    pub(crate) corners: Vec<f64>,
}

impl Node {
    /// The four corners of cell (i, j): (v₀₀, v₀₁, v₁₀, v₁₁), first index along θₕ.
    #[inline]
    fn corners(&self, i: usize, j: usize) -> [f64; 4] {
        let j1 = (j + 1) % COLS;
        let c = &self.corners;
        [c[i * COLS + j], c[i * COLS + j1], c[(i + 1) * COLS + j], c[(i + 1) * COLS + j1]]
    }
}

/// x in [0, 1] with density ∝ (1 − x)·a + x·b for u in [0, 1] (pbrt-v4's `SampleLinear`; uniform when a = b).
#[inline]
fn sample_linear(u: f64, a: f64, b: f64) -> f64 {
    if u == 0.0 && a == 0.0 {
        return 0.0;
    }
    let x = u * (a + b) / (a + (a * a + u * (b * b - a * a)).max(0.0).sqrt());
    x.clamp(0.0, 1.0)
}

/// (1 − a)(1 − b)·v₀₀ + (1 − a)b·v₀₁ + a(1 − b)·v₁₀ + ab·v₁₁.
#[inline]
fn bilinear(v: [f64; 4], a: f64, b: f64) -> f64 {
    (1.0 - a) * ((1.0 - b) * v[0] + b * v[1]) + a * ((1.0 - b) * v[2] + b * v[3])
}

/// What a tabulated sampler needs of one wi, computed once per wi: the nodes it mixes with their weights, and the
/// frame φₕ is measured in.
#[derive(Clone, Copy, Debug)]
struct TabAt {
    ws: [(usize, f64); 4],
    turn: Turn,
}

impl Tabulated {
    /// The nodes wi mixes, their weights, and the frame of φₕ.
    fn at(&self, wi: V3) -> TabAt {
        let t = wi[2].clamp(-1.0, 1.0).acos();
        let tw = theta_weights(&self.thetas, t);
        if self.isotropic {
            return TabAt { ws: [tw[0], tw[1], (0, 0.0), (0, 0.0)], turn: azimuth_of(wi) };
        }
        let np = self.phis;
        let phi = wi[1].atan2(wi[0]);
        let p = phi.rem_euclid(2.0 * PI) / (2.0 * PI) * np as f64;
        let k = (p as usize).min(np - 1);
        let f = (p - k as f64).clamp(0.0, 1.0);
        let k1 = (k + 1) % np;
        let at = |t: usize, q: usize| t * np + q;
        TabAt {
            ws: [
                (at(tw[0].0, k), tw[0].1 * (1.0 - f)),
                (at(tw[0].0, k1), tw[0].1 * f),
                (at(tw[1].0, k), tw[1].1 * (1.0 - f)),
                (at(tw[1].0, k1), tw[1].1 * f),
            ],
            turn: NO_TURN,
        }
    }

    fn sample(&self, at: &TabAt, wi: V3, u1: f64, u2: f64) -> V3 {
        let (k, u) = pick_node(&at.ws, u1);
        match &self.nodes[k] {
            None => cosine_sample(u, u2),
            Some(d) => {
                // The cell by its mass, then the point in it by the bilinear density: along θₕ by the marginal
                // (linear), along φₕ by the conditional (linear), each from the uniform fraction within the cell.
                let (i, f1, j, f2) = d.cells.sample_cell(u, u2);
                let v = d.corners(i, j);
                let a = sample_linear(f1, v[0] + v[1], v[2] + v[3]);
                let b = sample_linear(f2, v[0] + a * (v[2] - v[0]), v[1] + a * (v[3] - v[1]));
                let s = self.bands[i] + a * (self.bands[i + 1] - self.bands[i]);
                let (ct, st) = cos_sin_of_band(s);
                let h = half_at(ct, st, (j as f64 + b) / COLS as f64, at.turn);
                reflect(wi, h)
            }
        }
    }

    #[inline]
    fn pdf(&self, at: &TabAt, wi: V3, wo: V3, cos_pdf: f64) -> f64 {
        let tc = table_coords(wi, wo, at.turn, &self.bands, &self.guide);
        // Σ w·(density in ωₕ) over the tables, divided by the Jacobian once; empty nodes add w·cosθₒ/π.
        let (mut empty, mut tables) = (0.0, 0.0);
        for &(k, w) in &at.ws {
            if w > 0.0 {
                match (&self.nodes[k], tc) {
                    (None, _) => empty += w * cos_pdf,
                    (Some(d), Some((row, a, col, b, jac))) if jac > 0.0 => tables += w * bilinear(d.corners(row, col), a, b),
                    _ => {}
                }
            }
        }
        match tc {
            Some((.., jac)) if tables > 0.0 => empty + tables / jac,
            _ => empty,
        }
    }
}

/// The largest f64 below 1.
const ONE_MINUS: f64 = 1.0 - f64::EPSILON / 2.0;

/// The exact mechanism: a 1-D table in the lobe angle θ about the lobe axis per incidence node.
///
/// NH: one table of lum(f(cos θₕ)) (f alone; the half vector's map and cosθₒ are not in it). VR: one table per
/// incidence node θₖ (the tabulated mechanism's isotropic nodes) of lum(f(cos θ))·c̄(θ, θₖ), where c̄ is the mean
/// of max(cosθₒ, 0) over the ring of directions at angle θ from R ([`ring`]); within the ring the azimuth about R
/// is drawn with density ∝ max(cosθₒ, 0) for the actual wi, so the lobe is sampled with the cosine and without
/// the part the horizon cuts.
#[derive(Clone, Debug)]
struct Exact {
    lobe: Input,
    theta_max: f64,
    /// θᵢ of the incidence nodes (one node at 0 for NH).
    thetas: Vec<f64>,
    /// Each node's table (`None`: the lobe is 0 wherever that node's rings reach above the horizon).
    nodes: Vec<Option<Dist1D>>,
    /// sin²(θ/2) at the cell edges ([`band_edges`]): within a cell θ is drawn uniform in this (uniform in solid
    /// angle about the axis), so the density in solid angle is constant over each ring of a cell and bounded.
    bands: Vec<f64>,
    /// [`EXACT_CELLS`]·4π·(bands\[i + 1\] − bands\[i\]): a cell density (∫ over θ/θmax = 1) over this is the
    /// density in solid angle about the axis (before the azimuth's weighting, for VR).
    measure: Vec<f64>,
}

/// The ring at angle θ from R for wi at θᵢ: with c = cosθ·cosθᵢ and d = sinθ·sinθᵢ (≥ 0), the ring's direction
/// at azimuth ψ from the ring's lowest point's opposite has cosθₒ = c + d·cosψ. Returns (ψmax, H): cosθₒ > 0 for
/// |ψ| < ψmax, and H = ∫₀^ψmax (c + d·cosψ) dψ = c·ψmax + d·sinψmax, half the integral of max(cosθₒ, 0) over the
/// ring's azimuth (so the ring's mean cosine is H/π). (0, 0) when the whole ring is at or below the horizon.
#[inline]
fn ring(c: f64, d: f64) -> (f64, f64) {
    if c >= d {
        (PI, PI * c)
    } else if c <= -d {
        (0.0, 0.0)
    } else {
        let psi = (-c / d).acos();
        // d·sinψmax = √(d² − c²).
        (psi, c * psi + ((d - c) * (d + c)).max(0.0).sqrt())
    }
}

/// ψ in [0, ψmax] with c·ψ + d·sinψ = t·H ([`ring`]; t in [0, 1]), and (sinψ, cosψ): Newton's method from
/// ψ = t·ψmax, kept inside a shrinking bracket (bisection where a step would leave it); c + d·cosψ ≥ 0 on
/// [0, ψmax], so the left side increases. Stops when a Newton step is below 10⁻¹⁵·(1 + ψ).
#[inline]
fn ring_azimuth(c: f64, d: f64, psi_max: f64, h: f64, t: f64) -> (f64, f64, f64) {
    let goal = t * h;
    let (mut lo, mut hi) = (0.0, psi_max);
    let mut psi = t * psi_max;
    for _ in 0..RING_ITERATIONS {
        let (s, co) = psi.sin_cos();
        let g = c * psi + d * s - goal;
        let slope = c + d * co;
        let step = g / slope;
        if slope > 0.0 && step.abs() <= 1e-15 * (1.0 + psi) {
            return (psi, s, co);
        }
        if g < 0.0 {
            lo = psi;
        } else {
            hi = psi;
        }
        let next = psi - step;
        psi = if slope > 0.0 && next > lo && next < hi { next } else { 0.5 * (lo + hi) };
    }
    let (s, co) = psi.sin_cos();
    (psi, s, co)
}

/// The most steps of [`ring_azimuth`] (bisection alone halves the bracket 64 times: below an ulp of π).
const RING_ITERATIONS: usize = 64;

/// The frame about R = (−wi.x, −wi.y, wi.z) for the VR lobe: t in the plane of R and N, pointing down (t.z =
/// −sinθᵢ), b horizontal, R. A direction at angle θ from R and azimuth φ from t has cosθₒ = cosθ·cosθᵢ −
/// sinθ·sinθᵢ·cosφ. (sinθᵢ, cosθᵢ) returned with it.
#[inline]
fn mirror_frame(wi: V3) -> ([V3; 3], f64, f64) {
    let rho = (wi[0] * wi[0] + wi[1] * wi[1]).sqrt();
    let (ax, ay) = if rho > 0.0 { (-wi[0] / rho, -wi[1] / rho) } else { (1.0, 0.0) };
    let ct = wi[2];
    ([[ct * ax, ct * ay, -rho], [-ay, ax, 0.0], [-wi[0], -wi[1], wi[2]]], rho, ct)
}

/// (cos θ, sin θ) of s = sin²(θ/2) ([`band_edges`]), without trigonometry.
#[inline]
fn cos_sin_of_band(s: f64) -> (f64, f64) {
    let s = s.clamp(0.0, 1.0);
    (1.0 - 2.0 * s, 2.0 * (s * (1.0 - s)).sqrt())
}

impl Exact {
    #[inline]
    fn axis(&self, wi: V3) -> V3 {
        if self.lobe == Input::VR {
            [-wi[0], -wi[1], wi[2]]
        } else {
            [0.0, 0.0, 1.0]
        }
    }

    /// The nodes wi mixes and their weights.
    #[inline]
    fn at(&self, wi: V3) -> [(usize, f64); 2] {
        if self.thetas.len() == 1 {
            return [(0, 1.0), (0, 0.0)];
        }
        theta_weights(&self.thetas, wi[2].clamp(-1.0, 1.0).acos())
    }

    fn sample(&self, ws: &[(usize, f64); 2], wi: V3, u1: f64, u2: f64) -> V3 {
        let (k, u) = pick_node(ws, u1);
        let Some(dist) = &self.nodes[k] else { return cosine_sample(u, u2) };
        let (i, f) = dist.sample_cell(u);
        let s = self.bands[i] + f * (self.bands[i + 1] - self.bands[i]);
        let (ct, st) = cos_sin_of_band(s);
        if self.lobe == Input::NH {
            let (sp, cp) = (2.0 * PI * u2).sin_cos();
            return reflect(wi, [st * cp, st * sp, ct]);
        }
        // The azimuth about R by max(cosθₒ, 0) on the ring, symmetric about its highest point (φ = π): u2 < ½ to
        // one side, the rest to the other. A ring wholly below the horizon (possible only from a node steeper
        // than wi) takes a uniform azimuth; its directions have weight 0.
        let ([t, b, r], rho, cti) = mirror_frame(wi);
        let (c, d) = (ct * cti, st * rho);
        let (psi_max, h) = ring(c, d);
        let (cp, sp) = if h > 0.0 {
            let side = if u2 < 0.5 { 1.0 } else { -1.0 };
            let (_, s, co) = ring_azimuth(c, d, psi_max, h, (2.0 * u2 - 1.0).abs().min(1.0));
            (-co, -side * s)
        } else {
            let (s, co) = (2.0 * PI * u2).sin_cos();
            (co, s)
        };
        std::array::from_fn(|k| ct * r[k] + st * (cp * t[k] + sp * b[k]))
    }

    #[inline]
    fn pdf(&self, ws: &[(usize, f64); 2], wi: V3, wo: V3, cos_pdf: f64) -> f64 {
        // The angle to the axis by atan2(|d × a|, d·a): acos loses digits near the axis, where the lobe is.
        let (d, a, jac) = if self.lobe == Input::NH {
            let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
            let len = dot(s, s).sqrt();
            if len.is_nan() || len <= 0.0 {
                return 0.0;
            }
            let sign = if s[2] < 0.0 { -1.0 / len } else { 1.0 / len };
            let h = [s[0] * sign, s[1] * sign, s[2] * sign];
            (h, [0.0, 0.0, 1.0], 4.0 * dot(wi, h).abs())
        } else {
            (wo, self.axis(wi), 1.0)
        };
        let x = [d[1] * a[2] - d[2] * a[1], d[2] * a[0] - d[0] * a[2], d[0] * a[1] - d[1] * a[0]];
        let (sin_t, cos_t) = (dot(x, x).sqrt(), dot(d, a));
        let v = sin_t.atan2(cos_t) / self.theta_max;
        let inside = (0.0..1.0).contains(&v);
        let i = ((v * EXACT_CELLS as f64) as usize).min(EXACT_CELLS - 1);
        let den = self.measure[i] * jac;
        // VR: the azimuth's density on the ring relative to uniform, 2π·max(cosθₒ, 0)/(2H) (1 on a ring wholly
        // below the horizon, whose azimuth is uniform).
        let azimuth = if self.lobe == Input::VR {
            let (_, rho, cti) = mirror_frame(wi);
            let (_, h) = ring(cos_t * cti, sin_t * rho);
            if h > 0.0 {
                PI * wo[2].max(0.0) / h
            } else {
                1.0
            }
        } else {
            1.0
        };
        let mut p = 0.0;
        for &(k, w) in ws {
            if w > 0.0 {
                p += w * match &self.nodes[k] {
                    None => cos_pdf,
                    Some(_) if !inside || den.is_nan() || den <= 0.0 => 0.0,
                    Some(dist) => dist.pdf(v) / den * azimuth,
                };
            }
        }
        p
    }
}

/// The node of `ws` that u falls in (by weight) and u rescaled within it.
#[inline]
fn pick_node(ws: &[(usize, f64)], u1: f64) -> (usize, f64) {
    let mut acc = 0.0;
    let mut pick = None;
    for &(k, w) in ws {
        if w > 0.0 {
            if u1 < acc + w {
                return (k, ((u1 - acc) / w).clamp(0.0, ONE_MINUS));
            }
            acc += w;
            pick = Some((k, ONE_MINUS));
        }
    }
    pick.unwrap_or((0, u1))
}

/// One checked wi and what the mechanism computed of it ([`Sampler::at`]).
#[derive(Clone, Copy, Debug)]
struct At {
    wi: V3,
    tab: Option<TabAt>,
    /// The exact mechanism's nodes and weights.
    exact: [(usize, f64); 2],
}

#[derive(Clone, Debug)]
enum Body {
    Cosine,
    Tabulated(Tabulated),
    Exact(Exact),
}

/// wo with density cosθ/π.
#[inline]
fn cosine_sample(u1: f64, u2: f64) -> V3 {
    let r = u1.sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    [r * c, r * s, (1.0 - u1).max(0.0).sqrt()]
}

/// A sampler of wo given wi for one formula at one parameter vector (module docs).
#[derive(Clone)]
pub struct Sampler {
    target: Target,
    cos_frac: f64,
    body: Body,
    pub report: Report,
}

impl std::fmt::Debug for Sampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sampler").field("report", &self.report).field("cosine_fraction", &self.cos_frac).finish()
    }
}

/// A direction given to the sampler as a unit vector, or the error for it.
fn unit(w: V3, what: &str) -> Result<V3, Diagnostic> {
    if !w.iter().all(|x| x.is_finite()) {
        return Err(Diagnostic::error(format!("{what} ({}, {}, {}) is not finite", w[0], w[1], w[2])).hint("give a finite direction"));
    }
    let l2 = dot(w, w);
    if l2 == 0.0 {
        return Err(Diagnostic::error(format!("{what} is the zero vector")).hint("give a non-zero direction"));
    }
    if (l2 - 1.0).abs() <= 1e-9 {
        return Ok(w);
    }
    let l = l2.sqrt();
    Ok([w[0] / l, w[1] / l, w[2] / l])
}

/// wi as the sampler takes it: finite, non-zero, normalised, above the horizon.
fn incident(wi: V3) -> Result<V3, Diagnostic> {
    let w = unit(wi, "the incident direction wi")?;
    if w[2].is_nan() || w[2] <= 0.0 {
        return Err(Diagnostic::error(format!(
            "the incident direction wi = ({}, {}, {}) is not above the horizon (wi.z ≤ 0)",
            wi[0], wi[1], wi[2]
        ))
        .hint("wi is the formula's L, a direction of the upper hemisphere (z > 0 in the local frame)"));
    }
    Ok(w)
}

impl Sampler {
    /// A sampler for a scalar formula's kernel at `params` (the full parameter vector, declaration order).
    pub fn build(kernel: &Kernel, params: &[f64], opts: &Options) -> Result<Sampler, Diagnostic> {
        Sampler::build_channels(std::slice::from_ref(kernel), params, opts)
    }

    /// A sampler for a formula's channel kernels (one, or red, green, blue: `Formula::channels`).
    pub fn build_channels(kernels: &[Kernel], params: &[f64], opts: &Options) -> Result<Sampler, Diagnostic> {
        let t0 = Instant::now();
        if !(opts.cosine_fraction > 0.0 && opts.cosine_fraction < 1.0) {
            return Err(Diagnostic::error(format!("the cosine fraction {} is not in (0, 1)", opts.cosine_fraction))
                .hint("a small fraction such as 0.05 keeps pdf > 0 wherever cosθₒ > 0"));
        }
        let lum = match kernels.len() {
            1 => vec![1.0],
            3 => LUMINANCE.to_vec(),
            n => return Err(Diagnostic::error(format!("a sampler takes 1 or 3 channel kernels, not {n}"))),
        };
        let used: InputSet = kernels.iter().map(|k| k.used_inputs()).collect();
        let target = Target { kernels: kernels.to_vec(), lum, params: params.to_vec(), used };
        let isotropic = !used.reads_directions() || kernels.iter().all(|k| turns_with_the_frame(k, params));
        let one_cosine = crate::numerics::one_lobe_cosine(used);
        let make = |body: Body, empty: Vec<(f64, f64)>, mechanism: Mechanism| Sampler {
            target: target.clone(),
            cos_frac: opts.cosine_fraction,
            body,
            report: Report { mechanism, isotropic, build: Duration::ZERO, empty_nodes: empty, candidates: vec![] },
        };
        let tabulated = |target: &Target| -> Result<Sampler, Diagnostic> {
            let (t, empty) = build_tabulated(target, isotropic)?;
            Ok(if t.nodes.iter().all(Option::is_none) {
                make(Body::Cosine, empty, Mechanism::Cosine)
            } else {
                make(Body::Tabulated(t), empty, Mechanism::Tabulated)
            })
        };
        let exact = |target: &Target, lobe: Input| -> Result<Sampler, Diagnostic> {
            Ok(match build_exact(target, lobe)? {
                Some(e) => make(Body::Exact(e), vec![], Mechanism::Exact),
                None => make(Body::Cosine, vec![], Mechanism::Cosine),
            })
        };
        let mut s = match opts.choice {
            Choice::Force(Mechanism::Cosine) => make(Body::Cosine, vec![], Mechanism::Cosine),
            Choice::Force(Mechanism::Tabulated) => tabulated(&target)?,
            Choice::Force(Mechanism::Exact) => match one_cosine {
                Some(lobe) => exact(&target, lobe)?,
                None => {
                    return Err(Diagnostic::error("the exact mechanism needs a formula of one cosine (it reads NH alone, or VR alone)")
                        .hint("use the tabulated mechanism, which takes any formula"))
                }
            },
            Choice::Auto => {
                let mut cands = vec![tabulated(&target)?];
                if let Some(lobe) = one_cosine {
                    cands.push(exact(&target, lobe)?);
                }
                cands.push(make(Body::Cosine, vec![], Mechanism::Cosine));
                let scores: Vec<f64> = cands.iter().map(Sampler::probe_efficiency).collect();
                let best = (0..cands.len()).max_by(|&a, &b| scores[a].total_cmp(&scores[b])).unwrap_or(0);
                let candidates = cands.iter().zip(&scores).map(|(c, e)| (c.report.mechanism, *e)).collect();
                let empty = cands[0].report.empty_nodes.clone();
                let mut s = cands.swap_remove(best);
                s.report.candidates = candidates;
                s.report.empty_nodes = empty;
                s
            }
        };
        s.report.build = t0.elapsed();
        Ok(s)
    }

    /// The channels of the weights (1 or 3).
    pub fn channels(&self) -> usize {
        self.target.channels()
    }

    /// The cosine part of the mixture.
    pub fn cosine_fraction(&self) -> f64 {
        self.cos_frac
    }

    /// Mean efficiency E\[w\]²/E\[w²\] over θᵢ = 0°, 30°, 60°, 85° (φᵢ = 0°), [`PROBE_SAMPLES`] each, seed fixed.
    fn probe_efficiency(&self) -> f64 {
        let incs = [0.0f64, 30.0, 60.0, 85.0];
        let mut total = 0.0;
        for (j, deg) in incs.iter().enumerate() {
            let wi = dir(deg.to_radians(), 0.0);
            let u: Vec<[f64; 2]> = (0..PROBE_SAMPLES as u64)
                .map(|i| {
                    let c = (j as u64) << 32 | i;
                    [crate::base::rng::counter_unit(0x5A3F, 2 * c), crate::base::rng::counter_unit(0x5A3F, 2 * c + 1)]
                })
                .collect();
            let Ok(s) = self.sample_many(&[wi], &u) else { return 0.0 };
            total += efficiency((0..s.pdf.len()).map(|i| s.luminance(i)));
        }
        total / incs.len() as f64
    }

    /// What the mechanism needs of one (checked) wi, computed once for every wo at that wi.
    #[inline]
    fn at(&self, wi: V3) -> At {
        match &self.body {
            Body::Tabulated(t) => At { wi, tab: Some(t.at(wi)), exact: [(0, 1.0), (0, 0.0)] },
            Body::Exact(e) => At { wi, tab: None, exact: e.at(wi) },
            Body::Cosine => At { wi, tab: None, exact: [(0, 1.0), (0, 0.0)] },
        }
    }

    /// wo for one (wi, u).
    #[inline]
    fn draw(&self, at: &At, u: [f64; 2]) -> V3 {
        let (u1, u2) = (u[0].clamp(0.0, ONE_MINUS), u[1].clamp(0.0, ONE_MINUS));
        let c = self.cos_frac;
        if u1 < c {
            return cosine_sample((u1 / c).min(ONE_MINUS), u2);
        }
        let v = ((u1 - c) / (1.0 - c)).clamp(0.0, ONE_MINUS);
        match (&self.body, &at.tab) {
            (Body::Tabulated(t), Some(ta)) => t.sample(ta, at.wi, v, u2),
            (Body::Exact(e), _) => e.sample(&at.exact, at.wi, v, u2),
            _ => cosine_sample(v, u2),
        }
    }

    /// The mixture density of wo at wi (both unit, wi checked): the one function `sample` and `pdf` share.
    #[inline(always)]
    fn density(&self, at: &At, wo: V3) -> f64 {
        let cos_pdf = wo[2].max(0.0) / PI;
        let body = match (&self.body, &at.tab) {
            (Body::Tabulated(t), Some(ta)) => t.pdf(ta, at.wi, wo, cos_pdf),
            (Body::Exact(e), _) => e.pdf(&at.exact, at.wi, wo, cos_pdf),
            _ => cos_pdf,
        };
        self.cos_frac * cos_pdf + (1.0 - self.cos_frac) * body
    }

    /// One sample per `u` (uniforms in [0, 1)²); `wi` holds one direction for all, or one per sample.
    pub fn sample_many(&self, wi: &[V3], u: &[[f64; 2]]) -> Result<Samples, Diagnostic> {
        let wis = incidents(wi, u.len())?;
        let n = u.len();
        let mut wo = Vec::with_capacity(n);
        let mut pdf = Vec::with_capacity(n);
        let one = wis.first().map(|&w| self.at(w));
        for (i, ui) in u.iter().enumerate() {
            let at = match one {
                Some(a) if wis.len() == 1 => a,
                _ => self.at(wis[i]),
            };
            let o = self.draw(&at, *ui);
            wo.push(o);
            pdf.push(self.density(&at, o));
        }
        let nch = self.channels();
        let mut vals = vec![];
        self.target.eval_inputs(n, |i| inputs_from_dirs(wis[if wis.len() == 1 { 0 } else { i }], wo[i]), &mut vals);
        let mut weight = vec![0.0; n * nch];
        for i in 0..n {
            if wo[i][2] > 0.0 && pdf[i] > 0.0 {
                // f·cosθₒ/pdf in that order: a per-sample 1/pdf factor would round subnormal weights differently.
                for c in 0..nch {
                    weight[i * nch + c] = vals[i * nch + c] * wo[i][2] / pdf[i];
                }
            }
        }
        Ok(Samples { wo, pdf, weight, channels: nch })
    }

    /// The density of each `wo` (normalised unless unit to 10⁻⁹) given `wi` (one for all, or one per `wo`).
    pub fn pdf_many(&self, wi: &[V3], wo: &[V3]) -> Result<Vec<f64>, Diagnostic> {
        let wis = incidents(wi, wo.len())?;
        let one = wis.first().map(|&w| self.at(w));
        wo.iter()
            .enumerate()
            .map(|(i, &o)| {
                let at = match one {
                    Some(a) if wis.len() == 1 => a,
                    _ => self.at(wis[i]),
                };
                Ok(self.density(&at, unit(o, "the outgoing direction wo")?))
            })
            .collect()
    }

    /// The density as a function of unit wo for one incident `wi` (checked once): what a quadrature over wo calls.
    /// wo is taken as given (unit; [`Sampler::pdf_many`] normalises).
    pub fn pdf_at(&self, wi: V3) -> Result<impl Fn(V3) -> f64 + Sync + '_, Diagnostic> {
        let at = self.at(incident(wi)?);
        Ok(move |wo: V3| self.density(&at, wo))
    }

    /// The formula's channel values f(wi, wo) (`out[i·channels + c]`), the weights' f.
    pub fn eval_many(&self, wi: &[V3], wo: &[V3]) -> Result<Vec<f64>, Diagnostic> {
        let wis = incidents(wi, wo.len())?;
        let mut out = vec![];
        self.target.eval_inputs(wo.len(), |i| inputs_from_dirs(wis[if wis.len() == 1 { 0 } else { i }], wo[i]), &mut out);
        Ok(out)
    }
}

/// Checked incident directions: one, or `n`.
fn incidents(wi: &[V3], n: usize) -> Result<Vec<V3>, Diagnostic> {
    if wi.len() != 1 && wi.len() != n {
        return Err(Diagnostic::error(format!("{} incident directions for {n} samples", wi.len())).hint("give one wi for all, or one per sample"));
    }
    wi.iter().map(|&w| incident(w)).collect()
}

/// E\[w\]²/E\[w²\] of weights (0 when every weight is 0).
pub fn efficiency(w: impl Iterator<Item = f64>) -> f64 {
    let (mut n, mut s, mut s2) = (0usize, 0.0, 0.0);
    for x in w {
        n += 1;
        s += x;
        s2 += x * x;
    }
    if s2 > 0.0 {
        s * s / (n as f64 * s2)
    } else {
        0.0
    }
}

/// [`band_edges`] of n bands and n·4π·(width of each band in sin²(θ/2)).
fn bands_and_measure(n: usize, theta: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>) {
    let bands = band_edges(n, theta);
    let measure = bands.windows(2).map(|w| n as f64 * 4.0 * PI * (w[1] - w[0])).collect();
    (bands, measure)
}

/// Every incidence node's table (module docs), and the nodes left empty.
fn build_tabulated(target: &Target, isotropic: bool) -> Result<(Tabulated, Vec<(f64, f64)>), Diagnostic> {
    let (nt, np) = if isotropic { (ISO_NODES, 1) } else { (ANISO_THETA_NODES, ANISO_PHI_NODES) };
    let thetas: Vec<f64> = (0..nt).map(|k| node_theta(k, nt)).collect();
    let mut nodes = Vec::with_capacity(nt * np);
    let mut empty = vec![];
    let mut scratch = NodeScratch::default();
    for &t in &thetas {
        let mut at_normal: Option<Option<Node>> = None;
        for p in 0..np {
            let phi = 2.0 * PI * p as f64 / np as f64;
            // At θᵢ = 0 every azimuth is the same wi: one table.
            let d = match (&at_normal, t == 0.0) {
                (Some(d), true) => d.clone(),
                _ => node_table(target, dir(t, phi), &mut scratch)?,
            };
            if t == 0.0 {
                at_normal = Some(d.clone());
            }
            if d.is_none() {
                empty.push((t, if isotropic { 0.0 } else { phi }));
            }
            nodes.push(d);
        }
    }
    let bands = band_edges(ROWS, row_theta);
    let guide = row_guide(&bands);
    Ok((Tabulated { isotropic, thetas, phis: np, nodes, bands, guide }, empty))
}

#[derive(Default)]
struct NodeScratch {
    pairs: Vec<(V3, V3)>,
    slots: Vec<usize>,
    g: Vec<f64>,
    vals: Vec<f64>,
}

/// One node's table at incidence `wi`. φₕ is measured from azimuth 0: an isotropic formula's nodes lie at
/// azimuth 0 (so this is φₕ from wi's azimuth, as [`Tabulated::at`] turns it), an anisotropic one's φₕ is
/// absolute.
fn node_table(target: &Target, wi: V3, s: &mut NodeScratch) -> Result<Option<Node>, Diagnostic> {
    let (pr, pc) = (2 * ROWS + 1, 2 * COLS + 1);
    s.pairs.clear();
    s.slots.clear();
    s.g.clear();
    s.g.resize(pr * pc, 0.0);
    let mut jacs = Vec::with_capacity(pr * pc);
    for a in 0..pr {
        let x1 = a as f64 / (2 * ROWS) as f64;
        for b in 0..pc {
            let x2 = b as f64 / (2 * COLS) as f64;
            let h = half_from(x1, x2, NO_TURN);
            let wo = reflect(wi, h);
            if wo[2] > 0.0 {
                s.pairs.push((wi, wo));
                s.slots.push(a * pc + b);
                jacs.push(4.0 * dot(wi, h) * wo[2]);
            }
        }
    }
    target.eval_pairs(&s.pairs, &mut s.vals);
    let nch = target.channels();
    for (i, &slot) in s.slots.iter().enumerate() {
        let v = &s.vals[i * nch..(i + 1) * nch];
        check_point(v, || describe_pair(s.pairs[i].0, s.pairs[i].1))?;
        s.g[slot] = target.luminance(v) * jacs[i];
    }
    // A corner's value: the largest g over the sub-grid points within half a cell of it (the columns wrap; the
    // pole's corners, one direction, share the largest), so a cell with g > 0 at one of its points has a
    // positive corner. A cell's mass: its solid angle 4π·Δ(sin²(θₕ/2))/COLS times the mean of its corners.
    let mut corners = vec![0.0; (ROWS + 1) * COLS];
    for i in 0..=ROWS {
        for j in 0..COLS {
            let mut m = 0.0f64;
            for a in (2 * i).saturating_sub(1)..=(2 * i + 1).min(2 * ROWS) {
                for db in 0..3 {
                    let b = (2 * j + 2 * COLS + db - 1) % (2 * COLS);
                    m = m.max(s.g[a * pc + b]);
                }
            }
            corners[i * COLS + j] = m;
        }
    }
    let pole = corners[..COLS].iter().fold(0.0f64, |a, &b| a.max(b));
    corners[..COLS].fill(pole);
    let bands = band_edges(ROWS, row_theta);
    let mut cells = vec![0.0; ROWS * COLS];
    for i in 0..ROWS {
        let omega = 4.0 * PI * (bands[i + 1] - bands[i]) / COLS as f64;
        for j in 0..COLS {
            let j1 = (j + 1) % COLS;
            let c = &corners;
            cells[i * COLS + j] = omega * 0.25 * (c[i * COLS + j] + c[i * COLS + j1] + c[(i + 1) * COLS + j] + c[(i + 1) * COLS + j1]);
        }
    }
    let total: f64 = cells.iter().sum();
    Ok(Dist2D::new(&cells, ROWS, COLS).map(|cells| {
        corners.iter_mut().for_each(|c| *c /= total);
        Node { cells, corners }
    }))
}

/// The exact path's table for a formula of the one input `lobe` (NH or VR); `None` when it is 0 everywhere.
fn build_exact(target: &Target, lobe: Input) -> Result<Option<Exact>, Diagnostic> {
    let theta_max = if lobe == Input::VR { PI } else { FRAC_PI_2 };
    let np = 2 * EXACT_CELLS + 1;
    let theta = |a: usize| theta_max * a as f64 / (2 * EXACT_CELLS) as f64;
    let mut vals = vec![];
    target.eval_inputs(
        np,
        |a| {
            let mut x = [0.0; N_INPUTS];
            x[lobe.index()] = theta(a).cos();
            x
        },
        &mut vals,
    );
    let nch = target.channels();
    let mut q = vec![0.0; np];
    for a in 0..np {
        let v = &vals[a * nch..(a + 1) * nch];
        let c = theta(a).cos();
        check_point(v, || format!("{} = {c:.9} (the formula's only input)", lobe.name()))?;
        q[a] = target.luminance(v);
    }
    // A cell's mass: the largest value at its ends and middle times its solid angle about the axis; for VR the
    // value at each point times the ring's mean max(cosθₒ, 0) at the node's θᵢ ([`ring`]).
    let (bands, measure) = bands_and_measure(EXACT_CELLS, |i| theta_max * i as f64 / EXACT_CELLS as f64);
    let thetas: Vec<f64> = if lobe == Input::VR { (0..ISO_NODES).map(|k| node_theta(k, ISO_NODES)).collect() } else { vec![0.0] };
    let sc: Vec<(f64, f64)> = (0..np).map(|a| theta(a).sin_cos()).collect();
    let nodes: Vec<Option<Dist1D>> = thetas
        .iter()
        .map(|&ti| {
            let (sti, cti) = ti.sin_cos();
            let g = |a: usize| {
                if lobe == Input::VR {
                    let (st, ct) = sc[a];
                    q[a] * ring(ct * cti, st * sti).1 / PI
                } else {
                    q[a]
                }
            };
            let cells: Vec<f64> = (0..EXACT_CELLS).map(|i| g(2 * i).max(g(2 * i + 1)).max(g(2 * i + 2)) * (bands[i + 1] - bands[i])).collect();
            Dist1D::new(&cells)
        })
        .collect();
    if nodes.iter().all(Option::is_none) {
        return Ok(None);
    }
    Ok(Some(Exact { lobe, theta_max, thetas, nodes, bands, measure }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_vector_map_round_trips() {
        let wi = dir(0.7, 0.3);
        let bands = band_edges(ROWS, row_theta);
        let guide = row_guide(&bands);
        for &(x1, x2) in &[(0.1, 0.2), (0.5, 0.9), (0.8, 0.45), (0.03, 0.6), (0.002, 0.01), (0.999, 0.99)] {
            let turn = (0.3f64.cos(), 0.3f64.sin());
            let h = half_from(x1, x2, turn);
            let wo = reflect(wi, h);
            let (row, a, col, b, jac) = table_coords(wi, wo, turn, &bands, &guide).unwrap();
            assert_eq!(row, (x1 * ROWS as f64) as usize, "{x1}");
            let th = FRAC_PI_2 * x1 * x1;
            let sh = (0.5 * th).sin().powi(2);
            assert!((bands[row] + a * (bands[row + 1] - bands[row]) - sh).abs() < 1e-15, "{x1}");
            assert_eq!(col, (x2 * COLS as f64) as usize);
            // φₕ of a half vector θₕ from the pole carries wi + wo's cancellation: an error ~ε/θₕ.
            assert!((col as f64 + b - x2 * COLS as f64).abs() < 1e-12f64.max(1e-14 / th), "{x2}");
            assert!((jac - 4.0 * dot(wi, h).abs()).abs() < 1e-12 * jac);
            let (ct, st) = cos_sin_of_band(sh);
            assert!((ct - th.cos()).abs() < 1e-15 && (st - th.sin()).abs() < 1e-15);
        }
    }

    #[test]
    fn small_arctangent_and_row_search_are_exact() {
        for k in 0..=1000 {
            let z = (PI / 16.0).tan() * k as f64 / 1000.0;
            assert!((atan_small(z) - z.atan()).abs() <= 4.0 * f64::EPSILON * z.atan().max(f64::MIN_POSITIVE), "{z}");
        }
        let bands = band_edges(ROWS, row_theta);
        let guide = row_guide(&bands);
        let mut rng = crate::base::rng::Rng(0x80F5);
        for _ in 0..100_000 {
            let sh = 0.5 * rng.unit().powi(4);
            let want = (bands.partition_point(|&b| b <= sh) - 1).min(ROWS - 1);
            assert_eq!(row_of(sh, &bands, &guide), want, "{sh}");
        }
        for &sh in &bands {
            let want = (bands.partition_point(|&b| b <= sh) - 1).min(ROWS - 1);
            assert_eq!(row_of(sh, &bands, &guide), want, "{sh}");
        }
    }

    #[test]
    fn the_mirror_ring_integrates_the_cosine() {
        // H against a midpoint sum of max(c + d·cosψ, 0) over ψ in [0, π], and the azimuth's inverse.
        for &(th, ti) in &[(0.1, 0.2), (1.2, 1.4), (2.0, 1.0), (0.4, 1.55), (1.7, 0.0), (3.0, 1.5)] {
            let (c, d) = (f64::cos(th) * f64::cos(ti), f64::sin(th) * f64::sin(ti));
            let (psi_max, h) = ring(c, d);
            let n = 200_000;
            let sum: f64 = (0..n).map(|k| (c + d * (PI * (k as f64 + 0.5) / n as f64).cos()).max(0.0)).sum::<f64>() * PI / n as f64;
            assert!((h - sum).abs() < 1e-8, "θ {th} θi {ti}: {h} against {sum}");
            if h > 0.0 {
                assert!(c + d * psi_max.cos() >= -1e-12);
                for t in [0.0, 0.1, 0.5, 0.9, 1.0] {
                    let (psi, sp, cp) = ring_azimuth(c, d, psi_max, h, t);
                    assert!(psi >= 0.0 && psi <= psi_max && sp == psi.sin() && cp == psi.cos());
                    assert!((c * psi + d * psi.sin() - t * h).abs() < 1e-12 * h.max(1.0), "t {t}");
                }
            }
        }
        // The frame: cosθₒ = cosθ·cosθᵢ − sinθ·sinθᵢ·cosφ about R.
        let wi = dir(1.1, 0.7);
        let ([t, b, r], rho, ct) = mirror_frame(wi);
        assert!((rho - 1.1f64.sin()).abs() < 1e-15 && (ct - 1.1f64.cos()).abs() < 1e-15);
        for (x, y, want) in [(t, t, 1.0), (b, b, 1.0), (r, r, 1.0), (t, b, 0.0), (t, r, 0.0), (b, r, 0.0)] {
            assert!((dot(x, y) - want).abs() < 1e-15);
        }
        assert!((t[2] + rho).abs() < 1e-15 && b[2] == 0.0);
    }

    #[test]
    fn columns_are_the_azimuth_sectors() {
        assert_eq!(EDGES.len(), COLS / 4 - 1);
        for (k, &(c, s)) in EDGES.iter().enumerate() {
            let a = 2.0 * PI * (k + 1) as f64 / COLS as f64;
            assert!((c - a.cos()).abs() < 4e-16 && (s - a.sin()).abs() < 4e-16, "edge {k}");
        }
        let mut rng = crate::base::rng::Rng(0xC015);
        for _ in 0..100_000 {
            let (x, y) = (2.0 * rng.unit() - 1.0, 2.0 * rng.unit() - 1.0);
            let p = (y.atan2(x) / (2.0 * PI)).rem_euclid(1.0) * COLS as f64;
            // Away from an edge (within 1e-9 of one the two may round apart), the sector atan2 names.
            let (col, pos) = column_and_position(x, y);
            if (p - p.round()).abs() > 1e-9 {
                assert_eq!(col, (p as usize) % COLS, "({x}, {y})");
                assert!((col as f64 + pos - p).abs() < 1e-13, "({x}, {y})");
            }
        }
    }

    #[test]
    fn node_thetas_start_at_the_normal_and_crowd_toward_grazing() {
        let t: Vec<f64> = (0..ISO_NODES).map(|k| node_theta(k, ISO_NODES).to_degrees()).collect();
        assert_eq!(t[0], 0.0);
        assert!((t[ISO_NODES - 1] - LAST_NODE_DEG).abs() < 1e-12);
        assert!(t[1] - t[0] > 10.0 * (t[ISO_NODES - 1] - t[ISO_NODES - 2]));
        let w = theta_weights(&[0.0, 1.0, 2.0], 1.25);
        assert_eq!(w, [(1, 0.75), (2, 0.25)]);
        assert_eq!(theta_weights(&[0.0, 1.0], 3.0)[0], (1, 1.0));
    }
}
