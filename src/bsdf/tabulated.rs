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

/// The half vector at polar angle θₕ and azimuth φₕ = 2πx₂ measured in the frame turned by `turn`.
#[inline]
fn half_at(th: f64, x2: f64, turn: Turn) -> V3 {
    let (st, ct) = th.sin_cos();
    let (sp, cp) = (2.0 * PI * x2).sin_cos();
    let (c, s) = turn;
    [st * (cp * c - sp * s), st * (sp * c + cp * s), ct]
}

/// The half vector of table coordinates (x₁, x₂) (θₕ = (π/2)·x₁²) in the frame turned by `turn`.
#[inline]
fn half_from(x1: f64, x2: f64, turn: Turn) -> V3 {
    half_at(FRAC_PI_2 * x1 * x1, x2, turn)
}

/// The θ edges of the tabulated mechanism's rows: θₕ = (π/2)·(i/[`ROWS`])².
fn row_theta(i: usize) -> f64 {
    let x = i as f64 / ROWS as f64;
    FRAC_PI_2 * x * x
}

/// Table coordinates of the half vector of (wi, wo) (azimuth in the frame turned by `turn`): x₁, θₕ, the column
/// of x₂ among [`COLS`], the position in that column (x₂·COLS − column, in [0, 1]), and dωₒ/dωₕ = 4|wi·h|;
/// `None` when wo = −wi (no half vector).
///
/// θₕ comes from atan2 of the unnormalised sum s = wi + wo (turned into the table's frame, sign chosen so
/// h.z ≥ 0): atan2 is scale-free. θₕ by atan2, not acos, which loses digits near the normal where the lobes
/// are. The column is counted from the quadrant and seven comparisons against the column edges
/// ([`column_of`]), the position in it from atan2 (clamped into the column where the two round apart).
#[inline]
fn table_coords(wi: V3, wo: V3, turn: Turn) -> Option<(f64, f64, usize, f64, f64)> {
    let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
    let len2 = dot(s, s);
    if len2.is_nan() || len2 <= 0.0 {
        return None;
    }
    let (c, sn) = turn;
    let sign = if s[2] < 0.0 { -1.0 } else { 1.0 };
    let (hx, hy) = (sign * (s[0] * c + s[1] * sn), sign * (s[1] * c - s[0] * sn));
    let sxy = (hx * hx + hy * hy).sqrt();
    let th = sxy.atan2(s[2].abs());
    let x1 = (th / FRAC_PI_2).sqrt();
    let jac = 4.0 * dot(wi, s).abs() / len2.sqrt();
    let col = column_of(hx, hy);
    let x2 = (hy.atan2(hx) / (2.0 * PI)).rem_euclid(1.0);
    let b = (x2 * COLS as f64 - col as f64).clamp(0.0, 1.0);
    Some((x1, th, col, b, jac))
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

/// The column of azimuth atan2(y, x) among [`COLS`] equal sectors of [0, 2π): the quadrant, then the number of
/// column edges inside it that the direction lies beyond (0 for the zero vector).
#[inline]
fn column_of(x: f64, y: f64) -> usize {
    // (a, b): (x, y) turned back by the quadrant's multiple of 90°, so a > 0, b ≥ 0.
    let (q, a, b) = if y >= 0.0 {
        if x > 0.0 { (0, x, y) } else { (1, y, -x) }
    } else if x <= 0.0 {
        (2, -x, -y)
    } else {
        (3, -y, x)
    };
    let beyond: usize = EDGES.iter().map(|&(ce, se)| usize::from(b * ce > a * se)).sum();
    q * (COLS / 4) + beyond
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
pub(super) struct Tabulated {
    pub(super) isotropic: bool,
    pub(super) thetas: Vec<f64>,
    /// φᵢ nodes (anisotropic only; one node at 0 for an isotropic formula).
    pub(super) phis: usize,
    /// Node (θ index t, φ index p) at t·phis + p; `None`: an empty table.
    pub(super) nodes: Vec<Option<Node>>,
    /// sin²(θₕ/2) at the row edges ([`band_edges`]).
    pub(super) bands: Vec<f64>,
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
        let mut acc = 0.0;
        let mut pick = None;
        for &(k, w) in &at.ws {
            if w > 0.0 {
                if u1 < acc + w {
                    pick = Some((k, ((u1 - acc) / w).clamp(0.0, ONE_MINUS)));
                    break;
                }
                acc += w;
                pick = Some((k, ONE_MINUS));
            }
        }
        let (k, u) = pick.unwrap_or((0, u1));
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
                let h = half_at(theta_of_band(s), (j as f64 + b) / COLS as f64, at.turn);
                reflect(wi, h)
            }
        }
    }

    #[inline]
    pub(super) fn pdf(&self, at: &TabAt, wi: V3, wo: V3, cos_pdf: f64) -> f64 {
        let tc = table_coords(wi, wo, at.turn);
        let mut p = 0.0;
        for &(k, w) in &at.ws {
            if w > 0.0 {
                p += w * match (&self.nodes[k], tc) {
                    (None, _) => cos_pdf,
                    (Some(d), Some((x1, th, col, b, jac))) if jac > 0.0 && x1 <= 1.0 => {
                        let row = ((x1 * ROWS as f64) as usize).min(ROWS - 1);
                        let h = (0.5 * th).sin();
                        let (s0, s1) = (self.bands[row], self.bands[row + 1]);
                        let a = ((h * h - s0) / (s1 - s0)).clamp(0.0, 1.0);
                        bilinear(d.corners(row, col), a, b) / jac
                    }
                    _ => 0.0,
                };
            }
        }
        p
    }
}

/// Every incidence node's table (module docs), and the nodes left empty.
pub(super) fn build_tabulated(target: &Target, isotropic: bool) -> Result<(Tabulated, Vec<(f64, f64)>), Diagnostic> {
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
    Ok((Tabulated { isotropic, thetas, phis: np, nodes, bands }, empty))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_vector_map_round_trips() {
        let wi = dir(0.7, 0.3);
        for &(x1, x2) in &[(0.1, 0.2), (0.5, 0.9), (0.8, 0.45), (0.03, 0.6)] {
            let turn = (0.3f64.cos(), 0.3f64.sin());
            let h = half_from(x1, x2, turn);
            let wo = reflect(wi, h);
            let (y1, th, col, b, jac) = table_coords(wi, wo, turn).unwrap();
            assert!((x1 - y1).abs() < 1e-12, "{x1} → {y1}");
            assert!((th - FRAC_PI_2 * x1 * x1).abs() < 1e-12);
            assert_eq!(col, (x2 * COLS as f64) as usize);
            assert!((col as f64 + b - x2 * COLS as f64).abs() < 1e-9);
            assert!((jac - 4.0 * dot(wi, h).abs()).abs() < 1e-12 * jac);
            let s = band_edges(1, |_| FRAC_PI_2 * x1 * x1)[0];
            assert!((theta_of_band(s) - FRAC_PI_2 * x1 * x1).abs() < 1e-15);
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
            if (p - p.round()).abs() > 1e-9 {
                assert_eq!(column_of(x, y), (p as usize) % COLS, "({x}, {y})");
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
