//! What `lobe check` reports about a formula, computed once for every front end (the command's text and
//! JSON report, the Python binding's `Kernel.check()`): the simplification and its rewrites, the inputs read,
//! parameters baked or live, the builtins' bounds, the accuracy pass's [`Outcome`] measured everywhere, and
//! the compile time on each backend. A colour formula is checked on its red channel ([`Check::channel`]).

use super::robust::{self, ErrorStatsJson, Outcome, PassOptions, Stage};
use crate::ir::{Formula, Input, InputSet};
use crate::{Backend, Diagnostics, Mode, Options};

/// One formula's check (see the module docs).
pub struct Check {
    /// The channel checked: the whole formula, or its red channel (named so).
    pub formula: Formula,
    /// `Some("red")` for a colour formula.
    pub channel: Option<&'static str>,
    pub bake: Vec<(usize, f64)>,
    pub simplified: Formula,
    pub report: crate::simplify::Report,
    pub used: InputSet,
    pub unused: Vec<&'static str>,
    /// Parameters the simplified formula still reads.
    pub live: Vec<u16>,
    /// The builtins the simplified formula calls, each with its stated bound in the math mode.
    pub bounds: Vec<(&'static str, String)>,
    pub math: Mode,
    pub pass: Outcome,
    pub pass_ms: f64,
    /// How far the worst well-conditioned point is from the ill-conditioned threshold.
    pub cond_well: Option<f64>,
    pub jit_us: f64,
    pub interp_us: f64,
    /// In fast math: the chosen form in fast math against the same form in precise math, over the report's
    /// points (every parameter over its declared range).
    pub fast_vs_precise: Option<FastVsPrecise>,
}

/// How far fast math moves a formula from precise math over a sample: the largest relative difference where the
/// precise value is at least [`FastVsPrecise::REL_FLOOR`] (below it fast exp flushes to 0, and a relative
/// difference to a value that is 0 in one mode says nothing), the largest absolute difference relative to the
/// sample's largest precise value (fast acos and sin are absolute-error functions), and the points where one mode
/// is finite and the other is not.
#[derive(Clone, Debug, PartialEq)]
pub struct FastVsPrecise {
    pub max_rel: f64,
    /// The point of `max_rel`, its fast and precise values.
    pub at: Option<(robust::Point, f64, f64)>,
    pub max_abs_vs_peak: f64,
    pub nonfinite: usize,
    pub points: usize,
}

impl FastVsPrecise {
    /// Where relative differences are counted: well above fast exp's flush to 0 below e⁻⁷⁰⁸ ≈ 3.3e-308.
    pub const REL_FLOOR: f64 = 1e-290;

    /// `f` compiled in both modes (interpreted: the tiers give its bits) over `points`.
    pub fn measure(f: &Formula, points: &[robust::Point]) -> Result<FastVsPrecise, Diagnostics> {
        use rayon::prelude::*;
        let k = |mode| crate::build_kernel(std::sync::Arc::new(f.clone()), Backend::Interp, mode);
        let (fast, precise) = (k(Mode::Fast)?, k(Mode::Precise)?);
        let rows: Vec<(f64, f64)> = points.par_iter().map(|pt| (fast.evaluator().eval(&pt.x, &pt.p), precise.evaluator().eval(&pt.x, &pt.p))).collect();
        let peak = rows.iter().filter(|r| r.1.is_finite()).fold(0.0f64, |m, r| m.max(r.1.abs()));
        let mut out = FastVsPrecise { max_rel: 0.0, at: None, max_abs_vs_peak: 0.0, nonfinite: 0, points: points.len() };
        for (pt, &(a, b)) in points.iter().zip(&rows) {
            if a.is_finite() != b.is_finite() {
                out.nonfinite += 1;
                continue;
            }
            if !b.is_finite() || a == b {
                continue;
            }
            if peak > 0.0 {
                out.max_abs_vs_peak = out.max_abs_vs_peak.max((a - b).abs() / peak);
            }
            let rel = (a - b).abs() / b.abs();
            if b.abs() >= Self::REL_FLOOR && rel > out.max_rel {
                out.max_rel = rel;
                out.at = Some((pt.clone(), a, b));
            }
        }
        Ok(out)
    }
}

/// The builtins `f` calls, each with its stated bound in `mode` (sorted by table order).
fn builtin_bounds(f: &Formula, mode: Mode) -> Vec<(&'static str, String)> {
    let mut used = vec![];
    f.ir.walk(f.root, |n| {
        if let crate::ir::Node::Call(b, _) = n {
            used.push(*b);
        }
    });
    used.sort();
    used.dedup();
    used.into_iter().map(|b| (b.name(), b.info().bound.describe(mode))).collect()
}

/// Checks `whole` (its red channel if it is a colour formula) with `set` baked: the accuracy pass searches at
/// `pass` (the commands' points and options, so the form it chooses is the one they compile; its decision goes
/// to `store` unless the budget cut it short), then the written and the chosen form are measured on
/// `report_points` points with the truth's condition everywhere; `observe` hears the stages.
pub fn check(
    whole: &Formula,
    set: &[(String, f64)],
    pass: &PassOptions,
    report_points: usize,
    store: Option<&dyn robust::DecisionStore>,
    observe: &dyn Fn(Stage),
) -> Result<Check, Diagnostics> {
    let channel = whole.is_rgb().then_some("red");
    let f = whole.named_channels().remove(0);
    let bake = crate::resolve_bake(&f, set)?;
    let (simplified, report) = crate::simplify::simplify_report(&f, &bake);
    let used = simplified.used_inputs();
    let unused = Input::ALL.iter().filter(|i| !used.contains(**i)).map(|i| i.name()).collect();
    let live = simplified.ir.used_params(simplified.root).into_iter().collect();
    let t = std::time::Instant::now();
    let opts = PassOptions { conditioning: robust::Conditioning::WhereInaccurate, ..*pass };
    let outcome = robust::improve_observed(&f, &bake, &opts, observe);
    if let Some(s) = store {
        s.store_finished(&f, &bake, &opts, &outcome);
    }
    let mut outcome = outcome;
    if outcome.decision == robust::Decision::default() {
        // A decision that keeps nothing compiles the plain simplification (the search's base may carry a sign
        // clamp the compile step's does not): show that kernel.
        outcome.formula = simplified.clone();
    }
    let outcome = outcome.measured_on(&f, &bake, &opts, report_points, observe);
    let pass_ms = t.elapsed().as_secs_f64() * 1e3;
    let cond_well = outcome.after.condition_at_worst_well;
    let compile = |backend| Options { backend, bake: set.to_vec(), math: pass.math, ..Options::default() };
    let fast_vs_precise = if pass.math == Mode::Fast {
        let points = robust::sample(&f, &bake, outcome.points, pass.seed);
        Some(FastVsPrecise::measure(&outcome.formula, &points)?)
    } else {
        None
    };
    let jit = crate::compile_formula(f.clone(), &compile(Backend::Jit))?;
    let interp = crate::compile_formula(f.clone(), &compile(Backend::Interp))?;
    Ok(Check {
        bounds: builtin_bounds(&simplified, pass.math),
        formula: f,
        channel,
        bake,
        simplified,
        report,
        used,
        unused,
        live,
        math: pass.math,
        pass: outcome,
        pass_ms,
        cond_well,
        jit_us: jit.compile_time.as_secs_f64() * 1e6,
        interp_us: interp.compile_time.as_secs_f64() * 1e6,
        fast_vs_precise,
    })
}

impl Check {
    /// The JSON report of the check command.
    pub fn json(&self) -> robust::CheckReport {
        let f = &self.formula;
        let params = f
            .params
            .iter()
            .enumerate()
            .map(|(i, p)| robust::ParamJson {
                name: p.name.clone(),
                default: p.default,
                lo: p.lo,
                hi: p.hi,
                baked: self.bake.iter().find(|(j, _)| *j == i).map(|(_, v)| *v),
                live: self.live.contains(&(i as u16)),
            })
            .collect();
        let rounding_changes = self
            .report
            .rounding
            .iter()
            .map(|r| {
                let (line, col) = crate::base::span::line_col(&f.source, r.span.start as usize);
                robust::RoundingJson { rule: r.rule, line, col, detail: r.detail.clone() }
            })
            .collect();
        let pass = &self.pass;
        robust::CheckReport {
            file: f.file.clone(),
            name: f.display_name().to_string(),
            citation: f.meta.citation.clone(),
            channel: self.channel,
            params,
            // The let form: printing shared `let`s as a tree grows exponentially with their depth.
            formula: f.to_program_text(),
            simplified: self.simplified.to_program_text(),
            nodes_before: self.report.nodes_before,
            nodes_after: self.report.nodes_after,
            rewrites: self.report.fired.iter().map(|(k, v)| robust::RewriteCount { rule: k, count: *v }).collect(),
            rounding_changes,
            passes: self.report.passes,
            used_inputs: self.used.iter().map(|i| i.name()).collect(),
            unused_inputs: self.unused.clone(),
            math: self.math.name(),
            builtins: self.bounds.iter().map(|(n, b)| robust::BuiltinBound { name: n, bound: b.clone() }).collect(),
            points: pass.points,
            after: ErrorStatsJson::new(f, &pass.after),
            condition_ulps_at_worst_well_conditioned: self.cond_well,
            before: ErrorStatsJson::new(f, &pass.before),
            accuracy_rewrites: robust::TrialJson::all(pass),
            truncated: pass.truncated,
            compiled: pass.formula.to_program_text(),
            cost_ratio: pass.cost_after / pass.cost_before,
            compile_us: robust::CompileUs { jit: self.jit_us, interp: self.interp_us },
            fast_vs_precise: self.fast_vs_precise.as_ref().map(|d| robust::FastJson {
                max_rel: d.max_rel,
                at: d.at.as_ref().map(|(pt, fast, precise)| robust::FastAtJson {
                    inputs: crate::base::json::Named::new(f.used_inputs().iter().map(|i| (i.name(), pt.x[i.index()]))),
                    params: crate::base::json::Named::new(f.params.iter().zip(&pt.p).map(|(d, v)| (d.name.as_str(), *v))),
                    fast: *fast,
                    precise: *precise,
                }),
                max_abs_vs_peak: d.max_abs_vs_peak,
                nonfinite: d.nonfinite,
                points: d.points,
            }),
        }
    }
}
