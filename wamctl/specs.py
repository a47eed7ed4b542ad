"""Declarative experiment specs (YAML) as pydantic models: a discriminated union on ``kind``.

Shared parts are declared once and reused by every kind: ``backend``, ``plant`` (the simulated arm's truth:
friction, effects, sensors), ``controller``, ``seed``, ``out_dir``. Joints are 1-based in specs (as on the
arm's labels) and 0-based in arrays. Every model forbids unknown keys, so a typo is an error naming the field.
"""

from __future__ import annotations

from pathlib import Path
from functools import lru_cache
from typing import Annotated, Any, Literal, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator, model_validator

from wamctl.errors import SpecError, WamctlError
from wamctl.model import params as P

Joint = Annotated[int, Field(ge=1, le=P.N_JOINTS, description="joint number 1..7")]
Vec7 = Annotated[list[float], Field(min_length=P.N_JOINTS, max_length=P.N_JOINTS)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=False)


# ----------------------------------------------------------------------------------------------- backend
class SimBackendSpec(Strict):
    kind: Literal["sim"] = "sim"
    physics_substeps: int = Field(2, ge=1, le=50, description="physics steps per 2 ms control period")


class SimulatedFault(Strict):
    """A link fault injected when the control loop reaches ``at_cycle`` (simulated pucks only): tests and demos
    of the CAN link watchdog. ``drop_replies``: replies lost with ``probability``; ``silent_puck``: ``puck``
    neither answers nor obeys; ``garbage_replies``: replies replaced by malformed frames with ``probability``;
    ``garbage_frames``: ``count`` malformed frames sent at once; ``stop_answering``: no puck answers;
    ``bus_error``: the host's next ``count`` transmissions fail with ``can.CanError``."""
    kind: Literal["drop_replies", "silent_puck", "garbage_replies", "garbage_frames", "stop_answering",
                  "bus_error"]
    at_cycle: int = Field(250, ge=0, description="control cycle (0 = first) at which the fault starts")
    puck: Joint = Field(7, description="silent_puck: the puck (1..7)")
    probability: float = Field(1.0, gt=0.0, le=1.0)
    count: int = Field(1, ge=1, le=1000)


class CanBackendSpec(Strict):
    kind: Literal["can"]
    interface: str = Field("socketcan", description="python-can interface: socketcan, pcan, virtual, ...")
    channel: str = "can0"
    bitrate: int = 1_000_000
    simulate_pucks: bool = Field(False, description="answer as the simulated arm's pucks (virtual bus demos)")
    watchdog_cycles: int = Field(3, ge=1, le=50, description="missing position replies tolerated")
    # added with the CAN backend (issue 9)
    reply_timeout_s: float = Field(0.0015, gt=0.0, le=1.0,
                                   description="wait for the 7 position replies; later ones count as missing")
    start_tolerance_rad: float = Field(0.05, gt=0.0, le=0.5,
                                       description="largest |q - q0_rad| accepted at start-up, per joint")
    physics_substeps: int = Field(2, ge=1, le=50, description="simulate_pucks: physics steps per control period")
    simulated_fault: SimulatedFault | None = Field(None, description="simulate_pucks: inject a link fault")

    @model_validator(mode="after")
    def _fault_needs_simulation(self):
        if self.simulated_fault is not None and not self.simulate_pucks:
            raise ValueError("simulated_fault needs simulate_pucks: true")
        if self.simulate_pucks and self.interface != "virtual":
            raise ValueError(f"simulate_pucks needs interface: virtual (python-can's in-process bus), not "
                             f"{self.interface!r}: simulated pucks must never answer on a bus with a real arm")
        return self


BackendSpec = Annotated[Union[SimBackendSpec, CanBackendSpec], Field(discriminator="kind")]


# ----------------------------------------------------------------------------------------------- plant
class FrictionInline(Strict):
    joints: dict[Joint, dict[str, float]]


class StribeckEffect(Strict):
    """Friction rising to a breakaway level ``breakaway_ratio * Fc`` at rest, decaying with speed (eq. 2.8)."""
    joints: list[Joint]
    breakaway_ratio: float = Field(1.6, gt=1.0, le=10.0)
    vs_rad_s: float = Field(0.05, gt=0.0, le=5.0)
    delta: float = Field(2.0, gt=0.0, le=5.0)


class RippleEffect(Strict):
    """Torque periodic in the joint angle: ``tau = amplitude sin(2 pi q / period + phase)`` (cogging, cables)."""
    joints: list[Joint]
    amplitude_Nm: float = Field(0.5, gt=0.0, le=20.0)
    period_rad: float = Field(0.2, ge=0.005, le=6.3)
    phase_rad: float = 0.0


class PayloadEffect(Strict):
    """A point mass at the wrist, in the link-7 frame."""
    mass_kg: float = Field(gt=0.0, le=5.0)
    com_m: Annotated[list[float], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.05]


class DelayEffect(Strict):
    """Measured positions lag the motion by a fixed time."""
    delay_s: float = Field(gt=0.0, le=0.1)


class FrictionDriftEffect(Strict):
    """Friction scaled by ``1 + fraction (1 - exp(-t / time_constant))`` (warming up: negative fraction)."""
    joints: list[Joint]
    fraction: float = Field(-0.4, ge=-0.9, le=3.0)
    time_constant_s: float = Field(20.0, gt=0.0)


class BacklashEffect(Strict):
    """A dead band of ``width_rad`` between motor (encoder) and link, traversed at direction reversals."""
    joints: list[Joint]
    width_rad: float = Field(0.002, gt=0.0, le=0.1)


class Effects(Strict):
    stribeck: StribeckEffect | None = None
    position_ripple: RippleEffect | None = None
    payload: PayloadEffect | None = None
    delay: DelayEffect | None = None
    friction_drift: FrictionDriftEffect | None = None
    backlash: BacklashEffect | None = None

    def names(self) -> list[str]:
        return [k for k in type(self).model_fields if getattr(self, k) is not None]


class SensorSpec(Strict):
    encoder_counts_per_rev: int = Field(P.ENCODER_COUNTS_PER_REV, ge=0,
                                        description="motor encoder resolution; 0 = ideal sensor")
    position_noise_rad: float = Field(0.0, ge=0.0, le=0.01)
    torque_noise_Nm: float = Field(0.0, ge=0.0, le=1.0, description="actuation noise added to the torque")


class PlantSpec(Strict):
    """The simulated arm: its friction (``table_4_1``, ``none``, a friction model file, or inline), the effects
    a real arm has and a declared model may lack, and its sensors."""
    friction: Union[Literal["table_4_1", "none"], FrictionInline, str] = "table_4_1"
    effects: Effects = Effects()
    sensors: SensorSpec = SensorSpec()


# ----------------------------------------------------------------------------------------------- controller
class ControllerSpec(Strict):
    kind: Literal["pd_g", "pid", "pd_g_ff"] = "pd_g"
    kp: Vec7 | None = Field(None, description="default: libbarrett's")
    kd: Vec7 | None = None
    ki: Vec7 | None = Field(None, description="pid only; default libbarrett's")
    gravity_compensation: bool = True
    friction_ff: str | None = Field(None, description="pd_g_ff: 'table_4_1' or a friction_model.yaml path")
    ff_inertia: bool = Field(True, description="pd_g_ff: include the m * qdd_r term of eq. 4.3")
    declared_payload: PayloadEffect | None = Field(None, description="payload known to gravity compensation")

    @model_validator(mode="after")
    def _check(self):
        if self.kind == "pd_g_ff" and not self.friction_ff:
            raise ValueError("friction_ff is required for kind pd_g_ff (a friction_model.yaml or 'table_4_1')")
        if self.kind != "pid" and self.ki is not None and any(self.ki):
            raise ValueError(f"ki is only used by kind pid, not {self.kind}")
        return self

    def gains(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        kp = np.array(self.kp if self.kp is not None else P.KP, float)
        kd = np.array(self.kd if self.kd is not None else P.KD, float)
        if self.kind == "pid":
            ki = np.array(self.ki if self.ki is not None else P.KI, float)
        else:
            ki = np.zeros(P.N_JOINTS)
        return kp, kd, ki


class Common(Strict):
    name: str = Field("run", pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    seed: int = 0
    backend: BackendSpec = SimBackendSpec()
    plant: PlantSpec = PlantSpec()
    controller: ControllerSpec = ControllerSpec()
    q0_rad: Vec7 = Field(default_factory=lambda: [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])
    out_dir: str = "runs"

    @field_validator("q0_rad")
    @classmethod
    def _q0_in_limits(cls, v):
        check_positions(np.array(v), "q0_rad")
        return v


def check_positions(q: np.ndarray, where: str) -> None:
    """Raise ValueError naming the joint if any position in ``q`` ((7,) or (n, 7)) is outside the joint limits."""
    q = np.atleast_2d(q)
    bad = (q < P.Q_MIN_RAD) | (q > P.Q_MAX_RAD)
    if bad.any():
        row, j = map(int, np.argwhere(bad)[0])
        raise ValueError(f"{where}: joint {j + 1} would reach {q[row, j]:.4f} rad, outside its limits "
                         f"[{P.Q_MIN_RAD[j]}, {P.Q_MAX_RAD[j]}] rad")


# ----------------------------------------------------------------------------------------------- kinds
class RotationTask(Strict):
    """Thesis chapter 3: rotate joints by ``amplitude_rad`` at ``velocity_rad_s`` (LSPB, t_c = 1 s)."""
    joints: list[Joint] = Field(default_factory=lambda: list(range(1, 8)))
    mode: Literal["one_at_a_time", "all_together"] = "one_at_a_time"
    amplitude_rad: float = Field(P.ROTATION_AMPLITUDE_RAD, description="rotation of each joint, rad (non-zero)")
    velocity_rad_s: float = Field(P.ROTATION_VELOCITY_RAD_S, gt=0.0, le=2.0)
    tc_s: float = Field(P.LSPB_TC_S, gt=0.0)
    settle_s: float = Field(0.5, ge=0.0, description="hold at q0 before each move")
    hold_s: float = Field(1.0, ge=0.0, description="hold at the target after each move")
    return_to_start: bool = Field(True, description="one_at_a_time: move back before the next joint")


class RotationSpec(Common):
    kind: Literal["rotation"]
    rotation: RotationTask = RotationTask()

    @model_validator(mode="after")
    def _targets_in_limits(self):
        q0 = np.array(self.q0_rad)
        for j in self.rotation.joints:
            q = q0.copy()
            q[j - 1] += self.rotation.amplitude_rad
            check_positions(q, "rotation.amplitude_rad")
        return self


# kind -> "module:Class" of its spec model. Each experiment module defines its own spec (a subclass of
# Common with ``kind: Literal[...]``); the union is assembled lazily, at the first parse.
SPEC_KINDS: dict[str, str] = {
    "rotation": "wamctl.specs:RotationSpec",
    "friction_sweep": "wamctl.experiments.friction_sweep:FrictionSweepSpec",
    "ift": "wamctl.experiments.ift:IftSpec",
    "hmi_block": "wamctl.experiments.hmi_block:HmiBlockSpec",
}


def spec_models() -> dict[str, type[Common]]:
    """The spec model of every kind whose module is installed."""
    import importlib
    out = {}
    for kind, target in SPEC_KINDS.items():
        mod, cls = target.split(":")
        try:
            out[kind] = getattr(importlib.import_module(mod), cls)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise
    return out


@lru_cache(maxsize=1)
def _adapter() -> TypeAdapter:
    models = tuple(spec_models().values())
    union = Union[models] if len(models) > 1 else models[0]
    return TypeAdapter(Annotated[union, Field(discriminator="kind")] if len(models) > 1 else union)


def format_validation_error(exc: ValidationError, source: str) -> str:
    """One line per problem: ``source: field.path: message``."""
    lines = []
    for err in exc.errors():
        loc = [str(x) for x in err["loc"]]
        if len(SPEC_KINDS) > 1 and loc and loc[0] in SPEC_KINDS:
            loc = loc[1:]  # the union's tag, not a field
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {'.'.join(loc)}: {msg}" if loc else f"{source}: {msg}")
    return "\n".join(lines)


def parse_spec(data: Any, source: str = "spec") -> Common:
    """Validate a mapping into a spec model, raising :class:`SpecError` naming the field."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: expected a mapping at the top level")
    kinds = spec_models()
    if "vary" in data:
        raise SpecError(f"{source}: vary: this spec varies parameters; run it with `wamctl sweep {source}`")
    if data.get("kind") not in kinds:
        raise SpecError(f"{source}: kind: {'missing' if 'kind' not in data else repr(data['kind']) + ' unknown'}; "
                        f"known kinds: {', '.join(sorted(kinds))}")
    try:
        return _adapter().validate_python(data)
    except ValidationError as exc:
        raise SpecError(format_validation_error(exc, source)) from None


def load_yaml(path: str | Path, error: type[WamctlError] = SpecError, missing: str = "no such file") -> Any:
    """The YAML document in ``path``; ``error`` (a spec's or a data file's) naming the line and column of a
    syntax error, or ``missing`` when there is no such file."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {missing}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise error(f"{path}: YAML syntax error at {where}{problem}") from None


MODEL_FILE_FORMAT = "wamctl-model/1"


def load_model_file(path: str | Path) -> dict:
    """A model file (``format: wamctl-model/1``): a plant description (``friction``, ``effects``, ``sensors``)
    as written by ``wamctl diagnose``; usable wherever a spec takes ``plant:``."""
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise SpecError(f"{path}: a model file is a mapping with friction/effects/sensors")
    data = {k: v for k, v in data.items() if k in PlantSpec.model_fields}
    return data


def load_spec(path: str | Path) -> Common:
    """Read and validate a spec file. ``plant: FILE`` loads a model file (relative to the spec's folder)."""
    path = Path(path)
    data = load_yaml(path)
    if isinstance(data, dict) and isinstance(data.get("plant"), str):
        model = Path(data["plant"])
        if not model.is_absolute() and not model.exists():
            model = path.parent / model
        data = dict(data, plant=load_model_file(model))
    return parse_spec(data, str(path))
