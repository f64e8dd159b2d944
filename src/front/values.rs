//! Typed values over the scalar IR: what both front ends (lobe's language and the BRDF Explorer importer) lower
//! vectors, booleans and the derived functions into.
//!
//! Design: the IR stays scalar (one f64 per node, one builtins table). A `vec3` is three nodes, a bool one node
//! holding 0 or 1, and every vector operation is expanded here into scalar nodes, so the interpreter, the JIT,
//! the checks and the shader exports need nothing new. The shading frame is the local one: N = (0, 0, 1),
//! X = (1, 0, 0), Y = (0, 1, 0) are constants and L, V are the six direction inputs, so `dot(N, L)` becomes the
//! single input `Lz` and a formula reads only the components it uses (the renderer computes nothing else).
//!
//! Folding here is structural, not numerical: a product with an exact constant 0 coming from a frame vector is
//! dropped when the other factor is a direction component or a finite constant (both finite by construction),
//! and products by 1 and sums with +0 are dropped. Nothing else is rewritten; the simplifier does the rest under
//! its IEEE policy. Cost: O(1) nodes per operation; `normalize` is a dot, a sqrt and three divisions.

use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::frame::Frame;
use crate::ir::{BinOp, Input, Ir, Node, NodeId};

/// A typed value: a float, a bool (a node that is 0 or 1), or a 3-vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Val {
    F(NodeId),
    B(NodeId),
    V([NodeId; 3]),
}

/// The type of a [`Val`], for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Ty {
    Float,
    Bool,
    Vec3,
}

impl Ty {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Ty::Float => "float",
            Ty::Bool => "bool",
            Ty::Vec3 => "vec3",
        }
    }
}

impl Val {
    pub(crate) fn ty(self) -> Ty {
        match self {
            Val::F(_) => Ty::Float,
            Val::B(_) => Ty::Bool,
            Val::V(_) => Ty::Vec3,
        }
    }
}

/// Comparison operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cmp {
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
}

impl Cmp {
    pub(crate) fn symbol(self) -> &'static str {
        match self {
            Cmp::Lt => "<",
            Cmp::Le => "<=",
            Cmp::Gt => ">",
            Cmp::Ge => ">=",
            Cmp::Eq => "==",
            Cmp::Ne => "!=",
        }
    }
}

/// Functions beyond the builtins table that both languages accept, expanded here. Each is `(name, arity, doc)`.
pub(crate) const DERIVED: [(&str, usize, &str); 14] = [
    ("dot", 2, "dot(a, b): dot product of two vec3"),
    ("cross", 2, "cross(a, b): cross product of two vec3"),
    ("length", 1, "length(v): Euclidean length of a vec3 (|x| of a float)"),
    ("normalize", 1, "normalize(v) = v / length(v)"),
    ("reflect", 2, "reflect(I, N) = I − 2·dot(N, I)·N"),
    ("distance", 2, "distance(a, b) = length(a − b)"),
    ("mix", 3, "mix(a, b, t) = a·(1 − t) + b·t"),
    ("smoothstep", 3, "smoothstep(e0, e1, x): 0 below e0, 1 above e1, t²(3 − 2t) between"),
    ("step", 2, "step(edge, x) = 0 if x < edge, else 1"),
    ("sign", 1, "sign(x): −1, 0 or 1"),
    ("fract", 1, "fract(x) = x − floor(x)"),
    ("vec3", 3, "vec3(x, y, z), or vec3(s) for (s, s, s)"),
    ("radians", 1, "degrees to radians"),
    ("degrees", 1, "radians to degrees"),
];

/// Builds typed values into an IR arena; every node gets `span`.
pub struct Values<'a> {
    pub ir: &'a mut Ir,
    pub span: Span,
}

type R = Result<Val, String>;

impl<'a> Values<'a> {
    pub fn new(ir: &'a mut Ir, span: Span) -> Values<'a> {
        Values { ir, span }
    }

    pub(crate) fn konst(&mut self, v: f64) -> NodeId {
        self.ir.konst(v, self.span)
    }

    pub fn num(&mut self, v: f64) -> Val {
        Val::F(self.konst(v))
    }

    /// A bool constant.
    pub(crate) fn boolean(&mut self, b: bool) -> Val {
        Val::B(self.konst(if b { 1.0 } else { 0.0 }))
    }

    /// The frame vectors by name: L and V (direction inputs), N, X, Y (constants of the local frame).
    pub fn frame(&mut self, name: &str) -> Option<Val> {
        let k = |s: &mut Self, v: [f64; 3]| Val::V(v.map(|c| s.konst(c)));
        Some(match name {
            "L" => Val::V([Input::Lx, Input::Ly, Input::Lz].map(|i| self.ir.input(i, self.span))),
            "V" => Val::V([Input::Vx, Input::Vy, Input::Vz].map(|i| self.ir.input(i, self.span))),
            "N" => k(self, Frame::LOCAL.n),
            "X" => k(self, Frame::LOCAL.x),
            "Y" => k(self, Frame::LOCAL.y),
            _ => return None,
        })
    }

    fn const_of(&self, a: NodeId) -> Option<f64> {
        self.ir.node(a).as_const()
    }

    /// Whether `a` is finite by construction: a finite constant or a direction component.
    fn finite(&self, a: NodeId) -> bool {
        match self.ir.node(a) {
            Node::Const(b) => f64::from_bits(*b).is_finite(),
            Node::Input(i) => i.is_direction(),
            _ => false,
        }
    }

    fn is_exact(&self, a: NodeId, v: f64) -> bool {
        self.const_of(a).is_some_and(|c| c.to_bits() == v.to_bits())
    }

    /// One scalar operation, with the structural folds of the module docs.
    pub(crate) fn bin(&mut self, op: BinOp, a: NodeId, b: NodeId) -> NodeId {
        match op {
            BinOp::Mul => {
                if self.is_exact(a, 1.0) {
                    return b;
                }
                if self.is_exact(b, 1.0) {
                    return a;
                }
                let zero = |s: &Self, z: NodeId, o: NodeId| s.const_of(z) == Some(0.0) && s.finite(o);
                if zero(self, a, b) || zero(self, b, a) {
                    return self.konst(0.0);
                }
            }
            BinOp::Add => {
                if self.is_exact(a, 0.0) {
                    return b;
                }
                if self.is_exact(b, 0.0) {
                    return a;
                }
            }
            BinOp::Sub if self.is_exact(b, 0.0) => return a,
            BinOp::Div if self.is_exact(b, 1.0) => return a,
            _ => {}
        }
        if let (Some(x), Some(y)) = (self.const_of(a), self.const_of(b)) {
            return self.konst(op.apply(x, y));
        }
        self.ir.bin(op, a, b, self.span)
    }

    pub(crate) fn call(&mut self, f: Builtin, args: &[NodeId]) -> NodeId {
        if args.iter().all(|a| self.const_of(*a).is_some()) {
            let v: Vec<f64> = args.iter().map(|a| self.const_of(*a).unwrap_or(f64::NAN)).collect();
            return self.konst(f.eval(&v));
        }
        self.ir.call(f, args, self.span)
    }

    fn neg_node(&mut self, a: NodeId) -> NodeId {
        match self.const_of(a) {
            Some(c) => self.konst(-c),
            None => self.ir.neg(a, self.span),
        }
    }

    /// `a op b` on floats and vectors, a float broadcast against a vector (GLSL's rule).
    pub fn arith(&mut self, op: BinOp, a: Val, b: Val) -> R {
        Ok(match (a, b) {
            (Val::F(x), Val::F(y)) => Val::F(self.bin(op, x, y)),
            (Val::V(x), Val::V(y)) => Val::V([0, 1, 2].map(|k| self.bin(op, x[k], y[k]))),
            (Val::V(x), Val::F(y)) => Val::V(x.map(|c| self.bin(op, c, y))),
            (Val::F(x), Val::V(y)) => Val::V(y.map(|c| self.bin(op, x, c))),
            _ => {
                return Err(format!(
                    "`{}` needs numbers or vectors, not {} and {}",
                    op.symbol(),
                    a.ty().name(),
                    b.ty().name()
                ))
            }
        })
    }

    pub fn neg(&mut self, a: Val) -> R {
        Ok(match a {
            Val::F(x) => Val::F(self.neg_node(x)),
            Val::V(v) => Val::V(v.map(|c| self.neg_node(c))),
            Val::B(_) => return Err("`-` needs a number or a vector, not a bool".into()),
        })
    }

    fn vector(&self, a: Val, what: &str) -> Result<[NodeId; 3], String> {
        match a {
            Val::V(v) => Ok(v),
            _ => Err(format!("{what} needs a vec3, not {}", a.ty().name())),
        }
    }

    pub(crate) fn boolean_of(&self, a: Val, what: &str) -> Result<NodeId, String> {
        match a {
            Val::B(x) => Ok(x),
            _ => Err(format!("{what} needs a bool, not {}", a.ty().name())),
        }
    }

    /// Component `k` (0, 1, 2: x/r, y/g, z/b) of a vector.
    pub fn component(&mut self, a: Val, k: usize) -> R {
        let v = self.vector(a, "a component")?;
        v.get(k).map(|c| Val::F(*c)).ok_or_else(|| format!("component {k} is out of range (a vec3 has 0, 1, 2)"))
    }

    pub fn dot(&mut self, a: Val, b: Val) -> R {
        let (x, y) = (self.vector(a, "dot")?, self.vector(b, "dot")?);
        Ok(Val::F(self.dot3(x, y)))
    }

    /// A dot product; a component that is the constant 0 in either vector contributes nothing, so a dot with a
    /// frame axis (N, X, Y) reads one component: `dot(N, H)` is `H.z` even where H's other components are not
    /// finite (L = −V), which IEEE's `0·inf` would turn into NaN. Only then do the two differ.
    fn dot3(&mut self, x: [NodeId; 3], y: [NodeId; 3]) -> NodeId {
        let zero = |s: &Self, a: NodeId| s.const_of(a) == Some(0.0);
        let terms: Vec<usize> = (0..3).filter(|&k| !zero(self, x[k]) && !zero(self, y[k])).collect();
        let mut acc: Option<NodeId> = None;
        for k in terms {
            let p = self.bin(BinOp::Mul, x[k], y[k]);
            acc = Some(match acc {
                None => p,
                Some(a) => self.bin(BinOp::Add, a, p),
            });
        }
        acc.unwrap_or_else(|| self.konst(0.0))
    }

    pub(crate) fn cross(&mut self, a: Val, b: Val) -> R {
        let (x, y) = (self.vector(a, "cross")?, self.vector(b, "cross")?);
        let mut c = |i: usize, j: usize| {
            let p = self.bin(BinOp::Mul, x[i], y[j]);
            let q = self.bin(BinOp::Mul, x[j], y[i]);
            self.bin(BinOp::Sub, p, q)
        };
        Ok(Val::V([c(1, 2), c(2, 0), c(0, 1)]))
    }

    pub(crate) fn length(&mut self, a: Val) -> R {
        Ok(match a {
            Val::F(x) => Val::F(self.call(Builtin::Abs, &[x])),
            Val::V(v) => {
                let d = self.dot3(v, v);
                Val::F(self.call(Builtin::Sqrt, &[d]))
            }
            Val::B(_) => return Err("length needs a vec3, not bool".into()),
        })
    }

    pub fn normalize(&mut self, a: Val) -> R {
        let v = self.vector(a, "normalize")?;
        let Val::F(len) = self.length(a)? else { unreachable!("length is a float") };
        Ok(Val::V(v.map(|c| self.bin(BinOp::Div, c, len))))
    }

    /// GLSL's `reflect(I, N) = I − 2·dot(N, I)·N`.
    pub(crate) fn reflect(&mut self, i: Val, n: Val) -> R {
        let d = self.dot(n, i)?;
        let two = self.num(2.0);
        let k = self.arith(BinOp::Mul, two, d)?;
        let kn = self.arith(BinOp::Mul, k, n)?;
        self.arith(BinOp::Sub, i, kn)
    }

    /// A comparison of two floats, as a bool.
    pub fn compare(&mut self, op: Cmp, a: Val, b: Val) -> R {
        let sym = op.symbol();
        let (x, y) = match (a, b) {
            (Val::F(x), Val::F(y)) | (Val::B(x), Val::B(y)) if matches!(op, Cmp::Eq | Cmp::Ne) => (x, y),
            (Val::F(x), Val::F(y)) => (x, y),
            _ => return Err(format!("`{sym}` compares two floats, not {} and {}", a.ty().name(), b.ty().name())),
        };
        let (f, l, r) = match op {
            Cmp::Lt => (Builtin::Lt, x, y),
            Cmp::Le => (Builtin::Le, x, y),
            Cmp::Gt => (Builtin::Lt, y, x),
            Cmp::Ge => (Builtin::Le, y, x),
            Cmp::Eq => (Builtin::Eq, x, y),
            Cmp::Ne => (Builtin::Ne, x, y),
        };
        Ok(Val::B(self.call(f, &[l, r])))
    }

    pub(crate) fn not(&mut self, a: Val) -> R {
        let x = self.boolean_of(a, "`!`")?;
        let zero = self.konst(0.0);
        Ok(Val::B(self.call(Builtin::Eq, &[x, zero])))
    }

    /// `a && b`: a select, so `b` is false wherever `a` is (b's value there is never read).
    pub fn and(&mut self, a: Val, b: Val) -> R {
        let (x, y) = (self.boolean_of(a, "`&&`")?, self.boolean_of(b, "`&&`")?);
        let zero = self.konst(0.0);
        Ok(Val::B(self.call(Builtin::Select, &[x, y, zero])))
    }

    pub(crate) fn or(&mut self, a: Val, b: Val) -> R {
        let (x, y) = (self.boolean_of(a, "`||`")?, self.boolean_of(b, "`||`")?);
        let one = self.konst(1.0);
        Ok(Val::B(self.call(Builtin::Select, &[x, one, y])))
    }

    /// `c ? a : b` for values of one type (component by component for vectors).
    pub fn select(&mut self, c: Val, a: Val, b: Val) -> R {
        let c = self.boolean_of(c, "a condition")?;
        if let Some(k) = self.const_of(c) {
            return Ok(if k != 0.0 { a } else { b });
        }
        let mut sel = |x: NodeId, y: NodeId| if x == y { x } else { self.call(Builtin::Select, &[c, x, y]) };
        Ok(match (a, b) {
            (Val::F(x), Val::F(y)) => Val::F(sel(x, y)),
            (Val::B(x), Val::B(y)) => Val::B(sel(x, y)),
            (Val::V(x), Val::V(y)) => Val::V([0, 1, 2].map(|k| sel(x[k], y[k]))),
            _ => return Err(format!("both branches must have one type, not {} and {}", a.ty().name(), b.ty().name())),
        })
    }

    /// A scalar builtin applied to floats, or component by component when any argument is a vector (a float
    /// argument is then used for every component, as GLSL's `min(vec3, float)`).
    pub fn builtin(&mut self, f: Builtin, args: &[Val]) -> R {
        self.each(f.name(), args, &mut |s, xs| s.call(f, xs))
    }

    /// Applies the scalar function `f` (named `name` in messages) to floats, or component by component when any
    /// argument is a vector.
    fn each(&mut self, name: &str, args: &[Val], f: &mut dyn FnMut(&mut Self, &[NodeId]) -> NodeId) -> R {
        if args.iter().any(|a| matches!(a, Val::B(_))) {
            return Err(format!("`{name}` needs numbers or vectors, not bool"));
        }
        let comp = |a: &Val, k: usize| match a {
            Val::V(v) => v[k],
            Val::F(x) | Val::B(x) => *x,
        };
        if !args.iter().any(|a| matches!(a, Val::V(_))) {
            let xs: Vec<NodeId> = args.iter().map(|a| comp(a, 0)).collect();
            return Ok(Val::F(f(self, &xs)));
        }
        let mut out = [NodeId(0); 3];
        for (k, o) in out.iter_mut().enumerate() {
            let xs: Vec<NodeId> = args.iter().map(|a| comp(a, k)).collect();
            *o = f(self, &xs);
        }
        Ok(Val::V(out))
    }

    /// A function by name: a builtin of the language (applied per component to vectors) or one of [`DERIVED`].
    /// `None` when the name is neither, as for an internal builtin ([`Builtin::is_internal`]: not a function of
    /// either language); `Some(Err)` for a wrong argument count or type.
    pub fn function(&mut self, name: &str, args: &[Val]) -> Option<R> {
        if let Some(b) = Builtin::from_name(name).filter(|b| !b.is_internal()) {
            if args.len() != b.arity() {
                return Some(Err(format!("`{name}` takes {} argument(s), got {}", b.arity(), args.len())));
            }
            return Some(self.builtin(b, args));
        }
        let &(_, arity, _) = DERIVED.iter().find(|d| d.0 == name)?;
        if name == "vec3" {
            return Some(match args {
                [Val::F(s)] => Ok(Val::V([*s; 3])),
                [Val::V(v)] => Ok(Val::V(*v)),
                [Val::F(x), Val::F(y), Val::F(z)] => Ok(Val::V([*x, *y, *z])),
                _ => Err("vec3 takes one float, one vec3, or three floats".into()),
            });
        }
        if args.len() != arity {
            return Some(Err(format!("`{name}` takes {arity} argument(s), got {}", args.len())));
        }
        let (a, b) = (args[0], args.get(1).copied().unwrap_or(args[0]));
        Some(match name {
            "dot" => self.dot(a, b),
            "cross" => self.cross(a, b),
            "length" => self.length(a),
            "normalize" => self.normalize(a),
            "reflect" => self.reflect(a, b),
            "distance" => self.arith(BinOp::Sub, a, b).and_then(|d| self.length(d)),
            // GLSL's definition: x·(1 − a) + y·a.
            "mix" => self.each(name, args, &mut |s, x| {
                let one = s.konst(1.0);
                let w = s.bin(BinOp::Sub, one, x[2]);
                let p = s.bin(BinOp::Mul, x[0], w);
                let q = s.bin(BinOp::Mul, x[1], x[2]);
                s.bin(BinOp::Add, p, q)
            }),
            "smoothstep" => self.each(name, args, &mut |s, x| {
                let num = s.bin(BinOp::Sub, x[2], x[0]);
                let den = s.bin(BinOp::Sub, x[1], x[0]);
                let q = s.bin(BinOp::Div, num, den);
                let (zero, one) = (s.konst(0.0), s.konst(1.0));
                let t = s.call(Builtin::Clamp, &[q, zero, one]);
                let two = s.konst(2.0);
                let three = s.konst(3.0);
                let tt = s.bin(BinOp::Mul, t, t);
                let t2 = s.bin(BinOp::Mul, two, t);
                let w = s.bin(BinOp::Sub, three, t2);
                s.bin(BinOp::Mul, tt, w)
            }),
            "step" => self.each(name, args, &mut |s, x| {
                let below = s.call(Builtin::Lt, &[x[1], x[0]]);
                let (zero, one) = (s.konst(0.0), s.konst(1.0));
                s.call(Builtin::Select, &[below, zero, one])
            }),
            "sign" => self.each(name, args, &mut |s, x| {
                let zero = s.konst(0.0);
                let pos = s.call(Builtin::Lt, &[zero, x[0]]);
                let neg = s.call(Builtin::Lt, &[x[0], zero]);
                s.bin(BinOp::Sub, pos, neg)
            }),
            "fract" => self.each(name, args, &mut |s, x| {
                let f = s.call(Builtin::Floor, &[x[0]]);
                s.bin(BinOp::Sub, x[0], f)
            }),
            "radians" => self.each(name, args, &mut |s, x| {
                let k = s.konst(std::f64::consts::PI / 180.0);
                s.bin(BinOp::Mul, x[0], k)
            }),
            "degrees" => self.each(name, args, &mut |s, x| {
                let k = s.konst(180.0 / std::f64::consts::PI);
                s.bin(BinOp::Mul, x[0], k)
            }),
            _ => Err(format!("internal: derived function `{name}` has no expansion")),
        })
    }

    /// The named shorthands of the cosine language beyond its inputs, from the direction inputs: LV, HX, HY,
    /// LX, LY, VX, VY (H = normalize(L + V)). `None` for other names.
    pub(crate) fn shorthand(&mut self, name: &str) -> Option<Val> {
        let l = self.frame("L")?;
        let v = self.frame("V")?;
        let h = |s: &mut Self| {
            let sum = s.arith(BinOp::Add, l, v).ok()?;
            s.normalize(sum).ok()
        };
        let comp = |s: &mut Self, a: Val, k: usize| s.component(a, k).ok();
        match name {
            "LV" => self.dot(l, v).ok(),
            "HX" => {
                let hv = h(self)?;
                comp(self, hv, 0)
            }
            "HY" => {
                let hv = h(self)?;
                comp(self, hv, 1)
            }
            "LX" => comp(self, l, 0),
            "LY" => comp(self, l, 1),
            "VX" => comp(self, v, 0),
            "VY" => comp(self, v, 1),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::interp::Interp;
    use crate::backend::Evaluator;
    use crate::ir::{Formula, Meta, ParamDecl};

    fn eval(ir: Ir, root: NodeId, l: [f64; 3], v: [f64; 3]) -> f64 {
        let f = Formula {
            meta: Meta::default(),
            params: vec![ParamDecl::float("n", 1.0, 1.0, 1.0)],
            ir,
            root,
            file: "t".into(),
            source: String::new(),
            rgb: None,
        };
        Interp::new(&f).eval(&crate::numerics::inputs_from_dirs(l, v), &[1.0])
    }

    #[test]
    fn frame_dots_read_single_components() {
        let mut ir = Ir::new();
        let mut b = Values::new(&mut ir, Span::default());
        let (n, l) = (b.frame("N").unwrap(), b.frame("L").unwrap());
        let Val::F(d) = b.dot(n, l).unwrap() else { panic!() };
        assert_eq!(*ir.node(d), Node::Input(Input::Lz));
    }

    #[test]
    fn half_vector_and_reflection_match_the_cosine_inputs() {
        let l = crate::numerics::dir(0.4, 0.3);
        let v = crate::numerics::dir(1.1, 2.0);
        let want = crate::numerics::inputs_from_dirs(l, v);
        // NH from normalize(L + V), VR from reflect(−L, N).
        let mut ir = Ir::new();
        let mut b = Values::new(&mut ir, Span::default());
        let (lv, vv, nv) = (b.frame("L").unwrap(), b.frame("V").unwrap(), b.frame("N").unwrap());
        let sum = b.arith(BinOp::Add, lv, vv).unwrap();
        let h = b.normalize(sum).unwrap();
        let Val::F(nh) = b.dot(nv, h).unwrap() else { panic!() };
        let ml = b.neg(lv).unwrap();
        let r = b.reflect(ml, nv).unwrap();
        let Val::F(vr) = b.dot(vv, r).unwrap() else { panic!() };
        let ir2 = ir.clone();
        assert!((eval(ir, nh, l, v) - want[Input::NH.index()]).abs() < 1e-15);
        assert!((eval(ir2, vr, l, v) - want[Input::VR.index()]).abs() < 1e-15);
    }

    #[test]
    fn select_keeps_the_untaken_branch_out() {
        let mut ir = Ir::new();
        let mut b = Values::new(&mut ir, Span::default());
        let l = b.frame("L").unwrap();
        let Val::F(lz) = b.component(l, 2).unwrap() else { panic!() };
        let zero = b.num(0.0);
        let c = b.compare(Cmp::Gt, Val::F(lz), zero).unwrap();
        let one = b.num(1.0);
        let inv = b.arith(BinOp::Div, one, zero).unwrap(); // +inf, folded
        let Val::F(r) = b.select(c, Val::F(lz), inv).unwrap() else { panic!() };
        assert_eq!(eval(ir.clone(), r, [0.0, 0.6, 0.8], [0.0, 0.0, 1.0]), 0.8);
        assert_eq!(eval(ir, r, [0.0, 1.0, -0.0], [0.0, 0.0, 1.0]), f64::INFINITY);
    }

    #[test]
    fn derived_functions_follow_glsl() {
        let mut ir = Ir::new();
        let mut b = Values::new(&mut ir, Span::default());
        let mut f = |name: &str, xs: &[f64]| {
            let args: Vec<Val> = xs.iter().map(|x| b.num(*x)).collect();
            let Val::F(r) = b.function(name, &args).unwrap().unwrap() else { panic!() };
            b.const_of(r).unwrap()
        };
        assert_eq!(f("mix", &[2.0, 4.0, 0.25]), 2.5);
        assert_eq!(f("smoothstep", &[0.0, 1.0, 0.5]), 0.5);
        assert_eq!(f("smoothstep", &[0.0, 1.0, 2.0]), 1.0);
        assert_eq!(f("step", &[0.5, 0.5]), 1.0);
        assert_eq!(f("step", &[0.5, 0.4]), 0.0);
        assert_eq!(f("sign", &[-3.0]), -1.0);
        assert_eq!(f("sign", &[0.0]), 0.0);
        assert_eq!(f("fract", &[-1.25]), 0.75);
    }
}
