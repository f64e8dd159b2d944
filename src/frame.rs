//! The shading frame: how a normal N, tangent X, bitangent Y and the directions L and V become a kernel's
//! inputs (`[f64; N_INPUTS]` in [`Input::ALL`] order). Every place that evaluates a formula at geometry —
//! the numerical checks, the sweep, the explorer front end, the renderer — takes its inputs from here, so
//! there is one definition of NH, VR, VH and the direction components.
//!
//! The input formulas are written once over [`Arith`] ([`local_inputs`], [`to_local`]): on `f64` through
//! [`Direct`] they are [`inputs_from_dirs`]; through an IR emitter (`simplify::emit::IrEmit`) they are the
//! same operations as nodes, so a shading program computes bit for bit what the checks compute.
//!
//! Two conventions without directions: [`from_cosines`] (a formula that reads only cosines needs no frame) and
//! [`lobe_inputs`] (the papers' one-angle lobe, `numerics` module docs).

use crate::builtins::dd::Arith;
use crate::builtins::math::Direct;
use crate::ir::{Input, N_INPUTS};

/// A 3-vector.
pub type V3 = [f64; 3];

/// An orthonormal frame: the normal N, the tangent X and the bitangent Y, in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub n: V3,
    pub x: V3,
    pub y: V3,
}

impl Frame {
    /// The local frame, N = +z, X = +x, Y = +y: the frame kernel inputs are expressed in.
    pub const LOCAL: Frame = Frame { n: [0.0, 0.0, 1.0], x: [1.0, 0.0, 0.0], y: [0.0, 1.0, 0.0] };

    /// The frame of unit normal `n` and unit tangent `x` orthogonal to it; Y = N × X.
    pub fn new(n: V3, x: V3) -> Frame {
        let y = [n[1] * x[2] - n[2] * x[1], n[2] * x[0] - n[0] * x[2], n[0] * x[1] - n[1] * x[0]];
        Frame { n, x, y }
    }

    /// World direction `w` in this frame's coordinates (components along X, Y, N). The local frame returns
    /// `w` itself, bit for bit (a dot product with a unit axis would turn −0 into +0).
    pub fn to_local(&self, w: V3) -> V3 {
        if *self == Frame::LOCAL {
            return w;
        }
        to_local(&mut Direct, [self.x, self.y, self.n], w)
    }

    /// The kernel inputs for unit world directions `l` and `v`.
    pub fn inputs(&self, l: V3, v: V3) -> [f64; N_INPUTS] {
        local_inputs(&mut Direct, self.to_local(l), self.to_local(v))
    }
}

/// `a·b`, summed left to right.
pub fn dot<A: Arith>(e: &mut A, a: [A::V; 3], b: [A::V; 3]) -> A::V {
    let p0 = e.mul(a[0], b[0]);
    let p1 = e.mul(a[1], b[1]);
    let s = e.add(p0, p1);
    let p2 = e.mul(a[2], b[2]);
    e.add(s, p2)
}

/// World direction `w` in the frame `[X, Y, N]` (each a world vector): `[w·X, w·Y, w·N]`.
pub fn to_local<A: Arith>(e: &mut A, [x, y, n]: [[A::V; 3]; 3], w: [A::V; 3]) -> [A::V; 3] {
    [dot(e, w, x), dot(e, w, y), dot(e, w, n)]
}

/// Every input from unit L and V given in the local frame (components along X, Y, N): NL = Lz, NV = Vz,
/// H = norm(L + V), NH = Hz, VH = V·H, R = 2(N·L)N − L, VR = V·R, then the components. When V = −L (H
/// undefined, |L + V| = 0) NH and VH are 0.
pub fn local_inputs<A: Arith>(e: &mut A, l: [A::V; 3], v: [A::V; 3]) -> [A::V; N_INPUTS] {
    let (nl, nv) = (l[2], v[2]);
    let h = [e.add(l[0], v[0]), e.add(l[1], v[1]), e.add(l[2], v[2])];
    let hh = dot(e, h, h);
    let hl = e.sqrt(hh);
    let zero = e.konst(0.0);
    let nh = e.div(h[2], hl);
    let nh = e.positive_select(hl, nh, zero);
    let vdh = dot(e, v, h);
    let vh = e.div(vdh, hl);
    let vh = e.positive_select(hl, vh, zero);
    let two = e.konst(2.0);
    let twice = e.mul(two, nl);
    let r = [e.neg(l[0]), e.neg(l[1]), e.sub(twice, l[2])];
    let vr = dot(e, v, r);
    [nl, nv, nh, vr, vh, l[0], l[1], l[2], v[0], v[1], v[2]]
}

/// [`local_inputs`] on `f64`: every input from real geometry in the local frame (N = +z, X = +x, Y = +y),
/// unit L and V.
pub fn inputs_from_dirs(l: V3, v: V3) -> [f64; N_INPUTS] {
    local_inputs(&mut Direct, l, v)
}

/// Kernel inputs from the five cosines alone, directions zero: for formulas that read only cosines.
pub fn from_cosines(c: [f64; 5]) -> [f64; N_INPUTS] {
    let mut x = [0.0; N_INPUTS];
    x[..5].copy_from_slice(&c);
    x
}

/// The inputs for lobe angle `c = cos θ` under the lobe convention (`numerics` module docs); `lobe` is
/// additionally set to `c` (a no-op for NH, VR and NV).
///
/// The directions are L = N and V at angle θ = acos c in the x–z plane, so NV = VR = c as the cosines say.
pub fn lobe_inputs(c: f64, lobe: Input) -> [f64; N_INPUTS] {
    let s = (1.0 - c * c).max(0.0).sqrt();
    let mut x = [1.0, c, c, c, (0.5 * (1.0 + c)).max(0.0).sqrt(), 0.0, 0.0, 1.0, s, 0.0, c];
    x[lobe.index()] = c;
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition before it was written over `Arith`: the generic one must give its bits.
    fn reference(l: V3, v: V3) -> [f64; N_INPUTS] {
        let d = |a: V3, b: V3| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (nl, nv) = (l[2], v[2]);
        let h = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
        let hl = d(h, h).sqrt();
        let (nh, vh) = if hl > 0.0 { (h[2] / hl, d(v, h) / hl) } else { (0.0, 0.0) };
        let r = [-l[0], -l[1], 2.0 * nl - l[2]];
        [nl, nv, nh, d(v, r), vh, l[0], l[1], l[2], v[0], v[1], v[2]]
    }

    #[test]
    fn generic_inputs_keep_the_bits() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut cases = vec![([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]), ([-0.0, 0.0, 1.0], [0.0, -0.0, 1.0]), ([1e-200, 0.0, 0.0], [-1e-200, 0.0, 0.0])];
        cases.extend((0..2000).map(|_| ([next(), next(), next()], [next(), next(), next()])));
        for (l, v) in cases {
            let (a, b) = (inputs_from_dirs(l, v), reference(l, v));
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{l:?} {v:?}");
            assert_eq!(Frame::LOCAL.inputs(l, v).map(f64::to_bits), b.map(f64::to_bits));
        }
    }

    #[test]
    fn a_rotated_frame_sees_the_same_cosines() {
        // N = +x, X = +y, so Y = N × X = +z; L and V rotated alike.
        let f = Frame::new([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(f.y, [0.0, 0.0, 1.0]);
        let (l, v) = ([0.6, 0.0, 0.8], [0.0, 0.6, 0.8]);
        let (lw, vw) = ([l[2], l[0], l[1]], [v[2], v[0], v[1]]);
        let (a, b) = (f.inputs(lw, vw), inputs_from_dirs(l, v));
        for i in 0..N_INPUTS {
            assert!((a[i] - b[i]).abs() < 1e-15, "{i}: {} vs {}", a[i], b[i]);
        }
    }
}
