//! The tabulated mechanism (the module docs of [`super`]): the half-vector map and its table coordinates, the
//! incidence nodes with their weights, one node's table of corner densities and cell masses built from the
//! kernels, and sampling and the density within a node's table.

use super::dist::Dist2D;
use super::*;
use std::f64::consts::{FRAC_PI_2, PI};

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
    let (cp, sp) = super::turn(x2);
    let (c, s) = turn;
    [st * (cp * c - sp * s), st * (sp * c + cp * s), ct]
}

/// The half vector of table coordinates (x₁, x₂) (θₕ = (π/2)·x₁²) in the frame turned by `turn`.
#[inline]
fn half_from(x1: f64, x2: f64, turn: Turn) -> V3 {
    let (st, ct) = (FRAC_PI_2 * x1 * x1).sin_cos();
    half_at(ct, st, x2, turn)
}

/// The θ edges of the tabulated mechanism's rows: θₕ = (π/2)·(i/[`ROWS`])².
fn row_theta(i: usize) -> f64 {
    let x = i as f64 / ROWS as f64;
    FRAC_PI_2 * x * x
}

/// Where a half vector falls in the tables: the row among [`ROWS`] and the position in it (`a`, in [0, 1], linear
/// in sin²(θₕ/2) between the row's edges), the column among [`COLS`] and the position in it (`b`, in [0, 1],
/// linear in φₕ), and dωₒ/dωₕ = 4|wi·h| (`jac`).
#[derive(Clone, Copy, Debug)]
struct Coords {
    row: usize,
    a: f64,
    col: usize,
    b: f64,
    jac: f64,
}

/// [`Coords`] of the half vector of (wi, wo) (azimuth in the frame turned by `turn`); `None` when wo = −wi (no
/// half vector).
///
/// No trigonometry: from the unnormalised sum s = wi + wo (turned into the table's frame, sign chosen so
/// h.z ≥ 0), sin²(θₕ/2) = (1 − cosθₕ)/2 = |sₓᵧ|²/(2|s|(|s| + |s_z|)), without the cancellation of 1 − cosθₕ near
/// the normal where the lobes are; the row by [`row_of`]; the column and the angle within it by
/// [`column_and_position`].
#[inline]
fn table_coords(wi: V3, wo: V3, turn: Turn, bands: &[f64], guide: &[u8]) -> Option<Coords> {
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
    Some(Coords { row, a, col, b, jac })
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
/// guide's entry, then one row up if the next edge is ≤ sh — a guide entry holds at most one row edge (every row
/// is wider than an entry; `one_step_past_the_guide_finds_every_row`), so one comparison, without a branch,
/// finds it.
#[inline]
fn row_of(sh: f64, bands: &[f64], guide: &[u8]) -> usize {
    let row = usize::from(guide[guide_index(sh)]).min(ROWS - 2);
    row + usize::from(bands[row + 1] <= sh)
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
const EDGES: [(f64, f64); COLS / 4 - 1] = SIXTEENTHS;

/// The quadrant of (x, y) and (a, b): (x, y) turned back by the quadrant's multiple of 90°, so a > 0, b ≥ 0
/// (a = b = 0 for the zero vector, quadrant 1).
///
/// Without branches (the quadrant of a random direction is not predictable): the half-turn first, then the
/// quarter-turn, each a select.
#[inline]
fn quadrant(x: f64, y: f64) -> (usize, f64, f64) {
    // Quadrants 2 and 3 (y < 0) turn by 180° first; quadrants 1 and 3 by 90° more (1: x ≤ 0 above the axis,
    // 3: x > 0 below it).
    // y < 0, or NaN (which the comparison y ≥ 0 refuses).
    let half = y.partial_cmp(&0.0).is_none_or(|o| o.is_lt());
    let quarter = (x > 0.0) == half;
    let (x1, y1) = if half { (-x, -y) } else { (x, y) };
    let (a, b) = if quarter { (y1, -x1) } else { (x1, y1) };
    (2 * usize::from(half) + usize::from(quarter), a, b)
}

/// The tabulated mechanism: a table per incidence node.
#[derive(Clone, Debug)]
pub(super) struct Tabulated {
    pub(super) isotropic: bool,
    pub(super) thetas: Vec<f64>,
    /// φᵢ nodes (anisotropic only; one node at 0 for an isotropic formula).
    pub(super) phis: usize,
    /// Node (θ index t, φ index p) at t·phis + p; `None`: an empty table.
    pub(super) nodes: Vec<Option<Node>>,
    /// sin²(θₕ/2) at the row edges ([`band_edges`]).
    pub(super) bands: Vec<f64>,
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
pub(super) struct TabAt {
    ws: [(usize, f64); 4],
    turn: Turn,
}

impl Tabulated {
    /// The nodes wi mixes, their weights, and the frame of φₕ.
    pub(super) fn at(&self, wi: V3) -> TabAt {
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

    pub(super) fn sample(&self, at: &TabAt, wi: V3, u1: f64, u2: f64) -> V3 {
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

    /// The density of wo at wi: Σ w·(density in ωₕ) over the nodes' tables at wo's half vector, divided by the
    /// Jacobian once; empty nodes add w·cosθₒ/π.
    ///
    /// A sample's density is this function of the wo drawn, not of the half vector it was drawn at: wo holds
    /// that half vector only to its rounding (an error of about ε/θₕ near the pole), so only a density computed
    /// from wo is the one `pdf` gives for the same wo.
    #[inline]
    pub(super) fn pdf(&self, at: &TabAt, wi: V3, wo: V3, cos_pdf: f64) -> f64 {
        let tc = table_coords(wi, wo, at.turn, &self.bands, &self.guide);
        let (mut empty, mut tables) = (0.0, 0.0);
        for &(k, w) in &at.ws {
            if w > 0.0 {
                match (&self.nodes[k], tc) {
                    (None, _) => empty += w * cos_pdf,
                    (Some(d), Some(c)) if c.jac > 0.0 => tables += w * bilinear(d.corners(c.row, c.col), c.a, c.b),
                    _ => {}
                }
            }
        }
        match tc {
            Some(c) if tables > 0.0 => empty + tables / c.jac,
            _ => empty,
        }
    }
}

/// Every incidence node's table (module docs), and the nodes left empty.
pub(super) fn build_tabulated(target: &Target, isotropic: bool) -> Result<(Tabulated, Vec<(f64, f64)>), Diagnostic> {
    let (nt, np) = if isotropic { (ISO_NODES, 1) } else { (ANISO_THETA_NODES, ANISO_PHI_NODES) };
    let thetas: Vec<f64> = (0..nt).map(|k| node_theta(k, nt)).collect();
    let mut nodes = Vec::with_capacity(nt * np);
    let mut empty = vec![];
    // The sub-grid's half vectors are the same at every node (φₕ from azimuth 0): computed once.
    let (pr, pc) = (2 * ROWS + 1, 2 * COLS + 1);
    let mut scratch = NodeScratch {
        halves: (0..pr * pc).map(|k| half_from((k / pc) as f64 / (2 * ROWS) as f64, (k % pc) as f64 / (2 * COLS) as f64, NO_TURN)).collect(),
        ..NodeScratch::default()
    };
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
    /// The half vector at sub-grid point (a, b) at a·(2·[`COLS`] + 1) + b, φₕ from azimuth 0.
    halves: Vec<V3>,
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
        for b in 0..pc {
            let h = s.halves[a * pc + b];
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
            let Coords { row, a, col, b, jac } = table_coords(wi, wo, turn, &bands, &guide).unwrap();
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
    fn quadrants_match_the_branching_definition() {
        // The definition the branch-free form replaces, on the axes, signed zeros and random points.
        let want = |x: f64, y: f64| {
            if y >= 0.0 {
                if x > 0.0 { (0, x, y) } else { (1, y, -x) }
            } else if x <= 0.0 {
                (2, -x, -y)
            } else {
                (3, -y, x)
            }
        };
        let mut rng = crate::base::rng::Rng(0x0ADC);
        let mut pts = vec![];
        for x in [0.0, -0.0, 1.0, -1.0, 1e-300, -1e-300] {
            for y in [0.0, -0.0, 1.0, -1.0, 1e-300, -1e-300] {
                pts.push((x, y));
            }
        }
        pts.extend((0..10_000).map(|_| (2.0 * rng.unit() - 1.0, 2.0 * rng.unit() - 1.0)));
        for (x, y) in pts {
            let (q, a, b) = quadrant(x, y);
            let (wq, wa, wb) = want(x, y);
            assert!(q == wq && a.to_bits() == wa.to_bits() && b.to_bits() == wb.to_bits(), "({x}, {y}): {:?} against {:?}", (q, a, b), (wq, wa, wb));
        }
    }

    #[test]
    fn one_step_past_the_guide_finds_every_row() {
        // The row by search against the row by guide and one step, at every guide entry's two ends, at every band
        // edge and its neighbours, and at random values over the octaves.
        let bands = band_edges(ROWS, row_theta);
        let guide = row_guide(&bands);
        let search = |sh: f64| (bands.partition_point(|&b| b <= sh).max(1) - 1).min(ROWS - 1);
        let mut pts = vec![0.0, 0.5, 1.0];
        for g in 0..=GUIDE as u64 {
            let lo = f64::from_bits((GUIDE_BASE + g) << (52 - GUIDE_BITS));
            pts.extend([lo, lo.next_down()]);
        }
        for &b in &bands {
            pts.extend([b, b.next_up(), b.next_down()]);
        }
        let mut rng = crate::base::rng::Rng(0x6D1E);
        pts.extend((0..100_000).map(|_| 0.5 * 2f64.powf(-30.0 * rng.unit())));
        for sh in pts.into_iter().filter(|v| (0.0..=1.0).contains(v)) {
            assert_eq!(row_of(sh, &bands, &guide), search(sh), "sin²(θₕ/2) = {sh:e}");
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
