"""Shared fixtures: small specs built in code, a temporary runs directory; how the suite shares two cores
(pytest-xdist, `make test`: each worker its own numba cache, tests sharing an expensive fixture kept together)."""

from __future__ import annotations

import inspect
import os
from pathlib import Path

# Under pytest-xdist each worker compiles into a numba cache of its own (kept between sessions, so a worker
# compiles once per source change). One cache shared by workers compiling at the same moment is racy: numba's
# IndexDataCacheFile.save reads the index, picks the first free data file name (`...py311.1.nbc`) and writes the
# index and the data file separately, so two workers compiling two signatures of one kernel after a source edit
# can both pick `.1.nbc` and leave an index entry that points at the other signature's machine code. Set before
# anything imports numba (it reads NUMBA_CACHE_DIR once, on import); a cache the user chose is left alone.
_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
if _WORKER and "NUMBA_CACHE_DIR" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "numba" / _WORKER)

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from cli_runs import small_runs  # noqa: F401, E402 - the session fixture of small runs of every kind (cli_runs.py)
from hypothesis import settings  # noqa: E402

from wamctl.model import params as P  # noqa: E402

# The property tests draw the same examples on every run (a red suite is a change, never a new draw): the
# "default" profile. `pytest --hypothesis-profile=explore` draws new examples, for looking for cases; a case
# found that way becomes a test of its own.
settings.register_profile("default", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, max_examples=1000, print_blob=True)

Q0 = np.array([0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])

TESTS = Path(__file__).resolve().parent


def _shared_scope(item: pytest.Item) -> str | None:
    """The xdist group of a test that shares an expensive fixture: ``small_runs`` (one small run of every kind,
    used by several files) or the test's module, when the test uses a module-, package- or session-scoped fixture
    written in tests/ (a simulated run that several tests read). None for a test that shares nothing."""
    if "small_runs" in item.fixturenames:
        return "small_runs"
    info = getattr(item, "_fixtureinfo", None)
    for name in item.fixturenames:
        defs = info.name2fixturedefs.get(name) if info is not None else None
        if not defs or defs[-1].scope not in ("module", "package", "session"):
            continue
        try:
            where = Path(inspect.getfile(defs[-1].func)).resolve()
        except (TypeError, OSError):
            continue
        if TESTS in where.parents:
            return item.nodeid.split("::", 1)[0]
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Under `pytest -n N --dist loadgroup` (`make test`): the tests that share an expensive fixture run in one
    worker, so that it is built once, not once per worker; every other test goes to whichever worker is free.
    The groups are handed out first, largest first (xdist's order), and the single tests fill the end."""
    if not config.pluginmanager.hasplugin("xdist"):   # the mark is xdist's; without --dist loadgroup it does nothing
        return
    for item in items:
        group = _shared_scope(item)
        if group is not None and not any(True for _ in item.iter_markers("xdist_group")):
            item.add_marker(pytest.mark.xdist_group(group))


@pytest.fixture
def runs_dir(tmp_path):
    d = tmp_path / "runs"
    d.mkdir()
    return d


@pytest.fixture
def q0():
    return Q0.copy()


def rotation_spec(**overrides) -> dict:
    """A rotation spec as a mapping (what a YAML file would hold)."""
    spec = {"kind": "rotation", "name": "t", "seed": 3, "backend": {"kind": "sim"},
            "plant": {"friction": "table_4_1"}, "controller": {"kind": "pd_g"},
            "q0_rad": Q0.tolist(),
            "rotation": {"joints": list(range(1, P.N_JOINTS + 1)), "mode": "all_together", "hold_s": 0.3,
                         "settle_s": 0.0}}
    for k, v in overrides.items():
        if isinstance(v, dict) and isinstance(spec.get(k), dict):
            spec[k] = {**spec[k], **v}
        else:
            spec[k] = v
    return spec
