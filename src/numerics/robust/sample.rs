//! The points of a formula's domain the pass measures on (module docs of [`super`]).

use crate::base::rng::Rng;
use crate::ir::{Formula, Input, ParamKind, N_INPUTS};

/// One point of the domain: inputs in [`Input::ALL`] order and the full parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    pub x: [f64; N_INPUTS],
    pub p: Vec<f64>,
}

/// The edge classes every input draws from (module docs).
pub(crate) const EDGES: [f64; 13] = [
    0.0,
    1.0,
    1.0 - 1.1102230246251565e-16,
    1.0 - 2.220446049250313e-16,
    5e-324,
    1e-310,
    2.2250738585072014e-308,
    1e-300,
    1.6e-162,
    1e-154,
    1e-77,
    1e-20,
    0.5,
];

fn input_value(r: &mut Rng) -> f64 {
    let u = r.unit();
    let v = r.unit();
    if u < 0.25 {
        EDGES[r.below(EDGES.len() as u64) as usize]
    } else if u < 0.5 {
        1.0 - 10f64.powf(-16.0 * v)
    } else if u < 0.7 {
        10f64.powf(-323.0 * v)
    } else {
        v
    }
}

/// A unit direction on the upper hemisphere: its normal component drawn like an input, a uniform azimuth (a
/// fifth on the frame axes).
fn direction(r: &mut Rng) -> crate::numerics::V3 {
    let z = input_value(r);
    if r.unit() < 0.2 {
        // On the axes the other component is exactly 0 (cos(π/2) is 6e-17, not 0).
        let k = r.below(4) as usize;
        let mut d = crate::numerics::dir_from_cos(z, k as f64 * std::f64::consts::FRAC_PI_2);
        d[(k + 1) % 2] = 0.0;
        return d;
    }
    crate::numerics::dir_from_cos(z, std::f64::consts::TAU * r.unit())
}

/// Values of each parameter where the formula changes character, so the pass measures there: where a
/// parameter times a constant is 1 or a parameter minus a constant is 0 (the quadratic model's 0.786·n = 1,
/// where its linear term vanishes), where a parameter divided by a constant is 1, and the integers 1 and 2
/// where a parameter is an exponent (a baked pow(x, 1) or pow(x, 2) folds away). Only values inside the
/// declared range; a pair of parameters equal to each other (F_ST's n = a) is drawn by [`sample`] itself.
pub fn special_values(f: &Formula) -> Vec<Vec<f64>> {
    use crate::builtins::Builtin;
    use crate::ir::{BinOp, Node};
    let mut out = vec![Vec::new(); f.params.len()];
    let param = |x| match *f.ir.node(x) {
        Node::Param(k) => Some(k as usize),
        _ => None,
    };
    let konst = |x| f.ir.node(x).as_const().filter(|c: &f64| c.is_finite() && *c != 0.0);
    for id in f.ir.ids() {
        let found: Vec<(usize, f64)> = match *f.ir.node(id) {
            Node::Binary(BinOp::Mul, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, 1.0 / konst(k)?))).collect(),
            Node::Binary(BinOp::Div, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, konst(k)?))).collect(),
            Node::Binary(BinOp::Sub, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, konst(k)?))).collect(),
            Node::Binary(BinOp::Add, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, -konst(k)?))).collect(),
            Node::Call(Builtin::Pow, [_, y, _]) => param(y).map(|k| vec![(k, 1.0), (k, 2.0)]).unwrap_or_default(),
            _ => vec![],
        };
        for (k, v) in found {
            let d = &f.params[k];
            if d.kind == ParamKind::Float && v > d.lo && v < d.hi && !out[k].contains(&v) {
                out[k].push(v);
            }
        }
    }
    out
}

/// One parameter value: a bool is 0 or 1; otherwise an endpoint, a special value ([`special_values`]), uniform
/// or log-uniform in the declared range. Draws the same count of random numbers whatever the outcome.
fn param_value(d: &crate::ir::ParamDecl, special: &[f64], r: &mut Rng) -> f64 {
    let (u, v) = (r.unit(), r.unit());
    if d.kind == ParamKind::Bool {
        return if u < 0.5 { 0.0 } else { 1.0 };
    }
    let val = if u < 0.15 {
        d.lo
    } else if u < 0.3 {
        d.hi
    } else if u < 0.45 && !special.is_empty() {
        special[((v * special.len() as f64) as usize).min(special.len() - 1)]
    } else if u < 0.7 || d.lo <= 0.0 {
        d.lo + v * (d.hi - d.lo)
    } else {
        d.lo * (d.hi / d.lo).powf(v)
    };
    val.clamp(d.lo, d.hi)
}

/// `n` points of `f`'s domain (module docs); parameters listed in `bake` keep their baked value.
pub fn sample(f: &Formula, bake: &[(usize, f64)], n: usize, seed: u64) -> Vec<Point> {
    let mut r = Rng(seed.max(1));
    let used = f.used_inputs();
    let special = special_values(f);
    let floats: Vec<usize> = (0..f.params.len()).filter(|&k| f.params[k].kind == ParamKind::Float).collect();
    (0..n)
        .map(|_| {
            let mut x = [0.5; N_INPUTS];
            if used.reads_directions() {
                let l = direction(&mut r);
                let mut v = direction(&mut r);
                // A twentieth of the pairs face each other across the normal (L + V ∥ N, of length 2·(Lz + Vz)
                // for grazing pairs): normalize(L + V)'s degenerate case.
                let lt = (l[0] * l[0] + l[1] * l[1]).sqrt();
                if r.unit() < 0.05 && lt > 0.0 {
                    let t = (1.0 - v[2] * v[2]).max(0.0).sqrt() / lt;
                    v = [-l[0] * t, -l[1] * t, v[2]];
                }
                x = crate::numerics::inputs_from_dirs(l, v);
            }
            for i in Input::ALL {
                if used.contains(i) && !used.reads_directions() {
                    x[i.index()] = input_value(&mut r);
                }
            }
            // Geometry: N·(L + V) = |L + V|·NH and |L + V| = 2·VH, so NL + NV = 2·NH·VH; split that total.
            if !used.reads_directions() && used.contains(Input::VH) && (used.contains(Input::NL) || used.contains(Input::NV)) {
                let total = 2.0 * x[Input::NH.index()] * x[Input::VH.index()];
                let nl = (input_value(&mut r) * total).min(1.0);
                let nv = (total - nl).min(1.0);
                x[Input::NL.index()] = (total - nv).min(1.0);
                x[Input::NV.index()] = nv;
            }
            // Drawn even when baked, so baking a parameter leaves every other value of the sample as it was (and
            // the pass measures a baked and a live compile on the same points).
            let mut p: Vec<f64> = f.params.iter().enumerate().map(|(k, d)| param_value(d, &special[k], &mut r)).collect();
            // A tenth of the points set one float parameter equal to another (F_ST's n = a, where its base
            // cancels to the cosine itself), when that value lies in its range.
            for &(k, v) in bake {
                p[k] = v;
            }
            let (u, i, j) = (r.unit(), r.below(floats.len().max(1) as u64) as usize, r.below(floats.len().max(1) as u64) as usize);
            if u < 0.1 && floats.len() >= 2 && i != j {
                let (i, j) = (floats[i], floats[j]);
                let d = &f.params[j];
                if (d.lo..=d.hi).contains(&p[i]) && !bake.iter().any(|(k, _)| *k == j) {
                    p[j] = p[i];
                }
            }
            Point { x, p }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn direction_formulas_are_sampled_on_real_geometry() {
        use crate::ir::{BinOp, Ir, Meta, ParamDecl};
        let mut ir = Ir::new();
        let s = crate::base::span::Span::default();
        let (lx, vy) = (ir.input(Input::Lx, s), ir.input(Input::Vy, s));
        let root = ir.bin(BinOp::Mul, lx, vy, s);
        let f = Formula { meta: Meta::default(), params: vec![ParamDecl::float("n", 1.0, 1.0, 1.0)], ir, root, file: "t".into(), source: String::new(), rgb: None };
        let pts = sample(&f, &[], 4000, 7);
        let (mut horizon, mut normal, mut axis) = (0, 0, 0);
        for p in &pts {
            let (l, v) = ([p.x[5], p.x[6], p.x[7]], [p.x[8], p.x[9], p.x[10]]);
            assert!((crate::numerics::dot(l, l) - 1.0).abs() < 1e-15 && (crate::numerics::dot(v, v) - 1.0).abs() < 1e-15, "{p:?}");
            assert!(l[2] >= 0.0 && v[2] >= 0.0);
            assert_eq!(p.x, crate::numerics::inputs_from_dirs(l, v), "every input from the same pair");
            horizon += usize::from(l[2] == 0.0);
            normal += usize::from(l[2] == 1.0);
            axis += usize::from(l[1] == 0.0 && l[2] < 1.0);
        }
        assert!(horizon > 10 && normal > 10 && axis > 10, "{horizon} {normal} {axis}");
    }
}
