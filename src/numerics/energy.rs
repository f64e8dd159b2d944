//! Energy: the papers' normalisation coefficient (lobe mode) and the real hemispherical-directional albedo
//! with a reciprocity check (full mode).
//!
//! Lobe mode. `coef = 1 / (2π·Int)`, `Int = ∫₀^{π/2} max(f(cos θ), 0) cos θ sin θ dθ`. With `c = cos θ` this is
//! `Int = ∫₀¹ max(f(c), 0)·c dc` — integrating in `c` turns the n = 1000 spike at θ = 0 into a smooth
//! boundary layer at c = 1 of width ~1/n, which a geometric ladder of breakpoints 1 − 2^−k (k = 1..24)
//! resolves. Kinks where a lobe is clamped to zero are located first (a scan of 83 points — 65 uniform plus
//! the ladder — then bisection to 1 ulp) and become breakpoints too, so adaptive GK15 (see
//! [`quad`](super::quad)) meets a 1e-11 relative tolerance in typically 400–1500 evaluations. Inputs follow the lobe convention of the [module
//! docs](super).
//!
//! Full mode. `ρ(θᵢ) = ∫_{H²} f(L, V) (N·V) dω_V` with N = +z, L at θᵢ in the xz-plane, V over the upper
//! hemisphere. V is parametrised around the mirror direction R (α = angle from R, φ = azimuth about R), where
//! every lobe of the catalogue peaks; the horizon N·V = 0 becomes an analytic cut φ*(α), and the problem's
//! mirror symmetry (y → −y) halves the azimuth range. Nested adaptive GK15 in α (with a ladder near α = 0)
//! and φ. Reciprocity compares f(L, V) with f(V, L) on a direction grid.
//!
//! Anisotropy. The mirror symmetry holds for every cosine formula (cosines do not change when the frame turns
//! about N), but not for a formula that reads direction components: its albedo depends on the azimuth φᵢ of L
//! as well. [`full_energy_for`] therefore integrates such formulas over the whole azimuth circle about R (no
//! halving), for L at every φᵢ of [`AZIMUTHS_DEG`] (the frame of the integration turned about N), and
//! reports ρ(θᵢ) = max over φᵢ, the maximum over both angles and where it is; reciprocity is checked with L at
//! those azimuths too. That costs ~48× the isotropic evaluations (24 azimuths, each integral over twice the
//! azimuth range) — unless the formula's values turn with the frame about N ([`turns_with_the_frame`], tested
//! at 4096 random pairs and angles: a GGX written with a half vector), when one azimuth stands for all (~2×).
//!
//! Cost: see the module docs of [`numerics`](super) (evaluation counts); measured times in BENCHMARKS.md
//! (`benches/energy.rs` reproduces them).

use crate::base::cancel::Cancel;
use super::quad::{integrate, integrate_with};
use super::{dir, Diagnostic, V3};
use crate::base::json::{self, Named};
use crate::frame::{inputs_from_dirs, lobe_inputs};
use crate::ir::Input;
use crate::backend::Evaluator;
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, PI};

/// The lobe integral with what it took.
#[derive(Clone, Debug, PartialEq)]
pub struct LobeIntegral {
    /// `∫₀¹ max(f(c), 0)·c dc`.
    pub integral: f64,
    /// Estimated absolute error.
    pub error: f64,
    pub evals: usize,
    /// Cosines where the lobe switches between zero and clearly positive values (its cut-off), ascending;
    /// underflow to zero is not listed.
    pub kinks: Vec<f64>,
    /// The formula is NaN for c ∈ [0, `.0`] (0/0 or ∞·0 at the endpoint, e.g. Beckmann's exp(−1/c²)/c⁴ at
    /// c = 0): that piece is skipped, taking the limit from the right; `.1` bounds what it could have
    /// contributed (|f| at the edge times the piece's ∫c dc), checked to be below the tolerance.
    pub skipped: Option<(f64, f64)>,
}

impl LobeIntegral {
    /// `1 / (2π·Int)`.
    pub fn coef(&self) -> f64 {
        1.0 / (2.0 * PI * self.integral)
    }
}

const REL_TOL: f64 = 1e-11;
/// Widest NaN piece at c = 0 the lobe integral skips (as a limit) rather than refuses.
const SKIP_MAX: f64 = 1e-6;

fn describe(lobe: Input, c: f64) -> String {
    format!("{} = {c} (θ = {:.4}°)", lobe.name(), c.clamp(-1.0, 1.0).acos().to_degrees())
}

/// `∫₀¹ max(f(c), 0)·c dc` under the lobe convention, with clear errors for NaN, an infinity at the normal, a
/// non-convergent (non-integrable) lobe, and a lobe that is zero everywhere.
pub fn lobe_integral(ev: &dyn Evaluator, params: &[f64], lobe: Input) -> Result<LobeIntegral, Diagnostic> {
    if let Some((i, v)) = params.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Diagnostic::error(format!("parameter #{i} is {v}; parameters must be finite")));
    }
    let f = |c: f64| ev.eval(&lobe_inputs(c, lobe), params);
    let at_normal = f(1.0);
    if at_normal.is_infinite() {
        return Err(Diagnostic::error(format!("the formula is infinite at the normal ({}): the lobe cannot be normalised", describe(lobe, 1.0)))
            .hint("a BRDF lobe must be finite at its peak; check for a division by (1 − c) or similar"));
    }
    // Scan for NaN and for the switches between zero and positive.
    let mut xs: Vec<f64> = (0..=64).map(|i| i as f64 / 64.0).collect();
    xs.extend((1..=24).map(|k| 1.0 - 2f64.powi(-k)));
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let ys: Vec<f64> = xs.iter().map(|&c| f(c)).collect();
    let mut evals = xs.len() + 1;
    // A NaN piece [0, c*] at the endpoint (0/0 or ∞·0 as c → 0) is skipped when the lobe is finite right of it
    // and the piece is negligible; a NaN anywhere else is an error.
    let lead = ys.iter().take_while(|y| y.is_nan()).count();
    let mut start = 0.0;
    let mut skipped = None;
    if lead > 0 && lead < xs.len() {
        let (mut a, mut b) = (xs[lead - 1], xs[lead]);
        for _ in 0..1100 {
            let m = if b > 2.0 * a.max(1e-300) { (a.max(1e-300) * b).sqrt() } else { 0.5 * (a + b) };
            if !(m > a && m < b) {
                break;
            }
            evals += 1;
            if f(m).is_nan() {
                a = m
            } else {
                b = m
            }
        }
        let edge = f(b);
        evals += 1;
        skipped = Some((a, crate::builtins::fmax(edge, 0.0) * 0.5 * b * b));
        start = b;
    }
    if let Some(i) = ys.iter().enumerate().position(|(i, y)| y.is_nan() && (i >= lead || lead == xs.len())) {
        return Err(Diagnostic::error(format!("the formula is NaN at {}", describe(lobe, xs[i])))
            .hint(super::NumericsAdvice::SweepForUndefined));
    }
    // Breakpoints at every switch; only switches next to a non-negligible value are reported as cut-offs
    // (c^1000 underflowing to 0 near 62° is not a clamp).
    let mut kinks = Vec::new();
    let mut switches = Vec::new();
    for i in 1..xs.len() {
        if (ys[i - 1] > 0.0) != (ys[i] > 0.0) {
            let significant = ys[i - 1].max(ys[i]) > 1e-200;
            let (mut a, mut b) = (xs[i - 1], xs[i]);
            let pa = ys[i - 1] > 0.0;
            for _ in 0..80 {
                let m = 0.5 * (a + b);
                if !(m > a && m < b) {
                    break;
                }
                evals += 1;
                if (f(m) > 0.0) == pa {
                    a = m
                } else {
                    b = m
                }
            }
            switches.push(0.5 * (a + b));
            if significant {
                kinks.push(0.5 * (a + b));
            }
        }
    }
    let mut breaks: Vec<f64> = vec![start, 1.0];
    breaks.extend((1..=24).map(|k| 1.0 - 2f64.powi(-k)));
    breaks.extend(switches);
    breaks.retain(|&b| b >= start);
    breaks.sort_by(f64::total_cmp);
    breaks.dedup();
    let mut nan_at = None;
    let r = integrate(
        |c| {
            let y = f(c);
            if y.is_nan() && nan_at.is_none() {
                nan_at = Some(c);
            }
            crate::builtins::fmax(y, 0.0) * c
        },
        &breaks,
        REL_TOL,
        1e-300,
        4000,
    );
    evals += r.evals;
    if let Some(c) = nan_at {
        return Err(Diagnostic::error(format!("the formula is NaN at {}", describe(lobe, c)))
            .hint(super::NumericsAdvice::SweepForUndefined));
    }
    if !r.value.is_finite() || !r.converged && r.error > 1e-7 * r.value.abs() {
        return Err(Diagnostic::error(format!(
            "the lobe integral does not converge (estimate {:e} ± {:e} after {} evaluations): the lobe is not integrable",
            r.value, r.error, r.evals
        ))
            .hint("the formula probably has a pole inside [0°, 90°]; check its denominators"));
    }
    if r.value <= 0.0 {
        return Err(Diagnostic::error("the integral is zero; cannot normalise")
            .hint("the formula is ≤ 0 (clamped to 0) at every angle for these parameters"));
    }
    if let Some((c, bound)) = skipped {
        if c > SKIP_MAX || bound.is_nan() || bound > REL_TOL * r.value {
            return Err(Diagnostic::error(format!("the formula is NaN for {} ≤ {c:e} and that piece is not negligible", lobe.name()))
                .hint(super::NumericsAdvice::RunAccuracyPass));
        }
    }
    Ok(LobeIntegral { integral: r.value, error: r.error, evals, kinks, skipped })
}

/// The exact normalisation coefficient `1 / (2π·Int)` of the papers (lobe convention; module docs).
/// Relative accuracy ~1e-11; a few hundred to ~2000 evaluations.
pub fn normalization_coef(ev: &dyn Evaluator, params: &[f64], lobe_input: Input) -> Result<f64, Diagnostic> {
    lobe_integral(ev, params, lobe_input).map(|r| r.coef())
}

/// `coef(n)` for every `n` in `ns` (parameter 0 replaced), in parallel.
pub fn coef_sweep(ev: &dyn Evaluator, params: &[f64], lobe: Input, ns: &[f64]) -> Vec<Result<LobeIntegral, Diagnostic>> {
    ns.par_iter()
        .map(|&n| {
            let mut p = params.to_vec();
            if let Some(p0) = p.first_mut() {
                *p0 = n;
            }
            lobe_integral(ev, &p, lobe)
        })
        .collect()
}

/// The most values of n one coefficient sweep ([`coef_range`]) takes.
pub(crate) const MAX_RANGE_POINTS: usize = 1_000_000;

/// A coefficient sweep: `(n, Int(n))` (what a fitted coefficient is scored against) and `(n, coef(n))`.
#[derive(Clone, Debug, PartialEq)]
pub struct CoefRange {
    pub integrals: Vec<(f64, f64)>,
    pub coefs: Vec<(f64, f64)>,
}

/// `coef(n)` for n = `lo`, `lo + step`, … up to `hi` (parameter 0 replaced; `n` is its declaration, whose
/// range the sweep must stay inside), in parallel: the energy command's range of n. The first n whose integral
/// fails is the error, naming that n.
pub fn coef_range(ev: &dyn Evaluator, params: &[f64], lobe: Input, n: Option<&crate::ir::ParamDecl>, lo: f64, hi: f64, step: f64) -> Result<CoefRange, Diagnostic> {
    let show = crate::ir::print::number;
    if !(lo.is_finite() && hi.is_finite()) || lo > hi {
        return Err(Diagnostic::error(format!("the range {}..{} of n is not finite lo ≤ hi", show(lo), show(hi))).hint("e.g. 1..1000"));
    }
    if !(step > 0.0 && step.is_finite()) {
        return Err(Diagnostic::error(format!("the step {} of the range of n must be positive", show(step))).hint(super::NumericsAdvice::PositiveStep));
    }
    if let Some(d) = n {
        if lo < d.lo || hi > d.hi {
            return Err(Diagnostic::error(format!("the range {}..{} leaves the declared range of n ({}..{})", show(lo), show(hi), show(d.lo), show(d.hi)))
                .hint(format!("choose a range inside {}..{}", show(d.lo), show(d.hi))));
        }
    }
    let count = ((hi - lo) / step + 1e-9).floor() as usize + 1;
    if count > MAX_RANGE_POINTS {
        return Err(Diagnostic::error(format!("the range {}..{} with step {} has {count} values of n", show(lo), show(hi), show(step))).hint("use a larger step"));
    }
    let ns: Vec<f64> = (0..count).map(|i| lo + i as f64 * step).collect();
    let (mut integrals, mut coefs) = (Vec::with_capacity(count), Vec::with_capacity(count));
    for (n, r) in ns.iter().zip(coef_sweep(ev, params, lobe, &ns)) {
        let r = r.map_err(|mut e| {
            e.message = format!("at n = {n}: {}", e.message);
            e
        })?;
        integrals.push((*n, r.integral));
        coefs.push((*n, r.coef()));
    }
    Ok(CoefRange { integrals, coefs })
}

/// Scores the fitted coefficient `fitted` (a formula of n and parameters, read at no input) against the exact
/// integrals of a sweep of formula `f` at `params`: the fitted formula's n is the sweep's, each of its other
/// parameters takes `f`'s value of the same name, else its own default.
pub fn score_fitted(f: &crate::ir::Formula, params: &[f64], fitted: &crate::Kernel, integrals: &[(f64, f64)]) -> AgainstScore {
    let mut ap = fitted.default_params();
    let n_idx = fitted.formula.param_index("n");
    for (i, d) in fitted.formula.params.iter().enumerate() {
        if let Some(j) = f.param_index(&d.name) {
            ap[i] = params[j];
        }
    }
    score_against(integrals, |n| {
        let mut p = ap.clone();
        if let Some(i) = n_idx {
            p[i] = n;
        }
        fitted.eval(&[0.0; crate::N_INPUTS], &p)
    })
}

/// How well a fitted normalisation formula does: `|coef_fit(n)·2π·Int(n) − 1|`.
#[derive(Clone, Debug, PartialEq)]
pub struct AgainstScore {
    pub max_abs: f64,
    pub worst_n: f64,
    pub mean_abs: f64,
    /// Per n: (n, exact coef, fitted coef, |coef_fit·2π·Int − 1|).
    pub rows: Vec<(f64, f64, f64, f64)>,
}

/// Scores a fitted coefficient `fit(n)` against the exact integrals `(n, Int)`.
pub fn score_against(exact: &[(f64, f64)], fit: impl Fn(f64) -> f64) -> AgainstScore {
    let rows: Vec<_> = exact
        .iter()
        .map(|&(n, int)| {
            let cf = fit(n);
            (n, 1.0 / (2.0 * PI * int), cf, (cf * 2.0 * PI * int - 1.0).abs())
        })
        .collect();
    let (mut max_abs, mut worst_n) = (0.0, f64::NAN);
    for r in &rows {
        // NaN counts as the worst possible.
        if r.3.is_nan() || r.3 > max_abs {
            max_abs = if r.3.is_nan() { f64::INFINITY } else { r.3 };
            worst_n = r.0;
        }
    }
    let mean_abs = rows.iter().map(|r| r.3).sum::<f64>() / rows.len().max(1) as f64;
    AgainstScore { max_abs, worst_n, mean_abs, rows }
}

/// The hemispherical-directional albedo `ρ(θᵢ)` (θᵢ in radians, < π/2) of an isotropic formula (L in the
/// xz-plane; the y → −y symmetry halves the azimuth range).
pub fn albedo(ev: &dyn Evaluator, params: &[f64], theta_i: f64) -> Result<f64, Diagnostic> {
    albedo_at(ev, params, theta_i, None)
}

/// `ρ(θᵢ, φᵢ)` for any formula: L at polar angle θᵢ and azimuth φᵢ (radians) about N, V over the whole
/// hemisphere (no symmetry assumed). `None` for φᵢ: [`albedo`].
pub fn albedo_at(ev: &dyn Evaluator, params: &[f64], theta_i: f64, phi_i: Option<f64>) -> Result<f64, Diagnostic> {
    albedo_until(ev, params, theta_i, phi_i, &Cancel::never())
}

/// [`albedo_at`], polling `cancel` before each inner integral (over φₒ at one θₒ): fails with the
/// cancellation once it trips.
fn albedo_until(ev: &dyn Evaluator, params: &[f64], theta_i: f64, phi_i: Option<f64>, cancel: &Cancel) -> Result<f64, Diagnostic> {
    let t = theta_i;
    let (st, ct) = t.sin_cos();
    let (sp, cp) = phi_i.unwrap_or(0.0).sin_cos();
    // The isotropic construction (L in the xz-plane) turned by φᵢ about N = +z.
    let turn = |a: V3| [cp * a[0] - sp * a[1], sp * a[0] + cp * a[1], a[2]];
    let l = turn([st, 0.0, ct]);
    let r = turn([-st, 0.0, ct]);
    let t1 = turn([ct, 0.0, st]);
    let t2 = turn([0.0, 1.0, 0.0]);
    let full_circle = phi_i.is_some();
    let mut nan = None;
    let mut nonconv = 0usize;
    let mut inner = |alpha: f64| -> f64 {
        if cancel.is_cancelled() {
            return 0.0;
        }
        let (sa, ca) = alpha.sin_cos();
        // Horizon: N·V = ca·ct + sa·cosφ·st > 0.
        let phi_max = if sa * st <= 0.0 || ca * ct >= sa * st {
            PI
        } else {
            (-(ca * ct) / (sa * st)).clamp(-1.0, 1.0).acos()
        };
        if phi_max <= 0.0 {
            return 0.0;
        }
        let g = |phi: f64| {
            let (sp, cp) = phi.sin_cos();
            let v: V3 = std::array::from_fn(|k| ca * r[k] + sa * (cp * t1[k] + sp * t2[k]));
            if v[2] <= 0.0 {
                return 0.0;
            }
            let y = ev.eval(&inputs_from_dirs(l, v), params);
            if y.is_nan() {
                nan.get_or_insert((alpha, phi));
                return 0.0;
            }
            crate::builtins::fmax(y, 0.0) * v[2]
        };
        let (q, twice) = if full_circle {
            (integrate_with(g, &[-phi_max, -0.5 * phi_max, 0.0, 0.5 * phi_max, phi_max], 1e-9, 1e-15, 800, 0), 1.0)
        } else {
            (integrate_with(g, &[0.0, 0.5 * phi_max, phi_max], 1e-9, 1e-15, 400, 0), 2.0)
        };
        if !q.converged {
            nonconv += 1;
        }
        twice * q.value * sa
    };
    let top = FRAC_PI_2 + t;
    let mut breaks = vec![0.0, top];
    breaks.extend((0..=16).map(|k| FRAC_PI_2 * 2f64.powi(-k)).filter(|&a| a < top));
    if FRAC_PI_2 - t > 0.0 {
        breaks.push(FRAC_PI_2 - t);
    }
    breaks.sort_by(f64::total_cmp);
    breaks.dedup();
    let q = integrate_with(&mut inner, &breaks, 1e-8, 1e-14, 2000, 0);
    cancel.check()?;
    if let Some((a, p)) = nan {
        let v: V3 = std::array::from_fn(|k| a.cos() * r[k] + a.sin() * (p.cos() * t1[k] + p.sin() * t2[k]));
        let x = inputs_from_dirs(l, v);
        return Err(Diagnostic::error(format!(
            "the formula is NaN at θᵢ = {:.3}° with NL={:.6} NV={:.6} NH={:.6} VR={:.6} VH={:.6}",
            t.to_degrees(),
            x[0],
            x[1],
            x[2],
            x[3],
            x[4]
        ))
            .hint(super::NumericsAdvice::SweepForUndefined));
    }
    if !q.value.is_finite() || (!q.converged && q.error > 1e-5 * q.value.abs()) {
        return Err(Diagnostic::error(format!("the albedo integral at θᵢ = {:.3}° does not converge (estimate {:e})", t.to_degrees(), q.value))
            .hint("the formula probably has a pole on the hemisphere"));
    }
    Ok(q.value)
}

/// Worst reciprocity violation `|f(L,V) − f(V,L)| / max(|f(L,V)|, |f(V,L)|)` over a direction grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reciprocity {
    pub max_rel: f64,
    pub theta_l_deg: f64,
    pub theta_v_deg: f64,
    pub phi_v_deg: f64,
    pub pairs: usize,
}

/// f(L,V) vs f(V,L): L at θ_L ∈ {0, 5, …, 85, 89}° (φ_L = 0, by symmetry), V at every θ_V of the same list and
/// φ_V ∈ {0, 15, …, 345}°. NaN on either side counts as a violation of 1.
pub(crate) fn reciprocity(ev: &dyn Evaluator, params: &[f64]) -> Reciprocity {
    reciprocity_over(ev, params, &[0.0])
}

/// [`reciprocity`] with L at each azimuth of `phis_l_deg` (φ_V is then relative to φ_L).
pub(crate) fn reciprocity_over(ev: &dyn Evaluator, params: &[f64], phis_l_deg: &[f64]) -> Reciprocity {
    let thetas: Vec<f64> = (0..18).map(|i| i as f64 * 5.0).chain([89.0]).collect();
    let mut best = Reciprocity { max_rel: 0.0, theta_l_deg: 0.0, theta_v_deg: 0.0, phi_v_deg: 0.0, pairs: 0 };
    for (&tl, &pl) in thetas.iter().flat_map(|t| phis_l_deg.iter().map(move |p| (t, p))) {
        let l = dir(tl.to_radians(), pl.to_radians());
        for &tv in &thetas {
            for k in 0..24 {
                let pv = k as f64 * 15.0;
                let v = dir(tv.to_radians(), (pl + pv).to_radians());
                let a = ev.eval(&inputs_from_dirs(l, v), params);
                let b = ev.eval(&inputs_from_dirs(v, l), params);
                best.pairs += 1;
                let m = a.abs().max(b.abs());
                let rel = if a.is_nan() || b.is_nan() {
                    1.0
                } else if m == 0.0 || a == b {
                    0.0
                } else {
                    (a - b).abs() / m
                };
                if rel > best.max_rel {
                    best = Reciprocity { max_rel: rel, theta_l_deg: tl, theta_v_deg: tv, phi_v_deg: pv, pairs: best.pairs };
                }
            }
        }
    }
    best
}

/// The full-mode report.
#[derive(Clone, Debug, PartialEq)]
pub struct FullEnergy {
    /// (θᵢ in degrees, ρ(θᵢ)).
    pub albedo: Vec<(f64, f64)>,
    pub albedo_max: f64,
    pub theta_i_at_max_deg: f64,
    /// `1 / albedo_max`: the largest scale that keeps every ρ(θᵢ) ≤ 1.
    pub coef: f64,
    pub reciprocity: Reciprocity,
    /// For a formula that reads directions: every (θᵢ, φᵢ, ρ) in degrees, `albedo` holding the maximum over
    /// φᵢ at each θᵢ, and the φᵢ of the overall maximum. Empty and `None` for a cosine formula.
    pub albedo_phi: Vec<(f64, f64, f64)>,
    pub phi_i_at_max_deg: Option<f64>,
    /// For a formula that reads directions: whether it passed [`turns_with_the_frame`], so that `albedo_phi`
    /// holds φᵢ = 0 only (every φᵢ has that albedo). `None` for a cosine formula.
    pub isotropic: Option<bool>,
}

/// The azimuths of L for formulas that read directions: 0°, 15°, …, 345°.
pub(crate) const AZIMUTHS_DEG: [f64; 24] = {
    let mut a = [0.0; 24];
    let mut k = 0;
    while k < 24 {
        a[k] = k as f64 * 15.0;
        k += 1;
    }
    a
};

/// The full mode for a kernel that reads `used`: [`full_energy`] for a cosine formula; over θᵢ and φᵢ (see
/// the module docs) when a direction component is read.
pub fn full_energy_for(ev: &dyn Evaluator, used: crate::ir::InputSet, params: &[f64]) -> Result<FullEnergy, Diagnostic> {
    full_energy_cancellable(ev, used, params, &Cancel::never())
}

/// [`full_energy_for`], polling `cancel` inside each albedo integral: fails with the cancellation once it trips.
pub(crate) fn full_energy_cancellable(ev: &dyn Evaluator, used: crate::ir::InputSet, params: &[f64], cancel: &Cancel) -> Result<FullEnergy, Diagnostic> {
    if !used.reads_directions() {
        return full_energy_in(ev, params, cancel);
    }
    // A formula whose values turn with the frame about N has one albedo for every φᵢ: the sweep over φᵢ
    // would integrate the same function 24 times.
    let isotropic = turns_with_the_frame(ev, params);
    let azimuths: &[f64] = if isotropic { &[0.0] } else { &AZIMUTHS_DEG };
    let grid: Vec<(f64, f64)> = full_mode_angles().into_iter().flat_map(|t| azimuths.iter().map(move |&p| (t, p))).collect();
    let cells: Result<Vec<(f64, f64, f64)>, Diagnostic> = grid
        .par_iter()
        .map(|&(t, p)| {
            albedo_until(ev, params, t.to_radians(), Some(p.to_radians()), cancel).map(|r| (t, p, r))
        })
        .collect();
    let cells = cells?;
    let rows: Vec<(f64, f64)> = cells
        .chunks(azimuths.len())
        .map(|c| (c[0].0, c.iter().map(|x| x.2).fold(f64::NEG_INFINITY, f64::max)))
        .collect();
    let mut r = summarise(rows, reciprocity_over(ev, params, &AZIMUTHS_DEG))?;
    let best = cells.iter().filter(|c| c.0 == r.theta_i_at_max_deg).max_by(|a, b| a.2.total_cmp(&b.2));
    r.phi_i_at_max_deg = best.map(|c| c.1);
    r.albedo_phi = cells;
    r.isotropic = Some(isotropic);
    Ok(r)
}

/// [`full_energy_for`] of an isotropic evaluator with kinks or steps everywhere — a measured table's channel
/// ([`crate::measured`]: piecewise multilinear, or piecewise constant under the nearest lookup), which would
/// drive the adaptive quadrature to its subdivision limit everywhere: ρ(θᵢ) by the midpoint rule over 90 θₒ ×
/// 360 φₒ cells of the hemisphere (a table's own resolution), L at azimuth 0 (isotropic by construction, so
/// `albedo_phi` holds φᵢ = 0 only). Measured on linear-lookup tables of Blinn (n = 10, 60, 500), Phong 60,
/// Ward 0.1: 4 × 4 times the cells move ρ(θᵢ ≤ 80°) by ≤ 0.2 %, the table's own error against the formula.
pub fn full_energy_tabulated(ev: &dyn Evaluator, params: &[f64]) -> Result<FullEnergy, Diagnostic> {
    let rows: Vec<(f64, f64)> = full_mode_angles().par_iter().map(|&deg| (deg, albedo_tabulated(ev, params, deg.to_radians()))).collect();
    let mut r = summarise(rows.clone(), reciprocity_over(ev, params, &[0.0]))?;
    r.albedo_phi = rows.iter().map(|&(t, v)| (t, 0.0, v)).collect();
    r.phi_i_at_max_deg = Some(0.0);
    r.isotropic = Some(true);
    Ok(r)
}

/// ρ(θᵢ) (θᵢ in radians) of an isotropic evaluator with kinks or steps everywhere, a measured table's channel,
/// by the midpoint rule over 90 θₒ × 360 φₒ cells ([`full_energy_tabulated`]'s rule), L at azimuth 0.
pub fn albedo_tabulated(ev: &dyn Evaluator, params: &[f64], theta_i: f64) -> f64 {
    let (nt, np) = (90usize, 360usize);
    let (dt, dp) = (FRAC_PI_2 / nt as f64, 2.0 * PI / np as f64);
    let l = dir(theta_i, 0.0);
    let mut sum = 0.0;
    for a in 0..nt {
        let to = (a as f64 + 0.5) * dt;
        let w = to.cos() * to.sin() * dt * dp;
        for b in 0..np {
            let y = ev.eval(&inputs_from_dirs(l, dir(to, (b as f64 + 0.5) * dp)), params);
            if y.is_finite() {
                sum += crate::builtins::fmax(y, 0.0) * w;
            }
        }
    }
    sum
}

/// Pairs [`turns_with_the_frame`] tries.
pub const ISOTROPY_PAIRS: usize = 4096;

/// Whether `ev` gives the same value at (L, V) and at both turned about N by the same angle, at
/// [`ISOTROPY_PAIRS`] random pairs and angles (within 10⁻⁹ relative: the turned components round): a sampled
/// test of isotropy. A formula that reads the tangent frame (anisotropic Ward with αx ≠ αy) fails it at almost
/// every pair; one written with direction components but only through cosines (a half vector's N·H) passes.
pub fn turns_with_the_frame(ev: &dyn Evaluator, params: &[f64]) -> bool {
    let mut r = crate::base::rng::Rng(0x150_7209);
    let mut unit = || r.unit();
    (0..ISOTROPY_PAIRS).all(|_| {
        let (tl, pl, tv, pv, turn) = (unit() * FRAC_PI_2, unit() * 2.0 * PI, unit() * FRAC_PI_2, unit() * 2.0 * PI, unit() * 2.0 * PI);
        let (l, v) = (dir(tl, pl), dir(tv, pv));
        let (lt, vt) = (dir(tl, pl + turn), dir(tv, pv + turn));
        let (a, b) = (ev.eval(&inputs_from_dirs(l, v), params), ev.eval(&inputs_from_dirs(lt, vt), params));
        a == b || (a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
    })
}

/// The incidence angles of the full mode: 0°, 1°, …, 89°, 89.9°.
pub(crate) fn full_mode_angles() -> Vec<f64> {
    (0..90).map(f64::from).chain([89.9]).collect()
}

/// ρ(θᵢ) over [`full_mode_angles`] (in parallel), its maximum, and reciprocity.
pub fn full_energy(ev: &dyn Evaluator, params: &[f64]) -> Result<FullEnergy, Diagnostic> {
    full_energy_in(ev, params, &Cancel::never())
}

fn full_energy_in(ev: &dyn Evaluator, params: &[f64], cancel: &Cancel) -> Result<FullEnergy, Diagnostic> {
    let angles = full_mode_angles();
    let rows: Result<Vec<(f64, f64)>, Diagnostic> = angles
        .par_iter()
        .map(|&d| {
            albedo_until(ev, params, d.to_radians(), None, cancel).map(|r| (d, r))
        })
        .collect();
    summarise(rows?, reciprocity(ev, params))
}

/// The maximum of ρ(θᵢ) rows and the coefficient it gives.
fn summarise(rows: Vec<(f64, f64)>, reciprocity: Reciprocity) -> Result<FullEnergy, Diagnostic> {
    let (mut albedo_max, mut at) = (f64::NEG_INFINITY, 0.0);
    for &(d, r) in &rows {
        if r > albedo_max {
            albedo_max = r;
            at = d;
        }
    }
    if albedo_max <= 0.0 {
        return Err(Diagnostic::error("the albedo is zero at every incidence angle; cannot normalise")
            .hint("the formula is ≤ 0 (clamped to 0) everywhere for these parameters"));
    }
    Ok(FullEnergy { albedo: rows, albedo_max, theta_i_at_max_deg: at, coef: 1.0 / albedo_max, reciprocity, albedo_phi: vec![], phi_i_at_max_deg: None, isotropic: None })
}

/// The energy command's JSON report: one of the three modes' (keys listed in docs/commands.md; numbers follow
/// [`crate::base::json`]).
#[derive(Clone, Debug, serde::Serialize)]
#[serde(untagged)]
pub enum EnergyReport {
    Lobe(LobeReport),
    Full(FullReport),
    Range(RangeReport),
}

/// The lobe mode at one set of parameters.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LobeReport {
    /// Always `"lobe"`.
    pub mode: &'static str,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub coef: f64,
    #[serde(serialize_with = "json::num")]
    pub integral: f64,
    pub lobe_input: &'static str,
    pub evals: usize,
    #[serde(serialize_with = "json::opt_num")]
    pub skipped_nan_up_to: Option<f64>,
    #[serde(serialize_with = "json::opt_num")]
    pub skipped_bound: Option<f64>,
}

impl LobeReport {
    pub fn new(params: Named, lobe: Input, r: &LobeIntegral) -> LobeReport {
        LobeReport {
            mode: "lobe",
            params,
            coef: r.coef(),
            integral: r.integral,
            lobe_input: lobe.name(),
            evals: r.evals,
            skipped_nan_up_to: r.skipped.map(|s| s.0),
            skipped_bound: r.skipped.map(|s| s.1),
        }
    }
}

/// The full mode: albedo over incidence angles and reciprocity.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FullReport {
    /// Always `"full"`.
    pub mode: &'static str,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub coef: f64,
    #[serde(serialize_with = "json::num")]
    pub albedo_max: f64,
    #[serde(serialize_with = "json::num")]
    pub theta_i_at_max_deg: f64,
    pub albedo: Vec<AlbedoRow>,
    #[serde(serialize_with = "json::num")]
    pub reciprocity_max_rel: f64,
    pub reciprocity_worst: ReciprocityWorst,
    /// Only for a formula that reads directions.
    #[serde(serialize_with = "json::opt_num", skip_serializing_if = "Option::is_none")]
    pub phi_i_at_max_deg: Option<f64>,
    /// Only for a formula that reads directions: every (θᵢ, φᵢ, ρ).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub albedo_phi: Option<Vec<AlbedoPhiRow>>,
    /// Only for a formula that reads directions: its values turn with the frame about N on the sampled pairs,
    /// so `albedo_phi` has φᵢ = 0 only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub isotropic: Option<bool>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct AlbedoRow {
    #[serde(serialize_with = "json::num")]
    pub theta_i_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub rho: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct AlbedoPhiRow {
    #[serde(serialize_with = "json::num")]
    pub theta_i_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub phi_i_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub rho: f64,
}

/// Where reciprocity is worst.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReciprocityWorst {
    #[serde(serialize_with = "json::num")]
    pub theta_l_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub theta_v_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub phi_v_deg: f64,
}

impl FullReport {
    pub fn new(params: Named, r: &FullEnergy) -> FullReport {
        let rec = &r.reciprocity;
        FullReport {
            mode: "full",
            params,
            coef: r.coef,
            albedo_max: r.albedo_max,
            theta_i_at_max_deg: r.theta_i_at_max_deg,
            albedo: r.albedo.iter().map(|&(theta_i_deg, rho)| AlbedoRow { theta_i_deg, rho }).collect(),
            reciprocity_max_rel: rec.max_rel,
            reciprocity_worst: ReciprocityWorst { theta_l_deg: rec.theta_l_deg, theta_v_deg: rec.theta_v_deg, phi_v_deg: rec.phi_v_deg },
            phi_i_at_max_deg: r.phi_i_at_max_deg,
            albedo_phi: r.phi_i_at_max_deg.map(|_| {
                r.albedo_phi.iter().map(|&(theta_i_deg, phi_i_deg, rho)| AlbedoPhiRow { theta_i_deg, phi_i_deg, rho }).collect()
            }),
            isotropic: r.isotropic,
        }
    }
}

/// The lobe mode over a range of n, optionally scored against a fitted coefficient.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RangeReport {
    /// Always `"lobe"`.
    pub mode: &'static str,
    /// The parameters other than the swept n.
    pub params: Named,
    pub lobe_input: &'static str,
    pub range: Vec<CoefRow>,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub against: Option<AgainstReport>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct CoefRow {
    #[serde(serialize_with = "json::num")]
    pub n: f64,
    #[serde(serialize_with = "json::num")]
    pub coef: f64,
}

/// [`AgainstScore`] in the report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AgainstReport {
    #[serde(serialize_with = "json::num")]
    pub against_max_abs: f64,
    #[serde(serialize_with = "json::num")]
    pub against_worst_n: f64,
    #[serde(serialize_with = "json::num")]
    pub against_mean_abs: f64,
}

impl RangeReport {
    /// `coefs` are (n, coef(n)).
    pub fn new(params: Named, lobe: Input, coefs: &[(f64, f64)], score: Option<&AgainstScore>) -> RangeReport {
        RangeReport {
            mode: "lobe",
            params,
            lobe_input: lobe.name(),
            range: coefs.iter().map(|&(n, coef)| CoefRow { n, coef }).collect(),
            against: score.map(|s| AgainstReport { against_max_abs: s.max_abs, against_worst_n: s.worst_n, against_mean_abs: s.mean_abs }),
        }
    }
}

/// A report per channel: a scalar formula's own, or for a colour formula the red channel's keys at the top
/// level and all three channels' reports (red, green, blue) under `channels`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PerChannel<T> {
    #[serde(flatten)]
    pub first: T,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub channels: Option<Vec<T>>,
}

impl<T: Clone> PerChannel<T> {
    /// `reports` has one element per channel (one or three).
    pub fn new(mut reports: Vec<T>) -> PerChannel<T> {
        if reports.len() == 1 {
            PerChannel { first: reports.remove(0), channels: None }
        } else {
            PerChannel { first: reports[0].clone(), channels: Some(reports) }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::twins;
    use crate::backend::FnEvaluator;

    #[test]
    fn coef_range_steps_through_n_and_refuses_bad_ranges() {
        let t = twins::phong();
        let decl = crate::ir::ParamDecl { name: "n".into(), default: 10.0, lo: 1.0, hi: 1000.0, span: None, kind: crate::ir::ParamKind::Float };
        let r = coef_range(t.ev.as_ref(), &[1.0], Input::VR, Some(&decl), 3.0, 30.0, 4.5).unwrap();
        let ns: Vec<f64> = r.coefs.iter().map(|c| c.0).collect();
        assert_eq!(ns, [3.0, 7.5, 12.0, 16.5, 21.0, 25.5, 30.0]);
        for (&(n, coef), &(m, int)) in r.coefs.iter().zip(&r.integrals) {
            assert!(n == m && (coef / ((n + 2.0) / (2.0 * PI)) - 1.0).abs() < 1e-9 && (coef * 2.0 * PI * int - 1.0).abs() < 1e-15, "n = {n}");
        }
        for (lo, hi, step, what) in [(0.0, 5.0, 1.0, "declared range"), (5.0, 4.0, 1.0, "lo ≤ hi"), (1.0, 5.0, 0.0, "positive"), (1.0, 1000.0, 1e-4, "values of n")] {
            let e = coef_range(t.ev.as_ref(), &[1.0], Input::VR, Some(&decl), lo, hi, step).unwrap_err();
            assert!(e.message.contains(what), "{what}: {}", e.message);
        }
    }

    #[test]
    fn phong_closed_form_to_1e_9() {
        let t = twins::phong();
        for n in [1.0, 2.0, 10.0, 100.0, 500.0, 1000.0] {
            let c = normalization_coef(t.ev.as_ref(), &[n], Input::VR).unwrap();
            let exact = (n + 2.0) / (2.0 * PI);
            assert!((c / exact - 1.0).abs() < 1e-9, "n={n}: {c} vs {exact}");
        }
    }

    #[test]
    fn clamped_lobes_match_closed_forms() {
        // F_SCOS, zero beyond c0 = (n−2)/n: ∫_{c0}^1 (n/2(c−1)+1)² c dc, by the substitution u = 1 − c:
        // ∫_0^{2/n} (1 − nu/2)² (1 − u) du = 2/(3n) − (2/n)²/12·... computed exactly below.
        let t = twins::scos();
        for n in [3.0, 10.0, 100.0, 1000.0] {
            let w = 2.0 / n;
            // ∫_0^w (1 − u/w)²(1 − u) du = w/3 − w²/12.
            let exact = w / 3.0 - w * w / 12.0;
            let r = lobe_integral(t.ev.as_ref(), &[n], Input::NH).unwrap();
            assert!((r.integral / exact - 1.0).abs() < 1e-9, "n={n}: {} vs {exact}", r.integral);
            assert_eq!(r.kinks.len(), 1);
            // Underflow of c^1000 to zero is not a cut-off.
            let ph = lobe_integral(twins::phong().ev.as_ref(), &[1000.0], Input::VR).unwrap();
            assert!(ph.kinks.is_empty(), "{:?}", ph.kinks);
            assert!((r.kinks[0] - (n - 2.0) / n).abs() < 1e-12);
        }
    }

    #[test]
    fn quadratic_matches_its_closed_form() {
        // 0.786n·c² + (1 − 0.786n)·c, zero below c0 = max(0, (0.786n − 1)/(0.786n)):
        // Int = a(1 − c0⁴)/4 + b(1 − c0³)/3 with a = 0.786n, b = 1 − a.
        let t = twins::quadratic();
        for n in [1.0, 20.0, 60.0, 120.0, 1000.0] {
            let a: f64 = 0.786 * n;
            let b = 1.0 - a;
            let c0 = ((a - 1.0) / a).max(0.0);
            let exact = a * (1.0 - c0.powi(4)) / 4.0 + b * (1.0 - c0.powi(3)) / 3.0;
            let r = lobe_integral(t.ev.as_ref(), &[n], Input::NH).unwrap();
            assert!((r.integral / exact - 1.0).abs() < 1e-9, "n={n}: {} vs {exact}", r.integral);
        }
    }

    #[test]
    fn bad_lobes_get_clear_errors() {
        let zero = FnEvaluator(|_: &[f64; crate::N_INPUTS], _: &[f64]| 0.0);
        let e = normalization_coef(&zero, &[50.0], Input::NH).unwrap_err();
        assert!(e.message.contains("integral is zero; cannot normalise"), "{e}");
        let pole = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| 1.0 / (1.0 - x[2]));
        let e = normalization_coef(&pole, &[50.0], Input::NH).unwrap_err();
        assert!(e.message.contains("infinite at the normal"), "{e}");
        let nan = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| (x[2] - 0.5).sqrt());
        let e = normalization_coef(&nan, &[50.0], Input::NH).unwrap_err();
        assert!(e.message.contains("NaN"), "{e}");
        let e = normalization_coef(twins::blinn().ev.as_ref(), &[f64::NAN], Input::NH).unwrap_err();
        assert!(e.message.contains("finite"), "{e}");
        // A pole inside the hemisphere (not at the normal): not integrable.
        let inner = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| 1.0 / (x[2] - 0.5).abs());
        let e = normalization_coef(&inner, &[50.0], Input::NH).unwrap_err();
        assert!(e.message.contains("does not converge"), "{e}");
    }

    #[test]
    fn a_nan_piece_at_the_endpoint_is_skipped_and_said() {
        // Beckmann as f64 computes it: NaN for c ≤ ~1e-77 (c⁴ underflows: ∞·0), true value 0 there.
        let m2 = 0.09;
        let beck = FnEvaluator(move |x: &[f64; crate::N_INPUTS], _: &[f64]| {
            let c = x[2];
            1.0 / (m2 * c * c * c * c) * ((c * c - 1.0) / (m2 * c * c)).exp()
        });
        let r = lobe_integral(&beck, &[1.0], Input::NH).unwrap();
        let (c, bound) = r.skipped.unwrap();
        assert!(c > 1e-80 && c < 1e-76 && bound == 0.0, "{c} {bound}");
        // Beckmann's lobe coefficient is 1/π: ∫₀¹ D(c)·c dc = 1/2 for every m.
        assert!((r.coef() * PI - 1.0).abs() < 1e-9, "{}", r.coef());
        // A NaN piece whose edge value is not negligible is an error.
        let bad = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| if x[2] < 1e-3 { f64::NAN } else { 1.0 });
        assert!(lobe_integral(&bad, &[1.0], Input::NH).unwrap_err().message.contains("not negligible"));
    }

    #[test]
    fn against_score_is_relative_to_exact() {
        let exact = [(1.0, 1.0 / (2.0 * PI * 0.5)), (2.0, 0.25)];
        // exact coef = 1/(2π Int); a fit 1% high everywhere scores 0.01.
        let s = score_against(&exact, |n| 1.01 / (2.0 * PI * exact.iter().find(|e| e.0 == n).unwrap().1));
        assert!((s.max_abs - 0.01).abs() < 1e-12 && (s.mean_abs - 0.01).abs() < 1e-12);
    }

    #[test]
    fn lambert_albedo_is_one_at_every_angle() {
        let lambert = FnEvaluator(|_: &[f64; crate::N_INPUTS], _: &[f64]| 1.0 / PI);
        for d in [0.0, 30.0, 60.0, 85.0, 89.9] {
            let r = albedo(&lambert, &[], f64::to_radians(d)).unwrap();
            assert!((r - 1.0).abs() < 1e-7, "θ={d}: {r}");
        }
    }

    #[test]
    fn phong_albedo_at_normal_incidence_is_the_lobe_integral() {
        let t = twins::phong();
        for n in [1.0, 50.0, 1000.0] {
            let r = albedo(t.ev.as_ref(), &[n], 0.0).unwrap();
            let exact = 2.0 * PI / (n + 2.0);
            assert!((r / exact - 1.0).abs() < 1e-6, "n={n}: {r} vs {exact}");
        }
    }

    #[test]
    fn phong_albedo_falls_off_at_grazing_and_is_reciprocal() {
        let t = twins::phong();
        let full = full_energy(t.ev.as_ref(), &[20.0]).unwrap();
        // Energy is lost below the horizon as θᵢ grows, so the maximum is at normal incidence.
        assert_eq!(full.theta_i_at_max_deg, 0.0);
        assert!(full.albedo.last().unwrap().1 < 0.6 * full.albedo_max);
        assert!(full.reciprocity.max_rel < 1e-12, "{:?}", full.reciprocity);
        // NL·VR^n is not reciprocal.
        let nonrec = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| x[0] * x[3].max(0.0).powf(p[0]));
        assert!(reciprocity(&nonrec, &[20.0]).max_rel > 0.5);
    }
}
