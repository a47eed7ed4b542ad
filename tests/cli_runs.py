"""The command line run in-process (``wamctl.cli.main`` with ``sys.exit`` caught), and one small run of every
kind made through it once per test session, with what each command printed at 80 columns.

Used by the terminal test (tests/commands/test_terminal.py), the browser test (tests/report/test_browser.py)
and the fuzz test (tests/commands/test_fuzz.py). The runs are made once per session, for every pytest-xdist worker
(tests/once.py). Every run is small (a few seconds of arm time); the specs are
written here, in code.
"""

from __future__ import annotations

import io
import logging
import os
import subprocess
import sys
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml
from once import make_once

ROOT = Path(__file__).resolve().parents[1]
Q0 = [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0]


@dataclass
class CliResult:
    code: int
    out: str
    err: str
    exc: BaseException | None = None      # an exception that escaped main(): a traceback for a user
    tb: str = ""


def run_cli(*args, columns: int | None = 80, log_to_err: bool = False) -> CliResult:
    """``wamctl ARGS`` in this process, as a terminal of ``columns`` would show it: the exit code, stdout and
    stderr. An exception escaping ``main()`` (what a user would see as a traceback) is returned, not raised.

    ``log_to_err``: the warnings the command logs are written to its stderr, as in a process of its own
    (``wamctl.cli`` sets logging up with ``basicConfig``, which does nothing in a process whose root logger has
    handlers already, as pytest's has): for a test of what stderr holds when a warning comes before an error."""
    from wamctl.cli import main

    out, err = io.StringIO(), io.StringIO()
    old_argv, old_cols = sys.argv, os.environ.get("COLUMNS")
    sys.argv = ["wamctl", *map(str, args)]
    if columns is not None:
        os.environ["COLUMNS"] = str(columns)
    code, exc, tb = 0, None, ""
    root, handler = logging.getLogger(), None
    if log_to_err:        # basicConfig's handler (stream, format) at the command's default level, WARNING
        handler = logging.StreamHandler(err)
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        handler.setLevel(logging.WARNING)
        root.addHandler(handler)
    try:
        with redirect_stdout(out), redirect_stderr(err):
            try:
                main()
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            except BaseException as e:  # noqa: BLE001 - this is what the test looks for
                code, exc, tb = 1, e, traceback.format_exc()
    finally:
        if handler is not None:
            root.removeHandler(handler)
        sys.argv = old_argv
        if old_cols is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old_cols
    return CliResult(code, out.getvalue(), err.getvalue(), exc, tb)


def wamctl_completed(*args, columns: int | None = 80, log_to_err: bool = False) -> subprocess.CompletedProcess:
    """``run_cli`` as ``subprocess.run`` would return it, for tests written against a process: stderr is what a
    user would see, an exception escaping ``main()`` as its traceback. A command run this way costs no new Python
    (2.5 s of CPU each for the imports and the compiled kernels' cache): tests whose subject is not the process
    itself (a signal, a killed process, start-up, settings read once per process) use it."""
    r = run_cli(*args, columns=columns, log_to_err=log_to_err)
    return subprocess.CompletedProcess(["wamctl", *map(str, args)], r.code, r.out, r.err + r.tb)


def write_yaml(path: Path, obj) -> Path:
    path.write_text(yaml.safe_dump(obj, sort_keys=False))
    return path


# Small specs of every kind (what a user would write for a quick look)
ROTATION = {"kind": "rotation", "name": "rot", "seed": 3, "plant": {"friction": "table_4_1"}, "q0_rad": Q0,
            "rotation": {"joints": [1, 4, 7], "mode": "all_together", "hold_s": 0.3, "settle_s": 0.0}}
FRICTION = {"kind": "friction_sweep", "name": "fs", "seed": 5,
            "plant": {"friction": "table_4_1", "sensors": {"position_noise_rad": 2.0e-5}},
            "sweep": {"joints": [7], "velocities_rad_s": [0.05, 0.1, 0.2, 0.5, 1.0], "travel_rad": {7: 1.0},
                      "cruise_s": 1.0}}
# one joint, a payload the model lacks, two iterations: the gains end at their bounds (kp 4x the start)
IFT = {"kind": "ift", "name": "ift", "seed": 5, "controller": {"kind": "pid"}, "q0_rad": Q0,
       "plant": {"friction": "table_4_1", "effects": {"payload": {"mass_kg": 0.3, "com_m": [0.0, 0.0, 0.05]}}},
       "ift": {"joints": [7], "task": {"settle_s": 0.2, "hold_s": 0.5}, "max_iterations": 2,
               "schedule": [{"method": "bfgs", "gamma": 0.5, "iterations": 1}, {"method": "gauss_newton", "gamma": 2.0},
                            {"method": "gauss_newton", "gamma": 0.5}]}}
HMI = {"kind": "hmi_block", "name": "hmi", "seed": 1,
       "hmi": {"subject": {"id": "S1", "seed": 11, "skill": 0.9}, "locations": ["P1", "P4"]}}
SWEEP = {"kind": "rotation", "name": "tiny", "seed": 0, "q0_rad": Q0,
         "plant": {"friction": "table_4_1", "sensors": {"position_noise_rad": 1e-4}},
         "rotation": {"joints": [1, 7], "mode": "all_together", "amplitude_rad": 0.05, "velocity_rad_s": 0.25,
                      "tc_s": 0.1, "settle_s": 0.0, "hold_s": 0.1},
         "vary": {"grid": {"seed": [1, 2]}}}


@dataclass
class SmallRuns:
    """Run directories of every kind, the reports written, and what each command printed."""

    root: Path
    runs: dict[str, Path] = field(default_factory=dict)            # kind -> run directory
    reports: dict[str, Path] = field(default_factory=dict)         # report name -> report.html
    printed: dict[str, CliResult] = field(default_factory=dict)    # command label -> its result
    seconds: dict[str, float] = field(default_factory=dict)        # command label -> wall time


def _only_new(runs_dir: Path, before: set) -> Path:
    new = sorted(set(runs_dir.iterdir()) - before)
    assert len(new) == 1, new
    return new[0]


def make_small_runs(root: Path) -> SmallRuns:
    s = SmallRuns(root)
    runs = root / "runs"
    runs.mkdir(parents=True)

    def cli(label: str, *args) -> CliResult:
        t0 = time.perf_counter()
        r = run_cli(*args)
        s.seconds[label] = time.perf_counter() - t0
        assert r.exc is None, r.tb
        assert r.code == 0, (label, r.out[-2000:], r.err[-2000:])
        s.printed[label] = r
        return r

    def run(label: str, kind: str, cmd: str, spec: dict, *extra) -> Path:
        before = set(runs.iterdir())
        cli(label, cmd, write_yaml(root / f"{label}.yaml", spec), "--out", runs, *extra)
        s.runs[kind] = _only_new(runs, before)
        return s.runs[kind]

    run("run", "rotation", "run", ROTATION)
    run("run-seed-4", "rotation_seed_4", "run", dict(ROTATION, seed=4), "--quiet")
    run("friction-id", "friction_sweep", "friction-id", FRICTION)
    run("tune-ift", "ift", "tune-ift", IFT)
    run("hmi-session", "hmi_block", "hmi-session", HMI)
    cli("export", "export", s.runs["rotation"], "--to", root / "measured")
    meta = yaml.safe_load((root / "measured" / "meta.yaml").read_text())   # a recording of no particular test
    meta["experiment"]["kind"] = "free"
    write_yaml(root / "measured" / "meta.yaml", meta)
    before = set(runs.iterdir())
    cli("import", "import", root / "measured", "--out", runs)
    s.runs["measured"] = _only_new(runs, before)
    before = set(runs.iterdir())
    cli("diagnose", "diagnose", root / "measured", "--out", runs)
    s.runs["diagnosis"] = _only_new(runs, before)
    cli("bus-check", "bus-check", "--interface", "virtual", "--channel", "wamctl-terminal-test", "--simulate-pucks",
        "--window", "0.1")
    cli("sweep --dry-run", "sweep", write_yaml(root / "sweep.yaml", SWEEP), "--dry-run")
    s.runs["sweep"] = _sweep(cli, root / "sweep.yaml", root / SWEEP_PARENT)
    for k in ("rotation", "friction_sweep", "ift", "hmi_block", "diagnosis"):
        s.reports[k] = s.runs[k] / "report.html"
    # the reports of repeated runs, an HMI block and the imported run into one folder, with the combined report
    cli("report", "report", s.runs["rotation"], s.runs["rotation_seed_4"], s.runs["hmi_block"], s.runs["measured"],
        "--out", root / "reports")
    s.reports["measured"] = root / "reports" / s.runs["measured"].name / "report.html"
    s.reports["combined"] = root / "reports" / "combined_report.html"
    s.reports["sweep"] = s.runs["sweep"] / "report.html"
    csv = ROOT / "tests" / "fixtures" / "hmi" / "thesis_t6_10_subjects.csv"
    cli("report --hmi-results", "report", "--hmi-results", csv, "--out", root / "hmi_results")
    s.reports["hmi_results"] = root / "hmi_results" / f"{csv.stem}_report.html"
    # the lab's view of the runs folder (issue 30): the index page and two rotation runs side by side
    cli("runs --html", "runs", runs, "--html")
    s.reports["runs_index"] = runs / "index.html"
    cli("compare", "compare", s.runs["rotation"], s.runs["rotation_seed_4"], "--out", root / "compare")
    s.reports["compare"] = root / "compare" / "compare.html"
    return s


# the sweep's parent folder: a path longer than 80 characters (tests/commands/test_reading_output.py)
SWEEP_PARENT = "a-parent-folder-whose-name-is-long-enough-to-pass-80-columns-" + "x" * 20


def _sweep(cli, spec: Path, out: Path) -> Path:
    """``wamctl sweep`` of two points on an in-process Dask scheduler (one worker thread, no worker processes to
    start): its sweep directory (what it printed: ``printed["sweep"]``)."""
    import distributed

    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as c:
        cli("sweep", "sweep", spec, "--scheduler", c.scheduler_address, "--out", out)
    (sweep_dir,) = out.iterdir()
    return sweep_dir


@pytest.fixture(scope="session")
def small_runs(tmp_path_factory) -> SmallRuns:
    """Made once per session for every xdist worker (tests/once.py; the two workers had each made them): its run
    directories and reports are read, never changed, by the tests."""
    return make_once(tmp_path_factory, "small_runs", make_small_runs)
