//! What every candidate of the accuracy pass is: a [`Rule`] (name, description, how it applies, the rewrite
//! and an example), and the [`Source`] whole-formula rules rebuild from. The registry, the one list of rules,
//! is [`super::RULES`].

use super::super::rewrite::Analysis;
use super::super::{keep_sign, simplify, simplify_with, Sign};
use crate::ir::{Formula, NodeId};

/// How the search applies a rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sites {
    /// A whole-formula form, rebuilt from the search's [`Source`] rather than from the current best.
    Whole,
    /// Every place it matches at once.
    Everywhere,
    /// One place (or one variant) at a time, numbered from 0 in arena order: the search keeps it where it
    /// helps and leaves it where it only costs.
    EachInTurn,
    /// Like [`Sites::EachInTurn`], but once one site is kept the rule is done (its own terms would be sites
    /// next).
    FirstKept,
    /// Only with baked values, as the baked pass's first trial: the live decision with the values folded in.
    Baked,
}

/// A formula a rule rewrites, for the registry's documentation and its test.
#[derive(Clone, Copy, Debug)]
pub struct Example {
    /// Source text.
    pub before: &'static str,
    /// Parameters baked (by index) before the rule is applied.
    pub bake: &'static [(usize, f64)],
    /// The site tried.
    pub site: Option<usize>,
    /// Text the rewritten program shows and the plain one does not.
    pub shows: &'static str,
}

/// One candidate rewrite of the accuracy pass (module docs of [`super`]). Every rule is exact in real
/// arithmetic; only where f64 rounds changes. It proposes; the pass (`numerics::robust`) measures and judges.
/// Readable from outside the crate (reports name and describe rules), implementable only inside it: the rewrite
/// reads the crate's own analysis.
#[allow(private_interfaces)]
pub trait Rule: Sync {
    /// The name in reports and in the pass cache's files.
    fn name(&self) -> &'static str;
    /// What it does, for reports.
    fn doc(&self) -> &'static str;
    /// How the search applies it.
    fn sites(&self) -> Sites;
    /// The rewritten formula built from `a` (the current best, analysed once for every rule and site tried
    /// on it), or from `src` for a whole-formula rule; `None` where it does not apply or changes nothing.
    fn apply(&self, src: &Source, a: &Analysis, site: Option<usize>) -> Option<Formula>;
    /// A formula it rewrites.
    fn example(&self) -> Example;
    /// Tried before the other rules on `a` (the live search's source): see `compensated-params`.
    fn early(&self, _a: &Analysis) -> bool {
        false
    }
    /// Its budget may reach the cost of the source's pow calls (it replaces them: `compensated-power`).
    fn replaces_pow_calls(&self) -> bool {
        false
    }
    /// [`Rule::apply`] to `f` with nothing baked and `f` as its own source.
    fn apply_to(&self, f: &Formula, site: Option<usize>) -> Option<Formula> {
        self.apply(&Source::new(f, &[], super::super::sign_of(f, &[]), true), &Analysis::new(f.clone()), site)
    }
}

/// A rule prints as its name.
impl std::fmt::Display for dyn Rule {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::fmt::Debug for dyn Rule {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Rules are known by name (the registry's names are distinct: its test).
impl PartialEq for dyn Rule {
    fn eq(&self, o: &dyn Rule) -> bool {
        self.name() == o.name()
    }
}

impl Eq for dyn Rule {}

/// What the whole-formula rules rebuild from: the search's source formula (the formula as written, or the live
/// choice for baked values), the baked values, the sign every candidate keeps, and its forms with integer
/// powers above 8 kept as pow calls.
pub(crate) struct Source {
    src: Formula,
    bake: Vec<(usize, f64)>,
    sign: Sign,
    /// The accuracy preference (pow calls where the live kernel calls pow); the speed preference bakes with
    /// the simplifier's chains.
    pow_calls: bool,
    pow_call: Formula,
    compensated: Option<Formula>,
}

impl Source {
    pub(crate) fn new(src: &Formula, bake: &[(usize, f64)], sign: Sign, pow_calls: bool) -> Source {
        let pow_call = simplify_with(src, bake, &super::chain::pow_call_policy()).0;
        let compensated = super::chain::compensated_powers(&pow_call);
        Source { src: src.clone(), bake: bake.to_vec(), sign, pow_calls, pow_call, compensated }
    }

    /// `f` simplified with the baked values, its sign kept: the fastest form.
    pub(crate) fn base(&self, f: &Formula) -> Formula {
        keep_sign(&self.sign, simplify(f, &self.bake))
    }

    /// Rule `r` on `a` (the current best) at `site`, its sign kept.
    pub(crate) fn build(&self, r: &dyn Rule, a: &Analysis, site: Option<usize>) -> Option<Formula> {
        Some(keep_sign(&self.sign, r.apply(self, a, site)?))
    }

    /// The static cost of the source's pow calls form.
    pub(crate) fn pow_cost(&self) -> f64 {
        super::cost(&self.pow_call)
    }

    pub(crate) fn src(&self) -> &Formula {
        &self.src
    }

    pub(crate) fn bake(&self) -> &[(usize, f64)] {
        &self.bake
    }

    pub(crate) fn pow_calls(&self) -> bool {
        self.pow_calls
    }

    pub(crate) fn pow_call(&self) -> &Formula {
        &self.pow_call
    }

    pub(crate) fn compensated(&self) -> Option<&Formula> {
        self.compensated.as_ref()
    }
}

/// A formula's identity for the search: a hash of the tree its root reaches (operations, constants' bits and
/// operands, recursively), so two arenas that build the same tree are the same candidate whatever their
/// layout and names.
pub fn identity(f: &Formula) -> u64 {
    use std::hash::{Hash, Hasher};
    let uses = f.ir.use_counts(f.root);
    let mut h: Vec<u64> = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        if uses[id.index()] == 0 {
            h.push(0);
            continue;
        }
        let mut s = std::collections::hash_map::DefaultHasher::new();
        let node = *f.ir.node(id);
        node.map_args(|_| NodeId(0)).hash(&mut s);
        node.for_each_arg(|a| h[a.index()].hash(&mut s));
        h.push(s.finish());
    }
    h[f.root.index()]
}
