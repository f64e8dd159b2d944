"""scipy.optimize.least_squares fed Kernel.jacobian reaches the answer `lobe fit` reaches with its own
Levenberg–Marquardt (tests/it/fit_grad.rs): both recover GGX's alpha and f0 from data made at random values."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

scipy_optimize = pytest.importorskip("scipy.optimize")

GGX = os.path.join(ROOT, "examples", "explorer", "ggx.brdf")


def test_least_squares_with_lobes_jacobian_agrees_with_lobe_fit(lobe_cli, tmp_path):
    rng = np.random.default_rng(4848)
    alpha, f0 = 0.1 + 0.8 * rng.random(), 0.1 + 0.8 * rng.random()
    # lobe fit: a synthetic MERL table of GGX, fitted under the rmse metric (residuals s·f − m).
    table = tmp_path / "ggx.binary"
    lobe_cli("tabulate", GGX, "--set", f"alpha={alpha},f0={f0}", "-o", str(table))
    out = json.loads(lobe_cli("fit", GGX, "--measured", str(table), "--param", "alpha=0.001..1", "--param", "f0=0..1",
                              "--metric", "rmse", "--stride", "3", "--grid-stride", "6", "--json"))
    assert out["refinement"] == "levenberg-marquardt"
    got = (out["params"]["alpha"], out["params"]["f0"])

    # scipy: the same model's values at random directions, the residuals f(p) − target, lobe's Jacobian.
    k = lobe.compile(GGX)
    def upper(n):
        d = rng.normal(size=(n, 3))
        d[:, 2] = np.abs(d[:, 2]) + 0.05
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    L, V = upper(2000), upper(2000)
    target = k(L=L, V=V, alpha=alpha, f0=f0)

    def residual(p):
        return k(L=L, V=V, alpha=p[0], f0=p[1]) - target

    def jac(p):
        return k.jacobian(["alpha", "f0"], L=L, V=V, alpha=p[0], f0=p[1])

    r = scipy_optimize.least_squares(residual, x0=[0.5, 0.5], jac=jac, bounds=([0.001, 0.0], [1.0, 1.0]), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert r.success
    for want, a, b in zip((alpha, f0), got, r.x):
        assert abs(a - want) <= 1e-6 * want, (got, alpha, f0)
        assert abs(b - want) <= 1e-6 * want, (r.x, alpha, f0)
        assert abs(a - b) <= 1e-6 * want, (got, r.x)
