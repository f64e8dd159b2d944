//! Validation of a sampler against its own pdf, as Mitsuba 3's `chi2.py` (`ChiSquareTest` over a
//! `SphericalDomain`) does it: a histogram of the sampled directions over the sphere in (φ, cosθ) cells — 2·res
//! columns in φ ∈ [−π, π) by res rows in cosθ ∈ [−1, 1], cells of equal solid angle — against the pdf integrated
//! over each cell; cells expecting fewer than 5 samples pooled into one; Pearson's χ² with (cells − 1) degrees of
//! freedom; the p-value from the regularised upper incomplete gamma function [`gamma_q`]; the hypothesis "the
//! samples follow the pdf" rejected below the significance level, α = 0.01 Šidák-corrected over the tests run
//! ([`sidak`]).
//!
//! The pdf is integrated per cell in (φ, θ) (the integrand pdf·sinθ, so cells near the poles, where a sharp lobe
//! at the normal sits, are resolved in angle rather than in cosθ) by an adaptive midpoint rule: a 4 × 4 estimate
//! sets the cell's tolerance, then each cell starts from 16 × 16 rectangles (64 × 64 in busy cells; [`start_grid`]
//! says why); a rectangle whose one-point and four-point estimates differ by more than its share of the cell's
//! tolerance is split in four, to depth [`MAX_DEPTH`]. The tolerance is a tenth of the sampling noise the cell's
//! count has (0.1·√(expected count)): the quadrature error then moves χ² by ~1 % of its spread. The
//! samplers' pdfs are piecewise smooth with jumps along table cell edges, which the splitting follows. A cell that
//! received samples but integrates to 0 is integrated again on a dense grid ([`resolve_empty_cells`]) before the
//! test calls it a failure.

use crate::frame::V3;
use std::f64::consts::PI;

/// Deepest split of a quadrature rectangle.
pub const MAX_DEPTH: u32 = 9;
/// Cells expecting fewer samples than this are pooled.
pub const MIN_EXPECTED: f64 = 5.0;

/// The outcome of one test.
#[derive(Clone, Debug, PartialEq)]
pub struct Chi2 {
    pub statistic: f64,
    pub dof: usize,
    pub p_value: f64,
    /// Cells pooled for expecting fewer than [`MIN_EXPECTED`] samples.
    pub pooled: usize,
    /// The integrated pdf over the whole sphere (1 for a normalised density).
    pub mass: f64,
    /// Why the test failed outright (samples in a cell the pdf gives no mass), if it did.
    pub failure: Option<String>,
}

impl Chi2 {
    /// Whether the samples pass at significance `alpha` (already corrected for the number of tests).
    pub fn passes(&self, alpha: f64) -> bool {
        self.failure.is_none() && self.p_value >= alpha
    }
}

/// The per-test level that keeps the family-wise level at `alpha` over `tests` independent tests:
/// 1 − (1 − α)^(1/tests).
pub fn sidak(alpha: f64, tests: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / tests.max(1) as f64)
}

/// The cell of direction `w` in the (φ, cosθ) grid of `res` rows and 2·res columns, row-major.
pub fn cell_of(w: V3, res: usize) -> usize {
    let cols = 2 * res;
    let phi = w[1].atan2(w[0]);
    let c = (((phi + PI) / (2.0 * PI) * cols as f64) as usize).min(cols - 1);
    let r = (((w[2].clamp(-1.0, 1.0) + 1.0) * 0.5 * res as f64) as usize).min(res - 1);
    r * cols + c
}

/// Counts of `wo` per cell.
pub fn histogram(wo: &[V3], res: usize) -> Vec<f64> {
    let mut h = vec![0.0; 2 * res * res];
    for &w in wo {
        h[cell_of(w, res)] += 1.0;
    }
    h
}

/// Each cell's probability under `pdf` (a density over solid angle), to a tolerance set by `samples`.
pub fn cell_probabilities(pdf: &(dyn Fn(V3) -> f64 + Sync), res: usize, samples: usize) -> Vec<f64> {
    use rayon::prelude::*;
    let cols = 2 * res;
    let n = samples.max(1) as f64;
    (0..res * cols)
        .into_par_iter()
        .map(|cell| {
            let (p0, p1, t0, t1) = cell_bounds(cell, res);
            let f = |p: f64, t: f64| integrand(pdf, p, t);
            let k = 4;
            let (dp, dt) = ((p1 - p0) / k as f64, (t1 - t0) / k as f64);
            let mut coarse = 0.0;
            for a in 0..k {
                for b in 0..k {
                    coarse += f(p0 + (a as f64 + 0.5) * dp, t0 + (b as f64 + 0.5) * dt) * dp * dt;
                }
            }
            let tol = 0.1 * (coarse * n).max(1.0).sqrt() / n;
            let k = start_grid(coarse * n);
            let (dp, dt) = ((p1 - p0) / k as f64, (t1 - t0) / k as f64);
            let mut sum = 0.0;
            for a in 0..k {
                for b in 0..k {
                    let pa = p0 + a as f64 * dp;
                    let tb = t0 + b as f64 * dt;
                    sum += adapt(&f, pa, pa + dp, tb, tb + dt, tol / (k * k) as f64, MAX_DEPTH);
                }
            }
            sum
        })
        .collect()
}

/// Rectangles per side the adaptive rule starts from in a cell expecting `expected` samples: 16, and 64 from
/// 2048 samples.
///
/// The rule's error estimate (one point against four) cannot see a feature both estimates miss, and a tabulated
/// sampler's pdf has thin ones: the table's last row over a lobe with a hard edge (max over the cell, so the row
/// reaches past the edge) is a ring a fraction of a degree wide at the lobe's density, and below the horizon at
/// grazing incidence the table cells that straddle it crowd toward −wi (dωₒ = 4|wi·h| dωₕ vanishes there).
/// From 4 × 4 rectangles the rule put 9 samples where 442 were due on such a ring (Quadratic, n = 707, θᵢ = 30°:
/// χ² p = 1e-37 on a sampler a plain 16 × 16 grid per cell finds right, 5052 on 5050 degrees of freedom) and
/// lost 0.2 % of the mass below the horizon at θᵢ = 85°. A busy cell needs the precision its count has
/// (0.1·√e of e): 64 × 64 there.
fn start_grid(expected: f64) -> usize {
    if expected >= 2048.0 {
        64
    } else {
        16
    }
}

/// The (φ, θ) bounds (p0, p1, t0, t1) of a cell of the grid of `res` rows.
fn cell_bounds(cell: usize, res: usize) -> (f64, f64, f64, f64) {
    let cols = 2 * res;
    let (r, c) = (cell / cols, cell % cols);
    let (z0, z1) = (-1.0 + 2.0 * r as f64 / res as f64, -1.0 + 2.0 * (r + 1) as f64 / res as f64);
    // θ decreases as z grows.
    let (t0, t1) = (z1.clamp(-1.0, 1.0).acos(), z0.clamp(-1.0, 1.0).acos());
    (-PI + 2.0 * PI * c as f64 / cols as f64, -PI + 2.0 * PI * (c + 1) as f64 / cols as f64, t0, t1)
}

/// pdf·sinθ at (φ, θ): the density over the cell's (φ, θ) rectangle.
#[inline]
fn integrand(pdf: &(dyn Fn(V3) -> f64 + Sync), p: f64, t: f64) -> f64 {
    let (st, ct) = t.sin_cos();
    let (sp, cp) = p.sin_cos();
    pdf([st * cp, st * sp, ct]) * st
}

/// Points per side of the dense grid of [`resolve_empty_cells`].
pub const DENSE: usize = 256;

/// Cells that received samples but whose probability came out 0: integrated again by the midpoint rule on a
/// [`DENSE`] × [`DENSE`] grid. The adaptive rule starts from 16 × 16 points per cell and splits only where they
/// differ, so a density whose support covers a thin sliver of a cell between those points — a tabulated
/// sampler's table cell straddling the horizon sends a few directions just below it — integrates to 0 there,
/// and one sample in it would fail the test outright. A cell the dense grid also finds empty stays 0 (and
/// fails). Only the cells' probabilities are recomputed, from the pdf alone; the counts choose which.
pub fn resolve_empty_cells(pdf: &(dyn Fn(V3) -> f64 + Sync), res: usize, observed: &[f64], probabilities: &mut [f64]) {
    use rayon::prelude::*;
    let cells: Vec<usize> = (0..probabilities.len()).filter(|&i| observed[i] > 0.0 && (probabilities[i].is_nan() || probabilities[i] <= 0.0)).collect();
    let found: Vec<(usize, f64)> = cells
        .into_par_iter()
        .map(|cell| {
            let (p0, p1, t0, t1) = cell_bounds(cell, res);
            let (dp, dt) = ((p1 - p0) / DENSE as f64, (t1 - t0) / DENSE as f64);
            let mut sum = 0.0;
            for a in 0..DENSE {
                for b in 0..DENSE {
                    sum += integrand(pdf, p0 + (a as f64 + 0.5) * dp, t0 + (b as f64 + 0.5) * dt);
                }
            }
            (cell, sum * dp * dt)
        })
        .collect();
    for (cell, p) in found {
        probabilities[cell] = p;
    }
}

/// ∫∫ f over [p0, p1] × [t0, t1] by the adaptive midpoint rule (module docs).
fn adapt(f: &impl Fn(f64, f64) -> f64, p0: f64, p1: f64, t0: f64, t1: f64, tol: f64, depth: u32) -> f64 {
    let (pm, tm) = (0.5 * (p0 + p1), 0.5 * (t0 + t1));
    let area = (p1 - p0) * (t1 - t0);
    let one = f(pm, tm) * area;
    let (qp, qt) = (0.25 * (p1 - p0), 0.25 * (t1 - t0));
    let four = (f(pm - qp, tm - qt) + f(pm + qp, tm - qt) + f(pm - qp, tm + qt) + f(pm + qp, tm + qt)) * 0.25 * area;
    if depth == 0 || (four - one).abs() <= tol {
        // Richardson: the midpoint rule's error falls by 4 per halving where f is smooth.
        return four + (four - one) / 3.0;
    }
    let t = tol * 0.5;
    adapt(f, p0, pm, t0, tm, t, depth - 1) + adapt(f, pm, p1, t0, tm, t, depth - 1) + adapt(f, p0, pm, tm, t1, t, depth - 1) + adapt(f, pm, p1, tm, t1, t, depth - 1)
}

/// Pearson's χ² of `observed` counts against `probabilities`·`samples`, cells expecting fewer than
/// [`MIN_EXPECTED`] pooled (Mitsuba's rule: sorted by expectation, pooled from the smallest).
pub fn chi2(observed: &[f64], probabilities: &[f64], samples: usize) -> Chi2 {
    let n = samples as f64;
    let mass: f64 = probabilities.iter().sum();
    let mut cells: Vec<(f64, f64)> = observed.iter().zip(probabilities).map(|(&o, &p)| (o, p * n)).collect();
    cells.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (mut stat, mut dof, mut pooled) = (0.0, 0usize, 0usize);
    let (mut pool_obs, mut pool_exp) = (0.0, 0.0);
    let mut failure = None;
    for &(o, e) in &cells {
        if e <= 0.0 && o > 0.0 && failure.is_none() {
            failure = Some(format!("{o} samples fell in a cell where the pdf integrates to {e}"));
        }
        if e < MIN_EXPECTED {
            pool_obs += o;
            pool_exp += e;
            pooled += 1;
        } else {
            stat += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_exp > 0.0 {
        stat += (pool_obs - pool_exp) * (pool_obs - pool_exp) / pool_exp;
        dof += 1;
    }
    let dof = dof.saturating_sub(1);
    let p_value = if dof == 0 { 1.0 } else { gamma_q(0.5 * dof as f64, 0.5 * stat) };
    Chi2 { statistic: stat, dof, p_value, pooled, mass, failure }
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, 9 terms; relative error ~1e-15).
pub fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x)Γ(1 − x) = π / sin(πx).
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// The regularised upper incomplete gamma function Q(a, x) = Γ(a, x)/Γ(a) for a > 0, x ≥ 0: the series for
/// x < a + 1, the continued fraction (modified Lentz) otherwise (Numerical Recipes §6.2). NaN outside the domain.
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if a.is_nan() || a <= 0.0 || x.is_nan() || x < 0.0 {
        return f64::NAN;
    }
    if x == 0.0 {
        return 1.0;
    }
    if x == f64::INFINITY {
        return 0.0;
    }
    let lead = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del, mut sum) = (a, 1.0 / a, 1.0 / a);
        for _ in 0..100_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * lead).max(0.0)
    } else {
        const TINY: f64 = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / TINY;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..100_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < TINY {
                d = TINY;
            }
            c = b + an / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (lead * h).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q(k, x) for integer k by its finite sum e^(−x)·Σ_{j<k} x^j/j!, in logs (an independent formula).
    fn q_integer(k: usize, x: f64) -> f64 {
        let mut log_fact = 0.0;
        let mut s = 0.0;
        for j in 0..k {
            if j > 0 {
                log_fact += (j as f64).ln();
            }
            s += (-x + j as f64 * x.ln() - log_fact).exp();
        }
        s
    }

    #[test]
    fn gamma_q_against_known_values() {
        // Q(1/2, x) = erfc(√x): erfc(0.5), erfc(1), erfc(2).
        for (x, want) in [(0.25, 0.479_500_122_186_953_5), (1.0, 0.157_299_207_050_285_13), (4.0, 0.004_677_734_981_047_266)] {
            let q = gamma_q(0.5, x);
            assert!((q - want).abs() < 1e-13 * want.max(1e-300) + 1e-15, "Q(0.5, {x}) = {q}, want {want}");
        }
        // Q(1, x) = e^(−x).
        for x in [0.1, 1.0, 7.5, 40.0] {
            assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-14 * (-x).exp().max(1e-300));
        }
        // The χ² quantile table: P(χ²₁₀ > 23.2093) = 0.01, P(χ²₁ > 3.84146) = 0.05.
        assert!((gamma_q(5.0, 23.209_251 / 2.0) - 0.01).abs() < 1e-7);
        assert!((gamma_q(0.5, 3.841_459 / 2.0) - 0.05).abs() < 1e-7);
        // Integer a against the finite sum, small and large (the dof of a 101 × 202 histogram).
        for (k, x) in [(3, 0.5), (3, 9.0), (40, 35.0), (40, 60.0), (5000, 4900.0), (5000, 5100.0), (10_000, 10_300.0)] {
            let (q, want) = (gamma_q(k as f64, x), q_integer(k, x));
            assert!((q - want).abs() < 1e-9 * want.max(1e-12), "Q({k}, {x}) = {q}, want {want}");
        }
        assert_eq!(gamma_q(2.0, 0.0), 1.0);
        assert!(gamma_q(-1.0, 1.0).is_nan());
    }

    #[test]
    fn ln_gamma_matches_factorials() {
        let mut f = 1.0f64;
        for n in 1..30 {
            f *= n as f64;
            assert!((ln_gamma(n as f64 + 1.0) - f.ln()).abs() < 1e-12 * f.ln().max(1.0));
        }
        assert!((ln_gamma(0.5) - PI.sqrt().ln()).abs() < 1e-14);
    }

    #[test]
    fn sidak_level() {
        assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
        let a = sidak(0.01, 100);
        assert!((1.0 - (1.0 - a).powi(100) - 0.01).abs() < 1e-12);
    }

    /// Uniform sphere samples against the uniform density pass; against a density tilted toward +z they fail.
    #[test]
    fn the_test_accepts_a_right_pdf_and_rejects_a_wrong_one() {
        let n = 200_000;
        let wo: Vec<V3> = (0..n as u64)
            .map(|i| {
                let (u1, u2) = (crate::base::rng::counter_unit(3, 2 * i), crate::base::rng::counter_unit(3, 2 * i + 1));
                let z = 1.0 - 2.0 * u1;
                let r = (1.0 - z * z).max(0.0).sqrt();
                [r * (2.0 * PI * u2).cos(), r * (2.0 * PI * u2).sin(), z]
            })
            .collect();
        let h = histogram(&wo, 21);
        let right = chi2(&h, &cell_probabilities(&|_| 1.0 / (4.0 * PI), 21, n), n);
        assert!((right.mass - 1.0).abs() < 1e-5, "{right:?}");
        assert!(right.passes(0.01), "{right:?}");
        let wrong = chi2(&h, &cell_probabilities(&|w: V3| (1.0 + 0.2 * w[2]) / (4.0 * PI), 21, n), n);
        assert!(!wrong.passes(1e-6), "{wrong:?}");
        // Samples where the pdf has no mass: an outright failure.
        let upper = |w: V3| if w[2] > 0.0 { 1.0 / (2.0 * PI) } else { 0.0 };
        let mut probs = cell_probabilities(&upper, 21, n);
        resolve_empty_cells(&upper, 21, &h, &mut probs);
        let half = chi2(&h, &probs, n);
        assert!(half.failure.is_some(), "{half:?}");
    }

    /// A density on a thin strip of one cell, between the adaptive rule's starting points: the rule finds 0 there,
    /// the dense grid finds the strip's mass, and a cell with no density stays 0.
    #[test]
    fn empty_cells_with_samples_are_integrated_densely() {
        let res = 21;
        let (p0, p1, t0, t1) = cell_bounds(5 * 42 + 7, res);
        // θ in the strip [t0 + 0.05·(t1 − t0), t0 + 0.075·(t1 − t0)]: between the rows the adaptive rule evaluates
        // first (16 starting rectangles, each at its centre and its quarter points: 3/64, 5/64).
        let (s0, s1) = (t0 + 0.05 * (t1 - t0), t0 + 0.075 * (t1 - t0));
        let strip = move |w: V3| {
            let (t, p) = (w[2].clamp(-1.0, 1.0).acos(), w[1].atan2(w[0]));
            if t > s0 && t < s1 && p > p0 && p < p1 { 1.0 } else { 0.0 }
        };
        let mut probs = cell_probabilities(&strip, res, 1000);
        assert_eq!(probs[5 * 42 + 7], 0.0);
        let mut observed = vec![0.0; probs.len()];
        observed[5 * 42 + 7] = 1.0;
        observed[3] = 1.0;
        resolve_empty_cells(&strip, res, &observed, &mut probs);
        let want = (p1 - p0) * (s0.cos() - s1.cos());
        // The strip spans 6.4 of the dense grid's 256 rows: the midpoint rule sees 6.
        assert!((probs[5 * 42 + 7] - want).abs() < 0.1 * want, "{} vs {want}", probs[5 * 42 + 7]);
        assert_eq!(probs[3], 0.0);
    }
}
