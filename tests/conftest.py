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
# In a fresh clone every worker compiled the same kernels (about 20 s of CPU each): the controller compiles them
# once into a seed cache before the workers start (tests/numba_warmup.py, `pytest_configure` below), and a worker
# whose own cache does not exist yet starts from a copy of it (no process ever writes into another's cache).
_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
_OWN_NUMBA_CACHE = "NUMBA_CACHE_DIR" not in os.environ          # the user chose none: the suite keeps its own
if _OWN_NUMBA_CACHE:
    import hashlib

    _SRC = Path(__file__).resolve().parents[1] / "wamctl"
    _DIGEST = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(_SRC.rglob("*.py"))
                                      if b"@njit" in p.read_bytes())).hexdigest()[:12]
    _NUMBA_ROOT = _SRC.parent / ".pytest_cache" / "numba" / _DIGEST
    _NUMBA_SEED = _NUMBA_ROOT / "seed"
    if _WORKER:
        _own = _NUMBA_ROOT / _WORKER
        if not _own.exists() and _NUMBA_SEED.is_dir():
            import shutil

            try:
                shutil.copytree(_NUMBA_SEED, _own)
            except OSError:          # a copy cut short: the worker compiles everything, as without a seed
                shutil.rmtree(_own, ignore_errors=True)
        os.environ["NUMBA_CACHE_DIR"] = str(_own)

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


def pytest_configure(config):
    """Under xdist, in the controller: the seed cache of the numba kernels, compiled once before the workers start
    (see the top of this file); a failure leaves the workers to compile, as without it."""
    if (not _OWN_NUMBA_CACHE or hasattr(config, "workerinput") or not config.getoption("numprocesses", None)
            or config.getoption("collectonly", False) or _NUMBA_SEED.is_dir() or not _many_files(config)):
        return
    import shutil
    import subprocess
    import sys
    import tempfile

    _NUMBA_ROOT.mkdir(parents=True, exist_ok=True)
    part = Path(tempfile.mkdtemp(prefix="seed.", dir=_NUMBA_ROOT))
    try:
        with tempfile.TemporaryDirectory() as work:
            r = subprocess.run([sys.executable, str(Path(__file__).with_name("numba_warmup.py")), work],
                               env={**os.environ, "NUMBA_CACHE_DIR": str(part)}, capture_output=True, text=True,
                               timeout=900, check=False)
        if r.returncode == 0:
            part.rename(_NUMBA_SEED)     # atomic; another session's seed made meanwhile wins (OSError)
        else:
            last = (r.stderr.strip().splitlines() or [""])[-1]
            print(f"tests/numba_warmup.py failed (exit {r.returncode}: {last}); each worker compiles its kernels",
                  file=sys.stderr)
    except (OSError, subprocess.SubprocessError) as e:
        print(f"tests/numba_warmup.py: {e}; each worker compiles its kernels", file=sys.stderr)
    finally:
        shutil.rmtree(part, ignore_errors=True)


def _many_files(config) -> bool:
    """The suite, a folder of it or more than five files: worth the seed's 35 s of CPU (a file or two after an edit
    of a kernel compile only the kernels they use, in the workers, as before)."""
    files = {str(a).split("::")[0] for a in config.args}
    return not files or any(Path(f).is_dir() for f in files) or len(files) > 5


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
