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

/// Words a parameter may not be called in either language: GLSL and WGSL keywords and reserved words, GLSL
/// built-in functions and types, the input names and lobe's temporaries (`t0`, `t1`, …). Mangling for both
/// dialects at once keeps one exported signature for a formula whichever language is asked for.
const RESERVED: &[&str] = &[
    // GLSL keywords, types and reserved words
    "attribute", "const", "uniform", "varying", "buffer", "shared", "coherent", "volatile", "restrict", "readonly",
    "writeonly", "layout", "centroid", "flat", "smooth", "noperspective", "patch", "sample", "break", "continue",
    "do", "for", "while", "switch", "case", "default", "if", "else", "subroutine", "in", "out", "inout", "float",
    "double", "int", "void", "bool", "true", "false", "invariant", "precise", "discard", "return", "mat2", "mat3",
    "mat4", "dmat2", "dmat3", "dmat4", "vec2", "vec3", "vec4", "ivec2", "ivec3", "ivec4", "bvec2", "bvec3",
    "bvec4", "dvec2", "dvec3", "dvec4", "uint", "uvec2", "uvec3", "uvec4", "lowp", "mediump", "highp",
    "precision", "sampler2D", "sampler3D", "samplerCube", "struct", "common", "partition", "active", "asm",
    "class", "union", "enum", "typedef", "template", "this", "resource", "goto", "inline", "noinline", "public",
    "static", "extern", "external", "interface", "long", "short", "half", "fixed", "unsigned", "superp", "input",
    "output", "hvec2", "hvec3", "hvec4", "fvec2", "fvec3", "fvec4", "filter", "sizeof", "cast", "namespace",
    "using", "main",
    // GLSL built-in functions a formula could shadow
    "radians", "degrees", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh",
    "atanh", "pow", "exp", "log", "exp2", "log2", "sqrt", "inversesqrt", "abs", "sign", "floor", "trunc", "round",
    "roundEven", "ceil", "fract", "mod", "modf", "min", "max", "clamp", "mix", "step", "smoothstep", "isnan",
    "isinf", "fma", "length", "distance", "dot", "cross", "normalize", "reflect", "refract", "faceforward",
    "uintBitsToFloat", "floatBitsToUint", "floatBitsToInt", "intBitsToFloat",
    // WGSL keywords and reserved words
    "alias", "bitcast", "continuing", "diagnostic", "discard", "enable", "fallthrough", "fn", "let", "loop",
    "override", "requires", "var", "while", "f32", "f16", "i32", "u32", "array", "atomic", "mat2x2", "mat3x3",
    "mat4x4", "ptr", "sampler", "texture_2d", "vec2f", "vec3f", "vec4f", "NULL", "Self", "abstract", "await",
    "become", "catch", "cbuffer", "co_await", "co_return", "co_yield", "compile", "concept", "constexpr",
    "crate", "delete", "dynamic_cast", "explicit", "export", "final", "finally", "friend", "from", "handle",
    "impl", "import", "instanceof", "macro", "match", "meta", "module", "move", "mut", "mutable", "new", "nil",
    "noexcept", "null", "of", "operator", "package", "private", "protected", "pub", "ref", "regardless",
    "self", "signed", "super", "throw", "trait", "try", "type", "typename", "typeof", "unless", "virtual",
    "where", "with", "yield",
    // lobe's own names in the emitted function
    "NL", "NV", "NH", "VR", "VH",
];

/// Shader identifiers for the formula's parameters (by index). A name that is reserved in GLSL or WGSL, looks
/// like a temporary (`t0`) or the exported function (`lobe_…`), starts with `gl_` or `_`, or contains `__`
/// (reserved in both languages) becomes
/// `p_NAME` with underscores collapsed, made unique; every other name is kept, so an exported signature reads
/// as the .brdf file does.
pub fn param_names(f: &Formula) -> Vec<String> {
    let needs_mangling = |n: &str| {
        RESERVED.contains(&n)
            || n.starts_with("gl_")
            || n.starts_with('_')
            || n.contains("__")
            || n.starts_with("lobe_")
            || (n.len() > 1 && n.starts_with('t') && n[1..].bytes().all(|b| b.is_ascii_digit()))
    };
    let mut out: Vec<String> = Vec::with_capacity(f.params.len());
    for p in &f.params {
        let mut name = if needs_mangling(&p.name) {
            let collapsed: Vec<&str> = p.name.split('_').filter(|s| !s.is_empty()).collect();
            format!("p_{}", collapsed.join("_"))
        } else {
            p.name.clone()
        };
        let base = name.clone();
        let mut k = 1;
        while out.contains(&name) || f.params.iter().any(|q| q.name == name && q.name != p.name) {
            name = format!("{base}_{k}");
            k += 1;
        }
        out.push(name);
    }
    out
}

/// Text safe inside a `//` comment: control characters and Unicode line separators (which would end the
/// comment and inject code) become spaces.
fn comment_text(s: &str) -> String {
    s.chars().map(|c| if c.is_control() || matches!(c, '\u{2028}' | '\u{2029}') { ' ' } else { c }).collect()
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
    let _ = writeln!(out, "// {} — exported by lobe {} as {lang}.", comment_text(&f.display_name()), env!("CARGO_PKG_VERSION"));
    if let Some(c) = &f.meta.citation {
        let _ = writeln!(out, "// Source: {}", comment_text(c));
    }
    // The let form, not the expanded tree: shared subexpressions would otherwise grow exponentially.
    let program = f.to_program_text();
    match program.lines().count() {
        0 | 1 => {
            let _ = writeln!(out, "// Formula (simplified): {}", comment_text(&program));
        }
        _ => {
            let _ = writeln!(out, "// Formula (simplified):");
            for line in program.lines() {
                let _ = writeln!(out, "//   {}", comment_text(line));
            }
        }
    }
    let pnames = param_names(f);
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
        let pname = &pnames[*p as usize];
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
            Node::Param(p) => pnames[p as usize].clone(),
            Node::Neg(a) => format!("(-{})", t(a)),
            Node::Binary(op, a, b) => format!("({} {} {})", t(a), op.symbol(), t(b)),
            Node::Call(b, a) => {
                let mut s = match d {
                    Dialect::Glsl => b.info().glsl,
                    Dialect::Wgsl => b.wgsl(),
                }
                .to_string();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hostile_names_are_mangled_and_metadata_cannot_inject_code() {
        let src = "@name \"x\\r#define pow(a,b) 0.0\"\nparam t0 = 1\nparam float = 2\nparam gl_Position = 3\nparam alias = 4\n\
                   param p_float = 5\nparam a__b = 6\nNH^n * t0 + float + gl_Position + alias + p_float + a__b\n";
        let src = src.replace("\\r", "\r");
        let f = crate::front::parse("hostile.brdf", &src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let names = param_names(&f);
        assert_eq!(names, ["n", "p_t0", "p_float_1", "p_gl_Position", "p_alias", "p_float", "p_a_b"]);
        for d in [Dialect::Glsl, Dialect::Wgsl] {
            let text = export(&f, d);
            assert!(text.lines().all(|l| l.starts_with("//") || !l.contains("define")), "{text}");
            assert!(!text.contains('\r'), "{text}");
            let code: String = text.lines().filter(|l| !l.starts_with("//")).collect::<Vec<_>>().join("\n");
            assert!(code.contains("p_gl_Position") && !code.contains(" gl_Position"), "{text}");
        }
    }
}
