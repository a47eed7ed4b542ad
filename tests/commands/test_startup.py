"""`wamctl --help` and `--version` stay light (issue 16: under 0.3 s): they import typer, rich and the command
modules, never the scientific stack. The time itself is measured by benchmarks/bench_cli_start.py (no
wall-clock assertion here); what this test pins is the cause of a slow start-up, which fails on any machine."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("numpy", "pandas", "scipy", "matplotlib", "pinocchio", "pyarrow", "statsmodels", "can", "serial")

PROBE = """
import sys
sys.argv = ["wamctl", *sys.argv[1:]]
from wamctl.cli import main
try:
    main()
except SystemExit:
    pass
print("LOADED", " ".join(sorted(m for m in {heavy!r} if m in sys.modules)), file=sys.stderr)
"""


@pytest.mark.parametrize("args", [["--help"], ["--version"], ["run", "--help"], ["diagnose", "--help"]])
def test_help_and_version_import_no_scientific_module(args):
    r = subprocess.run([sys.executable, "-c", PROBE.format(heavy=HEAVY), *args], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    loaded = r.stderr.rsplit("LOADED", 1)[1].split()
    assert loaded == [], f"wamctl {' '.join(args)} imported {loaded}"
    assert r.stdout.strip()
