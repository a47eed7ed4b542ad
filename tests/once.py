"""A value made once per test session, however many pytest-xdist workers ask for it.

``make_once(tmp_path_factory, key, make)`` calls ``make(folder)`` in the first worker that asks and keeps the value
(cloudpickle, in the session's temporary folder, which every worker of the session shares); a worker asking while
it is being made waits for it (an exclusive ``flock``), then reads it. The run directories ``make`` writes in
``folder`` stay there for every worker to read: the tests that share a value must not change its files. Without
xdist, ``make`` runs in the one process (nothing written but its folder). The kept values are removed when the
session ends (tests/conftest.py, ``remove_values``).

Used where two workers made the same runs or diagnoses (tests/cli_runs.py: the small runs of every kind,
tests/analysis/test_diagnose.py: the generated runs and their diagnoses).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cloudpickle

try:
    import fcntl
except ImportError:          # no flock (Windows): each worker makes its own value
    fcntl = None

_MEMORY: dict[tuple[str, str], Any] = {}


def shared_folder(tmp_path_factory) -> Path:
    """The session's temporary folder every xdist worker sees (each worker's own basetemp is a child of it)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") and fcntl is not None else base


def make_once(tmp_path_factory, key: str, make: Callable[[Path], Any], keep: bool = True) -> Any:
    """``make(folder)``'s value, made once per session for all workers (see the module's docstring); ``keep``:
    also kept in this process's memory for the rest of the session (False for large values the caller keeps
    as long as it needs them)."""
    root = shared_folder(tmp_path_factory) / "made_once"
    memo = (str(root), key)
    if memo in _MEMORY:
        return _MEMORY[memo]
    root.mkdir(exist_ok=True)
    if not os.environ.get("PYTEST_XDIST_WORKER") or fcntl is None:     # one process: nothing to share
        value = _make_in(root / key, make)
    else:
        value_file = root / f"{key}.pkl"
        with open(root / f"{key}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)     # released when the file closes (also if make raises)
            if value_file.exists():
                value = cloudpickle.loads(value_file.read_bytes())
            else:
                value = _make_in(root / key, make)
                part = value_file.with_suffix(".part")
                part.write_bytes(cloudpickle.dumps(value))
                part.replace(value_file)
    if keep:
        _MEMORY[memo] = value
    return value


def _make_in(folder: Path, make: Callable[[Path], Any]) -> Any:
    if folder.exists():              # what a worker's failed make left
        shutil.rmtree(folder)
    folder.mkdir()
    return make(folder)


def remove_values(basetemp: Path) -> None:
    """Remove the kept values of a session (the diagnoses are 50-150 MB each; pytest keeps the last three
    sessions' folders), once no worker can ask for them: at the end of the session, in the controller. The run
    directories stay, as every test's temporary files do."""
    for f in (Path(basetemp) / "made_once").glob("*.pkl"):
        f.unlink(missing_ok=True)


def independent_run(tmp_path_factory, cid: str, plan: tuple = (3, 3, 7, 0)):
    """The independent generator's run ``cid`` of ``cases(*plan[:2], seed=plan[2], n_pairs=plan[3])``
    (tests/analysis/gen_independent), generated once per session for every worker (its ``GeneratedRun``): runs
    two test files read (test_diagnose_v2's independent subset, test_friction_id's sweeps of the generator).
    Read only: a test must not change its files."""
    def make(folder: Path):
        from gen_independent import cases, generate

        case = next(c for c in cases(plan[0], plan[1], seed=plan[2], n_pairs=plan[3]) if c["id"] == cid)
        return generate(case, folder / cid)
    return make_once(tmp_path_factory, "independent_{}_{}_{}_{}_{}".format(*plan, cid), make)
