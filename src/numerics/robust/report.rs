//! The check command's JSON report of a pass (keys listed in docs/commands.md).

use super::metric::{ErrorStats, Worst};
use super::search::Outcome;
use crate::base::json::{self, Named};
use crate::ir::Formula;

/// The check command's JSON report (keys listed in docs/commands.md; numbers follow [`crate::base::json`]): the formula, its
/// simplification, the builtins' bounds, the pass's [`Outcome`] (the error after the pass at the top level,
/// `before` for the plain simplification), and the compile times. The caller fills it; the error statistics
/// come from [`ErrorStatsJson::new`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct CheckReport {
    pub file: String,
    pub name: String,
    pub citation: Option<String>,
    /// `null`, or `"red"` for a colour formula (its red channel is checked).
    pub channel: Option<&'static str>,
    pub params: Vec<ParamJson>,
    pub formula: String,
    pub simplified: String,
    pub nodes_before: usize,
    pub nodes_after: usize,
    pub rewrites: Vec<RewriteCount>,
    pub rounding_changes: Vec<RoundingJson>,
    pub passes: usize,
    pub used_inputs: Vec<&'static str>,
    pub unused_inputs: Vec<&'static str>,
    pub math: &'static str,
    pub builtins: Vec<BuiltinBound>,
    pub points: usize,
    #[serde(flatten)]
    pub after: ErrorStatsJson,
    #[serde(serialize_with = "json::opt_num")]
    pub condition_ulps_at_worst_well_conditioned: Option<f64>,
    pub before: ErrorStatsJson,
    pub accuracy_rewrites: Vec<TrialJson>,
    /// The search stopped at its time budget.
    pub truncated: bool,
    pub compiled: String,
    #[serde(serialize_with = "json::num")]
    pub cost_ratio: f64,
    pub compile_us: CompileUs,
    /// Fast math only: fast against precise math over the report's points.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fast_vs_precise: Option<FastJson>,
}

/// A declared parameter: its range, its baked value (`null` when live or unused) and whether code reads it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ParamJson {
    pub name: String,
    #[serde(serialize_with = "json::num")]
    pub default: f64,
    #[serde(serialize_with = "json::num")]
    pub lo: f64,
    #[serde(serialize_with = "json::num")]
    pub hi: f64,
    #[serde(serialize_with = "json::opt_num")]
    pub baked: Option<f64>,
    pub live: bool,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct RewriteCount {
    pub rule: &'static str,
    pub count: usize,
}

/// A simplification that changed rounding, at a line and column of the source.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RoundingJson {
    pub rule: &'static str,
    pub line: usize,
    pub col: usize,
    pub detail: String,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct BuiltinBound {
    pub name: &'static str,
    pub bound: String,
}

/// Compile times in µs.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CompileUs {
    #[serde(serialize_with = "json::num")]
    pub jit: f64,
    #[serde(serialize_with = "json::num")]
    pub interp: f64,
}

/// [`ErrorStats`] in a report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ErrorStatsJson {
    #[serde(serialize_with = "json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max: f64,
    pub bits_error_worst: Option<WorstJson>,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max_well_conditioned: f64,
    pub bits_error_worst_well_conditioned: Option<WorstJson>,
    pub nonfinite_where_finite: usize,
    pub ill_conditioned: usize,
    pub undefined: usize,
    pub limit_points: usize,
    pub poles: usize,
    pub pole_misses: usize,
    pub wrong_sign: usize,
    pub over_target_well_conditioned: usize,
}

/// `fast_vs_precise` of the check report (fast math): the chosen form in fast math against precise math.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FastJson {
    #[serde(serialize_with = "json::num")]
    pub max_rel: f64,
    pub at: Option<FastAtJson>,
    #[serde(serialize_with = "json::num")]
    pub max_abs_vs_peak: f64,
    pub nonfinite: usize,
    pub points: usize,
}

/// Where fast math is furthest from precise math.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FastAtJson {
    pub inputs: Named,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub fast: f64,
    #[serde(serialize_with = "json::num")]
    pub precise: f64,
}

/// A [`Worst`] point: the inputs `f` reads and every parameter, by name.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WorstJson {
    pub inputs: Named,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub value: f64,
    #[serde(serialize_with = "json::num")]
    pub truth: f64,
    #[serde(serialize_with = "json::num")]
    pub bits: f64,
}

impl WorstJson {
    pub(crate) fn new(f: &Formula, w: &Worst) -> WorstJson {
        WorstJson {
            inputs: Named::new(f.used_inputs().iter().map(|i| (i.name(), w.point.x[i.index()]))),
            params: Named::new(f.params.iter().zip(&w.point.p).map(|(d, v)| (d.name.as_str(), *v))),
            value: w.got,
            truth: w.truth,
            bits: w.bits,
        }
    }
}

impl ErrorStatsJson {
    /// The statistics of formula `f` (which names the worst points' inputs and parameters).
    pub fn new(f: &Formula, s: &ErrorStats) -> ErrorStatsJson {
        ErrorStatsJson {
            bits_error_avg: s.avg_bits,
            bits_error_max: s.max_bits,
            bits_error_worst: s.worst.as_ref().map(|w| WorstJson::new(f, w)),
            bits_error_max_well_conditioned: s.max_bits_well,
            bits_error_worst_well_conditioned: s.worst_well.as_ref().map(|w| WorstJson::new(f, w)),
            nonfinite_where_finite: s.nonfinite,
            ill_conditioned: s.ill_conditioned,
            undefined: s.undefined,
            limit_points: s.limits,
            poles: s.poles,
            pole_misses: s.pole_misses,
            wrong_sign: s.wrong_sign,
            over_target_well_conditioned: s.over_target,
        }
    }
}

/// One [`Trial`](super::search::Trial) of the pass: its cost relative to the plain simplification's and its error.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrialJson {
    pub rule: &'static str,
    pub kept: bool,
    pub reason: String,
    #[serde(serialize_with = "json::num")]
    pub cost_ratio: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max: f64,
    pub nonfinite_where_finite: usize,
}

impl TrialJson {
    /// The pass's trials.
    pub fn all(pass: &Outcome) -> Vec<TrialJson> {
        pass.trials
            .iter()
            .map(|t| TrialJson {
                rule: t.rule.name(),
                kept: t.kept,
                reason: t.reason.clone(),
                cost_ratio: t.cost / pass.cost_before,
                bits_error_avg: t.stats.avg_bits,
                bits_error_max: t.stats.max_bits,
                nonfinite_where_finite: t.stats.nonfinite,
            })
            .collect()
    }
}
