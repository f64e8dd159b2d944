//! Shader export: a self-contained GLSL or WGSL function, or a file Disney's BRDF Explorer loads, from the same
//! IR and builtins table the JIT uses.
//!
//! Design: one expression emitter ([`emit`]) writes every body: one statement per IR node that is used more
//! than once or is a call (so shared subexpressions are computed once, as in the kernel), everything else
//! inlined with full parentheses (no reliance on the target language's precedence). Builtins are spelled by the
//! table's `glsl` column, which is also valid WGSL for every builtin lobe has. The accuracy pass's internal
//! builtins ([`Builtin::is_internal`]) have no spelling: their rewrites are for f64 (double-double tails,
//! scalings by 2^600 that are ∞ in a GPU float), so an export is made from the plain simplification, and a
//! formula that still holds one is refused with an error. A colour formula's three channels
//! are merged into one arena first, so what they share is computed once and the function returns a `vec3`.
//! The GLSL/WGSL function takes only the inputs the formula reads and its live parameters (a colour parameter as
//! one `vec3`), so a shader that uses it computes nothing extra — the same "model only what the scene needs"
//! rule as the renderer. The BRDF Explorer file wraps the same body in `vec3 BRDF(L, V, N, X, Y)`, which first
//! computes the inputs read (`NL = dot(N, L)`, `Lx = dot(L, X)`, …) from the vectors BRDF Explorer passes, and
//! declares the live parameters in its `::begin parameters` block (BRDF Explorer makes each a uniform).
//! Cost: linear in the formula's nodes; no evaluation.
//!
//! Differences from lobe's own evaluation, stated in the emitted header: shaders run in f32, not f64; GPU
//! `min`/`max` need not propagate NaN; `pow(x, y)` is undefined on GPUs for x < 0 and for x = 0, y ≤ 0; in BRDF
//! Explorer, `normalize(L + V)` is undefined when V = −L, where lobe's inputs give NH = VH = 0.

use crate::base::diag::Diagnostic;
use crate::builtins::Builtin;
use crate::ir::{Formula, Input, InputSet, Ir, Node, NodeId, ParamDecl, ParamKind};
use std::fmt::Write;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dialect {
    Glsl(GlslVersion),
    Wgsl,
}

/// The GLSL an export is written for. What differs: `fma` exists from GLSL 4.00 (and ES 3.20) only, so for 330
/// and ES 300 it is written `a * b + c` (which a compiler may or may not fuse; the header says so); ES declares
/// every float `highp`, so the function computes in 32 bits whatever default precision the shader including it
/// declares.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GlslVersion {
    V330,
    #[default]
    V450,
    Es300,
}

impl GlslVersion {
    pub const ALL: [GlslVersion; 3] = [GlslVersion::V330, GlslVersion::V450, GlslVersion::Es300];

    /// The version's short name: `330`, `450`, `es300`.
    pub fn name(self) -> &'static str {
        match self {
            GlslVersion::V330 => "330",
            GlslVersion::V450 => "450",
            GlslVersion::Es300 => "es300",
        }
    }

    /// The `#version` line of a shader in this version.
    pub fn directive(self) -> &'static str {
        match self {
            GlslVersion::V330 => "#version 330 core",
            GlslVersion::V450 => "#version 450",
            GlslVersion::Es300 => "#version 300 es",
        }
    }

    fn has_fma(self) -> bool {
        self == GlslVersion::V450
    }

    /// The scalar and vector types of declarations.
    fn types(self) -> (&'static str, &'static str) {
        match self {
            GlslVersion::Es300 => ("highp float", "highp vec3"),
            _ => ("float", "vec3"),
        }
    }
}

impl std::str::FromStr for GlslVersion {
    type Err = String;
    fn from_str(s: &str) -> Result<GlslVersion, String> {
        GlslVersion::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| format!("unknown GLSL version `{s}`; expected `330`, `450` or `es300`"))
    }
}

impl Dialect {
    fn glsl(self) -> Option<GlslVersion> {
        match self {
            Dialect::Glsl(v) => Some(v),
            Dialect::Wgsl => None,
        }
    }
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
    // lobe's own names in the emitted function, and BRDF Explorer's function arguments and locals
    "NL", "NV", "NH", "VR", "VH", "Lx", "Ly", "Lz", "Vx", "Vy", "Vz", "L", "V", "N", "X", "Y", "H", "BRDF",
    // globals of BRDF Explorer's shader templates, which its files are pasted into
    "brightness", "exposure", "gamma", "incidentVector", "incidentTheta", "incidentPhi", "useNDotL", "fragColor",
    "drawColor", "thickness", "colorMask", "showChroma", "useLogPlot", "thetaD", "thetaH", "phiD", "phiV",
];

/// Text safe inside a `//` comment: control characters and Unicode line separators (which would end the
/// comment and inject code) become spaces.
fn comment_text(s: &str) -> String {
    s.chars().map(|c| if c.is_control() || matches!(c, '\u{2028}' | '\u{2029}') { ' ' } else { c }).collect()
}

/// A literal for `v`: the shortest text that round-trips the f32 value the shader computes with, or with
/// `exact` the f64 value (for text lobe reads back: a BRDF Explorer file imported again keeps lobe's constants;
/// the GPU still rounds it to f32). A constant a shader cannot hold is refused ([`f32_trouble`]).
fn literal(v: f64, exact: bool) -> String {
    let s = if exact { format!("{v:?}") } else { format!("{:?}", v as f32) };
    let s = if s.contains('.') || s.contains('e') || s.contains("inf") { s } else { format!("{s}.0") };
    if v < 0.0 {
        format!("({s})")
    } else {
        s
    }
}

/// Why `v` cannot be a constant of f32 code, if it cannot: NaN and ∞ have no literal in GLSL or WGSL (and a bit
/// pattern for them is undefined behaviour in WGSL's constant evaluation), a magnitude above f32's largest
/// rounds to ∞, and a nonzero one below its smallest normal is flushed to 0 by GPUs that do not keep subnormals.
fn f32_trouble(v: f64) -> Option<&'static str> {
    if v.is_nan() {
        Some("is NaN, which f32 shader code has no literal for")
    } else if v.is_infinite() {
        Some("is infinite, which f32 shader code has no literal for")
    } else if v.abs() > f32::MAX as f64 {
        Some("is beyond f32's range (largest 3.4028235e38): a shader would compute with ∞")
    } else if v != 0.0 && v.abs() < f32::MIN_POSITIVE as f64 {
        Some("is below f32's smallest normal number (1.1754944e-38): GPUs may flush it to 0")
    } else {
        None
    }
}

/// The error for a constant a shader cannot hold, pointing at it in the source.
fn refuse_constant(v: f64, why: &str, span: crate::base::span::Span) -> Diagnostic {
    let shown = crate::ir::print::number(v);
    Diagnostic::error(format!("the constant {shown} cannot be exported: it {why}"))
        .at(span, "this constant, after simplification")
        .hint("scale the formula so its constants lie within ±3.4e38 and are 0 or above 1.2e-38 in magnitude, or bake parameters that produce it differently")
}

/// The group name of a parameter: a colour channel `NAME.r` belongs to `NAME`; every other parameter is its own.
fn group(p: &ParamDecl) -> &str {
    match p.kind {
        ParamKind::Color(_) => p.name.rsplit_once('.').map_or(p.name.as_str(), |(g, _)| g),
        _ => &p.name,
    }
}

/// Shader identifiers for the formula's parameters (by index). A name that is reserved in GLSL or WGSL, looks
/// like a temporary (`t0`) or the exported function (`lobe_…`), starts with `gl_` or `_`, or contains `__`
/// (reserved in both languages) becomes
/// `p_NAME` with underscores collapsed, made unique; every other name is kept, so an exported signature reads
/// as the .brdf file does. The three channels of a colour parameter share one identifier (a `vec3`).
pub(crate) fn param_names(f: &Formula) -> Vec<String> {
    let needs_mangling = |n: &str| {
        RESERVED.contains(&n)
            || n.starts_with("gl_")
            || n.starts_with('_')
            || n.contains("__")
            || n.starts_with("lobe_")
            || (n.len() > 1 && n.starts_with('t') && n[1..].bytes().all(|b| b.is_ascii_digit()))
    };
    let mut out: Vec<String> = Vec::with_capacity(f.params.len());
    for (i, p) in f.params.iter().enumerate() {
        let g = group(p);
        if i > 0 && matches!(p.kind, ParamKind::Color(k) if k > 0) && group(&f.params[i - 1]) == g {
            out.push(out[i - 1].clone());
            continue;
        }
        let mut name = if needs_mangling(g) {
            let collapsed: Vec<&str> = g.split('_').filter(|s| !s.is_empty()).collect();
            format!("p_{}", collapsed.join("_"))
        } else {
            g.to_string()
        };
        let base = name.clone();
        let mut k = 1;
        while out.contains(&name) || f.params.iter().any(|q| group(q) == name && group(q) != g) {
            name = format!("{base}_{k}");
            k += 1;
        }
        out.push(name);
    }
    out
}

/// How the body reads each parameter: its identifier, a colour channel as `NAME.r` (valid in both languages),
/// a bool as `float(NAME)` when it is declared `bool` (BRDF Explorer's uniforms) rather than a float argument.
fn param_reads(f: &Formula, names: &[String], bools_are_bool: bool) -> Vec<String> {
    f.params
        .iter()
        .zip(names)
        .map(|(p, n)| match p.kind {
            ParamKind::Color(k) => format!("{n}.{}", ["r", "g", "b"][k.min(2) as usize]),
            ParamKind::Bool if bools_are_bool => format!("float({n})"),
            _ => n.clone(),
        })
        .collect()
}

/// A live parameter as a shader declares it: one float or bool, or one `vec3` for a colour's channels;
/// `first` is the index of its (first) parameter.
struct Decl {
    name: String,
    kind: ParamKind,
    first: usize,
}

/// The declarations of the live parameters, in declaration order, one per colour group.
fn live_decls(f: &Formula, names: &[String], live: &[u16]) -> Vec<Decl> {
    let mut out: Vec<Decl> = vec![];
    for &p in live {
        let i = p as usize;
        if out.iter().any(|d| d.name == names[i]) {
            continue;
        }
        let kind = f.params[i].kind;
        let first = match kind {
            ParamKind::Color(k) => i - k as usize,
            _ => i,
        };
        out.push(Decl { name: names[i].clone(), kind, first });
    }
    out.sort_by_key(|d| d.first);
    out
}

/// Inputs and live parameters of all `roots`.
fn uses_of(ir: &Ir, roots: &[NodeId]) -> (InputSet, Vec<u16>) {
    let inputs: InputSet = roots.iter().map(|r| ir.used_inputs(*r)).collect();
    let mut params: Vec<u16> = roots.iter().flat_map(|r| ir.used_params(*r)).collect();
    params.sort_unstable();
    params.dedup();
    (inputs, params)
}

/// The one expression emitter behind every shader lobe writes (GLSL, WGSL, BRDF Explorer): appends
/// to `out` one indented statement per node that is shared (by any of `roots`) or is a call, binding it to a
/// temporary `tK`; every other node is inlined with full parentheses. Returns each root's expression.
/// Inputs are referred to by name (function arguments or locals) and parameters by `params` (see
/// [`param_reads`]). An internal builtin is refused ([`refuse_internal`]).
/// The longest expression text written inline; a longer one is bound to a temporary.
const MAX_INLINE_CHARS: usize = 1000;

fn emit(ir: &Ir, roots: &[NodeId], d: Dialect, exact: bool, params: &[String], out: &mut String) -> Result<Vec<String>, Diagnostic> {
    let mut uses = vec![0u32; ir.len()];
    for r in roots {
        for (u, c) in uses.iter_mut().zip(ir.use_counts(*r)) {
            *u += c;
        }
    }
    let ty = match d {
        Dialect::Glsl(v) => v.types().0,
        Dialect::Wgsl => "f32",
    };
    let single = (roots.len() == 1).then(|| roots[0]);
    let mut text: Vec<String> = Vec::with_capacity(ir.len());
    let mut ntemps = 0;
    for id in ir.ids() {
        if uses[id.index()] == 0 {
            text.push(String::new());
            continue;
        }
        let node = ir.node(id);
        let t = |a: NodeId| text[a.index()].clone();
        let e = match *node {
            Node::Const(b) => {
                let v = f64::from_bits(b);
                if let Some(why) = f32_trouble(v) {
                    return Err(refuse_constant(v, why, ir.span(id)));
                }
                literal(v, exact)
            }
            Node::Input(i) => i.name().to_string(),
            Node::Param(p) => params[p as usize].clone(),
            // Formulas have no data columns (only shading programs, which are not exported); named for dumps.
            Node::Column(k) => format!("column{k}"),
            Node::Neg(a) => format!("(-{})", t(a)),
            Node::Binary(op, a, b) => format!("({} {} {})", t(a), op.symbol(), t(b)),
            Node::Call(b, _) if b.is_internal() => return Err(refuse_internal(b)),
            Node::Call(Builtin::Fma, a) if d.glsl().is_some_and(|v| !v.has_fma()) => format!("({} * {} + {})", t(a[0]), t(a[1]), t(a[2])),
            Node::Call(b, a) => {
                let mut s = match d {
                    Dialect::Glsl(_) => b.info().glsl,
                    Dialect::Wgsl => b.wgsl(),
                }
                .to_string();
                for (k, arg) in a[..b.arity()].iter().enumerate() {
                    s = s.replace(&format!("{{{k}}}"), &t(*arg));
                }
                s
            }
        };
        let leaf = matches!(node, Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_));
        // A long expression gets a name too: a chain of single-use nodes (`NH+NH+…`, 600 000 deep under the
        // source cap) would otherwise copy its growing text at every node (quadratic; 23 GB) and nest deeper
        // than shader compilers take.
        let long = e.len() > MAX_INLINE_CHARS;
        let bind = Some(id) != single && !leaf && (uses[id.index()] > 1 || matches!(node, Node::Call(..)) || long);
        if bind {
            let tname = format!("t{ntemps}");
            ntemps += 1;
            let _ = match d {
                Dialect::Glsl(_) => writeln!(out, "    {ty} {tname} = {e};"),
                Dialect::Wgsl => writeln!(out, "    let {tname}: {ty} = {e};"),
            };
            text.push(tname);
        } else {
            text.push(e);
        }
    }
    Ok(roots.iter().map(|r| text[r.index()].clone()).collect())
}

/// The error for a formula that holds an internal builtin: a shader has no spelling for it.
fn refuse_internal(b: Builtin) -> Diagnostic {
    Diagnostic::error(format!(
        "`{}` cannot be exported: it is internal to the accuracy pass, whose rewrites are for f64, not a GPU's f32",
        b.name()
    ))
    .hint("export the plain simplification (the formula compiled without the accuracy pass)")
}

/// The header every export starts with (each line to be prefixed by the target's comment marker): what the
/// formula is, what was baked, and how the shader differs from lobe's own evaluation.
fn header(f: &Formula, inputs: InputSet, live: &[u16], lang: &str) -> Vec<String> {
    let mut out = vec![format!("{} — exported by lobe {} as {lang}.", comment_text(&f.display_name()), env!("CARGO_PKG_VERSION"))];
    if let Some(c) = &f.meta.citation {
        out.push(format!("Source: {}", comment_text(c)));
    }
    let channels = f.channels();
    for (k, c) in channels.iter().enumerate() {
        let which = if channels.len() == 1 { String::new() } else { format!(", {} channel", ["red", "green", "blue"][k.min(2)]) };
        // The let form, not the expanded tree: shared subexpressions would otherwise grow exponentially.
        let program = c.to_program_text();
        if program.lines().count() <= 1 {
            out.push(format!("Formula (simplified){which}: {}", comment_text(&program)));
        } else {
            out.push(format!("Formula (simplified){which}:"));
            out.extend(program.lines().map(|l| format!("  {}", comment_text(l))));
        }
    }
    let baked: Vec<&str> =
        f.params.iter().enumerate().filter(|(i, _)| !live.contains(&(*i as u16))).map(|(_, p)| p.name.as_str()).collect();
    if !baked.is_empty() {
        out.push(format!("Baked or unused parameters (folded into constants): {}", baked.join(", ")));
    }
    if inputs.reads_directions() {
        out.push("Lx..Vz are the components of the unit light and view directions in the local frame".into());
        out.push("(N = +z, X = +x, Y = +y); cosine inputs are clamped where lobe clamps them.".into());
    } else {
        out.push("Inputs are cosines (clamped to [0, 1] here, as lobe does); the result is clamped at 0.".into());
    }
    out.push("lobe evaluates in f64; this runs in f32. GPU min/max need not propagate NaN, and".into());
    out.push("pow(x, y) is undefined on GPUs for x < 0 or x = 0, y <= 0.".into());
    out
}

/// Exports the formula as one shader function: the inputs it reads and its live parameters as arguments (a
/// colour parameter as one `vec3`), returning `float` (`f32`) or, for a colour formula, `vec3` (`vec3<f32>`).
/// An error when the formula holds an internal builtin (see the module documentation).
pub fn export(f: &Formula, d: Dialect) -> Result<String, Diagnostic> {
    let f = &f.in_language();
    let (ir, roots) = f.merged_roots();
    let (inputs, live) = uses_of(&ir, &roots);
    let names = param_names(f);
    let lang = match d {
        Dialect::Glsl(GlslVersion::V330) => "GLSL 3.30",
        Dialect::Glsl(GlslVersion::V450) => "GLSL 4.50",
        Dialect::Glsl(GlslVersion::Es300) => "GLSL ES 3.00",
        Dialect::Wgsl => "WGSL",
    };
    let mut out = String::new();
    let mut lines = header(f, inputs, &live, lang);
    if d.glsl().is_some_and(|v| !v.has_fma()) && ir.nodes().iter().any(|n| matches!(n, Node::Call(Builtin::Fma, _))) {
        lines.push(format!("{lang} has no fma: fma(a, b, c) is written a * b + c, which need not round once."));
    }
    for line in lines {
        let _ = writeln!(out, "// {line}");
    }
    let arg = |name: &str, vec: bool| match (d, vec) {
        (Dialect::Glsl(v), false) => format!("{} {name}", v.types().0),
        (Dialect::Glsl(v), true) => format!("{} {name}", v.types().1),
        (Dialect::Wgsl, false) => format!("{name}: f32"),
        (Dialect::Wgsl, true) => format!("{name}: vec3<f32>"),
    };
    let mut args: Vec<String> = inputs.iter().map(|i| arg(i.name(), false)).collect();
    args.extend(live_decls(f, &names, &live).iter().map(|p| arg(&p.name, matches!(p.kind, ParamKind::Color(_)))));
    let rgb = roots.len() == 3;
    let name = function_name(f);
    let _ = match (d, rgb) {
        (Dialect::Glsl(v), _) => writeln!(out, "{} {name}({}) {{", if rgb { v.types().1 } else { v.types().0 }, args.join(", ")),
        (Dialect::Wgsl, _) => writeln!(out, "fn {name}({}) -> {} {{", args.join(", "), if rgb { "vec3<f32>" } else { "f32" }),
    };
    let results = emit(&ir, &roots, d, false, &param_reads(f, &names, false), &mut out)?;
    let _ = writeln!(out, "    return {};", result(&results, d));
    let _ = writeln!(out, "}}");
    Ok(out)
}

/// The returned expression: the scalar, or `vec3(r, g, b)`.
fn result(results: &[String], d: Dialect) -> String {
    match (results, d) {
        ([one], _) => one.clone(),
        (_, Dialect::Glsl(_)) => format!("vec3({})", results.join(", ")),
        (_, Dialect::Wgsl) => format!("vec3<f32>({})", results.join(", ")),
    }
}

/// A number as BRDF Explorer's parameter reader (`stream >> float`) takes it; the f64 text, so an importer
/// reading it back gets lobe's value.
fn be_number(v: f64) -> String {
    format!("{v}")
}

/// A finite slider range for a parameter (BRDF Explorer needs one): the declared bound where it is finite in
/// f32, else ten times the default's magnitude (at least 10) away from the default. `true` when chosen here.
fn slider_range(p: &ParamDecl) -> (f64, f64, bool) {
    let finite = |v: f64| (v as f32).is_finite();
    let reach = p.default.abs().max(1.0) * 10.0;
    let lo = if finite(p.lo) { p.lo } else { p.default - reach };
    let hi = if finite(p.hi) { p.hi } else { p.default + reach };
    (lo, hi, !(finite(p.lo) && finite(p.hi)))
}

/// How BRDF Explorer's `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)` computes each input lobe's kernels
/// read, from the world-space vectors it is given (H = normalize(L + V), R = reflect(−L, N)).
fn be_input(i: Input) -> &'static str {
    match i {
        Input::NL => "dot(N, L)",
        Input::NV => "dot(N, V)",
        Input::NH => "dot(N, H)",
        Input::VR => "dot(V, reflect(-L, N))",
        Input::VH => "dot(V, H)",
        Input::Lx => "dot(L, X)",
        Input::Ly => "dot(L, Y)",
        Input::Lz => "dot(L, N)",
        Input::Vx => "dot(V, X)",
        Input::Vy => "dot(V, Y)",
        Input::Vz => "dot(V, N)",
    }
}

/// The formula as a file Disney's BRDF Explorer loads: `analytic`, a `::begin parameters` block declaring the
/// live parameters (`float NAME MIN MAX DEFAULT`, `bool NAME DEFAULT`, `color NAME R G B`), and a
/// `::begin shader` block defining `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)` that computes only the
/// inputs the formula reads and then the body [`export`] writes (the same emitter). BRDF Explorer declares
/// each parameter as a uniform of its type (`uniform float`, `uniform bool`, `uniform vec3`), so a bool is
/// read as `float(NAME)` and a colour channel as `NAME.r`; a scalar formula returns `vec3(F)`. An error when
/// the formula holds an internal builtin, as for [`export`].
pub fn brdf_explorer(f: &Formula) -> Result<String, Diagnostic> {
    let f = &f.in_language();
    let (ir, roots) = f.merged_roots();
    let (inputs, live) = uses_of(&ir, &roots);
    let names = param_names(f);
    let mut out = String::from("analytic\n\n");
    for line in header(f, inputs, &live, "a BRDF Explorer file") {
        let _ = writeln!(out, "# {line}");
    }
    let decls = live_decls(f, &names, &live);
    for d in &decls {
        let p = &f.params[d.first];
        if let (ParamKind::Float, (lo, hi, true)) = (d.kind, slider_range(p)) {
            let _ = writeln!(
                out,
                "# {}: declared range {}..{}; BRDF Explorer needs a finite one, so its slider spans {}..{}.",
                d.name,
                crate::ir::print::number(p.lo),
                crate::ir::print::number(p.hi),
                be_number(lo),
                be_number(hi)
            );
        }
    }
    out.push_str("\n# [type] [name] [min val] [max val] [default val]\n::begin parameters\n");
    for d in &decls {
        let p = &f.params[d.first];
        let _ = match d.kind {
            ParamKind::Float => {
                let (lo, hi, _) = slider_range(p);
                writeln!(out, "float {} {} {} {}", d.name, be_number(lo), be_number(hi), be_number(p.default))
            }
            ParamKind::Bool => writeln!(out, "bool {} {}", d.name, u8::from(p.default != 0.0)),
            ParamKind::Color(_) => {
                let c: Vec<String> = (0..3).map(|k| be_number(f.params.get(d.first + k).map_or(0.0, |q| q.default))).collect();
                writeln!(out, "color {} {}", d.name, c.join(" "))
            }
        };
    }
    out.push_str("::end parameters\n\n::begin shader\n");
    let _ = writeln!(out, "vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)\n{{");
    if inputs.contains(Input::NH) || inputs.contains(Input::VH) {
        out.push_str("    vec3 H = normalize(L + V);\n");
    }
    for i in inputs.iter() {
        let _ = writeln!(out, "    float {} = {};", i.name(), be_input(i));
    }
    // BRDF Explorer compiles GLSL 4.10, which has fma.
    let glsl = Dialect::Glsl(GlslVersion::V450);
    let results = emit(&ir, &roots, glsl, true, &param_reads(f, &names, true), &mut out)?;
    let ret = match results.as_slice() {
        [one] => format!("vec3({one})"),
        _ => result(&results, glsl),
    };
    let _ = writeln!(out, "    return {ret};\n}}\n::end shader");
    Ok(out)
}

/// A complete fragment shader in `version` around the exported GLSL function (for validators and quick
/// previews); an error as for [`export`].
pub fn glsl_test_shader(f: &Formula, version: GlslVersion) -> Result<String, Diagnostic> {
    let func = export(f, Dialect::Glsl(version))?;
    let (ir, roots) = f.merged_roots();
    let (inputs, live) = uses_of(&ir, &roots);
    let mut call_args: Vec<String> = inputs.iter().map(|_| "0.5".to_string()).collect();
    for d in live_decls(f, &param_names(f), &live) {
        let lit = |k: usize| literal(f.params[d.first + k].default, false);
        call_args.push(match d.kind {
            ParamKind::Color(_) => format!("vec3({}, {}, {})", lit(0), lit(1), lit(2)),
            _ => lit(0),
        });
    }
    let call = format!("{}({})", function_name(f), call_args.join(", "));
    let value = if roots.len() == 3 { format!("vec4({call}, 1.0)") } else { format!("vec4({call})") };
    let precision = if version == GlslVersion::Es300 { "precision highp float;\n" } else { "" };
    Ok(format!(
        "{}\n{precision}{func}\nlayout(location = 0) out vec4 color;\nvoid main() {{\n    color = {value};\n}}\n",
        version.directive()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hostile_names_are_mangled_and_metadata_cannot_inject_code() {
        // A CR ends the line (also in a string), so a name cannot hold one; a Unicode line separator or a
        // vertical tab is what is left to try.
        let src = "@name \"x\\u{2028}#define pow(a,b) 0.0\\x0b#define exp(a) 0.0\"\nparam t0 = 1\nparam float = 2\nparam gl_Position = 3\nparam alias = 4\n\
                   param p_float = 5\nparam a__b = 6\nNH^n * t0 + float + gl_Position + alias + p_float + a__b\n";
        let src = src.replace("\\u{2028}", "\u{2028}").replace("\\x0b", "\x0b");
        let f = crate::front::parse("hostile.brdf", &src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let names = param_names(&f);
        assert_eq!(names, ["n", "p_t0", "p_float_1", "p_gl_Position", "p_alias", "p_float", "p_a_b"]);
        for d in [Dialect::Glsl(GlslVersion::V450), Dialect::Wgsl] {
            let text = export(&f, d).unwrap();
            assert!(text.lines().all(|l| l.starts_with("//") || !l.contains("define")), "{text}");
            assert!(!text.contains(['\r', '\u{2028}', '\x0b']), "{text}");
            let code: String = text.lines().filter(|l| !l.starts_with("//")).collect::<Vec<_>>().join("\n");
            assert!(code.contains("p_gl_Position") && !code.contains(" gl_Position"), "{text}");
        }
    }

    /// A formula that holds one of the accuracy pass's internal builtins (read with `parse_internal`, as the
    /// pass's output would hold it) is refused by every export with an error naming it, never written as
    /// something else.
    #[test]
    fn exports_refuse_internal_builtins() {
        for (name, src) in [
            ("expmuldiv", "param m = 0.3 in 0.01..1\nNL * expmuldiv(NH - 1, m, NV)"),
            ("acoslo", "acos(NH) + acoslo(NH)"),
            ("powlo", "pow(NH, n) + powlo(NH, n)"),
        ] {
            let f = crate::front::parse_internal("internal.brdf", src).unwrap_or_else(|d| panic!("{}", d.render(false)));
            let f = crate::simplify::simplify(&f, &[(0, 50.0)]);
            assert!(f.ir.nodes().iter().any(|n| matches!(n, Node::Call(b, _) if b.is_internal())), "{name}: {}", f.to_program_text());
            let errors = [
                export(&f, Dialect::Glsl(GlslVersion::V450)),
                export(&f, Dialect::Wgsl),
                brdf_explorer(&f),
                glsl_test_shader(&f, GlslVersion::Es300),
            ];
            for e in errors {
                let e = e.expect_err(name);
                assert!(e.message.contains(&format!("`{name}` cannot be exported")), "{e}");
                assert!(!e.hints.is_empty(), "{e}");
            }
            // The same formula without the internal call exports.
            let plain = crate::front::parse("plain.brdf", "acos(NH) + pow(NH, n)").unwrap();
            assert!(export(&plain, Dialect::Glsl(GlslVersion::V330)).is_ok());
        }
    }

    /// A constant no f32 shader can hold is refused at its place in the source, whatever produced it (written,
    /// or folded from baked parameters); constants within f32's normal range export.
    #[test]
    fn constants_outside_f32_are_refused_where_they_are() {
        for (src, needle) in [
            ("NH * 1e300", "beyond f32's range"),
            ("NH + 1e-300", "below f32's smallest normal"),
            ("param k = 1e200\nNH * k * k", "beyond f32's range"),
            ("NH * (0/0)", "NaN"),
            ("NH * (1/0)", "infinite"),
        ] {
            let f = crate::front::parse("c.brdf", src).unwrap_or_else(|d| panic!("{}", d.render(false)));
            let f = crate::simplify::simplify(&f, &[(0, 50.0), (1, 1e200)]);
            for d in [Dialect::Glsl(GlslVersion::V330), Dialect::Glsl(GlslVersion::Es300), Dialect::Wgsl] {
                let e = export(&f, d).expect_err(src);
                assert!(e.message.contains(needle) && e.primary.is_some(), "{src}: {e}");
            }
            assert!(brdf_explorer(&f).is_err(), "{src}");
        }
        for src in ["NH * 3e38", "NH + 1.2e-38", "NH * 0 + 1"] {
            let f = crate::front::parse("c.brdf", src).unwrap();
            let f = crate::simplify::simplify(&f, &[]);
            assert!(export(&f, Dialect::Wgsl).is_ok(), "{src}");
        }
    }

    /// GLSL 3.30 and ES 3.00 have no fma: the call is written as a multiply-add and the header says so; 4.50
    /// keeps it. ES declares every float highp.
    #[test]
    fn fma_and_precision_follow_the_glsl_version() {
        let f = crate::front::parse("f.brdf", "fma(NH, NV, NL) * n").unwrap();
        let f = crate::simplify::simplify(&f, &[]);
        let v450 = export(&f, Dialect::Glsl(GlslVersion::V450)).unwrap();
        assert!(v450.contains("= fma(t2, t1, t0);") && !v450.contains("has no fma"), "{v450}");
        for v in [GlslVersion::V330, GlslVersion::Es300] {
            let text = export(&f, Dialect::Glsl(v)).unwrap();
            let code: String = text.lines().filter(|l| !l.starts_with("//")).collect();
            assert!(!code.contains("fma(") && code.contains("= (t2 * t1 + t0);"), "{text}");
            assert!(text.contains("has no fma"), "{text}");
            assert_eq!(code.contains("highp float NH"), v == GlslVersion::Es300, "{text}");
        }
        assert_eq!("es300".parse::<GlslVersion>(), Ok(GlslVersion::Es300));
        assert!("300".parse::<GlslVersion>().unwrap_err().contains("expected `330`, `450` or `es300`"));
    }
}
