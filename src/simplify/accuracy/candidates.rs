//! What one search of the accuracy pass measures, built here in one call per search so that the pass
//! (`numerics::robust`) only measures and judges: the formula as written with the baked values it reads
//! ([`Written`]: the truth's formula and the sample's domain), and the [`Candidates`] — the fastest form the
//! search starts from, the sign every candidate keeps, the order the rules are tried in and each rule's
//! candidate from a current form, with its static cost.

use super::super::rewrite::Analysis;
use super::super::{bake_only, range_sign, simplify};
use super::rule::{identity, Rule, Sites, Source};
use super::{cost, COMPENSATED_POWER, LIVE_CHOICE, RULES};
use crate::ir::Formula;

/// The formula as written, with the baked values it reads folded into its truth's formula: what a search
/// measures against, and whose domain it samples.
pub(crate) struct Written {
    orig: Formula,
    /// The baked values the formula reads (a value it never reads changes nothing: the live decision is then
    /// the whole decision).
    bake: Vec<(usize, f64)>,
    /// `orig` with only `bake` folded, nothing simplified: the formula the truth evaluates.
    truth: Formula,
    /// Its nodes (every node as written, parameter-only ones included): the truth's work per point.
    truth_nodes: usize,
}

impl Written {
    /// `orig` with the values of `bake` that it reads.
    pub(crate) fn new(orig: &Formula, bake: &[(usize, f64)]) -> Written {
        let read = simplify(orig, &[]);
        let read = read.ir.used_params(read.root);
        let bake: Vec<(usize, f64)> = bake.iter().copied().filter(|(k, _)| read.contains(&(*k as u16))).collect();
        Written::folded(orig, bake)
    }

    /// `orig` with every parameter live.
    pub(crate) fn live(orig: &Formula) -> Written {
        Written::folded(orig, Vec::new())
    }

    fn folded(orig: &Formula, bake: Vec<(usize, f64)>) -> Written {
        let truth = bake_only(orig, &bake);
        let truth_nodes = truth.ir.use_counts(truth.root).iter().filter(|&&u| u > 0).count();
        Written { orig: orig.clone(), bake, truth, truth_nodes }
    }

    pub(crate) fn orig(&self) -> &Formula {
        &self.orig
    }

    pub(crate) fn bake(&self) -> &[(usize, f64)] {
        &self.bake
    }

    pub(crate) fn truth(&self) -> &Formula {
        &self.truth
    }

    /// The nodes of the truth's formula (every node as written, parameter-only ones included): its work per
    /// point.
    pub(crate) fn truth_nodes(&self) -> usize {
        self.truth_nodes
    }
}

/// A rule's candidate from a current form ([`Candidates::next`]), matched as soon as it is returned.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Candidate {
    /// The rule does not apply (at this site or any later one).
    Done,
    /// This site's rewrite is the current form again: the search goes on to the next site.
    Same,
    /// A new form and its static cost ([`cost`]).
    New(Formula, f64),
}

/// The candidates of one search, every one with the sign of the formula as written kept: its fastest form
/// (the base), and each rule's rewrite of a current form. With baked values, also the live decision baked
/// ([`LIVE_CHOICE`]) and its powers as compensated chains ([`COMPENSATED_POWER`]).
pub(crate) struct Candidates {
    written: Written,
    /// The formula as written, the source of the whole-formula rules.
    plain: Source,
    /// The live search's choice when it kept a rule: the baked search's source after its first trial.
    choice: Option<Source>,
    base: Formula,
    base_cost: f64,
}

impl Candidates {
    /// The candidates of `written` (nothing baked for the live search). `choice`, the live search's choice when
    /// it kept a rule, is what the baked search's own rules rebuild from; `pow_calls` as [`Source::new`] takes it.
    pub(crate) fn new(written: Written, choice: Option<&Formula>, pow_calls: bool) -> Candidates {
        let (orig, bake) = (&written.orig, &written.bake[..]);
        let sign = range_sign(&written.truth);
        let plain = Source::new(orig, bake, sign, pow_calls);
        let choice = choice.map(|f| Source::new(f, bake, sign, pow_calls));
        let base = plain.base(orig);
        let base_cost = cost(&base);
        Candidates { written, plain, choice, base, base_cost }
    }

    /// The formula as written: what this search measures against.
    pub(crate) fn written(&self) -> &Written {
        &self.written
    }

    /// The formula simplified with the baked values, its sign kept: the fastest form, where the search starts.
    pub(crate) fn base(&self) -> &Formula {
        &self.base
    }

    /// The base's static cost ([`cost`]).
    pub(crate) fn base_cost(&self) -> f64 {
        self.base_cost
    }

    /// The static cost of the source's pow calls form: the budget of a rule that replaces them
    /// ([`Rule::replaces_pow_calls`]).
    pub(crate) fn pow_cost(&self) -> f64 {
        self.plain.pow_cost()
    }

    /// The rules of the live search in the order it tries them: the registry's, those that ask to go early on
    /// `a` (the base, analysed) first; the baked search's own rule left out.
    pub(crate) fn order(&self, a: &Analysis) -> Vec<&'static dyn Rule> {
        let (early, late): (Vec<&'static dyn Rule>, Vec<&'static dyn Rule>) = RULES.iter().copied().filter(|r| r.sites() != Sites::Baked).partition(|r| r.early(a));
        early.into_iter().chain(late).collect()
    }

    /// Rule `r` on `cur` (the current form) at `site`, its sign kept; `None` where it does not apply.
    pub(crate) fn build(&self, r: &dyn Rule, cur: &Analysis, site: Option<usize>) -> Option<Formula> {
        self.plain.build(r, cur, site)
    }

    /// [`Candidates::build`] as the live search tries it: a site's rewrite that is the current form again is
    /// [`Candidate::Same`].
    pub(crate) fn next(&self, r: &dyn Rule, cur: &Analysis, site: Option<usize>) -> Candidate {
        match self.build(r, cur, site) {
            None => Candidate::Done,
            Some(g) if site.is_some() && identity(&g) == identity(&cur.f) => Candidate::Same,
            Some(g) => {
                let c = cost(&g);
                Candidate::New(g, c)
            }
        }
    }

    /// The baked search's first trial: the live choice (the formula as written when the live search kept
    /// nothing) with the values baked, where it is not the base, and its cost.
    pub(crate) fn live_choice(&self) -> Option<(Formula, f64)> {
        let g = self.build_baked(LIVE_CHOICE, &Analysis::new(self.base.clone()), true).filter(|g| identity(g) != identity(&self.base))?;
        let c = cost(&g);
        Some((g, c))
    }

    /// The baked search's second: the baked powers as compensated chains — of the live choice's when it was
    /// kept (`after_choice`), else of the formula as written — and its cost.
    pub(crate) fn compensated_power(&self, cur: &Formula, after_choice: bool) -> Option<(Formula, f64)> {
        let g = self.build_baked(COMPENSATED_POWER, &Analysis::new(cur.clone()), after_choice)?;
        let c = cost(&g);
        Some((g, c))
    }

    /// Rule `r` of the baked search on `cur`, rebuilt from the live choice (`after_choice`: the formula as
    /// written when the live search kept nothing) or from the formula as written; its sign kept.
    pub(crate) fn build_baked(&self, r: &dyn Rule, cur: &Analysis, after_choice: bool) -> Option<Formula> {
        let src = if after_choice { self.choice.as_ref().unwrap_or(&self.plain) } else { &self.plain };
        src.build(r, cur, None)
    }
}
