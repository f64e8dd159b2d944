"""`lobe.fit` against a measured table and against another formula: the numbers of `lobe fit --measured` and
`lobe fit --reference` (`--json`) on the same inputs."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
FST = os.path.join(ROOT, "examples", "brdfs", "fst.brdf")
SCHLICK = os.path.join(ROOT, "examples", "brdfs", "modified_schlick.brdf")
BECKMANN = os.path.join(ROOT, "examples", "brdfs", "beckmann.brdf")
GGX = os.path.join(ROOT, "examples", "explorer", "ggx.brdf")

# Timings, and the path the command names the table by.
VARYING = {"seconds"}


def same_report(mine, theirs, rtol=0.0):
    for key in theirs:
        if key in VARYING:
            continue
        a, b = mine[key], theirs[key]
        if rtol and isinstance(b, float):
            assert a == pytest.approx(b, rel=rtol), key
        elif rtol and isinstance(b, dict):
            assert a == pytest.approx(b, rel=rtol), key
        else:
            assert a == b, key


def test_fit_to_a_table_is_the_commands(lobe_cli, tmp_path):
    rng = np.random.default_rng(11)
    n = float(np.round(rng.uniform(20, 300), 2))
    table = str(tmp_path / "blinn.binary")
    lobe.compile(BLINN).tabulate(table, color=(0.9, 0.7, 0.5), n=n)
    for metric in ("log", "rmse", "cosine"):
        theirs = json.loads(lobe_cli("fit", SCHLICK, "--measured", table, "--param", "n=1..1000", "--stride", "3", "--metric", metric, "--json"))
        mine = lobe.fit(lobe.compile(SCHLICK), lobe.load_measured(table), {"n": (1, 1000)}, stride=3, metric=metric)
        same_report(mine, theirs)
        assert mine["best"][0]["error"] == theirs["error"] and mine["best"][0]["scale"] == theirs["scale"]
        assert set(mine) == set(theirs) | {"best"}
    # The derivative-free refinement and another grid stride are the command's flags.
    theirs = json.loads(lobe_cli("fit", SCHLICK, "--measured", table, "--param", "n=1..1000", "--stride", "4", "--grid-stride", "6", "--derivative-free", "--json"))
    mine = lobe.fit(lobe.compile(SCHLICK), lobe.load_measured(table), {"n": (1, 1000)}, stride=4, grid_stride=6, derivative_free=True)
    same_report(mine, theirs)
    assert mine["refinement"] == "derivative-free"


def test_fit_to_a_formula_over_the_hemisphere_is_the_commands(lobe_cli):
    """GGX against Beckmann at a random m (`--measured REF.brdf --set`), and GGX against Blinn (`--reference`,
    which compares over the hemisphere since GGX reads no n): absolute values, or a fitted scale."""
    rng = np.random.default_rng(5)
    m = float(np.round(rng.uniform(0.1, 0.5), 3))
    theirs = json.loads(lobe_cli("fit", GGX, "--measured", BECKMANN, "--param", "alpha=0.01..1", "--set", f"m={m}", "--stride", "4", "--json"))
    mine = lobe.fit(lobe.compile(GGX), lobe.compile(BECKMANN), {"alpha": (0.01, 1)}, set={"m": m}, stride=4)
    # The command bakes m into the reference, Python gives it as a value: the same formula to rounding.
    same_report(mine, theirs, rtol=1e-9)
    assert mine["scale"] == [1.0, 1.0, 1.0]
    theirs = json.loads(lobe_cli("fit", GGX, "--reference", BLINN, "--param", "alpha=0.01..1", "--stride", "4", "--fit-scale", "--json"))
    mine = lobe.fit(lobe.compile(GGX), lobe.compile(BLINN), {"alpha": (0.01, 1)}, stride=4, fit_scale=True)
    same_report(mine, theirs)
    assert mine["scale"] != [1.0, 1.0, 1.0]


def test_the_papers_fit_where_both_read_n(lobe_cli):
    theirs = json.loads(lobe_cli("fit", FST, "--reference", BLINN, "--param", "a=260..280", "--json", "--quiet"))
    mine = lobe.fit(lobe.compile(FST), lobe.compile(BLINN), {"a": (260, 280)})
    same_report(mine, theirs)
    assert mine["params"] == theirs["best"][0]["params"]
    theirs = json.loads(lobe_cli("fit", FST, "--reference", BLINN, "--param", "a=200..300:10", "--metric", "max-abs", "--no-refine", "--json", "--quiet"))
    mine = lobe.fit(lobe.compile(FST), lobe.compile(BLINN), {"a": (200, 300, 10)}, metric="max-abs", refine=False)
    same_report(mine, theirs)


def test_fits_against_tables_and_formulas_refuse_bad_arguments(tmp_path):
    ggx, blinn = lobe.compile(GGX), lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="papers' metrics sweep n, and ggx reads no n") as e:
        lobe.fit(ggx, blinn, {"alpha": (0.01, 1)}, metric="mean-abs")
    assert "whole hemisphere" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="metric") as e:
        lobe.fit(lobe.compile(FST), blinn, {"a": (1, 100)}, metric="log")
    assert e.value.diagnostics[0]["hint"]
    table = blinn.tabulate(tmp_path / "t.binary", n=20)
    with pytest.raises(lobe.LobeError, match="always fitted"):
        lobe.fit(lobe.compile(SCHLICK), table, {"n": (1, 100)}, fit_scale=False)
    with pytest.raises(lobe.LobeError, match="no formula has a parameter `mm`") as e:
        lobe.fit(ggx, lobe.compile(BECKMANN), {"alpha": (0.01, 1)}, set={"mm": 0.3})
    assert "alpha" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="takes no points"):
        lobe.fit(ggx, table, {"alpha": (0.01, 1)}, NH=0.5)
    with pytest.raises(lobe.LobeError, match="declared"):
        lobe.fit(ggx, table, {"alpha": (0.01, 2)})
    with pytest.raises(lobe.LobeError, match="stride"):
        lobe.fit(ggx, table, {"alpha": (0.01, 1)}, stride=0)
    with pytest.raises(lobe.LobeError, match="stride"):
        lobe.fit(ggx, table, {"alpha": (0.01, 1)}, stride=91)
    with pytest.raises(lobe.LobeError, match="top"):
        lobe.fit(ggx, table, {"alpha": (0.01, 1)}, top=-1)
    with pytest.raises(lobe.LobeError, match="reads none of the parameters"):
        lobe.fit(ggx, table, {"n": (1, 100)})
    nan = lobe.compile("param a = 1 in 1..4\n0*NH/0 + a")
    with pytest.raises(lobe.LobeError, match="no candidate has a finite error") as e:
        lobe.fit(nan, table, {"a": (1, 4)}, stride=8)
    assert "lobe sweep" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="apply to fits against"):
        lobe.fit(ggx, np.zeros(3), {"alpha": (0.01, 1)}, metric="log", NH=np.zeros(3))
