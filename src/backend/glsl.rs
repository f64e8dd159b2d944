//! Shader export: a self-contained GLSL (or WGSL) function from the same IR and builtins table the JIT uses.
//!
//! Design: one statement per IR node that is used more than once or is a call (so shared subexpressions are
//! computed once, as in the kernel), everything else inlined with full parentheses (no reliance on the target
//! language's precedence). Builtins are spelled by the table's `glsl` column, which is also valid WGSL for every
//! builtin lobe has. The function takes only the inputs the formula reads and its live parameters, so a shader
//! that uses it computes nothing extra — the same "model only what the scene needs" rule as the renderer.
//!
//! Differences from lobe's own evaluation, stated in the emitted header: shaders run in f32, not f64; GPU
//! `min`/`max` need not propagate NaN; `pow(x, y)` is undefined on GPUs for x < 0 and for x = 0, y ≤ 0.

use crate::ir::{Formula, Node, NodeId};
use std::fmt::Write;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dialect {
    Glsl,
    Wgsl,
}

/// A valid identifier for the function: `lobe_` + the file stem with non-identifier characters replaced.
pub fn function_name(f: &Formula) -> String {
    let stem = std::path::Path::new(&f.file)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut name: String = stem.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
    if name.is_empty() || name.starts_with('<') {
        name = "brdf".into();
    }
    format!("lobe_{}", name.trim_matches('_'))
}

fn literal(v: f64, d: Dialect) -> String {
    let bits = |b: u32| match d {
        Dialect::Glsl => format!("uintBitsToFloat({b:#010x}u)"),
        Dialect::Wgsl => format!("bitcast<f32>({b:#010x}u)"),
    };
    if v.is_nan() {
        return bits(0x7fc0_0000);
    }
    if v.is_infinite() {
        return bits(if v > 0.0 { 0x7f80_0000 } else { 0xff80_0000 });
    }
    // f32 is what the shader computes in; print the shortest text that round-trips the f32 value.
    let f = v as f32;
    if f.is_infinite() {
        return bits(if f > 0.0 { 0x7f80_0000 } else { 0xff80_0000 });
    }
    let s = format!("{f:?}");
    let s = if s.contains('.') || s.contains('e') || s.contains("inf") { s } else { format!("{s}.0") };
    if v < 0.0 {
        format!("({s})")
    } else {
        s
    }
}

/// Exports the formula as one shader function.
pub fn export(f: &Formula, d: Dialect) -> String {
    let (ir, root) = f.ir.compact(f.root);
    let uses = ir.use_counts(root);
    let used_inputs = ir.used_inputs(root);
    let live_params = ir.used_params(root);
    let name = function_name(f);
    let ty = match d {
        Dialect::Glsl => "float",
        Dialect::Wgsl => "f32",
    };

    let mut out = String::new();
    let lang = match d {
        Dialect::Glsl => "GLSL",
        Dialect::Wgsl => "WGSL",
    };
    let _ = writeln!(out, "// {} — exported by lobe {} as {lang}.", f.display_name(), env!("CARGO_PKG_VERSION"));
    if let Some(c) = &f.meta.citation {
        let _ = writeln!(out, "// Source: {c}");
    }
    let _ = writeln!(out, "// Formula (simplified): {}", f.to_text());
    let baked: Vec<String> = f
        .params
        .iter()
        .enumerate()
        .filter(|(i, _)| !live_params.contains(&(*i as u16)))
        .map(|(_, p)| p.name.clone())
        .collect();
    if !baked.is_empty() {
        let _ = writeln!(out, "// Baked or unused parameters (folded into constants): {}", baked.join(", "));
    }
    let _ = writeln!(out, "// Inputs are cosines (clamped to [0, 1] here, as lobe does); the result is clamped at 0.");
    let _ = writeln!(out, "// lobe evaluates in f64; this runs in f32. GPU min/max need not propagate NaN, and");
    let _ = writeln!(out, "// pow(x, y) is undefined on GPUs for x < 0 or x = 0, y <= 0.");

    let mut args: Vec<String> = used_inputs
        .iter()
        .map(|i| match d {
            Dialect::Glsl => format!("float {}", i.name()),
            Dialect::Wgsl => format!("{}: f32", i.name()),
        })
        .collect();
    for p in &live_params {
        let pname = &f.params[*p as usize].name;
        args.push(match d {
            Dialect::Glsl => format!("float {pname}"),
            Dialect::Wgsl => format!("{pname}: f32"),
        });
    }
    match d {
        Dialect::Glsl => {
            let _ = writeln!(out, "float {name}({}) {{", args.join(", "));
        }
        Dialect::Wgsl => {
            let _ = writeln!(out, "fn {name}({}) -> f32 {{", args.join(", "));
        }
    }

    // Expression text per node; nodes bound to temporaries are referred to by name.
    let mut text: Vec<String> = Vec::with_capacity(ir.len());
    let mut ntemps = 0;
    for id in ir.ids() {
        let node = ir.node(id);
        let t = |a: NodeId| text[a.index()].clone();
        let e = match *node {
            Node::Const(b) => literal(f64::from_bits(b), d),
            Node::Input(i) => i.name().to_string(),
            Node::Param(p) => f.params[p as usize].name.clone(),
            Node::Neg(a) => format!("(-{})", t(a)),
            Node::Binary(op, a, b) => format!("({} {} {})", t(a), op.symbol(), t(b)),
            Node::Call(b, a) => {
                let mut s = b.info().glsl.to_string();
                for (k, arg) in a[..b.arity()].iter().enumerate() {
                    s = s.replace(&format!("{{{k}}}"), &t(*arg));
                }
                s
            }
        };
        let leaf = matches!(node, Node::Const(_) | Node::Input(_) | Node::Param(_));
        let bind = id != root && !leaf && (uses[id.index()] > 1 || matches!(node, Node::Call(..)));
        if bind {
            let tname = format!("t{ntemps}");
            ntemps += 1;
            let _ = match d {
                Dialect::Glsl => writeln!(out, "    {ty} {tname} = {e};"),
                Dialect::Wgsl => writeln!(out, "    let {tname}: {ty} = {e};"),
            };
            text.push(tname);
        } else {
            text.push(e);
        }
    }
    let _ = writeln!(out, "    return {};", text[root.index()]);
    let _ = writeln!(out, "}}");
    out
}

/// A complete fragment shader around the exported GLSL function (for validators and quick previews).
pub fn glsl_test_shader(f: &Formula) -> String {
    let func = export(f, Dialect::Glsl);
    let (ir, root) = f.ir.compact(f.root);
    let mut call_args: Vec<String> = ir.used_inputs(root).iter().map(|_| "0.5".to_string()).collect();
    for p in ir.used_params(root) {
        call_args.push(literal(f.params[p as usize].default, Dialect::Glsl));
    }
    format!(
        "#version 450\n{func}\nlayout(location = 0) out vec4 color;\nvoid main() {{\n    color = vec4({}({}));\n}}\n",
        function_name(f),
        call_args.join(", ")
    )
}
