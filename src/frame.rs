//! The shading frame: how a normal N, tangent X, bitangent Y and the directions L and V become a kernel's
//! inputs (`[f64; N_INPUTS]` in [`Input::ALL`] order). Every place that evaluates a formula at geometry —
//! the numerical checks, the sweep, the explorer front end, the renderer — takes its inputs from here, so
//! there is one definition of NH, VR, VH and the direction components.
//!
//! The input formulas are written once over [`Arith`], in two entries: the local one ([`local_inputs`],
//! [`to_local`]) from unit directions, which on `f64` through [`Direct`] is [`inputs_from_dirs`]; and the
//! world-space one ([`world_view`], [`world_axes`], [`world_light_inputs`]) from interpolated vectors that need
//! not be unit, which the renderer's shading program writes as IR nodes (`render::program`) and which agrees
//! with the local one to rounding (tested).
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
pub(crate) fn to_local<A: Arith>(e: &mut A, [x, y, n]: [[A::V; 3]; 3], w: [A::V; 3]) -> [A::V; 3] {
    [dot(e, w, x), dot(e, w, y), dot(e, w, n)]
}

/// Every input from unit L and V given in the local frame (components along X, Y, N): NL = Lz, NV = Vz,
/// H = norm(L + V), NH = Hz, VH = V·H, R = 2(N·L)N − L, VR = V·R, then the components. When V = −L (H
/// undefined, |L + V| = 0) NH and VH are 0.
pub(crate) fn local_inputs<A: Arith>(e: &mut A, l: [A::V; 3], v: [A::V; 3]) -> [A::V; N_INPUTS] {
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

/// What the world-space entry needs beyond [`Arith`]: `a < b ? x : y` (both computed; `y` where either is NaN).
pub trait Compare: Arith {
    fn less_select(&mut self, a: Self::V, b: Self::V, x: Self::V, y: Self::V) -> Self::V;
}

impl Compare for Direct {
    fn less_select(&mut self, a: f64, b: f64, x: f64, y: f64) -> f64 {
        if a < b { x } else { y }
    }
}

/// `1/√x`.
pub(crate) fn inv_len<A: Arith>(e: &mut A, x: A::V) -> A::V {
    let one = e.konst(1.0);
    let r = e.sqrt(x);
    e.div(one, r)
}

/// The view at a surface point in world space (the renderer's entry: interpolated vectors, not unit): the
/// normal `n` and the view vector `v` (eye − point), their inverse lengths and NV = (n·v)/|n|/|v|.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WorldView<V> {
    pub n: [V; 3],
    pub inv_n: V,
    pub v: [V; 3],
    pub inv_v: V,
    pub nv: V,
}

/// [`WorldView`] of normal `n` and view vector `v`.
pub(crate) fn world_view<A: Arith>(e: &mut A, n: [A::V; 3], v: [A::V; 3]) -> WorldView<A::V> {
    let nn = dot(e, n, n);
    let inv_n = inv_len(e, nn);
    let vv = dot(e, v, v);
    let inv_v = inv_len(e, vv);
    let nvr = dot(e, n, v);
    let nvn = e.mul(nvr, inv_n);
    let nv = e.mul(nvn, inv_v);
    WorldView { n, inv_n, v, inv_v, nv }
}

/// The tangent frame at a surface point in world space, for formulas that read directions: X̂ = norm(t − N̂(N̂·t))
/// (Duff et al.'s tangent of N̂ where t ∥ n), Ŷ = N̂ × X̂, both turned by the angle whose (cos, sin) is
/// `rotation`; and V's components along them.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WorldAxes<V> {
    pub x: [V; 3],
    pub y: [V; 3],
    pub vx: V,
    pub vy: V,
}

/// [`WorldAxes`] of the view `w` and the interpolated tangent `t`.
pub(crate) fn world_axes<A: Compare>(e: &mut A, w: &WorldView<A::V>, t: [A::V; 3], [c, s]: [f64; 2]) -> WorldAxes<A::V> {
    let (n, inv_n) = (w.n, w.inv_n);
    let (zero, one) = (e.konst(0.0), e.konst(1.0));
    let nh = [e.mul(n[0], inv_n), e.mul(n[1], inv_n), e.mul(n[2], inv_n)];
    let kk = dot(e, nh, t);
    let proj = [e.mul(nh[0], kk), e.mul(nh[1], kk), e.mul(nh[2], kk)];
    let u = [e.sub(t[0], proj[0]), e.sub(t[1], proj[1]), e.sub(t[2], proj[2])];
    let l2 = dot(e, u, u);
    let eps = e.konst(1e-20);
    let m1 = e.konst(-1.0);
    let sign = e.less_select(nh[2], zero, m1, one);
    let sd = e.add(sign, nh[2]);
    let q = e.div(m1, sd);
    // Duff's tangent (1 + s·a²·q, s·a·b·q, −s·a), s·a built once.
    let sa = e.mul(sign, nh[0]);
    let saa = e.mul(sa, nh[0]);
    let saq = e.mul(saa, q);
    let ox = e.add(one, saq);
    let sab = e.mul(sa, nh[1]);
    let oy = e.mul(sab, q);
    let oz = e.neg(sa);
    let il = inv_len(e, l2);
    let il = e.less_select(eps, l2, il, one);
    let un = [e.mul(u[0], il), e.mul(u[1], il), e.mul(u[2], il)];
    let u = [e.less_select(eps, l2, un[0], ox), e.less_select(eps, l2, un[1], oy), e.less_select(eps, l2, un[2], oz)];
    let mut cross = |i: usize, j: usize| {
        let x = e.mul(nh[i], u[j]);
        let y = e.mul(nh[j], u[i]);
        e.sub(x, y)
    };
    let b = [cross(1, 2), cross(2, 0), cross(0, 1)];
    let (ck, sk) = (e.konst(c), e.konst(s));
    let mut rot = |x: A::V, y: A::V, plus: bool| {
        let cx = e.mul(ck, x);
        let sy = e.mul(sk, y);
        if plus { e.add(cx, sy) } else { e.sub(cx, sy) }
    };
    let x = [rot(u[0], b[0], true), rot(u[1], b[1], true), rot(u[2], b[2], true)];
    let y = [rot(b[0], u[0], false), rot(b[1], u[1], false), rot(b[2], u[2], false)];
    let vt = dot(e, w.v, x);
    let vx = e.mul(vt, w.inv_v);
    let vb = dot(e, w.v, y);
    let vy = e.mul(vb, w.inv_v);
    WorldAxes { x, y, vx, vy }
}

/// The inputs for one light at a surface point in world space: `l` the vector towards the light (not unit) and
/// `il` its inverse length; only what `needs` asks for (and NL, NV, which lighting always reads) is computed,
/// the rest is `None`. The same definitions as [`local_inputs`] (H = norm(L̂ + V̂) through |L̂ + V̂|² = 2 + 2V̂·L̂,
/// NH and VH 0 where L = −V; VR = 2·NL·NV − V̂·L̂), in the form the renderer's program computes per pixel.
pub(crate) fn world_light_inputs<A: Compare>(
    e: &mut A,
    w: &WorldView<A::V>,
    axes: Option<&WorldAxes<A::V>>,
    l: [A::V; 3],
    il: A::V,
    needs: &dyn Fn(Input) -> bool,
) -> [Option<A::V>; N_INPUTS] {
    let nlr = dot(e, w.n, l);
    let nln = e.mul(nlr, w.inv_n);
    let nl = e.mul(nln, il);
    let mut x: [Option<A::V>; N_INPUTS] = [None; N_INPUTS];
    x[Input::NL.index()] = Some(nl);
    x[Input::Lz.index()] = Some(nl);
    x[Input::NV.index()] = Some(w.nv);
    x[Input::Vz.index()] = Some(w.nv);
    if needs(Input::NH) || needs(Input::VH) || needs(Input::VR) {
        let (zero, one, two) = (e.konst(0.0), e.konst(1.0), e.konst(2.0));
        let vlr = dot(e, w.v, l);
        let vln = e.mul(vlr, w.inv_v);
        let vl = e.mul(vln, il);
        if needs(Input::NH) || needs(Input::VH) {
            let tvl = e.mul(two, vl);
            let h2 = e.add(two, tvl);
            let tiny = e.konst(1e-300);
            let ih = inv_len(e, h2);
            let ih = e.less_select(tiny, h2, ih, zero);
            let s = e.add(nl, w.nv);
            x[Input::NH.index()] = Some(e.mul(s, ih));
            let s = e.add(one, vl);
            x[Input::VH.index()] = Some(e.mul(s, ih));
        }
        if needs(Input::VR) {
            let tn = e.mul(two, nl);
            let tnv = e.mul(tn, w.nv);
            x[Input::VR.index()] = Some(e.sub(tnv, vl));
        }
    }
    if let Some(a) = axes {
        x[Input::Vx.index()] = Some(a.vx);
        x[Input::Vy.index()] = Some(a.vy);
        let lt = dot(e, l, a.x);
        x[Input::Lx.index()] = Some(e.mul(lt, il));
        let lb = dot(e, l, a.y);
        x[Input::Ly.index()] = Some(e.mul(lb, il));
    }
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

    #[test]
    fn world_entry_agrees_with_the_local_definitions() {
        // Random frames and directions: the renderer's world-space form (vectors not unit, on f64) gives the
        // inputs of `Frame::inputs` to rounding.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let unit = |v: V3| {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / l, v[1] / l, v[2] / l]
        };
        for _ in 0..2000 {
            let n = unit([next(), next(), next()]);
            let r = [next(), next(), next()];
            let k = r[0] * n[0] + r[1] * n[1] + r[2] * n[2];
            let t = unit([r[0] - k * n[0], r[1] - k * n[1], r[2] - k * n[2]]);
            let fr = Frame::new(n, t);
            let (l, v) = (unit([next(), next(), next()]), unit([next(), next(), next()]));
            let want = fr.inputs(l, v);
            // Scaled (not unit) normal, tangent, view and light vectors, as interpolation gives them.
            let (sn, sv, sl) = (1.0 + next().abs(), 0.5 + next().abs(), 2.0 + next().abs());
            let e = &mut Direct;
            let w = world_view(e, n.map(|c| c * sn), v.map(|c| c * sv));
            let axes = world_axes(e, &w, t.map(|c| c * 3.0), [1.0, 0.0]);
            let ll = l.map(|c| c * sl);
            let il = 1.0 / dot(e, ll, ll).sqrt();
            let got = world_light_inputs(e, &w, Some(&axes), ll, il, &|_| true);
            for i in Input::ALL {
                let g = got[i.index()].unwrap();
                assert!((g - want[i.index()]).abs() < 1e-12, "{} {g} vs {}", i.name(), want[i.index()]);
            }
        }
    }

}
