"""The closed-loop engine: runs a sampled reference through a controller on a backend, recording every tick.

The engine knows nothing about experiment kinds: an experiment builds a :class:`~wamctl.control.trajectory.
Reference` and a controller, and the engine executes them (bluesky's plan / engine / consumer split).

Recorded columns (one row per control tick, wide and unit-named): ``t_s``, ``q_ref_{j}_rad``, ``q_{j}_rad``
(measured), ``tau_{j}_Nm`` (applied, after saturation), and on the simulator also the truth
``q_true_{j}_rad`` and ``qd_true_{j}_rad_s``; joints j = 1..n, n the arm's (7 on the wam7, 4 on the wam4: the
backend's ``n_joints``).
"""

from __future__ import annotations

import logging

import numpy as np

from wamctl.backends.base import ArmBackend, record_row
from wamctl.backends.sim_fused import FusedLoop, fused_supported
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import Reference
from wamctl.model import params as P
from wamctl.runs.store import TableWriter

log = logging.getLogger(__name__)
J = range(1, P.N_JOINTS + 1)


def data_columns(with_truth: bool, n_joints: int = P.N_JOINTS) -> list[str]:
    """The loop table's columns for an arm of ``n_joints`` (default the wam7's seven)."""
    J = range(1, n_joints + 1)
    cols = ["t_s"] + [f"q_ref_{j}_rad" for j in J] + [f"q_{j}_rad" for j in J] + [f"tau_{j}_Nm" for j in J]
    if with_truth:
        cols += [f"q_true_{j}_rad" for j in J] + [f"qd_true_{j}_rad_s" for j in J]
    return cols


class LoopRecorder:
    """Rows of a loop in memory, mirrored to a chunked table on disk every ``chunk_rows`` ticks."""

    def __init__(self, n_rows: int, with_truth: bool, writer: TableWriter | None = None,
                 t_offset_s: float = 0.0, n_joints: int = P.N_JOINTS):
        self.columns = data_columns(with_truth, n_joints)
        self.rows = np.full((n_rows, len(self.columns)), np.nan)
        self.writer = writer
        self.n = 0
        self._flushed = 0
        self.t_offset_s = t_offset_s

    def flush(self) -> None:
        """Write every row recorded so far that is not yet on disk (idempotent: an interrupt anywhere in it
        neither loses nor repeats a row when it is called again)."""
        if self.writer is None:
            return
        self.writer.sync(self.rows, self.n)
        self.writer.flush()
        self._flushed = self.n

    def result(self) -> np.ndarray:
        return self.rows[: self.n]


def run_loop(backend: ArmBackend, controller: JointController, reference: Reference,
             recorder: LoopRecorder, progress=None, chunk_ticks: int = 2500, *, fused: bool = True) -> None:
    """Execute ``reference`` tick by tick. Raises whatever the backend raises (safety faults, Ctrl-C);
    the caller flushes ``recorder`` and records the status.

    ``fused=True`` (the default): on the simulator with a plain joint controller (:func:`wamctl.backends.sim_fused.
    fused_supported`; elsewhere, e.g. a wam4, the CAN arm or another controller, the Python path) the ticks run
    compiled, in chunks that end where this loop flushes the recorder or reports progress, equal to the Python
    path within ~1e-15 rad per step; ``fused=False`` keeps the Python path. That rounding difference (the numba
    rigid body vs pinocchio's) can move a true position held still by stiction across an encoder count's
    rounding boundary, after which a long run with stick-slip is another realisation of the same noise model
    (tests/analysis/test_diagnose.py's seed-11 Stribeck run: one count at tick 7582 of 16447). The diagnosis'
    breakaway estimate no longer depends on such a count (tests/analysis/test_diagnose_stribeck_stability.py);
    friction-id's standard errors hold the truth on either path's realisations since they carry the rigid
    body's timing within the held torque's period (:data:`wamctl.analysis.friction_id.velocity_map.
    TIMING_SE_PERIODS`: without it a viscous coefficient was 5-7 of its standard errors off on some seeds of
    both paths)."""
    if fused and fused_supported(backend, controller):
        _run_fused(backend, controller, reference, recorder, progress, chunk_ticks)
        return
    rows = recorder.rows
    n_j = getattr(backend, "n_joints", P.N_JOINTS)
    truth = backend.truth() if hasattr(backend, "truth") else (np.zeros(n_j), np.zeros(n_j))
    if rows.shape[1] not in (1 + 3 * n_j, 1 + 5 * n_j):
        raise ValueError(f"the recorder's table has {rows.shape[1]} columns, the arm's {n_j} joints need "
                         f"{1 + 3 * n_j}: build it with LoopRecorder(..., n_joints={n_j})")
    q_ref = reference.q_rad
    t_s = reference.t_s + recorder.t_offset_s
    n = len(reference)
    update_every = max(1, n // 200)
    for k in range(n):
        q = backend.read_positions()
        tau = backend.command_torques(controller.update(q_ref[k], q))
        record_row(rows, recorder.n, t_s[k], q_ref[k], q, tau, truth[0], truth[1])
        recorder.n += 1
        backend.wait_next_cycle()
        if recorder.writer is not None and recorder.n - recorder._flushed >= chunk_ticks:
            recorder.flush()
        if progress is not None and k % update_every == 0:
            progress(k, n)
    if progress is not None:
        progress(n, n)


def _run_fused(backend, controller, reference, recorder, progress, chunk_ticks) -> None:
    """:func:`run_loop` through :class:`wamctl.backends.sim_fused.FusedLoop`: the Python-side work (flush,
    progress) at the ticks the Python path does it; a tick that would fault runs on the Python path, which
    raises."""
    loop = FusedLoop(backend, controller)
    q_ref = np.ascontiguousarray(reference.q_rad, dtype=float)
    t_s = np.ascontiguousarray(reference.t_s + recorder.t_offset_s, dtype=float)
    n = len(reference)
    update_every = max(1, n // 200)
    k = 0
    while k < n:
        end = n
        if recorder.writer is not None:          # the tick after which the Python path flushes
            end = min(end, k + max(1, chunk_ticks - (recorder.n - recorder._flushed)))
        if progress is not None:                 # the tick after which it reports progress
            end = min(end, k + (-k) % update_every + 1)
        done = loop.advance(k, end, q_ref, t_s, recorder)
        if done < end - k:                       # tick k + done faults: the Python path raises it
            k += done
            q = backend.read_positions()
            tau = backend.command_torques(controller.update(q_ref[k], q))
            raise RuntimeError(f"the compiled loop stopped before tick {k} but the tick ran ({tau})")
        k = end
        if recorder.writer is not None and recorder.n - recorder._flushed >= chunk_ticks:
            recorder.flush()
        if progress is not None and (k - 1) % update_every == 0:
            progress(k - 1, n)
    if progress is not None:
        progress(n, n)
