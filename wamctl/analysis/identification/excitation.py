"""Exciting trajectories for the identification: finite Fourier series designed under the arm's limits.

Trajectory (Swevers et al., "Optimal robot excitation and identification", IEEE TRA 1997), per joint ``j``,
with base frequency ``w = 2 pi / period`` and ``L`` harmonics:

    q_j(t) = q0_j + sum_l  a_jl / (w l) sin(w l t) - b_jl / (w l) (cos(w l t) - 1)
    qd_j   =        sum_l  a_jl cos(w l t) + b_jl sin(w l t)                       (a, b in rad/s)

Every period starts and ends at ``q0`` at rest: ``sum_l a_jl = 0`` (no velocity) and ``sum_l l b_jl = 0`` (no
acceleration) are built in by solving for ``a_j1`` and ``b_j1``, so the free coefficients are ``a_j2..a_jL``,
``b_j2..b_jL`` of the moving joints (the others hold ``q0``). Periodic data can be averaged and the run can be
repeated.

Design: minimise a criterion of the base regressor over one period (sampled at ``n_grid`` points; rows of the
moving joints only, the held joints' rows carry unknown static friction), subject to the limits over the
whole period: joint range (with a margin), speed, acceleration, the torque the declared model needs (rigid
body + friction) against the torque limits with a margin, and the wrist's Cartesian speed (the WAM's safety
module faults at 1 m/s). Criteria: ``d_optimal`` (maximise ``log det(Yb^T Yb)``: independent of the
parameters' units, smooth) or ``condition`` (minimise the condition number of the column-equilibrated base
regressor). scipy's SLSQP from several random feasible starts; the best design is then checked at the control
rate and scaled back toward q0 if a limit is crossed between grid points. The base columns used are those the
moving joints can determine (:func:`target_columns`).

The world around the arm (:class:`World`, optional): self-collision between the arm's capsules, a table plane
and a workspace box (:mod:`wamctl.model.collision`), each kept ``clearance_m`` away on the grid as constraints of
SLSQP, then over the whole period at the control rate with the sampling's own bound subtracted
(:func:`world_clearance`: between two samples nothing moves farther than ``dt x sum_j |qd_j| lever_j``). A
candidate SLSQP leaves infeasible is repaired (its coefficients scaled back toward ``q0`` until every limit
holds) rather than dropped; the chosen design is scaled back the same way if the dense check finds a crossing
between grid points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from wamctl.analysis.blas import single_threaded_blas
from wamctl.analysis.identification.base import (
    BaseParameters,
    base_parameters,
    identifiability,
    standard_regressor,
    standard_vector,
)
from wamctl.model import collision as C
from wamctl.model import params as P

log = logging.getLogger(__name__)
N7 = P.N_JOINTS


# ----------------------------------------------------------------------------------------------- trajectory
@dataclass
class FourierTrajectory:
    """A finite Fourier series per joint, at rest at ``q0`` at the start and end of every period.

    Attributes
    ----------
    q0_rad : (n,) start and end of each period (n: the arm's joints, 7 on the wam7, 4 on the wam4).
    period_s : base period.
    a, b : (n, L) coefficients, rad/s (rows of held joints are zero).
    """

    q0_rad: np.ndarray
    period_s: float
    a: np.ndarray
    b: np.ndarray

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def moving(self) -> list[int]:
        """0-based joints that move."""
        return [j for j in range(len(self.a)) if np.any(self.a[j]) or np.any(self.b[j])]

    @classmethod
    def from_free(cls, q0_rad, period_s: float, joints: list[int], x: np.ndarray, harmonics: int):
        """The trajectory of free coefficients ``x`` ((len(joints), 2 (L-1)) flattened: ``a_2..a_L, b_2..b_L``
        per joint) for the 0-based ``joints``."""
        L = harmonics
        n = len(np.atleast_1d(q0_rad))
        a, b = np.zeros((n, L)), np.zeros((n, L))
        x = np.asarray(x, float).reshape(len(joints), 2 * (L - 1))
        ls = np.arange(2, L + 1)
        for row, j in zip(x, joints):
            a[j, 1:], b[j, 1:] = row[: L - 1], row[L - 1:]
            a[j, 0] = -a[j, 1:].sum()
            b[j, 0] = -(ls * b[j, 1:]).sum()
        return cls(np.asarray(q0_rad, float).copy(), float(period_s), a, b)

    def evaluate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``q, qd, qdd`` (n, 7) at times ``t_s`` (n,) (periodic)."""
        w = 2 * np.pi / self.period_s
        ls = np.arange(1, self.harmonics + 1)
        ph = w * np.outer(np.asarray(t_s, float), ls)          # (n, L)
        s, c = np.sin(ph), np.cos(ph)
        wl = w * ls
        q = self.q0_rad + s @ (self.a / wl).T - (c - 1.0) @ (self.b / wl).T
        qd = c @ self.a.T + s @ self.b.T
        qdd = -s @ (self.a * wl).T + c @ (self.b * wl).T
        return q, qd, qdd

    def to_dict(self) -> dict:
        return {"period_s": self.period_s, "harmonics": self.harmonics,
                "coefficients": {j + 1: {"a_rad_s": [float(v) for v in self.a[j]],
                                         "b_rad_s": [float(v) for v in self.b[j]]} for j in self.moving}}


# ----------------------------------------------------------------------------------------------- limits
@dataclass
class ExcitationLimits:
    """What the trajectory must respect everywhere (arrays (n,), the arm's joints). ``torque_fraction``: share of
    the torque limits the declared model may need (``torque_limit_Nm``, default the wam7's); ``cartesian_speed_m_s``:
    largest speed of the flange (link-7 origin on the wam7, the tool plate on the wam4). :meth:`of_robot`: an arm's
    limits."""

    q_min_rad: np.ndarray
    q_max_rad: np.ndarray
    qd_max_rad_s: np.ndarray
    qdd_max_rad_s2: np.ndarray
    torque_fraction: float = 0.7
    cartesian_speed_m_s: float = 0.8
    world: World | None = None
    torque_limit_Nm: np.ndarray | None = None

    @property
    def tau_max_Nm(self) -> np.ndarray:
        return self.torque_fraction * (P.TAU_MAX_NM if self.torque_limit_Nm is None else self.torque_limit_Nm)

    @classmethod
    def of_robot(cls, robot, qdd_max_rad_s2, **kw) -> ExcitationLimits:
        """The limits of a registered arm (:mod:`wamctl.model.robots`): its joint range, speed and torque limits,
        with the given accelerations (and ``torque_fraction``, ``cartesian_speed_m_s``, ``world``)."""
        from wamctl.model.robots import get_robot

        r = get_robot(robot)
        return cls(r.q_min_rad.copy(), r.q_max_rad.copy(), r.qd_max_rad_s.copy(),
                   np.broadcast_to(np.asarray(qdd_max_rad_s2, float), (r.n_joints,)).copy(),
                   torque_limit_Nm=r.tau_max_Nm.copy(), **kw)

    KINDS = ("position", "speed", "acceleration", "torque", "cartesian_speed")


@dataclass
class World:
    """The arm's surroundings the trajectory keeps ``clearance_m`` from: its own links (``self_collision``), a
    table plane at ``table_z_m`` (frame 0: the shoulder at 0, z up), a workspace box (``box_min_m``,
    ``box_max_m``, (3,) each) the arm's moving links stay inside. ``geometry``: the capsules."""

    geometry: C.ArmGeometry
    self_collision: bool = True
    table_z_m: float | None = None
    box_min_m: np.ndarray | None = None
    box_max_m: np.ndarray | None = None
    clearance_m: float = 0.02

    @property
    def active(self) -> bool:
        return self.self_collision or self.table_z_m is not None or self.box_min_m is not None

    def distances(self, frames: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
        return C.distances(frames, self.geometry, self.table_z_m, self.box_min_m, self.box_max_m,
                           self.self_collision)

    def margins(self, frames: np.ndarray) -> np.ndarray:
        """``(distance - clearance) / 0.1 m`` of every kind, pair or link and sample, flattened (>= 0 where it
        holds; scaled to the order of the other margins)."""
        dist = self.distances(frames)
        parts = [(d - self.clearance_m) / 0.1 for per in dist.values() for d in per.values()]
        return np.concatenate(parts) if parts else np.zeros(0)


@dataclass
class WorldClearance:
    """The smallest distances over one period sampled every ``dt_s``: per kind (``self``, ``table``, ``box``) a
    :class:`wamctl.model.collision.Clearance` (sampled); ``sampling_bound_m``: how much smaller the distance
    can be between samples; ``clearance_m``: what the world asks."""

    smallest: dict
    sampling_bound_m: float
    dt_s: float
    clearance_m: float

    def guaranteed_m(self, kind: str) -> float:
        """The distance the whole period keeps at least (sampled minus the sampling's bound)."""
        return self.smallest[kind].distance_m - self.sampling_bound_m

    @property
    def worst(self):
        """The :class:`Clearance` whose guaranteed distance is smallest, or None."""
        return min(self.smallest.values(), key=lambda c: c.distance_m, default=None)

    @property
    def respected(self) -> bool:
        w = self.worst
        return w is None or w.distance_m - self.sampling_bound_m >= self.clearance_m - 1e-12

    def statement(self) -> str:
        w = self.worst
        if w is None:
            return "no world (self-collision, table, box) checked"
        return (f"smallest distance at least {w.distance_m - self.sampling_bound_m:.3f} m ({w.kind}: {w.between}; "
                f"{w.distance_m:.3f} m sampled), clearance {self.clearance_m:g} m")

    def to_dict(self) -> dict:
        return {"clearance_m": self.clearance_m, "sampling_dt_s": self.dt_s,
                "sampling_bound_m": self.sampling_bound_m,
                "smallest": {k: {**c.to_dict(), "guaranteed_m": self.guaranteed_m(k)}
                             for k, c in self.smallest.items()},
                "respected": self.respected}


def world_clearance(traj: FourierTrajectory, world: World, dynamics, limits: ExcitationLimits | None = None,
                    rate_hz: float = P.CONTROL_RATE_HZ) -> WorldClearance:
    """The world's smallest distances over one period sampled at ``rate_hz``, with the bound of what the
    sampling can miss: ``dt x sum_j (max |qd_j| + qdd_max_j dt / 2) lever_j`` (the speed between samples is at
    most the sampled one plus the acceleration limit over half a step; the nearest sample is at most ``dt / 2``
    away and two moving links each move that far)."""
    dt = 1.0 / rate_hz
    t = np.arange(int(round(traj.period_s * rate_hz)) + 1) * dt
    q, qd, qdd = traj.evaluate(t)
    acc = np.abs(qdd).max(axis=0) if limits is None else np.maximum(limits.qdd_max_rad_s2, np.abs(qdd).max(axis=0))
    speed = np.abs(qd).max(axis=0) + acc * dt / 2
    bound = float(dt * speed @ world.geometry.levers_m())
    return WorldClearance(C.smallest(world.distances(dynamics.joint_frames(q))), bound, dt, world.clearance_m)


@dataclass
class LimitUse:
    """How close a trajectory comes to each limit: ``used[kind]`` (7,) (or a float for the Cartesian speed),
    the largest share of the limit reached (<= 1 when respected); ``peak[kind]`` the value at that point."""

    used: dict = field(default_factory=dict)
    peak: dict = field(default_factory=dict)

    @property
    def worst(self) -> tuple[str, int | None, float]:
        """(limit kind, 1-based joint or None, share used) of the limit closest to being crossed."""
        best = ("", None, -np.inf)
        for kind, u in self.used.items():
            arr = np.atleast_1d(u)
            k = int(np.argmax(arr))
            if arr[k] > best[2]:
                best = (kind, k + 1 if np.ndim(u) else None, float(arr[k]))
        return best

    @property
    def respected(self) -> bool:
        return self.worst[2] <= 1.0 + 1e-9


def limit_use(q, qd, qdd, tau_Nm, cart_speed_m_s, limits: ExcitationLimits) -> LimitUse:
    """Shares of each limit used by a sampled trajectory ((n, 7) arrays, (n,) Cartesian speed)."""
    mid = 0.5 * (limits.q_min_rad + limits.q_max_rad)
    half = 0.5 * (limits.q_max_rad - limits.q_min_rad)
    out = LimitUse()
    dev = np.abs(q - mid)
    out.used["position"] = dev.max(axis=0) / half
    out.peak["position"] = q[np.argmax(dev, axis=0), np.arange(q.shape[1])]
    for kind, x, lim in (("speed", qd, limits.qd_max_rad_s), ("acceleration", qdd, limits.qdd_max_rad_s2),
                         ("torque", tau_Nm, limits.tau_max_Nm)):
        peak = np.abs(x).max(axis=0)
        out.used[kind], out.peak[kind] = peak / lim, peak
    out.peak["cartesian_speed"] = float(np.max(cart_speed_m_s)) if len(cart_speed_m_s) else 0.0
    out.used["cartesian_speed"] = out.peak["cartesian_speed"] / limits.cartesian_speed_m_s
    return out


# ----------------------------------------------------------------------------------------------- criterion
def target_columns(joints: list[int], base: BaseParameters | None = None, seed: int = 0) -> np.ndarray:
    """(nb,) bool: the base parameters that data moving only the 0-based ``joints`` (each through rich
    random motion, the others held, rows of the moving joints only) can determine (the arm of ``base``, default
    the wam7)."""
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.robots import get_robot

    base = base if base is not None else base_parameters()
    r = get_robot(base.robot)
    rng = np.random.default_rng(seed)
    n, nj = 150, r.n_joints
    q = np.tile(0.5 * (r.q_min_rad + r.q_max_rad), (n, 1))
    qd, qdd = np.zeros((n, nj)), np.zeros((n, nj))
    q[:, joints] = rng.uniform(r.q_min_rad[joints], r.q_max_rad[joints], (n, len(joints)))
    qd[:, joints] = rng.normal(0, 1, (n, len(joints)))
    qdd[:, joints] = rng.normal(0, 2, (n, len(joints)))
    Y = standard_regressor(WamDynamics(robot=r), q, qd, qdd)[:, joints, :].reshape(-1, base.n_standard)
    return identifiability(base.regressor(Y), base).identified


class Criterion:
    """The design's objective and limit margins for one set of moving joints (callable on free
    coefficients). ``dynamics`` (WamDynamics) and ``friction`` (FrictionModel) are the declared model the
    torque limit is checked with."""

    def __init__(self, q0_rad, period_s: float, joints: list[int], harmonics: int, limits: ExcitationLimits,
                 dynamics, friction, kind: str = "d_optimal", n_grid: int = 60):
        if kind not in CRITERIA:
            raise ValueError(f"criterion: {kind!r}; choose {' or '.join(CRITERIA)}")
        self.q0, self.period_s, self.joints, self.L = np.asarray(q0_rad, float), period_s, joints, harmonics
        self.limits, self.dyn, self.kind = limits, dynamics, kind
        self.base = base_parameters(getattr(dynamics, "robot", None))
        self.cols = self.base.independent[target_columns(joints, self.base)]
        self.pi_nominal = standard_vector(dynamics, friction)
        self.t_grid = (np.arange(n_grid) + 0.5) * period_s / n_grid
        self.world = limits.world if limits.world is not None and limits.world.active else None
        self._mid = 0.5 * (limits.q_min_rad + limits.q_max_rad)[joints]
        self._half = 0.5 * (limits.q_max_rad - limits.q_min_rad)[joints]
        self._cache: tuple[bytes, tuple] | None = None

    @property
    def n_free(self) -> int:
        return len(self.joints) * 2 * (self.L - 1)

    def trajectory(self, x) -> FourierTrajectory:
        return FourierTrajectory.from_free(self.q0, self.period_s, self.joints, x, self.L)

    def _evaluate(self, x):
        """(eigenvalues of the column-equilibrated information matrix, per-point margins (n_grid, ...))."""
        key = np.asarray(x, float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        q, qd, qdd = self.trajectory(x).evaluate(self.t_grid)
        Y = standard_regressor(self.dyn, q, qd, qdd)
        tau = Y @ self.pi_nominal
        J = self.joints
        Yb = Y[:, J, :][:, :, self.cols].reshape(-1, len(self.cols))
        G = Yb.T @ Yb
        d = np.sqrt(np.maximum(np.diag(G), 1e-300))
        ev = np.linalg.eigvalsh(G / np.outer(d, d))
        lim = self.limits
        margins = np.concatenate([
            (1.0 - np.abs(q[:, J] - self._mid) / self._half).ravel(),
            (1.0 - np.abs(qd[:, J]) / lim.qd_max_rad_s[J]).ravel(),
            (1.0 - np.abs(qdd[:, J]) / lim.qdd_max_rad_s2[J]).ravel(),
            (1.0 - np.abs(tau[:, J]) / lim.tau_max_Nm[J]).ravel(),
            1.0 - self.dyn.link7_speed_m_s(q, qd) / lim.cartesian_speed_m_s,
            self.world.margins(self.dyn.joint_frames(q)) if self.world is not None else np.zeros(0)])
        self._cache = (key, (ev, margins))
        return ev, margins

    def objective(self, x) -> float:
        """``-log det`` of the column-equilibrated information matrix ``Yb^T Yb`` per parameter (d_optimal;
        the equilibration makes it independent of the parameters' units), or the log of the condition number
        of the column-equilibrated base regressor (condition)."""
        ev, _ = self._evaluate(x)
        if ev[0] <= 1e-14 * ev[-1]:
            return 1e3
        if self.kind == "d_optimal":
            return float(-np.sum(np.log(ev)) / len(ev))
        return float(0.5 * np.log(ev[-1] / ev[0]))

    def condition_number(self, x) -> float:
        """Condition number of the column-equilibrated base regressor over one period."""
        ev, _ = self._evaluate(x)
        return float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")

    def margins(self, x) -> np.ndarray:
        """``1 - share of the limit used`` at every grid point, moving joint and limit (>= 0 where it holds)."""
        return self._evaluate(x)[1]

    def worst(self, x) -> tuple[str, int | None, float]:
        """(limit kind, 1-based joint or None, share of the limit used) of the most used limit at ``x``."""
        m = self.margins(x)
        k = int(np.argmin(m))
        n, nj = len(self.t_grid), len(self.joints)
        kinds = ("position", "speed", "acceleration", "torque")
        block = k // (n * nj)
        if block >= len(kinds) and k < len(kinds) * n * nj + n:
            return "cartesian_speed", None, float(1.0 - m[k])
        if block >= len(kinds):
            return "world", None, float(1.0 - m[k])
        return kinds[block], self.joints[k % nj] + 1, float(1.0 - m[k])

    def joint_kinematic_scale(self, x: np.ndarray) -> np.ndarray:
        """``x`` with each joint's block scaled to use at most half of its own range, speed and acceleration
        (the joints' starts do not depend on each other; the torque and Cartesian limits then scale all)."""
        x = np.array(x, float).reshape(len(self.joints), -1)
        q, qd, qdd = self.trajectory(x.ravel()).evaluate(self.t_grid)
        lim = self.limits
        for r, j in enumerate(self.joints):
            used = max(np.abs(q[:, j] - self._mid[r]).max() / self._half[r] if self._half[r] > 0 else np.inf,
                       np.abs(qd[:, j]).max() / lim.qd_max_rad_s[j], np.abs(qdd[:, j]).max() / lim.qdd_max_rad_s2[j])
            x[r] *= 0.5 / used if used > 0 else 0.0
        return x.ravel()


CRITERIA = ("d_optimal", "condition")


@dataclass
class ExcitationDesign:
    """The designed trajectory and what it achieves (on the design grid)."""

    trajectory: FourierTrajectory
    criterion: str
    objective: float
    condition_number: float
    n_target: int
    starts: list[dict]
    clearance: WorldClearance | None = None
    scaled_back: float = 1.0


def design_excitation(q0_rad, joints: list[int], period_s: float, harmonics: int, limits: ExcitationLimits,
                      dynamics, friction, criterion: str = "d_optimal", starts: int = 3, max_iterations: int = 60,
                      seed: int = 0, n_grid: int = 60, progress=None) -> ExcitationDesign:
    """Design an exciting trajectory (see the module doc) for the 0-based moving ``joints``.

    ``progress(done, total, label)`` is called after each start. Raises ValueError when no feasible start is
    found (``q0`` outside the margins, or a torque limit already used up at ``q0``)."""
    if harmonics < 2:
        raise ValueError("harmonics: at least 2 (the first harmonic's coefficients keep the ends at rest)")
    crit = Criterion(q0_rad, period_s, joints, harmonics, limits, dynamics, friction, criterion, n_grid)
    rng = np.random.default_rng(seed)
    best, tried = None, []
    with single_threaded_blas():
        for s in range(starts):
            x0 = _feasible_start(crit, crit.joint_kinematic_scale(rng.normal(0.0, 1.0, crit.n_free)))
            if x0 is None:
                tried.append({"start": s + 1, "status": "no feasible start"})
                continue
            res = minimize(crit.objective, x0, method="SLSQP",
                           constraints=[{"type": "ineq", "fun": crit.margins}],
                           options={"maxiter": max_iterations, "ftol": 1e-7})
            x, scale = res.x, 1.0
            if crit.margins(x).min() < 0:   # repaired: scaled back toward q0 until every limit holds
                scale = _largest_scale(lambda c, end=res.x: crit.margins(c * end).min() >= 0)
                x = scale * res.x
                if crit.objective(x0) < crit.objective(x):
                    x, scale = x0, 0.0
            f = crit.objective(x)
            tried.append({"start": s + 1, "objective": f, "condition_number": crit.condition_number(x),
                          "iterations": int(res.nit), "message": str(res.message),
                          "repair": ("none" if scale == 1.0 else "SLSQP's end infeasible: its start kept"
                                     if scale == 0.0 else f"SLSQP's end infeasible: scaled back to {scale:.6f}")})
            if best is None or f < best[0]:
                best = (f, x)
            if progress:
                progress(s + 1, starts, f"excitation design: start {s + 1}/{starts}")
    if best is None:
        if crit.world is not None:
            q0_clear = world_clearance(crit.trajectory(np.zeros(crit.n_free)), crit.world, dynamics, limits)
            if not q0_clear.respected:
                w = q0_clear.worst
                raise ValueError(f"no feasible excitation: at q0 the {w.kind} distance {w.between} is "
                                 f"{w.distance_m:.3f} m, below the clearance {crit.world.clearance_m:g} m; choose "
                                 "another q0_rad or change world")
        kind, joint, share = crit.worst(1e-4 * crit.joint_kinematic_scale(np.ones(crit.n_free)))
        where = f"joint {joint} " if joint else ""
        raise ValueError(f"no feasible excitation: barely moving from q0, {where}{kind} is at {share:.0%} of its "
                         "limit (torque: gravity and Coulomb friction of the declared model against the torque "
                         "margin); choose another q0_rad or relax the limit")
    f, x = best
    clear, scale = None, 1.0
    if crit.world is not None:
        clear = world_clearance(crit.trajectory(x), crit.world, dynamics, limits)
        if not clear.respected:     # a crossing between grid points: scaled back toward q0 until clear
            traj, scale, clear = scaled_back_clear(crit.trajectory(x), crit.world, dynamics, limits)
            x = scale * x
            f = crit.objective(x)
            log.info("excitation: scaled back to %.3f to keep the world's clearance between grid points", scale)
    if not sampled_limit_use(crit.trajectory(x), limits, dynamics, friction).respected:
        # a limit crossed between grid points (at the control rate): scaled back toward q0 the same way
        c = _largest_scale(lambda v: sampled_limit_use(crit.trajectory(v * x), limits, dynamics,
                                                       friction).respected, steps=12)
        x, scale = c * x, scale * c
        f = crit.objective(x)
        if crit.world is not None:
            clear = world_clearance(crit.trajectory(x), crit.world, dynamics, limits)
        log.info("excitation: scaled back to %.3f to keep every limit between grid points", scale)
    return ExcitationDesign(crit.trajectory(x), criterion, f, crit.condition_number(x), int(len(crit.cols)), tried,
                            clear, scale)


def scaled_back_clear(traj: FourierTrajectory, world: World, dynamics, limits: ExcitationLimits | None = None,
                      steps: int = 12) -> tuple[FourierTrajectory, float, WorldClearance]:
    """The repair of a trajectory that comes closer to the world than its clearance: its coefficients scaled by
    the largest ``c`` in [0, 1] (bisection, ``steps`` halvings) that keeps the clearance over the whole period
    (``q0 + c (q(t) - q0)``: the same motion, smaller, toward q0). Returns (trajectory, c, its clearance);
    raises ValueError naming the obstacle when even q0 is too close."""
    def scaled(c):
        return FourierTrajectory(traj.q0_rad, traj.period_s, c * traj.a, c * traj.b)

    at_q0 = world_clearance(scaled(0.0), world, dynamics, limits)
    if not at_q0.respected:
        w = at_q0.worst
        raise ValueError(f"no feasible excitation: at q0 the {w.kind} distance {w.between} is {w.distance_m:.3f} "
                         f"m, below the clearance {world.clearance_m:g} m; choose another q0_rad or change world")
    c = _largest_scale(lambda v: world_clearance(scaled(v), world, dynamics, limits).respected, steps)
    return scaled(c), c, world_clearance(scaled(c), world, dynamics, limits)


def _largest_scale(feasible, steps: int = 25) -> float:
    """The largest ``c`` in [0, 1] with ``feasible(c)`` (bisection, feasible at 0 assumed), 0 if none."""
    if feasible(1.0):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if feasible(mid) else (lo, mid)
    return lo


def _feasible_start(crit: Criterion, direction: np.ndarray) -> np.ndarray | None:
    """The largest multiple of ``direction`` (bisection) within every limit, shrunk to 90 % of it."""
    if crit.margins(np.zeros_like(direction)).min() < 0:
        return None
    lo, hi = 0.0, 1.0
    while crit.margins(hi * direction).min() >= 0 and hi < 1e3:
        lo, hi = hi, 2 * hi
    for _ in range(25):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if crit.margins(mid * direction).min() >= 0 else (lo, mid)
    return 0.9 * lo * direction if lo > 0 else None


def sampled_limit_use(traj: FourierTrajectory, limits: ExcitationLimits, dynamics, friction,
                      rate_hz: float = P.CONTROL_RATE_HZ) -> LimitUse:
    """:class:`LimitUse` of one period sampled at ``rate_hz`` (the design grid is coarser)."""
    t = np.arange(int(round(traj.period_s * rate_hz)) + 1) / rate_hz
    q, qd, qdd = traj.evaluate(t)
    tau = standard_regressor(dynamics, q, qd, qdd) @ standard_vector(dynamics, friction)
    return limit_use(q, qd, qdd, tau, dynamics.link7_speed_m_s(q, qd), limits)


def predicted_tracking_share(traj: FourierTrajectory, dynamics, friction, kp: np.ndarray, kd: np.ndarray,
                             n_samples: int = 2048) -> np.ndarray:
    """(n,) per joint: the tracking error a PD + gravity controller (gains ``kp``, ``kd``) will leave over one
    period, as a share of the joint's motion (RMS of the error over the standard deviation of the position; NaN
    for joints that do not move), the figure :func:`wamctl.analysis.identification.data.tracking_shares` measures
    on the run. Linear, per joint: the torque the declared model needs beyond gravity (rigid body + friction)
    through ``1 / (kp + i w kd - w^2 M_jj)`` (``M_jj`` at ``q0``). On configs/excitation.yaml it predicts
    2.4 / 0.6 / 1.2 / 1.2 / 2.3 / 5.0 / 45 % against 2.3 / 0.6 / 1.1 / 1.5 / 2.1 / 5.2 / 40 % measured on a
    simulated arm whose links are 20 % off (joint 7: its friction against kp = 8)."""
    t = np.arange(n_samples) * traj.period_s / n_samples
    q, qd, qdd = traj.evaluate(t)
    tau = dynamics.inverse_dynamics_many(q, qd, qdd) - dynamics.gravity_many(q) + friction.friction_torque(qd)
    m = np.diag(dynamics.mass_matrix(traj.q0_rad))
    w = 2 * np.pi * np.fft.rfftfreq(n_samples, traj.period_s / n_samples)[:, None]
    e = np.fft.irfft(np.fft.rfft(tau, axis=0) / (np.asarray(kp) - w ** 2 * m + 1j * w * np.asarray(kd)),
                     n_samples, axis=0)
    motion = q.std(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(motion > 1e-9, np.sqrt(np.mean(e ** 2, axis=0)) / motion, np.nan)
