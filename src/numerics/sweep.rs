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
//! A formula that reads directions (Lx..Vz) is swept on real geometry instead, so its inputs are consistent:
//! L and V each over 11 polar angles (at the normal, 1e-8 from it, six interior, grazing at π/2 − 1e-8, exactly
//! in the horizon plane, and just below it) × 6 azimuths, plus one direction well below the surface (67 each,
//! 4 489 pairs per parameter combination), every input computed from the pair by
//! [`super::inputs_from_dirs`]; a point's region is the more extreme of its two directions' categories (at the
//! normal: one; 1e-8 from it: near-one; grazing: tiny; horizon: zero; below: negative). This includes V = −L in
//! the horizon plane, where the half vector is undefined.
//!
//! Negative values are only visible on the *unclamped* formula: the lowering's root is `max(raw, 0)`, which
//! [`Formula::unclamped`] peels. The input clamps `clamp(INPUT, 0, 1)` stay, so negative and above-one
//! cosines exercise those clamps (a NaN there is a real bug in the domain policy).
//!
//! Cost: about `max_evals` batched evaluations (default 2 M; never fewer than 64 input points per parameter
//! combination), in parallel over parameter combinations; measured times in BENCHMARKS.md.

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
pub fn param_values(d: &ParamDecl) -> Vec<f64> {
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
}

/// Sweeps `ev` (normally the [`Formula::unclamped`] kernel) over the domain described in the module docs.
/// The extent of a bad region along one input: starting from an example `x` where `bad(value)` holds, the
/// interval of that input in [0, 1] (the others and the parameters fixed) over which it still holds, found by
/// bisection toward 0 and toward 1 (geometric steps across binades, then halving: ~1 100 evaluations at most).
/// `None` when the example's value of the input is outside [0, 1]. Assumes the bad set is one interval along
/// the line, which holds for the underflow and overflow regions this is for (it reports the interval around
/// the example either way).
pub fn extent(ev: &dyn Evaluator, x: &[f64; N_INPUTS], params: &[f64], input: usize, bad: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    let v = x[input];
    if !(0.0..=1.0).contains(&v) {
        return None;
    }
    let at = |t: f64| {
        let mut y = *x;
        y[input] = t;
        bad(ev.eval(&y, params))
    };
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

/// Unit directions over the upper hemisphere and just below it, with the category of their polar angle
/// (module docs): the geometric grid of a formula that reads directions.
fn direction_grid() -> Vec<(super::V3, usize)> {
    use std::f64::consts::FRAC_PI_2;
    let thetas: [(f64, usize); 11] = [
        (0.0, 1),
        (1e-8, 2),
        (0.1, 0),
        (0.4, 0),
        (0.8, 0),
        (1.1, 0),
        (1.3, 0),
        (1.5, 0),
        (FRAC_PI_2 - 1e-8, 3),
        (FRAC_PI_2, 4),
        (FRAC_PI_2 + 1e-9, 7),
    ];
    let phis = [0.0, 0.7, FRAC_PI_2, 2.0, std::f64::consts::PI, -FRAC_PI_2];
    let mut out = vec![];
    for (t, c) in thetas {
        for p in phis {
            // Exactly in the horizon plane (z = 0), not cos(π/2) ≈ 6e-17.
            let d = if c == 4 { [p.cos(), p.sin(), 0.0] } else { super::dir(t, p) };
            out.push((d, c));
        }
    }
    out.push(([0.0, -0.6, -0.8], 7));
    out
}

/// The points a sweep walks, by index: a Cartesian product of cosines over the inputs a formula reads, or of
/// (L, V) pairs for a formula that reads directions.
enum Domain {
    Cosines { g: Vec<(f64, usize)>, used: Vec<usize> },
    Geometry(Vec<(super::V3, usize)>),
}

impl Domain {
    fn new(used: InputSet) -> Domain {
        if used.reads_directions() {
            Domain::Geometry(direction_grid())
        } else {
            Domain::Cosines { g: grid(), used: used.iter().map(|i| i.index()).collect() }
        }
    }

    fn size(&self) -> u64 {
        match self {
            Domain::Cosines { g, used } => g.len().pow(used.len() as u32) as u64,
            Domain::Geometry(d) => (d.len() * d.len()) as u64,
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
            Domain::Geometry(d) => {
                let n = d.len() as u64;
                let ((l, cl), (v, cv)) = (d[(gi % n) as usize], d[(gi / n) as usize]);
                for (col, x) in cols.iter_mut().zip(super::inputs_from_dirs(l, v)) {
                    col[row] = x;
                }
                cl.max(cv)
            }
        }
    }
}

pub fn sweep(ev: &dyn Evaluator, used: InputSet, decls: &[ParamDecl], opts: &SweepOptions) -> SweepReport {
    let domain = Domain::new(used);
    let gsize = domain.size();
    // Parameter combinations (mixed radix over each parameter's values).
    let pv: Vec<Vec<f64>> = decls.iter().map(param_values).collect();
    let combos: u64 = pv.iter().map(|v| v.len().max(1) as u64).product();
    let exhaustive = combos.saturating_mul(gsize) <= opts.max_evals;
    let per_combo = if exhaustive { gsize } else { (opts.max_evals / combos.max(1)).clamp(64.min(gsize), gsize) };
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
    SweepReport { regions, total, bound: opts.bound, exhaustive }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::backend::interp::Interp;
    use crate::ir::{BinOp, Input, Ir, Meta, ParamKind};
    use crate::backend::FnEvaluator;

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
        // sqrt(NH − 0.5) is NaN for NH < 0.5; 1/NL is inf at NL = ±0; NH − 0.25 is negative below 0.25.
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| (x[2] - 0.5).sqrt() * p[0] / x[0]);
        let mut used = InputSet::default();
        used.insert(Input::NH);
        used.insert(Input::NL);
        let r = sweep(&f, used, &[n_decl()], &SweepOptions::default());
        assert!(r.exhaustive);
        let g = grid().len() as u64;
        assert_eq!(r.total.evaluated, g * g * param_values(&n_decl()).len() as u64);
        assert!(r.total.nan > 0 && r.total.inf > 0);
        let zero = r.regions.iter().find(|s| s.region == "zero").unwrap();
        let ex = zero.first_inf.as_ref().unwrap();
        assert_eq!(ex.inputs[0], 0.0);
        assert!(ex.inputs[2] > 0.5);
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
        assert_eq!(r.total.evaluated, 67 * 67 * param_values(&n_decl()).len() as u64);
        assert_eq!(r.total.nan, 0, "{:?}", r.total.first_nan);
        // 1/Lz: infinite exactly in the horizon plane, negative below it.
        let zero = r.regions.iter().find(|s| s.region == "zero").unwrap();
        assert_eq!(zero.first_inf.as_ref().unwrap().inputs[7], 0.0);
        let below = r.regions.iter().find(|s| s.region == "negative").unwrap();
        assert!(below.negative > 0 && below.first_negative.as_ref().unwrap().inputs[7] < 0.0);
    }

    #[test]
    fn large_domains_are_subsampled_within_budget() {
        let f = FnEvaluator(|x: &[f64; crate::N_INPUTS], _: &[f64]| x.iter().sum::<f64>());
        let all = InputSet(0b11111);
        let opts = SweepOptions { max_evals: 100_000, ..Default::default() };
        let r = sweep(&f, all, &[n_decl()], &opts);
        assert!(!r.exhaustive);
        assert!(r.total.evaluated <= 100_000 && r.total.evaluated > 50_000, "{}", r.total.evaluated);
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
