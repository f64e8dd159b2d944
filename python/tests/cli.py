"""Where the `lobe` command-line binary is, for the tests and the benchmark (no pytest needed)."""

import os
import shutil

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def lobe_bin():
    """$LOBE_BIN, else target/release/lobe, else target/debug/lobe, else `lobe` on PATH (None if none)."""
    env = os.environ.get("LOBE_BIN")
    if env:
        return env
    for profile in ("release", "debug"):
        p = os.path.join(ROOT, "target", profile, "lobe")
        if os.path.isfile(p) and os.access(p, os.X_OK):
            return p
    return shutil.which("lobe")
