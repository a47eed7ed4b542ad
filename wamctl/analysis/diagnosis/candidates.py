"""Candidate effect signatures of the model diagnosis: one per effect name of the diagnosis vocabulary.

Every candidate turns the prepared signals of one joint into a change of the declared model that is linear in
its parameters once a few shape parameters (a grid) are fixed, so that "declared model + effect" nests the
declared model. Shape parameters are chosen on training data only (see :mod:`wamctl.analysis.diagnosis.crossval`).
Signs follow the residual ``y = tau - rnea(q, qd, qdd)``: what friction and the missing effects must supply.
Columns are built at the full rate and smoothed like the torque.

=================  =================================================================  ==============  =====
name               change of the model                                                grid            cols
=================  =================================================================  ==============  =====
stribeck           [qd>0] e^-(qd/vs)^2, -[qd<0] e^-(qd/vs)^2                          vs 4-400 mrad/s  2
position_ripple    sin, cos of 2 pi h q / P, h = 1 .. H (a fundamental and harmonics)  P 0.01-2 rad,   2 H
                                                                                      H 1-4
payload            link-7 columns of the joint torque regressor (m, m c, inertia),    none             10
                   the directions the joint's motion excites
delay              the whole model evaluated at the positions d later                 d 1-20 ms        0
friction_drift     Coulomb and viscous torque of the declared fit x exp(-t / T)       T 0.05-4 x run   2
backlash           (at onsets, :mod:`wamctl.analysis.diagnosis.backlash`, either side  none             1
                   of the gap) and the gravity stiffness x direction (the link sits
                   w/2 off the encoder; no column for a gap on the motor side)
=================  =================================================================  ==============  =====
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from wamctl.analysis.diagnosis.signals import savgol_gain
from wamctl.model import params as P
from wamctl.model.friction import stribeck_decay

EFFECT_NAMES = ("stribeck", "position_ripple", "payload", "delay", "friction_drift", "backlash", "link_parameters")
ARM_ONLY = ("link_parameters",)     # tested over the whole arm only (:mod:`wamctl.analysis.diagnosis.links`)

STRIBECK_VS_GRID_RAD_S = np.geomspace(0.004, 0.4, 13)
RIPPLE_PERIOD_MIN_RAD = 0.01
RIPPLE_PERIOD_MAX_RAD = 2.0
RIPPLE_MAX_HARMONICS = 4          # a ripple's fundamental and up to three harmonics
RIPPLE_MIN_PERIODS = 1.25         # a ripple is named only where the joint's travel covers this many periods
DELAY_GRID_S = np.arange(2, 41) * 0.5e-3                # 1 to 20 ms
DRIFT_T_GRID_FRACTION = np.geomspace(0.05, 30.0, 16)   # time constants as fractions of the run (30: linear)
D7_M = float(P.DH_D_M[6])
MAX_BREAKAWAY_RATIO = 10.0        # Stribeck breakaway / Coulomb (the plant's own bound, specs.StribeckEffect)


def stribeck_columns(qd: np.ndarray, vs: float) -> np.ndarray:
    """Stribeck regressor (m, 2): breakaway excess per direction, decaying with speed as exp(-(qd/vs)^2)."""
    qd = np.asarray(qd, float)
    e = stribeck_decay(qd, vs, 2.0)
    out = np.empty((2, len(qd)))       # filled row by row (contiguous writes), returned transposed
    np.multiply(qd > 0, e, out=out[0])
    np.multiply(qd < 0, e, out=out[1])
    np.negative(out[1], out=out[1])
    return out.T


def ripple_gain(qd: np.ndarray, period: float, window: int, gauss: float, dt_s: float) -> np.ndarray:
    """(m,) share of a ripple of ``period`` (rad) in the angle that the smoothing filter leaves when the joint
    passes it at speed ``qd`` (m,): the ripple's frequency in time is ``|qd| / period``."""
    return savgol_gain(window, np.abs(qd) * dt_s / period, gauss)


def ripple_columns(q: np.ndarray, qd: np.ndarray, period: float, window: int, gauss: float,
                   dt_s: float, n_harmonics: int = 1) -> np.ndarray:
    """sin/cos of 2 pi h q / period, h = 1 .. ``n_harmonics`` (m, 2 H: sin and cos of each harmonic in turn), each
    attenuated as the smoothing filter attenuates it at the current speed (harmonic h passes at ``h |qd| /
    period``). Used to compare candidate periods and for a declared ripple; the kept columns are smoothed
    exactly."""
    out = ripple_basis(q, period, n_harmonics)
    for h in range(1, n_harmonics + 1):
        out[:, 2 * h - 2: 2 * h] *= ripple_gain(qd, period / h, window, gauss, dt_s)[:, None]
    return out


def ripple_basis(q, period: float, n_harmonics: int) -> np.ndarray:
    """sin, cos of 2 pi h q / period for h = 1 .. ``n_harmonics`` in turn, shape ``q.shape + (2 H,)``: the one
    copy of a ripple's columns (the candidates' comparison and the design's kept columns)."""
    z1 = np.exp(2j * np.pi * np.asarray(q, float) / period)      # harmonic h: z1^h = cos + i sin
    z, out = z1, np.empty(np.shape(q) + (2 * n_harmonics,))
    for k in range(n_harmonics):
        out[..., 2 * k], out[..., 2 * k + 1] = z.imag, z.real
        z = z * z1
    return out


def ripple_key(h: int, what: str) -> str:
    """The report's key of harmonic ``h`` (1: the fundamental) of a ripple: ``amplitude_Nm``, ``phase_rad`` for
    the fundamental, ``amplitude_2_Nm``, ``phase_2_rad``, ... for the harmonics."""
    unit = {"amplitude": "Nm", "phase": "rad"}[what]
    return f"{what}_{unit}" if h == 1 else f"{what}_{h}_{unit}"


def ripple_harmonics(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """(amplitudes (H,), phases (H,)) of harmonics 1 .. H of a ripple's report parameters ``p`` (a one-sinusoid
    ripple without ``n_harmonics``)."""
    n = int(p.get("n_harmonics") or 1)
    amps = np.array([float(p[ripple_key(h, "amplitude")]) for h in range(1, n + 1)])
    phases = np.array([float(p[ripple_key(h, "phase")]) for h in range(1, n + 1)])
    return amps, phases


PAYLOAD_RANK_RTOL = 1e-3     # payload directions a joint's motion excites less than this (singular values) are left out


def payload_basis(P: np.ndarray) -> np.ndarray:
    """(10, 10) the payload's inertial-parameter directions a joint's regressor rows ``P`` (m, 10) excite: an
    orthonormal basis of the row space of the equilibrated columns (singular values at least
    ``PAYLOAD_RANK_RTOL`` of the largest), back in parameter units, padded with zero columns. The candidate's
    columns are ``P @ basis``: what the motion does not show is not fitted (and then extrapolated to the held-out
    folds that show a little of it)."""
    scale = np.sqrt((P ** 2).sum(axis=0))
    live = scale > 1e-9 * max(scale.max(), 1e-300)
    out = np.zeros((P.shape[1], P.shape[1]))
    if not live.any():
        return out
    _, sv, Vt = np.linalg.svd(P[:, live] / scale[live], full_matrices=False)
    V = Vt[sv >= sv[0] * PAYLOAD_RANK_RTOL].T
    out[np.ix_(live, np.arange(V.shape[1]))] = V / scale[live][:, None]
    return out


def payload_from_pi(pi: np.ndarray, robot: str = "wam7") -> dict:
    """Mass (kg) and centre of mass (m, flange frame) of a payload from the first four of its ten inertial
    parameters ``pi`` (the last link's frame: ``m``, ``m c``; on the wam7 link 7's, the flange ``D7_M`` along its
    z; on another arm :func:`flange_frame`); the centre is zero for a mass that is not positive."""
    m = float(pi[0])
    if m <= 0:
        return {"mass_kg": m, "com_m": [0.0, 0.0, 0.0]}
    if robot == "wam7":
        com = pi[1:4] / m - np.array([0.0, 0.0, D7_M])
    else:
        origin, rot = flange_frame(robot)
        com = rot.T @ (pi[1:4] / m - origin)
    return {"mass_kg": m, "com_m": [float(x) for x in com]}


def robot_of(des) -> str:
    """The arm of a run's :class:`~wamctl.analysis.diagnosis.design.Design` (set by
    :func:`wamctl.analysis.diagnosis.prepare.prepare_design`; the wam7 when not said)."""
    return getattr(des, "robot", "wam7")


@lru_cache(maxsize=4)
def flange_frame(robot: str = "wam7") -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), rotation (3, 3)) of ``robot``'s flange frame (where a payload's centre of mass is given,
    :mod:`wamctl.model.dynamics`) in the frame of its last link's inertial parameters: a point ``c`` of the
    flange frame is ``origin + rotation @ c`` there. Read from the model itself (a unit mass at the flange's
    origin and one along each of its axes): on the wam7 ``(0, 0, d7)`` and the identity; on the wam4 the tool
    plate 0.36 m along z4 and link 4's twist."""
    from wamctl.model.dynamics import Payload, WamDynamics

    bare = WamDynamics(robot=robot).standard_parameters()[-10:]

    def moment(c) -> np.ndarray:
        return (WamDynamics(Payload(1.0, tuple(c)), robot=robot).standard_parameters()[-10:] - bare)[1:4]

    origin = moment([0.0, 0.0, 0.0])
    rot = np.column_stack([moment(e) - origin for e in np.eye(3)])
    return origin, rot
