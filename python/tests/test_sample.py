"""Kernel.sample / Kernel.pdf (docs/sampling.md): the sampler of `lobe sample`, on numpy arrays."""

import json
import os

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")
WARD = os.path.join(ROOT, "examples", "explorer", "ward_anisotropic.brdf")
PRINCIPLED = os.path.join(ROOT, "examples", "explorer", "principled.brdf")


def direction(theta_deg, phi_deg=0.0):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.mark.parametrize("path", [BLINN, WARD, PRINCIPLED])
def test_sample_agrees_with_pdf_and_eval(path):
    """pdf from sample is pdf(wi, wo) bit for bit; weight is f·cosθo/pdf with f the kernel's value, 0 below the horizon."""
    k = lobe.compile(path)
    rng = np.random.default_rng(5)
    wi = np.stack([direction(t, p) for t, p in zip(rng.uniform(0, 89, 4000), rng.uniform(0, 360, 4000))])
    u = rng.random((4000, 2))
    wo, pdf, w = k.sample(wi, u)
    assert wo.shape == (4000, 3) and pdf.shape == (4000,)
    assert w.shape == ((4000,) if k.channels == 1 else (4000, 3))
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1.0, rtol=1e-12)
    assert np.array_equal(pdf, k.pdf(wi, wo))
    assert np.all(pdf > 0) and np.all(np.isfinite(w))
    f = k(L=wi, V=wo)
    cos = wo[:, 2] if k.channels == 1 else wo[:, 2:3]
    want = np.where(cos > 0, f * cos / (pdf if k.channels == 1 else pdf[:, None]), 0.0)
    np.testing.assert_allclose(w, want, rtol=1e-12, atol=0)


def test_albedo_from_samples_matches_the_command(lobe_cli):
    """The mean weight of 4·10⁵ samples at 30° is the albedo `lobe sample --json` integrates (3 stderr, 0.5 %)."""
    k = lobe.compile(BLINN)
    rng = np.random.default_rng(1)
    _, _, w = k.sample(direction(30.0), rng.random((400_000, 2)), n=40)
    q = json.loads(lobe_cli("sample", BLINN, "--set", "n=40", "--incidence", "30", "--count", "1000", "--json"))["albedo_quadrature"]
    err = w.std() / np.sqrt(w.size)
    assert abs(w.mean() - q) < 3 * err and abs(w.mean() - q) < 0.005 * q, (w.mean(), err, q)
    assert k.sampler_mechanism in ("tabulated", "exact", "cosine")


def test_broadcasting_and_parameters():
    k = lobe.compile(BLINN)
    u = np.random.default_rng(2).random((3, 5, 2))
    wo, pdf, w = k.sample(direction(40.0), u, n=100)
    assert wo.shape == (3, 5, 3) and pdf.shape == (3, 5) and w.shape == (3, 5)
    one = k.sample(direction(40.0), u[1, 2], n=100)
    assert np.array_equal(one[0], wo[1, 2]) and one[1] == pdf[1, 2]
    # Another n: another sampler, another density.
    assert not np.array_equal(k.pdf(direction(40.0), wo, n=10), pdf)


def test_bad_input_is_an_error():
    k = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="horizon"):
        k.sample(np.array([[0, 0, 1.0], [1.0, 0, -0.2]]), np.full((2, 2), 0.5))
    with pytest.raises(lobe.LobeError, match="flat index 1"):
        k.pdf(np.array([[0, 0, 1.0], [0, 0, 0.0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    with pytest.raises(lobe.LobeError, match=r"shape \(\.\.\., 2\)"):
        k.sample(direction(10.0), np.zeros(3))
    with pytest.raises(lobe.LobeError, match="outside its declared range"):
        k.sample(direction(10.0), np.zeros(2), n=-5)
