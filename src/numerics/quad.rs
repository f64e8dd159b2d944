//! Adaptive Gauss–Kronrod 7/15 quadrature with global interval bisection (QUADPACK's QAG strategy).
//!
//! Why this rule: a 15-point Kronrod rule is exact for polynomials of degree 22 and its embedded 7-point Gauss
//! rule gives an error estimate for free, so smooth pieces converge on the first try while kinks (a lobe
//! clamped to zero at its cut-off) and narrow peaks (n = 1000) are found by the error estimate and bisected.
//! Callers pass known breakpoints (kinks, the geometric ladder towards a peak) so bisection rarely has to find
//! them. The error estimate is the raw |K15 − G7|, which overestimates the true error of K15 by orders of
//! magnitude on smooth pieces — deliberately conservative, except on a panel holding a kink the breakpoints
//! miss at a place where the two rules' errors happen to cross (Cook–Torrance's G switching inside the lobe: the
//! estimate said 1e-14 where the panel was 2e-10 off). So a converged result is checked on every panel's halves
//! ([`integrate`]; nested inner integrals skip it, [`integrate_with`]).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

const XGK: [f64; 8] = [
    0.991_455_371_120_812_6,
    0.949_107_912_342_758_5,
    0.864_864_423_359_769_1,
    0.741_531_185_599_394_4,
    0.586_087_235_467_691_1,
    0.405_845_151_377_397_2,
    0.207_784_955_007_898_5,
    0.0,
];
const WGK: [f64; 8] = [
    0.022_935_322_010_529_22,
    0.063_092_092_629_978_55,
    0.104_790_010_322_250_2,
    0.140_653_259_715_525_9,
    0.169_004_726_639_267_9,
    0.190_350_578_064_785_4,
    0.204_432_940_075_298_9,
    0.209_482_141_084_727_8,
];
/// Gauss weights for XGK[1], XGK[3], XGK[5] and the centre XGK[7].
const WG: [f64; 4] = [0.129_484_966_168_869_7, 0.279_705_391_489_276_7, 0.381_830_050_505_118_9, 0.417_959_183_673_469_4];

/// An integral with its estimated absolute error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct QuadResult {
    pub value: f64,
    pub error: f64,
    /// Integrand evaluations used.
    pub evals: usize,
    /// False when the interval budget ran out before the tolerance was met (`value` is still the best estimate).
    pub converged: bool,
}

/// One GK15 panel on [a, b]: (Kronrod value, |Kronrod − Gauss|).
pub(crate) fn gk15(f: &mut impl FnMut(f64) -> f64, a: f64, b: f64) -> (f64, f64) {
    let c = 0.5 * (a + b);
    let h = 0.5 * (b - a);
    let fc = f(c);
    let mut k = WGK[7] * fc;
    let mut g = WG[3] * fc;
    for j in 0..7 {
        let dx = h * XGK[j];
        let s = f(c - dx) + f(c + dx);
        k += WGK[j] * s;
        if j % 2 == 1 {
            g += WG[j / 2] * s;
        }
    }
    (k * h, ((k - g) * h).abs())
}

struct Panel {
    a: f64,
    b: f64,
    value: f64,
    error: f64,
}

impl PartialEq for Panel {
    fn eq(&self, o: &Self) -> bool {
        self.error.total_cmp(&o.error) == Ordering::Equal
    }
}
impl Eq for Panel {}
impl PartialOrd for Panel {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Panel {
    fn cmp(&self, o: &Self) -> Ordering {
        self.error.total_cmp(&o.error)
    }
}

/// Verification rounds of [`integrate`] (each evaluates every panel's halves once).
const MAX_VERIFY: usize = 3;

/// Integrates `f` over `[breaks[0], breaks.last()]` (breaks sorted ascending; duplicates are skipped) until the
/// estimated error is at most `max(abs_tol, rel_tol·|I|)` — checked once more on every panel's halves, up to
/// [`MAX_VERIFY`] times (a kink can fool one panel's estimate) — or `max_panels` panels exist. A NaN anywhere makes the
/// result NaN (the caller reports it; quadrature never hides a NaN).
pub(crate) fn integrate(f: impl FnMut(f64) -> f64, breaks: &[f64], rel_tol: f64, abs_tol: f64, max_panels: usize) -> QuadResult {
    integrate_with(f, breaks, rel_tol, abs_tol, max_panels, MAX_VERIFY)
}

/// [`integrate`] with `verify` rounds of the halves' check (0: the plain QAG strategy, for inner integrals of a
/// nested quadrature, whose cost it would multiply).
pub(crate) fn integrate_with(mut f: impl FnMut(f64) -> f64, breaks: &[f64], rel_tol: f64, abs_tol: f64, max_panels: usize, verify: usize) -> QuadResult {
    let mut heap = BinaryHeap::new();
    let mut evals = 0;
    let (mut total, mut err) = (0.0, 0.0);
    for w in breaks.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b <= a {
            continue;
        }
        let (v, e) = gk15(&mut f, a, b);
        evals += 15;
        total += v;
        err += e;
        heap.push(Panel { a, b, value: v, error: e });
    }
    if !total.is_finite() || !err.is_finite() {
        return QuadResult { value: total, error: err, evals, converged: false };
    }
    let mut converged = true;
    let mut verified = 0;
    loop {
        if err <= abs_tol.max(rel_tol * total.abs()) {
            // |K15 − G7| can vanish by accident on a panel with a kink the breakpoints miss (both rules' errors
            // are ~h² times functions of where the kink sits, and they cross): a second opinion from each
            // panel's halves, which moves the kink's relative position. Where the halves disagree with the panel
            // by more than its estimate, they replace it with that disagreement as their error, and the
            // bisection goes on.
            if verified == verify || heap.len() * 2 > max_panels {
                break;
            }
            verified += 1;
            let mut next = BinaryHeap::with_capacity(heap.len() * 2);
            let mut moved = false;
            for p in heap.drain() {
                let m = 0.5 * (p.a + p.b);
                if !(m > p.a && m < p.b) {
                    next.push(p);
                    continue;
                }
                let (v1, e1) = gk15(&mut f, p.a, m);
                let (v2, e2) = gk15(&mut f, m, p.b);
                evals += 30;
                let diff = (v1 + v2 - p.value).abs();
                // Beyond the panel's estimate and beyond rounding noise (a panel where f is 0 or a polynomial
                // estimates 0).
                if diff > p.error.max(64.0 * f64::EPSILON * (v1.abs() + v2.abs())) {
                    moved = true;
                    total += v1 + v2 - p.value;
                    err += e1.max(0.5 * diff) + e2.max(0.5 * diff) - p.error;
                    next.push(Panel { a: p.a, b: m, value: v1, error: e1.max(0.5 * diff) });
                    next.push(Panel { a: m, b: p.b, value: v2, error: e2.max(0.5 * diff) });
                } else {
                    next.push(p);
                }
            }
            heap = next;
            if !total.is_finite() || !err.is_finite() {
                return QuadResult { value: total, error: err, evals, converged: false };
            }
            if !moved || err <= abs_tol.max(rel_tol * total.abs()) {
                break;
            }
            continue;
        }
        if heap.len() >= max_panels {
            converged = false;
            break;
        }
        let Some(p) = heap.pop() else { break };
        let m = 0.5 * (p.a + p.b);
        if !(m > p.a && m < p.b) {
            // The panel cannot be split in floating point; keep it and give up on it.
            heap.push(Panel { error: 0.0, ..p });
            err -= p.error;
            converged = false;
            continue;
        }
        let (v1, e1) = gk15(&mut f, p.a, m);
        let (v2, e2) = gk15(&mut f, m, p.b);
        evals += 30;
        total += v1 + v2 - p.value;
        err += e1 + e2 - p.error;
        if !total.is_finite() || !err.is_finite() {
            return QuadResult { value: total, error: err, evals, converged: false };
        }
        heap.push(Panel { a: p.a, b: m, value: v1, error: e1 });
        heap.push(Panel { a: m, b: p.b, value: v2, error: e2 });
    }
    // Re-sum to shed the drift of the running updates.
    let value: f64 = heap.iter().map(|p| p.value).sum();
    let error: f64 = heap.iter().map(|p| p.error).sum();
    QuadResult { value, error, evals, converged }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polynomials_are_exact_on_one_panel() {
        let r = integrate(|x| x.powi(20), &[0.0, 1.0], 1e-14, 0.0, 1);
        assert!((r.value - 1.0 / 21.0).abs() < 1e-15, "{r:?}");
    }

    #[test]
    fn kinks_and_peaks_converge_by_bisection() {
        // |x − 1/3| has a kink the breakpoints do not know about.
        let r = integrate(|x| (x - 1.0 / 3.0).abs(), &[0.0, 1.0], 1e-12, 0.0, 2000);
        let exact = (1.0 / 9.0 + 4.0 / 9.0) / 2.0;
        assert!(r.converged && (r.value - exact).abs() < 1e-11, "{r:?}");
        // A narrow peak: ∫ x^1000 = 1/1001.
        let r = integrate(|x| x.powi(1000), &[0.0, 1.0], 1e-12, 0.0, 2000);
        assert!((r.value * 1001.0 - 1.0).abs() < 1e-10, "{r:?}");
    }

    /// A kink placed where one panel's K15 and G7 errors cancel (found by scanning its position): the estimate
    /// of the panel says converged, the verification on its halves does not, and the result is right.
    #[test]
    fn a_kink_that_fools_one_panels_estimate_is_found() {
        let exact = |t: f64| (t * t + (1.0 - t) * (1.0 - t)) / 2.0;
        let mut worst = (0.0, 0.5);
        for i in 1..20000 {
            let t = i as f64 / 20000.0;
            let (k, e) = gk15(&mut |x: f64| (x - t).abs(), 0.0, 1.0);
            let ratio = (k - exact(t)).abs() / e.max(1e-300);
            if ratio > worst.0 {
                worst = (ratio, t);
            }
        }
        assert!(worst.0 > 100.0, "no kink position fools the estimate: {worst:?}");
        let t = worst.1;
        let r = integrate(|x| (x - t).abs(), &[0.0, 1.0], 1e-6, 0.0, 2000);
        assert!((r.value - exact(t)).abs() <= 1e-6 * exact(t), "t = {t}: {r:?} vs {}", exact(t));
        assert!((r.value - exact(t)).abs() <= r.error, "the stated error holds: {r:?}");
    }

    #[test]
    fn nan_is_reported_not_hidden() {
        let r = integrate(|x| if x > 0.5 { f64::NAN } else { x }, &[0.0, 1.0], 1e-12, 0.0, 100);
        assert!(r.value.is_nan());
    }
}
