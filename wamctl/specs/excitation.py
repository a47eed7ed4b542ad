"""The ``excitation`` spec: an exciting trajectory for ``wamctl identify`` (finite Fourier series per joint).

``wamctl excite SPEC.yaml`` designs the coefficients under the limits below and writes the same spec with
``excitation.coefficients`` filled in; ``wamctl run`` executes it on the simulated arm or the real one. A
spec without coefficients is designed when it is planned (deterministic: the spec's ``seed``).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, PrivateAttr, model_validator

from wamctl.model import params as P
from wamctl.model.robots import DEFAULT_ROBOT, ROBOTS, get_robot
from wamctl.specs.common import Common, Joint, Strict, Vec7


class ExcitationLimitsSpec(Strict):
    """Limits the trajectory respects everywhere (checked over the whole trajectory at the control rate)."""
    joint_margin_rad: float = Field(0.15, ge=0.0, le=1.0, description="distance kept from each joint limit")
    max_speed_rad_s: float | Vec7 = Field(1.2, description="per joint (or one for all), at most 2 rad/s")
    max_acceleration_rad_s2: float | Vec7 = Field(4.0, description="per joint (or one for all)")
    torque_margin: float = Field(0.3, ge=0.0, lt=1.0, description="share of each torque limit kept free: the "
                                 "declared model's torque stays below (1 - margin) x the robot's torque limits "
                                 "(25, 20, 15, 15, 5, 5, 5 N m on the wam7; 25, 20, 15, 15 N m on the wam4)")
    max_cartesian_speed_m_s: float = Field(0.8, gt=0.0, le=1.0, description="wrist speed (the WAM's safety "
                                           "module faults at 1 m/s; the tool plate on the wam4)")
    _robot: str = PrivateAttr(DEFAULT_ROBOT)     # the spec's robot (set by ExcitationSpec): its limits

    @model_validator(mode="after")
    def _check(self):
        self.check_robot(DEFAULT_ROBOT)
        return self

    def check_robot(self, robot) -> None:
        """Raise ValueError naming the field when a speed or acceleration is not > 0 or a speed is above the
        velocity limit of ``robot``'s joint (a vector of the wrong length is named by the spec's robot check)."""
        r = get_robot(robot)
        for name, hard in (("max_speed_rad_s", r.qd_max_rad_s), ("max_acceleration_rad_s2", None)):
            raw = np.atleast_1d(np.asarray(getattr(self, name), float))
            if raw.size not in (1, r.n_joints):
                continue
            v = np.broadcast_to(raw, (r.n_joints,))
            if (v <= 0).any():
                raise ValueError(f"{name}: must be > 0")
            if hard is not None and (v > hard).any():
                j = int(np.argmax(v > hard))
                raise ValueError(f"{name}: joint {j + 1}: {v[j]:g} rad/s is above the velocity limit {hard[j]:g}")

    def arrays(self, robot=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q_min, q_max, qd_max, qdd_max), (n,) each for the joints of ``robot`` (default: the spec's)."""
        r = get_robot(robot if robot is not None else self._robot)
        m = self.joint_margin_rad
        qd = np.broadcast_to(np.asarray(self.max_speed_rad_s, float), (r.n_joints,)).copy()
        qdd = np.broadcast_to(np.asarray(self.max_acceleration_rad_s2, float), (r.n_joints,)).copy()
        return r.q_min_rad + m, r.q_max_rad - m, qd, qdd


class DesignSpec(Strict):
    """How the coefficients are found: a criterion of the base regressor, minimised by SLSQP from ``starts``
    random feasible starts."""
    criterion: Literal["d_optimal", "condition"] = "d_optimal"
    starts: int = Field(3, ge=1, le=50)
    max_iterations: int = Field(60, ge=1, le=2000)
    grid_points: int = Field(60, ge=20, le=1000, description="samples of one period the criterion is built on")
    declared_friction: str = Field("table_4_1", description="friction the torque limit is checked with: "
                                                            "table_4_1, none or a friction/model file")


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class BoxSpec(Strict):
    """A workspace box in frame 0 (the shoulder at the origin, z up), m: the moving links stay inside."""
    min_m: Vec3
    max_m: Vec3

    @model_validator(mode="after")
    def _check(self):
        for k, axis in enumerate("xyz"):
            if not self.min_m[k] < self.max_m[k]:
                raise ValueError(f"min_m: {axis} {self.min_m[k]:g} m is not below max_m's {self.max_m[k]:g} m")
            if not self.min_m[k] < 0.0 < self.max_m[k]:
                raise ValueError(f"min_m/max_m: the shoulder (0 on {axis}) is outside the box")
        return self


class RadiiSpec(Strict):
    """Capsule radii, m (default: :data:`wamctl.model.collision.RADIUS_M`)."""
    shoulder: float | None = Field(None, gt=0.0, le=0.3)
    upper_arm: float | None = Field(None, gt=0.0, le=0.2)
    forearm: float | None = Field(None, gt=0.0, le=0.2)
    wrist: float | None = Field(None, gt=0.0, le=0.2)

    def mapping(self) -> dict:
        names = {"shoulder": "shoulder", "upper_arm": "upper arm", "forearm": "forearm", "wrist": "wrist and hand"}
        return {names[k]: v for k, v in self.model_dump().items() if v is not None}


class WorldSpec(Strict):
    """The arm's surroundings the trajectory keeps ``clearance_m`` from over the whole period (see
    :mod:`wamctl.model.collision` for the capsules)."""
    self_collision: bool = Field(True, description="non-adjacent links kept apart")
    table_z_m: float | None = Field(None, ge=-1.5, lt=0.0, description="a table or floor plane at this height "
                                    "in frame 0 (the shoulder at 0, z up); the base stands on it")
    box: BoxSpec | None = None
    clearance_m: float = Field(0.02, ge=0.0, le=0.3, description="distance kept from each obstacle")
    tool_length_m: float = Field(0.0, ge=0.0, le=0.5, description="a tool beyond the flange along z7")
    radii_m: RadiiSpec = RadiiSpec()

    @model_validator(mode="after")
    def _check(self):
        if self.box is not None and self.table_z_m is not None and self.box.max_m[2] <= self.table_z_m:
            raise ValueError(f"box.max_m: z {self.box.max_m[2]:g} m is at or below the table ({self.table_z_m:g} m)")
        return self


class JointCoefficients(Strict):
    a_rad_s: list[float]
    b_rad_s: list[float]


class ExcitationSection(Strict):
    """The trajectory: ``q_j(t) = q0_j + sum_l a_jl / (w l) sin(w l t) - b_jl / (w l) (cos(w l t) - 1)``,
    ``w = 2 pi / period_s``, repeated ``periods`` times between two holds at ``q0_rad``."""
    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)),
                                description="the joints that move (the others hold q0); default: every joint "
                                            "of the robot")
    period_s: float = Field(10.0, ge=1.0, le=120.0)
    harmonics: int = Field(5, ge=2, le=15)
    periods: int = Field(2, ge=1, le=100)
    settle_s: float = Field(1.0, ge=0.0, le=30.0, description="hold at q0 before and after")
    limits: ExcitationLimitsSpec = ExcitationLimitsSpec()
    design: DesignSpec = DesignSpec()
    world: WorldSpec = WorldSpec()
    coefficients: dict[Joint, JointCoefficients] | None = Field(
        None, description="the designed series (written by `wamctl excite`); absent: designed when planned")

    @model_validator(mode="after")
    def _coefficients(self):
        if self.coefficients is None:
            return self
        ls = np.arange(1, self.harmonics + 1)
        for j, c in self.coefficients.items():
            if j not in self.joints:
                raise ValueError(f"coefficients.{j}: joint {j} is not among the moving joints {self.joints}")
            for name in ("a_rad_s", "b_rad_s"):
                if len(getattr(c, name)) != self.harmonics:
                    raise ValueError(f"coefficients.{j}.{name}: expected {self.harmonics} values (harmonics)")
            a, b = np.asarray(c.a_rad_s), np.asarray(c.b_rad_s)
            scale = max(np.abs(a).max(), np.abs(b).max(), 1e-12)
            if abs(a.sum()) > 1e-9 * scale * self.harmonics:
                raise ValueError(f"coefficients.{j}.a_rad_s: must sum to 0 (the joint starts and ends at rest)")
            if abs((ls * b).sum()) > 1e-9 * scale * self.harmonics ** 2:
                raise ValueError(f"coefficients.{j}.b_rad_s: sum of l * b_l must be 0 (no acceleration at the "
                                 "start and end)")
        return self


class ExcitationSpec(Common):
    SUPPORTED_ROBOTS: ClassVar[tuple[str, ...]] = tuple(ROBOTS)
    kind: Literal["excitation"]
    excitation: ExcitationSection = ExcitationSection()

    @classmethod
    def robot_defaults(cls, data: dict, n_joints: int) -> None:
        ex = data.get("excitation")
        if ex is None or (isinstance(ex, dict) and "joints" not in ex):
            data["excitation"] = dict(ex or {}, joints=list(range(1, n_joints + 1)))

    @model_validator(mode="after")
    def _robot_limits(self):
        """The limits are the spec's robot's (its joint range, speeds and torque limits)."""
        lim = self.excitation.limits
        lim._robot = self.robot
        try:
            lim.check_robot(self.robot)
        except ValueError as exc:
            raise ValueError(f"excitation.limits.{exc}") from None
        return self
