//! Parameter fitting: find the parameter values that make a lobe closest to a reference lobe.
//!
//! Design: the papers' search, made fast. The metrics are the papers' ones as [`accuracy`](super::accuracy)
//! defines them — the same grid ([`AngleGrid::papers`], 91 angles × n = 1..n_max under the lobe convention of
//! the [module docs](super)), the same epicentre ([`epicenter_cos`]), the same per-row sums
//! ([`RowError`], [`papers_mean`]) — so a candidate's score is bit for bit what `accuracy` reports for it. The
//! reference is evaluated once ([`PapersReference`]); each candidate is then scored with batched evaluations
//! of the formula only (91 points per n), in parallel over candidates (rayon). Stage 1 is exhaustive over a
//! grid (41 values over [lo, hi], the integers for integer ranges wider than that, or `lo..hi:step`); stage 2 refines the best grid point continuously —
//! golden-section search for one free parameter, Nelder–Mead (clamped to the ranges) for several — within
//! one grid step of it; or, with the formula's [`Gradient`] ([`fit_with`]), Levenberg–Marquardt
//! ([`super::lm`]) on the metric's least-squares form from the grid's [`LM_STARTS`] best points.
//!
//! Cost: one mean-|Δ| score is 91 000 formula evaluations; a = 1..1000 for F_ST is 91 M evaluations plus ~60
//! scores for the refinement, so the evaluator's speed decides (measured times: BENCHMARKS.md).

use super::accuracy::{
    check_n_max, epicenter_cos, papers_mean, rel, with_n, AngleGrid, PapersReference, RowError, EPICENTER_FROM,
    PAPERS_ANGLES,
};
use super::grad::{Gradient, Var};
use super::lm::{is_exact, minimize_near, LmResult, Normal};
use super::{lobe_inputs, Diagnostic};
use crate::backend::Evaluator;
use crate::base::json::{self, Named};
use crate::ir::Input;
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

/// Intervals of a parameter's default grid (stage 1) when no step is given.
pub const GRID_INTERVALS: f64 = 40.0;

/// Values of a parameter's coarse grid before a Levenberg–Marquardt refinement (no step given): the centres of
/// this many equal cells of [lo, hi]. The grid only has to put a start in the right basin, the exact Jacobian
/// does the rest; and no start lies on a bound, where the bounds' transform is flat ([`super::lm`], "Bounds").
pub const LM_GRID_POINTS: f64 = 5.0;

/// How many of the grid's best points a Levenberg–Marquardt refinement starts from.
pub const LM_STARTS: usize = 4;

/// The most Levenberg–Marquardt iterations per start.
pub const LM_MAX_ITERATIONS: usize = 200;

/// How a fit refines the best points of its grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Refinement {
    /// Levenberg–Marquardt on the metric's least-squares form with the exact Jacobian
    /// ([`super::grad::Gradient`], [`super::lm`]) from the [`LM_STARTS`] best points of a coarse grid
    /// ([`LM_GRID_POINTS`]).
    #[default]
    Lm,
    /// The fine grid ([`GRID_INTERVALS`]) and golden section or Nelder–Mead around its best point.
    DerivativeFree,
}

impl Refinement {
    pub fn name(self) -> &'static str {
        match self {
            Refinement::Lm => "levenberg-marquardt",
            Refinement::DerivativeFree => "derivative-free",
        }
    }
}

/// Levenberg–Marquardt's statistics, summed over its starts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LmStats {
    pub starts: usize,
    pub iterations: usize,
    /// Evaluations of the value and Jacobian at every point.
    pub evaluations: usize,
}

/// The parameters of `free` that move (lo < hi), and the same with the coarse grid of [`LM_GRID_POINTS`] cell
/// centres where no step was given (their lo and hi the first and last centre: the grid's search only; the
/// refinement moves over the first list's whole ranges); a parameter whose range is one value (lo == hi) is
/// fixed there in `base` and named in the third list instead.
pub fn lm_grid(free: &[FreeParam], base: &mut [f64]) -> (Vec<FreeParam>, Vec<FreeParam>, Vec<String>) {
    let (mut moving, mut grid, mut fixed) = (vec![], vec![], vec![]);
    for f in free {
        if f.lo == f.hi {
            base[f.index] = f.lo;
            fixed.push(f.name.clone());
            continue;
        }
        moving.push(f.clone());
        grid.push(match f.step {
            Some(_) => f.clone(),
            None => {
                let h = (f.hi - f.lo) / LM_GRID_POINTS;
                FreeParam { lo: f.lo + h / 2.0, hi: f.hi - h / 2.0, step: Some(h), ..f.clone() }
            }
        });
    }
    (moving, grid, fixed)
}

/// A parameter to search: its index in the parameter vector, its range — the interval [lo, hi] — and the
/// grid step of stage 1 (None: [`GRID_INTERVALS`] intervals, or the integers when lo and hi are integers at
/// least that many apart). The refinement is continuous over [lo, hi] either way.
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
    pub fn grid(&self) -> Result<Vec<f64>, Diagnostic> {
        if !(self.lo.is_finite() && self.hi.is_finite() && self.lo <= self.hi) {
            return Err(Diagnostic::error(format!("bad range {}..{} for `{}`", self.lo, self.hi, self.name)).hint("write e.g. a=1..1000"));
        }
        let step = match self.step {
            Some(s) if s > 0.0 && s.is_finite() => s,
            Some(s) => return Err(Diagnostic::error(format!("step {s} for `{}` must be positive", self.name))),
            // The integers only where they are at least as fine as the default grid (n = 1..1000, as the
            // papers searched it): `0..1` is the interval [0, 1], not the two values {0, 1}.
            None if self.lo.fract() == 0.0 && self.hi.fract() == 0.0 && self.hi - self.lo >= GRID_INTERVALS => 1.0,
            None => (self.hi - self.lo) / GRID_INTERVALS,
        };
        let count = ((self.hi - self.lo) / step + 1e-9).floor() + 1.0;
        if count > 1e6 || step == 0.0 && self.hi > self.lo {
            return Err(Diagnostic::error(format!("`{}` would take {count} grid values", self.name)).hint("give a coarser step: a=lo..hi:step"));
        }
        let mut g: Vec<f64> = (0..count.max(1.0) as usize).map(|i| (self.lo + i as f64 * step).min(self.hi)).collect();
        // A last value short of hi by rounding alone is hi: the grid spans the whole interval.
        if let Some(last) = g.last_mut() {
            if self.hi - *last <= 1e-9 * step {
                *last = self.hi;
            }
        }
        Ok(g)
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
    /// The refinement that ran ([`Refinement::DerivativeFree`] also when no gradient was given).
    pub refinement: Refinement,
    /// Levenberg–Marquardt's starts, iterations and evaluations (zero for the derivative-free refinement).
    pub lm: LmStats,
}

/// Scores candidates against a reference evaluated once on the papers' grid ([`PapersReference`]).
pub(crate) struct Scorer<'a> {
    ev: &'a dyn Evaluator,
    lobe: Input,
    metric: Metric,
    n_max: u32,
    grid: AngleGrid,
    reference: PapersReference,
}

impl<'a> Scorer<'a> {
    pub(crate) fn new(ev: &'a dyn Evaluator, lobe: Input, reference: &dyn Evaluator, ref_params: &[f64], ref_lobe: Input, metric: Metric, n_max: u32) -> Scorer<'a> {
        let reference = PapersReference::new(reference, ref_params, ref_lobe, n_max);
        Scorer { ev, lobe, metric, n_max, grid: AngleGrid::papers(lobe), reference }
    }

    /// The normal equations of the metric's least-squares form ([`fit_with`]) at `params`, by the variables
    /// `var_of` (indices into `grad.vars`); `None` where a value or partial is not finite.
    fn normal(&self, grad: &Gradient, params: &[f64], var_of: &[usize]) -> Option<Normal> {
        let k = var_of.len();
        let mut p = with_n(params, 1.0);
        let mut n_eq = Normal::zeros(k);
        let mut g = vec![0.0; k];
        match self.metric {
            Metric::MeanAbs | Metric::MaxAbs => {
                let cols: [&[f64]; crate::N_INPUTS] = std::array::from_fn(|i| self.grid.col(i));
                for n in 1..=self.n_max {
                    p[0] = f64::from(n);
                    let gv = grad.run(&cols, &p, PAPERS_ANGLES);
                    for (a, r) in self.reference.row(n).iter().enumerate() {
                        for (j, v) in var_of.iter().enumerate() {
                            g[j] = gv.grad[*v][0][a];
                        }
                        n_eq.add(gv.value[0][a] - r, &g);
                    }
                }
            }
            Metric::Epicenter => {
                for n in EPICENTER_FROM..=self.n_max {
                    p[0] = f64::from(n);
                    let r = self.reference.at_epicenter(n);
                    if r == 0.0 {
                        continue;
                    }
                    let (v, d) = grad.eval(&lobe_inputs(epicenter_cos(p[0]), self.lobe), &p);
                    for (j, vi) in var_of.iter().enumerate() {
                        g[j] = d[*vi][0] / r;
                    }
                    n_eq.add((v[0] - r) / r, &g);
                }
            }
        }
        Some(n_eq)
    }

    /// Σ y² of the targets the least-squares form of the metric ([`Scorer::normal`]) is measured from: the
    /// reference's values over the papers' grid (mean-abs, max-abs), 1 per epicentre (epicenter: relative).
    fn targets(&self) -> f64 {
        match self.metric {
            Metric::MeanAbs | Metric::MaxAbs => (1..=self.n_max).map(|n| self.reference.row(n).iter().map(|r| r * r).sum::<f64>()).sum(),
            Metric::Epicenter => (EPICENTER_FROM..=self.n_max).filter(|n| self.reference.at_epicenter(*n) != 0.0).count() as f64,
        }
    }

    /// The metric for one full parameter vector (n is replaced as the metric sweeps it). A NaN anywhere
    /// scores +inf. Mean |Δ| is [`papers_mean`], bit for bit what [`accuracy`](super::accuracy::accuracy)
    /// reports as `mean_abs_grid` for the same parameters.
    pub(crate) fn score(&self, params: &[f64]) -> f64 {
        let mut p = with_n(params, 1.0);
        let s = match self.metric {
            Metric::MeanAbs | Metric::MaxAbs => {
                let mut out = [0.0; PAPERS_ANGLES];
                let mut rows = Vec::with_capacity(self.n_max as usize);
                for n in 1..=self.n_max {
                    p[0] = f64::from(n);
                    self.grid.eval_into(self.ev, &p, &mut out);
                    rows.push(RowError::new(&out, self.reference.row(n)));
                }
                let nan = rows.iter().map(|r| r.nan).sum();
                if self.metric == Metric::MeanAbs {
                    papers_mean(rows.iter().map(|r| r.sum), nan, self.n_max)
                } else if nan > 0 {
                    f64::NAN
                } else {
                    rows.iter().fold(0.0f64, |m, r| m.max(r.max))
                }
            }
            Metric::Epicenter => {
                let mut max = 0.0f64;
                for n in EPICENTER_FROM..=self.n_max {
                    p[0] = f64::from(n);
                    let c = epicenter_cos(p[0]);
                    let d = rel(self.ev.eval(&lobe_inputs(c, self.lobe), &p), self.reference.at_epicenter(n));
                    max = if d.is_nan() || max.is_nan() { f64::NAN } else { max.max(d) };
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

/// Refuses a fit of `n` (the metric sweeps it), of an index past the formula's parameters, or of a bad `n_max`.
fn check_request(base_params: &[f64], free: &[FreeParam], opts: &FitOptions) -> Result<(), Diagnostic> {
    if let Some(f) = free.iter().find(|f| f.index == 0 || f.index >= base_params.len()) {
        return Err(Diagnostic::error(format!("cannot fit `{}`", f.name))
            .hint(if f.index == 0 { "n is swept by the metric itself; fit the other parameters" } else { "not a parameter of the formula" }));
    }
    check_n_max(opts.n_max)
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
) -> Result<FitReport, Diagnostic> {
    check_request(base_params, free, opts)?;
    let scorer = Scorer::new(ev, lobe, reference, ref_params, ref_lobe, opts.metric, opts.n_max);
    search(base_params, free, opts.top, opts.refine, &|p| scorer.score(p), progress)
}

/// [`fit`] with the Levenberg–Marquardt refinement where `grad` (the formula's [`Gradient`] by the free
/// parameters) is given and `opts.refine` is on: the grid of stage 1 is the papers' own search and stays as it
/// is; Levenberg–Marquardt starts from its [`LM_STARTS`] best points and minimises the metric's least-squares
/// form — Σ (F − R)² over the papers' grid for mean-abs and max-abs, Σ ((F − R)/R)² over the epicentres for
/// epicenter — and its result is a candidate scored by the metric itself, ahead of the grid's only if it scores
/// lower (the least-squares optimum need not be the mean-|Δ| one).
#[allow(clippy::too_many_arguments)]
pub fn fit_with(
    ev: &dyn Evaluator,
    grad: Option<&Gradient>,
    base_params: &[f64],
    lobe: Input,
    reference: &dyn Evaluator,
    ref_params: &[f64],
    ref_lobe: Input,
    free: &[FreeParam],
    opts: &FitOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<FitReport, Diagnostic> {
    let Some(grad) = grad.filter(|_| opts.refine) else {
        return fit(ev, base_params, lobe, reference, ref_params, ref_lobe, free, opts, progress);
    };
    check_request(base_params, free, opts)?;
    let scorer = Scorer::new(ev, lobe, reference, ref_params, ref_lobe, opts.metric, opts.n_max);
    let top = opts.top.max(1);
    let mut rep = search(base_params, free, top.max(LM_STARTS), false, &|p| scorer.score(p), progress)?;
    // Parameters whose range is one value stay where the grid put them (lo).
    let moving: Vec<&FreeParam> = free.iter().filter(|f| f.lo < f.hi).collect();
    let var_of: Vec<usize> = moving
        .iter()
        .map(|f| grad.vars.iter().position(|v| *v == Var::Param(f.index as u16)))
        .collect::<Option<_>>()
        .ok_or_else(|| Diagnostic::error("the gradient lacks a searched parameter's partial"))?;
    let mut lm = LmStats::default();
    let mut best: Option<Candidate> = None;
    if !moving.is_empty() {
        let starts: Vec<Vec<f64>> = rep.best.iter().take(LM_STARTS).map(|c| c.params.clone()).collect();
        let targets = scorer.targets();
        let mut found: Vec<LmResult> = vec![];
        for start in &starts {
            // No start can do better than one that fits exactly (docs of super::lm, "Several starts").
            if found.iter().any(|r| is_exact(r.cost, targets)) {
                break;
            }
            let params_of = |x: &[f64]| {
                let mut p = start.clone();
                for (f, v) in moving.iter().zip(x) {
                    p[f.index] = *v;
                }
                p
            };
            let eval = |x: &[f64]| scorer.normal(grad, &params_of(x), &var_of);
            let x0: Vec<f64> = moving.iter().map(|f| start[f.index]).collect();
            let bounds: Vec<Option<(f64, f64)>> = moving.iter().map(|f| Some((f.lo, f.hi))).collect();
            let Some(r) = minimize_near(&eval, &x0, &bounds, LM_MAX_ITERATIONS, &found) else { continue };
            lm.starts += 1;
            lm.iterations += r.iterations;
            lm.evaluations += r.evaluations;
            // A start that joined an earlier one's minimum adds nothing new.
            if r.joined.is_some() {
                continue;
            }
            let params = params_of(&r.x);
            let score = scorer.score(&params);
            rep.evaluated += 1;
            if best.as_ref().is_none_or(|b| score < b.score) {
                best = Some(Candidate { params, score, refined: true });
            }
            found.push(r);
        }
    }
    if let Some(b) = best.filter(|b| rep.best.first().is_none_or(|g| b.score < g.score)) {
        rep.best.insert(0, b);
    }
    rep.best.truncate(top);
    Ok(FitReport { refinement: Refinement::Lm, lm, ..rep })
}

/// The search of [`fit`] over any score (lower is better; a NaN should score +inf): stage 1 scores every
/// point of the free parameters' grid in parallel, stage 2 refines the best one continuously (golden
/// section for one parameter, Nelder–Mead for several) within one grid step. Returns the `top` best.
pub fn search(
    base_params: &[f64],
    free: &[FreeParam],
    top: usize,
    refine_best: bool,
    score: &(dyn Fn(&[f64]) -> f64 + Sync),
    progress: &(dyn Fn() + Sync),
) -> Result<FitReport, Diagnostic> {
    if free.is_empty() {
        return Err(Diagnostic::error("nothing to fit").hint(super::NumericsAdvice::FitSomeParam));
    }
    let grids: Vec<Vec<f64>> = free.iter().map(FreeParam::grid).collect::<Result<_, _>>()?;
    let total: usize = grids.iter().map(Vec::len).product();
    if total > 2_000_000 {
        return Err(Diagnostic::error(format!("the grid has {total} points")).hint("use coarser steps (a=lo..hi:step) or fewer parameters"));
    }
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
            let score = score(&p);
            progress();
            Candidate { params: p, score, refined: false }
        })
        .collect();
    let mut evaluated = cands.len();
    cands.sort_by(|a, b| a.score.total_cmp(&b.score));
    cands.truncate(top.max(1));
    if refine_best {
        if let Some(best) = cands.first().cloned() {
            let (r, used) = refine(score, &best.params, free);
            evaluated += used;
            if r.score < best.score {
                cands.insert(0, r);
                cands.truncate(top.max(1));
            }
        }
    }
    Ok(FitReport { best: cands, evaluated, refinement: Refinement::DerivativeFree, lm: LmStats::default() })
}

/// What [`fit_points`] minimises over the points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Loss {
    /// The weighted mean of squared differences, Σ w·(f − t)² / Σ w (least squares).
    #[default]
    Mse,
    /// The weighted mean of absolute differences, Σ w·|f − t| / Σ w.
    Mae,
    /// The largest weighted absolute difference, max w·|f − t|.
    Max,
}

impl std::str::FromStr for Loss {
    type Err = String;
    fn from_str(s: &str) -> Result<Loss, String> {
        match s {
            "mse" => Ok(Loss::Mse),
            "mae" => Ok(Loss::Mae),
            "max" => Ok(Loss::Max),
            _ => Err(format!("unknown loss `{s}`; expected mse, mae or max")),
        }
    }
}

/// Target values to fit at given points: the inputs as batch columns, for each channel kernel its `len`
/// target values (`target` holds them channel after channel), and optional per-point weights (≥ 0).
#[derive(Clone, Copy, Debug)]
pub struct PointsTarget<'a> {
    pub cols: crate::Columns<'a>,
    pub len: usize,
    pub target: &'a [f64],
    pub weights: Option<&'a [f64]>,
}

impl PointsTarget<'_> {
    /// The loss of `channels` (one evaluator per channel) at the full parameter vector `params`, by the batched
    /// kernels; NaN anywhere (or no positive weight) scores +inf.
    pub fn score(&self, channels: &[&dyn Evaluator], params: &[f64], loss: Loss) -> f64 {
        let mut out = vec![0.0; self.len];
        let (mut sum, mut wsum, mut max) = (0.0f64, 0.0f64, 0.0f64);
        for (c, ev) in channels.iter().enumerate() {
            ev.eval_batch(&self.cols, params, &mut out);
            let t = &self.target[c * self.len..(c + 1) * self.len];
            for (i, (f, t)) in out.iter().zip(t).enumerate() {
                let w = self.weights.map_or(1.0, |w| w[i]);
                let d = (f - t).abs();
                let e = if loss == Loss::Mse { d * d } else { d };
                if e.is_nan() {
                    return f64::INFINITY;
                }
                sum += w * e;
                wsum += w;
                max = max.max(w * d);
            }
        }
        let s = match loss {
            Loss::Max => max,
            _ if wsum > 0.0 => sum / wsum,
            _ => f64::INFINITY,
        };
        if s.is_nan() {
            f64::INFINITY
        } else {
            s
        }
    }
}

/// Fits `free` parameters of `channels` (one evaluator per channel of one formula) to target values at given
/// points ([`PointsTarget`]), by [`search`] over the loss. The shapes are the caller's to check: every read
/// column, and the weights, have `len` values, and `target` has `len` per channel.
#[allow(clippy::too_many_arguments)]
pub fn fit_points(
    channels: &[&dyn Evaluator],
    base_params: &[f64],
    points: &PointsTarget,
    loss: Loss,
    free: &[FreeParam],
    top: usize,
    refine_best: bool,
) -> Result<FitReport, Diagnostic> {
    if points.target.len() != points.len * channels.len() || points.weights.is_some_and(|w| w.len() != points.len) {
        return Err(Diagnostic::error(format!(
            "{} target values and {} weights for {} points of {} channel(s)",
            points.target.len(),
            points.weights.map_or(0, <[f64]>::len),
            points.len,
            channels.len()
        )));
    }
    if points.weights.is_some_and(|w| w.iter().any(|w| !(*w >= 0.0 && w.is_finite()))) {
        return Err(Diagnostic::error("a weight is negative or not finite").hint("weights are finite numbers ≥ 0"));
    }
    // A NaN or infinite target makes every candidate's loss NaN or inf: a fit of nothing, not a result.
    if let Some(i) = points.target.iter().position(|t| !t.is_finite()) {
        let (channel, point) = (i / points.len.max(1), i % points.len.max(1));
        let which = if channels.len() > 1 { format!("point {point}, channel {channel}") } else { format!("point {point}") };
        return Err(Diagnostic::error(format!("the target is {} at {which}", points.target[i]))
            .hint("targets are finite numbers: leave that point out"));
    }
    search(base_params, free, top, refine_best, &|p| points.score(channels, p, loss), &|| {})
}

/// Continuous refinement within one grid step of `start`: golden section (1 parameter) or Nelder–Mead.
pub(crate) fn refine(score: &(dyn Fn(&[f64]) -> f64 + Sync), start: &[f64], free: &[FreeParam]) -> (Candidate, usize) {
    let mut used = 0;
    let mut eval = |x: &[f64]| {
        let mut p = start.to_vec();
        for (f, v) in free.iter().zip(x) {
            p[f.index] = v.clamp(f.lo, f.hi);
        }
        used += 1;
        (score(&p), p)
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

/// The fit command's JSON report (keys listed in docs/commands.md; numbers follow [`crate::base::json`]).
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitJson {
    /// Best first.
    pub best: Vec<CandidateJson>,
    pub metric: &'static str,
    pub evaluated: usize,
    /// [`Refinement::name`].
    pub refinement: &'static str,
    pub lm: LmStats,
    #[serde(serialize_with = "json::num")]
    pub seconds: f64,
}

/// A [`Candidate`]: the searched parameters by name.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CandidateJson {
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub score: f64,
    pub refined: bool,
}

impl FitJson {
    /// `free` are the searched parameters.
    pub fn new(rep: &FitReport, free: &[FreeParam], metric: Metric, seconds: f64) -> FitJson {
        let best = rep
            .best
            .iter()
            .map(|c| CandidateJson {
                params: Named::new(free.iter().map(|f| (f.name.as_str(), c.params[f.index]))),
                score: c.score,
                refined: c.refined,
            })
            .collect();
        FitJson { best, metric: metric.name(), evaluated: rep.evaluated, refinement: rep.refinement.name(), lm: rep.lm, seconds }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::FnEvaluator;
    use crate::numerics::accuracy::{accuracy, AccuracyOptions};
    use crate::numerics::twins;
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
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| p[1] * x[2].max(0.0).powf(p[2] * p[0]));
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
        let g = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| x[2].max(0.0).powf(1.1 * p[0]));
        let free = [FreeParam { index: 1, name: "e".into(), lo: 0.5, hi: 1.5, step: Some(0.25) }];
        let f2 = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| x[2].max(0.0).powf(p[1] * p[0]));
        let r = fit(&f2, &[1.0, 1.0], Input::NH, &g, &[1.0], Input::NH, &free, &opts, &|| {}).unwrap();
        assert!(r.best[0].refined && (r.best[0].params[1] - 1.1).abs() < 1e-4, "{:?}", r.best[0]);
    }

    #[test]
    fn levenberg_marquardt_reaches_an_off_grid_optimum_under_every_metric() {
        // s·NH^(e·n) against Blinn is exact at s = e = 1, a point on neither parameter's grid.
        let src = "param n = 50 in 1..1000\nparam s = 1 in 0..2\nparam e = 1 in 0.1..3\ns * pow(NH, e * n)";
        let f = crate::front::parse("t.brdf", src).unwrap();
        let opts = crate::Options { backend: crate::Backend::Interp, ..Default::default() };
        let k = crate::compile_formula(f.clone(), &opts).unwrap();
        let g = Gradient::compile_vars(&f, &opts, Some(&[Var::Param(1), Var::Param(2)])).unwrap();
        let b = twins::blinn();
        let free = [
            FreeParam { index: 1, name: "s".into(), lo: 0.5, hi: 1.6, step: None },
            FreeParam { index: 2, name: "e".into(), lo: 0.55, hi: 1.9, step: None },
        ];
        for metric in [Metric::MeanAbs, Metric::MaxAbs, Metric::Epicenter] {
            let o = FitOptions { metric, n_max: 40, ..Default::default() };
            let r = fit_with(&k, Some(&g), &[50.0, 1.0, 1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &free, &o, &|| {}).unwrap();
            let best = &r.best[0];
            // Every metric's least-squares form is fitted exactly here: the first start ends the search.
            assert!(best.refined && r.refinement == Refinement::Lm && r.lm.starts == 1, "{metric:?}: {r:?}");
            // The epicentre sees s·exp(−1.2·e) only: any (s, e) on that curve is exact there.
            let exact = (best.params[1] - 1.0).abs() < 1e-9 && (best.params[2] - 1.0).abs() < 1e-9;
            assert!(exact || metric == Metric::Epicenter, "{metric:?}: {best:?}");
            assert!(best.score < 1e-12, "{metric:?}: {best:?}");
            // The derivative-free search, for comparison, does no better.
            let old = fit(&k, &[50.0, 1.0, 1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &free, &o, &|| {}).unwrap();
            assert!(best.score <= old.best[0].score, "{metric:?}: {best:?} vs {:?}", old.best[0]);
        }
    }

    #[test]
    fn scores_are_the_accuracy_reports_numbers() {
        // One definition of the papers' grid and epicentre: a fit's score is, bit for bit, what `accuracy`
        // reports for the same parameters.
        let (st, b) = (twins::f_st(), twins::blinn());
        let p = [1.0, 268.0];
        let opts = AccuracyOptions { n_max: 100, ..Default::default() };
        let acc = accuracy(st.ev.as_ref(), &p, Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &opts).unwrap();
        let score = |metric| Scorer::new(st.ev.as_ref(), Input::NH, b.ev.as_ref(), &[1.0], Input::NH, metric, 100).score(&p);
        assert_eq!(score(Metric::MeanAbs).to_bits(), acc.mean_abs_grid.to_bits());
        assert_eq!(score(Metric::Epicenter).to_bits(), acc.epicenter.value.to_bits());
    }

    #[test]
    fn a_nan_anywhere_scores_infinity() {
        // NaN at one n in the middle of the sweep (not only at the last one) makes every metric +inf.
        let b = twins::blinn();
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| if p[0] == 5.0 { f64::NAN } else { x[2].max(0.0).powf(p[0]) });
        for metric in [Metric::MeanAbs, Metric::MaxAbs, Metric::Epicenter] {
            let s = Scorer::new(&f, Input::NH, b.ev.as_ref(), &[1.0], Input::NH, metric, 20).score(&[1.0]);
            assert_eq!(s, f64::INFINITY, "{metric:?}");
        }
        let s = Scorer::new(b.ev.as_ref(), Input::NH, b.ev.as_ref(), &[1.0], Input::NH, Metric::MaxAbs, 20).score(&[1.0]);
        assert_eq!(s, 0.0);
    }

    #[test]
    fn bad_requests_are_errors() {
        let b = twins::blinn();
        let e = fit(b.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &[], &FitOptions::default(), &|| {});
        assert!(e.unwrap_err().message.contains("nothing to fit"));
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 5.0, step: None }];
        let e = fit(b.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &free, &FitOptions::default(), &|| {});
        assert!(e.is_err());
        assert!(FreeParam { index: 1, name: "a".into(), lo: 0.0, hi: 1e9, step: Some(1.0) }.grid().is_err());
    }

    #[test]
    fn the_levenberg_marquardt_grid_is_cell_centres_inside_the_range() {
        let mut rng = crate::base::rng::Rng(0x1f3d_5b79);
        for _ in 0..100 {
            let lo = rng.unit() * 10.0 - 5.0;
            let hi = lo + 1e-3 + rng.unit() * 10.0;
            let step = (rng.unit() < 0.3).then(|| (hi - lo) / 7.0);
            let free = [
                FreeParam { index: 1, name: "a".into(), lo, hi, step },
                FreeParam { index: 2, name: "b".into(), lo: hi, hi, step: None },
            ];
            let mut base = [0.0; 3];
            let (moving, grid, fixed) = lm_grid(&free, &mut base);
            // The one-value range is fixed; the other moves over its whole range.
            assert_eq!((base[2], fixed), (hi, vec!["b".to_string()]));
            assert_eq!(moving, free[..1]);
            let g = grid[0].grid().unwrap();
            if step.is_some() {
                assert_eq!(g, free[0].grid().unwrap());
                continue;
            }
            let h = (hi - lo) / LM_GRID_POINTS;
            assert_eq!(g.len(), LM_GRID_POINTS as usize, "{lo}..{hi}: {g:?}");
            for (i, v) in g.iter().enumerate() {
                assert!((v - (lo + (i as f64 + 0.5) * h)).abs() <= 1e-12 * (1.0 + v.abs()), "{lo}..{hi}: {g:?}");
                assert!(*v > lo && *v < hi);
            }
        }
    }

    #[test]
    fn a_range_is_an_interval_whatever_its_ends_look_like() {
        let grid = |lo: f64, hi: f64| FreeParam { index: 0, name: "p".into(), lo, hi, step: None }.grid().unwrap();
        // Integer-looking ends narrower than the default grid: 41 values over [lo, hi], not the integers.
        for (lo, hi) in [(0.0, 1.0), (1.0, 4.0), (0.0, 39.0), (-2.0, 2.0)] {
            let g = grid(lo, hi);
            assert_eq!(g.len(), 41, "{lo}..{hi}");
            assert_eq!((g[0], g[40]), (lo, hi));
            assert!(g.windows(2).all(|w| w[1] > w[0]));
        }
        assert!(grid(0.0, 1.0).iter().any(|v| (v - 0.6).abs() < 1e-12));
        // Wide integer ranges keep the papers' integer grid; random real ranges get 41 values.
        assert_eq!(grid(1.0, 1000.0), (1..=1000).map(f64::from).collect::<Vec<_>>());
        let mut rng = crate::base::rng::Rng(0x9e37_79b9_7f4a_7c15);
        for _ in 0..100 {
            let lo = rng.unit() * 10.0 - 5.0;
            let hi = lo + 1e-3 + rng.unit() * 10.0;
            let g = grid(lo, hi);
            assert_eq!((g.len(), g[0], g[40]), (41, lo, hi), "{lo}..{hi}");
        }
    }
}
