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
PAYLOAD_BASE = slice(60, 70)  # link 7's on the wam7 (payload_map: the last link of any arm)
# a refit changes only the combinations of base parameters the training folds determine (columns equilibrated,
# singular values at least this share of the largest): moving what the data do not show would mispredict a
# held-out fold that shows it
RANK_RTOL = 1e-3
LIVE_RTOL = 1e-8             # a column with less than this share left once the joints' own columns are fitted


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


def _determined(H: np.ndarray, H_raw: np.ndarray) -> np.ndarray:
    """(nb, nb) projector onto the changes of the base parameters the training rows determine: columns
    equilibrated, directions whose singular value is at least ``RANK_RTOL`` of the largest; a column with less
    than ``LIVE_RTOL`` of its norm left once the joints' own columns are fitted (``H`` against ``H_raw``) is not
    determined."""
    hd, raw = np.diag(H), np.diag(H_raw)
    live = (hd > LIVE_RTOL * raw) & (raw > LIVE_RTOL * max(raw.max(), 1e-300))
    out = np.zeros_like(H)
    if not live.any():
        return out
    d = np.sqrt(hd[live])
    lam, V = np.linalg.eigh(H[np.ix_(live, live)] / np.outer(d, d))
    U = V[:, lam > max(lam.max(), 1e-300) * RANK_RTOL ** 2]
    out[np.ix_(live, live)] = (U @ U.T) / d[:, None] * d[None, :]
    return out


def determined_parameters(sys_: ArmSystem, share_tol: float = 0.01) -> tuple[np.ndarray, int]:
    """(nb,) whether each base parameter is determined by all the rows once the joints' own columns are fitted
    (at most ``share_tol`` of it, columns equilibrated, outside the determined directions), and how many
    directions are determined."""
    H, _, H_raw, _ = _reduced(sys_, None)
    Pr = _determined(H, H_raw)
    d = np.sqrt(np.clip(np.diag(H), 1e-300, None))
    S = Pr * d[:, None] / d[None, :]               # the projector in equilibrated coordinates (symmetric)
    rank = int(round(float(np.trace(S))))
    return np.diag(S) >= 1.0 - share_tol, rank


def _solve(H: np.ndarray, g: np.ndarray, Pr: np.ndarray, A: np.ndarray, bounds: tuple | None) -> np.ndarray:
    """argmin_v 1/2 v' B'HB v - g'B v with ``B = Pr A`` (the change restricted to what the data determine),
    ``lo <= v <= hi`` where ``bounds = (lo, hi)`` (None: free); among equal solutions one near zero (a ridge of
    1e-10, columns equilibrated)."""
    B = Pr @ A
    Hv, gv = B.T @ H @ B, B.T @ g
    v = np.zeros(A.shape[1])
    dv = np.diag(Hv)
    live = dv > 1e-12 * max(dv.max(), 1e-300)
    if not live.any():
        return v
    d = np.sqrt(dv[live])
    lam, V = np.linalg.eigh(Hv[np.ix_(live, live)] / np.outer(d, d))
    lam = np.clip(lam, 0.0, None) + 1e-10 * max(lam.max(), 1e-300)
    proj = V.T @ (gv[live] / d)
    x = V @ (proj / lam)
    if bounds is not None:
        lo, hi = (np.asarray(b, float)[live] * d for b in bounds)
        if np.any(x < lo) or np.any(x > hi):
            from scipy.optimize import lsq_linear

            # R'R = the ridged form, R'rhs = the scaled gradient
            x = lsq_linear(np.sqrt(lam)[:, None] * V.T, proj / np.sqrt(lam), bounds=(lo, hi), method="bvls").x
    v[live] = x / d
    return v


def arm_cv(sys_: ArmSystem, jds: dict, A: np.ndarray | None, bounds: tuple | None = None,
           folds: bool = True) -> tuple[dict, dict, dict]:
    """Held-out residuals {j: (m,)} of every joint's own model plus the shared change ``delta_beta = A v``
    (``A`` None: no change; only what the training folds determine is changed), ``v`` fitted without each fold
    (within ``bounds = (lo, hi)``, None: free);
    the change of the base parameters {fold: (nb,)} and ``v`` {fold: (k,)} per fold, on all data under key
    None (``folds`` False: on all data only, no held-out residuals)."""
    nb = sys_.n_base
    A = np.zeros((nb, 0)) if A is None else A
    e = {j: np.full(jds[j].n, np.nan) for j in sys_.js}
    vs, betas = {}, {}
    for f in [None] + (list(range(sys_.n_folds)) if folds else []):
        H, g, H_raw, parts = _reduced(sys_, f)
        Pr = _determined(H, H_raw)
        v = _solve(H, g, Pr, A, bounds) if A.shape[1] else np.zeros(0)
        vs[f] = v
        betas[f] = db = Pr @ (A @ v)
        if f is None:
            continue
        for j in sys_.js:
            jd = jds[j]
            y, X = sys_.own[j]
            Pxx, Sxz, Sxy = parts[j]
            theta = Pxx @ (Sxy - Sxz @ db)
            te = np.flatnonzero(jd.fold == f)
            e[j][te] = y[te] - X[te] @ theta - jd.extra["links_base"][te] @ db
            e[j][unpredictable(jd, np.flatnonzero(jd.fold != f), te)] = np.nan
    return e, betas, vs


def payload_map(robot: str = "wam7") -> np.ndarray:
    """(nb, 10) change of the rigid-body base parameters per inertial parameter of a payload on the last link
    (link 7 on the wam7, link 4 on the wam4)."""
    n = _n_joints(robot)
    return _base_map(robot)[:, 10 * (n - 1):10 * n]


def _n_joints(robot: str) -> int:
    from wamctl.model.robots import get_robot

    return get_robot(robot).n_joints


def payload_cone(max_com_m: float, robot: str = "wam7") -> tuple[np.ndarray, np.ndarray]:
    """(nb, 8) the wrist payloads as a cone: a positive mass whose centre lies within ``max_com_m`` of the flange
    (in each coordinate of the flange frame), its own inertia left out (small beside the mass's at the levers of
    the joints). Mass and first moment ``(m, m (c + d7 z))`` are the non-negative combinations of the eight
    rays ``(1, d7 z + max_com_m (+-1, +-1, +-1))``: coefficients in [0, inf). Returns the cone's base map
    (nb, 8) and the rays as (4, 8) columns (``(m, m c7) = rays @ coefficients``). On another arm than the wam7
    the flange is its own (:func:`~wamctl.analysis.diagnosis.candidates.flange_frame`: the wam4's tool plate)."""
    from wamctl.analysis.diagnosis.candidates import D7_M, flange_frame

    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    if robot == "wam7":
        rays = np.column_stack([np.ones(8), corners * max_com_m + np.array([0.0, 0.0, D7_M])])   # (8, 4)
    else:       # the flange box in the last link's frame (a rotation permutes the corners)
        origin, rot = flange_frame(robot)
        rays = np.column_stack([np.ones(8), origin + corners * max_com_m @ rot.T])
    return payload_map(robot)[:, :4] @ rays.T, rays.T


@lru_cache(maxsize=4)
def _base_map(robot: str = "wam7") -> np.ndarray:
    """(nb, 11 n) the base map restricted to the rigid body: ``delta_beta = K delta_pi`` (links and armature;
    77 columns on the wam7)."""
    from wamctl.analysis.identification.base import base_parameters

    base = base_parameters(robot)
    n_rigid = 11 * base.n_joints
    return base.matrix[base.independent < n_rigid][:, :n_rigid]


def plausible_link_map(links=None, payload=None, robot: str | None = None) -> np.ndarray:
    """(nb, 77) change of the rigid-body base parameters when one physical parameter of the declared arm moves
    to the bound of its declared accuracy (``LINK_PRIOR_SHARE``, ``LINK_PRIOR_COM_M``; coefficients in [-1, 1]):
    per link its mass, the three coordinates of its centre of mass (DH frame; the share of its distance from the
    frame's origin plus the absolute allowance), the six entries of its inertia about the centre (the share of
    its largest diagonal entry); per joint its armature. Central differences through the rigid body: exact for the
    masses, inertias and armatures; for a centre of mass the inertia about the joint grows with its square, which
    the map leaves out (at the bound about half the shift over the centre's distance). ``links``:
    :class:`~wamctl.model.params.LinkParameters` (None: the datasheet); ``payload``: a declared
    :class:`~wamctl.model.dynamics.Payload`, kept as it is."""
    from wamctl.model.params import LinkParameters

    return _plausible_link_map(links if links is not None else LinkParameters.datasheet(robot or "wam7"), payload)


@lru_cache(maxsize=4)
def _plausible_link_map(links, payload) -> np.ndarray:
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.params import LinkParameters

    robot = links.robot
    K = _base_map(robot)
    arrays = [np.array(links.mass_kg), np.array(links.com_m), np.array(links.inertia_kg_m2),
              np.array(links.armature_kg_m2)]

    def standard(a: list) -> np.ndarray:
        dyn = WamDynamics(payload, LinkParameters(*a, robot=robot))
        return np.concatenate([dyn.standard_parameters(), dyn.armature_kg_m2])

    s = LINK_PRIOR_SHARE
    out = []
    for i in range(len(arrays[0])):
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
