"""The numeric core must import without OCP (fresh interpreter)."""

import subprocess
import sys

CODE = (
    "import watertight_cli.core.bernstein, watertight_cli.core.bezier, watertight_cli.core.bspline, "
    "watertight_cli.core.compose, watertight_cli.core.approx, watertight_cli.core.reduce, "
    "watertight_cli.core.slender, sys; "
    "assert not any(m.startswith('OCP') for m in sys.modules), "
    "[m for m in sys.modules if m.startswith('OCP')]"
)


def test_core_imports_without_ocp():
    res = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
