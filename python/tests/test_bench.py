"""`Kernel.bench`: one row of `lobe bench --json`, its keys and its measured (not timed) columns equal."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
SCHLICK = os.path.join(ROOT, "examples", "brdfs", "modified_schlick.brdf")
COOK = os.path.join(ROOT, "examples", "brdfs", "cook_torrance.brdf")
PRINCIPLED = os.path.join(ROOT, "examples", "explorer", "principled.brdf")
FAST = ["--samples", "3", "--timing-points", "256"]
# Timings differ from run to run; everything else is computed.
TIMED = {"compile_us", "pass_ms", "jit_ns", "jit_spread", "jit_batch_ns", "interp_ns", "native_ns", "plain_jit_ns", "plain_jit_spread", "plain_jit_batch_ns", "tiers", "pareto"}


def same_row(mine, theirs):
    assert set(mine) - {"channels"} == set(theirs)
    for key, value in theirs.items():
        if key in TIMED:
            continue
        got = mine[key]
        if value == "NaN":
            assert isinstance(got, str) and got == "NaN" or got != got, key
        else:
            assert got == value, key


def test_a_bench_row_is_the_commands(lobe_cli):
    rng = np.random.default_rng(21)
    n = float(np.round(rng.uniform(5, 300), 2))
    for path, extra in ((SCHLICK, []), (COOK, ["--no-albedo"])):
        [theirs] = json.loads(lobe_cli("bench", path, "--json", "--set", f"n={n}", *FAST, *extra))
        mine = lobe.compile(path).bench(samples=3, timing_points=256, albedo=not extra, n=n)
        same_row(mine, theirs)
        assert mine["file"] == path and mine["jit_ns"] > 0
    # The default n is the command's 50, the reference another formula's.
    [theirs] = json.loads(lobe_cli("bench", SCHLICK, "--json", "--reference", BLINN, "--math", "fast", "--no-albedo", *FAST))
    same_row(lobe.compile(SCHLICK).bench(reference=lobe.compile(BLINN), math="fast", samples=3, timing_points=256, albedo=False), theirs)


def test_a_colour_formula_has_a_row_per_channel(lobe_cli):
    rows = json.loads(lobe_cli("bench", PRINCIPLED, "--json", "--no-albedo", *FAST))
    mine = lobe.compile(PRINCIPLED).bench(samples=3, timing_points=256, albedo=False)
    assert len(mine["channels"]) == len(rows) == 3
    for m, t in zip(mine["channels"], rows):
        same_row(m, t)
    assert mine["name"] == rows[0]["name"]


def test_bench_errors():
    k = lobe.compile(SCHLICK)
    with pytest.raises(lobe.LobeError, match="math"):
        k.bench(math="quick")
    with pytest.raises(lobe.LobeError, match="samples"):
        k.bench(samples=0)
    with pytest.raises(lobe.LobeError) as e:
        k.bench(tier="gpu")
    assert "cranelift" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="neither an input nor a parameter"):
        k.bench(q=3)
    with pytest.raises(TypeError):
        k.bench(reference="blinn")
