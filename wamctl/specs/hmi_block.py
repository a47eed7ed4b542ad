"""The ``hmi_block`` spec (thesis chapter 6): the subject, the gaze source, the control strategy, filter and
velocity profile, the spots on the table, the geometry of table, tool and scene camera, and the trial order.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Literal

from pydantic import Field, model_validator

from wamctl.hmi.gaze import NOMINAL_RATE_HZ
from wamctl.hmi.gripper import HAND_CLOSE_S, HAND_OPEN_S
from wamctl.hmi.kinematics import TOOL_OFFSET_M
from wamctl.hmi.scene import GRASP_HEIGHT_M, SCENE_FOCAL_PX, TABLE_Z_M
from wamctl.hmi.strategy import DEFAULT_CUBIC_VMAX_M_S, DEFAULT_DUAL_V1_M_S, DEFAULT_SINGLE_SPEED_M_S, STALL_TIMEOUT_S
from wamctl.specs.common import Common, Strict, Vec7

# ----------------------------------------------------------------------------------------------- defaults
#: Start cross (thesis Figure 6.20: the hand palm down over it at the start of every trial), m.
DEFAULT_START_M = (0.35, 0.0)
#: The eight marked spots (our layout; see the module docstring), m.
DEFAULT_TARGETS_M: dict[str, tuple[float, float]] = {
    "P1": (0.35, 0.10), "P2": (0.24, -0.14), "P3": (0.45, -0.15), "P4": (0.42, 0.05),
    "P5": (0.26, 0.13), "P6": (0.44, 0.17), "P7": (0.35, -0.22), "P8": (0.29, -0.11),
}
#: Box of the grasp centre on the table: clear of the base, inside the palm-down reach where joint 2 can carry the
#: arm (gravity below 95 % of its torque limit at the corners), m.
DEFAULT_WORKSPACE_X_M = (0.20, 0.47)
DEFAULT_WORKSPACE_Y_M = (-0.26, 0.26)
#: The subject's eyes: at the arm's left side (thesis 6.5.1), 0.65 m from the workspace centre line, 0.45 m above
#: the table (seated), looking at the start cross. (x, y) in frame 0, z above the table top.
DEFAULT_EYE_M = (0.35, 0.65, 0.45)

class SubjectSpec(Strict):
    """Who uses the HMI. ``seed``, ``skill`` and ``fatigue_per_min`` are the virtual subject's."""

    id: str = Field("S1", pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = 0
    skill: float = Field(0.8, ge=0.0, le=1.0, description="0 naive .. 1 expert")
    fatigue_per_min: float = Field(0.02, ge=0.0, le=1.0, description="relative growth of noise per minute")
    blink_rate_hz: float = Field(0.25, ge=0.0, le=2.0, description="involuntary blinks when rested")
    end_session_after_trial: int | None = Field(
        None, ge=1, description="virtual subject: after this trial (1-based, block order) it blinks three times "
                                "in a row, which ends the session (a subject who wants to stop)")


class VirtualSourceSpec(Strict):
    kind: Literal["virtual"] = "virtual"


# The gaze stream formats and the ASL Serial Out item types: the decoders live in wamctl.backends.gaze (formats.py,
# asl.py), above this layer; tests/backends/test_gaze_formats.py checks that these lists match theirs.
STREAM_FORMATS = ("asl-serial-out", "ascii-pair", "ascii-timestamped")
ASL_FIELD_TYPES = ("u8", "i8", "u16", "i16", "u32", "i32", "f32")
ASL_STANDARD_FIELDS = ("status:u8", "pupil:i16", "spare:u8", "x:i16", "y:i16")
_ASL_FIELD_RE = re.compile(rf"[A-Za-z_][A-Za-z0-9_]*:(?:{'|'.join(ASL_FIELD_TYPES)})")


class AslOptions(Strict):
    """Options of the ``asl-serial-out`` format (see :mod:`wamctl.backends.gaze.asl`)."""

    fields: list[str] = Field(default_factory=lambda: list(ASL_STANDARD_FIELDS),
                              description="the Serial Out items in order, NAME:TYPE; x and y required; pupil, "
                                          "status, counter have a meaning")
    byte_order: Literal["big", "little"] = Field("big", description="of multi-byte items (the tracker: big)")
    blink: Literal["either", "pupil-zero", "sentinel"] = Field(
        "either", description="pupil-zero: pupil diameter 0 (the tracker's loss code); sentinel: gaze (-2000, -2000) "
                              "(the thesis' relay); either")
    scale: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [1.0, 1.0], description="pixels per tracker unit, x and y")
    offset_px: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(default_factory=lambda: [0.0, 0.0])
    counter_hz: float = Field(30.0, gt=0.0, le=2000.0, description="counts per second of the counter item")

    @model_validator(mode="after")
    def _check(self):
        names = []
        for k, item in enumerate(self.fields):
            if not _ASL_FIELD_RE.fullmatch(item):
                raise ValueError(f"fields[{k}]: {item!r} is not NAME:TYPE with TYPE one of "
                                 f"{', '.join(ASL_FIELD_TYPES)}")
            names.append(item.partition(":")[0])
        for role in ("x", "y"):
            if role not in names:
                raise ValueError(f"fields: no {role!r} item (name the gaze coordinates x and y)")
        if len(set(names)) != len(names):
            raise ValueError("fields: a name appears twice")
        if "counter" in names and not self.fields[names.index("counter")].endswith((":u8", ":u16", ":u32")):
            raise ValueError("fields: the counter must be unsigned (u8, u16 or u32)")
        if self.blink == "pupil-zero" and "pupil" not in names:
            raise ValueError("blink: pupil-zero needs a pupil item in fields")
        return self


class StreamSpec(Strict):
    """How the bytes of a tracker stream are decoded: ``format`` and its options."""

    format: Literal["asl-serial-out", "ascii-pair", "ascii-timestamped"] = Field(
        "asl-serial-out", description="asl-serial-out: the tracker's binary Serial Out; ascii-pair: 'x,y' lines "
                                      "(thesis); ascii-timestamped: 't_ms,x_px,y_px' lines")
    asl: AslOptions | None = Field(None, description="options of asl-serial-out (default: the standard items)")

    @model_validator(mode="after")
    def _asl_only(self):
        if self.asl is not None and self.format != "asl-serial-out":
            raise ValueError(f"asl: options of the asl-serial-out format, but format is {self.format}")
        return self

    def decoder_options(self) -> dict:
        """Keyword arguments of the format's decoder."""
        if self.format != "asl-serial-out":
            return {}
        a = self.asl or AslOptions()
        return {"fields": list(a.fields), "byte_order": a.byte_order, "blink": a.blink, "scale": tuple(a.scale),
                "offset_px": tuple(a.offset_px), "counter_hz": a.counter_hz}


class SerialSourceSpec(StreamSpec):
    kind: Literal["serial"]
    url: str = Field(description="device path or pyserial URL (socket://host:port, loop://, a pty)")
    baudrate: int = Field(57600, gt=0, description="57600: ASL Serial Out")
    bytesize: Literal[5, 6, 7, 8] = 8
    parity: Literal["none", "even", "odd", "mark", "space"] = "none"
    stopbits: Literal[1, 1.5, 2] = 1
    flow_control: Literal["none", "rtscts", "xonxoff", "dsrdtr"] = "none"
    eof_idle_s: float | None = Field(None, gt=0.0, description="end of stream after this long without a byte")
    start_timeout_s: float = Field(30.0, gt=0.0, le=600.0, description="longest wait for the first sample")


class ReplaySourceSpec(Strict):
    kind: Literal["replay"]
    path: str = Field(description="gaze file (CSV t_s,x_px,y_px), relative to the spec's folder")


class RawReplaySourceSpec(StreamSpec):
    """A raw byte capture (``gaze_capture.txt`` of a run, ``gaze-check --capture``) decoded again: in-process with the
    recorded arrival times (``via: direct``), or written at its recorded pace into a pseudo-terminal read as a serial
    port (``via: pty``)."""

    kind: Literal["replay-raw"]
    path: str = Field(description="capture file, relative to the spec's folder")
    via: Literal["direct", "pty"] = "direct"
    realtime: bool = Field(False, description="direct: pace the reads on the wall clock (pty always does)")
    start_timeout_s: float = Field(30.0, gt=0.0, le=600.0, description="longest wait for the first sample")


SourceSpec = Annotated[VirtualSourceSpec | SerialSourceSpec | ReplaySourceSpec | RawReplaySourceSpec,
                       Field(discriminator="kind")]


class FilterSpec(Strict):
    """Gaze filtering: ``ma``/``wma`` on the point (thesis 6.3.1), ``kalman`` on the vector angle (6.4.1)."""

    kind: Literal["none", "ma", "wma", "kalman"]
    window_s: float = Field(0.3, gt=0.0, le=2.0, description="ma/wma window")
    q: float = Field(0.001, gt=0.0, le=1.0, description="kalman process-noise covariance")

    def label(self) -> str:
        if self.kind in ("ma", "wma"):
            return f"{self.kind}{round(self.window_s * 1000)}"
        if self.kind == "kalman":
            return f"kalman{self.q:g}"
        return "none"

    def delay_s(self) -> float:
        """Lag of the filter on a ramp, s (MA: (M-1)/2 samples; WMA: (M-1)/3)."""
        m = max(1, math.floor(self.window_s * NOMINAL_RATE_HZ + 0.5))
        if self.kind == "ma":
            return (m - 1) / 2 / NOMINAL_RATE_HZ
        if self.kind == "wma":
            return (m - 1) / 3 / NOMINAL_RATE_HZ
        return 0.0


class ProfileSpec(Strict):
    """Velocity profile (thesis 6.3.2, 6.4.2); ``speed_m_s`` is the single speed, V1 (dual) or V5 (cubic)."""

    kind: Literal["single", "dual", "cubic"] = "dual"
    speed_m_s: float | None = Field(None, gt=0.0, le=0.25)

    def speed(self) -> float:
        if self.speed_m_s is not None:
            return self.speed_m_s
        return {"single": DEFAULT_SINGLE_SPEED_M_S, "dual": DEFAULT_DUAL_V1_M_S,
                "cubic": DEFAULT_CUBIC_VMAX_M_S}[self.kind]


class WorkspaceSpec(Strict):
    x_m: Annotated[list[float], Field(min_length=2, max_length=2)] = list(DEFAULT_WORKSPACE_X_M)
    y_m: Annotated[list[float], Field(min_length=2, max_length=2)] = list(DEFAULT_WORKSPACE_Y_M)

    @model_validator(mode="after")
    def _increasing(self):
        if not (self.x_m[0] < self.x_m[1] and self.y_m[0] < self.y_m[1]):
            raise ValueError(f"bounds must be [low, high], got x_m {self.x_m}, y_m {self.y_m}")
        return self


class CameraSpec(Strict):
    """The subject's scene camera: ``eye_m`` = (x, y) in frame 0 and the height above the table top; it looks at
    ``look_at_m`` (x, y on the table at the grasp height; default the start cross)."""

    eye_m: Annotated[list[float], Field(min_length=3, max_length=3)] = list(DEFAULT_EYE_M)
    look_at_m: Annotated[list[float], Field(min_length=2, max_length=2)] | None = None
    focal_px: float = Field(SCENE_FOCAL_PX, gt=50.0, le=5000.0)


Point2 = Annotated[list[float], Field(min_length=2, max_length=2)]


class HmiTask(Strict):
    """The ``hmi:`` section of an ``hmi_block`` spec."""

    subject: SubjectSpec = SubjectSpec()
    source: SourceSpec = VirtualSourceSpec()
    strategy: Literal["four", "vector"] = "four"
    filter: FilterSpec | None = Field(None, description="default: ma 0.3 s (four), kalman q 0.001 (vector)")
    profile: ProfileSpec = ProfileSpec()
    condition: str | None = Field(None, pattern=r"^[A-Za-z0-9_.+-]+$",
                                  description="label in the tables; default strategy-filter-profile")
    targets_m: dict[str, Point2] = Field(default_factory=lambda: {k: list(v) for k, v in DEFAULT_TARGETS_M.items()})
    locations: list[str] | None = Field(None, description="spots to use, in order (default all of targets_m)")
    attempts: int = Field(1, ge=1, le=100, description="attempts per spot")
    order: Literal["by_location", "interleaved", "shuffled"] = "by_location"
    timeout_s: float = Field(60.0, gt=0.0, le=900.0)
    hit_radius_m: float = Field(0.03, gt=0.0, le=0.2)
    start_m: Point2 = list(DEFAULT_START_M)
    table_z_m: float = Field(TABLE_Z_M, ge=-1.0, le=0.5, description="table top in frame 0")
    grasp_height_m: float = Field(GRASP_HEIGHT_M, ge=0.0, le=0.4, description="grasp centre above the table")
    tool_offset_m: float = Field(TOOL_OFFSET_M, ge=0.0, le=0.4, description="grasp centre from the flange")
    workspace: WorkspaceSpec = WorkspaceSpec()
    camera: CameraSpec = CameraSpec()
    start_q_rad: Vec7 | None = Field(None, description="seed of the start pose IK (default elbow up)")
    home_q_rad: Vec7 | None = Field(None, description="pose at the end of the session (default the start pose)")
    watchdog_s: float = Field(STALL_TIMEOUT_S, gt=0.0, le=5.0)
    ik_rate_hz: float = Field(100.0, description="IK rate; divides 500 Hz")
    accel_m_s2: float = Field(1.0, gt=0.0, le=10.0, description="acceleration limit of the hand reference")
    joint_speed_rad_s: float = Field(0.5, gt=0.0, le=1.5, description="LSPB moves to start and home")
    gripper_close_s: float = Field(HAND_CLOSE_S, gt=0.0, le=10.0)
    gripper_open_s: float = Field(HAND_OPEN_S, gt=0.0, le=10.0)
    start: Literal["auto", "prompt"] | None = Field(None, description="supervisor start of each trial; default "
                                                                       "prompt for a serial tracker, else auto")
    record_trajectory: bool = True

    @model_validator(mode="after")
    def _check(self):
        f = self.resolved_filter()
        if f.kind == "kalman" and self.strategy != "vector":
            raise ValueError("filter.kind: kalman filters the vector control's angle; use ma, wma or none with the "
                             "four-directional control")
        n = 500.0 / self.ik_rate_hz
        if self.ik_rate_hz <= 0 or abs(n - round(n)) > 1e-9:
            raise ValueError(f"ik_rate_hz: {self.ik_rate_hz} does not divide the 500 Hz control rate "
                             f"(e.g. 50, 100, 125, 250)")
        if not self.targets_m:
            raise ValueError("targets_m: at least one spot")
        for loc in self.locations or []:
            if loc not in self.targets_m:
                raise ValueError(f"locations: {loc!r} is not one of targets_m ({', '.join(self.targets_m)})")
        ws = self.workspace
        for name, (x, y) in [("start_m", self.start_m)] + [(f"targets_m.{k}", v) for k, v in self.targets_m.items()]:
            if not (ws.x_m[0] <= x <= ws.x_m[1] and ws.y_m[0] <= y <= ws.y_m[1]):
                raise ValueError(f"{name}: ({x}, {y}) m is outside the workspace x {ws.x_m}, y {ws.y_m}")
        if self.subject.end_session_after_trial is not None and self.source.kind != "virtual":
            raise ValueError("subject.end_session_after_trial is for the virtual subject only")
        return self

    def resolved_filter(self) -> FilterSpec:
        if self.filter is not None:
            return self.filter
        return FilterSpec(kind="ma", window_s=0.3) if self.strategy == "four" else FilterSpec(kind="kalman", q=0.001)

    def condition_label(self) -> str:
        return self.condition or f"{self.strategy}-{self.resolved_filter().label()}-{self.profile.kind}"

    def start_mode(self) -> str:
        return self.start or ("prompt" if self.source.kind == "serial" else "auto")

    @property
    def z_tool_m(self) -> float:
        return self.table_z_m + self.grasp_height_m


class HmiBlockSpec(Common):
    kind: Literal["hmi_block"]
    hmi: HmiTask = HmiTask()
