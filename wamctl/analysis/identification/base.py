"""Base parameters of the WAM: the standard regressor, the numerical base, and what given data determine.

Stable API (other modules build on it, among them the diagnosis' ``link_parameters`` candidate; these names
and their meanings do not change)::

    STANDARD_NAMES, N_STANDARD             the 105 standard parameters, in the regressor's column order
    standard_regressor(dyn, q, qd, qdd)    (n, 7, 105) Y with tau = Y @ pi (rigid body + armature + friction)
    standard_vector(dyn, friction)         (105,) pi of a WamDynamics and a FrictionModel
    split_standard(pi)                     pi -> (70 inertial, (7,) armature, FrictionModel)
    base_parameters()                      BaseParameters: the combinations any data could determine (cached)
    identifiability(Yb, base)              Identifiability: rank, condition, what these data leave undetermined

Any arm of :mod:`wamctl.model.robots` (issue 27): an arm of ``n`` joints has ``15 n`` standard parameters
(``10 n`` inertial, ``n`` armature, ``4 n`` friction), in the order below with ``n`` for 7; the module's constants
(``N7``, ``N_STANDARD``, ``STANDARD_NAMES``, ...) are the wam7's, :func:`standard_names`, :func:`layout` and
``base_parameters(robot)`` any arm's. A function given standard parameters or a model infers the arm from their
size (``15 n``) or the model's ``robot``.

Standard parameters (column order of :func:`standard_regressor`)
-----------------------------------------------------------------
* ``0..69``: link ``i`` (1..7) at ``10 (i-1) + k``: ``m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz``, pinocchio's
  standard inertial parameters (first moment and inertia about the *joint* frame origin, joint-frame axes; see
  :mod:`wamctl.model.dynamics`). A payload is part of link 7.
* ``70..76``: armature ``Ia1..Ia7`` (reflected rotor inertia, kg m^2): the column is ``qdd_j`` on row ``j``.
* ``77..104``: classic per-direction friction of joint ``j`` at ``77 + 4 (j-1) + k``: ``fc_pos, fc_neg, b_pos,
  b_neg`` (magnitudes, thesis eq. 4.1), the columns of :func:`wamctl.model.friction.classic_friction_columns`
  on row ``j``.

Units: kg, kg m, kg m^2, N m, N m s/rad. Torque rows are in N m, sign convention of the logged torque (the
motor's: ``tau = B qdd + C qd + g + F(qd)``).

Base parameters
---------------
The regressor depends only on the kinematics (never on the link parameters), so which combinations of the
standard parameters move the torque at all is a property of the arm. :func:`base_parameters` finds them
numerically (Gautier's method): the standard regressor is stacked at ``N_STATES`` random states (positions
uniform within the joint limits, velocities and accelerations Gaussian; fixed seed), a QR decomposition with
column pivoting ``W P = Q R`` gives the numerical rank ``r`` (``|R_kk| > RANK_TOL |R_00|``), the ``r`` pivot
columns are the base's independent standard parameters and the others are regrouped into them:
``beta = pi_I + C pi_D`` with ``C = R_11^-1 R_12`` (entries below ``1e-10`` are exact zeros). Then
``Y @ pi == Y[:, I] @ beta`` for every state and every ``pi`` (a test checks it on other states). The base is
computed once per process and is deterministic (fixed seed, fixed number of states).

What given data determine
-------------------------
:func:`identifiability` takes a base regressor built from data (rows: the samples the estimator uses, weighted
as it weights them) and answers: its numerical rank, its condition number after column equilibration (each
column scaled to unit norm, so the number does not depend on units), and which base parameters lie in its null
space (undetermined: the data cannot tell them apart from a combination of others, e.g. every parameter that
only acts on a joint that never moved). Those are named; an estimator must not print a number for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np
import scipy.linalg

from wamctl.model import params as P
from wamctl.model.friction import FrictionModel, classic_friction_columns

N7 = P.N_JOINTS
LINK_PARAMETER_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
FRICTION_PARAMETER_NAMES = ("fc_pos", "fc_neg", "b_pos", "b_neg")
N_INERTIAL = 10 * N7
ARMATURE_SLICE = slice(N_INERTIAL, N_INERTIAL + N7)
FRICTION_SLICE = slice(N_INERTIAL + N7, N_INERTIAL + N7 + 4 * N7)
N_STANDARD = N_INERTIAL + N7 + 4 * N7
STANDARD_NAMES: tuple[str, ...] = (
    tuple(f"{p}{i + 1}" for i in range(N7) for p in LINK_PARAMETER_NAMES)
    + tuple(f"Ia{j + 1}" for j in range(N7))
    + tuple(f"{p}{j + 1}" for j in range(N7) for p in FRICTION_PARAMETER_NAMES))
STANDARD_UNITS: tuple[str, ...] = (
    tuple(u for _ in range(N7) for u in ("kg", "kg m", "kg m", "kg m") + ("kg m^2",) * 6)
    + ("kg m^2",) * N7 + tuple(u for _ in range(N7) for u in ("N m", "N m", "N m s/rad", "N m s/rad")))



def layout(n: int) -> tuple[int, slice, slice, int]:
    """``(n_inertial, armature slice, friction slice, n_standard)`` of an arm of ``n`` joints."""
    ni = 10 * n
    return ni, slice(ni, ni + n), slice(ni + n, ni + 5 * n), 15 * n


@cache
def standard_names(n: int = N7) -> tuple[str, ...]:
    """The ``15 n`` standard parameter names of an arm of ``n`` joints (:data:`STANDARD_NAMES` for seven)."""
    return (tuple(f"{p}{i + 1}" for i in range(n) for p in LINK_PARAMETER_NAMES)
            + tuple(f"Ia{j + 1}" for j in range(n))
            + tuple(f"{p}{j + 1}" for j in range(n) for p in FRICTION_PARAMETER_NAMES))


@cache
def standard_units(n: int = N7) -> tuple[str, ...]:
    """Units of :func:`standard_names`."""
    return (tuple(u for _ in range(n) for u in ("kg", "kg m", "kg m", "kg m") + ("kg m^2",) * 6)
            + ("kg m^2",) * n + tuple(u for _ in range(n) for u in ("N m", "N m", "N m s/rad", "N m s/rad")))


def n_joints_of(pi_or_width) -> int:
    """Joints of the arm whose standard parameters are ``pi`` (its last axis ``15 n``) or of a width ``15 n``."""
    width = int(pi_or_width) if np.ndim(pi_or_width) == 0 else np.shape(pi_or_width)[-1]
    if width % 15:
        raise ValueError(f"{width} standard parameters: not 15 per joint")
    return width // 15


N_STATES = 120          # random states stacked for the numerical base (840 rows for 105 columns)
SEED = 20240518
RANK_TOL = 1e-9         # relative to the largest |R_kk|: the gap in |diag R| spans ten orders of magnitude
COUPLING_ZERO = 1e-10
ZERO_COLUMN = 1e-10     # a data column this small relative to the largest is zero (columns differ by < 1e6)


# ----------------------------------------------------------------------------------------------- standard
def standard_regressor(dyn, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """The standard regressor along a trajectory.

    Parameters
    ----------
    dyn : :class:`wamctl.model.dynamics.WamDynamics` (only its kinematics matter).
    q, qd, qdd : (n, 7) rad, rad/s, rad/s^2.

    Returns
    -------
    (n, 7, 105): ``tau[k] = Y[k] @ pi`` with ``pi`` in the order of :data:`STANDARD_NAMES`.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(x, float)) for x in (q, qd, qdd))
    n = len(q)
    nj = int(getattr(dyn, "n_joints", N7))
    ni, _, fs, ns = layout(nj)
    Y = np.zeros((n, nj, ns))
    Y[:, :, :ni] = dyn.torque_regressor(q, qd, qdd)
    j = np.arange(nj)
    Y[:, j, ni + j] = qdd
    for jj in range(nj):
        c0 = fs.start + 4 * jj
        Y[:, jj, c0:c0 + 4] = classic_friction_columns(qd[:, jj])
    return Y


def standard_vector(dyn, friction: FrictionModel | None = None) -> np.ndarray:
    """(105,) standard parameters of a rigid body (a WamDynamics: its links, armature and payload) and a
    friction model (its classic part; zero friction if None)."""
    nj = int(getattr(dyn, "n_joints", N7))
    f = friction if friction is not None else FrictionModel.zero(nj)
    if f.n_joints != nj:
        raise ValueError(f"friction of {f.n_joints} joints for an arm of {nj}")
    fr = np.column_stack([f.fc_pos_Nm, f.fc_neg_Nm, f.viscous_pos_Nm_s_rad, f.viscous_neg_Nm_s_rad]).reshape(-1)
    return np.concatenate([dyn.standard_parameters(), dyn.armature_kg_m2, fr])


def split_standard(pi: np.ndarray) -> tuple[np.ndarray, np.ndarray, FrictionModel]:
    """``pi`` (105,) -> ((70,) inertial parameters, (7,) armature, the classic :class:`FrictionModel`)."""
    pi = np.asarray(pi, float)
    n = n_joints_of(pi)
    ni, arm, fs, _ = layout(n)
    fr = pi[fs].reshape(n, 4)
    return pi[:ni].copy(), pi[arm].copy(), FrictionModel(fr[:, 0], fr[:, 1], fr[:, 2], fr[:, 3])


def random_states(n: int, rng: np.random.Generator, robot=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random states of ``robot`` (default the wam7): positions uniform within the joint limits, velocities
    N(0, 1) rad/s and accelerations N(0, 4) rad/s^2 (never exactly zero, so every friction column is excited)."""
    from wamctl.model.robots import get_robot

    r = get_robot(robot)
    nj = r.n_joints
    q = rng.uniform(r.q_min_rad, r.q_max_rad, size=(n, nj))
    return q, rng.normal(0.0, 1.0, (n, nj)), rng.normal(0.0, 2.0, (n, nj))


# ----------------------------------------------------------------------------------------------- base
@dataclass(frozen=True)
class BaseParameters:
    """The numerical base of the WAM's standard parameters (see the module doc).

    Attributes
    ----------
    independent : (nb,) indices into the standard parameters, ascending: the base's columns of the regressor.
    dependent : (105 - nb,) the standard parameters regrouped into them.
    coupling : (nb, 105 - nb) ``C``: ``beta = pi[independent] + C @ pi[dependent]``.
    names : (nb,) the independent parameter's name, with ``'`` appended when others are regrouped into it.
    n_joints : the arm's joints (``15 n_joints`` standard parameters; 7: the wam7).
    robot : the arm's name.
    """

    independent: np.ndarray
    dependent: np.ndarray
    coupling: np.ndarray
    names: tuple[str, ...] = field(default=())
    n_joints: int = N7
    robot: str = "wam7"

    @property
    def n_standard(self) -> int:
        return 15 * self.n_joints

    @property
    def standard_names(self) -> tuple[str, ...]:
        return standard_names(self.n_joints)

    @property
    def n_base(self) -> int:
        return len(self.independent)

    @property
    def matrix(self) -> np.ndarray:
        """(nb, 105) ``K`` with ``beta = K @ pi``."""
        K = np.zeros((self.n_base, self.n_standard))
        K[np.arange(self.n_base), self.independent] = 1.0
        K[:, self.dependent] = self.coupling
        return K

    @property
    def units(self) -> tuple[str, ...]:
        units = standard_units(self.n_joints)
        return tuple(units[i] for i in self.independent)

    def of(self, pi: np.ndarray) -> np.ndarray:
        """Base parameters ``beta`` (nb,) or (m, nb) of standard parameters ``pi`` (105,) or (m, 105)."""
        pi = np.asarray(pi, float)
        return pi[..., self.independent] + pi[..., self.dependent] @ self.coupling.T

    def regressor(self, Y: np.ndarray) -> np.ndarray:
        """The base regressor: the independent columns of a standard regressor (..., 105) -> (..., nb)."""
        return Y[..., self.independent]

    def expression(self, k: int, digits: int = 4) -> str:
        """Base parameter ``k`` as a combination of standard parameters, e.g. ``Izz1 + Ia1 + 0.3025 m3``."""
        names = self.standard_names
        terms = [names[self.independent[k]]]
        for c, d in zip(self.coupling[k], self.dependent):
            if c != 0.0:
                mag = abs(c)
                coef = "" if np.isclose(mag, 1.0) else f"{mag:.{digits}g} "
                terms.append(f"{'-' if c < 0 else '+'} {coef}{names[d]}")
        return " ".join(terms)

    def index(self, name: str) -> int:
        """Position of a base parameter by its name (with or without the ``'``)."""
        for k, n in enumerate(self.names):
            if n == name or n.rstrip("'") == name:
                return k
        raise KeyError(name)

    def to_dict(self) -> dict:
        return {"n_base": self.n_base, "n_standard": self.n_standard, "robot": self.robot,
                "parameters": [{"name": self.names[k], "unit": self.units[k], "expression": self.expression(k)}
                               for k in range(self.n_base)]}


def base_from_regressor(W: np.ndarray, rank_tol: float = RANK_TOL, robot: str | None = None) -> BaseParameters:
    """The numerical base of a stacked standard regressor ``W`` (m, 15 n) by QR with column pivoting (``robot``:
    the arm's name, default the wam7)."""
    _, R, piv = scipy.linalg.qr(W, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > rank_tol * d[0]))
    coupling = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])
    coupling[np.abs(coupling) < COUPLING_ZERO] = 0.0
    order = np.argsort(piv[:r])
    independent = piv[:r][order]
    coupling = coupling[order]
    dep_order = np.argsort(piv[r:])
    dependent, coupling = piv[r:][dep_order], coupling[:, dep_order]
    nj = n_joints_of(W)
    all_names = standard_names(nj)
    names = tuple(all_names[i] + ("'" if coupling[k].any() else "") for k, i in enumerate(independent))
    return BaseParameters(independent, dependent, coupling, names, nj, robot or "wam7")


def base_parameters(robot=None) -> BaseParameters:
    """An arm's base parameters (structural, cached per arm; ``robot`` a name or :class:`~wamctl.model.robots.
    Robot`, default the wam7): see the module doc."""
    from wamctl.model.robots import get_robot

    return _base_parameters(get_robot(robot).name)


@cache
def _base_parameters(robot: str) -> BaseParameters:
    from wamctl.model.dynamics import WamDynamics

    dyn = WamDynamics(robot=robot)
    q, qd, qdd = random_states(N_STATES, np.random.default_rng(SEED), robot)
    W = standard_regressor(dyn, q, qd, qdd)
    return base_from_regressor(W.reshape(-1, W.shape[-1]), robot=robot)


# ----------------------------------------------------------------------------------------------- data
@dataclass
class Identifiability:
    """What a base regressor built from data determines.

    Attributes
    ----------
    n_base : base parameters in the model.
    rank : numerical rank of the column-equilibrated data regressor (tolerance ``rank_tol`` on the singular
        values relative to the largest).
    condition_number : of the column-equilibrated regressor, over the whole base (``inf`` if rank deficient).
    condition_number_identified : over the determined subspace (largest / smallest singular value kept).
    singular_values : (nb,) of the column-equilibrated regressor, descending.
    identified : (nb,) bool, the base parameters these data determine (orthogonal to the null space).
    null_share : (nb,) share of each base parameter in the null space (0: determined, 1: untouched by data).
    null_directions : combinations the data cannot see, each ``{name: coefficient}`` in equilibrated units
        (largest first), at most ``MAX_DIRECTIONS`` of them.
    names : (nb,) base parameter names.
    """

    n_base: int
    rank: int
    condition_number: float
    condition_number_identified: float
    singular_values: np.ndarray
    identified: np.ndarray
    null_share: np.ndarray
    null_directions: list[dict[str, float]]
    names: tuple[str, ...]

    MAX_DIRECTIONS = 20

    @property
    def full_rank(self) -> bool:
        return self.rank == self.n_base

    @property
    def undetermined(self) -> list[str]:
        """Names of the base parameters these data cannot determine."""
        return [n for n, ok in zip(self.names, self.identified) if not ok]

    def statement(self) -> str:
        """One paragraph a report can print."""
        s = (f"rank {self.rank} of {self.n_base} base parameters; condition number (column-equilibrated) "
             f"{self.condition_number:.4g}")
        if not self.full_rank:
            s += (f" (over the {self.rank} determined directions: {self.condition_number_identified:.4g}); "
                  f"not determined by these data ({len(self.undetermined)}): {', '.join(self.undetermined)}")
        return s

    def to_dict(self) -> dict:
        return {"n_base": self.n_base, "rank": self.rank, "condition_number": float(self.condition_number),
                "condition_number_identified": float(self.condition_number_identified),
                "undetermined": self.undetermined, "null_directions": self.null_directions}


def identifiability(Yb: np.ndarray, base: BaseParameters | None = None, rank_tol: float = 1e-8,
                    share_tol: float = 1e-6) -> Identifiability:
    """Rank, condition number and undetermined base parameters of a data base regressor.

    Parameters
    ----------
    Yb : (m, nb) base regressor rows (weighted as the estimator weights them; any row order).
    base : the base the columns belong to (default :func:`base_parameters`), for the names.
    rank_tol : singular values below ``rank_tol`` times the largest count as zero.
    share_tol : a base parameter whose share in the null space exceeds this is undetermined.
    """
    base = base if base is not None else base_parameters()
    Yb = np.asarray(Yb, float)
    nb = Yb.shape[1]
    norms = np.linalg.norm(Yb, axis=0)
    zero = norms <= ZERO_COLUMN * (norms.max() if norms.size else 0.0)   # rounding noise, e.g. cos(pi/2)
    Yb = np.where(zero, 0.0, Yb)
    scale = np.where(zero, 1.0, norms)
    s, Vt = _svd_small(Yb / scale)
    s_max = s[0] if len(s) and s[0] > 0 else 1.0
    keep = s > rank_tol * s_max
    rank = int(keep.sum())
    null = Vt[rank:].T                      # (nb, nb - rank) orthonormal basis of the null space
    share = np.sum(null ** 2, axis=1) if null.size else np.zeros(nb)
    share[zero] = 1.0
    identified = share <= share_tol
    cond = float(s_max / s[-1]) if rank == nb else float("inf")
    cond_id = float(s_max / s[rank - 1]) if rank else float("inf")
    directions = []
    for v in null.T[: Identifiability.MAX_DIRECTIONS]:
        order = np.argsort(-np.abs(v))
        v = v / v[order[0]]
        directions.append({base.names[k]: float(round(v[k], 4)) for k in order if abs(v[k]) > 0.05})
    return Identifiability(nb, rank, cond, cond_id, s, identified, share, directions, base.names)


def _svd_small(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors of a tall matrix (m >> n) through a QR first (cheaper)."""
    if A.shape[0] > 2 * A.shape[1]:
        A = np.linalg.qr(A, mode="r")
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    if len(s) < A.shape[1]:
        s = np.concatenate([s, np.zeros(A.shape[1] - len(s))])
    return s, Vt
