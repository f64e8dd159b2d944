//! Parameter fitting: find the parameter values that make a lobe closest to a reference lobe.
//!
//! Design: the papers' search, made fast. The reference is evaluated once on the metric's grid (for mean |Δ|:
//! 91 angles × n = 1..1000, the lobe convention of the [module docs](super)); each candidate is then scored
//! with batched evaluations of the formula only (91 points per n), in parallel over candidates (rayon).
//! Stage 1 is exhaustive over a grid (integers for integer ranges, or `lo..hi:step`); stage 2 refines the
//! best grid point continuously — golden-section search for one free parameter, Nelder–Mead (clamped to
//! the ranges) for several — within one grid step of it.
//!
//! Cost: one mean-|Δ| score is 91 000 formula evaluations; a = 1..1000 for F_ST is 91 M evaluations (~1–2 s
//! on the JIT on 2 cores, several seconds on the interpreter) plus ~60 scores for the refinement.

use super::{lobe_inputs, CheckError};
use crate::ir::Input;
use crate::backend::{Columns, Evaluator};
use crate::N_INPUTS;
use rayon::prelude::*;

/// What a fit minimises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Metric {
    /// Mean |F − R| over 0°..90° step 1° × n = 1..n_max (the papers' metric).
    #[default]
    MeanAbs,
    /// Max |F − R| over the same grid.
    MaxAbs,
    /// Max relative error at the epicentre acos(exp(−1.2/n)), n ∈ [2, n_max].
    Epicenter,
}

impl std::str::FromStr for Metric {
    type Err = String;
    fn from_str(s: &str) -> Result<Metric, String> {
        match s {
            "mean-abs" | "mean" => Ok(Metric::MeanAbs),
            "max-abs" => Ok(Metric::MaxAbs),
            "epicenter" | "epicentre" => Ok(Metric::Epicenter),
            _ => Err(format!("unknown metric `{s}`; expected mean-abs, max-abs or epicenter")),
        }
    }
}

impl Metric {
    pub fn name(self) -> &'static str {
        match self {
            Metric::MeanAbs => "mean-abs",
            Metric::MaxAbs => "max-abs",
            Metric::Epicenter => "epicenter",
        }
    }
}

/// A parameter to search: its index in the parameter vector, its range, and the grid step (None: integers
/// when the ends are integers, else 40 intervals).
#[derive(Clone, Debug, PartialEq)]
pub struct FreeParam {
    pub index: usize,
    pub name: String,
    pub lo: f64,
    pub hi: f64,
    pub step: Option<f64>,
}

impl FreeParam {
    /// The grid values of stage 1.
    pub fn grid(&self) -> Result<Vec<f64>, CheckError> {
        if !(self.lo.is_finite() && self.hi.is_finite() && self.lo <= self.hi) {
            return Err(CheckError::hint(format!("bad range {}..{} for `{}`", self.lo, self.hi, self.name), "write e.g. a=1..1000"));
        }
        let step = match self.step {
            Some(s) if s > 0.0 && s.is_finite() => s,
            Some(s) => return Err(CheckError::new(format!("step {s} for `{}` must be positive", self.name))),
            None if self.lo.fract() == 0.0 && self.hi.fract() == 0.0 => 1.0,
            None => (self.hi - self.lo) / 40.0,
        };
        let count = ((self.hi - self.lo) / step + 1e-9).floor() + 1.0;
        if count > 1e6 || step == 0.0 && self.hi > self.lo {
            return Err(CheckError::hint(format!("`{}` would take {count} grid values", self.name), "give a coarser step: a=lo..hi:step"));
        }
        Ok((0..count.max(1.0) as usize).map(|i| (self.lo + i as f64 * step).min(self.hi)).collect())
    }

    fn step_size(&self) -> f64 {
        match self.grid() {
            Ok(g) if g.len() > 1 => g[1] - g[0],
            _ => (self.hi - self.lo).max(1e-9),
        }
    }
}

/// One scored parameter vector (the full vector, declaration order).
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    pub params: Vec<f64>,
    pub score: f64,
    /// Found by the continuous refinement rather than the grid.
    pub refined: bool,
}

/// Options for [`fit`].
#[derive(Clone, Debug, PartialEq)]
pub struct FitOptions {
    pub metric: Metric,
    /// How many candidates to return.
    pub top: usize,
    pub refine: bool,
    pub n_max: u32,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions { metric: Metric::MeanAbs, top: 5, refine: true, n_max: 1000 }
    }
}

/// The fit result: the best candidates, best first, and how many scores were computed.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    pub best: Vec<Candidate>,
    pub evaluated: usize,
}

/// Scores candidates against a reference evaluated once.
pub struct Scorer<'a> {
    ev: &'a dyn Evaluator,
    lobe: Input,
    metric: Metric,
    n_max: u32,
    cols: [Vec<f64>; N_INPUTS],
    /// Reference values, row n−1, 91 angles.
    reference: Vec<Vec<f64>>,
    /// Reference at the epicentre for n = 2..=n_max.
    ref_epi: Vec<f64>,
}

impl<'a> Scorer<'a> {
    pub fn new(ev: &'a dyn Evaluator, lobe: Input, reference: &dyn Evaluator, ref_params: &[f64], ref_lobe: Input, metric: Metric, n_max: u32) -> Scorer<'a> {
        let mut cols: [Vec<f64>; N_INPUTS] = Default::default();
        let mut rcols: [Vec<f64>; N_INPUTS] = Default::default();
        for d in 0..=90 {
            let c = f64::from(d).to_radians().cos();
            let (x, xr) = (lobe_inputs(c, lobe), lobe_inputs(c, ref_lobe));
            for k in 0..N_INPUTS {
                cols[k].push(x[k]);
                rcols[k].push(xr[k]);
            }
        }
        let rc = Columns::new([&rcols[0], &rcols[1], &rcols[2], &rcols[3], &rcols[4]]);
        let reference_rows = (1..=n_max)
            .map(|n| {
                let mut out = vec![0.0; 91];
                reference.eval_batch(&rc, &with_n(ref_params, f64::from(n)), &mut out);
                out
            })
            .collect();
        let ref_epi = (2..=n_max)
            .map(|n| {
                let n = f64::from(n);
                reference.eval(&lobe_inputs((-1.2 / n).exp(), ref_lobe), &with_n(ref_params, n))
            })
            .collect();
        Scorer { ev, lobe, metric, n_max, cols, reference: reference_rows, ref_epi }
    }

    /// The metric for one full parameter vector (n is replaced as the metric sweeps it). NaN scores +inf.
    pub fn score(&self, params: &[f64]) -> f64 {
        let c = Columns::new([&self.cols[0], &self.cols[1], &self.cols[2], &self.cols[3], &self.cols[4]]);
        let mut p = params.to_vec();
        let s = match self.metric {
            Metric::MeanAbs | Metric::MaxAbs => {
                let mut out = [0.0; 91];
                let (mut sum, mut max) = (0.0, 0.0f64);
                for n in 1..=self.n_max {
                    p[0] = f64::from(n);
                    self.ev.eval_batch(&c, &p, &mut out);
                    for (a, b) in out.iter().zip(&self.reference[n as usize - 1]) {
                        let d = (a - b).abs();
                        sum += d;
                        max = if d.is_nan() { f64::NAN } else { max.max(d) };
                    }
                }
                if self.metric == Metric::MeanAbs {
                    sum / (91.0 * f64::from(self.n_max))
                } else {
                    max
                }
            }
            Metric::Epicenter => {
                let mut max = 0.0f64;
                for n in 2..=self.n_max {
                    p[0] = f64::from(n);
                    let r = self.ref_epi[n as usize - 2];
                    let d = (self.ev.eval(&lobe_inputs((-1.2 / p[0]).exp(), self.lobe), &p) - r).abs() / r;
                    max = if d.is_nan() { f64::NAN } else { max.max(d) };
                }
                max
            }
        };
        if s.is_nan() {
            f64::INFINITY
        } else {
            s
        }
    }
}

fn with_n(p: &[f64], n: f64) -> Vec<f64> {
    let mut v = p.to_vec();
    if v.is_empty() {
        v.push(n)
    } else {
        v[0] = n
    }
    v
}

/// Fits `free` parameters of `ev` to `reference` (see module docs). `progress` is called once per scored
/// grid candidate (from worker threads).
#[allow(clippy::too_many_arguments)]
pub fn fit(
    ev: &dyn Evaluator,
    base_params: &[f64],
    lobe: Input,
    reference: &dyn Evaluator,
    ref_params: &[f64],
    ref_lobe: Input,
    free: &[FreeParam],
    opts: &FitOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<FitReport, CheckError> {
    if free.is_empty() {
        return Err(CheckError::hint("nothing to fit", "name at least one parameter: --param a=1..1000"));
    }
    if let Some(f) = free.iter().find(|f| f.index == 0 || f.index >= base_params.len()) {
        return Err(CheckError::hint(
            format!("cannot fit `{}`", f.name),
            if f.index == 0 { "n is swept by the metric itself; fit the other parameters" } else { "not a parameter of the formula" },
        ));
    }
    if opts.n_max < 3 {
        return Err(CheckError::new("n_max must be at least 3"));
    }
    let grids: Vec<Vec<f64>> = free.iter().map(FreeParam::grid).collect::<Result<_, _>>()?;
    let total: usize = grids.iter().map(Vec::len).product();
    if total > 2_000_000 {
        return Err(CheckError::hint(format!("the grid has {total} points"), "use coarser steps (a=lo..hi:step) or fewer parameters"));
    }
    let scorer = Scorer::new(ev, lobe, reference, ref_params, ref_lobe, opts.metric, opts.n_max);
    let point = |mut i: usize| {
        let mut p = base_params.to_vec();
        for (f, g) in free.iter().zip(&grids) {
            p[f.index] = g[i % g.len()];
            i /= g.len();
        }
        p
    };
    let mut cands: Vec<Candidate> = (0..total)
        .into_par_iter()
        .map(|i| {
            let p = point(i);
            let score = scorer.score(&p);
            progress();
            Candidate { params: p, score, refined: false }
        })
        .collect();
    let mut evaluated = cands.len();
    cands.sort_by(|a, b| a.score.total_cmp(&b.score));
    cands.truncate(opts.top.max(1));
    if opts.refine {
        if let Some(best) = cands.first().cloned() {
            let (r, used) = refine(&scorer, &best.params, free);
            evaluated += used;
            if r.score < best.score {
                cands.insert(0, r);
                cands.truncate(opts.top.max(1));
            }
        }
    }
    Ok(FitReport { best: cands, evaluated })
}

/// Continuous refinement within one grid step of `start`: golden section (1 parameter) or Nelder–Mead.
fn refine(scorer: &Scorer, start: &[f64], free: &[FreeParam]) -> (Candidate, usize) {
    let mut used = 0;
    let mut eval = |x: &[f64]| {
        let mut p = start.to_vec();
        for (f, v) in free.iter().zip(x) {
            p[f.index] = v.clamp(f.lo, f.hi);
        }
        used += 1;
        (scorer.score(&p), p)
    };
    let x0: Vec<f64> = free.iter().map(|f| start[f.index]).collect();
    let steps: Vec<f64> = free.iter().map(FreeParam::step_size).collect();
    let best = if free.len() == 1 {
        let (f, h) = (&free[0], steps[0]);
        let (mut a, mut b) = ((x0[0] - h).max(f.lo), (x0[0] + h).min(f.hi));
        let g = 0.5 * (5f64.sqrt() - 1.0);
        let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
        let (mut fc, mut fd) = (eval(&[c]).0, eval(&[d]).0);
        for _ in 0..40 {
            if fc < fd {
                (b, d, fd) = (d, c, fc);
                c = b - g * (b - a);
                fc = eval(&[c]).0;
            } else {
                (a, c, fc) = (c, d, fd);
                d = a + g * (b - a);
                fd = eval(&[d]).0;
            }
            if (b - a).abs() < 1e-6 * (1.0 + x0[0].abs()) {
                break;
            }
        }
        eval(&[0.5 * (a + b)])
    } else {
        nelder_mead(&mut eval, &x0, &steps, 200)
    };
    (Candidate { params: best.1, score: best.0, refined: true }, used)
}

fn nelder_mead(eval: &mut impl FnMut(&[f64]) -> (f64, Vec<f64>), x0: &[f64], steps: &[f64], iters: usize) -> (f64, Vec<f64>) {
    let d = x0.len();
    let mut simplex: Vec<(f64, Vec<f64>)> = vec![(eval(x0).0, x0.to_vec())];
    for i in 0..d {
        let mut x = x0.to_vec();
        x[i] += 0.5 * steps[i];
        simplex.push((eval(&x).0, x));
    }
    let lin = |a: &[f64], b: &[f64], t: f64| a.iter().zip(b).map(|(x, y)| x + t * (y - x)).collect::<Vec<f64>>();
    for _ in 0..iters {
        simplex.sort_by(|a, b| a.0.total_cmp(&b.0));
        let centroid: Vec<f64> = (0..d).map(|k| simplex[..d].iter().map(|s| s.1[k]).sum::<f64>() / d as f64).collect();
        let worst = simplex[d].clone();
        let xr = lin(&centroid, &worst.1, -1.0);
        let fr = eval(&xr).0;
        if fr < simplex[0].0 {
            let xe = lin(&centroid, &worst.1, -2.0);
            let fe = eval(&xe).0;
            simplex[d] = if fe < fr { (fe, xe) } else { (fr, xr) };
        } else if fr < simplex[d - 1].0 {
            simplex[d] = (fr, xr);
        } else {
            let xc = lin(&centroid, &worst.1, 0.5);
            let fc = eval(&xc).0;
            if fc < worst.0 {
                simplex[d] = (fc, xc);
            } else {
                let b = simplex[0].1.clone();
                for s in simplex.iter_mut().skip(1) {
                    s.1 = lin(&b, &s.1, 0.5);
                    s.0 = eval(&s.1).0;
                }
            }
        }
        let spread = simplex.iter().map(|s| s.0).fold(f64::NEG_INFINITY, f64::max) - simplex[0].0;
        if spread.abs() < 1e-15 {
            break;
        }
    }
    simplex.sort_by(|a, b| a.0.total_cmp(&b.0));
    let best = simplex.swap_remove(0);
    eval(&best.1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::twins;
    use crate::backend::FnEvaluator;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn finds_a_268_for_f_st_against_blinn() {
        let st = twins::f_st();
        let b = twins::blinn();
        let free = [FreeParam { index: 1, name: "a".into(), lo: 200.0, hi: 340.0, step: None }];
        let count = AtomicUsize::new(0);
        let r = fit(st.ev.as_ref(), &[50.0, 16.0], Input::NH, b.ev.as_ref(), &[50.0], Input::NH, &free, &FitOptions::default(), &|| {
            count.fetch_add(1, Ordering::Relaxed);
        })
        .unwrap();
        assert_eq!(count.load(Ordering::Relaxed), 141);
        let grid_best = r.best.iter().find(|c| !c.refined).unwrap();
        assert_eq!(grid_best.params[1], 268.0, "{:?}", r.best);
        assert!((grid_best.score - 0.000474).abs() < 5e-7);
        // The refinement can only improve, and stays near 268.
        assert!(r.best[0].score <= grid_best.score && (r.best[0].params[1] - 268.0).abs() <= 1.0, "{:?}", r.best[0]);
    }

    #[test]
    fn nelder_mead_recovers_two_parameters() {
        // F = p1·c^(p2·n) against Blinn: exact at p1 = 1, p2 = 1.
        let f = FnEvaluator(|x: &[f64; 5], p: &[f64]| p[1] * x[2].max(0.0).powf(p[2] * p[0]));
        let b = twins::blinn();
        let free = [
            FreeParam { index: 1, name: "s".into(), lo: 0.5, hi: 1.5, step: Some(0.25) },
            FreeParam { index: 2, name: "e".into(), lo: 0.5, hi: 1.5, step: Some(0.25) },
        ];
        let opts = FitOptions { n_max: 30, ..Default::default() };
        let r = fit(&f, &[1.0, 1.0, 1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &free, &opts, &|| {}).unwrap();
        assert_eq!(r.best[0].score, 0.0);
        assert_eq!((r.best[0].params[1], r.best[0].params[2]), (1.0, 1.0));
        // Off-grid optimum: exponent 1.1 is not on the 0.25 grid; the refinement finds it.
        let g = FnEvaluator(|x: &[f64; 5], p: &[f64]| x[2].max(0.0).powf(1.1 * p[0]));
        let free = [FreeParam { index: 1, name: "e".into(), lo: 0.5, hi: 1.5, step: Some(0.25) }];
        let f2 = FnEvaluator(|x: &[f64; 5], p: &[f64]| x[2].max(0.0).powf(p[1] * p[0]));
        let r = fit(&f2, &[1.0, 1.0], Input::NH, &g, &[1.0], Input::NH, &free, &opts, &|| {}).unwrap();
        assert!(r.best[0].refined && (r.best[0].params[1] - 1.1).abs() < 1e-4, "{:?}", r.best[0]);
    }

    #[test]
    fn bad_requests_are_errors() {
        let b = twins::blinn();
        let e = fit(b.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &[], &FitOptions::default(), &|| {});
        assert!(e.unwrap_err().msg.contains("nothing to fit"));
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 5.0, step: None }];
        let e = fit(b.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &free, &FitOptions::default(), &|| {});
        assert!(e.is_err());
        assert!(FreeParam { index: 1, name: "a".into(), lo: 0.0, hi: 1e9, step: Some(1.0) }.grid().is_err());
    }
}
