//! The one table of builtin functions.
//!
//! Every backend reads this table and nothing else: the front end checks names and arity against it; the
//! interpreter and constant folding call [`Builtin::eval_in`]; the JIT emits sqrt/abs/min/max/clamp as native
//! instructions ([`Lowering::Inline`], modelled exactly by the functions here) and every transcendental
//! builtin ([`Lowering::Math`]) as the straight-line code of [`math`], the same definition the interpreter runs,
//! so the two agree bit for bit in each [`Mode`]; the GLSL export prints [`BuiltinInfo::glsl`] and the Mitsuba export [`BuiltinInfo::drjit`]. Three rows are
//! [internal](BuiltinInfo::internal): formed only by the accuracy pass, not callable from user text, never
//! exported. Each row states its error bound in each mode ([`Bound`]), which `lobe check` prints and the tests
//! verify; the C library's version ([`BuiltinInfo::libm`]) is kept as the reference the bounds are measured
//! against and as the fallback for huge trigonometric arguments.
//!
//! Derivatives: every row, internal ones and the comparisons included, has one tangent rule in [`derive`](mod@derive)
//! (the partials with respect to each argument, written with other builtins), and the choice at each kink
//! (abs, min, max, clamp, select, acos/asin at ±1, sqrt and ln at 0, pow at x = 0) is stated once in that
//! module's doc.
//!
//! Domain policy: `acos` and `asin` clamp their argument to [−1, 1] (a cosine computed from rounded vectors can
//! be 1 + 1 ulp, and acos of it must not be NaN). Everything else follows IEEE 754 and C99 (pow's special cases,
//! NaN in → NaN out).

pub mod dd;
pub mod derive;
pub(crate) mod math;
pub mod math_tables;

pub use math::Mode;
use std::fmt;

/// A builtin function. The discriminant order is the table order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Builtin {
    Pow,
    Cos,
    Sin,
    Tan,
    Acos,
    Asin,
    Atan,
    Exp,
    Ln,
    Sqrt,
    Abs,
    Min,
    Max,
    Clamp,
    Floor,
    Lt,
    Le,
    Eq,
    Ne,
    Select,
    Fma,
    ExpMulDiv,
    AcosLo,
    PowLo,
    SinNear,
}

/// How the JIT lowers a builtin.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lowering {
    /// A native instruction (sqrt, fabs, fmin, fmax); [`Builtin::eval_in`] is its exact model.
    Inline,
    /// The library's straight-line code ([`math`]), emitted into the kernel in the kernel's lane type.
    Math,
    /// Exact comparisons, selects and floor, written in the library's primitives ([`math::logic`]) and always
    /// emitted inline (a compare and a blend: never worth a call).
    Logic,
}

/// The C library's version of a builtin (Rust's `f64` methods: the platform libm).
#[derive(Clone, Copy, Debug)]
pub enum Libm {
    F1(extern "C" fn(f64) -> f64),
    F2(extern "C" fn(f64, f64) -> f64),
    F3(extern "C" fn(f64, f64, f64) -> f64),
    /// Inline builtins: exact, nothing to compare with but themselves.
    Exact,
}

/// A builtin's stated accuracy. `ulp` is the bound in precise mode, in units in the last place of the correctly
/// rounded result; `fast_rel` the bound in fast mode, relative (absolute where |result| < 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bound {
    pub ulp: f64,
    pub fast_rel: f64,
}

impl Bound {
    /// abs, min, max, clamp: no rounding at all.
    const EXACT: Bound = Bound { ulp: 0.0, fast_rel: 0.0 };
    /// sqrt: IEEE's correctly rounded square root.
    const ROUNDED: Bound = Bound { ulp: 0.5, fast_rel: 0.0 };
    const fn math(ulp: f64) -> Bound {
        Bound { ulp, fast_rel: 1e-6 }
    }

    /// The bound as text in `mode`: "≤ 2 ulp", "≤ 1e-6 rel.", "correctly rounded" or "exact".
    pub fn describe(&self, mode: Mode) -> String {
        match mode {
            _ if self.ulp == 0.0 => "exact".into(),
            _ if self.fast_rel == 0.0 => "correctly rounded".into(),
            Mode::Precise => format!("≤ {} ulp", self.ulp),
            Mode::Fast => format!("≤ {:e} rel.", self.fast_rel),
        }
    }
}

/// One row of the table.
#[derive(Clone, Copy, Debug)]
pub struct BuiltinInfo {
    pub builtin: Builtin,
    /// Name in the .brdf language.
    pub name: &'static str,
    pub arity: usize,
    pub lowering: Lowering,
    /// The C library's version: the reference for accuracy, and the JIT's fallback (under [`Self::symbol`])
    /// for trigonometric arguments beyond the library's reduction.
    pub libm: Libm,
    /// Symbol the JIT registers for the libm fallback (empty when there is none).
    pub symbol: &'static str,
    pub bound: Bound,
    /// GLSL spelling; `{0}`, `{1}`, `{2}` are the arguments. Empty for an [internal](Self::internal) builtin:
    /// no shader export writes one (the export refuses it).
    pub glsl: &'static str,
    /// WGSL spelling where it differs from GLSL's (empty: the same).
    pub wgsl: &'static str,
    /// Dr.Jit (Python) spelling for the Mitsuba 3 export ([`crate::backend::drjit`]); `_pow`, `_acos`, `_lt`, …
    /// are the exported module's helpers (IEEE pow, clamped acos, comparisons as 0/1). Empty for an internal
    /// builtin, as [`Self::glsl`].
    pub drjit: &'static str,
    /// One line for `lobe help` and hints.
    pub doc: &'static str,
    /// `Some(what to write instead)` for a builtin only the accuracy pass forms (rewrites for f64: double-double
    /// tails, exponentials scaled by powers of two beyond f32's range). It is not a function of the language:
    /// the front ends refuse it in user text with this hint ([`crate::front::parse_internal`] reads it back, for
    /// tests and the pass's own output), no hint or suggestion offers it, and no shader export writes it.
    pub internal: Option<&'static str>,
}

/// expmuldiv's C-library spelling, `exp(a)*b/c` as written (it underflows where the builtin does not).
extern "C" fn lobe_expmuldiv_libm(a: f64, b: f64, c: f64) -> f64 {
    a.exp() * b / c
}

/// expmuldiv's library code compiled by rustc, for outlined call sites.
extern "C" fn lobe_expmuldiv_precise(a: f64, b: f64, c: f64) -> f64 {
    math::exp_mul_div(&mut math::Direct, a, b, c, Mode::Precise)
}

extern "C" fn lobe_expmuldiv_fast(a: f64, b: f64, c: f64) -> f64 {
    math::exp_mul_div(&mut math::Direct, a, b, c, Mode::Fast)
}

/// acoslo's C-library spelling: the C library's acos minus lobe's (both within an ulp, so a rough reference).
extern "C" fn lobe_acoslo_libm(x: f64) -> f64 {
    x.acos() - math::acos(&mut math::Direct, x, Mode::Precise)
}

/// acoslo's library code compiled by rustc, for outlined call sites.
extern "C" fn lobe_acoslo_precise(x: f64) -> f64 {
    math::acos_lo(&mut math::Direct, x, Mode::Precise)
}

extern "C" fn lobe_acoslo_fast(x: f64) -> f64 {
    math::acos_lo(&mut math::Direct, x, Mode::Fast)
}

/// powlo's C-library spelling: the C library's pow minus lobe's (both within an ulp, so a rough reference).
extern "C" fn lobe_powlo_libm(x: f64, y: f64) -> f64 {
    x.powf(y) - math::pow(&mut math::Direct, x, y)
}

extern "C" fn lobe_pow(x: f64, y: f64) -> f64 {
    x.powf(y)
}
extern "C" fn lobe_cos(x: f64) -> f64 {
    x.cos()
}
extern "C" fn lobe_sin(x: f64) -> f64 {
    x.sin()
}
extern "C" fn lobe_tan(x: f64) -> f64 {
    x.tan()
}
extern "C" fn lobe_acos(x: f64) -> f64 {
    clamp(x, -1.0, 1.0).acos()
}
extern "C" fn lobe_asin(x: f64) -> f64 {
    clamp(x, -1.0, 1.0).asin()
}
extern "C" fn lobe_atan(x: f64) -> f64 {
    x.atan()
}
extern "C" fn lobe_exp(x: f64) -> f64 {
    x.exp()
}
extern "C" fn lobe_ln(x: f64) -> f64 {
    x.ln()
}


// The math library compiled by rustc as C functions, one per builtin and mode: what the JIT calls instead of
// inlining the library when a formula has many call sites (its compile time grows with the inlined code).
// Each runs `eval_in`, the same code, so calling instead of inlining changes no bit.
macro_rules! lib1 {
    ($name:ident, $b:ident, $m:ident) => {
        extern "C" fn $name(x: f64) -> f64 {
            Builtin::$b.eval_in(Mode::$m, &[x])
        }
    };
}
macro_rules! lib2 {
    ($name:ident, $b:ident, $m:ident) => {
        extern "C" fn $name(x: f64, y: f64) -> f64 {
            Builtin::$b.eval_in(Mode::$m, &[x, y])
        }
    };
}
lib2!(lobe_pow_precise, Pow, Precise);
lib2!(lobe_pow_fast, Pow, Fast);
lib2!(lobe_powlo_precise, PowLo, Precise);
lib2!(lobe_powlo_fast, PowLo, Fast);
lib1!(lobe_cos_precise, Cos, Precise);
lib1!(lobe_cos_fast, Cos, Fast);
lib1!(lobe_sin_precise, Sin, Precise);
lib1!(lobe_sin_fast, Sin, Fast);
lib1!(lobe_sinnear_precise, SinNear, Precise);
lib1!(lobe_sinnear_fast, SinNear, Fast);
lib1!(lobe_tan_precise, Tan, Precise);
lib1!(lobe_tan_fast, Tan, Fast);
lib1!(lobe_acos_precise, Acos, Precise);
lib1!(lobe_acos_fast, Acos, Fast);
lib1!(lobe_asin_precise, Asin, Precise);
lib1!(lobe_asin_fast, Asin, Fast);
lib1!(lobe_atan_precise, Atan, Precise);
lib1!(lobe_atan_fast, Atan, Fast);
lib1!(lobe_exp_precise, Exp, Precise);
lib1!(lobe_exp_fast, Exp, Fast);
lib1!(lobe_ln_precise, Ln, Precise);
lib1!(lobe_ln_fast, Ln, Fast);

/// IEEE 754-2019 `minimum`: NaN if either is NaN, −0 < +0. This is Cranelift's `fmin`.
pub(crate) fn fmin(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a == b {
        // Equal values differ only in the sign of zero: prefer −0.
        if a.is_sign_negative() {
            a
        } else {
            b
        }
    } else if a < b {
        a
    } else {
        b
    }
}

/// IEEE 754-2019 `maximum`: NaN if either is NaN, +0 > −0. This is Cranelift's `fmax`.
pub(crate) fn fmax(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a == b {
        if a.is_sign_positive() {
            a
        } else {
            b
        }
    } else if a > b {
        a
    } else {
        b
    }
}

/// `clamp(x, lo, hi) = min(max(x, lo), hi)` with the NaN-propagating min/max above.
pub(crate) fn clamp(x: f64, lo: f64, hi: f64) -> f64 {
    fmin(fmax(x, lo), hi)
}

const TABLE: [BuiltinInfo; 25] = [
    BuiltinInfo {
        builtin: Builtin::Pow,
        name: "pow",
        arity: 2,
        lowering: Lowering::Math,
        libm: Libm::F2(lobe_pow),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "pow({0}, {1})",
        wgsl: "",
        drjit: "_pow({0}, {1})",
        doc: "pow(x, y) = x^y; integer constant exponents become multiplications",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Cos,
        name: "cos",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_cos),
        symbol: "lobe_cos",
        bound: Bound::math(2.0),
        glsl: "cos({0})",
        wgsl: "",
        drjit: "dr.cos({0})",
        doc: "cosine of an angle in radians",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Sin,
        name: "sin",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_sin),
        symbol: "lobe_sin",
        bound: Bound::math(2.0),
        glsl: "sin({0})",
        wgsl: "",
        drjit: "dr.sin({0})",
        doc: "sine of an angle in radians",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Tan,
        name: "tan",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_tan),
        symbol: "lobe_tan",
        bound: Bound::math(3.0),
        glsl: "tan({0})",
        wgsl: "",
        drjit: "dr.tan({0})",
        doc: "tangent of an angle in radians",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Acos,
        name: "acos",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_acos),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "acos(clamp({0}, -1.0, 1.0))",
        wgsl: "",
        drjit: "_acos({0})",
        doc: "arc cosine in radians; the argument is clamped to [-1, 1]",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Asin,
        name: "asin",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_asin),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "asin(clamp({0}, -1.0, 1.0))",
        wgsl: "",
        drjit: "_asin({0})",
        doc: "arc sine in radians; the argument is clamped to [-1, 1]",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Atan,
        name: "atan",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_atan),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "atan({0})",
        wgsl: "",
        drjit: "dr.atan({0})",
        doc: "arc tangent in radians",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Exp,
        name: "exp",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_exp),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "exp({0})",
        wgsl: "",
        drjit: "dr.exp({0})",
        doc: "e^x",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Ln,
        name: "ln",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_ln),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "log({0})",
        wgsl: "",
        drjit: "dr.log({0})",
        doc: "natural logarithm",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Sqrt,
        name: "sqrt",
        arity: 1,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::ROUNDED,
        glsl: "sqrt({0})",
        wgsl: "",
        drjit: "dr.sqrt({0})",
        doc: "square root (NaN below 0)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Abs,
        name: "abs",
        arity: 1,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "abs({0})",
        wgsl: "",
        drjit: "dr.abs({0})",
        doc: "absolute value",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Min,
        name: "min",
        arity: 2,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "min({0}, {1})",
        wgsl: "",
        drjit: "dr.minimum({0}, {1})",
        doc: "smaller of two values (NaN if either is NaN)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Max,
        name: "max",
        arity: 2,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "max({0}, {1})",
        wgsl: "",
        drjit: "dr.maximum({0}, {1})",
        doc: "larger of two values (NaN if either is NaN)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Clamp,
        name: "clamp",
        arity: 3,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "clamp({0}, {1}, {2})",
        wgsl: "",
        drjit: "dr.minimum(dr.maximum({0}, {1}), {2})",
        doc: "clamp(x, lo, hi) = min(max(x, lo), hi)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Floor,
        name: "floor",
        arity: 1,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "floor({0})",
        wgsl: "",
        drjit: "dr.floor({0})",
        doc: "largest integer not above x",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Lt,
        name: "lt",
        arity: 2,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "float({0} < {1})",
        wgsl: "f32({0} < {1})",
        drjit: "_lt({0}, {1})",
        doc: "1 if a < b, else 0 (0 when either is NaN); what `a < b` and `b > a` mean",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Le,
        name: "le",
        arity: 2,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "float({0} <= {1})",
        wgsl: "f32({0} <= {1})",
        drjit: "_le({0}, {1})",
        doc: "1 if a <= b, else 0 (0 when either is NaN); what `a <= b` and `b >= a` mean",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Eq,
        name: "eq",
        arity: 2,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "float({0} == {1})",
        wgsl: "f32({0} == {1})",
        drjit: "_eq({0}, {1})",
        doc: "1 if a == b, else 0 (0 when either is NaN)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Ne,
        name: "ne",
        arity: 2,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "float({0} != {1})",
        wgsl: "f32({0} != {1})",
        drjit: "_ne({0}, {1})",
        doc: "1 if a != b, else 0 (1 when either is NaN)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Select,
        name: "select",
        arity: 3,
        lowering: Lowering::Logic,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::EXACT,
        glsl: "({0} != 0.0 ? {1} : {2})",
        wgsl: "select({2}, {1}, {0} != 0.0)",
        drjit: "_select({0}, {1}, {2})",
        doc: "select(c, a, b) = a if c is true (not 0), else b; the untaken value never reaches the result",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::Fma,
        name: "fma",
        arity: 3,
        lowering: Lowering::Inline,
        libm: Libm::Exact,
        symbol: "",
        bound: Bound::ROUNDED,
        glsl: "fma({0}, {1}, {2})",
        wgsl: "",
        drjit: "dr.fma({0}, {1}, {2})",
        doc: "fma(a, b, c) = a*b + c rounded once (the accuracy pass's compensated power chains use it)",
        internal: None,
    },
    BuiltinInfo {
        builtin: Builtin::ExpMulDiv,
        name: "expmuldiv",
        arity: 3,
        lowering: Lowering::Math,
        libm: Libm::F3(lobe_expmuldiv_libm),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "",
        wgsl: "",
        drjit: "",
        doc: "expmuldiv(a, b, c) = exp(a)*b/c with no intermediate underflow or overflow (the accuracy pass forms it)",
        internal: Some("write `exp(a) * b / c`; the accuracy pass forms expmuldiv itself where exp(a) alone would under- or overflow"),
    },
    BuiltinInfo {
        builtin: Builtin::AcosLo,
        name: "acoslo",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_acoslo_libm),
        symbol: "",
        bound: Bound::math(1.0),
        glsl: "",
        wgsl: "",
        drjit: "",
        doc: "acoslo(x) = acos(x) minus lobe's acos(x): its rounding error, 0 in fast math (the accuracy pass forms it)",
        internal: Some("write `acos(x)`; the accuracy pass adds acos's rounding error (acoslo) itself where that pays"),
    },
    BuiltinInfo {
        builtin: Builtin::PowLo,
        name: "powlo",
        arity: 2,
        lowering: Lowering::Math,
        libm: Libm::F2(lobe_powlo_libm),
        symbol: "",
        bound: Bound::math(1.0),
        glsl: "",
        wgsl: "",
        drjit: "",
        doc: "powlo(x, y) = pow(x, y) minus lobe's pow(x, y): its rounding error, 0 in fast math (the accuracy pass forms it)",
        internal: Some("write `pow(x, y)`; the accuracy pass adds pow's rounding error (powlo) itself where that pays"),
    },
    BuiltinInfo {
        builtin: Builtin::SinNear,
        name: "sinnear",
        arity: 1,
        lowering: Lowering::Math,
        libm: Libm::F1(lobe_sin),
        symbol: "",
        bound: Bound::math(2.0),
        glsl: "",
        wgsl: "",
        drjit: "",
        doc: "sinnear(x) = sin(x), computed without range reduction where |x| ≤ 1.75 (the simplifier forms it where range analysis bounds x)",
        internal: Some("write `sin(x)`; the simplifier uses sinnear itself where range analysis bounds the argument"),
    },
];

impl Builtin {
    pub const ALL: [Builtin; 25] = [
        Builtin::Pow,
        Builtin::Cos,
        Builtin::Sin,
        Builtin::Tan,
        Builtin::Acos,
        Builtin::Asin,
        Builtin::Atan,
        Builtin::Exp,
        Builtin::Ln,
        Builtin::Sqrt,
        Builtin::Abs,
        Builtin::Min,
        Builtin::Max,
        Builtin::Clamp,
        Builtin::Floor,
        Builtin::Lt,
        Builtin::Le,
        Builtin::Eq,
        Builtin::Ne,
        Builtin::Select,
        Builtin::Fma,
        Builtin::ExpMulDiv,
        Builtin::AcosLo,
        Builtin::PowLo,
        Builtin::SinNear,
    ];

    pub fn info(self) -> &'static BuiltinInfo {
        &TABLE[self as usize]
    }
    pub fn name(self) -> &'static str {
        self.info().name
    }
    pub fn arity(self) -> usize {
        self.info().arity
    }
    /// The WGSL spelling (see [`BuiltinInfo::wgsl`]).
    pub(crate) fn wgsl(self) -> &'static str {
        let i = self.info();
        if i.wgsl.is_empty() {
            i.glsl
        } else {
            i.wgsl
        }
    }

    /// The builtin of this name, internal ones included (the front ends decide whether text may call it).
    pub fn from_name(name: &str) -> Option<Builtin> {
        TABLE.iter().find(|r| r.name == name).map(|r| r.builtin)
    }

    /// The rows user text may call: the table without the [internal](Self::is_internal) builtins.
    pub(crate) fn language() -> impl Iterator<Item = &'static BuiltinInfo> {
        TABLE.iter().filter(|r| r.internal.is_none())
    }

    /// Only the accuracy pass or the simplifier forms it ([`BuiltinInfo::internal`]): not a function of the
    /// language, and never written by a shader export.
    pub fn is_internal(self) -> bool {
        self.info().internal.is_some()
    }

    /// Which of lobe's passes forms this [internal](Self::is_internal) builtin (for messages).
    pub fn formed_by(self) -> &'static str {
        match self {
            Builtin::SinNear => "the simplifier",
            _ => "the accuracy pass",
        }
    }

    /// The language's function this builtin computes, where it is only another coding of one: sinnear is sin
    /// (what text and shaders for people write); every other builtin is itself.
    pub fn language_form(self) -> Builtin {
        match self {
            Builtin::SinNear => Builtin::Sin,
            b => b,
        }
    }

    /// Reference semantics in precise mode; `args` has exactly `arity()` values.
    pub fn eval(self, args: &[f64]) -> f64 {
        self.eval_in(Mode::Precise, args)
    }

    /// Reference semantics in `mode`: what every backend computes, bit for bit.
    pub fn eval_in(self, mode: Mode, args: &[f64]) -> f64 {
        match self {
            Builtin::Sqrt => args[0].sqrt(),
            Builtin::Abs => args[0].abs(),
            Builtin::Min => fmin(args[0], args[1]),
            Builtin::Max => fmax(args[0], args[1]),
            Builtin::Clamp => clamp(args[0], args[1], args[2]),
            Builtin::Fma => dd::Arith::fma(&mut math::Direct, args[0], args[1], args[2]),
            _ => self.emit(&mut math::Direct, mode, args).unwrap_or(f64::NAN),
        }
    }

    /// The library code of a [`Lowering::Math`] or [`Lowering::Logic`] builtin on `args` (exactly `arity()`
    /// values), emitted through `e`; `None` for the inline builtins, whose lowering is the backend's.
    pub(crate) fn emit<E: math::Emit>(self, e: &mut E, mode: Mode, args: &[E::V]) -> Option<E::V> {
        use math::*;
        let fast = mode == Mode::Fast;
        let x = args[0];
        Some(match self {
            Builtin::Pow if fast => pow_fast(e, x, args[1]),
            Builtin::Pow => pow(e, x, args[1]),
            Builtin::Exp if fast => exp_fast(e, x),
            Builtin::Exp => exp(e, x),
            Builtin::Ln if fast => ln_fast(e, x),
            Builtin::Ln => ln(e, x),
            Builtin::Cos => cos(e, x, mode),
            Builtin::Sin => sin(e, x, mode),
            Builtin::SinNear => sin_near(e, x, mode),
            Builtin::Tan => tan(e, x, mode),
            Builtin::Acos => acos(e, x, mode),
            Builtin::Asin => asin(e, x, mode),
            Builtin::Atan => atan(e, x),
            Builtin::Floor => logic::floor(e, x),
            Builtin::Lt => logic::flag(e, |e| e.lt(x, args[1])),
            Builtin::Le => logic::flag(e, |e| e.le(x, args[1])),
            Builtin::Eq => logic::flag(e, |e| e.eq(x, args[1])),
            Builtin::Ne => logic::flag(e, |e| {
                let eq = e.eq(x, args[1]);
                e.not(eq)
            }),
            Builtin::Select => logic::select(e, x, args[1], args[2]),
            Builtin::ExpMulDiv => exp_mul_div(e, x, args[1], args[2], mode),
            Builtin::AcosLo => acos_lo(e, x, mode),
            Builtin::PowLo => pow_lo(e, x, args[1], mode),
            Builtin::Sqrt | Builtin::Abs | Builtin::Min | Builtin::Max | Builtin::Clamp | Builtin::Fma => return None,
        })
    }

    /// The C library's value (the reference the bounds are measured against); for inline builtins, `eval`.
    pub fn libm(self, args: &[f64]) -> f64 {
        match self.info().libm {
            Libm::F1(f) => f(args[0]),
            Libm::F2(f) => f(args[0], args[1]),
            Libm::F3(f) => f(args[0], args[1], args[2]),
            Libm::Exact => self.eval(args),
        }
    }

    /// The math library's code for this builtin in `mode` as a C function (symbol and pointer), for call sites
    /// the JIT does not inline; `None` for the inline builtins.
    pub(crate) fn outlined(self, mode: Mode) -> Option<(&'static str, Libm)> {
        Some(match (self, mode) {
            (Builtin::Pow, Mode::Precise) => ("lobe_pow_precise", Libm::F2(lobe_pow_precise)),
            (Builtin::Pow, Mode::Fast) => ("lobe_pow_fast", Libm::F2(lobe_pow_fast)),
            (Builtin::Cos, Mode::Precise) => ("lobe_cos_precise", Libm::F1(lobe_cos_precise)),
            (Builtin::Cos, Mode::Fast) => ("lobe_cos_fast", Libm::F1(lobe_cos_fast)),
            (Builtin::Sin, Mode::Precise) => ("lobe_sin_precise", Libm::F1(lobe_sin_precise)),
            (Builtin::Sin, Mode::Fast) => ("lobe_sin_fast", Libm::F1(lobe_sin_fast)),
            (Builtin::SinNear, Mode::Precise) => ("lobe_sinnear_precise", Libm::F1(lobe_sinnear_precise)),
            (Builtin::SinNear, Mode::Fast) => ("lobe_sinnear_fast", Libm::F1(lobe_sinnear_fast)),
            (Builtin::Tan, Mode::Precise) => ("lobe_tan_precise", Libm::F1(lobe_tan_precise)),
            (Builtin::Tan, Mode::Fast) => ("lobe_tan_fast", Libm::F1(lobe_tan_fast)),
            (Builtin::Acos, Mode::Precise) => ("lobe_acos_precise", Libm::F1(lobe_acos_precise)),
            (Builtin::Acos, Mode::Fast) => ("lobe_acos_fast", Libm::F1(lobe_acos_fast)),
            (Builtin::Asin, Mode::Precise) => ("lobe_asin_precise", Libm::F1(lobe_asin_precise)),
            (Builtin::Asin, Mode::Fast) => ("lobe_asin_fast", Libm::F1(lobe_asin_fast)),
            (Builtin::Atan, Mode::Precise) => ("lobe_atan_precise", Libm::F1(lobe_atan_precise)),
            (Builtin::Atan, Mode::Fast) => ("lobe_atan_fast", Libm::F1(lobe_atan_fast)),
            (Builtin::Exp, Mode::Precise) => ("lobe_exp_precise", Libm::F1(lobe_exp_precise)),
            (Builtin::Exp, Mode::Fast) => ("lobe_exp_fast", Libm::F1(lobe_exp_fast)),
            (Builtin::Ln, Mode::Precise) => ("lobe_ln_precise", Libm::F1(lobe_ln_precise)),
            (Builtin::Ln, Mode::Fast) => ("lobe_ln_fast", Libm::F1(lobe_ln_fast)),
            (Builtin::ExpMulDiv, Mode::Precise) => ("lobe_expmuldiv_precise", Libm::F3(lobe_expmuldiv_precise)),
            (Builtin::ExpMulDiv, Mode::Fast) => ("lobe_expmuldiv_fast", Libm::F3(lobe_expmuldiv_fast)),
            (Builtin::AcosLo, Mode::Precise) => ("lobe_acoslo_precise", Libm::F1(lobe_acoslo_precise)),
            (Builtin::AcosLo, Mode::Fast) => ("lobe_acoslo_fast", Libm::F1(lobe_acoslo_fast)),
            (Builtin::PowLo, Mode::Precise) => ("lobe_powlo_precise", Libm::F2(lobe_powlo_precise)),
            (Builtin::PowLo, Mode::Fast) => ("lobe_powlo_fast", Libm::F2(lobe_powlo_fast)),
            (Builtin::Sqrt | Builtin::Abs | Builtin::Min | Builtin::Max | Builtin::Clamp | Builtin::Fma, _) => return None,
            (Builtin::Floor | Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne | Builtin::Select, _) => return None,
        })
    }

    /// The one-argument C library function, if that is what this builtin's libm is.
    pub(crate) fn libm1(self) -> Option<extern "C" fn(f64) -> f64> {
        match self.info().libm {
            Libm::F1(f) => Some(f),
            _ => None,
        }
    }
}

impl fmt::Display for Builtin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_rows_are_in_enum_order_and_consistent() {
        for (i, b) in Builtin::ALL.iter().enumerate() {
            let r = &TABLE[i];
            assert_eq!(r.builtin, *b);
            assert_eq!(Builtin::from_name(r.name), Some(*b));
            let inline = matches!(b, Builtin::Sqrt | Builtin::Abs | Builtin::Min | Builtin::Max | Builtin::Clamp | Builtin::Fma);
            assert_eq!(r.lowering == Lowering::Inline, inline, "{}", r.name);
            match r.libm {
                Libm::F1(_) => assert_eq!(r.arity, 1, "{}", r.name),
                Libm::F2(_) => assert_eq!(r.arity, 2, "{}", r.name),
                Libm::F3(_) => assert_eq!(r.arity, 3, "{}", r.name),
                Libm::Exact => assert!(r.lowering != Lowering::Math, "{}", r.name),
            }
            // The library emits exactly the Math and Logic rows; only Math rows have an outlined version.
            let args = vec![0.5; r.arity];
            assert_eq!(b.emit(&mut math::Direct, Mode::Precise, &args).is_some(), !inline, "{}", r.name);
            assert_eq!(b.outlined(Mode::Precise).is_some(), r.lowering == Lowering::Math, "{}", r.name);
            // Only the trigonometric functions fall back to the C library (for huge arguments).
            let trig = matches!(b, Builtin::Sin | Builtin::Cos | Builtin::Tan);
            assert_eq!(!r.symbol.is_empty(), trig, "{}", r.name);
            // Exactly the passes' own builtins are internal, and only they have no shader spelling (an export
            // writes sinnear as sin: `language_form`).
            let internal = matches!(b, Builtin::ExpMulDiv | Builtin::AcosLo | Builtin::PowLo | Builtin::SinNear);
            assert_eq!(b.is_internal(), internal, "{}", r.name);
            assert_eq!(r.glsl.is_empty(), internal, "{}", r.name);
            assert_eq!(r.drjit.is_empty(), internal, "{}", r.name);
            assert_eq!(b.language_form() != *b, *b == Builtin::SinNear, "{}", r.name);
            assert_eq!(Builtin::language().any(|l| l.builtin == *b), !internal, "{}", r.name);
        }
    }

    #[test]
    fn min_max_follow_ieee_2019() {
        assert!(fmin(f64::NAN, 1.0).is_nan());
        assert!(fmax(1.0, f64::NAN).is_nan());
        assert!(fmin(0.0, -0.0).is_sign_negative());
        assert!(fmax(-0.0, 0.0).is_sign_positive());
        assert_eq!(clamp(2.0, 0.0, 1.0), 1.0);
        assert_eq!(clamp(-2.0, 0.0, 1.0), 0.0);
    }

    #[test]
    fn logic_builtins_are_exact() {
        let f = |b: Builtin, a: &[f64]| b.eval(a);
        for (x, want) in [(2.5f64, 2.0f64), (-2.5, -3.0), (-0.0, -0.0), (0.3, 0.0), (-0.3, -1.0), (3.0, 3.0), (-7.0, -7.0), (1e300, 1e300)] {
            assert_eq!(f(Builtin::Floor, &[x]).to_bits(), want.to_bits(), "floor({x})");
        }
        let x = 4503599627370495.5; // 2^52 − 0.5: the largest non-integer
        assert_eq!(f(Builtin::Floor, &[x]), x.floor());
        assert_eq!(f(Builtin::Floor, &[-x]), (-x).floor());
        assert!(f(Builtin::Floor, &[f64::NAN]).is_nan());
        assert_eq!(f(Builtin::Floor, &[f64::NEG_INFINITY]), f64::NEG_INFINITY);
        assert_eq!(f(Builtin::Lt, &[1.0, 2.0]), 1.0);
        assert_eq!(f(Builtin::Lt, &[f64::NAN, 2.0]), 0.0);
        assert_eq!(f(Builtin::Le, &[2.0, 2.0]), 1.0);
        assert_eq!(f(Builtin::Eq, &[-0.0, 0.0]), 1.0);
        assert_eq!(f(Builtin::Ne, &[f64::NAN, f64::NAN]), 1.0);
        // The untaken value, even NaN or infinite, never reaches the result.
        assert_eq!(f(Builtin::Select, &[1.0, 3.0, f64::NAN]), 3.0);
        assert_eq!(f(Builtin::Select, &[0.0, f64::INFINITY, 4.0]), 4.0);
        assert_eq!(f(Builtin::Select, &[-0.0, 1.0, 4.0]), 4.0);
    }

    /// Precise exp passes x·128/ln 2 (any sign, not an integer) to the lookup: the row must be the nearest
    /// integer (ties to even) modulo the table's length, and no input may index outside the table.
    #[test]
    fn table_index_is_the_rounded_value_modulo_the_length() {
        for (x, want) in [(0.0, 0), (5.0, 5), (5.5, 6), (6.5, 6), (127.4, 127), (128.0, 0), (-1.0, 127), (-128.0, 0), (-129.6, 126), (-0.5, 0), (-1.5, 126)] {
            assert_eq!(math::table_index(x, 128), want, "index of {x}");
        }
        for k in -300i32..300 {
            assert_eq!(math::table_index(f64::from(k), 64), k.rem_euclid(64) as usize, "index of {k}");
        }
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300] {
            assert!(math::table_index(x, 64) < 64, "index of {x}");
        }
    }

    #[test]
    fn acos_clamps_its_domain() {
        let one_plus = f64::from_bits(1f64.to_bits() + 1);
        assert_eq!(Builtin::Acos.eval(&[one_plus]), 0.0);
        assert_eq!(Builtin::Acos.eval(&[-1.5]), std::f64::consts::PI);
        assert!(Builtin::Acos.eval(&[f64::NAN]).is_nan());
    }
}
