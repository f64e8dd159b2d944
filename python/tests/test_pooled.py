"""Results come from a pool of reused buffers (python/src/pool.rs): each call still returns a fresh array its
caller owns. Results never alias, keep their values while later calls run, outlive the kernel, and a reused
buffer's old contents never show through (the kernel writes every element)."""

import copy
import gc
import os
import pickle
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import lobe
from conftest import CATALOGUE, ROOT
from test_kernel import bits, parse_values, random_dirs, random_param_column, random_params, write_csv

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
# A value no formula gives at these points: where a reused buffer's old contents showed through.
STALE = 1.2345e300
# Lengths around the pool's smallest (4096) and a batch's chunk (16384), partial chunks among them.
SIZES = (0, 1, 4095, 4096, 4097, 16384, 16385, 3 * 16384 + 7)


def address(a):
    return a.__array_interface__["data"][0]


def poison(a):
    """Overwrites `a` with STALE and returns its address; the caller then drops it, so its buffer goes back."""
    a[...] = STALE
    return address(a)


def test_consecutive_results_do_not_alias():
    k = lobe.compile(BLINN)
    nh = np.linspace(0, 1, 1 << 16)
    a = k(NH=nh)
    b = k(NH=nh)
    assert not np.shares_memory(a, b)
    want = b.copy()
    a[:] = -1.0
    np.testing.assert_array_equal(bits(b), bits(want))
    del a
    c = k(NH=nh)  # may take a's buffer: a is gone, b is not
    assert not np.shares_memory(b, c)
    c[:] = -2.0
    np.testing.assert_array_equal(bits(b), bits(want))


def test_a_kept_result_keeps_its_values_while_many_calls_run():
    k = lobe.compile(BLINN)
    rng = np.random.default_rng(3)
    kept = k(NH=rng.uniform(0, 1, 1 << 15), n=40.0)
    want = kept.copy()
    for i in range(200):
        n = int(rng.choice([1 << 12, 1 << 15, (1 << 15) - 3, 1 << 16, 5000]))
        r = k(NH=rng.uniform(0, 1, n), n=float(rng.uniform(1, 1000)))
        r[...] = STALE  # results written to and dropped at once: their buffers come back to the pool
        if i % 7 == 0:
            held = r  # and some kept a while
    del held
    np.testing.assert_array_equal(bits(kept), bits(want))


def test_results_outlive_the_kernel_and_survive_pickling_copies_and_views():
    k = lobe.compile("vec3(NH, NH^2, 1 - NH)")
    nh = np.linspace(0, 1, 1 << 14)
    a = k(NH=nh)
    want = np.stack([nh, nh**2, 1 - nh], axis=-1)
    np.testing.assert_array_equal(a, want)
    view = a[::3, 1]
    del k
    gc.collect()
    for b in (pickle.loads(pickle.dumps(a)), pickle.loads(pickle.dumps(a, protocol=5)), copy.copy(a), copy.deepcopy(a), a.copy()):
        assert not np.shares_memory(a, b)
        np.testing.assert_array_equal(b, want)
    del a
    gc.collect()
    other = lobe.compile(BLINN)
    for _ in range(20):
        r = other(NH=nh)
        r[...] = STALE
    np.testing.assert_array_equal(view, want[::3, 1])
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(view)), want[::3, 1])
    view[0] = 7.0  # the view is writable, as any numpy result
    assert view[0] == 7.0


@pytest.mark.parametrize("path", CATALOGUE, ids=[os.path.basename(os.path.dirname(p)) + "/" + os.path.basename(p) for p in CATALOGUE])
def test_a_reused_buffer_is_written_everywhere(path):
    """Every catalogue formula (colour included), cosines or directions, one or a per-point parameter, at lengths
    around the pool's and the chunks' boundaries, into a buffer just filled with STALE: the values of a call
    into a fresh NaN-filled `out=` (or the first call), bit for bit, and no STALE left."""
    k = lobe.compile(path)
    rng = np.random.default_rng(abs(hash(os.path.basename(path))) % 2**32)
    reused = 0
    for n in SIZES:
        L, V = random_dirs(rng, max(n, 5))[:n], random_dirs(rng, max(n, 5))[:n]
        params = random_params(k, rng)
        calls = [dict(L=L, V=V, **params)]
        if params:
            name = next(iter(params))
            calls.append(dict(L=L, V=V, **{**params, name: random_param_column(k, name, rng, n)}))
        for kw in calls:
            first = k(**kw)
            want = first.copy()
            if k.channels == 1:
                into = np.full(want.shape, np.nan)
                np.testing.assert_array_equal(bits(k(**kw, out=into)), bits(want))
            at = poison(first)
            del first
            again = k(**kw)
            reused += address(again) == at and n >= 4096
            assert not (again == STALE).any()
            np.testing.assert_array_equal(bits(again), bits(want))
            # A shorter result in the same buffer (it takes a pooled one up to twice its length).
            if n >= 8192:
                at = poison(again)
                del again
                short = k(**{key: (v[: n - 4000] if isinstance(v, np.ndarray) else v) for key, v in kw.items()})
                reused += address(short) == at
                np.testing.assert_array_equal(bits(short), bits(want[: n - 4000]))
    # The pool was exercised (a buffer just returned is the best fit for the same length).
    assert reused > 0


def test_empty_and_small_results():
    k = lobe.compile(BLINN)
    assert k(NH=np.empty(0)).shape == (0,)
    assert k(NH=np.empty((0, 4))).shape == (0, 4)
    assert lobe.compile("vec3(NH, 1, 2)")(NH=np.empty(0)).shape == (0, 3)
    np.testing.assert_array_equal(k(NH=np.ones(3), n=2.0), np.ones(3))


def test_threads_get_the_sequential_bits():
    """Dask-style: threads calling kernels at once, writing to and dropping their results (buffers going back
    and forth through the pool), get exactly the values of sequential calls."""
    ks = [lobe.compile(p) for p in CATALOGUE[:6]]
    rng = np.random.default_rng(11)
    jobs = []
    for i in range(48):
        k = ks[i % len(ks)]
        n = int(rng.choice([4096, 5000, 16385, 1 << 15, 40000]))
        jobs.append((k, dict(L=random_dirs(rng, n), V=random_dirs(rng, n), **random_params(k, rng))))
    want = [bits(k(**kw)) for k, kw in jobs]

    def run(j):
        k, kw = jobs[j]
        out = []
        for _ in range(3):
            r = k(**kw)
            out.append(bits(r))
            r[...] = STALE
            del r
        return out

    with ThreadPoolExecutor(4) as ex:
        for j, got in zip(range(len(jobs)), ex.map(run, range(len(jobs)))):
            for g in got:
                np.testing.assert_array_equal(g, want[j])


def test_random_formulas_at_random_points_are_the_command_lines(lobe_cli, tmp_path):
    """Random formulas over the cosines at 20 000 random points (two chunks, the second partial), each call into
    buffers that held other values: `lobe eval --points`'s bits."""
    rng = np.random.default_rng(5)
    leaves = ["NH", "NL", "NV", "VH", "0.5", "2", "1.25"]

    def expr(depth):
        if depth == 0 or rng.random() < 0.25:
            return str(rng.choice(leaves))
        a, b = expr(depth - 1), expr(depth - 1)
        form = int(rng.integers(0, 8))
        return [f"({a} + {b})", f"({a} - {b})", f"({a} * {b})", f"({a} / (1 + abs({b})))", f"sqrt(abs({a}))", f"exp(-{a})", f"max({a}, {b})", f"({a})^2"][form]

    n = 20_000
    cos = {c: rng.uniform(0, 1, n) for c in ("NL", "NV", "NH", "VH")}
    csv = tmp_path / "p.csv"
    write_csv(csv, list(cos), list(cos.values()))
    for i in range(6):
        text = expr(4)
        path = tmp_path / f"f{i}.brdf"
        path.write_text(text + "\n")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a random formula may read no input
            k = lobe.compile(str(path))
        for _ in range(3):
            r = k(**cos)
            r[...] = STALE
            del r
        cli = parse_values(lobe_cli("eval", str(path), "--points", str(csv)), 1)
        np.testing.assert_array_equal(bits(k(**cos)), bits(cli), err_msg=text)


def test_grad_sample_pdf_and_tables_reuse_buffers_soundly():
    """The other array-returning calls from the pool: the same values again after their buffers held STALE."""
    k = lobe.compile(os.path.join(ROOT, "examples", "explorer", "ggx.brdf"))
    rng = np.random.default_rng(9)
    n = 20_000
    L, V = random_dirs(rng, n), random_dirs(rng, n)
    g1 = k.grad(L=L, V=V)
    want_g = {name: a.copy() for name, a in g1.items()}
    for a in g1.values():
        a[...] = STALE
    del g1, a
    g2 = k.grad(L=L, V=V)
    assert set(g2) == set(want_g)
    for name in want_g:
        np.testing.assert_array_equal(bits(g2[name]), bits(want_g[name]))
    wi = random_dirs(rng, n)
    wi[:, 2] = np.abs(wi[:, 2]) + 0.1
    u = rng.uniform(0, 1, (n, 2))
    first = k.sample(wi, u)
    want_s = [a.copy() for a in first]
    for a in first:
        a[...] = STALE
    del first, a
    for a, w in zip(k.sample(wi, u), want_s):
        np.testing.assert_array_equal(bits(a), bits(w))
    p = k.pdf(wi, want_s[0])
    want_p = p.copy()
    p[...] = STALE
    del p
    np.testing.assert_array_equal(bits(k.pdf(wi, want_s[0])), bits(want_p))
    np.testing.assert_array_equal(bits(want_p), bits(want_s[1]))
    # A measured table's lookup (Measured.values).
    t = lobe.compile(BLINN).tabulate(n=3)
    v = t.values(L, V)
    want_v = v.copy()
    v[...] = STALE
    del v
    np.testing.assert_array_equal(bits(t.values(L, V)), bits(want_v))
