"""The parts of a spec every kind shares: ``robot``, ``backend``, ``plant`` (the simulated arm's truth: friction,
effects, sensors), ``controller``, ``seed``, ``q0_rad``, ``out_dir``. Joints are 1-based in specs (as on the
arm's labels) and 0-based in arrays. Every model forbids unknown keys, so a typo is an error naming the field.

``robot`` (default ``wam7``) names the arm (:mod:`wamctl.model.robots`): its joint count sets the length of every
joint vector (``q0_rad``, the gains) and the joint numbers a spec may name (1..4 on the ``wam4``: a larger one is
refused naming the field), its limits check the positions, its gains are the controller's defaults. The defaults
that list joints (``q0_rad``, ``rotation.joints``, ``sweep.joints``) are the robot's.
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from wamctl.model import params as P
from wamctl.model.robots import DEFAULT_ROBOT, ROBOTS, get_robot

MAX_JOINTS = max(r.n_joints for r in ROBOTS.values())
# markers the robot check (Common._robot_fits) finds in the annotations: a joint number, a joint vector
_JOINT, _JOINT_VECTOR = "wamctl:joint", "wamctl:joint-vector"
Joint = Annotated[int, Field(ge=1, le=MAX_JOINTS, description="joint number 1..7 (1..4 on the wam4)"), _JOINT]
# one value per joint of the spec's robot (7 on the wam7, 4 on the wam4; checked against the robot)
Vec7 = Annotated[list[float], Field(min_length=1, max_length=MAX_JOINTS), _JOINT_VECTOR]
RobotName = Literal[tuple(ROBOTS)]
# q0_rad when the spec gives none: the elbow bent to 1.57 rad, the rest at zero (the wam7's historic default)
DEFAULT_Q0_RAD = {name: [1.57 if j == 3 else 0.0 for j in range(r.n_joints)] for name, r in ROBOTS.items()}


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=False)


def _marked(annotation, marker: str) -> bool:
    return typing.get_origin(annotation) is Annotated and marker in typing.get_args(annotation)[1:]


def _runtime_type(annotation):
    """The class a value of ``annotation`` is an instance of (``list`` for ``list[float]``), or None."""
    while typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    base = typing.get_origin(annotation) or annotation
    return base if isinstance(base, type) else None


def _robot_problem(value, annotation, path: str, n: int, robot: str) -> str | None:
    """The first joint number above ``n`` or joint vector not of length ``n`` in ``value`` (typed
    ``annotation``), as ``path: why``; None if everything fits the robot."""
    if value is None:
        return None
    if isinstance(value, BaseModel):
        for name, info in type(value).model_fields.items():
            ann = Annotated[(info.annotation, *info.metadata)] if info.metadata else info.annotation
            why = _robot_problem(getattr(value, name), ann, f"{path}.{name}" if path else name, n, robot)
            if why:
                return why
        return None
    if _marked(annotation, _JOINT):
        if isinstance(value, int) and not 1 <= value <= n:
            return f"{path}: joint {value} is not a joint of the {robot} (joints 1..{n})"
        return None
    if _marked(annotation, _JOINT_VECTOR):
        if isinstance(value, list | tuple) and len(value) != n:
            return (f"{path}: List should have {'at least' if len(value) < n else 'at most'} {n} items (one per "
                    f"joint of the {robot}), not {len(value)}")
        return None
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Annotated:
        return _robot_problem(value, args[0], path, n, robot)
    if origin in (typing.Union, types.UnionType):
        for arg in args:
            base = _runtime_type(arg)
            if isinstance(base, type) and isinstance(value, base):
                return _robot_problem(value, arg, path, n, robot)
        return None
    if origin in (list, tuple) and args and isinstance(value, list | tuple):
        for v in value:
            why = _robot_problem(v, args[0], path, n, robot)
            if why:
                return why
    if origin is dict and len(args) == 2 and isinstance(value, dict):
        for k, v in value.items():
            why = _robot_problem(k, args[0], path, n, robot) or _robot_problem(v, args[1], f"{path}.{k}", n, robot)
            if why:
                return why
    return None


# ----------------------------------------------------------------------------------------------- backend
class SimBackendSpec(Strict):
    kind: Literal["sim"] = "sim"
    physics_substeps: int = Field(2, ge=1, le=50, description="physics steps per 2 ms control period")


class SimulatedFault(Strict):
    """A link fault injected when the control loop reaches ``at_cycle`` (simulated pucks only): tests and demos
    of the CAN link watchdog. ``drop_replies``: replies lost with ``probability``; ``silent_puck``: ``puck``
    neither answers nor obeys; ``garbage_replies``: replies replaced by malformed frames with ``probability``;
    ``garbage_frames``: ``count`` malformed frames sent at once; ``stop_answering``: no puck answers;
    ``bus_error``: the host's next ``count`` transmissions fail with ``can.CanError``; ``shift_idle``,
    ``estop``: the operator presses them on the pendant; ``velocity_fault``: the safety module trips VL2."""
    kind: Literal["drop_replies", "silent_puck", "garbage_replies", "garbage_frames", "stop_answering",
                  "bus_error", "shift_idle", "estop", "velocity_fault"]
    at_cycle: int = Field(250, ge=0, description="control cycle (0 = first) at which the fault starts")
    puck: Joint = Field(7, description="silent_puck: the puck (1..7)")
    probability: float = Field(1.0, gt=0.0, le=1.0)
    count: int = Field(1, ge=1, le=1000)


_PENDANT_ITEM = r"(activate|idle|estop|move)@[0-9]+(\.[0-9]*)?|idle@end"
_PENDANT_SCRIPT = rf"^(never|({_PENDANT_ITEM})(,({_PENDANT_ITEM}))*)$"  # wamctl.backends.can.sim.pendant


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
    # the session the safety system expects (issue 14)
    bus_options: dict[str, str | int | float | bool] = Field(
        default_factory=dict, description="further python-can Bus arguments, e.g. {port: 43113} for udp_multicast")
    zeroing_confirmed: bool = Field(False, description="the arm is at its home pose: zero it without asking (--yes)")
    activation_timeout_s: float = Field(60.0, gt=0.0, le=3600.0,
                                        description="wait for Shift-Idle, the start pose and Shift-Activate")
    idle_wait_s: float = Field(10.0, ge=0.0, le=600.0, description="after the run, wait for Shift-Idle")
    # a spec may lower the safety module's limits, never raise them above Barrett's defaults or switch them off
    velocity_limit_m_s: float | None = Field(None, gt=0.0, le=1.0, description="safety module VL2 (VL1 = 0.9 "
                                             "VL2), at most Barrett's 1.0 m/s; default: the module's EEPROM limits")
    torque_limit_Nm: float | None = Field(None, gt=0.0, le=1.92, description="safety module TL2 in motor N m at "
                                          "IPNM 2700 (TL1 = 0.9 TL2), at most Barrett's 5204 units; default: EEPROM")
    simulated_pendant: str = Field("activate@0.2,idle@end", pattern=_PENDANT_SCRIPT,
                                   description="simulate_pucks: the pendant's script, e.g. activate@0.2,idle@end")

    @model_validator(mode="after")
    def _fault_needs_simulation(self):
        if self.simulated_fault is not None and not self.simulate_pucks:
            raise ValueError("simulated_fault needs simulate_pucks: true")
        if self.simulate_pucks and self.interface != "virtual":
            raise ValueError(f"simulate_pucks needs interface: virtual (python-can's in-process bus), not "
                             f"{self.interface!r}: simulated pucks must never answer on a bus with a real arm")
        return self


BackendSpec = Annotated[SimBackendSpec | CanBackendSpec, Field(discriminator="kind")]


# ----------------------------------------------------------------------------------------------- plant
class FrictionInline(Strict):
    joints: dict[Joint, dict[str, float]]


class StribeckEffect(Strict):
    """Friction rising to a breakaway level ``breakaway_ratio * Fc`` at rest, decaying with speed (eq. 2.8)."""
    joints: list[Joint]
    breakaway_ratio: float = Field(1.6, gt=1.0, le=10.0)
    vs_rad_s: float = Field(0.05, gt=0.0, le=5.0)
    delta: float = Field(2.0, gt=0.0, le=5.0)


class RippleHarmonic(Strict):
    """One harmonic above the fundamental of a position ripple."""
    amplitude_Nm: float = Field(ge=0.0, le=20.0)
    phase_rad: float = 0.0


class RippleEffect(Strict):
    """Torque periodic in the joint angle (cogging, cables, gears): ``tau = amplitude sin(2 pi q / period + phase)``
    plus, optionally, its harmonics ``amplitude_h sin(2 pi h q / period + phase_h)``, h = 2, 3, ... in the order of
    ``harmonics`` (none: one sinusoid)."""
    joints: list[Joint]
    amplitude_Nm: float = Field(0.5, gt=0.0, le=20.0)
    period_rad: float = Field(0.2, ge=0.005, le=6.3)
    phase_rad: float = 0.0
    harmonics: list[RippleHarmonic] = Field(default_factory=list, max_length=7)


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


class LinkEntry(Strict):
    """One link's inertial parameters in place of the datasheet's (keys left out keep the datasheet's):
    mass, COM in DH frame i, inertia about the COM (``Ixx, Iyy, Izz, Ixy, Ixz, Iyz``, frame-i axes) and the
    armature (reflected rotor inertia) of the joint that drives it."""
    mass_kg: float | None = Field(None, gt=0.0, le=100.0)
    com_m: Annotated[list[float], Field(min_length=3, max_length=3)] | None = None
    inertia_kg_m2: Annotated[list[float], Field(min_length=6, max_length=6)] | None = None
    armature_kg_m2: float | None = Field(None, ge=0.0, le=10.0)


Links = dict[Joint, LinkEntry]


def link_parameters(links: dict | None, robot=None) -> P.LinkParameters:
    """The datasheet's link parameters of ``robot`` (default the wam7) with a ``links:`` mapping ({joint:
    LinkEntry or dict}) in place.

    Raises ValueError naming ``links.<joint>`` when a link is not a physical body (see
    :meth:`wamctl.model.params.LinkParameters.inconsistent_links`)."""
    name = get_robot(robot).name
    if not links:
        return P.LinkParameters.datasheet(name)
    out = P.LinkParameters.datasheet(name).with_overrides(links)
    bad = [(j, why) for j, why in out.inconsistent_links().items() if int(j) in {int(k) for k in links}]
    if bad:
        j, why = bad[0]
        raise ValueError(f"links.{j}: not a physical body: {why}")
    return out


class PlantSpec(Strict):
    """The simulated arm: its friction (``table_4_1``, ``none``, a friction model file, or inline), the effects
    a real arm has and a declared model may lack, its sensors, and its links (the datasheet's unless ``links``
    says otherwise, e.g. a model file written by ``wamctl identify``)."""
    friction: Literal["table_4_1", "none"] | FrictionInline | str = "table_4_1"
    effects: Effects = Effects()
    sensors: SensorSpec = SensorSpec()
    links: Links | None = Field(None, description="per-link mass, COM, inertia, armature in place of the "
                                                  "datasheet's ({joint: {mass_kg, com_m, inertia_kg_m2, "
                                                  "armature_kg_m2}})")
    _robot: str = PrivateAttr(DEFAULT_ROBOT)     # the spec's robot (set by Common): Plant's default arm

    @field_validator("links")
    @classmethod
    def _physical_links(cls, v):
        if v and max(int(j) for j in v) <= min(r.n_joints for r in ROBOTS.values()):
            link_parameters(v)       # joints every robot has: checked here; the others once the robot is known
        return v


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
    declared_links: Links | str | None = Field(
        None, description="the links the controller's model uses (gravity compensation, feed-forward inertia) "
                          "in place of the datasheet's: a links mapping, or a model file with a links: section "
                          "(e.g. the model.yaml of `wamctl identify`)")
    _robot: str = PrivateAttr(DEFAULT_ROBOT)     # the spec's robot (set by Common): the default gains

    @field_validator("declared_links")
    @classmethod
    def _physical_declared_links(cls, v):
        if isinstance(v, dict) and v and max(int(j) for j in v) <= min(r.n_joints for r in ROBOTS.values()):
            link_parameters(v)
        return v

    @model_validator(mode="after")
    def _check(self):
        if self.kind == "pd_g_ff" and not self.friction_ff:
            raise ValueError("friction_ff is required for kind pd_g_ff (a friction_model.yaml or 'table_4_1')")
        if self.kind != "pid" and self.ki is not None and any(self.ki):
            raise ValueError(f"ki is only used by kind pid, not {self.kind}")
        return self

    def gains(self, robot=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """kp, kd, ki of the spec's robot (``robot``, default the one its spec names): the spec's values, else
        the robot's libbarrett defaults (:mod:`wamctl.model.robots`); ki zero unless ``pid``."""
        r = get_robot(robot if robot is not None else self._robot)
        kp = np.array(self.kp if self.kp is not None else r.kp, float)
        kd = np.array(self.kd if self.kd is not None else r.kd, float)
        if self.kind == "pid":
            ki = np.array(self.ki if self.ki is not None else r.ki, float)
        else:
            ki = np.zeros(r.n_joints)
        return kp, kd, ki


class Common(Strict):
    name: str = Field("run", pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    robot: RobotName = Field(DEFAULT_ROBOT, description="the arm: wam7 (7-DOF, with the wrist) or wam4 "
                                                        "(libbarrett's 4-DOF arm, no wrist)")
    seed: int = Field(0, ge=0, description="every random draw of the run comes from it (numpy needs >= 0)")
    backend: BackendSpec = SimBackendSpec()
    plant: PlantSpec = PlantSpec()
    controller: ControllerSpec = ControllerSpec()
    q0_rad: Vec7 = Field(default_factory=lambda: list(DEFAULT_Q0_RAD[DEFAULT_ROBOT]))
    out_dir: str = "runs"

    @field_validator("q0_rad")
    @classmethod
    def _q0_in_limits(cls, v, info: ValidationInfo):
        robot = info.data.get("robot", DEFAULT_ROBOT)      # validated before q0_rad (field order)
        why = _robot_problem(v, Vec7, "", get_robot(robot).n_joints, robot)
        if why:
            raise ValueError(why.removeprefix(": "))
        check_positions(np.array(v), "", robot)     # pydantic names the field
        return v

    @model_validator(mode="before")
    @classmethod
    def _robot_defaults(cls, data):
        """The defaults that list joints are the robot's: ``q0_rad`` here, a kind's joint lists in
        :meth:`robot_defaults`."""
        if isinstance(data, dict) and data.get("robot", DEFAULT_ROBOT) != DEFAULT_ROBOT \
                and data.get("robot") in ROBOTS:
            data = dict(data)
            n = ROBOTS[data["robot"]].n_joints
            data.setdefault("q0_rad", list(DEFAULT_Q0_RAD[data["robot"]]))
            cls.robot_defaults(data, n)
        return data

    @classmethod
    def robot_defaults(cls, data: dict, n_joints: int) -> None:
        """Fill in place the defaults of a kind that list joints, for an arm of ``n_joints`` (a robot other than
        the wam7); a kind with such defaults overrides it."""

    # the robots a kind runs on: the wam7 unless the kind's spec says more (its experiment, analysis and report
    # take the robot's joint count); another robot is refused naming the field
    SUPPORTED_ROBOTS: ClassVar[tuple[str, ...]] = (DEFAULT_ROBOT,)

    @model_validator(mode="after")
    def _robot_fits(self):
        """The kind runs on the spec's robot; every joint number and joint vector of the spec fits it (refused
        naming the field); the robot is handed to the plant and the controller."""
        if self.robot not in self.SUPPORTED_ROBOTS:
            kind = getattr(self, "kind", type(self).__name__)
            raise ValueError(f"robot: {kind} runs on the {', '.join(self.SUPPORTED_ROBOTS)} only so far, not the "
                             f"{self.robot}")
        r = get_robot(self.robot)
        why = _robot_problem(self, None, "", r.n_joints, r.name)
        if why:
            raise ValueError(why)
        for key, links in (("plant.links", self.plant.links), ("controller.declared_links",
                                                                self.controller.declared_links)):
            if isinstance(links, dict) and links:
                try:
                    link_parameters(links, r)
                except ValueError as exc:
                    raise ValueError(f"{key}: {exc}") from None
        self.plant._robot = r.name
        self.controller._robot = r.name
        return self

    @property
    def n_joints(self) -> int:
        """The joints of the spec's robot."""
        return get_robot(self.robot).n_joints


def check_positions(q: np.ndarray, where: str, robot=None) -> None:
    """Raise ValueError naming the joint (after ``where``, if given) if any position in ``q`` ((n,) or (k, n))
    is outside the joint limits of ``robot`` (default the wam7)."""
    r = get_robot(robot)
    q = np.atleast_2d(q)
    if q.shape[-1] != r.n_joints:
        raise ValueError(f"{where + ': ' if where else ''}{q.shape[-1]} joint values, the {r.name} has "
                         f"{r.n_joints} joints")
    bad = (q < r.q_min_rad) | (q > r.q_max_rad)
    if bad.any():
        row, j = map(int, np.argwhere(bad)[0])
        raise ValueError(f"{where + ': ' if where else ''}joint {j + 1} would reach {q[row, j]:.4f} rad, outside "
                         f"its limits [{r.q_min_rad[j]}, {r.q_max_rad[j]}] rad")


def check_files(spec: Common, base_dir: Path | None, source: str = "spec") -> None:
    """Raise SpecError naming the field when a friction file the spec names (``plant.friction``,
    ``controller.friction_ff``) is missing or unreadable, so that ``validate`` and ``--dry-run`` catch what the
    run would otherwise fail on once started. Paths are relative to ``base_dir`` (the spec's folder)."""
    from wamctl.errors import SpecError, WamctlError
    from wamctl.model.plant import resolve_friction

    for name, value in (("plant.friction", spec.plant.friction), ("controller.friction_ff",
                                                                  spec.controller.friction_ff)):
        if isinstance(value, str) and value not in ("table_4_1", "none"):
            try:
                resolve_friction(value, base_dir, get_robot(getattr(spec, "robot", None)).n_joints)
            except WamctlError as exc:
                raise SpecError(f"{source}: {name}: {exc}") from None
