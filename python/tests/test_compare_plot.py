"""`lobe.compare` and `lobe.plot`: the metrics, pictures and plotted numbers of `lobe compare` and `lobe plot`
on the same inputs."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
PHONG = os.path.join(ROOT, "examples", "brdfs", "phong.brdf")
SCHLICK = os.path.join(ROOT, "examples", "brdfs", "modified_schlick.brdf")
WARD = os.path.join(ROOT, "examples", "brdfs", "ward.brdf")
SPHERE = os.path.join(ROOT, "examples", "scenes", "paper_sphere.toml")


def test_compare_is_the_commands(lobe_cli, tmp_path):
    rng = np.random.default_rng(8)
    n = float(np.round(rng.uniform(5, 400), 2))
    out = tmp_path / "cmp.png"
    theirs = json.loads(lobe_cli("compare", BLINN, SCHLICK, "--set", f"n={n}", "--size", "48x40", "--json", "-o", str(out)))
    mine = lobe.compare(lobe.compile(BLINN), lobe.compile(SCHLICK), size=(48, 40), n=n)
    for key, value in theirs.items():
        assert mine[key + "_name" if key in ("a", "b") else key] == value, key
    assert mine["a"].shape == mine["b"].shape == mine["difference"].shape == (40, 48, 3)
    assert isinstance(mine["figure"], lobe.Image)
    assert mine["figure"].png() == out.read_bytes()
    # The same render as lobe.render of the scene with the formula: A is Blinn's picture.
    assert not np.array_equal(mine["a"], mine["b"])
    assert mine["difference"].max() > 0
    # A baked value is the comparison's value; a scene file and a measured table saved to a file.
    table = lobe.compile(PHONG).tabulate(tmp_path / "phong.binary", n=n)
    theirs = json.loads(lobe_cli("compare", BLINN, str(tmp_path / "phong.binary"), "--scene", SPHERE, "--set", f"n={n}", "--size", "32", "--json"))
    mine = lobe.compare(lobe.compile(BLINN, n=n), table, scene=SPHERE, size=32)
    for key, value in theirs.items():
        assert mine[key + "_name" if key in ("a", "b") else key] == value, key


def test_compare_errors():
    b = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="neither formula declares a parameter `q`") as e:
        lobe.compare(b, lobe.compile(SCHLICK), size=16, q=2)
    assert e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="not saved to a file") as e:
        lobe.compare(b, b.tabulate(n=10), size=16)
    assert "save" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="baked at"):
        lobe.compare(lobe.compile(BLINN, n=10), lobe.compile(SCHLICK, n=20), size=16)
    with pytest.raises(lobe.LobeError, match="image size"):
        lobe.compare(b, b, size=0)


def plotted(lobe_cli, tmp_path, *args):
    out = tmp_path / "plot.png"
    j = json.loads(lobe_cli("plot", *args, "-o", str(out), "--json"))
    return j, out.read_bytes()


def test_plot_is_the_commands(lobe_cli, tmp_path):
    rng = np.random.default_rng(12)
    n = float(np.round(rng.uniform(2, 200), 2))
    table = lobe.compile(PHONG).tabulate(tmp_path / "phong.binary", n=n)
    cases = [
        ((BLINN, SCHLICK), {}, ()),
        ((BLINN, SCHLICK), {"log": True, "ylim": (1e-3, 2.0)}, ("--log", "--ylim", "0.001,2")),
        ((BLINN, WARD), {"incidence": 30.0, "polar": True}, ("--incidence", "30", "--polar")),
        ((SCHLICK, str(tmp_path / "phong.binary")), {"incidence": 45.0, "size": (400, 300)}, ("--incidence", "45", "--size", "400x300")),
    ]
    for files, kw, flags in cases:
        items = [table if f.endswith(".binary") else lobe.compile(f) for f in files]
        j, png = plotted(lobe_cli, tmp_path, *files, "--set", f"n={n}", *flags)
        image, data = lobe.plot(*items, n=n, **kw)
        assert data["title"] == j["title"] and data["x_label"] == j["x"] and data["y_label"] == j["y"]
        assert list(data["y"]) == [s["name"] for s in j["series"]]
        for s in j["series"]:
            np.testing.assert_array_equal(data["x"], s["x"])
            ys = np.array([np.nan if v is None or isinstance(v, str) else v for v in s["y"]], dtype=float)
            np.testing.assert_array_equal(data["y"][s["name"]], ys)
        assert image.png() == png, (files, kw)
    # The error against a reference.
    j, png = plotted(lobe_cli, tmp_path, SCHLICK, "--reference", BLINN, "--error", "--set", f"n={n}")
    image, data = lobe.plot(lobe.compile(SCHLICK), reference=lobe.compile(BLINN), error=True, n=n)
    assert data["title"] == j["title"] and data["y_label"] == j["y"] and image.png() == png


def test_a_table_in_a_plot_is_its_lookup(lobe_cli, tmp_path):
    """`Measured.values` against the command's plot of the table in the plane of incidence."""
    lobe.compile(BLINN).tabulate(tmp_path / "b.binary", color=(1.0, 0.5, 0.25), n=40)
    t = lobe.load_measured(tmp_path / "b.binary")
    j, _ = plotted(lobe_cli, tmp_path, str(tmp_path / "b.binary"), "--incidence", "35")
    th = np.radians(np.array(j["series"][0]["x"]))
    ti = np.radians(35.0)
    L = np.array([np.sin(ti), 0.0, np.cos(ti)])
    V = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    v = t.values(L, V)
    for c in range(3):
        np.testing.assert_array_equal(v[:, c], j["series"][c]["y"])


def test_plot_errors():
    b = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="outside 0..90"):
        lobe.plot(b, incidence=95)
    with pytest.raises(lobe.LobeError, match="cartesian"):
        lobe.plot(b, polar=True, log=True)
    with pytest.raises(lobe.LobeError, match="not an interval"):
        lobe.plot(b, ylim=(2, 1))
    with pytest.raises(lobe.LobeError, match="nothing to plot"):
        lobe.plot()
    with pytest.raises(lobe.LobeError, match="needs a reference"):
        lobe.plot(b, error=True)
    with pytest.raises(lobe.LobeError, match="plot size") as e:
        lobe.plot(b, size=(10, 10))
    assert e.value.diagnostics[0]["hint"]
    with pytest.raises(TypeError):
        lobe.plot(b, "examples/brdfs/phong.brdf")
