//! A formula against a measurement ([`crate::measured`]): the residual under a named metric with the best
//! per-channel colour scale, and the fit of the formula's parameters to the table ([`fit_measured`]: a coarse
//! grid through [`super::fit::search`], then Levenberg–Marquardt with the exact Jacobian ([`lm_refine`]), or
//! the papers' fits' fine grid + derivative-free refinement).
//!
//! # Where it is measured
//! At the table's own entries, at the convention's angles ([`crate::measured::entry_dirs`]), every entry
//! measured in all three channels, taking every `stride`-th index along each of θ_h, θ_d and φ_d (stride 1:
//! all of them, ~0.75 M for a full table; 4: 1/64 of them). Nothing is re-sampled or interpolated. The
//! formula is evaluated once per entry (its batched kernel), the kernel inputs built from the entry's L and V
//! by [`crate::frame`], so the formula sees what a render would.
//!
//! # The metrics (per channel c, entry i; the formula's value f, the measurement m, cos θ_i = N·L)
//! - `log` (the fitting literature's cosine-weighted log error; Löw et al. 2012, after Ngan et al. 2005):
//!   E = √( Σ (ln(1 + s_c·f·cosθ_i) − ln(1 + m·cosθ_i))² / (3N) ). The log compresses the specular peak, so
//!   the fit weighs the lobe's shape, not only its peak; the cosine weights the entries as light reaching the
//!   eye does. A negative s·f counts as 0 here.
//! - `rmse`: plain E = √( Σ (s_c·f − m)² / (3N) ).
//! - `cosine` (the cosine-weighted L2 of Ngan et al. 2005, after Lafortune et al. 1997): the error of the
//!   reflected radiance per unit irradiance, E = √( Σ (s_c·f − m)²·cos²θ_i / (3N) ).
//!
//! # Against a formula
//! The reference can be another formula instead of a table ([`FormulaReference`]): its values at the same
//! entries (the table convention's angles, every `stride`-th index), and for a pair of formulas that is not
//! isotropic also with the half vector turned about the normal ([`AZIMUTHS`] values of φ_h), so that the
//! metric covers the whole hemisphere of both directions. A formula's values are absolute, so no colour scale
//! is fitted against one (s_c = 1) unless asked ([`Samples::fit_scale`]); a table's calibration is unknown,
//! so the scale is fitted against it.
//!
//! # The colour scale
//! The scale s_c ≥ 0 is solved in closed form per channel for each candidate: for `rmse` the least-squares
//! s_c = Σ f·m / Σ f², for `cosine` the same with the weight cos²θ_i; for `log` the weighted least squares of the metric linearised about the measured
//! values (Gauss–Newton's first step from the data: residual ≈ (s·a − y)/(1 + y), a = f·cosθ_i, y = m·cosθ_i),
//! s_c = Σ w·a·y / Σ w·a², w = 1/(1 + y)². Exact when the formula can match the data (a synthetic table of the
//! formula itself), and close to the metric's own optimum otherwise.
//!
//! Cost: one candidate is one batched kernel call over the entries plus ~4 flops and (log) one `ln` per
//! entry and channel; the grid stage runs on a coarser stride than the refinement (the caller's choice).

use super::fit::{lm_grid, search, Candidate, FreeParam, LmStats, Refinement, LM_MAX_ITERATIONS, LM_STARTS};
use super::grad::{Gradient, Var};
use super::lm::{is_exact, minimize_near, LmResult, Normal};
use super::Diagnostic;
use crate::backend::{Columns, Evaluator};
use crate::frame::V3;
use crate::ir::N_INPUTS;
use crate::measured::{self, Measured, DIMS};
use rayon::prelude::*;

/// What a measured fit minimises (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MeasuredMetric {
    /// Cosine-weighted log error.
    #[default]
    Log,
    /// Plain RMSE.
    Rmse,
    /// Cosine-weighted L2 (Ngan et al. 2005).
    Cosine,
}

impl std::str::FromStr for MeasuredMetric {
    type Err = String;
    fn from_str(s: &str) -> Result<MeasuredMetric, String> {
        match s {
            "log" => Ok(MeasuredMetric::Log),
            "rmse" => Ok(MeasuredMetric::Rmse),
            "cosine" => Ok(MeasuredMetric::Cosine),
            _ => Err(format!("unknown metric `{s}` for a measured fit; expected log, rmse or cosine")),
        }
    }
}

impl MeasuredMetric {
    pub fn name(self) -> &'static str {
        match self {
            MeasuredMetric::Log => "log",
            MeasuredMetric::Rmse => "rmse",
            MeasuredMetric::Cosine => "cosine",
        }
    }

    /// Every metric, in the order reports list them.
    pub const ALL: [MeasuredMetric; 3] = [MeasuredMetric::Log, MeasuredMetric::Rmse, MeasuredMetric::Cosine];
}

/// A table's measured entries at the convention's angles: the kernel inputs (columns) and the values.
pub struct Samples {
    pub stride: usize,
    cols: Vec<Vec<f64>>,
    /// Red, green, blue measured values.
    m: [Vec<f64>; 3],
    /// cos θ_i (= NL) per entry.
    cos: Vec<f64>,
    /// ln(1 + m·cos θ_i) per channel.
    log_m: [Vec<f64>; 3],
    /// Whether a colour scale is fitted (a table's unknown calibration) or s_c = 1 (a formula's absolute values).
    pub fit_scale: bool,
}

/// Where a fit's reference values come from: a measured table, or a formula at the same angles.
pub trait Reference: Send + Sync {
    /// The name reports use (the file).
    fn name(&self) -> &str;
    /// The entries at every `stride`-th index per axis.
    fn samples(&self, stride: usize) -> Samples;
}

impl Reference for Measured {
    fn name(&self) -> &str {
        &self.name
    }
    fn samples(&self, stride: usize) -> Samples {
        Samples::new(self, stride)
    }
}

/// Values of φ_h at which a pair of formulas that is not isotropic is compared (k·360°/AZIMUTHS).
pub const AZIMUTHS: usize = 8;

/// A formula as a fit's reference (module docs): its kernel (or red, green, blue ones) at `params`.
pub struct FormulaReference {
    pub name: String,
    pub channels: Vec<std::sync::Arc<dyn Evaluator>>,
    pub params: Vec<f64>,
    /// Whether to compare at [`AZIMUTHS`] values of φ_h (else at φ_h = 0 only, enough when both formulas are
    /// isotropic: [`turns_with_the_frame`]).
    pub azimuths: bool,
    /// Fit a colour scale against it (default: its values are absolute, s_c = 1).
    pub fit_scale: bool,
}

impl FormulaReference {
    /// The formula `channels` (named `name`) at `params` as a reference: compared at φ_h turns too unless it and
    /// every formula compared with it (`others`: kernels and their parameter values) are isotropic
    /// ([`turns_with_the_frame`]); a colour scale fitted only when `fit_scale`.
    pub fn new(name: &str, channels: Vec<std::sync::Arc<dyn Evaluator>>, params: Vec<f64>, others: &[(&dyn Evaluator, Vec<f64>)], fit_scale: bool) -> FormulaReference {
        let azimuths = !(channels.iter().all(|k| turns_with_the_frame(k.as_ref(), &params)) && others.iter().all(|(k, p)| turns_with_the_frame(*k, p)));
        FormulaReference { name: name.to_string(), channels, params, azimuths, fit_scale }
    }
}

impl Reference for FormulaReference {
    fn name(&self) -> &str {
        &self.name
    }
    fn samples(&self, stride: usize) -> Samples {
        let stride = stride.max(1);
        let turns = if self.azimuths { AZIMUTHS } else { 1 };
        let mut cols = vec![vec![]; N_INPUTS];
        let mut cos = vec![];
        for i in (0..DIMS[0]).step_by(stride) {
            for j in (0..DIMS[1]).step_by(stride) {
                for k in (0..DIMS[2]).step_by(stride) {
                    let (l, w) = measured::entry_dirs(i, j, k);
                    for t in 0..turns {
                        let (l, w) = (turn(l, t), turn(w, t));
                        if !(l[2] > 0.0 && w[2] > 0.0) {
                            continue;
                        }
                        for (c, xv) in cols.iter_mut().zip(crate::frame::inputs_from_dirs(l, w)) {
                            c.push(xv);
                        }
                        cos.push(l[2]);
                    }
                }
            }
        }
        let all = Samples { stride, cols, m: Default::default(), cos, log_m: Default::default(), fit_scale: self.fit_scale };
        let values: Vec<Vec<f64>> = self.channels.iter().map(|ev| all.eval(ev.as_ref(), &self.params)).collect();
        // An entry where the reference is not finite is not a reference value: left out, as a table leaves out
        // what it did not measure.
        let keep: Vec<bool> = (0..all.len()).map(|e| values.iter().all(|v| v[e].is_finite())).collect();
        let pick = |v: &[f64]| v.iter().zip(&keep).filter(|(_, k)| **k).map(|(x, _)| *x).collect::<Vec<f64>>();
        let m: [Vec<f64>; 3] = std::array::from_fn(|c| pick(&values[c.min(values.len() - 1)]));
        let cos = pick(&all.cos);
        let log_m = std::array::from_fn(|c| m[c].iter().zip(&cos).map(|(v, k)| (v * k).max(0.0).ln_1p()).collect());
        Samples { stride, cols: all.cols.iter().map(|c| pick(c)).collect(), m, cos, log_m, fit_scale: self.fit_scale }
    }
}

/// `d` turned about the normal by the `t`-th of [`AZIMUTHS`] angles.
fn turn(d: V3, t: usize) -> V3 {
    if t == 0 {
        return d;
    }
    let (s, c) = (std::f64::consts::TAU * t as f64 / AZIMUTHS as f64).sin_cos();
    [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]]
}

/// Whether `ev` at `params` gives the same values (within 1e-9 relative) with both directions turned about the
/// normal, at every [`AZIMUTHS`] angle and 500 random pairs: an isotropic formula, which a comparison at
/// φ_h = 0 covers.
pub fn turns_with_the_frame(ev: &dyn Evaluator, params: &[f64]) -> bool {
    let mut rng = crate::base::rng::Rng(0x150);
    let mut hemi = || {
        let (u, v) = (rng.unit(), rng.unit());
        let (r, phi) = ((1.0 - u * u).sqrt(), std::f64::consts::TAU * v);
        [r * phi.cos(), r * phi.sin(), u.max(1e-3)]
    };
    (0..500).all(|_| {
        let (l, w) = (hemi(), hemi());
        let a = ev.eval(&crate::frame::inputs_from_dirs(l, w), params);
        (1..AZIMUTHS).all(|t| {
            let b = ev.eval(&crate::frame::inputs_from_dirs(turn(l, t), turn(w, t)), params);
            a == b || (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) || (a.is_nan() && b.is_nan())
        })
    })
}

impl Samples {
    /// Every `stride`-th index along each axis (≥ 1) of the entries measured in all three channels, in index
    /// order (built a θ_h row per task, in parallel).
    pub fn new(t: &Measured, stride: usize) -> Samples {
        let stride = stride.max(1);
        let rows: Vec<usize> = (0..DIMS[0]).step_by(stride).collect();
        let dirs = measured::EntryDirs::new();
        let per_row = DIMS[1].div_ceil(stride) * DIMS[2].div_ceil(stride);
        // Per row: the N_INPUTS columns, m in three channels, cos θ_i, ln(1 + m·cos θ_i) in three channels.
        let parts: Vec<Vec<Vec<f64>>> = rows
            .into_par_iter()
            .map(|i| {
                let mut out: Vec<Vec<f64>> = (0..N_INPUTS + 7).map(|_| Vec::with_capacity(per_row)).collect();
                for j in (0..DIMS[1]).step_by(stride) {
                    for k in (0..DIMS[2]).step_by(stride) {
                        let e = measured::index(i, j, k);
                        let (Some(r), Some(g), Some(b)) = (t.value(0, e), t.value(1, e), t.value(2, e)) else { continue };
                        let (l, w) = dirs.at(i, j, k);
                        if !(l[2] > 0.0 && w[2] > 0.0) {
                            continue;
                        }
                        let x = crate::frame::inputs_from_dirs(l, w);
                        for (c, xv) in out.iter_mut().zip(x) {
                            c.push(xv);
                        }
                        for (c, v) in [r, g, b].into_iter().enumerate() {
                            out[N_INPUTS + c].push(v);
                            out[N_INPUTS + 4 + c].push((v * l[2]).ln_1p());
                        }
                        out[N_INPUTS + 3].push(l[2]);
                    }
                }
                out
            })
            .collect();
        let mut all: Vec<Vec<f64>> = (0..N_INPUTS + 7).map(|c| Vec::with_capacity(parts.iter().map(|p| p[c].len()).sum())).collect();
        for p in parts {
            all.iter_mut().zip(p).for_each(|(a, b)| a.extend(b));
        }
        let mut all = all.into_iter();
        let cols: Vec<Vec<f64>> = all.by_ref().take(N_INPUTS).collect();
        let m: [Vec<f64>; 3] = std::array::from_fn(|_| all.next().unwrap_or_default());
        let cos = all.next().unwrap_or_default();
        let log_m = std::array::from_fn(|_| all.next().unwrap_or_default());
        Samples { stride, cols, m, cos, log_m, fit_scale: true }
    }

    pub fn len(&self) -> usize {
        self.cos.len()
    }

    /// Σ y² of the targets the residuals of `metric` are measured from ([`lm_refine`]): m (`rmse`), m·cos θ_i
    /// (`cosine`), ln(1 + m·cos θ_i) (`log`), over every channel and entry.
    fn targets(&self, metric: MeasuredMetric) -> f64 {
        (0..3)
            .map(|c| match metric {
                MeasuredMetric::Rmse => self.m[c].iter().map(|m| m * m).sum::<f64>(),
                MeasuredMetric::Cosine => self.m[c].iter().zip(&self.cos).map(|(m, k)| (m * k).powi(2)).sum(),
                MeasuredMetric::Log => self.log_m[c].iter().map(|v| v * v).sum(),
            })
            .sum()
    }

    pub fn is_empty(&self) -> bool {
        self.cos.is_empty()
    }

    /// The formula's values (one channel's kernel) at every entry.
    fn eval(&self, ev: &dyn Evaluator, params: &[f64]) -> Vec<f64> {
        let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| self.cols[i].as_slice());
        let mut out = vec![0.0; self.len()];
        ev.eval_batch(&Columns::new(cols), params, &mut out);
        out
    }
}

/// A candidate's error: the metric's value and the colour scale that attains it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Residual {
    pub error: f64,
    pub scale: [f64; 3],
}

/// The error of the formula (`channels`: one kernel, or red, green, blue) with `params` against `s`, with
/// the closed-form colour scale (module docs). Non-finite formula values anywhere: +inf.
pub fn residual(channels: &[&dyn Evaluator], params: &[f64], s: &Samples, metric: MeasuredMetric) -> Residual {
    match values(channels, params, s) {
        Some(v) => residual_of(&v, s, metric),
        None => FAIL,
    }
}

/// [`residual`] under every metric ([`MeasuredMetric::ALL`]'s order), the formula evaluated once.
pub fn residuals(channels: &[&dyn Evaluator], params: &[f64], s: &Samples) -> [Residual; 3] {
    match values(channels, params, s) {
        Some(v) => MeasuredMetric::ALL.map(|m| residual_of(&v, s, m)),
        None => [FAIL; 3],
    }
}

/// No residual: +inf, the scale unknown.
const FAIL: Residual = Residual { error: f64::INFINITY, scale: [f64::NAN; 3] };

/// The formula's values per channel at every entry of `s`; `None` when there is none, or one is not finite.
fn values(channels: &[&dyn Evaluator], params: &[f64], s: &Samples) -> Option<Vec<Vec<f64>>> {
    if s.is_empty() || channels.is_empty() {
        return None;
    }
    let values: Vec<Vec<f64>> = channels.iter().map(|ev| s.eval(*ev, params)).collect();
    values.iter().flatten().all(|v| v.is_finite()).then_some(values)
}

/// [`residual`] of the formula's `values` (one list per channel, [`values`]).
fn residual_of(values: &[Vec<f64>], s: &Samples, metric: MeasuredMetric) -> Residual {
    let mut scale = [0.0; 3];
    let mut sum = 0.0;
    for c in 0..3 {
        let f = &values[c.min(values.len() - 1)];
        let m = &s.m[c];
        // The least-squares scale of a weighted quadratic metric, or 1 against absolute values.
        let fitted = |fm: f64, ff: f64| if !s.fit_scale { 1.0 } else if ff > 0.0 { (fm / ff).max(0.0) } else { 0.0 };
        match metric {
            MeasuredMetric::Rmse => {
                let (fm, ff) = f.iter().zip(m).fold((0.0, 0.0), |(a, b), (f, m)| (a + f * m, b + f * f));
                let k = fitted(fm, ff);
                sum += f.iter().zip(m).map(|(f, m)| (k * f - m).powi(2)).sum::<f64>();
                scale[c] = k;
            }
            MeasuredMetric::Cosine => {
                let w = |cos: &f64| cos * cos;
                let (fm, ff) = f.iter().zip(m).zip(&s.cos).fold((0.0, 0.0), |(a, b), ((f, m), cos)| (a + w(cos) * f * m, b + w(cos) * f * f));
                let k = fitted(fm, ff);
                sum += f.iter().zip(m).zip(&s.cos).map(|((f, m), cos)| w(cos) * (k * f - m).powi(2)).sum::<f64>();
                scale[c] = k;
            }
            MeasuredMetric::Log => {
                let (mut ay, mut aa) = (0.0, 0.0);
                for ((f, m), cos) in f.iter().zip(m).zip(&s.cos) {
                    let (a, y) = (f * cos, m * cos);
                    let w = 1.0 / ((1.0 + y) * (1.0 + y));
                    ay += w * a * y;
                    aa += w * a * a;
                }
                let k = fitted(ay, aa);
                sum += f.iter().zip(&s.cos).zip(&s.log_m[c]).map(|((f, cos), lm)| ((k * f * cos).max(0.0).ln_1p() - lm).powi(2)).sum::<f64>();
                scale[c] = k;
            }
        }
    }
    let error = (sum / (3 * s.len()) as f64).sqrt();
    if error.is_finite() { Residual { error, scale } } else { FAIL }
}

/// One formula fitted to one reference, as the fit command reports it: the fit, and the best candidate's
/// error under every metric ([`MeasuredMetric::ALL`]'s order).
pub struct MeasuredRow {
    pub fit: MeasuredFit,
    pub all: [f64; 3],
}

/// [`fit_measured`] of `free` parameters (with nothing to search: the formula as it is at `params`, with its
/// colour scale), and the best candidate's error under every metric on the `opts.stride` entries.
pub fn fit_row(
    channels: &[&dyn Evaluator],
    grad: Option<&Gradient>,
    params: &[f64],
    free: &[FreeParam],
    t: &dyn Reference,
    opts: &MeasuredFitOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<MeasuredRow, Diagnostic> {
    let s = t.samples(opts.stride);
    let fit = if free.is_empty() {
        let r = residual(channels, params, &s, opts.metric);
        let best = vec![MeasuredCandidate { params: params.to_vec(), residual: r, refined: false }];
        MeasuredFit { best, evaluated: 1, entries: s.len(), grid_entries: s.len(), refinement: opts.refinement, lm: LmStats::default(), fixed: vec![] }
    } else {
        fit_on(channels, grad, params, free, t, &s, opts, progress)?
    };
    let all = residuals(channels, &fit.best[0].params, &s).map(|r| r.error);
    Ok(MeasuredRow { fit, all })
}

/// One fit as the fit command's JSON gives it (keys in docs/measured.md).
#[derive(serde::Serialize)]
pub struct MeasuredRowJson<'a> {
    pub formula: String,
    pub file: &'a str,
    pub measured: &'a str,
    pub metric: &'static str,
    pub params: crate::base::json::Named,
    #[serde(serialize_with = "crate::base::json::num")]
    pub error: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub log: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub rmse: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub cosine: f64,
    pub scale: [f64; 3],
    pub entries: usize,
    pub grid_entries: usize,
    pub evaluated: usize,
    pub refinement: &'static str,
    pub lm: LmStats,
    pub fixed: &'a [String],
    #[serde(serialize_with = "crate::base::json::num")]
    pub seconds: f64,
}

impl<'a> MeasuredRowJson<'a> {
    /// The row of formula `formula` (read from `file`; `free` its searched parameters) fitted to `measured`
    /// under `metric` in `seconds`.
    pub fn new(formula: String, file: &'a str, measured: &'a str, free: &[FreeParam], r: &'a MeasuredRow, metric: MeasuredMetric, seconds: f64) -> MeasuredRowJson<'a> {
        let b = &r.fit.best[0];
        MeasuredRowJson {
            formula,
            file,
            measured,
            metric: metric.name(),
            params: crate::base::json::Named::new(free.iter().map(|f| (f.name.as_str(), b.params[f.index]))),
            error: b.residual.error,
            log: r.all[0],
            rmse: r.all[1],
            cosine: r.all[2],
            scale: b.residual.scale,
            entries: r.fit.entries,
            grid_entries: r.fit.grid_entries,
            evaluated: r.fit.evaluated,
            refinement: r.fit.refinement.name(),
            lm: r.fit.lm,
            fixed: &r.fit.fixed,
            seconds,
        }
    }
}

/// How [`fit_measured`] runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasuredFitOptions {
    pub metric: MeasuredMetric,
    /// The entries the refinement and the reported residual use (every `stride`-th index per axis).
    pub stride: usize,
    /// The entries the grid stage uses (coarser: the grid scores many candidates).
    pub grid_stride: usize,
    pub top: usize,
    pub refine: bool,
    /// Levenberg–Marquardt where a [`Gradient`] is given, else the derivative-free refinement.
    pub refinement: Refinement,
}

impl Default for MeasuredFitOptions {
    fn default() -> Self {
        MeasuredFitOptions { metric: MeasuredMetric::Log, stride: 1, grid_stride: 4, top: 5, refine: true, refinement: Refinement::Lm }
    }
}

/// A fitted candidate: the full parameter vector, its residual (on the fine entries) and its colour scale.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredCandidate {
    pub params: Vec<f64>,
    pub residual: Residual,
    pub refined: bool,
}

/// The fit's result, best first.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredFit {
    pub best: Vec<MeasuredCandidate>,
    /// Residuals computed (grid and refinement).
    pub evaluated: usize,
    /// Entries of the refinement and of the reported residuals.
    pub entries: usize,
    /// Entries of the grid stage.
    pub grid_entries: usize,
    /// The refinement that ran ([`Refinement::DerivativeFree`] also when no gradient was given).
    pub refinement: Refinement,
    /// Levenberg–Marquardt's iterations and evaluations (zero for the derivative-free refinement).
    pub lm: LmStats,
    /// Parameters whose range was one value (lo == hi): fixed there, not searched.
    pub fixed: Vec<String>,
}

/// Fits `free` parameters of the formula (`channels`: one kernel, or red, green, blue) to table `t`: the
/// grid on the `grid_stride` entries, the refinement of the best grid point on the `stride` entries, each
/// candidate under `metric` with its closed-form colour scale (module docs).
///
/// With `opts.refinement` [`Refinement::Lm`] and `grad` (the formula's [`Gradient`] by the free parameters),
/// the grid is coarse ([`super::fit::LM_GRID_POINTS`]) and Levenberg–Marquardt refines its best
/// [`LM_STARTS`] points on the fine entries ([`lm_refine`]).
pub fn fit_measured(
    channels: &[&dyn Evaluator],
    grad: Option<&Gradient>,
    base_params: &[f64],
    free: &[FreeParam],
    t: &dyn Reference,
    opts: &MeasuredFitOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<MeasuredFit, Diagnostic> {
    fit_on(channels, grad, base_params, free, t, &t.samples(opts.stride), opts, progress)
}

/// [`fit_measured`] with the fine entries (`t`'s at `opts.stride`) already read.
#[allow(clippy::too_many_arguments)]
fn fit_on(
    channels: &[&dyn Evaluator],
    grad: Option<&Gradient>,
    base_params: &[f64],
    free: &[FreeParam],
    t: &dyn Reference,
    fine: &Samples,
    opts: &MeasuredFitOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<MeasuredFit, Diagnostic> {
    if let Some(f) = free.iter().find(|f| f.index >= base_params.len()) {
        return Err(Diagnostic::error(format!("cannot fit `{}`", f.name)).hint("not a parameter of the formula"));
    }
    let coarse = if opts.grid_stride == fine.stride { None } else { Some(t.samples(opts.grid_stride)) };
    let coarse_ref = coarse.as_ref().unwrap_or(fine);
    if fine.is_empty() || coarse_ref.is_empty() {
        return Err(Diagnostic::error(format!("`{}` has no entry measured in all three channels at stride {}", t.name(), opts.stride.max(opts.grid_stride)))
            .hint("use a smaller stride, or check the file: every entry is negative (not measured)"));
    }
    let metric = opts.metric;
    let lm_grad = grad.filter(|_| opts.refine && opts.refinement == Refinement::Lm);
    let mut base = base_params.to_vec();
    let (free, grid_free, fixed) = match lm_grad {
        Some(_) => lm_grid(free, &mut base),
        None => (free.to_vec(), free.to_vec(), vec![]),
    };
    if free.is_empty() {
        let r = residual(channels, &base, fine, metric);
        let best = vec![MeasuredCandidate { params: base, residual: r, refined: false }];
        return Ok(MeasuredFit { best, evaluated: 1, entries: fine.len(), grid_entries: fine.len(), refinement: opts.refinement, lm: LmStats::default(), fixed });
    }
    // The grid on the coarse entries, without the search's own refinement (which must run on the fine ones).
    let top = if lm_grad.is_some() { opts.top.max(LM_STARTS) } else { opts.top };
    let grid = search(&base, &grid_free, top, false, &|p| residual(channels, p, coarse_ref, metric).error, progress)?;
    let mut evaluated = grid.evaluated;
    let mut best: Vec<Candidate> = grid.best;
    let mut lm = LmStats::default();
    let mut lm_best = None;
    if let Some(g) = lm_grad {
        let starts: Vec<&[f64]> = best.iter().take(LM_STARTS).map(|c| c.params.as_slice()).collect();
        // Every start on the grid's entries (cheap), then the best result polished on the fine ones.
        let (coarse_best, mut stats) = lm_refine(channels, g, coarse_ref, &free, &starts, None, metric)?;
        if let Some(c) = coarse_best {
            let (cand, polish) = lm_refine(channels, g, fine, &free, &[&c.params], Some(c.residual.scale), metric)?;
            stats.iterations += polish.iterations;
            stats.evaluations += polish.evaluations;
            lm_best = cand;
        }
        lm = stats;
    } else if opts.refine {
        if let Some(b) = best.first() {
            let (cand, used) = super::fit::refine(&|p| residual(channels, p, fine, metric).error, &b.params, &free);
            evaluated += used;
            best.insert(0, cand);
        }
    }
    let mut out: Vec<MeasuredCandidate> = best
        .par_iter()
        .map(|c| MeasuredCandidate { params: c.params.clone(), residual: residual(channels, &c.params, fine, metric), refined: c.refined })
        .collect();
    out.extend(lm_best);
    out.sort_by(|a, b| a.residual.error.total_cmp(&b.residual.error));
    out.dedup_by(|a, b| a.params == b.params);
    out.truncate(opts.top.max(1));
    let refinement = if lm_grad.is_some() { Refinement::Lm } else { Refinement::DerivativeFree };
    Ok(MeasuredFit { best: out, evaluated, entries: fine.len(), grid_entries: coarse_ref.len(), refinement, lm, fixed })
}

/// Entries per chunk of a Jacobian evaluation (the chunks run in parallel).
const CHUNK: usize = 4096;

/// Levenberg–Marquardt ([`super::lm`]) on the metric's residuals over the entries of `s`, from each of
/// `starts` (full parameter vectors); the variables are the `free` parameters (bounded by their ranges) and,
/// where `s` fits one ([`Samples::fit_scale`]), the three colour scales (unbounded, started at `scale`, or else
/// at the closed-form ones). The residuals, per channel c and entry i, with cos θ_i = N·L:
/// - `rmse`: r = s_c·f − m, so ∂r/∂p = s_c·∂f/∂p and ∂r/∂s_c = f;
/// - `cosine`: r = (s_c·f − m)·cos θ_i, so ∂r/∂p = s_c·cos θ_i·∂f/∂p and ∂r/∂s_c = f·cos θ_i;
/// - `log`: r = ln(1 + s_c·f·cos θ_i) − ln(1 + m·cos θ_i), so ∂r/∂p = s_c·cos θ_i·∂f/∂p / (1 + s_c·f·cos θ_i)
///   and ∂r/∂s_c = f·cos θ_i / (1 + s_c·f·cos θ_i) (a negative s_c·f counts as 0, as in [`residual`]: r is
///   then constant).
///
/// The best result is a candidate whose residual is the metric at the scales Levenberg–Marquardt found, or at
/// the closed-form scales if those score lower (`None` when no start could be evaluated).
pub fn lm_refine(
    channels: &[&dyn Evaluator],
    grad: &Gradient,
    s: &Samples,
    free: &[FreeParam],
    starts: &[&[f64]],
    scale: Option<[f64; 3]>,
    metric: MeasuredMetric,
) -> Result<(Option<MeasuredCandidate>, LmStats), Diagnostic> {
    let var_of: Vec<usize> = free
        .iter()
        .map(|f| grad.vars.iter().position(|v| *v == Var::Param(f.index as u16)))
        .collect::<Option<_>>()
        .ok_or_else(|| Diagnostic::error("the gradient lacks a searched parameter's partial"))?;
    let nf = free.len();
    let k = if s.fit_scale { nf + 3 } else { nf };
    let len = s.len();
    let chunks = len.div_ceil(CHUNK);
    let mut stats = LmStats::default();
    let mut best: Option<MeasuredCandidate> = None;
    let bounds: Vec<Option<(f64, f64)>> = free.iter().map(|f| Some((f.lo, f.hi))).chain(vec![None; k - nf]).collect();
    let targets = s.targets(metric);
    let mut found: Vec<LmResult> = vec![];
    for start in starts {
        let params_of = |x: &[f64]| {
            let mut p = start.to_vec();
            for (f, v) in free.iter().zip(x) {
                p[f.index] = *v;
            }
            p
        };
        let eval = |x: &[f64]| -> Option<Normal> {
            let p = params_of(x);
            let scale: [f64; 3] = if s.fit_scale { [x[nf], x[nf + 1], x[nf + 2]] } else { [1.0; 3] };
            (0..chunks)
                .into_par_iter()
                .map(|ci| {
                    let (a, b) = (ci * CHUNK, ((ci + 1) * CHUNK).min(len));
                    let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| &s.cols[i][a..b]);
                    let gv = grad.run(&cols, &p, b - a);
                    let mut n = Normal::zeros(k);
                    let mut g = vec![0.0; k];
                    for (c, &sc) in scale.iter().enumerate() {
                        let ch = c.min(grad.channels - 1);
                        for i in 0..b - a {
                            let f = gv.value[ch][i];
                            if !f.is_finite() {
                                return None;
                            }
                            let (r, dr_df, dr_ds) = match metric {
                                MeasuredMetric::Rmse => (sc * f - s.m[c][a + i], sc, f),
                                MeasuredMetric::Cosine => {
                                    let cos = s.cos[a + i];
                                    ((sc * f - s.m[c][a + i]) * cos, sc * cos, f * cos)
                                }
                                MeasuredMetric::Log => {
                                    let cos = s.cos[a + i];
                                    let arg = sc * f * cos;
                                    if arg >= 0.0 {
                                        (arg.ln_1p() - s.log_m[c][a + i], sc * cos / (1.0 + arg), f * cos / (1.0 + arg))
                                    } else {
                                        (-s.log_m[c][a + i], 0.0, 0.0)
                                    }
                                }
                            };
                            for (j, v) in var_of.iter().enumerate() {
                                g[j] = dr_df * gv.grad[*v][ch][i];
                            }
                            for (q, gq) in g[nf..].iter_mut().enumerate() {
                                *gq = if q == c { dr_ds } else { 0.0 };
                            }
                            n.add(r, &g);
                        }
                    }
                    Some(n)
                })
                .try_reduce(|| Normal::zeros(k), |x, y| Some(x.merge(y)))
        };
        // A start beyond the first runs only while no earlier one fits exactly (no start can do better).
        if found.iter().any(|r| is_exact(r.cost, targets)) {
            break;
        }
        let scales = match scale {
            _ if !s.fit_scale => vec![],
            Some(sc) => sc.to_vec(),
            None => {
                let closed = residual(channels, start, s, metric);
                if !closed.error.is_finite() {
                    continue;
                }
                closed.scale.to_vec()
            }
        };
        let x0: Vec<f64> = free.iter().map(|f| start[f.index]).chain(scales).collect();
        let Some(r) = minimize_near(&eval, &x0, &bounds, LM_MAX_ITERATIONS, &found) else { continue };
        stats.starts += 1;
        stats.iterations += r.iterations;
        stats.evaluations += r.evaluations;
        // A start that joined an earlier one's minimum adds nothing new.
        if r.joined.is_some() {
            continue;
        }
        let params = params_of(&r.x[..nf]);
        let own = Residual { error: (r.cost / (3 * len) as f64).sqrt(), scale: if s.fit_scale { [r.x[nf], r.x[nf + 1], r.x[nf + 2]] } else { [1.0; 3] } };
        let closed = residual(channels, &params, s, metric);
        let residual = if own.error <= closed.error { own } else { closed };
        if residual.error.is_finite() && best.as_ref().is_none_or(|b| residual.error < b.residual.error) {
            best = Some(MeasuredCandidate { params, residual, refined: true });
        }
        found.push(r);
    }
    Ok((best, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::FnEvaluator;
    use crate::ir::Input;

    fn nh(x: &[f64; N_INPUTS]) -> f64 {
        x[Input::NH.index()]
    }

    /// A table of `f` in every channel, times `colour`.
    fn table(f: impl Fn(&[f64; N_INPUTS]) -> f64 + Sync, colour: [f64; 3]) -> Measured {
        Measured::tabulate("synthetic", &|l, v| {
            let y = f(&crate::frame::inputs_from_dirs(l, v));
            colour.map(|c| c * y)
        })
    }

    #[test]
    fn recovers_blinns_n_and_the_colour_under_both_metrics() {
        let t = table(|x| nh(x).powf(120.0), [0.5, 0.8, 1.2]);
        let blinn = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| nh(x).powf(p[0]));
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 1000.0, step: None }];
        for metric in [MeasuredMetric::Log, MeasuredMetric::Rmse] {
            // Strides that keep a debug-build test fast: 1/27 of the entries for the refinement, 1/216 for the grid.
            let opts = MeasuredFitOptions { metric, stride: 3, grid_stride: 6, ..Default::default() };
            let r = fit_measured(&[&blinn], None, &[1.0], &free, &t, &opts, &|| {}).unwrap();
            let b = &r.best[0];
            assert!((b.params[0] - 120.0).abs() < 1.2, "{metric:?}: {b:?}");
            assert!(b.residual.error < 1e-3, "{metric:?}: {b:?}");
            for (s, want) in b.residual.scale.iter().zip([0.5, 0.8, 1.2]) {
                assert!((s - want).abs() < 0.01 * want, "{metric:?}: {b:?}");
            }
            assert!(r.entries > r.grid_entries && r.grid_entries > 1000);
        }
    }

    #[test]
    fn a_random_exponent_is_recovered_and_a_wrong_formula_scores_worse() {
        let mut rng = crate::base::rng::Rng(3);
        for _ in 0..3 {
            let n = 5.0 + rng.unit() * 400.0;
            let t = table(|x| nh(x).powf(n), [1.0; 3]);
            let blinn = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| nh(x).powf(p[0]));
            let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 1000.0, step: None }];
            let opts = MeasuredFitOptions { stride: 4, grid_stride: 8, top: 3, ..Default::default() };
            let r = fit_measured(&[&blinn], None, &[1.0], &free, &t, &opts, &|| {}).unwrap();
            assert!((r.best[0].params[0] - n).abs() < 0.01 * n, "{n}: {:?}", r.best[0]);
            // A flat lobe cannot match a sharp one: its best error is larger.
            let s = Samples::new(&t, 4);
            let flat = FnEvaluator(|_: &[f64; N_INPUTS], _: &[f64]| 1.0);
            assert!(residual(&[&flat], &[], &s, MeasuredMetric::Log).error > 10.0 * r.best[0].residual.error);
        }
    }

    /// Against a formula (no colour scale) the cosine metric recovers a random exponent and colour-free values;
    /// with the scale fitted, an overall factor is absorbed by it instead.
    #[test]
    fn a_formula_reference_is_absolute_and_every_metric_recovers_its_parameter() {
        let mut rng = crate::base::rng::Rng(0xc05);
        let blinn = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| nh(x).powf(p[0]));
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 1000.0, step: None }];
        for _ in 0..2 {
            let n = 5.0 + rng.unit() * 300.0;
            for (fit_scale, factor) in [(false, 1.0), (true, 2.0)] {
                let want = factor;
                let r = FormulaReference {
                    name: "ref".into(),
                    channels: vec![std::sync::Arc::new(FnEvaluator(move |x: &[f64; N_INPUTS], _: &[f64]| factor * nh(x).powf(n)))],
                    params: vec![],
                    azimuths: false,
                    fit_scale,
                };
                for metric in MeasuredMetric::ALL {
                    let opts = MeasuredFitOptions { metric, stride: 4, grid_stride: 8, top: 3, ..Default::default() };
                    let f = fit_measured(&[&blinn], None, &[1.0], &free, &r, &opts, &|| {}).unwrap();
                    let b = &f.best[0];
                    assert!((b.params[0] - n).abs() < 0.01 * n, "{metric:?} scale fitted {fit_scale}: n {n}: {b:?}");
                    assert!(b.residual.scale.iter().all(|s| (s - want).abs() < 0.01 * want), "{metric:?}: {b:?}");
                }
            }
        }
    }

    /// An anisotropic formula is compared at every φ_h turn (AZIMUTHS times the entries); the isotropy test
    /// tells them apart.
    #[test]
    fn anisotropic_formulas_are_compared_at_every_azimuth() {
        let aniso = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| {
            let (hx, hy, hz) = (x[Input::Lx.index()] + x[Input::Vx.index()], x[Input::Ly.index()] + x[Input::Vy.index()], x[Input::Lz.index()] + x[Input::Vz.index()]);
            (-(hx * hx / (p[0] * p[0]) + hy * hy) / (hz * hz)).exp()
        });
        assert!(!turns_with_the_frame(&aniso, &[0.3]));
        assert!(turns_with_the_frame(&FnEvaluator(|x: &[f64; N_INPUTS], _: &[f64]| nh(x).powi(7)), &[]));
        let one = |azimuths| FormulaReference { name: "a".into(), channels: vec![std::sync::Arc::new(FnEvaluator(|_: &[f64; N_INPUTS], _: &[f64]| 1.0))], params: vec![], azimuths, fit_scale: false };
        assert_eq!(one(true).samples(9).len(), AZIMUTHS * one(false).samples(9).len());
    }

    #[test]
    fn the_entries_are_in_index_order_and_every_metric_is_its_own_residual() {
        let mut rng = crate::base::rng::Rng(0x5a3);
        let t = table(|x| nh(x).powf(40.0) + 0.1, [0.7, 0.9, 1.1]);
        for stride in [3, 7] {
            // The entries built a row per task are those of one pass in index order.
            let s = Samples::new(&t, stride);
            let mut at = 0;
            for i in (0..DIMS[0]).step_by(stride) {
                for j in (0..DIMS[1]).step_by(stride) {
                    for k in (0..DIMS[2]).step_by(stride) {
                        let (l, w) = measured::entry_dirs(i, j, k);
                        if !(l[2] > 0.0 && w[2] > 0.0) {
                            continue;
                        }
                        let x = crate::frame::inputs_from_dirs(l, w);
                        assert!((0..N_INPUTS).all(|c| s.cols[c][at].to_bits() == x[c].to_bits()), "{i} {j} {k}");
                        assert_eq!(s.m[2][at], t.value(2, measured::index(i, j, k)).unwrap());
                        at += 1;
                    }
                }
            }
            assert_eq!(at, s.len());
            // `residuals` is `residual` under each metric, bit for bit, from one evaluation.
            let blinn = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| nh(x).powf(p[0]) + p[1]);
            for _ in 0..5 {
                let p = [1.0 + 100.0 * rng.unit(), rng.unit()];
                let all = residuals(&[&blinn], &p, &s);
                for (m, r) in MeasuredMetric::ALL.iter().zip(all) {
                    let one = residual(&[&blinn], &p, &s, *m);
                    assert_eq!((one.error.to_bits(), one.scale.map(f64::to_bits)), (r.error.to_bits(), r.scale.map(f64::to_bits)), "{m:?}");
                }
            }
        }
    }

    /// `param n … pow(NH, n)`: the kernel and its gradient by n.
    fn power() -> (crate::Kernel, Gradient) {
        let f = crate::front::parse("p.brdf", "param n = 50 in 1..1000\npow(NH, n)").unwrap();
        let opts = crate::Options { backend: crate::Backend::Interp, ..Default::default() };
        (crate::compile_formula(f.clone(), &opts).unwrap(), Gradient::compile_vars(&f, &opts, Some(&[Var::Param(0)])).unwrap())
    }

    #[test]
    fn an_exact_fit_ends_the_starts_and_others_join_a_minimum_found_before() {
        let (k, g) = power();
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 1000.0, step: None }];
        let mut rng = crate::base::rng::Rng(0x70f);
        for _ in 0..3 {
            let n = 20.0 + 300.0 * rng.unit();
            let starts: Vec<Vec<f64>> = (0..4).map(|_| vec![1.0 + 999.0 * rng.unit()]).collect();
            let starts: Vec<&[f64]> = starts.iter().map(Vec::as_slice).collect();
            // A table of the formula itself: the first start fits it exactly, and is the only one run.
            let s = Samples::new(&table(|x| nh(x).powf(n), [0.6, 0.8, 1.0]), 6);
            let (best, stats) = lm_refine(&[&k], &g, &s, &free, &starts, None, MeasuredMetric::Log).unwrap();
            let best = best.unwrap();
            assert!((best.params[0] - n).abs() < 1e-9 * n && stats.starts == 1, "{n}: {best:?} {stats:?}");
            // A table it cannot fit (a power plus a broad term): every start runs; those that come beside the
            // minimum another found stop there, after fewer evaluations than alone, at the same answer.
            let s = Samples::new(&table(|x| nh(x).powf(n) + 0.2 * nh(x).powi(3), [0.6, 0.8, 1.0]), 6);
            let (best, stats) = lm_refine(&[&k], &g, &s, &free, &starts, None, MeasuredMetric::Log).unwrap();
            let best = best.unwrap();
            assert_eq!(stats.starts, 4, "{stats:?}");
            let alone: Vec<(Option<MeasuredCandidate>, LmStats)> = starts.iter().map(|st| lm_refine(&[&k], &g, &s, &free, &[st], None, MeasuredMetric::Log).unwrap()).collect();
            let lowest = alone.iter().filter_map(|a| a.0.as_ref()).map(|c| c.residual.error).fold(f64::INFINITY, f64::min);
            assert!(best.residual.error <= lowest * (1.0 + 1e-9), "{best:?} against {lowest}");
            let evaluations: usize = alone.iter().map(|a| a.1.evaluations).sum();
            assert!(stats.evaluations < evaluations, "{stats:?}: {evaluations} alone");
        }
    }

    #[test]
    fn nan_and_empty_tables_are_handled() {
        let t = table(nh, [1.0; 3]);
        let s = Samples::new(&t, 9);
        let nan = FnEvaluator(|x: &[f64; N_INPUTS], _: &[f64]| if nh(x) > 0.99 { f64::NAN } else { 1.0 });
        assert_eq!(residual(&[&nan], &[], &s, MeasuredMetric::Rmse).error, f64::INFINITY);
        let none = Measured::tabulate("none", &|_, _| [f64::NAN; 3]);
        assert_eq!(none.measured_entries(), 0);
        let free = [FreeParam { index: 0, name: "n".into(), lo: 1.0, hi: 2.0, step: None }];
        let e = fit_measured(&[&nan], None, &[1.0], &free, &none, &MeasuredFitOptions::default(), &|| {}).unwrap_err();
        assert!(e.message.contains("no entry measured"), "{}", e.message);
        assert!("lg".parse::<MeasuredMetric>().is_err());
    }
}
