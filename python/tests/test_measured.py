"""Measured tables from Python: `Kernel.tabulate` writes `lobe tabulate`'s file, `load_measured` reads it as the
command does, `Measured.values` is the table's lookup."""

import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
COOK = os.path.join(ROOT, "examples", "brdfs", "cook_torrance.brdf")


def test_tabulate_writes_the_commands_file(lobe_cli, tmp_path):
    rng = np.random.default_rng(31)
    n, m = float(np.round(rng.uniform(5, 200), 3)), float(np.round(rng.uniform(0.05, 0.6), 3))
    color = tuple(float(c) for c in np.round(rng.uniform(0.2, 1.0, 3), 3))
    k = lobe.compile(COOK)
    mine = k.tabulate(tmp_path / "py.binary", color=color, n=n, m=m)
    theirs = tmp_path / "cli.binary"
    lobe_cli("tabulate", COOK, "--set", f"n={n},m={m}", "--color", ",".join(map(str, color)), "-o", str(theirs))
    assert (tmp_path / "py.binary").read_bytes() == theirs.read_bytes()
    assert mine.path == str(tmp_path / "py.binary")
    assert mine.to_bytes() == theirs.read_bytes()
    # Read back: the same table, as many entries measured.
    t = lobe.load_measured(theirs)
    assert t.measured_entries == mine.measured_entries
    assert 0 < t.measured_entries < lobe.Measured.entries == 90 * 90 * 180
    assert t.channels == 3 and t.name == str(theirs)
    assert "entries measured" in repr(t)
    # An in-memory table has no path until saved.
    assert k.tabulate(n=n).path is None


def test_values_are_the_lookup_of_the_tabulated_formula():
    """A smooth lobe tabulated, looked up between its entries: close to the formula (multilinear), and exactly
    the stored value at an entry's own directions; shapes broadcast; below the horizon 0."""
    rng = np.random.default_rng(7)
    k = lobe.compile(BLINN)
    t = k.tabulate(n=3)
    th_i, th_o, ph = rng.uniform(0.05, 1.2, 400), rng.uniform(0.05, 1.2, 400), rng.uniform(0, 2 * np.pi, 400)
    L = np.stack([np.sin(th_i), np.zeros_like(th_i), np.cos(th_i)], -1)
    V = np.stack([np.sin(th_o) * np.cos(ph), np.sin(th_o) * np.sin(ph), np.cos(th_o)], -1)
    v = t.values(L, V)
    assert v.shape == (400, 3)
    f = k(L=L, V=V, n=3)
    np.testing.assert_allclose(v[:, 0], f, rtol=0.02, atol=1e-3)
    np.testing.assert_allclose(v[:, 0], v[:, 1], rtol=1e-15)
    # Nearest reads one entry: a step function, still near the formula at n = 3.
    near = t.values(L, V, lookup="nearest")
    assert not np.array_equal(near, v)
    np.testing.assert_allclose(near[:, 0], f, rtol=0.2, atol=0.02)
    # L at the normal, V at the mirror direction: θ_h = θ_d = 0, entry (0, 0, 0) exactly.
    z = np.array([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(t.values(z, z), [1.0, 1.0, 1.0])
    assert t.values(z, np.array([[0, 0, 1.0], [0.6, 0, -0.8]])).shape == (2, 3)
    np.testing.assert_array_equal(t.values(z, [0.6, 0, -0.8]), [0, 0, 0])


def test_bad_tables_and_arguments_raise_lobe_errors(tmp_path):
    bad = tmp_path / "short.binary"
    bad.write_bytes(b"\x5a\x00\x00\x00" * 3 + b"\x00" * 16)
    with pytest.raises(lobe.LobeError) as e:
        lobe.load_measured(bad)
    assert e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError):
        lobe.load_measured(tmp_path / "missing.binary")
    k = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="named .binary") as e:
        k.tabulate(tmp_path / "t.bin")
    assert e.value.diagnostics[0]["hint"] == "e.g. save('gold.binary')"
    with pytest.raises(lobe.LobeError, match="three finite factors"):
        k.tabulate(color=(1, -1, 1))
    with pytest.raises(lobe.LobeError, match="outside its declared range"):
        k.tabulate(n=0)
    t = k.tabulate(n=10)
    with pytest.raises(lobe.LobeError, match="lookup") as e:
        t.values([0, 0, 1], [0, 0, 1], lookup="cubic")
    assert "nearest" in e.value.diagnostics[0]["hint"]
    with pytest.raises(lobe.LobeError, match="no direction"):
        t.values([[0, 0, 1], [0, 0, 0]], [0, 0, 1])
    with pytest.raises(lobe.LobeError, match=r"\(\.\.\., 3\)"):
        t.values([0, 1], [0, 0, 1])
    with pytest.raises(TypeError):
        lobe.Measured()
