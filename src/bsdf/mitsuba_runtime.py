
# ---- The runtime (the same in every export; the tables and the formula above are this formula's) ----
#
# Everything below computes in Float64 (Dr.Jit's array type of the variant; a one-element dr.scalar.ArrayXf64
# in scalar variants, whose Python floats would raise on a division by zero): the formula as lobe evaluates it
# in f64, and lobe's sampler (src/bsdf/mod.rs) operation for operation, so pdf_f64() equals lobe's pdf to
# rounding. Mitsuba's interfaces are f32: the plugin converts at its edges.

import array as _array
import base64 as _base64
import itertools as _itertools
import sys as _sys

import drjit as dr
import mitsuba as mi

_PI = 3.141592653589793
_ONE_MINUS = 1.0 - 2.0 ** -53


def _decode(text):
    a = _array.array('d', _base64.b64decode(text))
    if _sys.byteorder != 'little':
        a.byteswap()
    return a


def _dist1d(values):
    """Running sums (cdf[0] = 0) and the last cell with mass, as lobe's Dist1D keeps them."""
    cdf = [0.0] + list(_itertools.accumulate(values))
    last = max((i for i, v in enumerate(values) if v > 0.0), default=0)
    return cdf, last


def _build_lists():
    cells = _decode(_TABLE)
    if _MECHANISM == 'tabulated':
        rc = _ROWS * _COLS
        rcdf, rlast, ccdf, clast = [], [], [], []
        for k in range(len(_EMPTY)):
            node = cells[k * rc:(k + 1) * rc]
            rows = [node[i * _COLS:(i + 1) * _COLS] for i in range(_ROWS)]
            c, last = _dist1d([sum(r) for r in rows])
            rcdf += c
            rlast.append(last)
            for r in rows:
                c, last = _dist1d(r)
                ccdf += c
                clast.append(last)
        return dict(pdf=list(cells), rcdf=rcdf, rlast=rlast, ccdf=ccdf, clast=clast, corners=list(_decode(_CORNERS)))
    if _MECHANISM == 'exact':
        cdf, last = [], []
        for k in range(len(_EMPTY)):
            c, l = _dist1d(cells[k * _EXACT_CELLS:(k + 1) * _EXACT_CELLS])
            cdf += c
            last.append(l)
        return dict(pdf=list(cells), cdf=cdf, last=last)
    return {}


_LISTS = _build_lists()


class _State:
    """The Dr.Jit types of the current variant and the tables as its arrays."""

    def __init__(self):
        self.scalar = not dr.is_array_v(mi.Float)
        self.F = dr.scalar.ArrayXf64 if self.scalar else mi.Float64
        self.U = dr.uint32_array_t(self.F)
        self.t = {k: (self.U(v) if k in ('rlast', 'clast', 'last') else self.F(v)) for k, v in _LISTS.items()}
        self.thetas = self.F(_THETAS)
        self.bands = self.F(_BANDS)
        self.measure = self.F(_MEASURE)
        self.empty = self.U(_EMPTY)

    def const(self, v):
        return self.F([v]) if self.scalar else self.F(v)

    def lift(self, x):
        return self.const(float(x)) if isinstance(x, (int, float)) else x

    def to64(self, x):
        return self.F([x]) if self.scalar else self.F(x)

    def to32(self, x):
        return float(x[0]) if self.scalar else mi.Float(x)

    def gather(self, table, index):
        return dr.gather(self.F, self.t[table], index)

    def gather_u(self, table, index):
        return dr.gather(self.U, self.t[table], index)


_STATES = {}


def _st():
    v = mi.variant()
    if v not in _STATES:
        _STATES[v] = _State()
    return _STATES[v]


# Helpers the formula's spellings call (lobe's builtins table, `drjit` column).
def _pow(x, y):
    S = _st()
    x, y = S.lift(x), S.lift(y)
    r = dr.power(dr.abs(x), y)
    integer = dr.floor(y) == y
    odd = integer & (dr.abs(y - 2.0 * dr.floor(0.5 * y)) == 1.0)
    r = dr.select(x < 0.0, dr.select(integer, dr.select(odd, -r, r), S.const(float('nan'))), r)
    return dr.select((y == 0.0) | (x == 1.0), S.const(1.0), r)


def _acos(x):
    x = dr.clip(_st().lift(x), -1.0, 1.0)
    return dr.atan2(dr.sqrt(dr.maximum((1.0 - x) * (1.0 + x), 0.0)), x)


def _asin(x):
    x = dr.clip(_st().lift(x), -1.0, 1.0)
    return dr.atan2(x, dr.sqrt(dr.maximum((1.0 - x) * (1.0 + x), 0.0)))


def _bool(m):
    S = _st()
    return dr.select(m, S.const(1.0), S.const(0.0))


def _lt(a, b):
    return _bool(_st().lift(a) < b)


def _le(a, b):
    return _bool(_st().lift(a) <= b)


def _eq(a, b):
    return _bool(_st().lift(a) == b)


def _ne(a, b):
    return _bool(_st().lift(a) != b)


def _select(c, a, b):
    S = _st()
    return dr.select(S.lift(c) != 0.0, S.lift(a), S.lift(b))


# Geometry, as lobe's src/frame.rs and src/bsdf/mod.rs write it (the same association of every sum and product).
def _dot(a, b):
    return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]


def _inputs(l, v):
    h = (l[0] + v[0], l[1] + v[1], l[2] + v[2])
    hl = dr.sqrt(_dot(h, h))
    ok = hl > 0.0
    nh = dr.select(ok, h[2] / hl, 0.0)
    vh = dr.select(ok, _dot(v, h) / hl, 0.0)
    r = (-l[0], -l[1], 2.0 * l[2] - l[2])
    vr = _dot(v, r)
    return (l[2], v[2], nh, vr, vh, l[0], l[1], l[2], v[0], v[1], v[2])


def _unit(w):
    l2 = _dot(w, w)
    n = dr.sqrt(l2)
    keep = dr.abs(l2 - 1.0) <= 1e-9
    return tuple(dr.select(keep, c, c / n) for c in w)


def _reflect(wi, h):
    d = 2.0 * _dot(wi, h)
    return (d * h[0] - wi[0], d * h[1] - wi[1], d * h[2] - wi[2])


def _dir(theta, phi):
    st, ct = dr.sin(theta), dr.cos(theta)
    sp, cp = dr.sin(phi), dr.cos(phi)
    return (st * cp, st * sp, ct)


def _cosine_sample(u1, u2):
    r = dr.sqrt(u1)
    s, c = dr.sin(2.0 * _PI * u2), dr.cos(2.0 * _PI * u2)
    return (r * c, r * s, dr.sqrt(dr.maximum(1.0 - u1, 0.0)))


def _sample1d(S, cdf, last, base, lbase, n, u):
    """lobe's Dist1D::sample_cell over the n cells of `cdf` from `base`: (cell, fraction of its mass below u)."""
    total = S.gather(cdf, base + n)
    target = u * total
    pp = S.U(dr.binary_search(0, n, lambda k: S.gather(cdf, base + S.U(k)) <= target))
    i = dr.minimum(dr.maximum(pp, 1) - 1, n - 1)
    i = dr.select(target >= total, S.gather_u(last, lbase), i)
    lo, hi = S.gather(cdf, base + i), S.gather(cdf, base + i + 1)
    return i, dr.clip((target - lo) / (hi - lo), 0.0, 1.0)


def _band_theta(S, i, f):
    """θ at fraction f of band i, uniform in sin²(θ/2) (lobe's bands; uniform in solid angle)."""
    b0, b1 = dr.gather(S.F, S.bands, i), dr.gather(S.F, S.bands, i + 1)
    s = b0 + f * (b1 - b0)
    return 2.0 * dr.atan2(dr.sqrt(dr.maximum(s, 0.0)), dr.sqrt(dr.maximum(1.0 - s, 0.0)))


def _cell(S, x, n):
    """The cell of x among n, and whether x is in [0, 1)."""
    inside = (x >= 0.0) & (x < 1.0)
    i = S.U(dr.clip(x * n, 0.0, n - 1.0))
    return dr.minimum(i, n - 1), inside


# The tabulated mechanism.
def _node_weights(S, wi):
    t = _acos(wi[2])
    phi = dr.atan2(wi[1], wi[0])
    nt = len(_THETAS)
    pp = S.U(dr.binary_search(0, nt - 1, lambda k: dr.gather(S.F, S.thetas, S.U(k)) <= t))
    k = dr.minimum(dr.maximum(pp, 1) - 1, nt - 2)
    t0, t1 = dr.gather(S.F, S.thetas, k), dr.gather(S.F, S.thetas, k + 1)
    f = (t - t0) / (t1 - t0)
    f = dr.select(t <= _THETAS[0], 0.0, dr.select(t >= _THETAS[-1], 1.0, f))
    tw = [(k, 1.0 - f), (k + 1, f)]
    if _ISOTROPIC:
        return tw, phi
    npf = float(_NPHI)
    p = dr.select(phi < 0.0, phi + 2.0 * _PI, phi) / (2.0 * _PI) * npf
    kp = dr.minimum(S.U(dr.clip(dr.floor(p), 0.0, npf - 1.0)), _NPHI - 1)
    fp = dr.clip(p - S.F(kp), 0.0, 1.0)
    kp1 = dr.select(kp + 1 == _NPHI, 0, kp + 1)
    out = []
    for (tk, w) in tw:
        out.append((tk * _NPHI + kp, w * (1.0 - fp)))
        out.append((tk * _NPHI + kp1, w * fp))
    return out, S.const(0.0)


def _sample_linear(u, a, b):
    """lobe's sample_linear: x in [0, 1] with density ∝ (1 − x)·a + x·b (pbrt-v4's SampleLinear)."""
    x = u * (a + b) / (a + dr.sqrt(dr.maximum(a * a + u * (b * b - a * a), 0.0)))
    return dr.select((u == 0.0) & (a == 0.0), 0.0, dr.clip(x, 0.0, 1.0))


def _corners(S, k, i, j):
    """The four corners (v00, v01, v10, v11) of cell (i, j) of node k (lobe's Node::corners)."""
    j1 = dr.select(j + 1 == _COLS, 0, j + 1)
    base = k * ((_ROWS + 1) * _COLS)
    return (S.gather('corners', base + i * _COLS + j), S.gather('corners', base + i * _COLS + j1),
            S.gather('corners', base + (i + 1) * _COLS + j), S.gather('corners', base + (i + 1) * _COLS + j1))


def _bilinear(v, a, b):
    return (1.0 - a) * ((1.0 - b) * v[0] + b * v[1]) + a * ((1.0 - b) * v[2] + b * v[3])


def _table_coords(wi, wo, phi0):
    s = (wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2])
    ln = dr.sqrt(_dot(s, s))
    valid = ln > 0.0
    sign = dr.select(s[2] < 0.0, -1.0 / ln, 1.0 / ln)
    h = (s[0] * sign, s[1] * sign, s[2] * sign)
    st = dr.sqrt(h[0] * h[0] + h[1] * h[1])
    th = dr.atan2(st, h[2])
    x1 = dr.sqrt(th / (_PI / 2.0))
    v = (dr.atan2(h[1], h[0]) - phi0) / (2.0 * _PI)
    r = dr.select(dr.abs(v) >= 1.0, 0.0, v)
    r = dr.select(r < 0.0, r + 1.0, r)
    x2 = dr.select(r >= 1.0, 0.0, r)
    jac = 4.0 * dr.abs(_dot(wi, s)) / ln
    return x1, th, x2, jac, valid


def _tab_pdf(S, wi, wo, cos_pdf):
    ws, phi0 = _node_weights(S, wi)
    x1, th, x2, jac, valid = _table_coords(wi, wo, phi0)
    i, _ = _cell(S, x1, _ROWS)
    j, _ = _cell(S, x2, _COLS)
    b = dr.clip(x2 * _COLS - S.F(j), 0.0, 1.0)
    hs = dr.sin(0.5 * th)
    s0, s1 = dr.gather(S.F, S.bands, i), dr.gather(S.F, S.bands, i + 1)
    a = dr.clip((hs * hs - s0) / (s1 - s0), 0.0, 1.0)
    p = S.const(0.0)
    for (k, w) in ws:
        d = _bilinear(_corners(S, k, i, j), a, b)
        term = dr.select(valid & (jac > 0.0) & (x1 <= 1.0), d / jac, 0.0)
        term = dr.select(dr.gather(S.U, S.empty, k) != 0, cos_pdf, term)
        p = p + dr.select(w > 0.0, w * term, 0.0)
    return p


def _pick_node(S, ws, u1):
    """lobe's pick_node: the node u1 falls in by weight, and u1 rescaled within it."""
    acc = S.const(0.0)
    chosen = dr.zeros(dr.mask_t(S.F), dr.width(u1))
    k_sel, u_sel = ws[0][0], u1
    for (k, w) in ws:
        live = (w > 0.0) & ~chosen
        hit = live & (u1 < acc + w)
        fall = live & ~hit
        k_sel = dr.select(hit | fall, k, k_sel)
        u_sel = dr.select(hit, dr.clip((u1 - acc) / w, 0.0, _ONE_MINUS), dr.select(fall, _ONE_MINUS, u_sel))
        chosen = chosen | hit
        acc = dr.select(live, acc + w, acc)
    return k_sel, u_sel


def _tab_sample(S, wi, u1, u2):
    ws, phi0 = _node_weights(S, wi)
    k_sel, u_sel = _pick_node(S, ws, u1)
    row, f1 = _sample1d(S, 'rcdf', 'rlast', k_sel * (_ROWS + 1), k_sel, _ROWS, u_sel)
    crow = k_sel * _ROWS + row
    col, f2 = _sample1d(S, 'ccdf', 'clast', crow * (_COLS + 1), crow, _COLS, u2)
    v = _corners(S, k_sel, row, col)
    a = _sample_linear(f1, v[0] + v[1], v[2] + v[3])
    b = _sample_linear(f2, v[0] + a * (v[2] - v[0]), v[1] + a * (v[3] - v[1]))
    x2 = (S.F(col) + b) / _COLS
    h = _dir(_band_theta(S, row, a), 2.0 * _PI * x2 + phi0)
    wo = _reflect(wi, h)
    cw = _cosine_sample(u_sel, u2)
    empty = dr.gather(S.U, S.empty, k_sel) != 0
    return tuple(dr.select(empty, c, w) for c, w in zip(cw, wo))


# The exact mechanism (a formula of NH alone or VR alone).
def _exact_axis(S, wi):
    if _EXACT_LOBE == 'VR':
        return (-wi[0], -wi[1], wi[2])
    z = dr.zeros(S.F, dr.width(wi[2]))
    return (z, z, z + 1.0)


def _cos_sin_of_band(S, i, f):
    """(cos θ, sin θ) at fraction f of band i, uniform in sin²(θ/2) (lobe's cos_sin_of_band)."""
    b0, b1 = dr.gather(S.F, S.bands, i), dr.gather(S.F, S.bands, i + 1)
    s = dr.clip(b0 + f * (b1 - b0), 0.0, 1.0)
    return 1.0 - 2.0 * s, 2.0 * dr.sqrt(s * (1.0 - s))


def _mirror_frame(wi):
    """lobe's mirror_frame: (t, b, R) about R, t in the plane of R and N pointing down; sinθi, cosθi."""
    rho = dr.sqrt(wi[0] * wi[0] + wi[1] * wi[1])
    ok = rho > 0.0
    ax = dr.select(ok, -wi[0] / dr.select(ok, rho, 1.0), 1.0)
    ay = dr.select(ok, -wi[1] / dr.select(ok, rho, 1.0), 0.0)
    ct = wi[2]
    zero = 0.0 * ct
    return ((ct * ax, ct * ay, -rho), (-ay, ax, zero), (-wi[0], -wi[1], wi[2])), rho, ct


def _ring(S, c, d):
    """lobe's ring: (ψmax, H) of the ring with cosθo = c + d·cosψ."""
    full = c >= d
    none = c <= -d
    r = dr.clip(-c / dr.select(d > 0.0, d, 1.0), -1.0, 1.0)
    psi = _acos(r)
    part = c * psi + dr.sqrt(dr.maximum((d - c) * (d + c), 0.0))
    psi_max = dr.select(full, _PI, dr.select(none, 0.0, psi))
    h = dr.select(full, _PI * c, dr.select(none, 0.0, part))
    return psi_max, h


# Steps of the ring's azimuth solve: Newton kept in a bracket that bisection at least halves (64 halvings are
# below an ulp of π); lobe stops when a step is below 1e-15 of ψ, which Newton reaches in a few steps.
_RING_ITERATIONS = 64


def _ring_azimuth(S, c, d, psi_max, h, t):
    goal = t * h
    lo, hi = 0.0 * c, psi_max + 0.0 * c
    psi = t * psi_max
    for _ in range(_RING_ITERATIONS):
        g = c * psi + d * dr.sin(psi) - goal
        below = g < 0.0
        lo = dr.select(below, psi, lo)
        hi = dr.select(below, hi, psi)
        slope = c + d * dr.cos(psi)
        nxt = psi - g / dr.select(slope > 0.0, slope, 1.0)
        psi = dr.select((slope > 0.0) & (nxt > lo) & (nxt < hi), nxt, 0.5 * (lo + hi))
    return psi


def _exact_sample(S, wi, u1, u2):
    if _EXACT_LOBE == 'NH':
        i, f = _sample1d(S, 'cdf', 'last', S.U(0), S.U(0), _EXACT_CELLS, u1)
        ct, st = _cos_sin_of_band(S, i, f)
        sp, cp = dr.sin(2.0 * _PI * u2), dr.cos(2.0 * _PI * u2)
        return _reflect(wi, (st * cp, st * sp, ct))
    ws, _ = _node_weights(S, wi)
    k, u = _pick_node(S, ws, u1)
    i, f = _sample1d(S, 'cdf', 'last', k * (_EXACT_CELLS + 1), k, _EXACT_CELLS, u)
    ct, st = _cos_sin_of_band(S, i, f)
    (t, b, r), rho, cti = _mirror_frame(wi)
    c, d = ct * cti, st * rho
    psi_max, h = _ring(S, c, d)
    side = dr.select(u2 < 0.5, 1.0, -1.0)
    psi = _ring_azimuth(S, c, d, psi_max, h, dr.minimum(dr.abs(2.0 * u2 - 1.0), 1.0))
    on = h > 0.0
    cp = dr.select(on, -dr.cos(psi), dr.cos(2.0 * _PI * u2))
    sp = dr.select(on, -side * dr.sin(psi), dr.sin(2.0 * _PI * u2))
    wo = tuple(ct * r[k3] + st * (cp * t[k3] + sp * b[k3]) for k3 in range(3))
    cw = _cosine_sample(u, u2)
    empty = dr.gather(S.U, S.empty, k) != 0
    return tuple(dr.select(empty, a, w) for a, w in zip(cw, wo))


def _exact_pdf(S, wi, wo, cos_pdf):
    if _EXACT_LOBE == 'NH':
        s = (wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2])
        ln = dr.sqrt(_dot(s, s))
        valid = ln > 0.0
        sign = dr.select(s[2] < 0.0, -1.0 / ln, 1.0 / ln)
        d = (s[0] * sign, s[1] * sign, s[2] * sign)
        a = _exact_axis(S, wi)
        jac = 4.0 * dr.abs(_dot(wi, d))
    else:
        d, a, jac, valid = wo, _exact_axis(S, wi), 1.0, wo[2] == wo[2]
    x = (d[1] * a[2] - d[2] * a[1], d[2] * a[0] - d[0] * a[2], d[0] * a[1] - d[1] * a[0])
    sin_t, cos_t = dr.sqrt(_dot(x, x)), _dot(d, a)
    th = dr.atan2(sin_t, cos_t)
    i, inside = _cell(S, th / _EXACT_THETA_MAX, _EXACT_CELLS)
    den = dr.gather(S.F, S.measure, i) * jac
    ok = valid & inside & (den > 0.0)
    if _EXACT_LOBE == 'NH':
        return dr.select(ok, S.gather('pdf', i) / den, 0.0)
    _, rho, cti = _mirror_frame(wi)
    _, h = _ring(S, cos_t * cti, sin_t * rho)
    azimuth = dr.select(h > 0.0, _PI * dr.maximum(wo[2], 0.0) / dr.select(h > 0.0, h, 1.0), 1.0)
    ws, _ = _node_weights(S, wi)
    p = S.const(0.0)
    for (k, w) in ws:
        term = dr.select(ok, S.gather('pdf', k * _EXACT_CELLS + i) / den * azimuth, 0.0)
        term = dr.select(dr.gather(S.U, S.empty, k) != 0, cos_pdf, term)
        p = p + dr.select(w > 0.0, w * term, 0.0)
    return p


# lobe's Sampler: the mixture with the cosine density.
def _density(S, wi, wo):
    cos_pdf = dr.maximum(wo[2], 0.0) / _PI
    if _MECHANISM == 'tabulated':
        body = _tab_pdf(S, wi, wo, cos_pdf)
    elif _MECHANISM == 'exact':
        body = _exact_pdf(S, wi, wo, cos_pdf)
    else:
        body = cos_pdf
    return _COS_FRAC * cos_pdf + (1.0 - _COS_FRAC) * body


def _draw(S, wi, u1, u2):
    u1, u2 = dr.clip(u1, 0.0, _ONE_MINUS), dr.clip(u2, 0.0, _ONE_MINUS)
    c = _COS_FRAC
    cw = _cosine_sample(dr.minimum(u1 / c, _ONE_MINUS), u2)
    v = dr.clip((u1 - c) / (1.0 - c), 0.0, _ONE_MINUS)
    if _MECHANISM == 'tabulated':
        bw = _tab_sample(S, wi, v, u2)
    elif _MECHANISM == 'exact':
        bw = _exact_sample(S, wi, v, u2)
    else:
        bw = _cosine_sample(v, u2)
    return tuple(dr.select(u1 < c, a, b) for a, b in zip(cw, bw))


def eval_f64(wi, wo):
    """The formula's channel values f(wi, wo) (wi its L, wo its V; unit, local frame) in Float64 arrays."""
    S = _st()
    wi, wo = tuple(S.lift(c) for c in wi), tuple(S.lift(c) for c in wo)
    zero = dr.zeros(S.F, max(dr.width(wi[2]), dr.width(wo[2])))
    return tuple(zero + c for c in _formula(*_inputs(wi, wo)))


def pdf_f64(wi, wo):
    """lobe's pdf(wi, wo) in Float64: wi is normalised (above the horizon), wo normalised unless unit to 1e-9."""
    S = _st()
    wi, wo = _unit(tuple(S.lift(c) for c in wi)), _unit(tuple(S.lift(c) for c in wo))
    return _density(S, wi, wo)


def sample_f64(wi, u1, u2):
    """lobe's sample(wi, (u1, u2)) in Float64: (wo, pdf, weights per channel); weight 0 below the horizon."""
    S = _st()
    wi = _unit(tuple(S.lift(c) for c in wi))
    u1, u2 = S.lift(u1), S.lift(u2)
    wo = _draw(S, wi, u1, u2)
    pdf = _density(S, wi, wo)
    f = eval_f64(wi, wo)
    ok = (wo[2] > 0.0) & (pdf > 0.0)
    return wo, pdf, tuple(dr.select(ok, c * wo[2] / pdf, 0.0) for c in f)


# The smallest normal f32: the plugin's weights and pdfs are f32, and a weight below this would be a subnormal
# that a flush-to-zero backend reads as 0.
_F32_MIN_NORMAL = 2.0 ** -126


def _plugin_values(S, wi, wo):
    """What the plugin reports at (wi, wo), in Float64: f·cosθo per channel, the pdf, and whether the direction is
    one sample() returns as a valid sample (some channel's weight f·cosθo/pdf is a normal f32 > 0).

    Mitsuba's convention, which mi.chi2.BSDFAdapter tests: a sample of weight 0 is invalid (the adapter drops it),
    and pdf(wo) is the density of the valid samples only. lobe's sampler mixes in cosine sampling, so it also draws
    directions where the formula is 0 (a clamped lobe, a shadowing term, below the horizon): sample() returns them
    with weight 0 and pdf 0, and pdf() is 0 at every such direction; elsewhere pdf() is lobe's pdf. The same
    function decides both, so sample() and pdf() stay one code path."""
    ok = (wi[2] > 0.0) & (wo[2] > 0.0)
    f = eval_f64(wi, wo)
    pdf = _density(S, wi, wo)
    ok = ok & (pdf > 0.0)
    fc = [dr.select(ok, c * wo[2], 0.0) for c in f]
    live = ok & (fc[0] / pdf >= _F32_MIN_NORMAL)
    for c in fc[1:]:
        live = live | (ok & (c / pdf >= _F32_MIN_NORMAL))
    return fc, dr.select(live, pdf, 0.0), live


def _spectrum(S, vals):
    v = [S.to32(c) for c in vals]
    return mi.Spectrum(v[0], v[1], v[2]) if len(v) == 3 else mi.Spectrum(v[0])


def _make_class():
    """The plugin class for the current variant (each variant has its own mi.BSDF)."""

    class LobeBSDF(mi.BSDF):
        """The formula as a Mitsuba 3 BSDF: eval, pdf, sample and eval_pdf (module docstring)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            if not mi.is_rgb:
                raise RuntimeError(_NAME + ': lobe\'s Mitsuba export runs in RGB variants (scalar_rgb, llvm_ad_rgb, '
                                   'cuda_ad_rgb), not ' + mi.variant())
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if not _ISOTROPIC:
                flags = flags | mi.BSDFFlags.Anisotropic
            self.m_components = [flags]
            self.m_flags = flags

        def _dirs(self, si, wo):
            S = _st()
            wi = tuple(S.to64(c) for c in (si.wi.x, si.wi.y, si.wi.z))
            w = tuple(S.to64(c) for c in (wo.x, wo.y, wo.z))
            return S, _unit(wi), _unit(w)

        def eval_pdf(self, ctx, si, wo, active=True):
            S, wi, w = self._dirs(si, wo)
            fc, pdf, _ = _plugin_values(S, wi, w)
            return _spectrum(S, fc), S.to32(pdf)

        def eval(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            S, wi, w = self._dirs(si, wo)
            return S.to32(_plugin_values(S, wi, w)[1])

        def sample(self, ctx, si, sample1, sample2, active=True):
            S = _st()
            wi = _unit(tuple(S.to64(c) for c in (si.wi.x, si.wi.y, si.wi.z)))
            above = wi[2] > 0.0
            wi_safe = tuple(dr.select(above, c, d) for c, d in zip(wi, (0.0, 0.0, 1.0)))
            wo = _draw(S, wi_safe, S.to64(sample2.x), S.to64(sample2.y))
            fc, pdf, live = _plugin_values(S, wi_safe, wo)
            ok = above & live
            weight = [c / dr.select(live, pdf, 1.0) for c in fc]
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = mi.Vector3f(S.to32(wo[0]), S.to32(wo[1]), S.to32(wo[2]))
            bs.pdf = S.to32(dr.select(ok, pdf, 0.0))
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            return bs, _spectrum(S, [dr.select(ok, c, 0.0) for c in weight])

        def traverse(self, callback):
            pass

        def to_string(self):
            return 'LobeBSDF[' + _NAME + ', ' + _MECHANISM + ' sampling]'

    return LobeBSDF


_CLASSES = {}


def register():
    """Registers the plugin under its name for the current variant (call again after mi.set_variant)."""
    v = mi.variant()
    if v not in _CLASSES:
        _CLASSES[v] = _make_class()
    cls = _CLASSES[v]
    mi.register_bsdf(_NAME, lambda props: cls(props))


if mi.variant() is not None:
    register()
