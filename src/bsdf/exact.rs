//! The exact mechanism for a formula of one cosine (the module docs of [`super`]): a 1-D table over the lobe
//! angle θ about the lobe axis (N for NH; for VR, R with one table per incidence node, its cells weighted by the
//! ring's mean max(cosθₒ, 0), and the azimuth about R drawn for the actual wi), θ uniform in sin²(θ/2) within a
//! cell.

use super::dist::Dist1D;
use super::*;
use std::f64::consts::{FRAC_PI_2, PI};

/// The exact mechanism: a 1-D table in the lobe angle θ about the lobe axis per incidence node.
///
/// NH: one table of lum(f(cos θₕ)) (f alone; the half vector's map and cosθₒ are not in it). VR: one table per
/// incidence node θₖ (the tabulated mechanism's isotropic nodes) of lum(f(cos θ))·c̄(θ, θₖ), where c̄ is the mean
/// of max(cosθₒ, 0) over the ring of directions at angle θ from R ([`ring`]); within the ring the azimuth about R
/// is drawn with density ∝ max(cosθₒ, 0) for the actual wi, so the lobe is sampled with the cosine and without
/// the part the horizon cuts.
#[derive(Clone, Debug)]
pub(super) struct Exact {
    pub(super) lobe: Input,
    pub(super) theta_max: f64,
    /// θᵢ of the incidence nodes (one node at 0 for NH).
    pub(super) thetas: Vec<f64>,
    /// Each node's table (`None`: the lobe is 0 wherever that node's rings reach above the horizon).
    pub(super) nodes: Vec<Option<Dist1D>>,
    /// sin²(θ/2) at the cell edges ([`band_edges`]): within a cell θ is drawn uniform in this (uniform in solid
    /// angle about the axis), so the density in solid angle is constant over each ring of a cell and bounded.
    pub(super) bands: Vec<f64>,
    /// [`EXACT_CELLS`]·4π·(bands\[i + 1\] − bands\[i\]): a cell density (∫ over θ/θmax = 1) over this is the
    /// density in solid angle about the axis (before the azimuth's weighting, for VR).
    pub(super) measure: Vec<f64>,
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

/// ψ in [0, ψmax] with c·ψ + d·sinψ = t·H ([`ring`]; t in [0, 1]), and (sinψ, cosψ): Halley's method from
/// ψ = t·ψmax, kept inside a shrinking bracket (bisection where a step would leave it); c + d·cosψ ≥ 0 on
/// [0, ψmax], so the left side increases. Halley's error goes as K·e³, so once K·step³ is at the rounding level
/// that step is taken without another evaluation, (sinψ, cosψ) turned by it: usually two evaluations where
/// Newton's method needed three or four and one more to see it had converged.
#[inline]
fn ring_azimuth(c: f64, d: f64, psi_max: f64, h: f64, t: f64) -> (f64, f64, f64) {
    let goal = t * h;
    let (mut lo, mut hi) = (0.0, psi_max);
    let mut psi = t * psi_max;
    for _ in 0..RING_ITERATIONS {
        let (co, s) = turn(psi * FRAC_1_2PI);
        let g = c * psi + d * s - goal;
        let slope = c + d * co;
        if g < 0.0 {
            lo = psi;
        } else {
            hi = psi;
        }
        // g'' = −d·sinψ: Halley's step g·g'/(g'² − g·g''/2).
        let step = 2.0 * g * slope / (2.0 * slope * slope + g * d * s);
        let next = psi - step;
        let inside = slope > 0.0 && next >= lo && next <= hi;
        // Halley's error after this step, K·|step|³ with K = |g‴/(6g′) − (g″/(2g′))²| (both sides times g′²: no
        // division), at most an ulp; or a step at the rounding level (near the ring's cut, where g′ → 0 and the
        // convergence is slow).
        let k2 = (d * co * slope / 6.0 + 0.25 * (d * s) * (d * s)).abs();
        let a = step.abs();
        let done = (a <= 1e-5 * (1.0 + psi) && k2 * a * a * a <= 1e-16 * (1.0 + psi) * slope * slope) || a <= 1e-15 * (1.0 + psi);
        if inside && done {
            // sin and cos of the step to its third and second powers: their remainders, below 1e-26, vanish.
            let (cs, ss) = (1.0 - 0.5 * step * step, step * (1.0 - step * step / 6.0));
            return (next, s * cs - co * ss, co * cs + s * ss);
        }
        psi = if inside { next } else { 0.5 * (lo + hi) };
    }
    let (co, s) = turn(psi * FRAC_1_2PI);
    (psi, s, co)
}

/// The most steps of [`ring_azimuth`] (bisection alone halves the bracket 64 times: below an ulp of π).
const RING_ITERATIONS: usize = 64;

/// 1/(2π): an angle in turns.
const FRAC_1_2PI: f64 = 0.5 * std::f64::consts::FRAC_1_PI;

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

impl Exact {
    #[inline]
    pub(super) fn axis(&self, wi: V3) -> V3 {
        if self.lobe == Input::VR {
            [-wi[0], -wi[1], wi[2]]
        } else {
            [0.0, 0.0, 1.0]
        }
    }

    /// The nodes wi mixes and their weights.
    #[inline]
    pub(super) fn at(&self, wi: V3) -> [(usize, f64); 2] {
        if self.thetas.len() == 1 {
            return [(0, 1.0), (0, 0.0)];
        }
        theta_weights(&self.thetas, wi[2].clamp(-1.0, 1.0).acos())
    }

    pub(super) fn sample(&self, ws: &[(usize, f64); 2], wi: V3, u1: f64, u2: f64) -> V3 {
        let (k, u) = pick_node(ws, u1);
        let Some(dist) = &self.nodes[k] else { return cosine_sample(u, u2) };
        let (i, f) = dist.sample_cell(u);
        let s = self.bands[i] + f * (self.bands[i + 1] - self.bands[i]);
        let (ct, st) = cos_sin_of_band(s);
        if self.lobe == Input::NH {
            let (cp, sp) = turn(u2);
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
            turn(u2)
        };
        std::array::from_fn(|k| ct * r[k] + st * (cp * t[k] + sp * b[k]))
    }

    /// The density of wo at wi (a sample's too: computed from the wo drawn, as the tabulated mechanism's).
    #[inline]
    pub(super) fn pdf(&self, ws: &[(usize, f64); 2], wi: V3, wo: V3, cos_pdf: f64) -> f64 {
        // wo's cell in θ about the axis, the cell's measure times dωₒ/dω about the axis (4|wi·h| for NH, 1 for VR),
        // and (VR) the azimuth's density on the ring relative to uniform; `None` outside the tables (beyond θmax,
        // or no half vector).
        let at = || -> Option<(usize, f64, f64)> {
            // The angle to the axis by atan2(|d × a|, d·a): acos loses digits near the axis, where the lobe is.
            let (d, a, jac) = if self.lobe == Input::NH {
                let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
                let len = dot(s, s).sqrt();
                if len.is_nan() || len <= 0.0 {
                    return None;
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
            if !(0.0..1.0).contains(&v) {
                return None;
            }
            let cell = ((v * EXACT_CELLS as f64) as usize).min(EXACT_CELLS - 1);
            // VR: 2π·max(cosθₒ, 0)/(2H) (1 on a ring wholly below the horizon, whose azimuth is uniform).
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
            Some((cell, self.measure[cell] * jac, azimuth))
        };
        let loc = at();
        let mut p = 0.0;
        for &(k, w) in ws {
            if w > 0.0 {
                p += w * match (&self.nodes[k], loc) {
                    (None, _) => cos_pdf,
                    (Some(dist), Some((cell, den, azimuth))) if den > 0.0 => dist.cell_pdf(cell) / den * azimuth,
                    _ => 0.0,
                };
            }
        }
        p
    }
}

/// [`band_edges`] of n bands and n·4π·(width of each band in sin²(θ/2)).
fn bands_and_measure(n: usize, theta: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>) {
    let bands = band_edges(n, theta);
    let measure = bands.windows(2).map(|w| n as f64 * 4.0 * PI * (w[1] - w[0])).collect();
    (bands, measure)
}

/// The exact path's table for a formula of the one input `lobe` (NH or VR); `None` when it is 0 everywhere.
pub(super) fn build_exact(target: &Target, lobe: Input) -> Result<Option<Exact>, Diagnostic> {
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
                    assert!(psi >= 0.0 && psi <= psi_max && (sp - psi.sin()).abs() < 1e-15 && (cp - psi.cos()).abs() < 1e-15);
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
}
