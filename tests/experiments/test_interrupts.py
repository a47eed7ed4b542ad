"""Ctrl-C and SIGTERM at any moment of a command (issue 32, item 1): the command ends in one line and exit code
130, no traceback, its run directory ``interrupted`` (or ``completed`` with a line saying its report was cut
short), and data.parquet holds every row recorded, contiguous, with no chunk or temporary file left behind. A run
interrupted before its data are saved says so first, in one line naming the rows being saved (the seconds a long
run's table takes to write used to pass in silence), and its events.csv ends at its last sample, with a row for
the stop.

The signals are sent deterministically: a hook on a function of the run (a control tick, a chunk write, the
consolidation, the manifest, the report's documents and figures) sends SIGINT or SIGTERM to this process at its
N-th call (``os.kill``: Python then runs the handler wherever the interpreter is next, as for a real Ctrl-C), or
raises KeyboardInterrupt right inside the chunk writer's ``to_parquet`` (an interrupt landing in the middle of a
write that nothing holds back). A dry run counts the calls; the points are spread evenly over them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli

ROOT = Path(__file__).resolve().parents[2]
Q0 = [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0]
CHUNK_ROWS = 30
# one joint, a 0.04 rad move and a hold: 225 ticks (0.45 s of arm time), 8 chunks of up to 30 rows
SPEC = {"kind": "rotation", "name": "int", "seed": 2, "plant": {"friction": "table_4_1"}, "q0_rad": Q0,
        "rotation": {"joints": [4], "mode": "all_together", "amplitude_rad": 0.04, "velocity_rad_s": 0.2,
                     "tc_s": 0.05, "settle_s": 0.0, "hold_s": 0.2}}
N_POINTS = 50


def notice_line(by: str, rows: int) -> str:
    """The line said when the interrupt is caught, before the run's data are saved."""
    return f"interrupted by {by}: saving {rows:,} samples ..."


def interrupted_line(run: Path, by: str) -> str:
    return f"error: {run}: interrupted by {by}; the data recorded so far are readable"


def check_ending(err: str, label) -> list[str]:
    """stderr of an interrupted command: no traceback, one error line, last, after at most one notice line
    (:func:`notice_line`); returns the lines."""
    lines = err.strip().splitlines()
    assert "Traceback" not in err and lines and lines[-1].startswith("error: "), (label, err)
    assert len(lines) == 1 or (len(lines) == 2 and lines[0].startswith("interrupted by ")
                               and lines[0].endswith(" ...")), (label, err)
    return lines


class Hooks:
    """Counts the calls of the hooked functions and, at one chosen call, interrupts."""

    def __init__(self):
        self.counts: Counter = Counter()
        self.sequence: list[tuple[str, int]] = []
        self.point: tuple[str, int] | None = None
        self.how = "SIGINT"
        self.fired = False
        self.ticks_at_fire = None

    def wrap(self, name: str, fn):
        def hooked(*args, **kwargs):
            self.counts[name] += 1
            k = self.counts[name]
            if self.point is None:
                self.sequence.append((name, k))
            elif not self.fired and self.point == (name, k):
                self.fired = True
                self.ticks_at_fire = self.counts["tick"]
                if self.how == "raise":
                    raise KeyboardInterrupt
                os.kill(os.getpid(), getattr(signal, self.how))
            return fn(*args, **kwargs)
        return hooked

    def reset(self, point=None, how="SIGINT"):
        self.counts.clear()
        self.point, self.how, self.fired, self.ticks_at_fire = point, how, False, None


@pytest.fixture
def hooks(monkeypatch):
    import matplotlib.figure

    import wamctl.report.document as document
    import wamctl.runs.store as store
    from wamctl.backends.sim import SimBackend

    h = Hooks()
    targets = {
        "tick": (SimBackend, "read_positions"),
        "to_parquet": (pd.DataFrame, "to_parquet"),
        "write_csv": (store, "write_csv"),
        "read_chunks": (store, "read_chunks"),
        "remove_chunks": (store, "remove_chunks"),
        "manifest": (store.RunDir, "write_manifest"),
        "events": (store.RunDir, "flush_events"),
        "replace": (os, "replace"),
        "markdown": (document.Document, "to_markdown"),
        "html": (document.Document, "to_html"),
        "savefig": (matplotlib.figure.Figure, "savefig"),
    }
    for name, (owner, attr) in targets.items():
        if hasattr(owner, attr):
            monkeypatch.setattr(owner, attr, h.wrap(name, getattr(owner, attr)))
    real_table = store.RunDir.table
    monkeypatch.setattr(store.RunDir, "table", lambda self, name, columns, chunk_rows=2500: real_table(
        self, name, columns, CHUNK_ROWS))
    from wamctl.experiments import engine
    monkeypatch.setattr(engine.run_loop, "__defaults__", (None, CHUNK_ROWS))
    return h


def spread_points(sequence: list[tuple[str, int]], n: int) -> list[tuple[str, int]]:
    """``n`` points over the run in the order of its calls: every call of the hooked functions other than the
    control tick (each is a different moment: chunk writes, consolidation, manifest, report), and control
    ticks evenly spaced for the rest."""
    others = [c for c in sequence if c[0] != "tick"]
    if len(others) > n - 10:
        others = [others[i] for i in np.unique(np.linspace(0, len(others) - 1, n - 10).round().astype(int))]
    ticks = [c for c in sequence if c[0] == "tick"]
    ticks = [ticks[i] for i in np.unique(np.linspace(0, len(ticks) - 1, n - len(others)).round().astype(int))]
    chosen = set(others) | set(ticks)
    return [c for c in sequence if c in chosen]


def check_interrupted_run(r, run_dir: Path, ticks_at_fire: int, ticks_total: int, label: str, by: str,
                          noticed: bool) -> str:
    """The command's end and its run directory as the issue asks; returns the run's status. ``noticed``: the
    interrupt came before the data table was consolidated, so the notice line comes first."""
    assert r.exc is None, (label, r.tb)
    assert r.code == 130, (label, r.code, r.err)
    lines = check_ending(r.err, label)
    m = json.loads((run_dir / "manifest.json").read_text())
    assert m["status"] in ("interrupted", "completed"), (label, m["status"], m["reason"])
    if m["status"] == "completed":      # the signal came after the run's last sample: its report was cut short
        assert len(lines) == 1 and "wamctl report" in lines[0], (label, lines)
    else:
        assert "interrupted" in lines[-1] and m["reason"] == f"stopped by {by}", (label, lines, m["reason"])
        ev = pd.read_csv(run_dir / "events.csv")
        assert ev["kind"].iloc[-1] == "interrupted" and ev["detail"].iloc[-1] == m["reason"], (label, ev)
    if ticks_at_fire == 0:              # stopped before the loop started: nothing recorded, no table
        assert not (run_dir / "data.parquet").exists() and not (run_dir / "data").exists(), label
        return m["status"]
    data = pd.read_parquet(run_dir / "data.parquet")
    if m["status"] == "interrupted":    # said before the saving, with the rows saved; events up to the last row
        assert lines == [notice_line(by, len(data))] * noticed + [interrupted_line(run_dir, by)], (label, lines)
        ev = pd.read_csv(run_dir / "events.csv")
        t_last = round(float(data["t_s"].iloc[-1]), 6) if len(data) else 0.0
        assert ev["t_s"].max() <= t_last and ev["t_s"].iloc[-1] == t_last, (label, ev, t_last)
    # every row recorded: the ticks read before the signal (the tick being read may or may not be recorded)
    assert ticks_at_fire - 1 <= len(data) <= min(ticks_at_fire + 1, ticks_total), (label, len(data), ticks_at_fire)
    assert data.notna().all().all(), label
    np.testing.assert_allclose(data["t_s"].to_numpy(), 0.002 * np.arange(len(data)), atol=1e-9, err_msg=label)
    assert len(pd.read_csv(run_dir / "data.csv")) == len(data), label
    left = sorted(p.name for p in run_dir.rglob("*") if p.name.endswith(".tmp") or "part-" in p.name)
    assert not left and not (run_dir / "data").exists(), (label, left)
    assert (run_dir / "events.csv").is_file(), label
    return m["status"]


def test_an_interrupt_at_any_of_50_points_of_a_run_keeps_every_row_and_ends_in_one_line(tmp_path, hooks):
    spec = tmp_path / "int.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    r = run_cli("run", spec, "--out", tmp_path / "dry", "--quiet")
    assert r.code == 0, r.err
    ticks_total = hooks.counts["tick"]
    assert ticks_total == 225 and hooks.counts["savefig"] >= 2 and hooks.counts["html"] == 1
    # the chunk writer ran 8 times, then the consolidation: Parquet files
    assert hooks.counts["to_parquet"] >= 9
    points = spread_points(hooks.sequence, N_POINTS)
    # two more where the chunk writer's own write is cut by an exception (nothing can hold that back)
    chunk_writes = [(n, k) for n, k in hooks.sequence if n == "to_parquet"][:8]
    plan = [(p, ("SIGINT", "SIGTERM")[i % 2]) for i, p in enumerate(points)]
    plan += [(chunk_writes[1], "raise"), (chunk_writes[7], "raise")]
    assert len(points) == N_POINTS
    assert {n for n, _ in points} >= {"tick", "to_parquet", "write_csv", "manifest", "replace", "savefig", "html"}
    statuses = Counter()
    for i, (point, how) in enumerate(plan):
        out = tmp_path / f"p{i:02d}"
        hooks.reset(point, how)
        r = run_cli("run", spec, "--out", out, "--quiet")
        label = f"{how} at call {point[1]} of {point[0]}"
        assert hooks.fired, label
        runs = [d for d in out.iterdir() if d.is_dir()] if out.exists() else []
        assert len(runs) == 1, (label, r.err)
        by = "SIGTERM" if how == "SIGTERM" else "Ctrl-C"
        # said before the saving: a signal up to the end of the table's consolidation; an exception (no signal,
        # nothing to notice in the loop) only when it leaves the table to the runner: in the last chunk's write,
        # made as the stage ends, before its consolidation (in an earlier one the stage consolidates it)
        noticed = (hooks.sequence.index(point) <= hooks.sequence.index(("remove_chunks", 1)) if how != "raise"
                   else point == chunk_writes[7])
        statuses[check_interrupted_run(r, runs[0], hooks.ticks_at_fire, ticks_total, label, by, noticed)] += 1
    # the points reach both ends: runs stopped mid-way, and runs completed whose report was stopped
    assert statuses["interrupted"] >= 20 and statuses["completed"] >= 10, statuses


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM"])
def test_an_interrupt_is_said_before_the_saving_and_the_events_end_at_the_last_sample(tmp_path, hooks, monkeypatch,
                                                                                    how):
    """Stopped at tick 60 of 225 (0.12 s, in the move): the line naming the rows is on stderr before the table is
    consolidated, and events.csv has the move's segment but not the hold's (0.25 s, never reached), then one
    ``interrupted`` row at the last sample's time."""
    import wamctl.runs.store as store

    said_at_saving = []
    real = store.read_chunks

    def reading(*args, **kwargs):           # the consolidation's first step: what stderr holds by then
        said_at_saving.append(sys.stderr.getvalue())
        return real(*args, **kwargs)
    monkeypatch.setattr(store, "read_chunks", reading)
    spec = tmp_path / "int.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    hooks.reset(("tick", 60), how)
    r = run_cli("run", spec, "--out", tmp_path / "runs", "--quiet")
    assert hooks.fired and r.code == 130, r.err
    run = next((tmp_path / "runs").iterdir())
    by = "SIGTERM" if how == "SIGTERM" else "Ctrl-C"
    data = pd.read_parquet(run / "data.parquet")
    assert 59 <= len(data) <= 61
    assert r.err.splitlines() == [notice_line(by, len(data)), interrupted_line(run, by)], r.err
    assert said_at_saving and said_at_saving[0] == notice_line(by, len(data)) + "\n", said_at_saving
    ev = pd.read_csv(run / "events.csv")
    t_last = round(float(data["t_s"].iloc[-1]), 6)
    assert ev["kind"].tolist() == ["segment", "interrupted"], ev
    assert ev["detail"].tolist() == ["move joints 4", f"stopped by {by}"], ev
    assert ev["t_s"].tolist() == [0.0, t_last] and pd.isna(ev["joint"].iloc[-1]), ev
    r = run_cli("report", run)       # the report of the interrupted run reads the new row
    assert r.code == 0, r.err


def test_a_failed_or_unstarted_run_keeps_only_the_events_that_happened(tmp_path):
    """``failed``: the planned segments after the last sample go, the stop row says why; no sample at all: every
    planned event goes, events recorded as they happened stay and the stop row takes the latest one's time."""
    from wamctl.runs.store import RunDir

    run = RunDir.create(tmp_path, "f", {}, 0, "rotation")
    w = run.table("data", ["t_s", "x"], chunk_rows=4)
    for k in range(6):
        w.append(np.array([0.002 * k, 1.0]))
    for t_s, label in [(0.0, "move"), (0.01, "hold"), (0.02, "return")]:
        run.event(t_s, "segment", None, label, planned=True)
    run.event(0.004, "torque_limit", 2, "at the limit")
    run.close_tables()
    run.finish("failed", "safety limit: joint 2 speed 2.1 rad/s")
    ev = pd.read_csv(run.path / "events.csv")
    assert ev["kind"].tolist() == ["segment", "segment", "torque_limit", "failed"], ev
    assert ev["t_s"].tolist() == [0.0, 0.01, 0.004, 0.01], ev
    assert ev["detail"].iloc[-1] == "safety limit: joint 2 speed 2.1 rad/s"

    run = RunDir.create(tmp_path, "u", {}, 0, "rotation")
    run.event(0.0, "segment", None, "move", planned=True)
    run.event(1.5, "ift_stage", 3, "stage 2")
    run.finish("interrupted", "stopped by SIGHUP")
    ev = pd.read_csv(run.path / "events.csv")
    assert ev["kind"].tolist() == ["ift_stage", "interrupted"] and ev["t_s"].tolist() == [1.5, 1.5], ev

    run = RunDir.create(tmp_path, "c", {}, 0, "rotation")    # completed: the plan as it was
    run.event(9.0, "segment", None, "hold", planned=True)
    run.finish("completed")
    assert pd.read_csv(run.path / "events.csv")["kind"].tolist() == ["segment"]


# ------------------------------------------------------------------------------ the other commands
FRICTION = {"kind": "friction_sweep", "name": "fs", "seed": 5, "plant": {"friction": "table_4_1"},
            "sweep": {"joints": [7], "velocities_rad_s": [0.5, 1.0], "travel_rad": {7: 1.0}, "cruise_s": 0.5}}
IFT = {"kind": "ift", "name": "ift", "seed": 5, "controller": {"kind": "pid"}, "q0_rad": Q0,
       "plant": {"friction": "table_4_1"},
       "ift": {"joints": [7], "task": {"settle_s": 0.1, "hold_s": 0.2}, "max_iterations": 1}}
HMI = {"kind": "hmi_block", "name": "hmi", "seed": 1,
       "hmi": {"subject": {"id": "S1", "seed": 11, "skill": 0.9}, "locations": ["P1"]}}


@pytest.mark.parametrize("command,spec,points", [
    ("friction-id", FRICTION, [("to_parquet", 3, "raise", False), ("write_csv", 1, "SIGTERM", True),
                               ("tick", 900, "SIGINT", True)]),
    ("tune-ift", IFT, [("tick", 150, "SIGINT", False), ("to_parquet", 4, "SIGTERM", False)]),
    ("hmi-session", HMI, [("tick", 200, "SIGTERM", False), ("to_parquet", 1, "SIGINT", False)])])
def test_an_interrupt_in_the_loop_or_a_table_write_of_other_commands(tmp_path, hooks, command, spec, points):
    """In a chunk write (an exception inside it), in the consolidation, in the loop: one error line, exit 130,
    the run ``interrupted`` with the signal named, no temporary file. A signal before a chunked table is
    consolidated (the friction sweep's) is said first, with the rows; tune-ift and hmi-session write their own
    tables as they go: nothing left to say."""
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(spec))
    for i, (name, k, how, noticed) in enumerate(points):
        out = tmp_path / f"p{i}"
        hooks.reset((name, k), how)
        r = run_cli(command, path, "--out", out, "--quiet")
        assert hooks.fired and r.exc is None, (name, k, r.tb)
        assert r.code == 130, r.err
        lines = check_ending(r.err, (name, k))
        run = [d for d in out.iterdir() if d.is_dir()][0]
        m = json.loads((run / "manifest.json").read_text())
        assert m["status"] == "interrupted", (name, k, m)
        by = "SIGTERM" if how == "SIGTERM" else "Ctrl-C"
        assert m["reason"] == f"stopped by {by}", m
        assert lines[-1].startswith(f"error: {run}: interrupted by {by}; "), lines
        assert len(lines) == 1 + noticed and lines[0].startswith(f"interrupted by {by}: saving " if noticed
                                                                 else "error: "), lines
        assert not [p for p in run.rglob("*") if p.name.endswith(".tmp")]


# ------------------------------------------------------------------------------ real signals, real processes
def _spawn(*args):
    # a shell that runs the suite in the background hands its children SIGINT ignored; a terminal does not
    return subprocess.Popen([sys.executable, "-m", "wamctl", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(pred, proc, timeout_s=120):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = pred()
        if found:
            return found
        if proc.poll() is not None:
            break
        time.sleep(0.01)
    proc.kill()
    raise AssertionError(f"not seen; the command said: {proc.communicate()[1][-2000:]}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_real_signal_during_the_chunked_run_ends_it_as_interrupted(tmp_path, sig):
    spec = tmp_path / "long.yaml"
    # six joints, 0.3 rad each: 12 700 ticks (a second or two of wall time), chunks of 2500 rows
    spec.write_text(yaml.safe_dump(dict(SPEC, rotation=dict(SPEC["rotation"], joints=[1, 3, 4, 5, 6, 7],
                                                               mode="one_at_a_time", amplitude_rad=0.3,
                                                               velocity_rad_s=0.1, hold_s=1.0))))
    runs = tmp_path / "runs"
    proc = _spawn("run", spec, "--out", runs, "--quiet")
    first_chunk = _wait_for(lambda: list(runs.glob("*/data/part-00000.parquet")) if runs.exists() else [], proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    run = first_chunk[0].parent.parent
    by = "Ctrl-C" if sig == signal.SIGINT else "SIGTERM"
    m = json.loads((run / "manifest.json").read_text())
    assert m["status"] == "interrupted"
    assert m["reason"] == f"stopped by {by}"
    data = pd.read_parquet(run / "data.parquet")
    assert check_ending(err, by) == [notice_line(by, len(data)), interrupted_line(run, by)], err
    assert len(data) >= 2500 and not (run / "data").exists()
    assert len(data) < 12000     # stopped mid-way
    np.testing.assert_allclose(data["t_s"].to_numpy(), 0.002 * np.arange(len(data)), atol=1e-9)


def test_sigterm_during_diagnose_marks_its_run_directory_interrupted(tmp_path):
    """An analysis command (no runner): SIGTERM used to kill it outright, its run directory left ``running``."""
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    r = run_cli("run", spec, "--out", tmp_path / "src", "--quiet")
    assert r.code == 0, r.err
    src = next((tmp_path / "src").iterdir())
    runs = tmp_path / "runs"
    proc = _spawn("diagnose", src, "--out", runs, "--quiet")
    # the signal once its run directory exists (the analysis is done, the report is being written) ...
    made = _wait_for(lambda: list(runs.glob("*/manifest.json")) if runs.exists() else [], proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    # one line of its own (the analysis may have logged a warning about the data before it)
    assert len([x for x in err.splitlines() if x.startswith("error:")]) == 1 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith("error:"), err
    m = json.loads(made[0].read_text())
    if m["status"] == "completed":      # ... lands in the report (it has no report then) or before its finish
        assert "its report was interrupted" in err and not (made[0].parent / "report.html").exists(), err
    else:
        assert m["status"] == "interrupted" and m["reason"] == "stopped by SIGTERM", m


SWEEP = {"kind": "rotation", "name": "tiny", "seed": 0, "q0_rad": Q0,
         "plant": {"friction": "table_4_1", "sensors": {"position_noise_rad": 1e-4}},
         "rotation": {"joints": [1, 7], "mode": "all_together", "amplitude_rad": 0.05, "velocity_rad_s": 0.25,
                      "tc_s": 0.1, "settle_s": 0.0, "hold_s": 0.1},
         "vary": {"grid": {"seed": [1, 2, 3, 4]}}}


def test_ctrl_c_to_the_process_group_while_the_sweep_cluster_starts(tmp_path):
    """Ctrl-C reaches every process of the terminal's group: while the Dask workers were starting it cut their
    imports (a traceback per worker, "Nanny failed to start", exit 1). Sent here as soon as the sweep has
    three child processes (the resource tracker and the first workers, still importing)."""
    spec = tmp_path / "sweep.yaml"
    spec.write_text(yaml.safe_dump(SWEEP))
    runs = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "wamctl", "sweep", str(spec), "--out", str(runs), "--workers",
                             "2", "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    import psutil
    made = _wait_for(lambda: list(runs.glob("*-sweep/index.csv")) if runs.exists() else [], proc)
    # the moment the worker processes are spawned (they import distributed for a second or more)
    _wait_for(lambda: len(psutil.Process(proc.pid).children(recursive=True)) >= 3, proc)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err[-3000:]
    assert err.startswith(f"error: {made[0].parent}: sweep interrupted, "), err


def test_a_notice_that_fails_does_not_stop_the_saving(tmp_path):
    """The saving notice prints to the terminal; a terminal gone (a broken pipe) must not keep the rows from
    data.parquet."""
    from wamctl.runs.store import RunDir, read_table

    run = RunDir.create(tmp_path, "n", {"kind": "rotation", "name": "n"}, 0, "rotation")
    w = run.table("data", ["t_s", "q_1_rad"])
    for k in range(10):
        w.append(np.array([k * 0.002, 0.1 * k]))

    def broken(rows):
        raise BrokenPipeError("stderr closed")

    run.on_saving = broken
    run.close_tables()
    assert len(read_table(run.path, "data")) == 10 and (run.path / "data.parquet").is_file()
