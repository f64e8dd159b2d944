"""`Kernel.export`: GLSL, WGSL, BRDF Explorer and Mitsuba text, that of `lobe export` on the same inputs."""

import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

COOK = os.path.join(ROOT, "examples", "brdfs", "cook_torrance.brdf")
BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
PRINCIPLED = os.path.join(ROOT, "examples", "explorer", "principled.brdf")


def test_every_format_is_the_commands_text(lobe_cli):
    rng = np.random.default_rng(3)
    n, m = float(np.round(rng.uniform(2, 500), 3)), float(np.round(rng.uniform(0.05, 0.9), 3))
    k = lobe.compile(COOK)
    cases = [
        ("glsl", {}, ["--glsl"]),
        ("glsl", {"glsl_version": "es300"}, ["--glsl", "--glsl-version", "es300"]),
        ("glsl", {"glsl_version": "330"}, ["--glsl-version", "330"]),
        ("wgsl", {}, ["--wgsl"]),
        ("brdf", {}, ["--brdf-explorer"]),
    ]
    for fmt, kw, flags in cases:
        for params, sets in (({}, []), ({"n": n, "m": m}, ["--set", f"n={n},m={m}"])):
            assert k.export(fmt, **kw, **params) == lobe_cli("export", COOK, *flags, *sets), (fmt, kw, params)
    # Values baked at compile are baked in the export too.
    assert lobe.compile(COOK, n=n).export("wgsl", m=m) == lobe_cli("export", COOK, "--wgsl", "--set", f"n={n},m={m}")
    # A colour formula.
    assert lobe.compile(PRINCIPLED).export("glsl") == lobe_cli("export", PRINCIPLED)


def test_the_mitsuba_module_is_the_commands(lobe_cli):
    rng = np.random.default_rng(4)
    n = float(np.round(rng.uniform(5, 300), 2))
    k = lobe.compile(BLINN)
    text = k.export("mitsuba", n=n)
    assert text == lobe_cli("export", BLINN, "--mitsuba", "--set", f"n={n}")
    assert "lobe_blinn" in text
    assert k.export("mitsuba", mechanism="cosine", n=n) == lobe_cli("export", BLINN, "--mitsuba", "--mechanism", "cosine", "--set", f"n={n}")


def test_export_errors_are_lobe_errors_with_hints():
    k = lobe.compile(COOK)
    with pytest.raises(lobe.LobeError, match="unknown export format `hlsl`") as e:
        k.export("hlsl")
    assert "wgsl" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError) as e:
        k.export("glsl", glsl_version="460")
    assert "es300" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError) as e:
        k.export("mitsuba", mechanism="magic")
    assert "auto" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="neither an input nor a parameter") as e:
        k.export("glsl", mm=0.3)
    assert "m" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="input, not a parameter"):
        k.export("glsl", NH=0.3)
