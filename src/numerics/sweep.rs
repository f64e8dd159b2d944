//! The stability sweep: evaluate a formula over its whole domain and count NaN, ±inf, negative values and
//! values above a bound, per region of the input domain, with the first example of each.
//!
//! Domain: n and every other parameter over its declared range (ends, default, interior points); each input
//! the formula reads over 27 cosines — −1, −0.5, −1e-9, −5e-324 (negative), ±0, 5e-324 and 1e-310
//! (denormals), 1e-300, 1e-16, 1e-8 (tiny), nine interior values, 1 − 1e-8, 1 − 2 ulp, 1 − 1 ulp (near
//! one), 1, and 1 + 1 ulp, 1 + 1e-8, 1.5 (above one: cosines of rounded vectors overshoot). Inputs it does not
//! read are fixed at 0.5. The full Cartesian product is evaluated when it has at most `max_evals` points;
//! otherwise each parameter combination gets an evenly strided, combination-dependent subset of the input
//! grid (deterministic), so every input value is still visited. A point's region is the most extreme category
//! among its inputs (negative > above-one > denormal > zero > tiny > near-one > one > interior).
//!
//! Cosines are not independent: NH, VR and VH follow from NL, NV and the azimuth between L and V, so a formula
//! that reads one of them with another cosine is swept on real geometry ([`DomainKind::LinkedCosines`]): L at
//! each cosine of the grid in [−1, 1] (azimuth 0: every cosine is invariant under rotation about N) and V at
//! each of those cosines × 6 azimuths (3 456 pairs per parameter combination), every input computed from the pair
//! by [`super::inputs_from_dirs`]. Directions are built from their cosine (z = c exactly), so denormal, tiny and
//! 1 − ulp cosines are reached as on the independent grid, and combinations no pair produces (NL = 1 with
//! NH = 0.1 above the horizon) are never evaluated. A point's region is the most extreme category among the
//! values read. A formula that reads directions (Lx..Vz) is swept the same way with L over all 6 azimuths too
//! (20 736 pairs), its region the more extreme of the two polar cosines' categories. This includes V = L,
//! V = the mirror of L (VR = 1) and V = −L in the horizon plane, where the half vector is undefined. Extents on
//! geometry follow one direction's polar angle ([`extent_polar`]); one cosine alone cannot move.
//!
//! Negative values are only visible on the *unclamped* formula: the lowering's root is `max(raw, 0)`, which
//! [`Formula::unclamped`] peels. The input clamps `clamp(INPUT, 0, 1)` stay, so negative and above-one
//! cosines exercise those clamps (a NaN there is a real bug in the domain policy); on geometry, cosines above one
//! occur only as rounding makes them.
//!
//! Cost: about `max_evals` batched evaluations (default 2 M; never fewer than 64 input points per parameter
//! combination), in parallel over parameter combinations; measured times in BENCHMARKS.md.

use crate::base::json::{self, Named};
use crate::builtins::Builtin;
use crate::ir::{Formula, InputSet, Node, ParamDecl, N_INPUTS};
use crate::backend::{Columns, Evaluator};
use rayon::prelude::*;

impl Formula {
    /// The formula without its root `max(raw, 0)` (from the lowering), so a sweep sees negative raw values.
    /// Returns the formula unchanged when the root is not such a clamp.
    pub fn unclamped(&self) -> Formula {
        let raw = match *self.ir.node(self.root) {
            Node::Call(Builtin::Max, [a, b, _]) => {
                let zero = |id| self.ir.node(id).as_const().is_some_and(|v| v == 0.0);
                if zero(b) {
                    Some(a)
                } else if zero(a) {
                    Some(b)
                } else {
                    None
                }
            }
            _ => None,
        };
        match raw {
            Some(r) => {
                let (ir, root) = self.ir.compact(r);
                Formula { ir, root, ..self.clone() }
            }
            None => self.clone(),
        }
    }
}

/// Input value categories, in increasing extremity order for region labels (see module docs).
const CATS: [&str; 8] = ["interior", "one", "near-one", "tiny", "zero", "denormal", "above-one", "negative"];

fn grid() -> Vec<(f64, usize)> {
    let one_m = f64::from_bits(1f64.to_bits() - 1);
    let one_m2 = f64::from_bits(1f64.to_bits() - 2);
    let one_p = f64::from_bits(1f64.to_bits() + 1);
    let mut g = vec![];
    g.extend([-1.0, -0.5, -1e-9, -5e-324].map(|v| (v, 7)));
    g.extend([0.0, -0.0].map(|v| (v, 4)));
    g.extend([5e-324, 1e-310].map(|v| (v, 5)));
    g.extend([1e-300, 1e-16, 1e-8].map(|v| (v, 3)));
    g.extend([1e-4, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 0.9999].map(|v| (v, 0)));
    g.extend([1.0 - 1e-8, one_m2, one_m].map(|v| (v, 2)));
    g.push((1.0, 1));
    g.extend([one_p, 1.0 + 1e-8, 1.5].map(|v| (v, 6)));
    g
}

/// Values tried for one parameter: the range ends, the default, and interior points (geometric when the
/// range is positive, since exponents act multiplicatively).
pub(crate) fn param_values(d: &ParamDecl) -> Vec<f64> {
    let mut v = vec![d.lo, d.hi, d.default];
    if d.name == "n" {
        v.extend([1.0, 1.0 + 1e-9, 1.5, 2.0, 3.0, 5.0, 10.0, 50.0, 100.0, 268.0, 500.0, 999.0, 1000.0]);
    }
    for t in [0.1, 0.5, 0.9] {
        v.push(d.lo + t * (d.hi - d.lo));
        if d.lo > 0.0 {
            v.push(d.lo * (d.hi / d.lo).powf(t));
        }
    }
    let mut v: Vec<f64> = v.into_iter().filter(|x| x.is_finite() && *x >= d.lo && *x <= d.hi).collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

/// An offending point.
#[derive(Clone, Debug, PartialEq)]
pub struct Example {
    pub inputs: [f64; N_INPUTS],
    pub params: Vec<f64>,
    pub value: f64,
}

/// Counts for one region. Serialises as the counts alone (`evaluated`, `nan`, …): the region's name and the
/// examples, whose parameters need their names, are the caller's to add.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RegionStats {
    #[serde(skip)]
    pub region: &'static str,
    pub evaluated: u64,
    pub nan: u64,
    pub inf: u64,
    pub negative: u64,
    pub over_bound: u64,
    #[serde(skip)]
    pub first_nan: Option<Example>,
    #[serde(skip)]
    pub first_inf: Option<Example>,
    #[serde(skip)]
    pub first_negative: Option<Example>,
    #[serde(skip)]
    pub first_over_bound: Option<Example>,
}

impl RegionStats {
    /// The count of one kind by name: nan, inf, negative, bound.
    pub fn count(&self, kind: &str) -> u64 {
        match kind {
            "nan" => self.nan,
            "inf" => self.inf,
            "negative" => self.negative,
            _ => self.over_bound,
        }
    }

    fn merge(&mut self, o: RegionStats) {
        self.evaluated += o.evaluated;
        self.nan += o.nan;
        self.inf += o.inf;
        self.negative += o.negative;
        self.over_bound += o.over_bound;
        self.first_nan = self.first_nan.take().or(o.first_nan);
        self.first_inf = self.first_inf.take().or(o.first_inf);
        self.first_negative = self.first_negative.take().or(o.first_negative);
        self.first_over_bound = self.first_over_bound.take().or(o.first_over_bound);
    }
}

/// Options for [`sweep`].
#[derive(Clone, Debug, PartialEq)]
pub struct SweepOptions {
    /// Values above this count as `over_bound`.
    pub bound: f64,
    /// Evaluation budget.
    pub max_evals: u64,
}

impl Default for SweepOptions {
    fn default() -> Self {
        SweepOptions { bound: 1e6, max_evals: 2_000_000 }
    }
}

/// The sweep result: per-region statistics (regions with no points omitted) and totals.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepReport {
    pub regions: Vec<RegionStats>,
    pub total: RegionStats,
    pub bound: f64,
    /// True when the full Cartesian product was evaluated.
    pub exhaustive: bool,
    /// How the points were chosen.
    pub domain: DomainKind,
}

/// The extent of a bad region along one input: starting from an example `x` where `bad(value)` holds, the
/// interval of that input in [0, 1] (the others and the parameters fixed) over which it still holds, found by
/// bisection toward 0 and toward 1 (geometric steps across binades, then halving: ~1 100 evaluations at most).
/// `None` when the example's value of the input is outside [0, 1]. Assumes the bad set is one interval along
/// the line, which holds for the underflow and overflow regions this is for (it reports the interval around
/// the example either way).
pub(crate) fn extent(ev: &dyn Evaluator, x: &[f64; N_INPUTS], params: &[f64], input: usize, bad: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    bad_interval(x[input], |t| {
        let mut y = *x;
        y[input] = t;
        bad(ev.eval(&y, params))
    })
}

/// The category of one value (the same classes as [`grid`]'s labels): the region of a point on real geometry,
/// where values are computed rather than chosen.
fn category(v: f64) -> usize {
    if v < 0.0 {
        7
    } else if v > 1.0 {
        6
    } else if v == 0.0 {
        4
    } else if v.is_subnormal() {
        5
    } else if v < 1e-7 {
        3
    } else if v == 1.0 {
        1
    } else if v > 1.0 - 1e-7 {
        2
    } else {
        0
    }
}

/// Unit directions over the hemisphere, in and just below the horizon plane: every cosine of [`grid`] in
/// [−1, 1] at each azimuth of `phis`.
fn directions(phis: &[f64]) -> Vec<super::V3> {
    let mut out = vec![];
    for (c, _) in grid().into_iter().filter(|(c, _)| (-1.0..=1.0).contains(c)) {
        for &p in phis {
            out.push(super::dir_from_cos(c, p));
        }
    }
    out
}

/// Azimuths of the geometric grids: along the tangent, oblique, along the bitangent, past it, opposite (V = the
/// mirror of L when their cosines match; V = −L in the horizon plane) and the other side.
const PHIS: [f64; 6] = [0.0, 0.7, std::f64::consts::FRAC_PI_2, 2.0, std::f64::consts::PI, -std::f64::consts::FRAC_PI_2];

/// How the inputs a formula reads can vary together (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DomainKind {
    /// Each cosine over the whole grid independently: one cosine, or NL and NV, which every pair of values in
    /// [−1, 1] is a real configuration of.
    Independent,
    /// Cosines that geometry links (NH, VR or VH with another cosine): points are real (L, V) pairs, L at
    /// azimuth 0 (every cosine is invariant under rotation about N) and V over all azimuths, so combinations no
    /// configuration produces (NL = 1 with NH = 0.1 on the upper hemisphere) are never evaluated.
    LinkedCosines,
    /// Direction components: real (L, V) pairs over all azimuths for both.
    Directions,
}

impl DomainKind {
    pub(crate) fn of(used: InputSet) -> DomainKind {
        use crate::ir::Input;
        if used.reads_directions() {
            DomainKind::Directions
        } else if used.len() > 1 && used.iter().any(|i| !matches!(i, Input::NL | Input::NV)) {
            DomainKind::LinkedCosines
        } else {
            DomainKind::Independent
        }
    }

    /// For reports: how points were chosen.
    pub fn describe(self) -> &'static str {
        match self {
            DomainKind::Independent => "independent cosines",
            DomainKind::LinkedCosines => "cosines of real (L, V) pairs",
            DomainKind::Directions => "real (L, V) pairs",
        }
    }

    /// Whether points are (L, V) pairs (extents then follow a polar angle, not one input).
    pub(crate) fn is_geometric(self) -> bool {
        self != DomainKind::Independent
    }
}

/// The points a sweep walks, by index: a Cartesian product of cosines over the inputs a formula reads, or of
/// (L, V) pairs whose cosines (and components) are computed.
enum Domain {
    Cosines { g: Vec<(f64, usize)>, used: Vec<usize> },
    Geometry { ls: Vec<super::V3>, vs: Vec<super::V3>, used: InputSet, directions: bool },
}

impl Domain {
    fn new(kind: DomainKind, used: InputSet) -> Domain {
        match kind {
            DomainKind::Independent => Domain::Cosines { g: grid(), used: used.iter().map(|i| i.index()).collect() },
            DomainKind::LinkedCosines => Domain::Geometry { ls: directions(&[0.0]), vs: directions(&PHIS), used, directions: false },
            DomainKind::Directions => Domain::Geometry { ls: directions(&PHIS), vs: directions(&PHIS), used, directions: true },
        }
    }

    fn size(&self) -> u64 {
        match self {
            Domain::Cosines { g, used } => g.len().pow(used.len() as u32) as u64,
            Domain::Geometry { ls, vs, .. } => (ls.len() * vs.len()) as u64,
        }
    }

    /// Writes point `gi` into row `row` of `cols` (inputs not read keep their value); returns its category.
    fn fill(&self, mut gi: u64, cols: &mut [Vec<f64>; N_INPUTS], row: usize) -> usize {
        match self {
            Domain::Cosines { g, used } => {
                let mut worst = 0;
                for &inp in used {
                    let (v, c) = g[(gi % g.len() as u64) as usize];
                    gi /= g.len() as u64;
                    cols[inp][row] = v;
                    worst = worst.max(c);
                }
                worst
            }
            Domain::Geometry { ls, vs, used, directions } => {
                let n = ls.len() as u64;
                let (l, v) = (ls[(gi % n) as usize], vs[(gi / n) as usize]);
                let x = super::inputs_from_dirs(l, v);
                for (col, x) in cols.iter_mut().zip(x) {
                    col[row] = x;
                }
                // Directions: the more extreme polar angle; cosines: the most extreme value read.
                if *directions {
                    category(l[2]).max(category(v[2]))
                } else {
                    used.iter().map(|i| category(x[i.index()])).max().unwrap_or(0)
                }
            }
        }
    }
}

/// The extent of a bad region along L's (`light = true`) or V's polar angle on real geometry: from an example
/// (a point of a geometric sweep, whose inputs hold L and V), the interval of that direction's cosine in [0, 1],
/// its azimuth and the other direction fixed, over which `bad` still holds; every input is recomputed from the
/// pair. `None` when the direction is below the horizon.
pub(crate) fn extent_polar(ev: &dyn Evaluator, x: &[f64; N_INPUTS], params: &[f64], light: bool, bad: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    let (l, v) = ([x[5], x[6], x[7]], [x[8], x[9], x[10]]);
    let d = if light { l } else { v };
    let phi = if d[0] == 0.0 && d[1] == 0.0 { 0.0 } else { d[1].atan2(d[0]) };
    bad_interval(d[2], |c| {
        let moved = super::dir_from_cos(c, phi);
        let y = if light { super::inputs_from_dirs(moved, v) } else { super::inputs_from_dirs(l, moved) };
        bad(ev.eval(&y, params))
    })
}

/// The interval of `t` in [0, 1] around `v` where `at(t)` holds, by bisection toward 0 and toward 1 (geometric
/// steps across binades, then halving: ~1 100 evaluations at most); `None` when `v` is outside [0, 1].
fn bad_interval(v: f64, at: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    if !(0.0..=1.0).contains(&v) {
        return None;
    }
    // Boundary between `inside` (bad) and `outside` (not bad), either order.
    let edge = |mut inside: f64, mut outside: f64| {
        for _ in 0..1100 {
            let (lo, hi) = (inside.min(outside), inside.max(outside));
            let m = if lo > 0.0 && hi > 4.0 * lo { (lo * hi).sqrt() } else if lo == 0.0 && hi > 1e-300 { hi * 1e-10 } else { 0.5 * (lo + hi) };
            if !(m > lo && m < hi) {
                break;
            }
            if at(m) {
                inside = m
            } else {
                outside = m
            }
        }
        inside
    };
    let lo = if at(0.0) { 0.0 } else { edge(v, 0.0) };
    let hi = if at(1.0) { 1.0 } else { edge(v, 1.0) };
    Some((lo, hi))
}

/// The smallest sweep of a formula reading `used` with parameters `decls`: every parameter combination, each
/// with at least 64 input points (all of them when the input grid is smaller). Returns (combinations, points
/// per combination); their product is the fewest evaluations [`sweep`] makes, whatever
/// [`SweepOptions::max_evals`] says, so a front end should refuse a smaller budget.
pub fn min_evals(used: InputSet, decls: &[ParamDecl]) -> (u64, u64) {
    let gsize = Domain::new(DomainKind::of(used), used).size();
    let combos: u64 = decls.iter().map(|d| param_values(d).len().max(1) as u64).product();
    (combos, 64.min(gsize))
}

/// Sweeps `ev` (normally the [`Formula::unclamped`] kernel) over the domain described in the module docs:
/// at most `opts.max_evals` evaluations, and never fewer than [`min_evals`].
pub fn sweep(ev: &dyn Evaluator, used: InputSet, decls: &[ParamDecl], opts: &SweepOptions) -> SweepReport {
    let kind = DomainKind::of(used);
    let domain = Domain::new(kind, used);
    let gsize = domain.size();
    // Parameter combinations (mixed radix over each parameter's values).
    let pv: Vec<Vec<f64>> = decls.iter().map(param_values).collect();
    let combos: u64 = pv.iter().map(|v| v.len().max(1) as u64).product();
    let exhaustive = combos.saturating_mul(gsize) <= opts.max_evals;
    let floor = min_evals(used, decls).1;
    let per_combo = if exhaustive { gsize } else { (opts.max_evals / combos.max(1)).clamp(floor, gsize) };
    let per_combo_stats: Vec<Vec<RegionStats>> = (0..combos)
        .into_par_iter()
        .map(|ci| {
            let mut params = Vec::with_capacity(pv.len());
            let mut r = ci;
            for v in &pv {
                let l = v.len().max(1) as u64;
                params.push(v.get((r % l) as usize).copied().unwrap_or(f64::NAN));
                r /= l;
            }
            // Strided subset of the input grid: gi = (offset + j·stride) mod gsize with stride coprime.
            let stride = if exhaustive { 1 } else { coprime_stride(gsize) };
            let offset = if exhaustive { 0 } else { ci.wrapping_mul(7919) % gsize };
            let mut stats: Vec<RegionStats> = CATS.iter().map(|c| RegionStats { region: c, ..Default::default() }).collect();
            let mut cols: [Vec<f64>; N_INPUTS] = Default::default();
            let mut cat = Vec::new();
            let mut j = 0u64;
            while j < per_combo {
                let end = (j + 4096).min(per_combo);
                for c in cols.iter_mut() {
                    c.clear();
                    c.resize((end - j) as usize, 0.5);
                }
                cat.clear();
                for (row, jj) in (j..end).enumerate() {
                    let gi = ((offset as u128 + jj as u128 * stride as u128) % gsize as u128) as u64;
                    cat.push(domain.fill(gi, &mut cols, row));
                }
                let mut out = vec![0.0; (end - j) as usize];
                let c = Columns::new(std::array::from_fn(|k| cols[k].as_slice()));
                ev.eval_batch(&c, &params, &mut out);
                for (row, &y) in out.iter().enumerate() {
                    let s = &mut stats[cat[row]];
                    s.evaluated += 1;
                    let ex = || Example { inputs: std::array::from_fn(|i| cols[i][row]), params: params.clone(), value: y };
                    if y.is_nan() {
                        s.nan += 1;
                        s.first_nan.get_or_insert_with(ex);
                    } else if y.is_infinite() {
                        s.inf += 1;
                        s.first_inf.get_or_insert_with(ex);
                    } else if y < 0.0 {
                        s.negative += 1;
                        s.first_negative.get_or_insert_with(ex);
                    }
                    if y > opts.bound {
                        s.over_bound += 1;
                        s.first_over_bound.get_or_insert_with(ex);
                    }
                }
                j = end;
            }
            stats
        })
        .collect();
    let mut regions: Vec<RegionStats> = CATS.iter().map(|c| RegionStats { region: c, ..Default::default() }).collect();
    for st in per_combo_stats {
        for (r, s) in regions.iter_mut().zip(st) {
            r.merge(s);
        }
    }
    let mut total = RegionStats { region: "all", ..Default::default() };
    for r in &regions {
        total.merge(r.clone());
    }
    regions.retain(|r| r.evaluated > 0);
    SweepReport { regions, total, bound: opts.bound, exhaustive, domain: kind }
}

fn coprime_stride(m: u64) -> u64 {
    let gcd = |mut a: u64, mut b: u64| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    let mut s = (m as f64 * 0.618_033_988_75) as u64 | 1;
    while gcd(s, m) != 1 {
        s += 2;
    }
    s.max(1)
}

/// One kind a sweep counts: label, JSON key, the region's first example, and the predicate on a value.
pub(crate) type Kind<'a> = (&'static str, &'static str, &'a Option<Example>, Box<dyn Fn(f64) -> bool>);

/// The four kinds a sweep counts, for one region.
pub fn kinds(r: &RegionStats, bound: f64) -> [Kind<'_>; 4] {
    [
        ("NaN", "nan", &r.first_nan, Box::new(f64::is_nan)),
        ("inf", "inf", &r.first_inf, Box::new(f64::is_infinite)),
        ("negative", "negative", &r.first_negative, Box::new(|y: f64| y < 0.0)),
        ("over bound", "over_bound", &r.first_over_bound, Box::new(move |y: f64| y > bound)),
    ]
}

/// One example's bad-region extents: along each input read (independent cosines) or along L's and V's polar
/// angles (geometry), as (label, lo, hi).
pub fn example_extents(ev: &dyn Evaluator, rep: &SweepReport, used: InputSet, e: &Example, bad: &dyn Fn(f64) -> bool) -> Vec<(String, f64, f64)> {
    if rep.domain.is_geometric() {
        [(true, "NL = Lz", "along L's polar angle"), (false, "NV = Vz", "along V's polar angle")]
            .into_iter()
            .filter_map(|(light, name, how)| extent_polar(ev, &e.inputs, &e.params, light, bad).map(|(lo, hi)| (format!("{name} {how}"), lo, hi)))
            .collect()
    } else {
        used.iter().filter_map(|i| extent(ev, &e.inputs, &e.params, i.index(), bad).map(|(lo, hi)| (i.name().to_string(), lo, hi))).collect()
    }
}

/// The sweep's JSON report (keys listed in docs/commands.md; numbers follow [`crate::base::json`]): the total counts,
/// then each region's counts with its first examples.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SweepJson {
    #[serde(flatten)]
    pub total: RegionStats,
    #[serde(serialize_with = "json::num")]
    pub bound: f64,
    pub exhaustive: bool,
    /// How points were chosen (`DomainKind::describe`).
    pub domain: &'static str,
    pub regions: Vec<RegionJson>,
    /// The same sweep of the compiled formula (absent when only the form as written is swept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compiled: Option<CompiledJson>,
}

/// A region's counts, its first example of each kind and their extents.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RegionJson {
    pub region: &'static str,
    #[serde(flatten)]
    pub counts: RegionStats,
    pub first: FirstExamples,
    pub extents: Vec<ExtentJson>,
}

/// The sweep of the compiled formula (the accuracy pass's choice) with its text.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CompiledJson {
    pub formula: String,
    #[serde(flatten)]
    pub total: RegionStats,
    pub regions: Vec<RegionJson>,
}

/// The first example of each kind in a region (`null` where none occurred).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FirstExamples {
    pub nan: Option<ExampleJson>,
    pub inf: Option<ExampleJson>,
    pub negative: Option<ExampleJson>,
    pub over_bound: Option<ExampleJson>,
}

/// An [`Example`] with its inputs and parameters by name.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExampleJson {
    pub inputs: Named,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub value: f64,
}

/// Where one kind extends from an example: along which input, from `lo` to `hi`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExtentJson {
    pub kind: &'static str,
    pub along: String,
    #[serde(serialize_with = "json::num")]
    pub lo: f64,
    #[serde(serialize_with = "json::num")]
    pub hi: f64,
}

/// A colour formula's sweep: `{"channels": {"red": …, "green": …, "blue": …}}`.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ChannelsJson {
    pub channels: std::collections::BTreeMap<String, SweepJson>,
}

/// A formula swept as the sweep command sweeps it: unclamped ([`Formula::unclamped`]), as written (the plain
/// simplification) and, with the accuracy pass, as compiled; the compiled form is swept again only when the
/// pass kept a rewrite.
pub struct Run {
    /// The parameters swept (baked ones fixed at their value), and their names.
    pub decls: Vec<ParamDecl>,
    pub names: Vec<String>,
    pub used: InputSet,
    /// The formula as written, and its sweep.
    pub k: crate::Kernel,
    pub rep: SweepReport,
    /// The formula as compiled (with the pass), and its sweep when it differs from the one as written.
    pub compiled: Option<crate::Kernel>,
    pub crep_changed: Option<SweepReport>,
}

/// The parameters a sweep of `f` with `set` baked varies: baked ones are fixed, swept at their value only.
pub fn swept_decls(f: &Formula, set: &[(String, f64)]) -> Vec<ParamDecl> {
    let mut decls = f.params.clone();
    for (name, v) in set {
        if let Some(i) = f.param_index(name) {
            decls[i].lo = *v;
            decls[i].hi = *v;
            decls[i].default = *v;
        }
    }
    decls
}

/// Sweeps `f` with `set` baked: compiled with `plain` as written, and with `pass` (options carrying the
/// accuracy pass) as compiled, when given.
pub fn sweep_formula(f: &Formula, set: &[(String, f64)], plain: &crate::Options, pass: Option<&crate::Options>, opts: &SweepOptions) -> Result<Run, crate::Diagnostics> {
    let decls = swept_decls(f, set);
    let used = f.used_inputs();
    // Every parameter combination gets its share of points: a smaller budget cannot be kept.
    let (combos, per) = min_evals(used, &decls);
    let least = combos.saturating_mul(per);
    if opts.max_evals < least {
        let d = crate::Diagnostic::error(format!(
            "an evaluation budget of {} is below this sweep's minimum of {least} evaluations ({combos} parameter combinations × {per} input points each)",
            opts.max_evals
        ));
        return Err(crate::Diagnostics::single(&f.file, d.hint(format!("allow {least} evaluations or more, or bake parameters so fewer combinations are swept"))));
    }
    let u = f.unclamped();
    let k = crate::compile_formula(u.clone(), &crate::Options { bake: set.to_vec(), ..plain.clone() })?;
    let compiled = match pass {
        Some(p) => Some(crate::compile_formula(u, &crate::Options { bake: set.to_vec(), ..p.clone() })?),
        None => None,
    };
    let rep = sweep(&k, used, &decls, opts);
    let changed = compiled.as_ref().filter(|c| Run::text(c) != Run::text(&k));
    let crep_changed = changed.map(|c| sweep(c, used, &decls, opts));
    let names = decls.iter().map(|d| d.name.clone()).collect();
    Ok(Run { decls, names, used, k, rep, compiled, crep_changed })
}

impl Run {
    /// A kernel's formula on one line.
    pub fn text(k: &crate::Kernel) -> String {
        k.formula.to_program_text().replace('\n', "; ")
    }
    /// The compiled kernel when the accuracy pass changed the formula.
    pub fn changed(&self) -> Option<&crate::Kernel> {
        self.compiled.as_ref().filter(|_| self.crep_changed.is_some())
    }
    /// The compiled formula's sweep (the one as written when the pass kept no rewrite), with the pass.
    pub fn crep(&self) -> Option<&SweepReport> {
        self.crep_changed.as_ref().or(self.compiled.as_ref().map(|_| &self.rep))
    }
    /// The JSON report of the sweep command.
    pub fn json(&self) -> SweepJson {
        let c = self.compiled.as_ref().zip(self.crep()).map(|(c, cr)| (c as &dyn Evaluator, Run::text(c), cr));
        SweepJson::new(&self.k, &self.rep, self.used, &self.names, c)
    }
}

impl SweepJson {
    /// The report of `rep`, the sweep of `ev` over inputs `used` and parameters `names`, and of the compiled
    /// formula's (`ev` of the compiled form, its text, its sweep), if any.
    pub fn new(ev: &dyn Evaluator, rep: &SweepReport, used: InputSet, names: &[String], compiled: Option<(&dyn Evaluator, String, &SweepReport)>) -> SweepJson {
        SweepJson {
            total: rep.total.clone(),
            bound: rep.bound,
            exhaustive: rep.exhaustive,
            domain: rep.domain.describe(),
            regions: regions_json(ev, rep, used, names),
            compiled: compiled.map(|(c, formula, cr)| CompiledJson { formula, total: cr.total.clone(), regions: regions_json(c, cr, used, names) }),
        }
    }
}

fn regions_json(ev: &dyn Evaluator, rep: &SweepReport, used: InputSet, names: &[String]) -> Vec<RegionJson> {
    let example = |e: &Example| ExampleJson {
        inputs: Named::new(crate::ir::Input::ALL.iter().map(|i| (i.name(), e.inputs[i.index()]))),
        params: Named::new(names.iter().map(String::as_str).zip(e.params.iter().copied())),
        value: e.value,
    };
    rep.regions
        .iter()
        .map(|r| {
            let mut first = FirstExamples::default();
            let mut extents = vec![];
            for (_, key, e, bad) in kinds(r, rep.bound) {
                let slot = match key {
                    "nan" => &mut first.nan,
                    "inf" => &mut first.inf,
                    "negative" => &mut first.negative,
                    _ => &mut first.over_bound,
                };
                *slot = e.as_ref().map(example);
                if let Some(e) = e {
                    for (along, lo, hi) in example_extents(ev, rep, used, e, &*bad) {
                        extents.push(ExtentJson { kind: key, along, lo, hi });
                    }
                }
            }
            RegionJson { region: r.region, counts: r.clone(), first, extents }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::backend::interp::Interp;
    use crate::ir::{BinOp, Input, Ir, Meta, ParamKind};
    use crate::backend::FnEvaluator;
    use crate::numerics::dir_from_cos;

    fn n_decl() -> ParamDecl {
        ParamDecl { name: "n".into(), default: 50.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }
    }

    #[test]
    fn extent_finds_the_underflow_region_of_beckmann() {
        let beck = crate::backend::FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| {
            let c = x[2];
            1.0 / (0.09 * c * c * c * c) * ((c * c - 1.0) / (0.09 * c * c)).exp()
        });
        let x = crate::from_cosines([0.5, 0.5, 1e-300, 0.5, 0.5]);
        let (lo, hi) = extent(&beck, &x, &[], 2, f64::is_nan).unwrap();
        assert_eq!(lo, 0.0);
        // c⁴·0.09 underflows to 0 below ~1.2e-77 (then 1/0 · exp(−∞) = NaN).
        assert!(hi > 1e-78 && hi < 1e-76, "{hi:e}");
        assert!(beck.eval(&crate::from_cosines([0.5, 0.5, hi, 0.5, 0.5]), &[]).is_nan());
        assert!(!beck.eval(&crate::from_cosines([0.5, 0.5, hi * 1.01, 0.5, 0.5]), &[]).is_nan());
    }

    #[test]
    fn finds_nan_inf_and_negatives_in_the_right_regions() {
        // sqrt(NV − 0.5) is NaN for NV < 0.5; 1/NL is inf at NL = ±0; NH − 0.25 is negative below 0.25.
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| (x[1] - 0.5).sqrt() * p[0] / x[0]);
        let used = set(&[Input::NL, Input::NV]);
        let r = sweep(&f, used, &[n_decl()], &SweepOptions::default());
        assert!(r.exhaustive);
        let g = grid().len() as u64;
        assert_eq!(r.total.evaluated, g * g * param_values(&n_decl()).len() as u64);
        assert!(r.total.nan > 0 && r.total.inf > 0);
        let zero = r.regions.iter().find(|s| s.region == "zero").unwrap();
        let ex = zero.first_inf.as_ref().unwrap();
        assert_eq!(ex.inputs[0], 0.0);
        assert!(ex.inputs[1] > 0.5);
        let neg = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| x[2] - 0.25);
        let mut used = InputSet::default();
        used.insert(Input::NH);
        let r = sweep(&neg, used, &[n_decl()], &SweepOptions::default());
        assert_eq!(r.total.nan + r.total.inf, 0);
        // Negative at 4 negative, 2 zero, 2 denormal, 3 tiny, and 3 interior (1e-4, 0.01, 0.1) cosines.
        assert_eq!(r.total.negative, 14 * param_values(&n_decl()).len() as u64);
    }

    #[test]
    fn direction_formulas_are_swept_on_real_geometry() {
        // |L|² − 1 and the cosine NL − Lz vanish on real geometry; independent inputs would make both large.
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| {
            let l2 = x[5] * x[5] + x[6] * x[6] + x[7] * x[7];
            if (l2 - 1.0).abs() > 1e-15 || x[0] != x[7] {
                f64::NAN
            } else {
                1.0 / x[7]
            }
        });
        let mut used = InputSet::default();
        used.insert(Input::Lx);
        let r = sweep(&f, used, &[n_decl()], &SweepOptions::default());
        assert!(r.exhaustive);
        assert_eq!(r.total.evaluated, 144 * 144 * param_values(&n_decl()).len() as u64);
        assert_eq!(r.total.nan, 0, "{:?}", r.total.first_nan);
        // 1/Lz: infinite exactly in the horizon plane, negative below it.
        let zero = r.regions.iter().find(|s| s.region == "zero").unwrap();
        assert_eq!(zero.first_inf.as_ref().unwrap().inputs[7], 0.0);
        let below = r.regions.iter().find(|s| s.region == "negative").unwrap();
        assert!(below.negative > 0 && below.first_negative.as_ref().unwrap().inputs[7] < 0.0);
    }

    fn set(inputs: &[Input]) -> InputSet {
        let mut s = InputSet::default();
        for &i in inputs {
            s.insert(i);
        }
        s
    }

    #[test]
    fn domain_kind_follows_what_geometry_links() {
        use Input::*;
        assert_eq!(DomainKind::of(set(&[NH])), DomainKind::Independent);
        assert_eq!(DomainKind::of(set(&[NL, NV])), DomainKind::Independent);
        assert_eq!(DomainKind::of(set(&[NL, NH])), DomainKind::LinkedCosines);
        assert_eq!(DomainKind::of(set(&[VR, VH])), DomainKind::LinkedCosines);
        assert_eq!(DomainKind::of(set(&[NL, NV, NH, VH])), DomainKind::LinkedCosines);
        assert_eq!(DomainKind::of(set(&[NL, Vy])), DomainKind::Directions);
    }

    #[test]
    fn linked_cosines_are_swept_only_where_geometry_puts_them() {
        // NaN flags combinations no pair above the horizon produces: L = N puts H halfway between N and V, so
        // NH ≥ cos 45°; L = V = N makes NH = VH = 1. An independent grid hits both everywhere.
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| {
            let (nl, nv, nh, vh) = (x[0], x[1], x[2], x[4]);
            let normal = nl == 1.0 && nv >= 0.0 && nh < 0.7;
            let both = nl == 1.0 && nv == 1.0 && (nh < 1.0 - 1e-12 || vh < 1.0 - 1e-12);
            if normal || both {
                f64::NAN
            } else {
                1.0 / nh
            }
        });
        let used = set(&[Input::NL, Input::NV, Input::NH, Input::VH]);
        let r = sweep(&f, used, &[n_decl()], &SweepOptions::default());
        assert_eq!(r.domain, DomainKind::LinkedCosines);
        assert!(r.exhaustive);
        assert_eq!(r.total.evaluated, 24 * 144 * param_values(&n_decl()).len() as u64);
        assert_eq!(r.total.nan, 0, "{:?}", r.total.first_nan);
        // 1/NH is infinite only where L + V has no z: both in the horizon plane (NH = 0 there).
        let zero = r.regions.iter().find(|s| s.region == "zero").unwrap();
        let ex = zero.first_inf.as_ref().unwrap();
        assert_eq!((ex.inputs[0], ex.inputs[1], ex.inputs[2]), (0.0, 0.0, 0.0), "{ex:?}");
        // Every region a cosine can fall in on real geometry is visited, denormals included.
        for region in ["interior", "one", "near-one", "tiny", "zero", "denormal", "negative"] {
            assert!(r.regions.iter().any(|s| s.region == region && s.evaluated > 0), "no {region} points");
        }
    }

    #[test]
    fn extent_on_geometry_follows_a_polar_angle() {
        // NaN where NH < 1e-77, as Beckmann as written: with L and V both grazing at right angles in azimuth,
        // NH = (NL + NV)/|L + V| ≈ NL/√2 once NL ≫ NV, so the region reaches NL ≈ √2·1e-77 along L.
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| if x[2] < 1e-77 { f64::NAN } else { x[2] });
        let (l, v) = (dir_from_cos(1e-300, 0.0), dir_from_cos(1e-300, std::f64::consts::FRAC_PI_2));
        let x = crate::numerics::inputs_from_dirs(l, v);
        let (lo, hi) = extent_polar(&f, &x, &[], true, f64::is_nan).unwrap();
        assert_eq!(lo, 0.0);
        assert!((hi / (std::f64::consts::SQRT_2 * 1e-77) - 1.0).abs() < 1e-6, "{hi:e}");
        // Below the horizon there is no polar interval in [0, 1] to report.
        let below = crate::numerics::inputs_from_dirs(dir_from_cos(-0.5, 0.0), v);
        assert_eq!(extent_polar(&f, &below, &[], true, f64::is_nan), None);
    }

    #[test]
    fn large_domains_are_subsampled_within_budget() {
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| x.iter().sum::<f64>());
        let all = InputSet(0b11111);
        let opts = SweepOptions { max_evals: 20_000, ..Default::default() };
        let r = sweep(&f, all, &[n_decl()], &opts);
        assert!(!r.exhaustive);
        assert!(r.total.evaluated <= 20_000 && r.total.evaluated > 10_000, "{}", r.total.evaluated);
        assert!(r.regions.iter().any(|s| s.region == "negative") && r.regions.iter().any(|s| s.region == "interior"));
    }

    #[test]
    fn unclamped_peels_the_root_max() {
        // max(NH^n − 0.5, 0): clamped it is never negative; unclamped it is.
        let mut ir = Ir::new();
        let s = Span::default();
        let nh = ir.input(Input::NH, s);
        let n = ir.param(0, s);
        let p = ir.call(Builtin::Pow, &[nh, n], s);
        let h = ir.konst(0.5, s);
        let raw = ir.bin(BinOp::Sub, p, h, s);
        let z = ir.konst(0.0, s);
        let root = ir.call(Builtin::Max, &[raw, z], s);
        let f = Formula { meta: Meta::default(), params: vec![n_decl()], ir, root, file: "t".into(), source: String::new(), rgb: None };
        let used = f.used_inputs();
        let clamped = sweep(&Interp::new(&f), used, &f.params, &SweepOptions::default());
        assert_eq!(clamped.total.negative, 0);
        let u = f.unclamped();
        assert_eq!(u.to_text(), "pow(NH, n) - 0.5");
        let r = sweep(&Interp::new(&u), used, &u.params, &SweepOptions::default());
        assert!(r.total.negative > 0);
        // A formula without the root clamp is unchanged.
        assert_eq!(u.unclamped().to_text(), u.to_text());
    }
}
