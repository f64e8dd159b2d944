"""The binding against the command line and itself: values, broadcasting, errors, pickling, the reports."""

import os
import pickle
import struct

import numpy as np
import pytest

import lobe
from conftest import CATALOGUE, ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
GGX = os.path.join(ROOT, "examples", "explorer", "ggx.brdf")


def bits(a):
    """float64 values as comparable bit patterns, every NaN as one pattern (text output drops payloads)."""
    a = np.asarray(a, dtype=np.float64).copy()
    nan = np.isnan(a)
    a[nan] = np.nan
    return np.where(nan, np.uint64(0x7FF8000000000000), a.view(np.uint64))


def parse_values(text, channels):
    rows = [line.strip() for line in text.splitlines() if line.strip()]
    if channels == 1:
        return np.array([float(r) for r in rows])
    return np.array([[float(x) for x in r.strip("[]").split(",")] for r in rows])


def random_dirs(rng, n):
    """Unit directions, most in the upper hemisphere, some below it and some exactly at the normal."""
    d = rng.normal(size=(n, 3))
    d[: n * 3 // 4, 2] = np.abs(d[: n * 3 // 4, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:5] = [0.0, 0.0, 1.0]
    return d


def random_params(k, rng):
    out = {}
    for name, (lo, hi) in k.param_ranges.items():
        if name in k.baked:
            continue
        out[name] = float(rng.uniform(lo, hi)) if hi > lo else lo
    return out


def write_csv(path, header, cols):
    n = len(cols[0])
    with open(path, "w") as f:
        f.write(",".join(header) + "\n")
        for i in range(n):
            f.write(",".join(repr(float(c[i])) for c in cols) + "\n")


@pytest.mark.parametrize("path", CATALOGUE, ids=[os.path.basename(os.path.dirname(p)) + "/" + os.path.basename(p) for p in CATALOGUE])
def test_bit_identical_to_eval_points(path, lobe_cli, tmp_path):
    """10⁴ points, random directions and random live parameters: Python's values are `lobe eval --points`'s bits."""
    rng = np.random.default_rng(abs(hash(os.path.basename(path))) % 2**32)
    k = lobe.compile(path)
    n = 10_000
    L, V = random_dirs(rng, n), random_dirs(rng, n)
    params = random_params(k, rng)
    csv = tmp_path / "points.csv"
    names = list(params)
    write_csv(csv, ["Lx", "Ly", "Lz", "Vx", "Vy", "Vz"] + names, [L[:, 0], L[:, 1], L[:, 2], V[:, 0], V[:, 1], V[:, 2]] + [np.full(n, params[p]) for p in names])
    cli = parse_values(lobe_cli("eval", path, "--points", str(csv)), k.channels)
    # The CSV carries the values' shortest decimal text; read back they are the same doubles.
    py = k(L=L, V=V, **params)
    assert py.shape == ((n,) if k.channels == 1 else (n, 3))
    np.testing.assert_array_equal(bits(py), bits(cli))
    # The cosine path, for formulas that read only cosines: the same bits from the cosine columns.
    if not any(i[0] in "LV" and len(i) == 2 for i in k.inputs):
        cos = {c: rng.uniform(0, 1, n) for c in ("NL", "NV", "NH", "VR", "VH")}
        cos["NH"][:3] = [0.0, 1.0, 0.5]
        write_csv(csv, list(cos) + names, list(cos.values()) + [np.full(n, params[p]) for p in names])
        cli = parse_values(lobe_cli("eval", path, "--points", str(csv)), k.channels)
        np.testing.assert_array_equal(bits(k(**cos, **params)), bits(cli))
    # Per-point parameters: a random value per row (some rows repeating the one before, as runs), given to
    # the command as parameter columns and to Python as arrays: the same bits.
    if names:
        per_row = {p: random_param_column(k, p, rng, n) for p in names}
        write_csv(csv, ["Lx", "Ly", "Lz", "Vx", "Vy", "Vz"] + names, [L[:, 0], L[:, 1], L[:, 2], V[:, 0], V[:, 1], V[:, 2]] + [per_row[p] for p in names])
        cli = parse_values(lobe_cli("eval", path, "--points", str(csv)), k.channels)
        np.testing.assert_array_equal(bits(k(L=L, V=V, **per_row)), bits(cli))


def random_param_column(k, name, rng, n):
    """n random values in the parameter's declared range, each repeated a random number of times (1 to 20)."""
    lo, hi = k.param_ranges[name]
    out = np.empty(n)
    i = 0
    while i < n:
        run = int(rng.integers(1, 21)) if rng.random() < 0.3 else 1
        out[i : i + run] = rng.uniform(lo, hi) if hi > lo else lo
        i += run
    return out


def test_baked_values_match_set(lobe_cli, tmp_path):
    """Baked parameters (compile(**baked)) are the command's --set, bit for bit."""
    path = os.path.join(ROOT, "examples", "brdfs", "cook_torrance.brdf")
    k0 = lobe.compile(path)
    rng = np.random.default_rng(7)
    baked = random_params(k0, rng)
    k = lobe.compile(path, **baked)
    assert k.baked == baked
    n = 2000
    L, V = random_dirs(rng, n), random_dirs(rng, n)
    csv = tmp_path / "p.csv"
    write_csv(csv, ["Lx", "Ly", "Lz", "Vx", "Vy", "Vz"], [L[:, 0], L[:, 1], L[:, 2], V[:, 0], V[:, 1], V[:, 2]])
    setarg = ",".join(f"{a}={v!r}" for a, v in baked.items())
    cli = parse_values(lobe_cli("eval", path, "--set", setarg, "--points", str(csv)), 1)
    np.testing.assert_array_equal(bits(k(L=L, V=V)), bits(cli))


def test_broadcasting_and_shapes():
    k = lobe.compile(BLINN)
    nh = np.linspace(0, 1, 7)
    a = k(NH=nh[:, None], n=np.float64(20))
    assert a.shape == (7, 1) and a.dtype == np.float64
    np.testing.assert_array_equal(a[:, 0], k(NH=nh, n=20))
    # Scalars give a 0-d array; the values are cos^n.
    assert k(NH=0.5, n=2).shape == ()
    np.testing.assert_allclose(k(NH=nh, n=3), nh**3, rtol=1e-15)
    # Unread inputs are accepted and ignored; non-contiguous and integer arrays are converted.
    m = np.linspace(0, 1, 20).reshape(4, 5)
    np.testing.assert_array_equal(k(NH=m.T, NL=1, n=5), k(NH=np.ascontiguousarray(m.T), n=5))
    assert k(NH=np.array([0, 1]), n=2).tolist() == [0.0, 1.0]
    # Large batches are split over threads: the same bits as element by element.
    rng = np.random.default_rng(1)
    big = rng.uniform(0, 1, 100_003)
    whole = k(NH=big, n=77)
    some = rng.integers(0, big.size, 50)
    for i in some:
        assert k(NH=big[i], n=77).tobytes() == whole[i].tobytes()


def test_directions_broadcast_and_colour():
    k = lobe.compile(GGX)
    assert k.channels == 1 or k.channels == 3
    L = np.array([0.3, 0.1, 0.9])
    V = np.stack([np.zeros(4), np.linspace(0, 0.5, 4), np.ones(4)], axis=-1)
    out = k(L=L, V=V)
    assert out.shape == ((4,) if k.channels == 1 else (4, 3))
    p = lobe.compile(os.path.join(ROOT, "examples", "explorer", "principled.brdf"))
    assert p.channels == 3
    out = p(L=L, V=V)
    assert out.shape == (4, 3)
    for i in range(4):
        np.testing.assert_array_equal(out[i], p(L=L, V=V[i]))


def test_params_inputs_source_and_pickle():
    k = lobe.compile(BLINN, n=30)
    assert list(k.params)[0] == "n" and k.params["n"] == 30
    assert k.inputs == ("NH",)
    assert "NH^n" in k.source and k.baked == {"n": 30.0} and k.math == "precise"
    k2 = pickle.loads(pickle.dumps(k))
    x = np.linspace(0, 1, 100)
    assert k2(NH=x).tobytes() == k(NH=x).tobytes()
    assert k2.baked == k.baked and k2.source == k.source
    t = lobe.compile("NH^n * 0.5\n", math="fast")
    t2 = pickle.loads(pickle.dumps(t))
    assert t2.math == "fast" and t2(NH=x, n=4).tobytes() == t(NH=x, n=4).tobytes()
    # A path object is read as a file.
    import pathlib

    assert lobe.compile(pathlib.Path(BLINN)).file.endswith("blinn.brdf")


def test_bad_formula_has_line_and_column():
    """A syntax error and an unknown name, each at its own line and column, with the caret text."""
    with pytest.raises(lobe.LobeError) as e:
        lobe.compile("# a comment\nparam a = 10 in 1..100\nNH^a + (1 +\n")
    d = e.value.diagnostics[0]
    assert d["severity"] == "error" and (d["line"], d["column"]) == (3, 11), d
    assert "after `+`" in d["message"] and d["hint"] and "<text>:3:11" in d["rendered"]
    assert len(e.value.diagnostics) == 2 and e.value.diagnostics[1]["message"] == "unterminated parenthesis"
    assert str(e.value).startswith("error: expected an operand")
    with pytest.raises(lobe.LobeError) as e:
        lobe.compile("param a = 10 in 1..100\n\n  NH^nn\n")
    d = e.value.diagnostics[0]
    assert (d["line"], d["column"], d["end_line"], d["end_column"]) == (3, 6, 3, 8), d
    assert d["file"] == "<text>" and "unknown variable `nn`" in d["message"] and d["label"] == "not defined"
    assert "^^ not defined" in d["rendered"]
    # A missing file (a path object is always a path) is an error naming it.
    import pathlib

    with pytest.raises(lobe.LobeError) as e:
        lobe.compile(pathlib.Path(ROOT) / "no-such.brdf")
    assert "no-such.brdf" in str(e.value)


def test_bad_calls_raise_lobe_error():
    k = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="neither an input nor a parameter"):
        k(NH=0.5, nn=3)
    with pytest.raises(lobe.LobeError, match="NH"):
        k(NL=0.5)
    with pytest.raises(lobe.LobeError, match="outside its declared range"):
        k(NH=0.5, n=-5)
    with pytest.raises(lobe.LobeError, match="broadcast"):
        k(NH=np.zeros(3), n=[1, 2])
    with pytest.raises(lobe.LobeError, match="broadcast"):
        k(NH=np.zeros(3), NL=np.zeros(4))
    with pytest.raises(lobe.LobeError, match="baked"):
        lobe.compile(BLINN, n=3)(NH=0.5, n=4)
    with pytest.raises(lobe.LobeError, match="no parameter"):
        lobe.compile(BLINN, q=3)
    g = lobe.compile(GGX)
    with pytest.raises(lobe.LobeError, match="directions"):
        g(NH=0.5)
    with pytest.raises(lobe.LobeError, match="no direction"):
        g(L=[0, 0, 0], V=[0, 0, 1])
    with pytest.raises(lobe.LobeError, match="shape"):
        g(L=[0, 1], V=[0, 0, 1])
    with pytest.raises(lobe.LobeError):
        lobe.compile(BLINN, math="sloppy")
    assert isinstance(lobe.LobeError("x"), Exception)


def test_reports_have_the_cli_keys(lobe_cli):
    import json

    k = lobe.compile(BLINN)
    # Baked, as the command's --set bakes: the same code, the same coefficient to the last bit.
    e = lobe.compile(BLINN, n=100).energy()
    cli = json.loads(lobe_cli("energy", BLINN, "--set", "n=100", "--json"))
    assert set(e) == set(cli) and e["coef"] == cli["coef"]
    # Live, the same to rounding.
    assert k.energy(n=100)["coef"] == pytest.approx(cli["coef"], rel=1e-13)
    full = k.energy(mode="full", n=10)
    assert {"coef", "albedo_max", "albedo"} <= set(full)
    s = k.sweep(max_evals=20_000)
    assert {"nan", "inf", "negative"} <= set(s)
    c = k.check(points=2000)
    cli = json.loads(lobe_cli("check", BLINN, "--points", "2000", "--json"))
    assert set(c) == set(cli) and c["simplified"] == cli["simplified"] and c["compiled"] == cli["compiled"]
    cli = json.loads(lobe_cli("sweep", BLINN, "--max-evals", "20000", "--json"))
    assert set(s) == set(cli) and s["nan"] == cli["nan"]
    ref = lobe.compile(os.path.join(ROOT, "examples", "brdfs", "phong.brdf"))
    a = lobe.compile(os.path.join(ROOT, "examples", "brdfs", "modified_schlick.brdf")).accuracy(k, n_max=50)
    cli = json.loads(lobe_cli("accuracy", os.path.join(ROOT, "examples", "brdfs", "modified_schlick.brdf"), "--reference", BLINN, "--n-max", "50", "--json"))
    assert set(a) - {"seconds"} == set(cli) - {"seconds"}
    assert a["mean_abs_grid"] == cli["mean_abs_grid"]
    assert ref.sweep(max_evals=20_000)["nan"] == 0
    path = os.path.join(ROOT, "examples", "explorer", "principled.brdf")
    p = lobe.compile(path)
    with pytest.raises(lobe.LobeError, match="minimum"):
        p.sweep(max_evals=200_000)
    # Every parameter baked but one: few combinations; a colour formula's sweep is per channel.
    baked = dict(list(p.params.items())[1:])
    s = lobe.compile(path, **baked).sweep(max_evals=200_000)
    assert set(s["channels"]) == {"red", "green", "blue"}


def test_fit_recovers_random_parameters():
    rng = np.random.default_rng(11)
    k = lobe.compile(BLINN)
    nh = rng.uniform(0, 1, 500)
    for true in rng.integers(2, 900, 3):
        r = lobe.fit(k, k(NH=nh, n=float(true)), {"n": (1, 1000)}, NH=nh)
        assert r["params"]["n"] == pytest.approx(float(true), abs=1e-6), r
        assert r["score"] <= 1e-20
    # Weights of zero leave points out; a target that is another formula fits somewhere inside the range.
    phong = lobe.compile(os.path.join(ROOT, "examples", "brdfs", "phong.brdf"))
    vr = rng.uniform(0, 1, 300)
    r = lobe.fit(k, phong(VR=vr, n=50), {"n": (1, 1000)}, NH=vr, weights=(vr > 0.5), loss="mae")
    assert 1 <= r["params"]["n"] <= 1000 and len(r["best"]) == 5
    with pytest.raises(lobe.LobeError):
        lobe.fit(k, 0.0, {"n": (0, 5000)}, NH=nh)
    with pytest.raises(lobe.LobeError):
        lobe.fit(k, 0.0, {"m": (1, 5)}, NH=nh)
    with pytest.raises(lobe.LobeError):
        lobe.fit(k, nh, {"n": (1, 5)}, NH=nh, weights=-np.ones(500))


def test_render_returns_an_image(root):
    img = lobe.render(os.path.join(root, "examples", "scenes", "paper_sphere.toml"), size=48)
    assert isinstance(img, lobe.Image) and img.shape == (48, 48, 3) and img.dtype == np.uint8
    png = img._repr_png_()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", png[16:24]) == (48, 48)
    assert img.max() > 0
    with pytest.raises(lobe.LobeError):
        lobe.render(os.path.join(root, "no-such-scene.toml"))


def test_a_panic_is_a_lobe_error():
    """A panic inside lobe (in a worker thread) is raised as LobeError; the interpreter carries on."""
    with pytest.raises(lobe.LobeError, match="internal error") as e:
        lobe._lobe._panic_for_tests()
    assert e.value.diagnostics and "deliberate panic" in e.value.diagnostics[0]["message"]
    assert lobe.compile(BLINN)(NH=0.5, n=2) == 0.25


@pytest.mark.parametrize("path", CATALOGUE)
def test_calls_with_plain_numbers_are_the_array_calls_bit_for_bit(path):
    """The per-call path (plain numbers: no arrays built) gives the values of the batched path, per point, at
    random inputs and parameters inside their ranges."""
    k = lobe.compile(path)
    rng = np.random.default_rng(7)
    live = {n: r for n, r in k.param_ranges.items()}
    directions = any(i not in ("NL", "NV", "NH", "VR", "VH") for i in k.inputs)
    for _ in range(20):
        params = {n: float(rng.uniform(lo, hi)) for n, (lo, hi) in live.items()}
        if directions:
            continue
        cos = {i: float(rng.uniform(0, 1)) for i in k.inputs}
        one = k(**cos, **params)
        arrays = k(**{i: np.array([v]) for i, v in cos.items()}, **params)
        a, b = np.asarray(one, dtype=np.float64).reshape(arrays.shape), np.asarray(arrays, dtype=np.float64)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_array_equal(a[~np.isnan(a)].view(np.uint64), b[~np.isnan(b)].view(np.uint64))
        assert isinstance(one, np.ndarray) and one.shape == (() if k.channels == 1 else (3,))


def test_the_per_call_path_keeps_the_errors():
    k = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="outside its declared range"):
        k(NH=0.5, n=5000)
    with pytest.raises(lobe.LobeError, match="NH"):
        k(NL=0.5)
    with pytest.raises(lobe.LobeError, match="neither an input nor a parameter"):
        k(NH=0.5, q=1)
    baked = lobe.compile(BLINN, n=20)
    with pytest.raises(lobe.LobeError, match="baked"):
        baked(NH=0.5, n=30)
    assert float(baked(NH=0.5)) == pytest.approx(float(k(NH=0.5, n=20)), rel=1e-12)


def test_out_receives_the_values_and_is_reused():
    k = lobe.compile(BLINN)
    nh = np.linspace(0, 1, 5000).reshape(50, 100)
    want = k(NH=nh, n=30.0)
    buf = np.full((50, 100), np.nan)
    got = k(NH=nh, n=30.0, out=buf)
    assert got is buf
    np.testing.assert_array_equal(buf.view(np.uint64), want.view(np.uint64))
    colour = lobe.compile("vec3(NH, NH^2, 1 - NH)")
    cbuf = np.empty((50, 100, 3))
    np.testing.assert_array_equal(colour(NH=nh, out=cbuf), colour(NH=nh))
    for bad in (np.empty((50, 99)), np.empty((50, 100), dtype=np.float32), np.empty((100, 50)).T, [0.0] * 5000):
        with pytest.raises(lobe.LobeError, match="out must be"):
            k(NH=nh, out=bad)
