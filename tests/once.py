"""A value made once per test session, however many pytest-xdist workers ask for it.

``make_once(tmp_path_factory, key, make)`` calls ``make(folder)`` in the first worker that asks and keeps the value
(cloudpickle, in the session's temporary folder, which every worker of the session shares); a worker asking while
it is being made waits for it (an exclusive ``flock``), then reads it. The run directories ``make`` writes in
``folder`` stay there for every worker to read: the tests that share a value must not change its files. Without
xdist, the same happens in the one process (the value is kept in memory too).

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


def make_once(tmp_path_factory, key: str, make: Callable[[Path], Any]) -> Any:
    """``make(folder)``'s value, made once per session for all workers (see the module's docstring)."""
    root = shared_folder(tmp_path_factory) / "made_once"
    memo = (str(root), key)
    if memo in _MEMORY:
        return _MEMORY[memo]
    root.mkdir(exist_ok=True)
    folder, value_file = root / key, root / f"{key}.pkl"
    with open(root / f"{key}.lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)     # released when the file closes (also if make raises)
        if value_file.exists():
            value = cloudpickle.loads(value_file.read_bytes())
        else:
            if folder.exists():              # what a worker's failed make left
                shutil.rmtree(folder)
            folder.mkdir()
            value = make(folder)
            part = value_file.with_suffix(".part")
            part.write_bytes(cloudpickle.dumps(value))
            part.replace(value_file)
    _MEMORY[memo] = value
    return value
