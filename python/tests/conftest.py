"""Shared fixtures: the repository's catalogue and the `lobe` binary the command-line comparisons run."""

import glob
import os
import subprocess

import pytest

from cli import ROOT, lobe_bin

CATALOGUE = sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf")) + glob.glob(os.path.join(ROOT, "examples", "explorer", "*.brdf")))


@pytest.fixture(scope="session")
def lobe_cli():
    b = lobe_bin()
    if b is None:
        pytest.fail("no lobe binary: build it (cargo build --release) or set LOBE_BIN")

    def run(*args):
        r = subprocess.run([b, *args], capture_output=True, text=True, cwd=ROOT)
        assert r.returncode == 0, f"lobe {' '.join(args)} failed:\n{r.stderr}"
        return r.stdout

    return run


@pytest.fixture(scope="session")
def root():
    return ROOT
