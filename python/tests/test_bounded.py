"""Hostile calls get a LobeError (or a right result) in bounded time: never NaN for a mistake, a bare Python
exception or an aborted interpreter."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import lobe
from conftest import ROOT

BLINN = os.path.join(ROOT, "examples", "brdfs", "blinn.brdf")


def test_none_is_no_value():
    k = lobe.compile(BLINN)
    with pytest.raises(lobe.LobeError, match="`n` is None"):
        k(NH=0.5, n=None)
    with pytest.raises(lobe.LobeError, match="`NH` is None"):
        k(NH=None)
    with pytest.raises(lobe.LobeError, match="`n` is None"):
        k.energy(n=None)


@pytest.mark.parametrize("points", [-1, 0, 2.5, True, "10"])
def test_check_refuses_a_bad_point_count(points):
    with pytest.raises(lobe.LobeError, match="a whole number"):
        lobe.compile(BLINN).check(points=points)


def test_fit_refuses_a_target_that_is_not_finite():
    k = lobe.compile(BLINN)
    nh = np.linspace(0, 1, 50)
    for bad in (np.nan, np.inf):
        t = k(NH=nh, n=30.0)
        t[7] = bad
        with pytest.raises(lobe.LobeError, match="the target is .* at point 7"):
            lobe.fit(k, t, {"n": (1, 1000)}, NH=nh)


@pytest.mark.parametrize("body", ["f{j}(x) + f{j}(x)", "f{j}(x) * f{j}(x)", "f{j}(x) + f{j}(x + 1)"])
def test_self_doubling_functions_answer_in_a_fresh_interpreter(body, lobe_cli, tmp_path):
    """40 functions, each calling the one before twice (2^40 calls written out): the same value as the
    command line, in a separate interpreter so that an abort would fail the test instead of ending the run."""
    src = "fn f0(x) = x*NH + NV\n" + "".join(f"fn f{i}(x) = {body.replace('{j}', str(i - 1))}\n" for i in range(1, 41)) + "f40(NH)\n"
    path = tmp_path / "chain.brdf"
    path.write_text(src)
    script = textwrap.dedent(
        f"""
        import lobe
        try:
            print(repr(float(lobe.compile({str(path)!r})(NH=0.5, NV=0.25))))
        except lobe.LobeError as e:
            print("LobeError", e)
        """
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    want = float(lobe_cli("eval", str(path), "--at", "NH=0.5,NV=0.25", "--no-cache").strip())
    assert float(r.stdout) == want, r.stdout


def test_errors_are_value_errors_and_paths_are_not_formulas(tmp_path):
    assert issubclass(lobe.LobeError, ValueError)
    with pytest.raises(ValueError):
        lobe.compile("NH +")
    for typo in ["examples/brdfs/blin.brdf", "blinn.brdf", str(tmp_path / "missing.brdf")]:
        with pytest.raises(FileNotFoundError):
            lobe.compile(typo)
    # Formula text with `/` and `.` stays formula text.
    assert lobe.compile("NH/2.5")(NH=1.0) == 0.4


def test_the_namespace_is_the_public_api():
    names = set(dir(lobe))
    assert {"compile", "Kernel", "LobeError", "fit", "render", "Image", "__version__"} <= names
    assert {"Measured", "load_measured", "compare", "plot"} <= names
    assert not names & {"np", "os", "re", "Any", "Optional", "errno"}
    assert sorted(dir(lobe)) == sorted(set(dir(lobe))), "a name listed twice"
    # Every public name and Kernel method is typed in the stubs.
    import ast
    stubs = ast.parse(open(os.path.join(os.path.dirname(lobe.__file__), "__init__.pyi")).read())
    typed = {n.name for n in stubs.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    assert names - {"__version__"} <= typed
    kernel = next(n for n in stubs.body if isinstance(n, ast.ClassDef) and n.name == "Kernel")
    methods = {n.name for n in kernel.body if isinstance(n, ast.FunctionDef)}
    assert {m for m in dir(lobe.Kernel) if not m.startswith("_")} <= methods
