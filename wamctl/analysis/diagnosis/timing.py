"""When a logged torque acts on the rigid body of the run's physics: the zero-order hold's timing (no I/O beyond
the run directory's manifest).

A controller reads ``q[k]`` at ``t[k]`` and holds ``tau[k]`` over the control period that follows; the diagnosis
takes the torque acting around ``t[k]`` as ``(tau[k-1] + tau[k]) / 2``
(:func:`~wamctl.analysis.diagnosis.signals.zoh_centred`), exact for an arm whose physics runs continuously under
the hold (a real arm). wamctl's simulated arm integrates the held torque in ``s`` semi-implicit Euler steps of
``h = T / s`` (wamctl/backends/sim.py): the torque of period ``k`` accelerates the positions at the steps that
start at ``t[k]``, ``t[k] + h``, ... (a centred second difference at each), so it acts around ``t[k] + (T - h) / 2``,
not ``t[k] + T / 2``: after the centring the rigid body the torque balances is the state ``h / 2`` *before* the
sample (0.5 ms at the default two steps of 1 ms). The friction of the step is applied at the step's new velocity
(``t + h / 2`` of a step that starts at ``t``), which the same count puts at ``t[k] + T / 2``: no shift after the
centring.

Measured on the README loop's designed run (joints 2, 4, 7, a 2 s period) with a 4 ms measurement delay: the
rigid body at the sampled state fitted the delay as 3.53 / 3.48 ms at joints 2 / 4 and what was left was named
``link_parameters`` (an armature error at joint 4 among others); with the rigid body taken ``h / 2`` earlier,
4.03 / 4.00 ms and the delay alone named.

A run whose manifest does not give its physics step (a real arm, an imported log, the simulated pucks behind the
CAN bus) is taken as continuous physics: no shift.
"""

from __future__ import annotations

import json
from pathlib import Path

# the integrator whose timing :func:`rigid_body_shift_s` knows (wamctl.backends.sim.SimBackend.metadata)
SEMI_IMPLICIT_EULER = "semi-implicit Euler"


def rigid_body_shift_s(run_path) -> float:
    """Seconds by which the rigid body the half-sample-centred torque balances is later than the sample (the
    state at ``t + shift``): ``-h / 2`` for a run of wamctl's simulated arm whose manifest gives its physics step
    ``h`` and a semi-implicit Euler integrator, else 0 (continuous physics; a path that is not a run directory)."""
    if run_path is None:
        return 0.0
    f = Path(run_path) / "manifest.json"
    if not f.is_file():
        return 0.0
    try:
        backend = (json.loads(f.read_text()) or {}).get("backend") or {}
    except (OSError, ValueError):
        return 0.0
    h = backend.get("physics_step_s")
    if not isinstance(h, (int, float)) or not h > 0 or SEMI_IMPLICIT_EULER not in str(backend.get("integrator", "")):
        return 0.0
    return -0.5 * float(h)


def shift_rigid_body(des, jds: dict, dynamics, shift_s: float) -> None:
    """A prepared design (:func:`~wamctl.analysis.diagnosis.prepare.prepare_design`) with its rigid body taken at
    the states ``shift_s`` later (:func:`rigid_body_shift_s`), in place: the full-rate rigid-body torque on its grid
    (``des.rnea_Nm``, which a delay term shifts further) and each joint's target ``y``; ``des.rigid_shift_s``
    records it (the delay-or-inertia check takes its rows' rigid body there too). The inertial regressor rows of
    the payload and link refits are left at the sampled states (they multiply a change of the parameters: the
    shift's effect on them is of second order)."""
    import numpy as np

    from wamctl.analysis.diagnosis.signals import GridSignal

    des.rigid_shift_s = float(shift_s)
    if not shift_s:
        return
    sig = des.sig
    k = shift_s / sig.dt_s

    def rnea(rows, s):
        return dynamics.inverse_dynamics_many(sig.at("q", rows, s), sig.at("qd", rows, s), sig.at("qdd", rows, s))

    grid = des.rnea_Nm.grid
    des.rnea_Nm = GridSignal(grid, rnea(grid, k))
    union = des.union
    change = rnea(union, k) - rnea(union, 0.0)
    for j, jd in jds.items():
        jd.y_Nm = jd.y_Nm - change[np.searchsorted(union, jd.idx), j]
