//! The one table of builtin functions.
//!
//! Every backend reads this table and nothing else: the front end checks names and arity against it, the
//! interpreter calls [`Builtin::eval`], the JIT either emits the native instruction ([`Lowering::Inline`]) or
//! calls the very same `extern "C"` Rust function the interpreter uses ([`Lowering::Call`], registered with
//! Cranelift under [`BuiltinInfo::symbol`]), and the GLSL export prints [`BuiltinInfo::glsl`]. Because the
//! interpreter and the JIT call the same function for transcendental builtins, they agree bit for bit there;
//! inline operations (sqrt, abs, min, max, clamp) are defined here with exactly Cranelift's semantics.
//!
//! Domain policy: `acos` and `asin` clamp their argument to [−1, 1] (a cosine computed from rounded vectors can
//! be 1 + 1 ulp, and acos of it must not be NaN). Everything else is plain IEEE/libm.

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
}

/// How the JIT lowers a builtin.
#[derive(Clone, Copy, Debug)]
pub enum Lowering {
    /// A native instruction (sqrt, fabs, fmin, fmax); the Rust function is its exact model.
    Inline,
    /// A call to an `extern "C"` function of one argument.
    Call1(extern "C" fn(f64) -> f64),
    /// A call to an `extern "C"` function of two arguments.
    Call2(extern "C" fn(f64, f64) -> f64),
}

/// One row of the table.
#[derive(Clone, Copy, Debug)]
pub struct BuiltinInfo {
    pub builtin: Builtin,
    /// Name in the .brdf language.
    pub name: &'static str,
    pub arity: usize,
    /// Symbol name the JIT registers for `Lowering::Call*`.
    pub symbol: &'static str,
    pub lowering: Lowering,
    /// GLSL spelling; `{0}`, `{1}`, `{2}` are the arguments.
    pub glsl: &'static str,
    /// One line for `lobe help` and hints.
    pub doc: &'static str,
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

/// IEEE 754-2019 `minimum`: NaN if either is NaN, −0 < +0. This is Cranelift's `fmin`.
pub fn fmin(a: f64, b: f64) -> f64 {
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
pub fn fmax(a: f64, b: f64) -> f64 {
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
pub fn clamp(x: f64, lo: f64, hi: f64) -> f64 {
    fmin(fmax(x, lo), hi)
}

const TABLE: [BuiltinInfo; 14] = [
    BuiltinInfo {
        builtin: Builtin::Pow,
        name: "pow",
        arity: 2,
        symbol: "lobe_pow",
        lowering: Lowering::Call2(lobe_pow),
        glsl: "pow({0}, {1})",
        doc: "pow(x, y) = x^y; integer constant exponents become multiplications",
    },
    BuiltinInfo {
        builtin: Builtin::Cos,
        name: "cos",
        arity: 1,
        symbol: "lobe_cos",
        lowering: Lowering::Call1(lobe_cos),
        glsl: "cos({0})",
        doc: "cosine of an angle in radians",
    },
    BuiltinInfo {
        builtin: Builtin::Sin,
        name: "sin",
        arity: 1,
        symbol: "lobe_sin",
        lowering: Lowering::Call1(lobe_sin),
        glsl: "sin({0})",
        doc: "sine of an angle in radians",
    },
    BuiltinInfo {
        builtin: Builtin::Tan,
        name: "tan",
        arity: 1,
        symbol: "lobe_tan",
        lowering: Lowering::Call1(lobe_tan),
        glsl: "tan({0})",
        doc: "tangent of an angle in radians",
    },
    BuiltinInfo {
        builtin: Builtin::Acos,
        name: "acos",
        arity: 1,
        symbol: "lobe_acos",
        lowering: Lowering::Call1(lobe_acos),
        glsl: "acos(clamp({0}, -1.0, 1.0))",
        doc: "arc cosine in radians; the argument is clamped to [-1, 1]",
    },
    BuiltinInfo {
        builtin: Builtin::Asin,
        name: "asin",
        arity: 1,
        symbol: "lobe_asin",
        lowering: Lowering::Call1(lobe_asin),
        glsl: "asin(clamp({0}, -1.0, 1.0))",
        doc: "arc sine in radians; the argument is clamped to [-1, 1]",
    },
    BuiltinInfo {
        builtin: Builtin::Atan,
        name: "atan",
        arity: 1,
        symbol: "lobe_atan",
        lowering: Lowering::Call1(lobe_atan),
        glsl: "atan({0})",
        doc: "arc tangent in radians",
    },
    BuiltinInfo {
        builtin: Builtin::Exp,
        name: "exp",
        arity: 1,
        symbol: "lobe_exp",
        lowering: Lowering::Call1(lobe_exp),
        glsl: "exp({0})",
        doc: "e^x",
    },
    BuiltinInfo {
        builtin: Builtin::Ln,
        name: "ln",
        arity: 1,
        symbol: "lobe_ln",
        lowering: Lowering::Call1(lobe_ln),
        glsl: "log({0})",
        doc: "natural logarithm",
    },
    BuiltinInfo {
        builtin: Builtin::Sqrt,
        name: "sqrt",
        arity: 1,
        symbol: "",
        lowering: Lowering::Inline,
        glsl: "sqrt({0})",
        doc: "square root (NaN below 0)",
    },
    BuiltinInfo {
        builtin: Builtin::Abs,
        name: "abs",
        arity: 1,
        symbol: "",
        lowering: Lowering::Inline,
        glsl: "abs({0})",
        doc: "absolute value",
    },
    BuiltinInfo {
        builtin: Builtin::Min,
        name: "min",
        arity: 2,
        symbol: "",
        lowering: Lowering::Inline,
        glsl: "min({0}, {1})",
        doc: "smaller of two values (NaN if either is NaN)",
    },
    BuiltinInfo {
        builtin: Builtin::Max,
        name: "max",
        arity: 2,
        symbol: "",
        lowering: Lowering::Inline,
        glsl: "max({0}, {1})",
        doc: "larger of two values (NaN if either is NaN)",
    },
    BuiltinInfo {
        builtin: Builtin::Clamp,
        name: "clamp",
        arity: 3,
        symbol: "",
        lowering: Lowering::Inline,
        glsl: "clamp({0}, {1}, {2})",
        doc: "clamp(x, lo, hi) = min(max(x, lo), hi)",
    },
];

impl Builtin {
    pub const ALL: [Builtin; 14] = [
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

    pub fn from_name(name: &str) -> Option<Builtin> {
        TABLE.iter().find(|r| r.name == name).map(|r| r.builtin)
    }

    /// All rows of the table.
    pub fn table() -> &'static [BuiltinInfo] {
        &TABLE
    }

    /// Reference semantics; `args` has exactly `arity()` values.
    pub fn eval(self, args: &[f64]) -> f64 {
        match self.info().lowering {
            Lowering::Call1(f) => f(args[0]),
            Lowering::Call2(f) => f(args[0], args[1]),
            Lowering::Inline => match self {
                Builtin::Sqrt => args[0].sqrt(),
                Builtin::Abs => args[0].abs(),
                Builtin::Min => fmin(args[0], args[1]),
                Builtin::Max => fmax(args[0], args[1]),
                Builtin::Clamp => clamp(args[0], args[1], args[2]),
                // Every other builtin has a Call lowering; the table test below enforces it.
                _ => f64::NAN,
            },
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
            match r.lowering {
                Lowering::Call1(_) => assert_eq!(r.arity, 1, "{}", r.name),
                Lowering::Call2(_) => assert_eq!(r.arity, 2, "{}", r.name),
                Lowering::Inline => {
                    assert!(matches!(b, Builtin::Sqrt | Builtin::Abs | Builtin::Min | Builtin::Max | Builtin::Clamp))
                }
            }
            assert_eq!(r.symbol.is_empty(), matches!(r.lowering, Lowering::Inline));
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
    fn acos_clamps_its_domain() {
        let one_plus = f64::from_bits(1f64.to_bits() + 1);
        assert_eq!(Builtin::Acos.eval(&[one_plus]), 0.0);
        assert_eq!(Builtin::Acos.eval(&[-1.5]), std::f64::consts::PI);
        assert!(Builtin::Acos.eval(&[f64::NAN]).is_nan());
    }
}
