"""The WAM's transmission: joint <-> motor angles and torques, and what the motor encoders report.

Motor angle = ``J2MP @ joint angle`` (cables and, for J5/J6, a differential; the matrix lives in
:mod:`wamctl.model.params`). The encoders sit on the motors and count ``CTS`` per motor revolution, so a
joint angle is seen as ``round(J2MP q * CTS / 2 pi)`` counts, mapped back through ``J2MP^-1``. That formula
is written once, here, in small numba kernels: the simulator's sensor chain (:mod:`wamctl.model.plant`)
calls :func:`quantise_joint_rad` every control tick, and the CAN backend and its simulated pucks go through
:func:`joint_rad_to_counts` and :func:`counts_to_joint_rad`, which run the same kernels. A position read
over the bus therefore equals the simulator's reading of the same angles, bit for bit.

Conventions: names carry units: ``q_rad`` (joint angle), ``m_rad`` (motor angle), ``counts`` (encoder
counts), ``tau_Nm`` (joint torque), ``tau_m_Nm`` (motor torque). Vectorised functions accept one vector of
shape ``(7,)`` or a batch ``(..., 7)``; ``cts`` may be a scalar or a ``(7,)`` array (one value per motor).
Another arm's ``j2mp`` (the wam4's 4 x 4) sets the length: ``(..., n)`` for an ``n x n`` transmission.
Counts are rounded to the nearest count (libbarrett floors; the difference is at most one count).

Sources: libbarrett ``config/wam7w.conf`` (j2mp), ``low_level_wam-inl.h`` and ``motor_puck.cpp``
(``update()``: rad per count = 2 pi / CTS).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from wamctl.model import params as P

__all__ = [
    "J2MP",
    "M2JP",
    "as_joint_vectors",
    "counts_per_rad",
    "counts_to_joint_rad",
    "counts_to_motor_rad",
    "joint_rad_per_count",
    "joint_rad_to_counts",
    "joint_rad_to_motor_rad",
    "joint_torque_to_motor_Nm",
    "motor_rad_to_counts",
    "motor_rad_to_joint_rad",
    "motor_torque_to_joint_Nm",
    "quantise_joint_rad",
    "transmission_inverse",
]

# A read-only view of the model's J2MP, so that no caller can alter the model's copy through this module.
J2MP = P.J2MP.view()
J2MP.setflags(write=False)
M2JP = np.linalg.inv(J2MP)  # joint angle = M2JP @ motor angle; motor torque = M2JP.T @ joint torque
M2JP.setflags(write=False)

_N = P.N_JOINTS


# --------------------------------------------------------------------------------------------------
# The encoder formula: one copy, in numba (the simulator calls it every tick)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _round_to_counts(m_rad, counts_per_rad):
    """Nearest encoder count (as a float) of a motor angle (rounding half to even, like ``numpy.rint``)."""
    return np.round(m_rad * counts_per_rad)


@njit(cache=True)
def _counts_to_rad(counts, counts_per_rad):
    """Motor angle of a count."""
    return counts / counts_per_rad


@njit(cache=True)
def _joint_rad_to_counts_row(q_rad, j2mp, counts_per_rad, out):
    """``out = round(j2mp @ q * counts_per_rad)``, one configuration (float counts)."""
    n = q_rad.shape[0]
    for i in range(n):
        m_rad = 0.0
        for j in range(n):
            m_rad += j2mp[i, j] * q_rad[j]
        out[i] = _round_to_counts(m_rad, counts_per_rad[i])


@njit(cache=True)
def _counts_to_joint_rad_row(counts, m2jp, counts_per_rad, out, m_rad):
    """``out = m2jp @ (counts / counts_per_rad)``, one configuration; ``m_rad`` is scratch (may be ``counts``)."""
    n = counts.shape[0]
    for j in range(n):
        m_rad[j] = _counts_to_rad(counts[j], counts_per_rad[j])
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += m2jp[i, j] * m_rad[j]
        out[i] = acc


@njit(cache=True)
def quantise_joint_rad(q_rad, j2mp, m2jp, counts_per_rad):
    """Joint angles as the motor encoders report them: ``m2jp @ (round(j2mp @ q * c) / c)``.

    Parameters
    ----------
    q_rad : numpy.ndarray, shape (7,)
        True joint angles (rad).
    j2mp, m2jp : numpy.ndarray, shape (7, 7)
        The transmission and its inverse (:data:`J2MP`, :data:`M2JP`; a caller on a hot path passes writable
        copies: numba dispatches faster on writable arrays).
    counts_per_rad : numpy.ndarray, shape (7,)
        Counts per motor radian, per motor (:func:`counts_per_rad`).

    Returns
    -------
    numpy.ndarray, shape (7,)
        Measured joint angles (rad).
    """
    counts = np.empty(q_rad.shape[0])
    _joint_rad_to_counts_row(q_rad, j2mp, counts_per_rad, counts)
    out = np.empty(q_rad.shape[0])
    _counts_to_joint_rad_row(counts, m2jp, counts_per_rad, out, counts)  # counts no longer needed: scratch
    return out


@njit(cache=True)
def _joint_rad_to_counts_rows(q_rad, j2mp, counts_per_rad):
    out = np.empty_like(q_rad)
    for k in range(q_rad.shape[0]):
        _joint_rad_to_counts_row(q_rad[k], j2mp, counts_per_rad[k], out[k])
    return out


@njit(cache=True)
def _counts_to_joint_rad_rows(counts, m2jp, counts_per_rad):
    out = np.empty_like(counts)
    m_rad = np.empty(counts.shape[1])
    for k in range(counts.shape[0]):
        _counts_to_joint_rad_row(counts[k], m2jp, counts_per_rad[k], out[k], m_rad)
    return out


@njit(cache=True)
def _round_to_counts_flat(m_rad, counts_per_rad):
    out = np.empty_like(m_rad)
    for k in range(m_rad.shape[0]):
        out[k] = _round_to_counts(m_rad[k], counts_per_rad[k])
    return out


@njit(cache=True)
def _counts_to_rad_flat(counts, counts_per_rad):
    out = np.empty_like(counts)
    for k in range(counts.shape[0]):
        out[k] = _counts_to_rad(counts[k], counts_per_rad[k])
    return out


# --------------------------------------------------------------------------------------------------
# numpy front ends
# --------------------------------------------------------------------------------------------------


def _matrix(j2mp: np.ndarray) -> np.ndarray:
    """An arm's square transmission (n x n: the wam7's 7 x 7, the wam4's 4 x 4)."""
    j2mp = np.asarray(j2mp, dtype=float)
    if j2mp.ndim != 2 or j2mp.shape[0] != j2mp.shape[1]:
        raise ValueError(f"j2mp must be square, got {j2mp.shape}")
    return j2mp


def _inverse(j2mp: np.ndarray) -> np.ndarray:
    if j2mp is J2MP or j2mp is P.J2MP:
        return M2JP
    return np.linalg.inv(_matrix(j2mp))


def as_joint_vectors(x: ArrayLike, name: str, n: int = _N) -> np.ndarray:
    """``x`` as a float array of shape ``(..., n)`` (one vector or a batch; n the arm's joints, 7 by default);
    ``ValueError`` naming ``name`` otherwise."""
    a = np.asarray(x, dtype=float)
    if a.shape[-1:] != (n,):
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def _rows(x: np.ndarray, cts: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``x`` as contiguous rows of its joints, and counts per radian broadcast to the same rows."""
    n = x.shape[-1]
    rows = np.ascontiguousarray(x.reshape(-1, n))
    cpr = np.ascontiguousarray(np.broadcast_to(counts_per_rad(cts), x.shape).reshape(-1, n))
    return rows, cpr


def _elementwise(kernel, x: ArrayLike, cts: ArrayLike):
    """``kernel`` over ``x`` and counts per radian broadcast together (a numpy scalar for scalar inputs)."""
    x, cpr = np.broadcast_arrays(np.asarray(x, dtype=float), counts_per_rad(cts))
    out = kernel(np.ascontiguousarray(x).reshape(-1), np.ascontiguousarray(cpr).reshape(-1)).reshape(x.shape)
    return out[()] if out.ndim == 0 else out


def counts_per_rad(cts: ArrayLike) -> np.ndarray:
    """Encoder counts per motor radian, ``CTS / (2 pi)``.

    Parameters
    ----------
    cts : float or array_like
        Counts per motor revolution (the pucks' CTS property), per motor.

    Returns
    -------
    numpy.ndarray
        Same shape as ``cts``.
    """
    return np.asarray(cts, dtype=float) / (2.0 * math.pi)


def joint_rad_per_count(cts: ArrayLike, j2mp: np.ndarray | None = None) -> np.ndarray:
    """Joint-angle size of one encoder count: per joint, the largest over the motors it is coupled to.

    Parameters
    ----------
    cts : float or array_like
        Counts per motor revolution, per motor.
    j2mp : numpy.ndarray, shape (n, n), optional
        The arm's transmission (a :class:`wamctl.model.robots.Robot`'s ``j2mp``); default the wam7's :data:`J2MP`.

    Returns
    -------
    numpy.ndarray, shape (n,)
        rad.
    """
    m2jp = M2JP if j2mp is None else transmission_inverse(j2mp)
    return np.abs(m2jp).max(axis=1) / counts_per_rad(cts)


def transmission_inverse(j2mp: np.ndarray) -> np.ndarray:
    """``j2mp^-1`` of any arm's square transmission (:data:`M2JP` itself for the wam7's :data:`J2MP`): joint
    angle = inverse @ motor angle."""
    j2mp = np.asarray(j2mp, dtype=float)
    if j2mp.shape == (_N, _N) and np.array_equal(j2mp, J2MP):
        return M2JP
    if j2mp.ndim != 2 or j2mp.shape[0] != j2mp.shape[1]:
        raise ValueError(f"j2mp must be square, got {j2mp.shape}")
    return np.linalg.inv(j2mp)


def joint_rad_to_motor_rad(q_rad: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Motor angles from joint angles: ``m = j2mp @ q``.

    Parameters
    ----------
    q_rad : array_like, shape (..., 7)
        Joint angles (rad).
    j2mp : numpy.ndarray, shape (7, 7), default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Motor angles (rad).
    """
    m = _matrix(j2mp)
    return as_joint_vectors(q_rad, "q_rad", m.shape[0]) @ m.T


def motor_rad_to_joint_rad(m_rad: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Joint angles from motor angles: ``q = j2mp^-1 @ m``.

    Parameters
    ----------
    m_rad : array_like, shape (..., 7)
        Motor angles (rad).
    j2mp : numpy.ndarray, shape (7, 7), default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint angles (rad).
    """
    return as_joint_vectors(m_rad, "m_rad", np.shape(j2mp)[0]) @ _inverse(j2mp).T


def motor_rad_to_counts(m_rad: ArrayLike, cts: ArrayLike = P.ENCODER_COUNTS_PER_REV) -> np.ndarray:
    """Encoder counts from motor angles: ``round(m * CTS / (2 pi))``.

    Rounded to the nearest count (libbarrett floors); the error is at most half a count.

    Parameters
    ----------
    m_rad : array_like
        Motor angles (rad).
    cts : float or array_like, default 4096
        Counts per motor revolution, per motor.

    Returns
    -------
    numpy.ndarray
        ``int64`` counts.
    """
    return _elementwise(_round_to_counts_flat, m_rad, cts).astype(np.int64)


def counts_to_motor_rad(counts: ArrayLike, cts: ArrayLike = P.ENCODER_COUNTS_PER_REV) -> np.ndarray:
    """Motor angles from encoder counts: ``counts / (CTS / (2 pi))``.

    Parameters
    ----------
    counts : array_like
        Encoder counts.
    cts : float or array_like, default 4096
        Counts per motor revolution, per motor.

    Returns
    -------
    numpy.ndarray
        Motor angles (rad).
    """
    return _elementwise(_counts_to_rad_flat, counts, cts)


def joint_rad_to_counts(
    q_rad: ArrayLike, cts: ArrayLike = P.ENCODER_COUNTS_PER_REV, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Encoder counts of the seven motors for joint angles: ``round(j2mp @ q * CTS / (2 pi))``.

    Parameters
    ----------
    q_rad : array_like, shape (..., 7)
        Joint angles (rad).
    cts : float or array_like, default 4096
        Counts per motor revolution, per motor.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        ``int64`` counts.
    """
    m = _matrix(j2mp)
    q = as_joint_vectors(q_rad, "q_rad", m.shape[0])
    rows, cpr = _rows(q, cts)
    return _joint_rad_to_counts_rows(rows, m, cpr).reshape(q.shape).astype(np.int64)


def counts_to_joint_rad(
    counts: ArrayLike, cts: ArrayLike = P.ENCODER_COUNTS_PER_REV, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Joint angles from the seven motors' encoder counts: ``j2mp^-1 @ (counts / (CTS / (2 pi)))``.

    Parameters
    ----------
    counts : array_like, shape (..., 7)
        Encoder counts of motors 1..7.
    cts : float or array_like, default 4096
        Counts per motor revolution, per motor.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint angles (rad).
    """
    c = as_joint_vectors(counts, "counts", np.shape(j2mp)[0])
    rows, cpr = _rows(c, cts)
    return _counts_to_joint_rad_rows(rows, np.ascontiguousarray(_inverse(j2mp)), cpr).reshape(c.shape)


def joint_torque_to_motor_Nm(tau_Nm: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Motor torques from joint torques: ``tau_m = j2mp^-T @ tau`` (power-conserving transmission).

    Parameters
    ----------
    tau_Nm : array_like, shape (..., 7)
        Joint torques (N m).
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Motor torques (N m).
    """
    # row-vector form of j2mp^-T @ tau
    return as_joint_vectors(tau_Nm, "tau_Nm", np.shape(j2mp)[0]) @ _inverse(j2mp)


def motor_torque_to_joint_Nm(tau_m_Nm: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Joint torques from motor torques: ``tau = j2mp^T @ tau_m``.

    Parameters
    ----------
    tau_m_Nm : array_like, shape (..., 7)
        Motor torques (N m).
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint torques (N m).
    """
    m = _matrix(j2mp)
    return as_joint_vectors(tau_m_Nm, "tau_m_Nm", m.shape[0]) @ m


def load_kernels() -> None:
    """Compile the kernels, or load them from numba's cache, for the argument types the simulator, the CAN
    backend and the simulated pucks pass. Called before a deadline starts (opening the CAN backend, starting
    the simulated pucks), not at import: the first call of any numba function costs ~0.5-1 s (numba's target
    set-up), which commands that never convert counts (validate, report, --help) should not pay."""
    q_rad = np.zeros(_N)
    counts = joint_rad_to_counts(q_rad)
    counts_to_joint_rad(counts)
    motor_rad_to_counts(q_rad)
    counts_to_motor_rad(counts)
    quantise_joint_rad(q_rad, np.array(J2MP), np.array(M2JP), np.full(_N, counts_per_rad(P.ENCODER_COUNTS_PER_REV)))

