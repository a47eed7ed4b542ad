"""The arm's rigid body refitted over the diagnosed joints (no I/O): one change of its base parameters shared by
every joint, on top of each joint's own model, with held-out residuals.

The change lives in the rigid-body base parameters of the identification
(:mod:`wamctl.analysis.identification.base`; ``links_base`` of each joint's data: the link and armature
combinations any data could determine), parametrised as ``delta_beta = A v``:

* free (``A`` the identity on the base columns these data determine): the unrestricted refit;
* a wrist payload (``A`` the link-7 columns of the base map: ten inertial parameters, free);
* plausible link errors (``A = plausible_link_map()``: each physical parameter of the declared arm moved within
  the declared accuracy, ``v`` in [-1, 1]);
* and their sums.

Every joint's own coefficients (friction, the other effects it kept) are profiled out of its per-fold normal
equations, so each model is a small quadratic problem in ``v`` (bounded where the parametrisation is); the normal
equations are built once per joint and fold and shared by every model compared.

The declared accuracy is an assumption of the method, stated here and in docs/diagnosis-report.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from wamctl.analysis.diagnosis.crossval import unpredictable
from wamctl.analysis.diagnosis.design import Design

# The declared accuracy of the arm's own parameters: a datasheet's link masses, centres of mass and inertias (and
# the reflected rotor inertias) are off by up to about 10 % on a real arm (CAD against identification); a centre
# of mass also by a few millimetres whatever the link's size (cables, covers, fasteners). A change of the torques
# that link errors within these bounds can make is the arm's own (``link_parameters``); a payload is named only
# for what they cannot make.
LINK_PRIOR_SHARE = 0.10
LINK_PRIOR_COM_M = 0.005
MAX_GRAM_ROWS = 20000        # rows per joint in the normal equations (evenly spaced): the refit has <= 77 unknowns
PAYLOAD_BASE = slice(60, 70)
# directions of the parameters the training folds excite less than this share of the best (columns equilibrated,
# eigenvalues of the normal equations: singular values below 1e-3) are held near zero by a ridge: a refit must
# not move what the data do not show (and then mispredict the held-out fold that shows it)
RIDGE_RTOL = 1e-6
LIVE_RTOL = 1e-8             # a column with less than this share left once the joints' own columns are fitted  # link 7's standard parameters: a payload is part of link 7


@dataclass
class ArmSystem:
    """Per-fold normal equations of the diagnosed joints ``js`` for ``[own columns, links_base, target]``."""

    js: list[int]
    own: dict                 # j -> (y (m,), X (m, p)): the joint's own model
    w: dict                   # j -> weight of its rows (1 / the RMS of its own held-out residual)
    grams: dict               # j -> (n_folds, d, d) unweighted normal equations of each fold's rows
    n_folds: int

    @property
    def n_base(self) -> int:
        return self.grams[self.js[0]].shape[1] - 1 - self.own[self.js[0]][1].shape[1]


def arm_system(des: Design, jds: dict, own: dict, w: dict) -> ArmSystem:
    """The normal equations of every joint in ``own`` ({j: (y, X)}), per fold."""
    js = list(own)
    grams = {}
    for j in js:
        jd = jds[j]
        y, X = own[j]
        rows = np.arange(jd.n)[:: max(1, jd.n // MAX_GRAM_ROWS)]
        M = np.column_stack([X[rows], jd.extra["links_base"][rows], y[rows]])
        fold = jd.fold[rows]
        grams[j] = np.stack([M[fold == f].T @ M[fold == f] for f in range(des.n_folds)])
    return ArmSystem(js, own, w, grams, des.n_folds)


def _pinv_sym(S: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric positive semi-definite matrix (scaled; directions below 1e-12 dropped)."""
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    lam, V = np.linalg.eigh(S / np.outer(d, d))
    keep = lam > max(lam.max(), 1e-300) * 1e-12
    return (V[:, keep] / lam[keep]) @ V[:, keep].T / np.outer(d, d)


def _reduced(sys_: ArmSystem, fold: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(H (nb, nb), g (nb,)) of the weighted training rows (all folds but ``fold``) with each joint's own
    coefficients profiled out, H before the profiling, and {j: (Sxx^+, Sxz, Sxy)} to recover them."""
    nb = sys_.n_base
    H, H_raw, g, parts = np.zeros((nb, nb)), np.zeros((nb, nb)), np.zeros(nb), {}
    for j in sys_.js:
        S = sys_.grams[j].sum(axis=0) - (sys_.grams[j][fold] if fold is not None else 0.0)
        p = sys_.own[j][1].shape[1]
        Sxx, Sxz, Sxy = S[:p, :p], S[:p, p:p + nb], S[:p, -1]
        Pxx = _pinv_sym(Sxx)
        w2 = sys_.w[j] ** 2
        H += w2 * (S[p:p + nb, p:p + nb] - Sxz.T @ Pxx @ Sxz)
        H_raw += w2 * S[p:p + nb, p:p + nb]
        g += w2 * (S[p:p + nb, -1] - Sxz.T @ Pxx @ Sxy)
        parts[j] = (Pxx, Sxz, Sxy)
    return H, g, H_raw, parts


def _solve(H: np.ndarray, g: np.ndarray, H_raw: np.ndarray, A: np.ndarray, bound: np.ndarray | None) -> np.ndarray:
    """argmin_v 1/2 v' A'HA v - g'A v (+ a ridge of ``RIDGE_RTOL``, columns equilibrated), with |v| <= bound
    where given (inf: free). A column the data do not excite (zero, or all but ``LIVE_RTOL`` of it in the span
    of the joints' own columns: ``H`` against ``H_raw``) stays at zero."""
    v = np.zeros(A.shape[1])
    raw = np.einsum("ij,ik,kj->j", A, H_raw, A)
    Hv = A.T @ H @ A
    live = (np.diag(Hv) > LIVE_RTOL * raw) & (raw > LIVE_RTOL * max(raw.max(), 1e-300))
    if not live.any():
        return v
    Hv, gv = Hv[np.ix_(live, live)], (A.T @ g)[live]
    d = np.sqrt(np.diag(Hv))
    lam, V = np.linalg.eigh(Hv / np.outer(d, d))
    lam = np.clip(lam, 0.0, None) + RIDGE_RTOL * max(lam.max(), 1e-300)
    proj = V.T @ (gv / d)
    x = V @ (proj / lam)
    if bound is not None and np.any(np.abs(x / d) > np.asarray(bound)[live]):
        from scipy.optimize import lsq_linear

        lim = np.asarray(bound, float)[live] * d        # R'R = the ridged form, R'rhs = the scaled gradient
        x = lsq_linear(np.sqrt(lam)[:, None] * V.T, proj / np.sqrt(lam), bounds=(-lim, lim), method="bvls").x
    v[live] = x / d
    return v


def arm_cv(sys_: ArmSystem, jds: dict, A: np.ndarray | None, bound: np.ndarray | None = None) -> tuple[dict, dict]:
    """Held-out residuals {j: (m,)} of every joint's own model plus the shared change ``delta_beta = A v``
    (``A`` None: no change), ``v`` fitted without each fold; and ``v`` per fold {fold: (k,)}, on all data under
    key None."""
    nb = sys_.n_base
    A = np.zeros((nb, 0)) if A is None else A
    e = {j: np.full(jds[j].n, np.nan) for j in sys_.js}
    vs = {}
    for f in [None] + list(range(sys_.n_folds)):
        H, g, H_raw, parts = _reduced(sys_, f)
        v = _solve(H, g, H_raw, A, bound) if A.shape[1] else np.zeros(0)
        vs[f] = v
        if f is None:
            continue
        db = A @ v
        for j in sys_.js:
            jd = jds[j]
            y, X = sys_.own[j]
            Pxx, Sxz, Sxy = parts[j]
            theta = Pxx @ (Sxy - Sxz @ db)
            te = np.flatnonzero(jd.fold == f)
            e[j][te] = y[te] - X[te] @ theta - jd.extra["links_base"][te] @ db
            e[j][unpredictable(jd, np.flatnonzero(jd.fold != f), te)] = np.nan
    return e, vs


def payload_map() -> np.ndarray:
    """(nb, 10) change of the rigid-body base parameters per inertial parameter of a payload on link 7."""
    return _base_map()[:, PAYLOAD_BASE]


@lru_cache(maxsize=1)
def _base_map() -> np.ndarray:
    """(nb, 77) the base map restricted to the rigid body: ``delta_beta = K delta_pi`` (links and armature)."""
    from wamctl.analysis.identification.base import N7, N_INERTIAL, base_parameters

    base = base_parameters()
    return base.matrix[base.independent < N_INERTIAL + N7][:, :N_INERTIAL + N7]


def plausible_link_map(links=None, payload=None) -> np.ndarray:
    """(nb, 77) change of the rigid-body base parameters when one physical parameter of the declared arm moves
    to the bound of its declared accuracy (``LINK_PRIOR_SHARE``, ``LINK_PRIOR_COM_M``): per link its mass, the
    three coordinates of its centre of mass (DH frame; the share of its distance from the frame's origin plus the
    absolute allowance), the six entries of its inertia about the centre (the share of its largest diagonal
    entry); per joint its armature. Central differences through the rigid body (linear to within the share
    squared). ``links``: :class:`~wamctl.model.params.LinkParameters` (None: the datasheet); ``payload``: a
    declared :class:`~wamctl.model.dynamics.Payload`, kept as it is."""
    from wamctl.model.params import LinkParameters

    return _plausible_link_map(links if links is not None else LinkParameters.datasheet(), payload)


@lru_cache(maxsize=4)
def _plausible_link_map(links, payload) -> np.ndarray:
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.params import N_JOINTS, LinkParameters

    K = _base_map()
    arrays = [np.array(links.mass_kg), np.array(links.com_m), np.array(links.inertia_kg_m2),
              np.array(links.armature_kg_m2)]

    def standard(a: list) -> np.ndarray:
        dyn = WamDynamics(payload, LinkParameters(*a))
        return np.concatenate([dyn.standard_parameters(), dyn.armature_kg_m2])

    s = LINK_PRIOR_SHARE
    out = []
    for i in range(N_JOINTS):
        moves = [(0, (i,), s * arrays[0][i])]
        moves += [(1, (i, k), s * np.linalg.norm(arrays[1][i]) + LINK_PRIOR_COM_M) for k in range(3)]
        moves += [(2, (i, k), s * arrays[2][i, :3].max()) for k in range(6)]
        moves += [(3, (i,), s * arrays[3][i])]
        for a, idx, b in moves:
            if b <= 0:
                out.append(np.zeros(len(K)))
                continue
            h = 1e-3 * b
            plus, minus = [x.copy() for x in arrays], [x.copy() for x in arrays]
            plus[a][idx] += h
            minus[a][idx] -= h
            out.append(K @ ((standard(plus) - standard(minus)) * (b / (2 * h))))
    return np.column_stack(out)
