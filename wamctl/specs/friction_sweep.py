"""The ``friction_sweep`` spec (thesis chapter 4.2): constant-velocity sweeps of chosen joints, both directions,
the identification's options and the optional validation by the rotation test.

The spec checks, before anything moves, that every move stays within the joint limits and that gravity leaves
each joint enough of its torque limit (:data:`GRAVITY_BUDGET`).
"""

from __future__ import annotations

from functools import lru_cache
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from wamctl.model import params as P
from wamctl.model.robots import ROBOTS, get_robot
from wamctl.specs.common import Common, Joint, Strict, check_positions

# Default speeds (rad/s), each run in both directions: from below 0.01 rad/s to 1 rad/s, roughly
# logarithmic, so that both the Coulomb level (slow) and the viscous slope (fast) are well determined.
DEFAULT_VELOCITIES_RAD_S = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]

GRAVITY_BUDGET = 0.6  # largest gravity torque allowed along a sweep, as a fraction of each joint's torque limit

Direction = Literal["auto", "positive", "negative"]


@lru_cache(maxsize=256)
def _travel_problem(q0: tuple, joint: int, travel_rad: float, payload, robot: str = "wam7") -> tuple[str, float]:
    """Why moving ``joint`` of ``robot`` by ``travel_rad`` from ``q0`` is not allowed ('' if it is), and the
    largest gravity load along the way as a fraction of the torque limit."""
    dyn = _dynamics(payload, robot)
    tau_max = get_robot(robot).tau_max_Nm
    q = np.tile(np.asarray(q0, float), (9, 1))
    q[:, joint - 1] += np.linspace(0.0, travel_rad, 9)
    try:
        check_positions(q, f"joint {joint} moved by {travel_rad:+.3g} rad from q0_rad", robot)
    except ValueError as exc:
        return str(exc), np.inf
    ratio = np.array([np.abs(dyn.gravity(x)) / tau_max for x in q])
    worst = float(ratio.max())
    if worst > GRAVITY_BUDGET:
        i, k = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        return (f"moved by {travel_rad:+.3g} rad, joint {k + 1} would need {ratio[i, k] * tau_max[k]:.1f} N m "
                f"against gravity, over {GRAVITY_BUDGET:.0%} of its {tau_max[k]:g} N m limit"), worst
    return "", worst


@lru_cache(maxsize=4)
def _dynamics(payload, robot: str = "wam7"):
    from wamctl.model.dynamics import Payload, WamDynamics
    return WamDynamics(Payload(payload[0], payload[1]) if payload else None, robot=robot)


class FrictionSweepSection(Strict):
    """What the sweep does: joints, speeds (magnitudes; each run both ways), travel and timing."""

    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)),
                                description="default: every joint of the robot")
    velocities_rad_s: list[float] | dict[Joint, list[float]] = Field(
        default_factory=lambda: list(DEFAULT_VELOCITIES_RAD_S),
        description="speed magnitudes, shared or per joint ({joint: [...]}); each is run in both directions")
    travel_rad: float | dict[Joint, float] = Field(
        0.6, description="largest travel of one move (shared or per joint); slow moves travel v * cruise_s + "
                         "lag_margin_rad")
    cruise_s: float = Field(2.0, gt=0.0, le=60.0, description="target length of the constant-velocity stage")
    lag_margin_rad: Literal["auto"] | float | dict[Joint, float] = Field(
        "auto", description="extra travel of slow moves, eaten while the PD error builds up to the breakaway "
                            "torque (the joint sticks meanwhile); auto: 2 * prior Coulomb level / kp")
    min_cruise_s: float = Field(0.4, gt=0.0, description="shortest constant-velocity stage accepted")
    tc_s: float = Field(0.25, gt=0.0, le=2.0, description="LSPB blend (acceleration) time")
    settle_s: float = Field(0.4, ge=0.0, le=10.0, description="hold before each move")
    first_direction: Direction | dict[Joint, Direction] = Field(
        "auto", description="direction of the first move of each pair (shared or per joint); auto: the side "
                            "within the joint limits with the smaller gravity load")

    @field_validator("joints")
    @classmethod
    def _unique_joints(cls, v):
        if not v:
            raise ValueError("at least one joint")
        if len(set(v)) != len(v):
            raise ValueError(f"joints repeated: {v}")
        return v

    @field_validator("velocities_rad_s")
    @classmethod
    def _speeds(cls, v):
        lists = v.values() if isinstance(v, dict) else [v]
        for speeds in lists:
            if len(speeds) < 2:
                raise ValueError("at least two speeds per joint (a line needs two points per direction)")
            bad = [s for s in speeds if not s > 0]
            if bad:
                raise ValueError(f"speeds are magnitudes (> 0), each run in both directions; got {bad}")
            if len(set(speeds)) != len(speeds):
                raise ValueError(f"speeds repeated: {speeds}")
        return v

    @field_validator("travel_rad")
    @classmethod
    def _travel(cls, v):
        vals = v.values() if isinstance(v, dict) else [v]
        if any(not x > 0 for x in vals):
            raise ValueError("travel must be > 0 rad")
        return v

    # --- per joint accessors (1-based joint numbers) ----------------------------------------------
    def speeds(self, joint: int) -> list[float]:
        v = self.velocities_rad_s
        return sorted(v[joint] if isinstance(v, dict) else v)

    def travel(self, joint: int) -> float:
        t = self.travel_rad
        return float(t.get(joint, 0.6)) if isinstance(t, dict) else float(t)

    def direction_setting(self, joint: int) -> str:
        d = self.first_direction
        return d.get(joint, "auto") if isinstance(d, dict) else d

    def lag_margin(self, joint: int, kp: np.ndarray) -> float:
        """Extra travel of a slow move of ``joint`` (rad); ``kp`` (7,) are the sweep's proportional gains."""
        m = self.lag_margin_rad
        if m == "auto":
            # Under PD a joint at rest starts to slide once kp * e exceeds the breakaway torque, and after a
            # reversal it first unwinds the residual error of the previous move: about 2 Fc / kp of the
            # reference passes while it sticks. Prior Fc: the larger Table 4.1 level of the joint.
            prior = max(P.TABLE_4_1_FC_POS_NM[joint - 1], P.TABLE_4_1_FC_NEG_NM[joint - 1])
            return float(np.clip(2.0 * prior / kp[joint - 1], 0.001, 0.05))
        return float(m.get(joint, 0.0)) if isinstance(m, dict) else float(m)

    def move_travel(self, joint: int, speed: float, kp: np.ndarray) -> float:
        """Travel of one move at ``speed``: ``min(travel, speed * cruise_s + lag margin)``."""
        return min(self.travel(joint), speed * self.cruise_s + self.lag_margin(joint, kp))


class ValidationSection(Strict):
    """Rotation test (thesis 4.4) after the identification, under pd_g and under pd_g_ff with the new model."""

    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)),
                                description="default: every joint of the robot")
    amplitude_rad: float = P.ROTATION_AMPLITUDE_RAD
    velocity_rad_s: float = Field(P.ROTATION_VELOCITY_RAD_S, gt=0.0, le=2.0)
    tc_s: float = Field(P.LSPB_TC_S, gt=0.0)
    settle_s: float = Field(0.3, ge=0.0)
    hold_s: float = Field(1.0, ge=0.0)

    @field_validator("amplitude_rad")
    @classmethod
    def _nonzero(cls, v):
        if v == 0:
            raise ValueError("the rotation must not be zero")
        return v


class IdentificationSection(Strict):
    """Options of the identification (analysis) step."""

    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = Field(
        "linear", description="least-squares loss; soft_l1/huber/cauchy down-weight outlying segments")
    criterion: Literal["bic", "aic"] = "bic"
    weighting: Literal["se", "none"] = Field(
        "se", description="se: weight segments by their standard error (plus a model-error term); none: the "
                          "thesis' unweighted least squares (eq. 4.2)")
    folds: int = Field(5, ge=2, le=20, description="k-fold over segments for the held-out criterion")
    models: list[Literal["classic", "classic_symmetric", "stribeck"]] = \
        Field(default_factory=lambda: ["classic", "classic_symmetric", "stribeck"], min_length=1)


class FrictionSweepSpec(Common):
    SUPPORTED_ROBOTS: ClassVar[tuple[str, ...]] = tuple(ROBOTS)
    kind: Literal["friction_sweep"]
    sweep: FrictionSweepSection = FrictionSweepSection()
    identification: IdentificationSection = IdentificationSection()
    validation: ValidationSection | None = None

    @classmethod
    def robot_defaults(cls, data: dict, n_joints: int) -> None:
        every = list(range(1, n_joints + 1))
        for key in ("sweep", "validation"):
            section = data.get(key)
            if (section is None and key == "sweep") or (isinstance(section, dict) and "joints" not in section):
                data[key] = dict(section or {}, joints=every)

    @model_validator(mode="after")
    def _check_sweep(self):
        s = self.sweep
        q0 = np.array(self.q0_rad)
        kp = self.controller.gains()[0]
        if not isinstance(s.lag_margin_rad, str):
            vals = s.lag_margin_rad.values() if isinstance(s.lag_margin_rad, dict) else [s.lag_margin_rad]
            if any(not 0 <= x <= 0.5 for x in vals):
                raise ValueError("sweep.lag_margin_rad: between 0 and 0.5 rad")
        if isinstance(s.velocities_rad_s, dict):
            missing = [j for j in s.joints if j not in s.velocities_rad_s]
            if missing:
                raise ValueError(f"sweep.velocities_rad_s: no speeds for joint(s) {missing}")
        if 2 * s.tc_s > 60:
            raise ValueError("sweep.tc_s: too long")
        qd_max = get_robot(self.robot).qd_max_rad_s
        for j in s.joints:
            if j > len(qd_max):
                continue           # Common names the joint the robot lacks
            for v in s.speeds(j):
                if v > qd_max[j - 1]:
                    raise ValueError(f"sweep.velocities_rad_s: joint {j} speed {v} rad/s above the limit "
                                     f"{qd_max[j - 1]} rad/s")
                cruise = s.move_travel(j, v, kp) / v
                if cruise < s.min_cruise_s:
                    raise ValueError(f"sweep.travel_rad: joint {j} at {v} rad/s travels {s.move_travel(j, v, kp):.3g} "
                                     f"rad, only {cruise:.2f} s at constant velocity (min_cruise_s "
                                     f"{s.min_cruise_s} s); raise travel_rad or drop the speed")
            self.first_sign(j)  # raises naming the field when neither allowed direction fits
        if self.validation is not None:
            for j in self.validation.joints:
                q = q0.copy()
                q[j - 1] += self.validation.amplitude_rad
                check_positions(q, "validation.amplitude_rad", self.robot)
        return self

    def _payload(self):
        p = self.plant.effects.payload or self.controller.declared_payload
        return (p.mass_kg, tuple(p.com_m)) if p else None

    def first_sign(self, joint: int) -> float:
        """+1 or -1: direction of the first move of each pair of ``joint`` (resolves ``auto``).

        A direction is allowed when the whole travel stays within the joint limits and the gravity torque of
        every joint stays within :data:`GRAVITY_BUDGET` of its torque limit (the rest is for the PD, friction
        and acceleration; beyond it the arm sags on the torque limit and the sweep is spoilt).
        """
        s = self.sweep
        setting = s.direction_setting(joint)
        options = {"positive": [1.0], "negative": [-1.0], "auto": [1.0, -1.0]}[setting]
        problems, best = [], None
        for sign in options:
            why, load = _travel_problem(tuple(self.q0_rad), joint, sign * s.travel(joint), self._payload(),
                                        self.robot)
            if why:
                problems.append(why)
            elif best is None or load < best[1] - 1e-9:
                best = (sign, load)
        if best is None:
            raise ValueError(f"sweep.travel_rad: joint {joint}: {'; '.join(problems)}; shorten sweep.travel_rad"
                             + (" or set sweep.first_direction" if setting != "auto" else "") + " or change q0_rad")
        return best[0]
