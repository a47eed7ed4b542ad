"""Shared fixtures: small specs built in code, a temporary runs directory; how the suite shares the cores
(pytest-xdist, `make test`: each worker its own numba cache)."""

from __future__ import annotations

import os
from pathlib import Path

# Under pytest-xdist each worker compiles into a numba cache of its own (kept between sessions, so a worker
# compiles once per source change). One cache shared by workers compiling at the same moment is racy: numba's
# IndexDataCacheFile.save reads the index, picks the first free data file name (`...py311.1.nbc`) and writes the
# index and the data file separately, so two workers compiling two signatures of one kernel after a source edit
# can both pick `.1.nbc` and leave an index entry that points at the other signature's machine code. Set before
# anything imports numba (it reads NUMBA_CACHE_DIR once, on import); a cache the user chose is left alone.
# The cache is also keyed by the compiled sources' content: numba checks only the timestamp of a kernel's own
# file, so a kernel that calls one from another file (sim_fused -> chain_kernels) would otherwise keep the old
# callee's machine code after an edit of the callee.
_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
if _WORKER and "NUMBA_CACHE_DIR" not in os.environ:
    import hashlib

    _SRC = Path(__file__).resolve().parents[1] / "wamctl"
    _DIGEST = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(_SRC.rglob("*.py"))
                                      if b"@njit" in p.read_bytes())).hexdigest()[:12]
    os.environ["NUMBA_CACHE_DIR"] = str(_SRC.parent / ".pytest_cache" / "numba" / _DIGEST / _WORKER)

# One BLAS thread in every test process and the processes it starts (the CLI's subprocesses inherit the setting),
# unless the user chose a number. The tests' linear algebra is small dense products (the analyses' fits, the
# independent generator's 4 kHz physics), where a second OpenBLAS thread only spin-waits: with two xdist workers
# on two cores, four BLAS threads contend, and one generated run of tests/analysis/gen_independent took 23 s of
# CPU against 2.5 s with one thread (benchmarks/bench_suite.py, issue 31). The environment variable reaches a
# numpy imported after this file; threadpoolctl limits one already imported (a plugin's).
if "OPENBLAS_NUM_THREADS" not in os.environ and "OMP_NUM_THREADS" not in os.environ:
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")
    except ImportError:      # threadpoolctl is optional (wamctl/analysis/blas.py): the variable alone then
        pass

# A shell that runs the suite in the background (`nohup make test &`, some CI runners) hands it SIGINT ignored, and
# the workers inherit that; the tests of Ctrl-C send SIGINT to their own process and need Python's handler, as a
# terminal gives it. (Tests of a child process set the child's own: tests/commands/test_cli.py.)
import signal  # noqa: E402

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:       # not the main thread: nothing to do there
        pass

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from cli_runs import small_runs  # noqa: F401, E402 - the session fixture of small runs of every kind (cli_runs.py)
from hypothesis import settings  # noqa: E402
from sim_arm import udp  # noqa: F401, E402 - a CAN bus of the test's own for wamctl sim-arm (sim_arm.py)

from wamctl.model import params as P  # noqa: E402

# The property tests draw the same examples on every run (a red suite is a change, never a new draw): the
# "default" profile. `pytest --hypothesis-profile=explore` draws new examples, for looking for cases; a case
# found that way becomes a test of its own.
settings.register_profile("default", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, max_examples=1000, print_blob=True)

Q0 = np.array([0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])


def pytest_sessionfinish(session):
    """The values made once for every worker (tests/once.py) are removed when the session ends: by the controller
    under xdist (its temporary folder is the one the workers share), after every worker has finished."""
    factory = getattr(session.config, "_tmp_path_factory", None)
    if not hasattr(session.config, "workerinput") and getattr(factory, "_basetemp", None) is not None:
        from once import remove_values

        remove_values(factory.getbasetemp())

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
