"""The joints of a run diagnosed in worker processes (wamctl.analysis.diagnosis.parallel): the same diagnosis bit for
bit as one after the other, a worker's error reaching the caller, a dead worker's joints done here."""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import signal

import pytest

from wamctl.analysis.diagnosis import parallel
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.analysis.diagnosis.parallel import joint_workers, map_in_order
from wamctl.runs.measured import load_run_data

pytestmark = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="needs fork")


def _as_json(diag, path) -> str:
    """diagnosis.json's content, as written (NaN spelled out, so that equal means bit for bit)."""
    return json.dumps(diag.to_dict(str(path)), sort_keys=True, default=repr)


@pytest.fixture(scope="module")
def ripple_run(tmp_path_factory):
    """The independent generator's dev case ``position_ripple-000``: five joints move, a ripple is named, and the
    net-gain check diagnoses joint 7 again without Stribeck (``_rediagnose``)."""
    from gen_independent import cases, generate

    case = next(c for c in cases(1, 0, 0, 0) if c["id"] == "position_ripple-000")
    d = tmp_path_factory.mktemp("ripple")
    generate(case, d)
    return d, load_run_data(d)


def test_the_joints_in_two_processes_give_the_same_diagnosis(ripple_run, monkeypatch):
    path, data = ripple_run
    again = []
    rediagnose = ModelDiagnosis._rediagnose

    def counted(self, j, *args):
        again.append(j)
        return rediagnose(self, j, *args)

    monkeypatch.setattr(ModelDiagnosis, "_rediagnose", counted)
    one = ModelDiagnosis(jobs=1).fit(data)
    assert "position_ripple" in one.effects_found_ and len(one.signals_.joints) == 5
    assert again, "the run was chosen for a joint diagnosed again after the arm-wide checks"
    seen = []
    two = ModelDiagnosis(jobs=2).fit(data, progress=lambda fraction, label: seen.append((fraction, label)))
    assert _as_json(two, path) == _as_json(one, path)
    assert sorted(two.map_tests_) == sorted(one.map_tests_)
    labels = [label for _, label in seen if "torque residual" in label]
    assert len(labels) == 1 + 5 and all("2 processes" in label for label in labels)
    assert [f for f, _ in seen] == sorted(f for f, _ in seen)
    assert multiprocessing.active_children() == [] and parallel._TASK is None


def test_a_worker_error_reaches_the_caller(ripple_run, monkeypatch):
    _, data = ripple_run
    diagnose = ModelDiagnosis._diagnose_joint

    def failing(self, jd, tests, rejected=None):
        if jd.j == 3:
            raise ValueError(f"joint {jd.j + 1}: no good")
        return diagnose(self, jd, tests, rejected)

    monkeypatch.setattr(ModelDiagnosis, "_diagnose_joint", failing)
    with pytest.raises(ValueError, match="joint 4: no good"):
        ModelDiagnosis(jobs=2).fit(data)
    assert multiprocessing.active_children() == []


def _square_or_fail(k: int) -> int:
    if k in (2, 4):
        raise KeyError(f"task {k}")
    return k * k


def test_the_earliest_error_is_raised_and_the_workers_stopped():
    with pytest.raises(KeyError, match="task 2"):
        map_in_order(_square_or_fail, 6, 2)
    assert multiprocessing.active_children() == []


_MANY_ERRORS = """
import time
import numpy as np
from wamctl.analysis.diagnosis.parallel import map_in_order

def task(k):
    if k == 1:
        time.sleep(0.02)
        raise ValueError("no good")
    return np.ones(400_000)         # 3.2 MB back through the pool's result pipe

for _ in range(40):
    try:
        map_in_order(task, 8, 2)
    except ValueError:
        pass
print("done")
"""


def test_an_error_while_other_workers_send_large_results_never_hangs():
    """Workers were terminated on an error; one killed while writing its result left a partial message in the
    pool's result pipe, and the pool's reader waited for the rest forever (the worker-error test above hung 600 s
    on a fresh clone). 40 errors, each while the other worker sends 3.2 MB: the terminating version hung every time
    within 30 s (3 of 3); now 3.5-3.7 s. In a subprocess, so that a hang fails here instead of stalling the suite."""
    import subprocess
    import sys

    try:
        r = subprocess.run([sys.executable, "-c", _MANY_ERRORS], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("map_in_order hung after a worker error (a worker cut off while sending its result)")
    assert r.returncode == 0 and r.stdout.strip() == "done", r.stderr


def test_logs_come_back_in_order_and_a_dead_worker_leaves_its_tasks_here(caplog):
    parent = os.getpid()

    def task(k: int) -> int:
        logging.getLogger("wamctl.test_parallel").warning("task %d in %s", k, "a worker" if os.getpid() != parent
                                                          else "the parent")
        if k == 3 and os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return k * k

    done = []
    with caplog.at_level(logging.WARNING):
        out = map_in_order(task, 6, 2, done.append)
    assert out == [k * k for k in range(6)]
    assert sorted(done) == list(range(6))
    said = [r.getMessage() for r in caplog.records]
    assert "task 3 in the parent" in said
    assert any("worker process of the joint diagnosis died" in m for m in said)
    assert [m for m in said if m.startswith("task 0") or m.startswith("task 1")] == \
        ["task 0 in a worker", "task 1 in a worker"]
    assert multiprocessing.active_children() == []


def test_short_runs_stay_in_one_process():
    assert joint_workers(7, 1000) == 1
    assert joint_workers(7, 10 ** 7, jobs=1) == 1
    assert joint_workers(3, 1000, jobs=8) == 3
    assert joint_workers(1, 10 ** 7) == 1
    assert joint_workers(7, 10 ** 7) == min(7, len(os.sched_getaffinity(0)))
