//! Accuracy of a lobe against a reference lobe (normally Blinn, cos^n), with the papers' metrics — and the one
//! definition of the papers' grid, shared with [`fit`](super::fit).
//!
//! Both formulas are evaluated under the lobe convention of the [module docs](super) with the lobe variable
//! `c = cos(angle)` and `n` swept over 1..=n_max (1000 in the papers; other parameters fixed). Metrics:
//! - `mean_abs_grid`: mean |F − R| over angle 0°..90° step 1° × n = 1..1000 (91 000 points, the papers' grid:
//!   [`AngleGrid::papers`]); the sum of each n's row ([`RowError`]) is added in order of n ([`papers_mean`]);
//! - epicentre: max over n ∈ [n₀, 1000] (n₀ = [`EPICENTER_FROM`] = 2, or 9 for F_dsh) of |F − R|/|R| at
//!   c = exp(−1.2/n), angle acos(c), where cos^n = e^−1.2 ≈ 0.3 ([`epicenter_cos`]);
//! - inflection: max over n ∈ [3, 1000] of |F − R|/|R| at x = atan(1/√(n−1));
//! - max absolute error over angles per n (on a fine grid, step 0.05°), the worst n and angle;
//! - max relative error over angles where R ≥ 2^−q (up to the reference's cut-off), worst n and angle;
//! - lobe-size ratio: cut-off angle of F (first angle from the normal where F < 2^−q, bisected to 1e-13 rad)
//!   over the cut-off angle of R (acos(2^(−q/n)) for Blinn), its min and max over n.
//!
//! The reference on the papers' grid and at the epicentres is evaluated once ([`PapersReference`]); a fit
//! reuses it for every candidate. A NaN anywhere makes the mean NaN and is the worst error of every other
//! metric.
//!
//! Evaluation is batched (`Evaluator::eval_batch` over precomputed SoA columns) and parallel over n (rayon).
//! Cost: 2 × 1000 × (91 + 1801) batched evaluations plus ~100 scalar ones per n for the cut-offs —
//! about 4 M evaluations for the whole report.

use super::{lobe_inputs, Diagnostic};
use crate::backend::{Columns, Evaluator};
use crate::base::json;
use crate::ir::Input;
use crate::N_INPUTS;
use rayon::prelude::*;

/// Number of angles of the papers' grid: 0°..90° in steps of 1°.
pub(crate) const PAPERS_ANGLES: usize = 91;

/// Smallest n of the papers' epicentre metric (F_dsh uses 9, see [`AccuracyOptions::epicenter_from`]).
pub(crate) const EPICENTER_FROM: u32 = 2;

/// The lobe cosine at the epicentre of `n`: where cos^n = e^−1.2 ≈ 0.3, i.e. c = exp(−1.2/n) (the angle is
/// acos(c)). Both the reference and the formula are evaluated at exactly this c.
pub(crate) fn epicenter_cos(n: f64) -> f64 {
    (-1.2 / n).exp()
}

/// Relative error |F − R| / |R|.
pub(crate) fn rel(f: f64, r: f64) -> f64 {
    (f - r).abs() / r.abs()
}

/// `p` with its first slot (n) replaced, or `[n]` when empty.
pub(crate) fn with_n(p: &[f64], n: f64) -> Vec<f64> {
    let mut v = p.to_vec();
    if v.is_empty() {
        v.push(n)
    } else {
        v[0] = n
    }
    v
}

/// Lobe angles (degrees) and their five input columns under the lobe convention, for batched evaluation.
pub(crate) struct AngleGrid {
    deg: Vec<f64>,
    cols: [Vec<f64>; N_INPUTS],
}

impl AngleGrid {
    pub(crate) fn new(deg: Vec<f64>, lobe: Input) -> AngleGrid {
        let mut cols: [Vec<f64>; N_INPUTS] = Default::default();
        for d in &deg {
            let x = lobe_inputs(d.to_radians().cos(), lobe);
            for k in 0..N_INPUTS {
                cols[k].push(x[k]);
            }
        }
        AngleGrid { deg, cols }
    }

    /// The papers' grid: [`PAPERS_ANGLES`] angles, 0°..90° step 1°.
    pub(crate) fn papers(lobe: Input) -> AngleGrid {
        AngleGrid::new((0..PAPERS_ANGLES as u32).map(f64::from).collect(), lobe)
    }

    /// The fine grid of the max-error and cut-off metrics: 0°..90° step 0.05° (1 801 angles).
    pub(crate) fn fine(lobe: Input) -> AngleGrid {
        AngleGrid::new((0..=1800).map(|i| i as f64 * 0.05).collect(), lobe)
    }

    /// Input column `k` ([`Input::ALL`](crate::ir::Input::ALL) order), one value per angle.
    pub(crate) fn col(&self, k: usize) -> &[f64] {
        &self.cols[k]
    }

    /// The angles in degrees.
    pub(crate) fn deg(&self) -> &[f64] {
        &self.deg
    }

    /// `ev` at every angle into `out` (one batched call; `out` has one slot per angle).
    pub(crate) fn eval_into(&self, ev: &dyn Evaluator, params: &[f64], out: &mut [f64]) {
        let c = Columns::new(std::array::from_fn(|k| self.cols[k].as_slice()));
        ev.eval_batch(&c, params, out);
    }

    /// `ev` at every angle.
    pub(crate) fn eval(&self, ev: &dyn Evaluator, params: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.deg.len()];
        self.eval_into(ev, params, &mut out);
        out
    }
}

/// The reference lobe on the papers' grid, evaluated once: one row of [`PAPERS_ANGLES`] values per
/// n = 1..=n_max, and its value at each n's epicentre ([`epicenter_cos`]).
pub(crate) struct PapersReference {
    rows: Vec<f64>,
    epicenter: Vec<f64>,
}

impl PapersReference {
    /// Evaluates `reference` (lobe variable `ref_lobe`, parameters `ref_params` with n replaced) for
    /// n = 1..=n_max, in parallel over n.
    pub(crate) fn new(reference: &dyn Evaluator, ref_params: &[f64], ref_lobe: Input, n_max: u32) -> PapersReference {
        let grid = AngleGrid::papers(ref_lobe);
        let per_n: Vec<(Vec<f64>, f64)> = (1..=n_max)
            .into_par_iter()
            .map(|ni| {
                let n = f64::from(ni);
                let p = with_n(ref_params, n);
                (grid.eval(reference, &p), reference.eval(&lobe_inputs(epicenter_cos(n), ref_lobe), &p))
            })
            .collect();
        let mut rows = Vec::with_capacity(per_n.len() * PAPERS_ANGLES);
        let mut epicenter = Vec::with_capacity(per_n.len());
        for (row, e) in per_n {
            rows.extend(row);
            epicenter.push(e);
        }
        PapersReference { rows, epicenter }
    }

    /// The reference at the papers' angles for `n` (1 ≤ n ≤ n_max).
    pub(crate) fn row(&self, n: u32) -> &[f64] {
        let i = (n as usize - 1) * PAPERS_ANGLES;
        &self.rows[i..i + PAPERS_ANGLES]
    }

    /// The reference at the epicentre of `n` (1 ≤ n ≤ n_max).
    pub(crate) fn at_epicenter(&self, n: u32) -> f64 {
        self.epicenter[n as usize - 1]
    }
}

/// |F − R| over one row of a grid: the sum and the max of the differences that are not NaN, and how many are.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct RowError {
    pub sum: f64,
    pub max: f64,
    pub nan: usize,
}

impl RowError {
    pub(crate) fn new(f: &[f64], r: &[f64]) -> RowError {
        let mut e = RowError::default();
        for (a, b) in f.iter().zip(r) {
            let d = (a - b).abs();
            if d.is_nan() {
                e.nan += 1;
            } else {
                e.sum += d;
                e.max = e.max.max(d);
            }
        }
        e
    }
}

/// The papers' mean |F − R|: the per-n row sums added in order of n, over [`PAPERS_ANGLES`] × n_max points;
/// NaN when `nan` points were NaN.
pub(crate) fn papers_mean(row_sums: impl IntoIterator<Item = f64>, nan: usize, n_max: u32) -> f64 {
    let sum = row_sums.into_iter().fold(0.0, |s, r| s + r);
    if nan > 0 {
        f64::NAN
    } else {
        sum / (PAPERS_ANGLES as f64 * f64::from(n_max))
    }
}

/// The smallest usable `n_max` for the papers' metrics is 3 (the inflection metric starts there).
pub(crate) fn check_n_max(n_max: u32) -> Result<(), Diagnostic> {
    if n_max < 3 {
        return Err(Diagnostic::error("n_max must be at least 3"));
    }
    Ok(())
}

/// Options for [`accuracy`].
#[derive(Clone, Debug, PartialEq)]
pub struct AccuracyOptions {
    /// Cut-off level 2^−q for the relative-error and lobe-size metrics.
    pub q: f64,
    /// Largest n (the papers: 1000).
    pub n_max: u32,
    /// Smallest n of the epicentre metric (the papers: 2; 9 for F_dsh).
    pub epicenter_from: u32,
    /// Smallest n of the inflection metric (the papers: 3).
    pub inflection_from: u32,
    /// Polled once per n: the computation fails with the cancellation once it trips (default: never).
    pub cancel: crate::base::cancel::Cancel,
}

impl Default for AccuracyOptions {
    fn default() -> Self {
        AccuracyOptions { q: 8.0, n_max: 1000, epicenter_from: EPICENTER_FROM, inflection_from: 3, cancel: Default::default() }
    }
}

/// A worst case: the value, the n, and the angle in degrees where it happened.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Worst {
    pub value: f64,
    pub n: f64,
    pub angle_deg: f64,
}

impl Worst {
    fn none() -> Worst {
        Worst { value: f64::NEG_INFINITY, n: f64::NAN, angle_deg: f64::NAN }
    }
    /// Keeps the larger; NaN beats everything (it is the worst possible error).
    fn take(&mut self, o: Worst) {
        if o.value.is_nan() && !self.value.is_nan() || o.value > self.value {
            *self = o;
        }
    }
}

/// The accuracy report (see the module docs for each metric).
#[derive(Clone, Debug, PartialEq)]
pub struct AccuracyReport {
    pub mean_abs_grid: f64,
    /// Relative error at the epicentre, as a fraction (×100 for percent).
    pub epicenter: Worst,
    pub inflection: Worst,
    pub max_abs: Worst,
    /// Per n: (n, max |F − R| over angles, its angle in degrees).
    pub max_abs_per_n: Vec<(f64, f64, f64)>,
    pub cutoff_rel: Worst,
    /// min and max over n of cut-off(F)/cut-off(R) (`angle_deg` holds cut-off(F) in degrees).
    pub lobe_ratio_min: Worst,
    pub lobe_ratio_max: Worst,
    /// Points where F or R was NaN (counted as the worst error wherever they occur).
    pub nan_points: usize,
    /// The reference's largest |value| on the fine angle grid over every n (NaN ignored): 0 when it is zero
    /// everywhere, and then every relative metric and the lobe-size ratio are undefined.
    pub reference_peak: f64,
}

/// The first angle (degrees) from the normal where `f < level`, bisected between fine-grid samples;
/// 90 when the lobe never drops below `level`.
fn cutoff_deg(f: &dyn Fn(f64) -> f64, deg: &[f64], vals: &[f64], level: f64) -> f64 {
    let Some(i) = vals.iter().position(|v| v.is_nan() || *v < level) else { return 90.0 };
    if i == 0 {
        return 0.0;
    }
    let (mut a, mut b) = (deg[i - 1].to_radians(), deg[i].to_radians());
    for _ in 0..60 {
        let m = 0.5 * (a + b);
        if f(m) >= level {
            a = m
        } else {
            b = m
        }
        if b - a < 1e-13 {
            break;
        }
    }
    (0.5 * (a + b)).to_degrees()
}

impl AccuracyReport {
    /// Marks the metrics that are undefined as NaN (value and n), as the accuracy command reports them: a
    /// relative error with no n where it is defined (the reference is 0 there), and, when the reference is 0
    /// everywhere, every relative error and the lobe-size ratio (the values found are x/0 = inf or 0/0 = NaN
    /// at arbitrary n). Returns whether the reference is 0 everywhere.
    pub fn mark_undefined(&mut self) -> bool {
        for m in [&mut self.epicenter, &mut self.inflection, &mut self.cutoff_rel] {
            if m.n.is_nan() {
                m.value = f64::NAN;
            }
        }
        let ref_zero = self.reference_is_zero();
        if ref_zero {
            let undefined = Worst { value: f64::NAN, n: f64::NAN, angle_deg: f64::NAN };
            for m in [&mut self.epicenter, &mut self.inflection, &mut self.cutoff_rel, &mut self.lobe_ratio_min, &mut self.lobe_ratio_max] {
                *m = undefined;
            }
        }
        ref_zero
    }

    /// Whether the reference is 0 (or NaN) at every angle and n: the relative metrics are then undefined.
    pub fn reference_is_zero(&self) -> bool {
        self.reference_peak == 0.0 || self.reference_peak.is_nan()
    }
}

/// [`accuracy`] of each channel of a formula (one, or red, green, blue) against one reference, in the lobe
/// variable `lobe`, with the undefined metrics marked ([`AccuracyReport::mark_undefined`]); each report with
/// the seconds it took. The accuracy command's reports, which [`channels_json`] writes.
#[allow(clippy::too_many_arguments)]
pub fn accuracy_channels(
    channels: &[&dyn Evaluator],
    params: &[f64],
    lobe: Input,
    reference: &dyn Evaluator,
    ref_params: &[f64],
    ref_lobe: Input,
    opts: &AccuracyOptions,
) -> Result<Vec<(AccuracyReport, f64)>, Diagnostic> {
    channels
        .iter()
        .map(|ev| {
            let t = std::time::Instant::now();
            let mut rep = accuracy(*ev, params, lobe, reference, ref_params, ref_lobe, opts)?;
            rep.mark_undefined();
            Ok((rep, t.elapsed().as_secs_f64()))
        })
        .collect()
}

/// The JSON of [`accuracy_channels`]' reports: a scalar formula's object, or for a colour formula the red
/// channel's with `channels` holding all three ([`PerChannel`](super::energy::PerChannel)).
pub fn channels_json(reports: &[(AccuracyReport, f64)], q: f64) -> super::energy::PerChannel<AccuracyJson> {
    super::energy::PerChannel::new(reports.iter().map(|(r, secs)| AccuracyJson::new(r, q, *secs)).collect())
}

/// Compares `ev` (lobe variable `lobe`, parameters `params`, n replaced) with `reference`.
#[allow(clippy::too_many_arguments)]
pub fn accuracy(
    ev: &dyn Evaluator,
    params: &[f64],
    lobe: Input,
    reference: &dyn Evaluator,
    ref_params: &[f64],
    ref_lobe: Input,
    opts: &AccuracyOptions,
) -> Result<AccuracyReport, Diagnostic> {
    if !(opts.q > 0.0 && opts.q.is_finite() && opts.q <= 1000.0) {
        return Err(Diagnostic::error(format!("q = {} is not a usable cut-off exponent", opts.q)).hint("use q in (0, 1000], e.g. 8"));
    }
    check_n_max(opts.n_max)?;
    let reference_grid = PapersReference::new(reference, ref_params, ref_lobe, opts.n_max);
    let gc = AngleGrid::papers(lobe);
    let (gf, gfr) = (AngleGrid::fine(lobe), AngleGrid::fine(ref_lobe));
    let level = 2f64.powf(-opts.q);
    struct PerN {
        sum_abs: f64,
        nan: usize,
        max_abs: Worst,
        cutoff_rel: Worst,
        ratio: Worst,
        epi: Option<Worst>,
        infl: Option<Worst>,
        ref_peak: f64,
    }
    let per_n: Option<Vec<PerN>> = (1..=opts.n_max)
        .into_par_iter()
        .map(|ni| {
            if opts.cancel.is_cancelled() {
                return None;
            }
            let n = f64::from(ni);
            let (p, pr) = (with_n(params, n), with_n(ref_params, n));
            let coarse = RowError::new(&gc.eval(ev, &p), reference_grid.row(ni));
            let mut nan = coarse.nan;
            let (f, r) = (gf.eval(ev, &p), gfr.eval(reference, &pr));
            let mut max_abs = Worst::none();
            let mut cutoff_rel = Worst::none();
            for i in 0..f.len() {
                let d = (f[i] - r[i]).abs();
                if d.is_nan() {
                    nan += 1;
                }
                max_abs.take(Worst { value: d, n, angle_deg: gf.deg()[i] });
                if r[i] >= level {
                    cutoff_rel.take(Worst { value: rel(f[i], r[i]), n, angle_deg: gf.deg()[i] });
                }
            }
            // The cut-off searches call each side many times with one parameter set: bind it once.
            let (pe, pre) = (ev.prepare(&p), reference.prepare(&pr));
            let fe = |x: f64| pe.eval(&lobe_inputs(x.cos(), lobe));
            let fr = |x: f64| pre.eval(&lobe_inputs(x.cos(), ref_lobe));
            let cf = cutoff_deg(&fe, gf.deg(), &f, level);
            let cr = cutoff_deg(&fr, gfr.deg(), &r, level);
            let ratio = Worst { value: cf / cr, n, angle_deg: cf };
            let epi = (ni >= opts.epicenter_from).then(|| {
                let c = epicenter_cos(n);
                let v = rel(ev.eval(&lobe_inputs(c, lobe), &p), reference_grid.at_epicenter(ni));
                Worst { value: v, n, angle_deg: c.acos().to_degrees() }
            });
            let infl = (ni >= opts.inflection_from.max(2)).then(|| {
                let x = (1.0 / (n - 1.0).sqrt()).atan();
                let c = x.cos();
                let v = rel(ev.eval(&lobe_inputs(c, lobe), &p), reference.eval(&lobe_inputs(c, ref_lobe), &pr));
                Worst { value: v, n, angle_deg: x.to_degrees() }
            });
            let ref_peak = r.iter().map(|v| v.abs()).filter(|v| !v.is_nan()).fold(0.0, f64::max);
            Some(PerN { sum_abs: coarse.sum, nan, max_abs, cutoff_rel, ratio, epi, infl, ref_peak })
        })
        .collect();
    let per_n = per_n.ok_or(crate::base::cancel::Cancelled)?;
    let mut rep = AccuracyReport {
        mean_abs_grid: 0.0,
        epicenter: Worst::none(),
        inflection: Worst::none(),
        max_abs: Worst::none(),
        max_abs_per_n: Vec::with_capacity(per_n.len()),
        cutoff_rel: Worst::none(),
        lobe_ratio_min: Worst { value: f64::INFINITY, n: f64::NAN, angle_deg: f64::NAN },
        lobe_ratio_max: Worst::none(),
        nan_points: 0,
        reference_peak: per_n.iter().map(|p| p.ref_peak).fold(0.0, f64::max),
    };
    for p in &per_n {
        rep.nan_points += p.nan;
        rep.max_abs.take(p.max_abs);
        rep.max_abs_per_n.push((p.max_abs.n, p.max_abs.value, p.max_abs.angle_deg));
        rep.cutoff_rel.take(p.cutoff_rel);
        rep.lobe_ratio_max.take(p.ratio);
        if p.ratio.value < rep.lobe_ratio_min.value || p.ratio.value.is_nan() {
            rep.lobe_ratio_min = p.ratio;
        }
        if let Some(e) = p.epi {
            rep.epicenter.take(e);
        }
        if let Some(e) = p.infl {
            rep.inflection.take(e);
        }
    }
    // A NaN anywhere (either grid) makes the mean NaN.
    rep.mean_abs_grid = papers_mean(per_n.iter().map(|p| p.sum_abs), rep.nan_points, opts.n_max);
    Ok(rep)
}

/// The accuracy command's JSON report (keys listed in docs/commands.md; numbers follow [`crate::base::json`]): the metrics of an
/// [`AccuracyReport`], relative errors in percent, with `q`, the NaN count and the time taken.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AccuracyJson {
    #[serde(serialize_with = "json::num")]
    pub mean_abs_grid: f64,
    #[serde(serialize_with = "json::num")]
    pub epicenter_max_rel_pct: f64,
    #[serde(serialize_with = "json::num")]
    pub epicenter_worst_n: f64,
    #[serde(serialize_with = "json::num")]
    pub inflection_max_rel_pct: f64,
    #[serde(serialize_with = "json::num")]
    pub inflection_worst_n: f64,
    #[serde(serialize_with = "json::num")]
    pub max_abs: f64,
    #[serde(serialize_with = "json::num")]
    pub max_abs_n: f64,
    #[serde(serialize_with = "json::num")]
    pub max_abs_angle_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub cutoff_max_rel_pct: f64,
    #[serde(serialize_with = "json::num")]
    pub cutoff_worst_n: f64,
    #[serde(serialize_with = "json::num")]
    pub cutoff_worst_angle_deg: f64,
    #[serde(serialize_with = "json::num")]
    pub lobe_ratio_min: f64,
    #[serde(serialize_with = "json::num")]
    pub lobe_ratio_min_n: f64,
    #[serde(serialize_with = "json::num")]
    pub lobe_ratio_max: f64,
    #[serde(serialize_with = "json::num")]
    pub lobe_ratio_max_n: f64,
    #[serde(serialize_with = "json::num")]
    pub q: f64,
    pub nan_points: usize,
    #[serde(serialize_with = "json::num")]
    pub seconds: f64,
}

impl AccuracyJson {
    pub fn new(rep: &AccuracyReport, q: f64, seconds: f64) -> AccuracyJson {
        AccuracyJson {
            mean_abs_grid: rep.mean_abs_grid,
            epicenter_max_rel_pct: rep.epicenter.value * 100.0,
            epicenter_worst_n: rep.epicenter.n,
            inflection_max_rel_pct: rep.inflection.value * 100.0,
            inflection_worst_n: rep.inflection.n,
            max_abs: rep.max_abs.value,
            max_abs_n: rep.max_abs.n,
            max_abs_angle_deg: rep.max_abs.angle_deg,
            cutoff_max_rel_pct: rep.cutoff_rel.value * 100.0,
            cutoff_worst_n: rep.cutoff_rel.n,
            cutoff_worst_angle_deg: rep.cutoff_rel.angle_deg,
            lobe_ratio_min: rep.lobe_ratio_min.value,
            lobe_ratio_min_n: rep.lobe_ratio_min.n,
            lobe_ratio_max: rep.lobe_ratio_max.value,
            lobe_ratio_max_n: rep.lobe_ratio_max.n,
            q,
            nan_points: rep.nan_points,
            seconds,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::twins;

    fn run(t: &twins::Twin, p: &[f64], opts: &AccuracyOptions) -> AccuracyReport {
        let b = twins::blinn();
        accuracy(t.ev.as_ref(), p, Input::NH, b.ev.as_ref(), &[50.0], Input::NH, opts).unwrap()
    }

    #[test]
    fn blinn_against_itself_is_exact_and_cutoffs_match_the_closed_form() {
        let b = twins::blinn();
        let opts = AccuracyOptions { n_max: 50, ..Default::default() };
        let r = run(&b, &[50.0], &opts);
        assert_eq!(r.mean_abs_grid, 0.0);
        assert_eq!(r.max_abs.value, 0.0);
        assert!((r.lobe_ratio_min.value - 1.0).abs() < 1e-12 && (r.lobe_ratio_max.value - 1.0).abs() < 1e-12);
        // The bisected cut-off of cos^n is acos(2^(−q/n)).
        let n = r.lobe_ratio_max.n;
        assert!((r.lobe_ratio_max.angle_deg - (2f64.powf(-8.0 / n)).acos().to_degrees()).abs() < 1e-9);
    }

    #[test]
    fn phong_vs_blinn_mean_error_matches_a_direct_sum() {
        // Phong reads VR and Blinn NH; both see c under the lobe convention, so the error is exactly zero.
        let p = twins::phong();
        let b = twins::blinn();
        let r = accuracy(p.ev.as_ref(), &[1.0], Input::VR, b.ev.as_ref(), &[1.0], Input::NH, &AccuracyOptions { n_max: 20, ..Default::default() })
            .unwrap();
        assert_eq!(r.mean_abs_grid, 0.0);
        // Schlick: compare with an independent direct double loop.
        let s = twins::schlick();
        let r = run(&s, &[50.0], &AccuracyOptions { n_max: 40, ..Default::default() });
        let mut sum = 0.0;
        for n in 1..=40 {
            for d in 0..=90 {
                let c = f64::from(d).to_radians().cos();
                let n = f64::from(n);
                sum += (c / (n - n * c + c) - c.powf(n)).abs();
            }
        }
        assert!((r.mean_abs_grid - sum / (91.0 * 40.0)).abs() < 1e-15);
    }

    #[test]
    fn bad_q_is_an_error() {
        let b = twins::blinn();
        let e = accuracy(b.ev.as_ref(), &[1.0], Input::NH, b.ev.as_ref(), &[1.0], Input::NH, &AccuracyOptions { q: -1.0, ..Default::default() });
        assert!(e.is_err());
    }
}
