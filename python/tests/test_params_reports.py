"""Per-point parameter arrays, every channel in accuracy, energy over a range of n, and render's math/backend/tier,
each against the command line."""

import json
import os
import warnings

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
FST = os.path.join(ROOT, "examples", "brdfs", "fst.brdf")
COOK = os.path.join(ROOT, "examples", "brdfs", "cook_torrance.brdf")
GOLD = os.path.join(ROOT, "examples", "vector", "gold_blinn.brdf")
PRINCIPLED = os.path.join(ROOT, "examples", "explorer", "principled.brdf")
SPHERE = os.path.join(ROOT, "examples", "scenes", "paper_sphere.toml")


def same_bits(a, b):
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    np.testing.assert_array_equal(a[ok].view(np.uint64), b[ok].view(np.uint64))


# -- per-point parameters ----------------------------------------------------------------------------------


def test_parameter_arrays_broadcast_with_the_inputs():
    k = lobe.compile(BLINN)
    nh = np.linspace(0, 1, 9)
    ns = np.array([1.0, 2.5, 40.0, 999.0])
    table = k(NH=nh, n=ns[:, None])
    assert table.shape == (4, 9)
    for i, n in enumerate(ns):
        same_bits(table[i], k(NH=nh, n=n))
    # Broadcasting by numpy's rules: a parameter's shape counts even when it has one value.
    assert k(NH=nh, n=np.array([[7.0]])).shape == (1, 9)
    assert k(NH=0.5, n=ns).shape == (4,)
    same_bits(k(NH=0.5, n=ns), [k(NH=0.5, n=n) for n in ns])
    # No points: an empty result.
    assert k(NH=nh[:0], n=ns[:0]).shape == (0,)
    # Every value is range-checked, and the error says which.
    with pytest.raises(lobe.LobeError, match=r"n = 0 \(at flat index 2\) is outside its declared range"):
        k(NH=nh[:4], n=[3, 4, 0, 5])
    with pytest.raises(lobe.LobeError, match="outside its declared range"):
        k(NH=0.5, n=[3, np.nan])
    with pytest.raises(lobe.LobeError, match="broadcast"):
        k(NH=nh, n=ns)


def test_random_parameter_arrays_over_threads_equal_point_by_point():
    """Large arrays (split over threads) of random inputs and random per-point parameters, two of them live at
    once, and runs of repeated values across the chunk boundaries: each value is the one-point call's."""
    rng = np.random.default_rng(20)
    k = lobe.compile(COOK)
    n = 70_001
    L = rng.normal(size=(n, 3))
    V = rng.normal(size=(n, 3))
    L[:, 2], V[:, 2] = np.abs(L[:, 2]), np.abs(V[:, 2])
    m = rng.uniform(0.01, 1, n)
    f0 = np.repeat(rng.uniform(0, 1, n // 1000 + 1), 1000)[:n]
    m[16_000:17_000] = 0.25
    out = k(L=L, V=V, m=m, F0=f0)
    for i in np.concatenate([rng.integers(0, n, 60), [0, 16_383, 16_384, 16_999, n - 1]]):
        same_bits(out[i], k(L=L[i], V=V[i], m=m[i], F0=f0[i]))
    # A colour formula: per-point parameters and (..., 3) values.
    p = lobe.compile(PRINCIPLED)
    rough = rng.uniform(0.02, 1, (5, 7))
    out = p(L=L[:7], V=V[:7], roughness=rough)
    assert out.shape == (5, 7, 3)
    for i in range(5):
        for j in range(7):
            same_bits(out[i, j], p(L=L[j], V=V[j], roughness=rough[i, j]))


def test_fit_refuses_a_parameter_array():
    k = lobe.compile(COOK)
    with pytest.raises(lobe.LobeError, match=r"one value in a fit, not an array \(F0\)"):
        lobe.fit(k, np.zeros(3), {"m": (0.1, 0.9)}, L=[[0, 0, 1]] * 3, V=[[0, 0.6, 0.8]] * 3, F0=[0.1, 0.2, 0.3])


# -- accuracy: every channel, live parameters ----------------------------------------------------------------


def test_accuracy_covers_every_channel_like_the_command(lobe_cli):
    ref = lobe.compile(BLINN)
    a = lobe.compile(GOLD).accuracy(ref, n_max=40)
    cli = json.loads(lobe_cli("accuracy", GOLD, "--reference", BLINN, "--n-max", "40", "--json"))
    assert len(a["channels"]) == 3 and len(cli["channels"]) == 3
    scalar_keys = set(lobe.compile(FST).accuracy(ref, n_max=40))
    for ours, theirs in zip([a] + a["channels"], [cli] + cli["channels"]):
        ours, theirs = dict(ours), dict(theirs)
        ours.pop("channels", None), theirs.pop("channels", None)
        assert set(ours) == scalar_keys == set(theirs)
        ours.pop("seconds"), theirs.pop("seconds")
        assert ours == theirs
    # The top level is the red channel; the channels differ (gold's base colour differs per channel).
    assert a["channels"][0]["mean_abs_grid"] == a["mean_abs_grid"]
    assert len({c["mean_abs_grid"] for c in a["channels"]}) == 3
    # A scalar formula has no "channels".
    assert "channels" not in lobe.compile(FST).accuracy(ref, n_max=10)


def test_accuracy_honours_live_parameters(lobe_cli):
    """Random values of F_ST's `a`, live: the command's report with `--set a=…` (baked), to rounding."""
    rng = np.random.default_rng(5)
    ref = lobe.compile(BLINN)
    k = lobe.compile(FST)
    default = k.accuracy(ref, n_max=60)
    for a in map(float, rng.uniform(1, 100, 2)):
        live = k.accuracy(ref, n_max=60, a=float(a))
        cli = json.loads(lobe_cli("accuracy", FST, "--reference", BLINN, "--n-max", "60", "--set", f"a={a!r}", "--json"))
        assert live["mean_abs_grid"] == pytest.approx(cli["mean_abs_grid"], rel=1e-9)
        assert live["max_abs"] == pytest.approx(cli["max_abs"], rel=1e-9)
        assert live["mean_abs_grid"] != default["mean_abs_grid"]
    # The reference runs at the values baked into it.
    soft, sharp = lobe.compile(COOK, m=0.6), lobe.compile(COOK, m=0.1)
    assert k.accuracy(soft, n_max=20)["mean_abs_grid"] != k.accuracy(sharp, n_max=20)["mean_abs_grid"]
    with pytest.raises(lobe.LobeError, match="accuracy sweeps n, which is baked"):
        lobe.compile(FST, n=5).accuracy(ref)
    with pytest.raises(lobe.LobeError, match="accuracy sweeps n, which is baked"):
        k.accuracy(lobe.compile(BLINN, n=5))


# -- energy over a range of n --------------------------------------------------------------------------------


def coefficient(text):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "reads no input": a coefficient is a function of n only
        return lobe.compile(text)


def test_energy_range_is_the_commands(lobe_cli):
    rng = np.random.default_rng(9)
    k = lobe.compile(BLINN)
    for _ in range(2):
        lo = float(rng.integers(1, 300))
        hi = lo + float(rng.integers(0, 300))
        step = [1.0, 7.0, 12.5][int(rng.integers(0, 3))]
        e = k.energy(range=(lo, hi), step=step)
        cli = json.loads(lobe_cli("energy", BLINN, "--range", f"{lo!r}..{hi!r}", "--step", repr(step), "--json"))
        assert e == cli
        assert [r["n"] for r in e["range"]] == list(np.arange(lo, hi + 1e-9, step))
    # Blinn's exact coefficient is (n + 2)/2π: scored against it, the error is rounding; against a wrong
    # one, it is not. The keys are the command's --against ones.
    exact = coefficient("param n = 1 in 1..1000\n(n + 2) / (2*pi)")
    e = k.energy(range=(1, 200), step=3, against=exact)
    cli = json.loads(lobe_cli("energy", BLINN, "--range", "1..200", "--step", "3", "--against-expr", "(n + 2) / (2*pi)", "--json"))
    assert set(e) == set(cli) and e["against_max_abs"] < 1e-9
    assert e["against_max_abs"] == pytest.approx(cli["against_max_abs"], abs=1e-12)
    wrong = k.energy(range=(1, 200), step=3, against=coefficient("param n = 1 in 1..1000\n(n + 1) / (2*pi)"))
    assert wrong["against_max_abs"] > 0.3
    # Other parameters are live and shown (n, swept, is not among them).
    f = lobe.compile(FST).energy(range=(10, 20), step=5, a=3)
    assert f["params"] == {"a": 3.0} and len(f["range"]) == 3
    assert f["range"][0]["coef"] != lobe.compile(FST).energy(range=(10, 20), step=5)["range"][0]["coef"]


def test_energy_range_refusals():
    k = lobe.compile(BLINN)
    for kwargs, what in [
        ({"range": (0, 40)}, "declared range of n"),
        ({"range": (1, 40), "step": 0}, "must be positive"),
        ({"range": (1, 40), "step": -1}, "must be positive"),
        ({"range": (40, 1)}, "lo ≤ hi"),
        ({"range": (1, 1000), "step": 1e-6}, "larger step"),
        ({"range": (1, 40), "mode": "full"}, "lobe"),
        ({"against": k}, "range"),
    ]:
        with pytest.raises(lobe.LobeError, match=what):
            k.energy(**kwargs)
    with pytest.raises(lobe.LobeError, match="sweeps n, which is baked"):
        lobe.compile(BLINN, n=4).energy(range=(1, 5))
    with pytest.raises(lobe.LobeError, match="sweeps n"):
        k.energy(range=(1, 5), n=3)
    with pytest.raises(lobe.LobeError, match="scalar formulas only"):
        lobe.compile(GOLD).energy(range=(1, 5))


# -- render: math, backend, tier -----------------------------------------------------------------------------


@pytest.fixture
def amplifier(tmp_path):
    """The papers' sphere with a formula that magnifies rounding: 10¹¹·|sin²+cos²−1| is below one 8-bit step in
    precise math and up to tens of steps in fast math, so an image shows which math mode rendered it."""
    (tmp_path / "amp.brdf").write_text("1e11 * abs(sin(NH)^2 + cos(NH)^2 - 1)\n")
    with open(SPHERE) as f:
        scene = f.read().replace('brdf = "../brdfs/modified_schlick_vr.brdf"', 'brdf = "amp.brdf"')
    assert 'brdf = "amp.brdf"' in scene
    (tmp_path / "amp.toml").write_text(scene)
    return str(tmp_path / "amp.toml")


@pytest.mark.parametrize("flags", [{}, {"math": "fast"}, {"backend": "interp"}, {"backend": "interp", "math": "fast"}, {"tier": "auto", "math": "fast"}])
def test_render_options_are_the_commands(flags, amplifier, lobe_cli, tmp_path):
    """The image's PNG is the command's file, byte for byte, with the same --math/--backend/--tier."""
    out = tmp_path / "r.png"
    args = [a for k, v in flags.items() for a in (f"--{k}", v)]
    lobe_cli("render", amplifier, "--size", "40", "-q", "-o", str(out), *args)
    img = lobe.render(amplifier, size=40, **flags)
    assert img.png() == out.read_bytes()


def test_render_math_shows_and_bad_options_are_errors(amplifier):
    precise, fast = lobe.render(amplifier, size=40), lobe.render(amplifier, size=40, math="fast")
    assert (precise != fast).sum() > 100
    # The default is the command's: precise math on the JIT.
    assert (lobe.render(amplifier, size=40, math="precise", backend="jit", tier="cranelift") == precise).all()
    for kwargs, what in [({"math": "sloppy"}, "math mode"), ({"backend": "gpu"}, "unknown backend"), ({"tier": "fastest"}, "unknown tier"), ({"backend": "interp", "tier": "llvm"}, "JIT")]:
        with pytest.raises(lobe.LobeError, match=what):
            lobe.render(SPHERE, size=8, **kwargs)
    # The module is built without the LLVM tier (python/Cargo.toml): asking for it says so, and how to get it.
    with pytest.raises(lobe.LobeError, match="no LLVM tier") as e:
        lobe.render(SPHERE, size=8, tier="llvm")
    assert e.value.diagnostics[0]["hint"]


# -- fits: a range is an interval ----------------------------------------------------------------------------


def test_a_two_parameter_fit_over_unit_ranges_recovers_ggx():
    """`(0.0, 1.0)` is the interval [0, 1], not the integers {0, 1}: GGX's alpha and f0 come back from its own
    values at random directions (the issue's pair and one drawn at random)."""
    k = lobe.compile(os.path.join(ROOT, "examples", "explorer", "ggx.brdf"))
    rng = np.random.default_rng(11)

    def hemisphere(m):
        v = rng.normal(size=(m, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    L, V = hemisphere(4000), hemisphere(4000)
    for alpha, f0 in [(0.35, 0.6), (rng.uniform(0.15, 0.8), rng.uniform(0.1, 0.9))]:
        target = k(L=L, V=V, alpha=alpha, f0=f0)
        r = lobe.fit(k, target, {"alpha": (0.01, 1.0), "f0": (0.0, 1.0)}, L=L, V=V)
        assert abs(r["params"]["alpha"] - alpha) < 0.01 * alpha, r
        assert abs(r["params"]["f0"] - f0) < 0.01, r
