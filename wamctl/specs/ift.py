"""The ``ift`` spec (thesis chapter 5): which joints to tune on which task, the model of the second experiment,
the Hessian schedule, gain bounds, safeguards and the strategy comparison.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from wamctl.model import params as P
from wamctl.specs.common import Common, ControllerSpec, Joint, PlantSpec, Strict, Vec7, check_positions

GAIN_NAMES = ("kp", "kd", "ki")   # the columns of a (7, 3) gain matrix
#: Their units: the PID's torque per position error, per its rate, per its integral.
GAIN_UNITS = {"kp": "N m/rad", "kd": "N m s/rad", "ki": "N m/(rad s)"}


class IftTask(Strict):
    """Per joint: hold at q0 (``settle_s``), an LSPB move of ``amplitude_rad`` at ``velocity_rad_s``, hold
    (``hold_s``). J is taken over these samples. Thesis: 0.5 rad at 0.083 rad/s, ~7.3 s per rotation."""
    amplitude_rad: float = P.ROTATION_AMPLITUDE_RAD
    velocity_rad_s: float = Field(P.ROTATION_VELOCITY_RAD_S, gt=0.0, le=2.0)
    tc_s: float = Field(P.LSPB_TC_S, gt=0.0)
    settle_s: float = Field(0.2, ge=0.0)
    hold_s: float = Field(1.0, ge=0.0)
    return_to_start: bool | None = Field(None, description="move back after the hold (not part of J); default: "
                                         "only on the CAN arm, which must end where the next experiment starts")

    @field_validator("amplitude_rad")
    @classmethod
    def _nonzero(cls, v):
        if v == 0:
            raise ValueError("amplitude_rad must not be 0")
        return v


class IftPlantSource(Strict):
    """Where the first experiment runs: ``backend`` (the spec's backend: the simulated arm of ``plant:`` or the
    CAN arm) or ``measured`` (recorded runs, one per iteration, each holding every tuned joint's move at that
    iteration's gains; when they run out the tuning stops and reports the next gains to record)."""
    source: Literal["backend", "measured"] = "backend"
    runs: list[str] = Field(default_factory=list, description="measured: run or measured-run directories")

    @model_validator(mode="after")
    def _runs(self):
        if self.source == "measured" and not self.runs:
            raise ValueError("source measured needs at least one entry in runs")
        if self.source == "backend" and self.runs:
            raise ValueError("runs are only read with source: measured")
        return self


class HessianStage(Strict):
    """One stage of the schedule: the Hessian method, the step gamma of eq. 2.14, and at most ``iterations``
    accepted iterations (None: until J stops decreasing)."""
    method: Literal["bfgs", "gauss_newton"]
    gamma: float = Field(gt=0.0)
    iterations: int | None = Field(None, ge=1)


def _thesis_schedule() -> list[HessianStage]:
    # Thesis section 5.2-5.3: BFGS with gamma = 0.5 first, then Gauss-Newton with gamma = 0.5 and 0.1.
    return [HessianStage(method="bfgs", gamma=0.5), HessianStage(method="gauss_newton", gamma=0.5),
            HessianStage(method="gauss_newton", gamma=0.1)]


class GainBounds(Strict):
    """Per-joint gain bounds. Defaults: kp and kd in [0.5, 4] x their initial value, ki in
    [0, ki_max_per_s x initial kp]."""
    kp_min: Vec7 | None = None
    kp_max: Vec7 | None = None
    kd_min: Vec7 | None = None
    kd_max: Vec7 | None = None
    ki_min: Vec7 | None = None
    ki_max: Vec7 | None = None
    kp_kd_factors: tuple[float, float] = Field((0.5, 4.0), description="default kp/kd bounds, x initial")
    ki_max_per_s: float = Field(100.0, gt=0.0, description="default ki upper bound = this x initial kp")

    @field_validator("kp_kd_factors")
    @classmethod
    def _factors(cls, v):
        if not 0 < v[0] <= 1 <= v[1]:
            raise ValueError("kp_kd_factors must be (low <= 1, high >= 1), low > 0")
        return v


class InitialGains(Strict):
    """Starting gains; default the PD gains of ``controller`` (libbarrett's) with ki = kd / 10 (Table 5.1)."""
    kp: Vec7 | None = None
    kd: Vec7 | None = None
    ki: Vec7 | None = None


class Safeguards(Strict):
    backtracking: int = Field(4, ge=0, le=30, description="retries of a rejected proposal with a smaller gamma")
    backtrack_factor: float = Field(0.5, gt=0.0, lt=1.0)
    max_error_rad: float = Field(0.05, gt=0.0, description="|error| above this on the model = diverging")
    torque_fraction: float = Field(0.95, gt=0.0, le=1.0,
                                   description="a torque reaching this fraction of the WAM limit on the model "
                                               "= the proposal would hit the torque limits")
    require_model_decrease: bool = Field(True, description="reject a proposal whose J does not decrease on "
                                                           "the model")


class Comparison(Strict):
    """Thesis section 5.4: the task under PD + gravity, PD + gravity + feed-forward friction (eq. 4.3, the
    identified friction) and the tuned PID, on the plant."""
    enabled: bool = True
    ff_inertia: bool = Field(True, description="include the m qdd_r term of eq. 4.3")


class IftSection(Strict):
    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)))
    task: IftTask = IftTask()
    plant: IftPlantSource = IftPlantSource()
    identified_friction: str = Field("table_4_1", description="the declared (identified) friction: a "
                                     "friction_model.yaml path, or table_4_1 as a stand-in; used by the default "
                                     "model and the feed-forward of the comparison")
    model: PlantSpec | str | None = Field(None, description="the model of the second experiment and of the "
                                               "safeguards: a plant description, a model file "
                                               "(wamctl-model/1), or None = rigid body + identified_friction, "
                                               "ideal sensors")
    second_experiment: Literal["incremental", "direct"] = "incremental"
    perturbation: float = Field(1.0, gt=0.0, le=10.0, description="eps: the second experiment's reference is "
                                "eps (r - y1) (incremental: around r); y2 is divided by eps")
    objective_signal: Literal["measured", "filtered"] = "measured"
    filter_cutoff_hz: float = Field(25.0, gt=0.0, lt=P.CONTROL_RATE_HZ / 2)
    schedule: list[HessianStage] = Field(default_factory=_thesis_schedule, min_length=1)
    max_iterations: int = Field(12, ge=0, le=200, description="plant experiments per joint after the initial one")
    stop_digits: int = Field(4, ge=1, le=12, description="J must decrease at this many significant digits")
    bounds: GainBounds = GainBounds()
    initial: InitialGains = InitialGains()
    safeguards: Safeguards = Safeguards()
    comparison: Comparison = Comparison()

    @field_validator("joints")
    @classmethod
    def _unique(cls, v):
        if not v or len(set(v)) != len(v):
            raise ValueError("joints must be a non-empty list without repeats")
        return sorted(v)


class IftSpec(Common):
    kind: Literal["ift"]
    controller: ControllerSpec = ControllerSpec(kind="pid")
    ift: IftSection = IftSection()

    @model_validator(mode="after")
    def _check(self):
        if self.controller.kind == "pd_g_ff":
            raise ValueError("controller.kind: ift tunes a PID (gravity compensation as controller says), not "
                             "pd_g_ff; use pid or pd_g, whose kp/kd are the starting gains")
        q0 = np.array(self.q0_rad)
        for j in self.ift.joints:
            q = q0.copy()
            q[j - 1] += self.ift.task.amplitude_rad
            check_positions(q, "ift.task.amplitude_rad")
        lo, hi = gain_bounds(self)
        g = initial_gains(self)
        bad = (g < lo - 1e-12) | (g > hi + 1e-12)
        if bad.any():
            j, i = map(int, np.argwhere(bad)[0])
            raise ValueError(f"ift.initial: joint {j + 1} {GAIN_NAMES[i]} = {g[j, i]:g} is outside its bounds "
                             f"[{lo[j, i]:g}, {hi[j, i]:g}]")
        if (lo > hi).any():
            j, i = map(int, np.argwhere(lo > hi)[0])
            raise ValueError(f"ift.bounds: joint {j + 1} {GAIN_NAMES[i]} lower bound above the upper bound")
        if (lo[:, :2] <= 0).any():
            raise ValueError("ift.bounds: kp_min and kd_min must be positive")
        if (lo[:, 2] < 0).any():
            raise ValueError("ift.bounds: ki_min must be >= 0")
        return self


def initial_gains(spec: IftSpec) -> np.ndarray:
    """(7, 3) starting gains [kp, kd, ki] per joint."""
    c, ini = spec.controller, spec.ift.initial
    kp = np.array(ini.kp if ini.kp is not None else (c.kp if c.kp is not None else P.KP), float)
    kd = np.array(ini.kd if ini.kd is not None else (c.kd if c.kd is not None else P.KD), float)
    if ini.ki is not None:
        ki = np.array(ini.ki, float)
    elif c.kind == "pid" and c.ki is not None:
        ki = np.array(c.ki, float)
    else:
        ki = kd / 10.0  # thesis section 5.2: Ki = Kd / 10 for the initial PID
    return np.stack([kp, kd, ki], axis=1)


def gain_bounds(spec: IftSpec) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper), each (7, 3) [kp, kd, ki]."""
    b = spec.ift.bounds
    g = initial_gains(spec)
    f_lo, f_hi = b.kp_kd_factors

    def pick(v, default):
        return np.array(v, float) if v is not None else default
    lo = np.stack([pick(b.kp_min, f_lo * g[:, 0]), pick(b.kd_min, f_lo * g[:, 1]), pick(b.ki_min, np.zeros(7))], 1)
    hi = np.stack([pick(b.kp_max, f_hi * g[:, 0]), pick(b.kd_max, f_hi * g[:, 1]),
                   pick(b.ki_max, b.ki_max_per_s * g[:, 0])], 1)
    return lo, hi
