"""Checks one module `lobe export --mitsuba` wrote, with Mitsuba's own tools (tests/it/mitsuba.rs runs it).

    check.py MODULE [--csv THETA,PHI=FILE ...] [--chi2 THETA,PHI ...] [--tests N] [--samples N]

--csv: samples `lobe sample` wrote at that incidence (wo, pdf, weights): the module's pdf_f64 and its weight
f·cosθo/pdf must equal lobe's to 1e-9 relative, and the plugin's f32 eval/pdf/eval_pdf (scalar_rgb and
llvm_ad_rgb) lobe's to 1e-4 (the plugin's pdf is 0 where every weight is below the smallest normal f32: Mitsuba's
convention that such a sample is invalid, docs/mitsuba.md). --chi2: mi.chi2.ChiSquareTest through Mitsuba's
stock mi.chi2.BSDFAdapter on the registered plugin at that incidence, with Mitsuba's defaults (10⁶ samples
unless --samples; ires 4 unless the trapezoid rule misreads the pdf at 4, `ires_for`; α = 0.01 Šidák-corrected over
--tests). Prints one line per check; exits 1 on any
failure.
"""
import importlib.util
import csv
import math
import sys

import drjit as dr
import mitsuba as mi

failures = []


def check(ok, what):
    print(('ok   ' if ok else 'FAIL ') + what, flush=True)
    if not ok:
        failures.append(what)


def load(path, variant):
    mi.set_variant(variant)
    spec = importlib.util.spec_from_file_location('lobe_export', path)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def num(x):
    """A Python float from a width-1 Dr.Jit array or a scalar variant's float."""
    return float(x[0]) if dr.is_array_v(x) else float(x)


def incidence(text):
    t, p = (float(x) for x in text.split(','))
    t, p = math.radians(t), math.radians(p)
    return [math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]


def tabulate(pdf_func, ires, samples):
    c = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=None, pdf_func=pdf_func, sample_dim=3,
                              sample_count=samples, ires=ires)
    c.tabulate_pdf()
    return [float(x) for x in c.pdf]


def misreads(pdf_func, samples, reference, candidates):
    """For each candidate ires in turn, Σ (a − r)²/r over the cells expecting ≥ 5 of `samples` (r the pdf's cell
    masses at ires `reference`, a at the candidate), until one is at most the statistic's standard deviation,
    √(2·cells). Returns the measures computed, the last the first candidate within it (or none is)."""
    ref = tabulate(pdf_func, reference, samples)
    cells = [i for i, x in enumerate(ref) if x >= 5]
    bound = math.sqrt(2 * max(len(cells), 1))
    stats = []
    for ires in candidates:
        a = tabulate(pdf_func, ires, samples)
        stats.append(sum((a[i] - ref[i]) ** 2 / ref[i] for i in cells))
        if stats[-1] <= bound:
            return stats, ires
    return stats, None


def ires_for(pdf_func, samples):
    """Mitsuba's default ires (4: a 4 × 4 trapezoid rule per χ² cell) unless that rule misreads the pdf under test
    by more than the χ² statistic's noise: then the smallest of 8, 16, 32 that does not (`misreads`, against the
    pdf's cell masses at ires 64, computed from the pdf alone, never the samples). Where even 32 misreads it — a
    lobe so narrow (a large exponent cut by the horizon at grazing incidence) that the 64 reference may misread it
    too — the same test one level up: 64 and 128 against 256, else 256. Returns the ires and the measure at ires
    4. At grazing incidence even the formula's own density f·cosθo (a perfect sampler's pdf) needs more than 4
    (docs/mitsuba.md); so does lobe's pdf where it steps to 0 at the edge of a clamped lobe (pdf() is 0 where the
    formula is)."""
    stats, ires = misreads(pdf_func, samples, 64, (4, 8, 16, 32))
    if ires is None:
        ires = misreads(pdf_func, samples, 256, (64, 128))[1] or 256
    return ires, stats[0]


def main(argv):
    path, csvs, chi2s, tests, samples = argv[0], [], [], 1, 1_000_000
    i = 1
    while i < len(argv):
        if argv[i] == '--csv':
            inc, f = argv[i + 1].split('=', 1)
            csvs.append((inc, f))
        elif argv[i] == '--chi2':
            chi2s.append(argv[i + 1])
        elif argv[i] == '--tests':
            tests = int(argv[i + 1])
        elif argv[i] == '--samples':
            samples = int(argv[i + 1])
        else:
            raise SystemExit('unknown argument ' + argv[i])
        i += 2
    m = load(path, 'llvm_ad_rgb')
    name = m._NAME
    for inc, f in csvs:
        rows = list(csv.DictReader(open(f)))
        wi_l = incidence(inc)
        wi = tuple(mi.Float64(c) for c in wi_l)
        wo = tuple(mi.Float64([float(r[k]) for r in rows]) for k in ('ox', 'oy', 'oz'))
        ref = mi.Float64([float(r['pdf']) for r in rows])
        p = m.pdf_f64(wi, wo)
        rel = dr.max(dr.abs(p - ref) / ref)[0]
        check(rel <= 1e-9, f'{name} at {inc}: pdf_f64 = lobe pdf over {len(rows)} samples (max rel {rel:.2e})')
        keys = [k for k in rows[0] if k.startswith('weight')]
        vals = m.eval_f64(wi, wo)
        worst = 0.0
        for c, k in zip(vals, keys):
            w = dr.select(wo[2] > 0.0, c * wo[2] / p, 0.0)
            refw = mi.Float64([float(r[k]) for r in rows])
            scale = dr.maximum(dr.abs(refw), 1e-300)
            worst = max(worst, dr.max(dr.abs(w - refw) / scale)[0])
        check(worst <= 1e-9, f'{name} at {inc}: eval_f64·cos/pdf = lobe weight (max rel {worst:.2e})')
        # The plugin itself, in f32, at the first samples above the horizon; both variants.
        up = [r for r in rows if float(r['oz']) > 1e-3][:64]
        for variant in ('llvm_ad_rgb', 'scalar_rgb'):
            mi.set_variant(variant)
            m.register()
            bsdf = mi.load_dict({'type': name})
            ctx = mi.BSDFContext()
            worst_v, worst_p = 0.0, 0.0
            for r in up:
                si = dr.zeros(mi.SurfaceInteraction3f)
                si.wi = mi.Vector3f(*wi_l)
                o = mi.Vector3f(float(r['ox']), float(r['oy']), float(r['oz']))
                v, pd = bsdf.eval_pdf(ctx, si, o)
                pd2 = bsdf.pdf(ctx, si, o)
                v2 = bsdf.eval(ctx, si, o)
                lw = [float(r[k]) for k in keys]
                # A direction of weight 0 in f32 is an invalid sample: pdf 0 (docs/mitsuba.md).
                lp = float(r['pdf']) if max(lw) >= 2.0 ** -126 else 0.0
                got = [num(v[c]) for c in range(3)]
                got2 = [num(v2[c]) for c in range(3)]
                pf = num(pd)
                pf2 = num(pd2)
                want = lw if len(lw) == 3 else lw * 3
                for c in range(3):
                    # eval = f·cos = weight·pdf
                    e = want[c] * float(r['pdf'])
                    worst_v = max(worst_v, abs(got[c] - e) / max(abs(e), 1e-30), abs(got2[c] - e) / max(abs(e), 1e-30))
                worst_p = max(worst_p, abs(pf - lp) / max(lp, 1e-30), abs(pf2 - lp) / max(lp, 1e-30))
            check(worst_v <= 1e-4 and worst_p <= 1e-4,
                  f'{name} at {inc}, {variant}: plugin eval/pdf/eval_pdf = lobe in f32 at {len(up)} samples '
                  f'(max rel {worst_v:.1e}, {worst_p:.1e})')
            # sample(): its pdf is pdf(wo) and its weight eval/pdf.
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*wi_l)
            worst_s = 0.0
            for k in range(16):
                u = mi.Point2f((k + 0.5) / 16, ((k * 7) % 16 + 0.25) / 16)
                bs, w = bsdf.sample(ctx, si, 0.5, u)
                spdf = num(bs.pdf)
                if spdf > 0:
                    v, pd = bsdf.eval_pdf(ctx, si, bs.wo)
                    pf = num(pd)
                    vv = [num(v[c]) for c in range(3)]
                    ww = [num(w[c]) for c in range(3)]
                    worst_s = max(worst_s, abs(spdf - pf) / pf)
                    for c in range(3):
                        worst_s = max(worst_s, abs(ww[c] - vv[c] / pf) / max(abs(vv[c] / pf), 1e-30))
            check(worst_s <= 1e-4, f'{name} at {inc}, {variant}: sample() pdf and weight = pdf(), eval/pdf (max rel {worst_s:.1e})')
    mi.set_variant('llvm_ad_rgb')
    m.register()
    for inc in chi2s:
        sample_func, pdf_func = mi.chi2.BSDFAdapter(name, {'type': name}, wi=incidence(inc))
        ires, stat = ires_for(pdf_func, samples)
        chi2 = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample_func,
                                     pdf_func=pdf_func, sample_dim=3, sample_count=samples, ires=ires)
        ok = chi2.run(0.01, tests)
        p = chi2.p_value
        check(ok, f'{name} at {inc}: mi.chi2.ChiSquareTest p = {num(p):.4f} (ires {ires}'
              + (')' if ires == 4 else f': ires 4 misreads the pdf by Σ(a−r)²/r = {stat:.0f})')
              + ('' if ok else '\n' + chi2.messages))
    if failures:
        sys.exit(1)


main(sys.argv[1:])
