//! Levenberg–Marquardt: the least-squares minimiser of the fits, driven by exact Jacobians
//! ([`super::grad::Gradient`]).
//!
//! The caller evaluates a problem's normal equations at a point ([`Normal`]: Σ r², JᵀJ and Jᵀr, accumulated
//! residual by residual, so a Jacobian of millions of rows is never stored). Each step solves
//! (JᵀJ + λ·D)·δ = −Jᵀr by Cholesky, D = diag(JᵀJ) (Marquardt's scaling, so a parameter's units do not matter);
//! λ follows the gain ratio of actual to predicted decrease (Nielsen 1999: shrink by up to 3× on a good step,
//! grow by 2, 4, 8, … on refused ones).
//!
//! # Bounds
//! A variable with a range [lo, hi] is moved as t with p = lo + (hi − lo)·(1 + sin t)/2 (MINUIT's transform).
//! Unlike a logistic, sin reaches both ends at finite t, so an optimum on a bound (metallic = 0) is reached,
//! not approached forever; and every t is a valid p, so no step is ever clipped. Its slope vanishes at the ends,
//! so a start exactly on a bound is moved 10⁻⁴ of the range inside (or it could never leave).
//!
//! # Stopping
//! Σ r² = 0; or the scaled gradient max |Jᵀr|ₐ / √((JᵀJ)ₐₐ·Σr²) (the cosine between the residual and each
//! column) below 10⁻¹²; or an accepted step below 10⁻¹⁰·(1 + |t|) in every variable (Levenberg–Marquardt
//! converges quadratically near a minimum, so the next step would be far below the 10⁻⁶ a fit must reach); or
//! the undamped (Gauss–Newton) step −(JᵀJ)⁻¹·Jᵀr at the current point below 10⁻¹⁴·(1 + |t|) in every variable
//! (the point is a minimum to rounding: a start there, such as the last refinement of a fit on more entries
//! whose minimum is the same, ends after its first evaluation instead of confirming it with a second); or λ
//! past 10¹⁶ (no decrease possible in floating point); or `max_iterations`.
//!
//! # Several starts
//! [`minimize_near`] is given the results of the starts run before: a start whose point comes within
//! [`JOIN`] of one of them (a fraction of each bounded variable's range, of 1 + |x| for an unbounded one) at a
//! cost no lower than that result's stops there, since it is converging to a minimum already found
//! ([`LmResult::joined`]). A start whose Σ r² is at most [`EXACT`] times the targets' Σ y² fits exactly
//! ([`is_exact`]): no other start can do better, and the callers run no more of them.

/// The normal equations of a least-squares problem at one point: `cost` = Σ r², `jtj` = JᵀJ (row-major k×k)
/// and `jtr` = Jᵀr, over the derivatives by the problem's k variables.
#[derive(Clone, Debug, PartialEq)]
pub struct Normal {
    pub cost: f64,
    pub jtj: Vec<f64>,
    pub jtr: Vec<f64>,
}

impl Normal {
    pub fn zeros(k: usize) -> Normal {
        Normal { cost: 0.0, jtj: vec![0.0; k * k], jtr: vec![0.0; k] }
    }

    /// Adds one residual `r` whose gradient by the variables is `g`.
    pub fn add(&mut self, r: f64, g: &[f64]) {
        let k = self.jtr.len();
        self.cost += r * r;
        for a in 0..k {
            if g[a] == 0.0 {
                continue;
            }
            self.jtr[a] += g[a] * r;
            for b in 0..k {
                self.jtj[a * k + b] += g[a] * g[b];
            }
        }
    }

    /// The sum of two parts' equations (one problem's residuals split into chunks).
    pub fn merge(mut self, o: Normal) -> Normal {
        self.cost += o.cost;
        self.jtj.iter_mut().zip(&o.jtj).for_each(|(a, b)| *a += b);
        self.jtr.iter_mut().zip(&o.jtr).for_each(|(a, b)| *a += b);
        self
    }

    fn is_finite(&self) -> bool {
        self.cost.is_finite() && self.jtj.iter().chain(&self.jtr).all(|v| v.is_finite())
    }
}

/// The result of [`minimize`]: the best point (in the problem's own variables), its Σ r², the iterations
/// (accepted or refused steps) and the evaluations of the normal equations.
#[derive(Clone, Debug, PartialEq)]
pub struct LmResult {
    pub x: Vec<f64>,
    pub cost: f64,
    pub iterations: usize,
    pub evaluations: usize,
    /// [`minimize_near`]: the earlier result (its index) this start stopped beside, its minimum already found.
    pub joined: Option<usize>,
}

/// How near (module docs, "Several starts") a start must come to an earlier result to stop there.
pub const JOIN: f64 = 1e-4;

/// Σ r² at most this times the targets' Σ y² is an exact fit (module docs, "Several starts").
pub const EXACT: f64 = 1e-20;

/// Whether Σ r² = `cost` fits targets whose Σ y² is `targets` exactly ([`EXACT`]).
pub fn is_exact(cost: f64, targets: f64) -> bool {
    cost <= EXACT * targets
}

/// Whether `x` lies within [`JOIN`] of `y` in every variable (of the range where bounded, of 1 + |y| where not).
fn beside(x: &[f64], y: &[f64], bounds: &[Option<(f64, f64)>]) -> bool {
    x.iter().zip(y).zip(bounds).all(|((x, y), b)| {
        let width = match b {
            Some((lo, hi)) => hi - lo,
            None => 1.0 + y.abs(),
        };
        (x - y).abs() <= JOIN * width
    })
}

/// The variables' map between t (what the steps move) and the problem's x (module docs, "Bounds").
fn to_x(t: f64, b: Option<(f64, f64)>) -> f64 {
    match b {
        Some((lo, hi)) => (lo + (hi - lo) * (1.0 + t.sin()) / 2.0).clamp(lo, hi),
        None => t,
    }
}

fn slope(t: f64, b: Option<(f64, f64)>) -> f64 {
    match b {
        Some((lo, hi)) => (hi - lo) * t.cos() / 2.0,
        None => 1.0,
    }
}

fn to_t(x: f64, b: Option<(f64, f64)>) -> f64 {
    match b {
        Some((lo, hi)) if hi > lo => {
            let u = ((x - lo) / (hi - lo)).clamp(1e-4, 1.0 - 1e-4);
            (2.0 * u - 1.0).asin()
        }
        Some(_) => 0.0,
        None => x,
    }
}

/// Solves (A + λ·D)·δ = −g by Cholesky (A symmetric k×k, D its diagonal floored at 10⁻³⁰ of the largest).
fn solve(a: &[f64], g: &[f64], lambda: f64) -> Option<Vec<f64>> {
    let k = g.len();
    let dmax = (0..k).map(|i| a[i * k + i]).fold(0.0f64, f64::max);
    let floor = (dmax * 1e-30).max(f64::MIN_POSITIVE);
    let mut l = vec![0.0; k * k];
    for i in 0..k {
        for j in 0..=i {
            let mut s = a[i * k + j];
            if i == j {
                s += lambda * a[i * k + i].max(floor);
            }
            for m in 0..j {
                s -= l[i * k + m] * l[j * k + m];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 {
                    return None;
                }
                l[i * k + i] = s.sqrt();
            } else {
                l[i * k + j] = s / l[j * k + j];
            }
        }
    }
    let mut y = vec![0.0; k];
    for i in 0..k {
        y[i] = (-g[i] - (0..i).map(|m| l[i * k + m] * y[m]).sum::<f64>()) / l[i * k + i];
    }
    let mut x = vec![0.0; k];
    for i in (0..k).rev() {
        x[i] = (y[i] - (i + 1..k).map(|m| l[m * k + i] * x[m]).sum::<f64>()) / l[i * k + i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Minimises Σ r² from `x0`. `eval` gives the normal equations at a point of the problem's variables (derivatives
/// by those variables), or `None` where the residuals are not all finite (a refused step). `bounds[i]`: the
/// range of variable i, or `None` (unbounded). Returns `None` when the start itself cannot be evaluated.
pub fn minimize(eval: &(dyn Fn(&[f64]) -> Option<Normal> + Sync), x0: &[f64], bounds: &[Option<(f64, f64)>], max_iterations: usize) -> Option<LmResult> {
    minimize_near(eval, x0, bounds, max_iterations, &[])
}

/// [`minimize`], stopping where the start comes beside one of the `known` results of earlier starts on the same
/// problem (module docs, "Several starts"; [`LmResult::joined`]).
pub fn minimize_near(
    eval: &(dyn Fn(&[f64]) -> Option<Normal> + Sync),
    x0: &[f64],
    bounds: &[Option<(f64, f64)>],
    max_iterations: usize,
    known: &[LmResult],
) -> Option<LmResult> {
    let k = x0.len();
    let xs = |t: &[f64]| t.iter().zip(bounds).map(|(t, b)| to_x(*t, *b)).collect::<Vec<f64>>();
    let mut evaluations = 0;
    // The equations by t: the chain rule through the bounds' map.
    let at = |t: &[f64], evaluations: &mut usize| -> Option<Normal> {
        *evaluations += 1;
        let mut n = eval(&xs(t)).filter(Normal::is_finite)?;
        let d: Vec<f64> = t.iter().zip(bounds).map(|(t, b)| slope(*t, *b)).collect();
        for a in 0..k {
            n.jtr[a] *= d[a];
            for b in 0..k {
                n.jtj[a * k + b] *= d[a] * d[b];
            }
        }
        Some(n)
    };
    let mut t: Vec<f64> = x0.iter().zip(bounds).map(|(x, b)| to_t(*x, *b)).collect();
    let mut cur = at(&t, &mut evaluations)?;
    let dmax = (0..k).map(|i| cur.jtj[i * k + i]).fold(0.0f64, f64::max);
    let mut lambda = if dmax > 0.0 { 1e-3 } else { 1.0 };
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut joined = None;
    while iterations < max_iterations && cur.cost > 0.0 {
        let x = xs(&t);
        joined = known.iter().position(|r| cur.cost >= r.cost && beside(&x, &r.x, bounds));
        if joined.is_some() {
            break;
        }
        let scaled = (0..k).map(|a| cur.jtr[a].abs() / (cur.jtj[a * k + a] * cur.cost).sqrt()).filter(|v| v.is_finite()).fold(0.0f64, f64::max);
        if scaled < 1e-12 || lambda > 1e16 || solve(&cur.jtj, &cur.jtr, 0.0).is_some_and(|gn| gn.iter().zip(&t).all(|(d, t)| d.abs() <= 1e-14 * (1.0 + t.abs()))) {
            break;
        }
        iterations += 1;
        let Some(delta) = solve(&cur.jtj, &cur.jtr, lambda) else {
            lambda *= nu;
            nu *= 2.0;
            continue;
        };
        let tn: Vec<f64> = t.iter().zip(&delta).map(|(t, d)| t + d).collect();
        // Predicted decrease of Σ r² under the linear model: δᵀAδ + 2λ·δᵀDδ.
        let (mut quad, mut damp) = (0.0, 0.0);
        for a in 0..k {
            damp += delta[a] * delta[a] * cur.jtj[a * k + a];
            for b in 0..k {
                quad += delta[a] * cur.jtj[a * k + b] * delta[b];
            }
        }
        let predicted = quad + 2.0 * lambda * damp;
        match at(&tn, &mut evaluations) {
            Some(next) if next.cost < cur.cost => {
                let rho = (cur.cost - next.cost) / predicted;
                lambda *= if rho.is_finite() { (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0) } else { 1.0 / 3.0 };
                nu = 2.0;
                let tiny_step = delta.iter().zip(&t).all(|(d, t)| d.abs() <= 1e-10 * (1.0 + t.abs()));
                t = tn;
                cur = next;
                if tiny_step {
                    break;
                }
            }
            _ => {
                lambda *= nu;
                nu *= 2.0;
            }
        }
    }
    Some(LmResult { x: xs(&t), cost: cur.cost, iterations, evaluations, joined })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Residuals r_i = y_i − a·exp(−b·x_i) (+ c): the problem's normal equations from its exact Jacobian.
    fn exp_fit<'a>(xs: &'a [f64], ys: &'a [f64]) -> impl Fn(&[f64]) -> Option<Normal> + Sync + 'a {
        move |p: &[f64]| {
            let mut n = Normal::zeros(p.len());
            for (x, y) in xs.iter().zip(ys) {
                let e = (-p[1] * x).exp();
                let r = p[0] * e - y;
                n.add(r, &[e, -p[0] * x * e]);
            }
            Some(n)
        }
    }

    #[test]
    fn recovers_random_exponentials_to_machine_precision() {
        let mut rng = crate::base::rng::Rng(7);
        let xs: Vec<f64> = (0..50).map(|i| f64::from(i) * 0.1).collect();
        for _ in 0..20 {
            let (a, b) = (0.5 + 4.0 * rng.unit(), 0.1 + 2.9 * rng.unit());
            let ys: Vec<f64> = xs.iter().map(|x| a * (-b * x).exp()).collect();
            let start = [0.5 + 4.0 * rng.unit(), 0.1 + 2.9 * rng.unit()];
            let r = minimize(&exp_fit(&xs, &ys), &start, &[Some((0.0, 5.0)), Some((0.05, 3.0))], 200).unwrap();
            assert!((r.x[0] - a).abs() < 1e-9 * a && (r.x[1] - b).abs() < 1e-9 * b, "{a} {b} from {start:?}: {r:?}");
            assert!(r.iterations < 100, "{r:?}");
        }
    }

    #[test]
    fn a_start_at_the_minimum_ends_after_one_evaluation() {
        // The Gauss–Newton step at an exact minimum is rounding: no second evaluation to confirm it.
        let mut rng = crate::base::rng::Rng(11);
        let xs: Vec<f64> = (0..40).map(|i| f64::from(i) * 0.1).collect();
        for _ in 0..20 {
            let (a, b) = (0.5 + 4.0 * rng.unit(), 0.1 + 2.9 * rng.unit());
            let ys: Vec<f64> = xs.iter().map(|x| a * (-b * x).exp()).collect();
            let bounds = [Some((0.0, 5.0)), Some((0.05, 3.0))];
            let r = minimize(&exp_fit(&xs, &ys), &[a, b], &bounds, 200).unwrap();
            assert_eq!((r.iterations, r.evaluations), (0, 1), "{a} {b}: {r:?}");
            assert!((r.x[0] - a).abs() < 1e-12 * a && (r.x[1] - b).abs() < 1e-12 * b, "{r:?}");
            // Off the minimum it still steps, and stops as close.
            let far = minimize(&exp_fit(&xs, &ys), &[a * 1.2, b * 0.9], &bounds, 200).unwrap();
            assert!(far.iterations > 0 && (far.x[0] - a).abs() < 1e-9 * a && (far.x[1] - b).abs() < 1e-9 * b, "{far:?}");
        }
    }

    #[test]
    fn a_start_beside_a_known_minimum_joins_it() {
        // A sum of two exponentials, fitted by one: a least-squares problem with a non-zero minimum, from
        // random starts. A second start given the first's result stops beside it (joined), after fewer
        // evaluations than alone, where alone it would end at the same minimum.
        let mut rng = crate::base::rng::Rng(12);
        let xs: Vec<f64> = (0..60).map(|i| f64::from(i) * 0.05).collect();
        let mut joins = 0;
        for _ in 0..20 {
            let (a, b) = (0.5 + 4.0 * rng.unit(), 0.3 + 2.0 * rng.unit());
            let ys: Vec<f64> = xs.iter().map(|x| a * (-b * x).exp() + 0.3 * (-0.1 * x).exp()).collect();
            let bounds = [Some((0.0, 6.0)), Some((0.01, 3.0))];
            let f = exp_fit(&xs, &ys);
            let start = |rng: &mut crate::base::rng::Rng| [0.5 + 5.0 * rng.unit(), 0.1 + 2.5 * rng.unit()];
            let (s1, s2) = (start(&mut rng), start(&mut rng));
            let first = minimize(&f, &s1, &bounds, 200).unwrap();
            assert!(first.cost > 1e-6 && first.joined.is_none(), "{first:?}");
            let alone = minimize(&f, &s2, &bounds, 200).unwrap();
            let second = minimize_near(&f, &s2, &bounds, 200, std::slice::from_ref(&first)).unwrap();
            let same = (alone.x[0] - first.x[0]).abs() < 1e-6 && (alone.x[1] - first.x[1]).abs() < 1e-6;
            if second.joined == Some(0) {
                joins += 1;
                // It joined only a minimum it was heading for, and stopped within JOIN of it, sooner.
                assert!(same, "{first:?} {alone:?} {second:?}");
                assert!(second.evaluations < alone.evaluations && second.cost >= first.cost, "{alone:?} {second:?}");
                for (i, (lo, hi)) in bounds.iter().flatten().enumerate() {
                    assert!((second.x[i] - first.x[i]).abs() <= JOIN * (hi - lo), "{second:?}");
                }
            } else {
                assert_eq!(second, alone);
            }
        }
        assert!(joins >= 15, "{joins} of 20 starts joined");
    }

    #[test]
    fn an_exact_fit_is_one_at_rounding() {
        let mut rng = crate::base::rng::Rng(13);
        let xs: Vec<f64> = (0..50).map(|i| f64::from(i) * 0.1).collect();
        for _ in 0..10 {
            let (a, b) = (0.5 + 4.0 * rng.unit(), 0.1 + 2.9 * rng.unit());
            let ys: Vec<f64> = xs.iter().map(|x| a * (-b * x).exp()).collect();
            let targets: f64 = ys.iter().map(|y| y * y).sum();
            let r = minimize(&exp_fit(&xs, &ys), &[2.0, 1.0], &[Some((0.0, 5.0)), Some((0.05, 3.0))], 200).unwrap();
            assert!(is_exact(r.cost, targets), "{r:?}");
            // Off by 10⁻⁹ in one value: not exact.
            let mut off = ys.clone();
            off[7] += 1e-9 * targets.sqrt();
            let r = minimize(&exp_fit(&xs, &off), &[2.0, 1.0], &[Some((0.0, 5.0)), Some((0.05, 3.0))], 200).unwrap();
            assert!(!is_exact(r.cost, targets), "{r:?}");
        }
    }

    #[test]
    fn a_bound_is_reached_and_never_left() {
        // The unconstrained optimum b = 4 lies beyond hi = 3: the fit ends on the bound, inside the range.
        let xs: Vec<f64> = (0..30).map(|i| f64::from(i) * 0.1).collect();
        let ys: Vec<f64> = xs.iter().map(|x| 2.0 * (-4.0 * x).exp()).collect();
        let r = minimize(&exp_fit(&xs, &ys), &[1.0, 1.0], &[Some((0.0, 5.0)), Some((0.05, 3.0))], 500).unwrap();
        assert!(r.x[1] <= 3.0 && r.x[1] > 3.0 - 1e-6, "{r:?}");
        // Unbounded variables move freely; a start that cannot be evaluated is no result.
        let r = minimize(&exp_fit(&xs, &ys), &[1.0, 1.0], &[None, None], 200).unwrap();
        assert!((r.x[1] - 4.0).abs() < 1e-9, "{r:?}");
        assert!(minimize(&|_: &[f64]| None, &[1.0], &[None], 10).is_none());
    }

    #[test]
    fn non_finite_steps_are_refused() {
        // r = sqrt(p) − 1 is NaN for p < 0: steps there are refused, the minimum p = 1 is still found.
        let f = |p: &[f64]| {
            let mut n = Normal::zeros(1);
            n.add(p[0].sqrt() - 1.0, &[0.5 / p[0].sqrt()]);
            Some(n)
        };
        let r = minimize(&f, &[0.01], &[None], 200).unwrap();
        assert!((r.x[0] - 1.0).abs() < 1e-12, "{r:?}");
    }
}
