"""Physical consistency of a link's inertial parameters: the pseudo-inertia and its log-Cholesky parameters.

Conventions
-----------
A link's 10 standard parameters (the order of :mod:`.base`: ``m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz``,
first moment ``h = m c`` and inertia ``I`` about a frame origin) are physically consistent (a mass distribution
with a non-negative density exists) exactly when the pseudo-inertia

    J = [[S, h], [h^T, m]],   S = tr(I) / 2 * 1 - I   (the second moment of the mass distribution)

is positive semidefinite (Wensing, Kim and Slotine, "Linear matrix inequalities for physically consistent
inertial parameter identification", IEEE RA-L 2017). The condition is frame-independent, so it can be checked
in pinocchio's joint frames as well as in the DH frames.

``J`` is linear in the standard parameters (``J = sum_k pi_k B_k``, :data:`PSEUDO_BASIS`), so "every link
physically consistent" is a linear matrix inequality: the identification's consistent estimate is a convex
program (:mod:`.estimator`).
"""

from __future__ import annotations

import numpy as np

N_LINK = 10


def _pseudo_basis() -> np.ndarray:
    """(10, 4, 4) symmetric matrices with ``J = sum_k pi_k B_k`` (the pseudo-inertia is linear in pi)."""
    out = np.empty((N_LINK, 4, 4))
    for k in range(N_LINK):
        e = np.zeros(N_LINK)
        e[k] = 1.0
        out[k] = pseudo_inertia(e)
    return out


def pseudo_inertia(pi10: np.ndarray) -> np.ndarray:
    """(4, 4) pseudo-inertia ``J`` of one link's standard parameters (10,)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(pi10, float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = (hx, hy, hz)
    J[3, 3] = m
    return J


def standard_from_pseudo(J: np.ndarray) -> np.ndarray:
    """The 10 standard parameters of a pseudo-inertia (4, 4): the inverse of :func:`pseudo_inertia`."""
    S = J[:3, :3]
    inertia = np.trace(S) * np.eye(3) - S
    return np.array([J[3, 3], J[0, 3], J[1, 3], J[2, 3], inertia[0, 0], inertia[0, 1], inertia[1, 1],
                     inertia[0, 2], inertia[1, 2], inertia[2, 2]])


def consistency_margin(pi: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of each link's pseudo-inertia, relative to its largest: (n_links,) for ``pi``
    (10 n_links,). Non-negative (to rounding) for a physically consistent link."""
    pi = np.asarray(pi, float).reshape(-1, N_LINK)
    out = np.empty(len(pi))
    for i, p in enumerate(pi):
        ev = np.linalg.eigvalsh(pseudo_inertia(p))
        out[i] = ev[0] / max(abs(ev[-1]), 1e-300)
    return out


def is_consistent(pi: np.ndarray, rel_tol: float = 1e-9) -> np.ndarray:
    """(n_links,) bool: each link's pseudo-inertia positive semidefinite (to ``rel_tol`` of its scale)."""
    return consistency_margin(pi) >= -rel_tol


PSEUDO_BASIS = _pseudo_basis()
