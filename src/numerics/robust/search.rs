//! The pass's search (module docs of [`super`]): the candidates of the rule registry
//! ([`crate::simplify::accuracy::RULES`]) from the current best, as `simplify::accuracy::Candidates` builds them
//! (one per search), measured, judged, kept or dropped; the baked pass; the replay of a decision; the pass as the
//! compile step's chooser.

use super::measure::{measurer, Conditioning, Reference};
use super::metric::{better, keeps_promise, ErrorStats, TARGET_BITS};
use super::sample::sample;
use crate::base::cancel::Cancel;
use crate::ir::Formula;
use crate::simplify::accuracy::{identity, Candidate, Candidates, Rule, Sites, Written, COMPENSATED_POWER, LIVE_CHOICE};
use crate::simplify::rewrite::Analysis;

/// Budget multiple for a candidate that removes NaN/∞ results where the truth is finite (wrong answers rather
/// than imprecise ones) under `Prefer::Accuracy`, whatever `max_cost` says; `Prefer::Speed` never pays it.
pub const NONFINITE_BUDGET: f64 = 2.0;

/// What to optimise for: speed or accuracy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Prefer {
    /// Only rewrites that cost nothing.
    Speed,
    /// The most accurate form within `max_cost` × the fastest form's cost.
    #[default]
    Accuracy,
}

impl std::str::FromStr for Prefer {
    type Err = String;
    fn from_str(s: &str) -> Result<Prefer, String> {
        match s {
            "speed" => Ok(Prefer::Speed),
            "accuracy" => Ok(Prefer::Accuracy),
            _ => Err(format!("unknown preference `{s}`; expected `speed` or `accuracy`")),
        }
    }
}

/// The search budget of commands that compile a formula to use it (`eval`, `render`, `energy`, the page's
/// renders): small, so the first command on a new file answers quickly; the decision cache makes the second free.
pub(crate) const COMMAND_BUDGET: std::time::Duration = std::time::Duration::from_secs(2);

/// Settings of the accuracy pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassOptions {
    pub prefer: Prefer,
    /// Budget for `Prefer::Accuracy`, as a multiple of the fastest form's static cost.
    pub max_cost: f64,
    /// Domain points the candidates are measured on.
    pub points: usize,
    pub seed: u64,
    /// The math mode candidates are measured in: the one the chosen formula will be compiled in.
    pub math: crate::Mode,
    /// Wall-clock time after which the search stops and keeps the best candidate so far ([`Outcome::truncated`]
    /// says so). The measuring of one candidate is not interrupted.
    pub budget: std::time::Duration,
    /// Where the condition of the truth is measured for the report of the chosen formula (the search itself
    /// always measures it only where it matters).
    pub conditioning: Conditioning,
}

impl PassOptions {
    /// The static cost a rewrite may reach, the fastest form costing `cost_before`: itself under
    /// [`Prefer::Speed`], `max_cost` × it under [`Prefer::Accuracy`].
    fn budget_for(&self, cost_before: f64) -> f64 {
        match self.prefer {
            Prefer::Speed => cost_before,
            Prefer::Accuracy => self.max_cost * cost_before,
        }
    }
}

impl Default for PassOptions {
    fn default() -> PassOptions {
        PassOptions {
            prefer: Prefer::Accuracy,
            max_cost: 1.3,
            points: 4096,
            seed: 0x5eed_1ab5,
            math: crate::Mode::Precise,
            // A library caller gets the whole search (deterministic); the CLI's compiles set 2 s.
            budget: std::time::Duration::from_secs(600),
            conditioning: Conditioning::WhereInaccurate,
        }
    }
}

/// Most truth work per measurement, in static cost units × points ([`cost`]); a formula above ~200 cost units
/// (40 shared trigonometric `let`s, say) is measured on fewer points than asked, and the report says how many.
pub(crate) const MAX_WORK: f64 = 2e7;

/// Why a trial was kept or dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Kept,
    /// No more accurate on the sample (or less accurate somewhere it was as accurate before).
    NotBetter,
    /// More accurate, but over the cost budget.
    OverBudget,
}

/// One candidate tried by the pass.
#[derive(Clone, Debug)]
pub struct Trial {
    /// The candidate: a rule of the registry (its name and description are the report's).
    pub rule: &'static dyn Rule,
    pub kept: bool,
    pub verdict: Verdict,
    /// The site (or variant) of a site-by-site rule.
    pub site: Option<usize>,
    /// Why it was kept or dropped.
    pub reason: String,
    pub stats: ErrorStats,
    pub cost: f64,
}

/// A kept step of the search, enough to rebuild its result without measuring ([`Decision`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    pub rule: &'static dyn Rule,
    pub site: Option<usize>,
}

/// What the pass decided, replayable without measuring: the live steps in order, and for baked values whether
/// the baked live choice was kept and which power form ended the baked search.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Decision {
    pub live: Vec<Step>,
    pub baked_live_choice: bool,
    pub baked_power: Option<&'static dyn Rule>,
}

/// The pass's result: the chosen formula, its error before and after, and every trial.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub formula: Formula,
    /// The form `before` measures: the plain simplification the search started from.
    pub base: Formula,
    pub before: ErrorStats,
    pub after: ErrorStats,
    /// The written form on the search's own points, what each trial's statistics compare with (`before` once
    /// [`Outcome::measured_on`] has measured it again on a report's points).
    pub searched: ErrorStats,
    pub cost_before: f64,
    pub cost_after: f64,
    pub trials: Vec<Trial>,
    /// Domain points measured (fewer than asked for a costly formula; [`MAX_WORK`]).
    pub points: usize,
    /// The search stopped at [`PassOptions::budget`] with candidates left untried.
    pub truncated: bool,
    pub decision: Decision,
}

/// The live pass's formula from its steps, without measuring (what [`Decision::live`] replays).
fn replay_live(cands: &Candidates, steps: &[Step]) -> Formula {
    let mut cur = Analysis::new(cands.base().clone());
    for s in steps {
        if let Some(g) = cands.build(s.rule, &cur, s.site) {
            cur = Analysis::new(g);
        }
    }
    cur.f
}

/// The baked formula from a decision, without measuring.
pub fn replay(orig: &Formula, bake: &[(usize, f64)], d: &Decision, prefer: Prefer) -> Formula {
    let pow_calls = prefer == Prefer::Accuracy;
    let written = Written::new(orig, bake);
    let live = replay_live(&Candidates::new(Written::live(orig), None, pow_calls), &d.live);
    if written.bake().is_empty() {
        return live;
    }
    let cands = Candidates::new(written, (!d.live.is_empty()).then_some(&live), pow_calls);
    let base = Analysis::new(cands.base().clone());
    match (d.baked_power, d.baked_live_choice) {
        (Some(r), after_choice) => cands.build_baked(r, &base, after_choice).unwrap_or(base.f),
        (None, true) => cands.build_baked(LIVE_CHOICE, &base, true).unwrap_or(base.f),
        (None, false) => base.f,
    }
}

/// The measuring half of a search: the reference, the interpreter in the pass's math mode, the budget.
struct Bench<'a> {
    reference: Reference<'a>,
    o: &'a PassOptions,
    /// Trips at the search's time budget ([`PassOptions::budget`]) or when the caller's token does.
    stop: &'a Cancel,
    observe: &'a dyn Fn(Stage),
}

/// What the pass is doing, for a progress display ([`improve_observed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The truth at the sample's points (the first and, with few candidates, the largest part).
    Truth { points: usize },
    /// Measuring a candidate, the `tried`-th of the search.
    Candidate { name: &'static str, tried: usize },
    /// The final report of the chosen form (with the conditioning measured everywhere for `lobe check`).
    Report,
}

impl Bench<'_> {
    /// A candidate's error and values, its regressions against `base`'s values.
    fn run(&self, f: &Formula, base: Option<&[f64]>) -> (ErrorStats, Vec<f64>) {
        self.reference.measure_from(&*measurer(f, self.o.math, self.reference.points().len()), Conditioning::WhereInaccurate, base)
    }

    fn out_of_time(&self) -> bool {
        self.stop.is_cancelled()
    }

    /// The final report of a formula, with the conditioning the options ask for.
    fn report(&self, f: &Formula, s: ErrorStats) -> ErrorStats {
        (self.observe)(Stage::Report);
        match self.o.conditioning {
            Conditioning::WhereInaccurate => s,
            Conditioning::Everywhere => self.reference.measure(&*measurer(f, self.o.math, self.reference.points().len()), Conditioning::Everywhere),
        }
    }
}

/// The points a search measures: fewer for a costly kernel (`base_cost`, the simplified formula's), and for a
/// formula whose truth (every node as written, parameter-only ones included, at every point) is far larger than
/// its simplified kernel — an eighth of a cost unit per node, so only such formulas are affected (a 10⁶-node
/// chain that simplifies to `NH`).
fn points_for(base_cost: f64, truth_nodes: usize, o: &PassOptions) -> usize {
    let work = base_cost.max(truth_nodes as f64 / 8.0).max(1.0);
    o.points.min((MAX_WORK / work) as usize).max(64)
}

/// The accuracy pass on `orig` with `bake` folded in (module docs).
pub fn improve(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Outcome {
    improve_observed(orig, bake, o, &|_| {})
}

/// [`improve`], telling `observe` each [`Stage`] as it starts.
pub(crate) fn improve_observed(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions, observe: &dyn Fn(Stage)) -> Outcome {
    improve_cancellable(orig, bake, o, &Cancel::never(), observe)
}

/// [`improve_observed`], also stopping (with the best form so far, [`Outcome::truncated`]) once `cancel` trips:
/// the time budget is a child of the caller's token, so one mechanism stops the search either way.
pub(crate) fn improve_cancellable(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions, cancel: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let stop = cancel.child(o.budget);
    let pow_calls = o.prefer == Prefer::Accuracy;
    let written = Written::new(orig, bake);
    let live = live_pass(&Candidates::new(Written::live(orig), None, pow_calls), o, &stop, observe);
    if written.bake().is_empty() {
        return live;
    }
    let choice = (!live.decision.live.is_empty()).then_some(&live.formula);
    baked_pass(&Candidates::new(written, choice, pow_calls), &live, o, &stop, observe)
}

/// A trial's verdict: kept when `better` and within `budget`.
fn verdict(better: bool, cost: f64, budget: f64) -> Verdict {
    if !better {
        Verdict::NotBetter
    } else if cost > budget {
        Verdict::OverBudget
    } else {
        Verdict::Kept
    }
}

impl Trial {
    /// A trial of `rule` at `site` and its reason: `prefix`, then `why[0]` when not better, `why[1]` when over
    /// budget, its cost relative to the fastest form's when kept.
    #[allow(clippy::too_many_arguments)]
    fn new(rule: &'static dyn Rule, site: Option<usize>, verdict: Verdict, prefix: &str, why: [String; 2], stats: ErrorStats, cost: f64, cost_before: f64) -> Trial {
        let [not_better, over_budget] = why;
        let reason = match verdict {
            Verdict::NotBetter => not_better,
            Verdict::OverBudget => over_budget,
            Verdict::Kept => format!("cost {:.2}× the fastest form", cost / cost_before),
        };
        Trial { rule, kept: verdict == Verdict::Kept, verdict, site, reason: format!("{prefix}{reason}"), stats, cost }
    }
}

/// The search with every parameter live (module docs).
fn live_pass(cands: &Candidates, o: &PassOptions, stop: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let (w, base, cost_before) = (cands.written(), cands.base().clone(), cands.base_cost());
    let n = points_for(cost_before, w.truth_nodes(), o);
    observe(Stage::Truth { points: n });
    let bench = Bench { reference: Reference::new_until(w.truth(), sample(w.orig(), w.bake(), n, o.seed), stop), o, stop, observe };
    let (before, mut cur_got) = bench.run(&base, None);
    let base_budget = o.budget_for(cost_before);
    let (mut cur, mut cur_stats, mut cur_cost) = (Analysis::new(base.clone()), before.clone(), cost_before);
    let mut trials: Vec<Trial> = Vec::new();
    let mut steps = Vec::new();
    let tries = cands.order(&cur);
    let (mut i, mut k) = (0, 0);
    let mut truncated = false;
    while i < tries.len() {
        if bench.out_of_time() {
            truncated = true;
            break;
        }
        let r = tries[i];
        let site = matches!(r.sites(), Sites::EachInTurn | Sites::FirstKept).then_some(k);
        let (cand, cost_c) = match cands.next(r, &cur, site) {
            Candidate::Done => {
                (i, k) = (i + 1, 0);
                continue;
            }
            Candidate::Same => {
                k += 1;
                continue;
            }
            Candidate::New(cand, cost_c) => (cand, cost_c),
        };
        observe(Stage::Candidate { name: r.name(), tried: trials.len() + 1 });
        let (stats, got) = bench.run(&cand, Some(&cur_got));
        let fixes = keeps_promise(&stats, &cur_stats);
        let budget = match o.prefer {
            Prefer::Accuracy if fixes => base_budget.max(NONFINITE_BUDGET * cost_before),
            // A baked power may cost what the live formula's pow call costs (module docs).
            Prefer::Accuracy if r.replaces_pow_calls() => base_budget.max(cands.pow_cost()),
            _ => base_budget,
        };
        let v = verdict(better(&stats, &cur_stats), cost_c, budget);
        let prefix = site.map_or(String::new(), |s| format!("site {}: ", s + 1));
        let over = format!("more accurate but costs {:.2}× the fastest form (budget {:.2}×)", cost_c / cost_before, budget / cost_before);
        let t = Trial::new(r, site, v, &prefix, ["no more accurate on the sample".to_string(), over], stats, cost_c, cost_before);
        let kept = t.kept;
        if kept {
            steps.push(Step { rule: r, site });
            (cur, cur_stats, cur_cost, cur_got) = (Analysis::new(cand), t.stats.clone(), cost_c, got);
        } else {
            k += 1;
        }
        trials.push(t);
        if site.is_none() || (kept && r.sites() == Sites::FirstKept) {
            (i, k) = (i + 1, 0);
        }
    }
    let before = bench.report(&base, before);
    let after = bench.report(&cur.f, cur_stats);
    let decision = Decision { live: steps, ..Decision::default() };
    Outcome { formula: cur.f, base, searched: before.clone(), before, after, cost_before, cost_after: cur_cost, trials, points: n, truncated, decision }
}

/// With baked values (module docs: bake-consistent choices): what the live kernel computes, the values folded
/// in — the live choice (or the formula as written when the live pass kept nothing) simplified with integer
/// powers above 8 kept as pow calls, as the live kernel calls pow ([`LIVE_CHOICE`]) — always kept, so a baked
/// kernel computes what the live one does; then the compensated chains of those powers where they are
/// no less accurate and cheaper (within 3 ulp of pow). No other rule is tried, so the baked kernel agrees with
/// the live one. `Prefer::Speed` bakes with the simplifier's own chains (the fastest form).
fn baked_pass(cands: &Candidates, live: &Outcome, o: &PassOptions, stop: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let (w, base, cost_before) = (cands.written(), cands.base().clone(), cands.base_cost());
    let n = points_for(cost_before, w.truth_nodes(), o);
    observe(Stage::Truth { points: n });
    let bench = Bench { reference: Reference::new_until(w.truth(), sample(w.orig(), w.bake(), n, o.seed), stop), o, stop, observe };
    let (before, mut cur_got) = bench.run(&base, None);
    let base_budget = o.budget_for(cost_before);
    let (mut cur, mut cur_stats, mut cur_cost) = (base.clone(), before.clone(), cost_before);
    let mut trials = Vec::new();
    let mut decision = Decision { live: live.decision.live.clone(), ..Decision::default() };
    if let Some((cand, c)) = cands.live_choice() {
        let (stats, got) = bench.run(&cand, None);
        let rules: Vec<&str> = live.decision.live.iter().map(|s| s.rule.name()).collect();
        let rules = if rules.is_empty() { "the formula as written".to_string() } else { rules.join(", ") };
        // Always kept: a baked kernel computes what the live one does, whatever the sample of these values
        // says (a form better here belongs in the live search, which judges every value). The report says when
        // the plain baked form would have kept the promise at more points.
        let note = if keeps_promise(&before, &stats) { "" } else { " (the plain form with these values baked keeps the promise at more points of this sample)" };
        let mut t = Trial::new(LIVE_CHOICE, None, Verdict::Kept, &format!("{rules}: "), [String::new(), String::new()], stats, c, cost_before);
        t.reason += note;
        (cur, cur_stats, cur_cost, cur_got) = (cand, t.stats.clone(), c, got);
        decision.baked_live_choice = true;
        trials.push(t);
    }
    let mut truncated = false;
    // `Prefer::Speed` bakes with the simplifier's own chains: no compensated power.
    let power = if o.prefer == Prefer::Accuracy { cands.compensated_power(&cur, decision.baked_live_choice) } else { None };
    if let Some((cand, cost_c)) = power {
        if bench.out_of_time() {
            truncated = true;
        } else {
            let (stats, _) = bench.run(&cand, Some(&cur_got));
            // In place of pow calls: no less accurate (within a bit) and cheaper; in place of plain chains: more
            // accurate within the pow calls' cost.
            let v = if decision.baked_live_choice {
                let no_worse = stats.regressions == 0
                    && stats.wrong_answers().iter().zip(&cur_stats.wrong_answers()).all(|(x, y)| x <= y)
                    && stats.max_bits_well <= cur_stats.max_bits_well.max(TARGET_BITS - 2.0) + 1.0;
                verdict(no_worse, cost_c, cur_cost.next_down())
            } else {
                verdict(better(&stats, &cur_stats), cost_c, base_budget.max(cands.pow_cost()))
            };
            let why = ["less accurate on the sample".to_string(), format!("costs {:.2}× the fastest form, no less than the form it would replace", cost_c / cost_before)];
            let t = Trial::new(COMPENSATED_POWER, None, v, "", why, stats, cost_c, cost_before);
            if t.kept {
                decision.baked_power = Some(COMPENSATED_POWER);
                (cur, cur_stats, cur_cost) = (cand, t.stats.clone(), cost_c);
            }
            trials.push(t);
        }
    }
    let before = bench.report(&base, before);
    let after = bench.report(&cur, cur_stats);
    Outcome { formula: cur, base, searched: before.clone(), before, after, cost_before, cost_after: cur_cost, trials, points: n, truncated: truncated || live.truncated, decision }
}

impl Outcome {
    /// `before` and `after` measured again on `points` domain points of `orig` with `bake` (the search's seed
    /// and math, the condition everywhere): the report of a search made on the commands' sample, so that what it
    /// describes is the kernel they compile (`lobe check`). The trials keep the search's own measurements.
    pub fn measured_on(mut self, orig: &Formula, bake: &[(usize, f64)], o: &PassOptions, points: usize, observe: &dyn Fn(Stage)) -> Outcome {
        let w = Written::new(orig, bake);
        let n = points_for(self.cost_before, w.truth_nodes(), &PassOptions { points, ..*o });
        observe(Stage::Truth { points: n });
        let reference = Reference::everywhere(w.truth(), sample(w.orig(), w.bake(), n, o.seed));
        observe(Stage::Report);
        let measure = |f: &Formula| reference.measure(&*measurer(f, o.math, n), Conditioning::Everywhere);
        self.before = measure(&self.base);
        self.after = if identity(&self.formula) == identity(&self.base) { self.before.clone() } else { measure(&self.formula) };
        self.points = n;
        self
    }
}

/// The accuracy pass as the compile step's chooser ([`crate::FormulaChooser`]): the decision comes from the
/// cache when it has one for this formula, these baked values and these options, and is stored there after a
/// search.
#[derive(Clone, Debug, Default)]
pub(crate) struct Chooser {
    pass: PassOptions,
    cache: Option<std::sync::Arc<dyn DecisionStore>>,
    /// Stops the search early (the compile then uses the best form so far and stores nothing, as after a search
    /// its own budget cut short).
    cancel: Cancel,
}

/// Where decisions are kept between commands ([`crate::numerics::pass_cache::Cache`] on disk): keyed by the formula, its
/// baked values and the options; a miss or a failed store changes nothing but the time taken.
pub trait DecisionStore: Send + Sync + std::fmt::Debug {
    fn load(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Option<Decision>;
    fn store(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions, d: &Decision);

    /// Stores a search's decision unless the search was cut short (by its budget: a loaded run must not fix a
    /// worse choice for later commands).
    fn store_finished(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions, out: &Outcome) {
        if !out.truncated {
            self.store(f, bake, o, &out.decision);
        }
    }
}

impl crate::FormulaChooser for Chooser {
    fn choose(&self, original: &Formula, bake: &[(usize, f64)], simplified: Formula) -> Formula {
        // A decision that keeps nothing compiles the plain simplification, searched or replayed alike (the
        // replay's base may carry a sign clamp the compile step's simplification does not).
        if let Some(d) = self.cache.as_ref().and_then(|c| c.load(original, bake, &self.pass)) {
            return if d == Decision::default() { simplified } else { replay(original, bake, &d, self.pass.prefer) };
        }
        let out = improve_cancellable(original, bake, &self.pass, &self.cancel, &|_| {});
        // A search cut short — by the caller, or by its own budget on a loaded machine — is not this formula's
        // decision: it compiles now, and the next compile searches again rather than replaying a worse choice.
        if let Some(c) = self.cache.as_ref().filter(|_| !self.cancel.is_cancelled()) {
            c.store_finished(original, bake, &self.pass, &out);
        }
        if out.decision == Decision::default() {
            simplified
        } else {
            out.formula
        }
    }
}

/// Compile options with the accuracy pass on, no cache.
pub fn with_pass(opts: crate::Options, pass: PassOptions) -> crate::Options {
    with_pass_cached(opts, pass, None)
}

/// Compile options with the accuracy pass on, its decisions kept in `cache` ([`crate::numerics::pass_cache::Cache::platform`]
/// is the user's cache directory).
pub fn with_pass_cached(opts: crate::Options, pass: PassOptions, cache: Option<std::sync::Arc<dyn DecisionStore>>) -> crate::Options {
    with_pass_until(opts, pass, cache, Cancel::never())
}

/// [`with_pass_cached`] whose searches also stop when `cancel` trips.
pub(crate) fn with_pass_until(mut opts: crate::Options, pass: PassOptions, cache: Option<std::sync::Arc<dyn DecisionStore>>, cancel: Cancel) -> crate::Options {
    let pass = PassOptions { math: opts.math, ..pass };
    opts.accuracy = Some(std::sync::Arc::new(Chooser { pass, cache, cancel }));
    opts
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::truth;
    use crate::simplify::accuracy::RULES;

    /// The registry: every rule listed once under a distinct name, and each rule's example rewritten by it (the
    /// rewritten program shows the example's text, the plain one does not) into a formula equal to the written
    /// one in real arithmetic: at points of its domain (random parameter values), the rewritten formula's exact
    /// value is the written one's (the truth evaluator takes rounding-error builtins as 0, as exact arithmetic
    /// has them).
    #[test]
    fn every_rule_of_the_registry_rewrites_its_example_to_an_equal_formula() {
        let mut names: Vec<&str> = RULES.iter().map(|r| r.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), RULES.len(), "a name twice in the registry");
        for (i, &r) in RULES.iter().enumerate() {
            assert_eq!(crate::simplify::accuracy::rule(r.name()).map(|x| x.name()), Some(r.name()));
            assert!(!r.doc().is_empty(), "{r}");
            let ex = r.example();
            let f = crate::front::parse("rule.brdf", ex.before).unwrap();
            let src = Candidates::new(Written::new(&f, ex.bake), None, true);
            let plain = src.base().clone();
            let g = src.build(r, &Analysis::new(plain.clone()), ex.site).unwrap_or_else(|| panic!("{r} does not rewrite its example {:?}", ex.before));
            assert_ne!(identity(&g), identity(&plain), "{r}");
            let (t, p) = (g.to_program_text(), plain.to_program_text());
            assert!(t.contains(ex.shows) && !p.contains(ex.shows), "{r}: {:?} in\n{t}\nnot in\n{p}", ex.shows);
            let mut compared = 0;
            for pt in sample(&f, ex.bake, 3000, 11 + i as u64) {
                let (a, b) = (truth::eval(&plain, &pt.x, &pt.p), truth::eval(&g, &pt.x, &pt.p));
                if !a.is_finite() || a == 0.0 {
                    continue; // 0/0 or ∞ as written, where a rule may give the limit; or below the f64 range
                }
                compared += 1;
                assert!((a - b).abs() <= 1e-9 * a.abs(), "{r}: {a} vs {b} at {pt:?}\n{}", g.to_text());
            }
            assert!(compared > 500, "{r}: {compared} points compared");
        }
    }

    /// A decision store in memory that counts what it is given.
    #[derive(Debug, Default)]
    struct Recorder(std::sync::Mutex<Vec<Decision>>);
    impl DecisionStore for Recorder {
        fn load(&self, _: &Formula, _: &[(usize, f64)], _: &PassOptions) -> Option<Decision> {
            None
        }
        fn store(&self, _: &Formula, _: &[(usize, f64)], _: &PassOptions, d: &Decision) {
            self.0.lock().unwrap().push(d.clone());
        }
    }

    /// A search its budget cut short compiles its best form so far but is never stored: a loaded first run must
    /// not fix a worse decision for every later command. A search that finished is stored.
    #[test]
    fn a_search_cut_short_by_its_budget_is_not_cached() {
        use crate::FormulaChooser;
        let f = crate::front::parse("b.brdf", "param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))").unwrap();
        let simplified = crate::simplify::simplify(&f, &[]);
        for (budget, stored) in [(std::time::Duration::ZERO, 0), (std::time::Duration::from_secs(600), 1)] {
            let rec = std::sync::Arc::new(Recorder::default());
            let pass = PassOptions { points: 512, budget, ..PassOptions::default() };
            let chooser = Chooser { pass, cache: Some(rec.clone()), cancel: Cancel::never() };
            let out = improve_cancellable(&f, &[], &pass, &Cancel::never(), &|_| {});
            assert_eq!(out.truncated, budget.is_zero());
            chooser.choose(&f, &[], simplified.clone());
            assert_eq!(rec.0.lock().unwrap().len(), stored, "budget {budget:?}");
        }
    }

    /// The stages a progress display sees: the truth first, each measured candidate in order, the report last;
    /// observing changes nothing.
    #[test]
    fn the_pass_reports_its_stages_in_order() {
        let f = crate::front::parse("b.brdf", "param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))").unwrap();
        let o = PassOptions { points: 512, ..PassOptions::default() };
        let seen = std::sync::Mutex::new(vec![]);
        let out = improve_observed(&f, &[], &o, &|s| seen.lock().unwrap().push(s));
        let seen = seen.into_inner().unwrap();
        assert_eq!(seen.first(), Some(&Stage::Truth { points: out.points }));
        assert_eq!(seen.last(), Some(&Stage::Report));
        let tried: Vec<usize> = seen.iter().filter_map(|s| if let Stage::Candidate { tried, .. } = s { Some(*tried) } else { None }).collect();
        assert_eq!(tried, (1..=out.trials.len()).collect::<Vec<_>>());
        assert_eq!(out.formula.to_program_text(), improve(&f, &[], &o).formula.to_program_text());
    }
}
