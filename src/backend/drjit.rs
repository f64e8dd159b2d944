//! Dr.Jit emission: a formula as a Python function of Dr.Jit operations, the body of the Mitsuba 3 export
//! (`bsdf::mitsuba`).
//!
//! Design: the same IR and builtins table as the GLSL export ([`crate::backend::glsl`]): each builtin is spelled
//! by the table's `drjit` column; the accuracy pass's internal builtins have none (an export is made from the
//! plain simplification, and a formula that still holds one is refused, as the GLSL export refuses it). Every
//! node that is not a leaf is bound to its own temporary `tK`, so no expression nests deeper than one call
//! (Python's parser refuses deeply nested parentheses) and shared subexpressions are computed once. A colour
//! formula's three channels are merged into one arena first.
//!
//! The function takes all eleven inputs by name (NL, NV, NH, VR, VH, Lx … Vz) and returns a tuple of one value
//! or three (red, green, blue). Every parameter must be baked: the Mitsuba export's sampling tables are built
//! at fixed parameters, so a live parameter (one the caller could change without rebuilding them) is refused.
//! The helpers the spellings call (`_pow`: IEEE 754 pow; `_acos`, `_asin`: clamped to [−1, 1] as lobe's;
//! `_lt`, `_le`, `_eq`, `_ne`: comparisons as 0 or 1; `_select`) are defined by the module that includes the
//! function. Constants are written as Python's f64 literals (exact: the module computes in `Float64`).
//! Cost: linear in the formula's nodes.

use crate::base::diag::Diagnostic;
use crate::builtins::Builtin;
use crate::ir::{Formula, Input, Node};
use std::fmt::Write;

/// A Python literal for `v`, exact in f64 (`float('inf')` and `float('nan')` for the non-finite).
pub fn literal(v: f64) -> String {
    if v.is_nan() {
        return "float('nan')".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "float('inf')".into() } else { "(-float('inf'))".into() };
    }
    let s = format!("{v:?}");
    if v.is_sign_negative() {
        format!("({s})")
    } else {
        s
    }
}

/// The inputs in the order the emitted function takes them.
pub const ARGUMENTS: [Input; 11] = Input::ALL;

/// The formula as `def NAME(NL, NV, NH, VR, VH, Lx, Ly, Lz, Vx, Vy, Vz):` returning a tuple of its channels
/// (module docs). An error for an internal builtin or a live parameter.
pub fn function(f: &Formula, name: &str) -> Result<String, Diagnostic> {
    let f = &f.in_language();
    let (ir, roots) = f.merged_roots();
    let uses = ir.use_counts_of(&roots);
    let args: Vec<&str> = ARGUMENTS.iter().map(|i| i.name()).collect();
    let mut out = format!("def {name}({}):\n", args.join(", "));
    let mut text: Vec<String> = Vec::with_capacity(ir.len());
    let mut ntemps = 0;
    for id in ir.ids() {
        if uses[id.index()] == 0 {
            text.push(String::new());
            continue;
        }
        let node = ir.node(id);
        let t = |a: crate::ir::NodeId| text[a.index()].clone();
        let e = match *node {
            Node::Const(b) => literal(f64::from_bits(b)),
            Node::Input(i) => i.name().to_string(),
            Node::Param(p) => {
                let name = f.params.get(p as usize).map_or("?", |d| d.name.as_str());
                return Err(Diagnostic::error(format!("the parameter `{name}` is live: a Mitsuba export bakes every parameter"))
                    .at(ir.span(id), "this parameter")
                    .hint("the sampling tables are built at fixed parameter values: bake every parameter (its default, or the value wanted)"));
            }
            Node::Column(k) => format!("column{k}"),
            Node::Neg(a) => format!("(-{})", t(a)),
            Node::Binary(op, a, b) => format!("({} {} {})", t(a), op.symbol(), t(b)),
            Node::Call(b, _) if b.is_internal() => {
                return Err(Diagnostic::error(format!(
                    "`{}` cannot be exported: it is internal to the accuracy pass",
                    b.name()
                ))
                .hint("export the plain simplification (the formula compiled without the accuracy pass)"))
            }
            Node::Call(b, a) => {
                let mut s = b.info().drjit.to_string();
                for (k, arg) in a[..b.arity()].iter().enumerate() {
                    s = s.replace(&format!("{{{k}}}"), &t(*arg));
                }
                s
            }
        };
        let leaf = matches!(node, Node::Const(_) | Node::Input(_) | Node::Column(_));
        if leaf {
            text.push(e);
        } else {
            let tname = format!("t{ntemps}");
            ntemps += 1;
            let _ = writeln!(out, "    {tname} = {e}");
            text.push(tname);
        }
    }
    let results: Vec<String> = roots.iter().map(|r| text[r.index()].clone()).collect();
    let _ = writeln!(out, "    return ({},)", results.join(", "));
    Ok(out)
}

/// Whether `b` has a Dr.Jit spelling (every builtin of the language does).
pub fn has_spelling(b: Builtin) -> bool {
    !b.info().drjit.is_empty()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literals_are_exact_python_floats() {
        assert_eq!(literal(0.1), "0.1");
        assert_eq!(literal(-2.5), "(-2.5)");
        assert_eq!(literal(1e-300), "1e-300");
        assert_eq!(literal(3.0), "3.0");
        assert_eq!(literal(f64::INFINITY), "float('inf')");
        assert_eq!(literal(f64::NAN), "float('nan')");
    }

    #[test]
    fn every_node_is_a_statement_and_live_parameters_are_refused() {
        let f = crate::front::parse("g.brdf", "param n = 20\npow(NH, n) * NL + acos(VH)").unwrap();
        let baked = crate::simplify::simplify(&f, &[(0, 20.0)]);
        let text = function(&baked, "lobe_g").unwrap();
        assert!(text.starts_with("def lobe_g(NL, NV, NH, VR, VH, Lx, Ly, Lz, Vx, Vy, Vz):\n"), "{text}");
        assert!(text.contains("_acos(t0)") && text.trim_end().ends_with(",)"), "{text}");
        let live = crate::simplify::simplify(&f, &[]);
        let e = function(&live, "lobe_g").unwrap_err();
        assert!(e.message.contains("`n` is live") && !e.hints.is_empty(), "{e}");
        for b in Builtin::ALL {
            assert_eq!(has_spelling(b), !b.is_internal(), "{}", b.name());
        }
    }
}
