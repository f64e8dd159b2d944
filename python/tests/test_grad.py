"""Kernel.grad and Kernel.jacobian against `lobe eval --grad` (bit for bit) and against themselves."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT
from test_kernel import bits, random_dirs

GGX = os.path.join(ROOT, "examples", "explorer", "ggx.brdf")
BECKMANN = os.path.join(ROOT, "examples", "brdfs", "beckmann.brdf")


def test_grad_is_the_command_lines(lobe_cli, tmp_path):
    rng = np.random.default_rng(48)
    L, V = random_dirs(rng, 40), random_dirs(rng, 40)
    k = lobe.compile(GGX)
    g = k.grad(L=L, V=V, alpha=0.3)
    csv = tmp_path / "dirs.csv"
    rows = ["Lx,Ly,Lz,Vx,Vy,Vz,alpha"] + [",".join(repr(float(x)) for x in (*l, *v, 0.3)) for l, v in zip(L, V)]
    csv.write_text("\n".join(rows) + "\n")
    out = json.loads(lobe_cli("eval", GGX, "--points", str(csv), "--grad", "--json"))
    assert list(g) == list(out["grad"])
    for name, want in out["grad"].items():
        want = np.array([float(x) for x in want])
        assert (bits(g[name]) == bits(want)).all(), name
    assert (bits(k(L=L, V=V, alpha=0.3)) == bits(np.array([float(x) for x in out["values"]]))).all()


def test_grad_broadcasts_and_matches_differences():
    k = lobe.compile(BECKMANN)
    nh = np.linspace(0.3, 0.95, 12).reshape(3, 4)
    g = k.grad(NH=nh, m=0.4)
    assert set(g) == {"n", "m", "NH"} and g["NH"].shape == (3, 4)
    h = 1e-6
    fd = (k(NH=nh, m=0.4 + h) - k(NH=nh, m=0.4 - h)) / (2 * h)
    assert np.allclose(g["m"], fd, rtol=1e-6, atol=0)
    fd = (k(NH=nh + h, m=0.4) - k(NH=nh - h, m=0.4)) / (2 * h)
    assert np.allclose(g["NH"], fd, rtol=1e-6, atol=0)


def test_jacobian_rows_are_values_and_columns_parameters():
    k = lobe.compile(GGX)
    rng = np.random.default_rng(7)
    L, V = random_dirs(rng, 10), random_dirs(rng, 10)
    J = k.jacobian(L=L, V=V)
    live = [p for p in k.params if p not in k.baked]
    assert J.shape == (10, len(live))
    g = k.grad(L=L, V=V)
    for j, p in enumerate(live):
        assert (bits(J[:, j]) == bits(g[p])).all()
    J2 = k.jacobian(["f0"], L=L, V=V)
    assert (bits(J2[:, 0]) == bits(g["f0"])).all()
    with pytest.raises(lobe.LobeError, match="not a parameter"):
        k.jacobian(["nope"], L=L, V=V)
    with pytest.raises(lobe.LobeError, match="one value per parameter"):
        k.grad(L=L, V=V, alpha=np.linspace(0.1, 0.5, 10))


def test_jacobian_drives_least_squares():
    opt = pytest.importorskip("scipy.optimize")
    k = lobe.compile(GGX)
    rng = np.random.default_rng(3)
    L, V = random_dirs(rng, 200), random_dirs(rng, 200)
    up = (L[:, 2] > 0.05) & (V[:, 2] > 0.05)
    L, V = L[up], V[up]
    target = k(L=L, V=V, alpha=0.25, f0=0.08)

    def residual(p):
        return k(L=L, V=V, alpha=p[0], f0=p[1]) - target

    def jac(p):
        return k.jacobian(["alpha", "f0"], L=L, V=V, alpha=p[0], f0=p[1])

    lo, hi = k.param_ranges["alpha"], k.param_ranges["f0"]
    r = opt.least_squares(residual, [0.5, 0.5], jac=jac, bounds=([lo[0], hi[0]], [lo[1], hi[1]]), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.allclose(r.x, [0.25, 0.08], rtol=1e-6)
