"""Iterative feedback tuning (IFT) of one joint's discrete PID: the maths, no I/O (thesis section 2.2.3, ch. 5).

Notation (thesis eqs. 2.12-2.17, Hjalmarsson et al. 1994, Hjalmarsson 2002)
--------------------------------------------------------------------------
* ``rho = [kp, kd, ki]`` (the thesis' order, ch. 5), one vector per joint: the arm's joint PIDs are tuned
  decentralised, each joint on its own move while the others hold.
* ``y_tilde = y - r`` the output error of the first experiment (eq. 2.12 with ``y_r = r``: the desired response
  is the reference itself), ``J(rho) = 1/(2N) sum y_tilde^2`` (eq. 2.13, one realisation of the expectation).
  The output error alone, as in the thesis: no effort term (Hjalmarsson's ``lambda u^2``). On the simulated arm
  such a term would not bound the gains either: the PID's torque is the friction and tool torque the move needs
  whatever the gains (joint 1: RMS within 1 % from 1x to 4x kp, kd, while J falls 16x), so an unbounded tuning
  ends at ``ift.bounds``, and the report says which gains J would have pushed further.
* The controller is libbarrett's discrete PID at the control period ``T`` (see
  :mod:`wamctl.control.controllers`), on the error ``e = r - y``::

      I[n] = I[n-1] + ki T e[n-1]
      u[n] = kp e[n] + I[n] + kd (e[n] - e[n-1]) / T

  i.e. with ``q = z^-1``::

      C(q) = kp + ki T q / (1 - q) + kd (1 - q) / T
           = [(kp T + kd) + (ki T^2 - kp T - 2 kd) q + kd q^2] / [T (1 - q)]  =  N(q) / (T (1 - q))

  and the derivatives ``dC/dkp = 1``, ``dC/dki = T q / (1 - q)``, ``dC/dkd = (1 - q) / T`` give the three
  IFT filters ``(1/C) dC/drho`` (Fig. 2.4)::

      kp:  T (1 - q)     / N(q)
      kd:  (1 - q)^2     / N(q)
      ki:  T^2 q         / N(q)

  They are stable when ``N`` has its roots inside the unit circle (C minimum phase), which holds for positive
  gains with ``kd < kp T + kd`` (always) and ``ki T^2 < 4 kd + 2 kp T``; :func:`pid_filters` checks it.
* Gradient (eq. 2.15): the second experiment drives the closed loop with ``r - y1`` as the reference; its
  output ``y2`` filtered through ``(1/C) dC/drho`` estimates ``d y_tilde / d rho`` (``psi``, shape (N, 3));
  ``dJ/drho = 1/N sum y_tilde psi``.
* Hessian: Gauss-Newton ``R = 1/N sum psi psi^T`` (eq. 2.16) or the BFGS update (eq. 2.17)
  ``B+ = B + z z^T / (z^T s) - B s s^T B / (s^T B s)`` with ``s = rho_{k+1} - rho_k``,
  ``z = J'(rho_{k+1}) - J'(rho_k)``, kept ``B+ = B`` unless ``z^T s > 0`` (so B stays positive definite).
* Update (eq. 2.14): ``rho+ = rho - gamma R^-1 dJ/drho``, then clipped to the gain bounds.

Units: positions in rad, J in rad^2, gains in N m/rad, N m s/rad, N m/(rad s). Arrays of one joint's signals
are (N,); ``psi`` is (N, 3).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

N_PARAMS = 3


# ------------------------------------------------------------------------------------------------ objective
def objective(y_tilde_rad: np.ndarray) -> float:
    """Eq. 2.13: ``J = 1/(2N) sum y_tilde^2`` of one experiment's output error (N,), rad^2."""
    y = np.asarray(y_tilde_rad, float)
    if y.ndim != 1 or len(y) == 0:
        raise ValueError("objective: y_tilde must be a non-empty 1-D array")
    return float(0.5 * np.mean(y * y))


def round_significant(x: float, digits: int = 4) -> float:
    """``x`` rounded to ``digits`` significant digits (the thesis compared J "using 4 digits")."""
    if not np.isfinite(x) or x == 0:
        return float(x)
    return float(f"{x:.{digits - 1}e}")


def decreased(j_new: float, j_old: float, digits: int = 4) -> bool:
    """True when ``j_new`` is below ``j_old`` at ``digits`` significant digits (thesis section 5.3 stopping rule:
    the iterations stop when J stops decreasing at four digits)."""
    return bool(np.isfinite(j_new) and round_significant(j_new, digits) < round_significant(j_old, digits))


# ------------------------------------------------------------------------------------------------ controller
def pid_numerator(kp: float, kd: float, ki: float, dt_s: float) -> np.ndarray:
    """Coefficients of ``N(q)`` in ``C(q) = N(q) / (T (1 - q))`` (powers of q = z^-1), shape (3,)."""
    T = float(dt_s)
    return np.array([kp * T + kd, ki * T * T - kp * T - 2.0 * kd, kd], float)


def pid_frequency_response(kp: float, kd: float, ki: float, dt_s: float, w_rad_s: np.ndarray) -> np.ndarray:
    """``C(e^{j w T})`` of the libbarrett PID at angular frequencies ``w`` (rad/s), complex (n,)."""
    q = np.exp(-1j * np.asarray(w_rad_s, float) * dt_s)
    return kp + ki * dt_s * q / (1 - q) + kd * (1 - q) / dt_s


def pid_filters(kp: float, kd: float, ki: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The IFT filters ``(1/C) dC/drho`` for rho = (kp, kd, ki) as ``(b, a)`` for :func:`scipy.signal.lfilter`.

    Returns
    -------
    b : (3, 3) numerator coefficients, one row per parameter (kp, kd, ki), powers of z^-1.
    a : (3,) common denominator N(z^-1).

    Raises
    ------
    ValueError
        If the filters are unstable (C(z) not minimum phase: a root of N outside the unit circle).
    """
    T = float(dt_s)
    a = pid_numerator(kp, kd, ki, T)
    if not np.all(np.isfinite(a)) or a[0] <= 0:
        raise ValueError(f"PID gains give no causal IFT filter: kp={kp}, kd={kd}, ki={ki}")
    roots = np.roots(a)
    if roots.size and np.max(np.abs(roots)) > 1.0 + 1e-9:
        raise ValueError(f"1/C is unstable for kp={kp:g}, kd={kd:g}, ki={ki:g} (|root| "
                         f"{np.max(np.abs(roots)):.4f} >= 1): the IFT filters would diverge")
    b = np.array([[T, -T, 0.0],           # kp: dC/dkp = 1         -> T (1 - q) / N
                  [1.0, -2.0, 1.0],       # kd: dC/dkd = (1-q)/T   -> (1 - q)^2 / N
                  [0.0, T * T, 0.0]])     # ki: dC/dki = T q/(1-q) -> T^2 q / N
    return b, a


def output_gradients(y2_rad: np.ndarray, kp: float, kd: float, ki: float, dt_s: float) -> np.ndarray:
    """``psi = d y_tilde / d rho``: the second experiment's output (N,) filtered through ``(1/C) dC/drho``.

    Zero initial filter state (both experiments start at rest). Returns (N, 3), columns kp, kd, ki.
    """
    y2 = np.asarray(y2_rad, float)
    b, a = pid_filters(kp, kd, ki, dt_s)
    from scipy.signal import lfilter  # imported here: scipy.signal costs ~1 s at CLI start-up
    return np.stack([lfilter(b[i], a, y2) for i in range(N_PARAMS)], axis=1)


# ------------------------------------------------------------------------------------------------ IFT step
def ift_gradient(y_tilde_rad: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Eq. 2.15: ``dJ/drho = 1/N sum y_tilde psi``. ``y_tilde`` (N,), ``psi`` (N, 3) -> (3,)."""
    y = np.asarray(y_tilde_rad, float)
    psi = np.asarray(psi, float)
    if psi.shape != (len(y), N_PARAMS):
        raise ValueError(f"psi must be ({len(y)}, {N_PARAMS}), got {psi.shape}")
    return psi.T @ y / len(y)


def gauss_newton_hessian(psi: np.ndarray) -> np.ndarray:
    """Eq. 2.16: ``R = 1/N sum psi psi^T``, (N, 3) -> (3, 3), symmetric positive semi-definite."""
    psi = np.asarray(psi, float)
    return psi.T @ psi / len(psi)


def bfgs_update(B: np.ndarray, s: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, bool]:
    """Eq. 2.17: one BFGS update of the Hessian estimate ``B`` (3, 3).

    ``s = rho_{k+1} - rho_k``, ``z = J'(rho_{k+1}) - J'(rho_k)`` (3,). Returns ``(B_next, updated)``;
    ``B_next = B`` (not updated) unless ``z^T s > 0`` and ``s^T B s > 0``, which keeps B positive definite.
    """
    B = np.asarray(B, float)
    s = np.asarray(s, float)
    z = np.asarray(z, float)
    zs = float(z @ s)
    Bs = B @ s
    sBs = float(s @ Bs)
    if not (zs > 0 and sBs > 0 and np.isfinite(zs) and np.isfinite(sBs)):
        return B.copy(), False
    B_next = B + np.outer(z, z) / zs - np.outer(Bs, Bs) / sBs
    return 0.5 * (B_next + B_next.T), True


def newton_direction(R: np.ndarray, grad: np.ndarray, free: np.ndarray | None = None,
                     rcond: float = 1e-10) -> np.ndarray:
    """``R^-1 dJ/drho`` (3,) restricted to the ``free`` parameters (bool (3,), default all; the others get no
    step: a projected Newton direction for gains held at a bound).

    Solved in the scaled coordinates ``rho_i |R_ii|^1/2`` so that the very different gain magnitudes
    (kp ~ 1e3, ki ~ 1) do not make R look singular (the direction itself does not depend on the scaling);
    singular directions (eigenvalues below ``rcond`` of the largest) get no step.
    """
    R = np.asarray(R, float)
    g = np.asarray(grad, float)
    free = np.ones(len(g), bool) if free is None else np.asarray(free, bool)
    out = np.zeros_like(g)
    if not free.any():
        return out
    Rf = R[np.ix_(free, free)]
    gf = g[free]
    d = np.sqrt(np.clip(np.diag(Rf), 0, None))
    d[d == 0] = 1.0
    Rs = Rf / np.outer(d, d)
    w, V = np.linalg.eigh(0.5 * (Rs + Rs.T))
    keep = w > rcond * max(w.max(), 0.0)
    if not keep.any():
        return out
    inv = V[:, keep] @ np.diag(1.0 / w[keep]) @ V[:, keep].T
    out[free] = (inv @ (gf / d)) / d
    return out


def free_parameters(rho: np.ndarray, grad: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                    rtol: float = 1e-9) -> np.ndarray:
    """Bool (3,): False for a gain at a bound whose descent direction ``-grad`` points out of the box (it is held
    there: the projected Newton step of Bertsekas 1982), True otherwise."""
    rho, g = np.asarray(rho, float), np.asarray(grad, float)
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    tol = rtol * np.maximum(np.abs(rho), 1.0)
    at_lo = (rho <= lo + tol) & (g > 0)
    at_hi = (rho >= hi - tol) & (g < 0)
    return ~(at_lo | at_hi)


def ift_update(rho: np.ndarray, grad: np.ndarray, R: np.ndarray, gamma: float,
               lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> np.ndarray:
    """Eq. 2.14: ``rho - gamma R^-1 dJ/drho`` (3,). With bounds, gains held at a bound by the descent direction
    are left out of the solve (:func:`free_parameters`) and the result is clipped into the bounds."""
    rho = np.asarray(rho, float)
    if lower is None or upper is None:
        return rho - float(gamma) * newton_direction(R, grad)
    free = free_parameters(rho, grad, lower, upper)
    return clip_to_bounds(rho - float(gamma) * newton_direction(R, grad, free), lower, upper)[0]


def clip_to_bounds(rho: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gains (3,) clipped into ``[lower, upper]``; returns ``(rho_clipped, clipped_mask)``."""
    rho = np.asarray(rho, float)
    lo = np.asarray(lower, float)
    hi = np.asarray(upper, float)
    out = np.clip(rho, lo, hi)
    return out, out != rho


@dataclass
class IftEstimate:
    """One joint's IFT quantities at gains ``rho`` from a pair of experiments."""

    rho: np.ndarray          # (3,) kp, kd, ki
    J: float                 # eq. 2.13 of the first experiment
    gradient: np.ndarray     # (3,) eq. 2.15
    gauss_newton: np.ndarray  # (3, 3) eq. 2.16
    psi: np.ndarray          # (N, 3)

    def to_dict(self) -> dict:
        return {"rho": self.rho.tolist(), "J": self.J, "gradient": self.gradient.tolist(),
                "gauss_newton": self.gauss_newton.tolist()}


def ift_estimate(rho: np.ndarray, y_tilde_rad: np.ndarray, y2_rad: np.ndarray, dt_s: float) -> IftEstimate:
    """J, gradient and Gauss-Newton Hessian of one joint from the first experiment's output error
    ``y_tilde = y1 - r`` (N,) and the second experiment's output ``y2`` (N,) (same samples)."""
    rho = np.asarray(rho, float)
    y_tilde = np.asarray(y_tilde_rad, float)
    y2 = np.asarray(y2_rad, float)
    if y2.shape != y_tilde.shape:
        raise ValueError(f"the two experiments differ in length: {y_tilde.shape} vs {y2.shape}")
    psi = output_gradients(y2, rho[0], rho[1], rho[2], dt_s)
    return IftEstimate(rho, objective(y_tilde), ift_gradient(y_tilde, psi), gauss_newton_hessian(psi), psi)
