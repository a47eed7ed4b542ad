"""A block of gaze-controlled reach-and-grasp trials (thesis 6.3.3, 6.4.3, 6.5; issue 7): ``kind: hmi_block``.

The set-up (thesis 6.1, 6.3.3, Figures 6.18-6.20, 6.27)
-------------------------------------------------------
The WAM stands on a table; the subject, wearing the head-mounted gaze tracker, sits at the arm's left side and
looks at the workspace. The hand starts each trial palm down over the start cross; an object is placed on one of
eight marked spots; the subject steers the hand with the gaze (four-directional or vector control, a velocity
profile) and closes the hand with a voluntary blink. A trial is a **hit** when the hand closes with its grasp
centre within ``hit_radius_m`` of the object before ``timeout_s``; the **execution time** is the time from the
start of the trial to the hand closed on the object (the grasp). The thesis ran 10 attempts per spot with one
subject (Tables 6.2-6.8) and one attempt per spot with nine subjects (Table 6.10).

The eight spots are given in metres on the table plane (frame-0 x forward, y to the arm's left; see
:mod:`wamctl.hmi.arm`). The thesis shows them only in photographs (Figures 6.19 and 6.27), so the default layout
:data:`DEFAULT_TARGETS_M` is ours, chosen to match what the thesis says and measures: all spots inside the
simulated arm's palm-down workspace (within 0.5 m of the shoulder axis, where joint 2 can carry the arm: see
:data:`wamctl.hmi.arm.TABLE_Z_M`) around the start cross at (0.35, 0.00) m; spot 2 near the arm's base, on the far
side from the subject (the thesis notes its view was obstructed by the base); distances from the start ordered as
the thesis' execution times suggest (Tables 6.3, 6.4: P4 and P1 quickest, then P8, P5, then P2, P3, P6, and P7 the
longest):

====  =============  ====================
spot  (x, y) m       distance from start
====  =============  ====================
P1    (0.35, 0.10)   0.10 m, towards the subject
P2    (0.24, -0.14)  0.18 m, by the base, far side
P3    (0.45, -0.15)  0.18 m, far side, away from the base
P4    (0.42, 0.05)   0.09 m
P5    (0.26, 0.13)   0.16 m, near side, by the base
P6    (0.44, 0.17)   0.19 m, near side
P7    (0.35, -0.22)  0.22 m, far side
P8    (0.29, -0.11)  0.13 m
====  =============  ====================

A trial
-------
1. The hand opens and the arm moves (LSPB in joint space) to the start pose: palm down over the start cross, the
   grasp centre ``grasp_height_m`` above the table.
2. The supervisor starts the trial: at once in simulation (``start: auto``), on Enter with a live tracker
   (``start: prompt``, the default for a serial source).
3. The gaze drives the hand (:class:`~wamctl.hmi.arm.HandArm`) until the hand has closed or the time-out. With the
   virtual subject, a :class:`~wamctl.hmi.policy.ReachPolicy` decides where it looks, closed-loop on the
   simulated hand seen through the scene camera.
4. The trial's row is written (``trials.csv``/``.parquet``), with its events (``hmi_events.csv``) and its hand
   trajectory (``trajectory/part-NNNNN.parquet``, one row per gaze sample).

Three voluntary blinks in a row end the session: the arm goes home (LSPB to ``home_q_rad``, by default the start
pose) and no further trial starts; a trial that had not been decided is not recorded. After the last trial the arm
goes home too. An interrupted block (Ctrl-C, a signal, the subject's go-home, a gaze stream that ended) resumes
at the next trial with ``wamctl hmi-session --resume RUN_DIR`` (:func:`resume`). The virtual subject of each
trial is seeded from (subject seed, trial number), so a resumed block runs the same trials as an uninterrupted
one (the arm's state at the start pose may differ by the tracking error); see :func:`trial_seed`.

Time: one clock, the arm's (control ticks of 2 ms since the block started). The virtual subject samples at 30 Hz
on it; a replayed or serial stream is mapped onto it by its first sample (the tracker's ``t_s``), and the
simulation waits for samples that have not arrived yet, never running ahead of the tracker by more than the wall
time elapsed (so a stalled stream stalls in real time and the 200 ms watchdog holds the hand).

Tables of the run directory
---------------------------
``trials``: ``trial, subject, condition, strategy, filter, profile, location, attempt, hit, time_s, outcome
(hit | miss | timeout), error_m, target_x_m, target_y_m, hand_x_m, hand_y_m, t_start_s, n_blinks,
n_voluntary_blinks, n_stalls, path_m, max_tilt_deg, subject_seed``; ``time_s`` is empty for a time-out.
The first six of the thesis columns are those of :data:`wamctl.analysis.hmi_results.TRIAL_COLUMNS`.

``hmi_events``: ``trial, location, attempt, t_s, t_trial_s, kind, detail``; trial 0 is outside trials. Kinds:
gaze events (``blink``, ``voluntary_blink``, ``gripper_close``, ``gripper_open``, ``go_home``), ``command``
(the motion, level or hold changed), arm events (``start``, ``stop``, ``stall``, ``bound``, ``gripper_closing``,
``gripper_closed``, ``gripper_opening``, ``gripper_opened``, ``gripper_ignored``, ``joint_move``,
``joint_move_done``, ``going_home``, ``home_reached``), and ``session_start``, ``stream_start``, ``trial_start``,
``grasp``, ``timeout``, ``end_session_blinks``, ``session_end``.

``trajectory``: one row per gaze sample during trials (``t_s`` arm time, ``gaze_t_s`` the tracker's time of the
sample, NaN for a corrupt line): ``trial, t_s, t_trial_s, gaze_t_s, gaze_x_px, gaze_y_px,
gaze_flags, motion, level, vx_cmd_m_s, vy_cmd_m_s, hold, arm_hold, hand_x_m, hand_y_m, hand_z_m, tilt_deg,
ref_x_m, ref_y_m, gripper`` and ``q_1_rad .. q_7_rad`` (measured). Codes: ``motion`` indexes
:data:`MOTION_CODES`, ``hold`` :data:`HOLD_CODES`, ``arm_hold`` :data:`ARM_HOLD_CODES`.
"""

from __future__ import annotations

import logging
import math
import os
import queue
import sys
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.backends import make_backend
from wamctl.control.trajectory import Reference
from wamctl.errors import BackendError, DataFormatError, SpecError
from wamctl.experiments.common import Plan, make_controller
from wamctl.hmi import arm as A
from wamctl.hmi.gaze import CENTER_X_PX, CENTER_Y_PX, GazeSample, VirtualSubject
from wamctl.hmi.policy import ReachPolicy
from wamctl.hmi.strategy import (
    PROFILES,
    Hold,
    Motion,
)
from wamctl.hmi.strategy import make_controller as make_gaze_controller
from wamctl.model import params as P
from wamctl.runs.store import RunDir, open_run, read_events, utc_now
from wamctl.specs import check_positions
from wamctl.specs.hmi_block import DEFAULT_TARGETS_M, HmiBlockSpec, HmiTask  # noqa: F401

log = logging.getLogger(__name__)

#: Longest wait for the first sample of a serial or replayed stream, s.
STREAM_START_TIMEOUT_S = 30.0
#: Saccade latency and perception before the filters: part of the policy's stopping lead, s.
SUBJECT_LATENCY_S = 0.3

MOTION_CODES: tuple[str, ...] = tuple(m.value for m in Motion)
HOLD_CODES: tuple[str, ...] = tuple(h.value for h in Hold)
ARM_HOLD_CODES: tuple[str, ...] = ("", "stop", "blink", "no_gaze", "stall", "gripper", "not_started", "session_ended")

TRIALS_TABLE = "trials"
EVENTS_FILE = "hmi_events.csv"
TRAJECTORY_TABLE = "trajectory"
TRIAL_TABLE_COLUMNS = ["trial", "subject", "condition", "strategy", "filter", "profile", "location", "attempt", "hit",
                       "time_s", "outcome", "error_m", "target_x_m", "target_y_m", "hand_x_m", "hand_y_m",
                       "t_start_s", "n_blinks", "n_voluntary_blinks", "n_stalls", "path_m", "max_tilt_deg",
                       "subject_seed"]
EVENT_COLUMNS = ["trial", "location", "attempt", "t_s", "t_trial_s", "kind", "detail"]
TRAJECTORY_COLUMNS = (["trial", "t_s", "t_trial_s", "gaze_t_s", "gaze_x_px", "gaze_y_px", "gaze_flags", "motion",
                       "level", "vx_cmd_m_s", "vy_cmd_m_s", "hold", "arm_hold", "hand_x_m", "hand_y_m", "hand_z_m",
                       "tilt_deg", "ref_x_m", "ref_y_m", "gripper"]
                      + [f"q_{j}_rad" for j in range(1, P.N_JOINTS + 1)])


# ----------------------------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class Trial:
    number: int  # 1-based, block order
    location: str
    attempt: int
    xy_m: tuple[float, float]


@dataclass
class HmiPlan(Plan):
    """The plan plus what the block needs: poses, geometry, trials."""

    q_start: np.ndarray = field(default_factory=lambda: np.zeros(P.N_JOINTS))
    q_home: np.ndarray = field(default_factory=lambda: np.zeros(P.N_JOINTS))
    q_targets: dict[str, np.ndarray] = field(default_factory=dict)
    R_ref: np.ndarray = field(default_factory=lambda: np.eye(3))
    camera: A.SceneCamera | None = None
    mapping: A.CommandMapping | None = None
    workspace: A.Workspace | None = None
    trials: list[Trial] = field(default_factory=list)
    condition: str = ""


def make_trials(task: HmiTask, seed: int) -> list[Trial]:
    """The block's trials in order (``order``: by location, interleaved, or shuffled with ``seed``)."""
    locs = task.locations or list(task.targets_m)
    if task.order == "interleaved":
        pairs = [(loc, a) for a in range(1, task.attempts + 1) for loc in locs]
    else:
        pairs = [(loc, a) for loc in locs for a in range(1, task.attempts + 1)]
    if task.order == "shuffled":
        perm = np.random.default_rng(np.random.SeedSequence([seed, 77])).permutation(len(pairs))
        shuffled = [pairs[i][0] for i in perm]
        seen: dict[str, int] = {}
        pairs = []
        for loc in shuffled:
            seen[loc] = seen.get(loc, 0) + 1
            pairs.append((loc, seen[loc]))
    return [Trial(i + 1, loc, a, (float(task.targets_m[loc][0]), float(task.targets_m[loc][1])))
            for i, (loc, a) in enumerate(pairs)]


def trial_seed(subject_seed: int, condition: str, number: int) -> int:
    """Seed of the virtual subject in one trial: from the subject's seed, the condition label and the trial
    number (so a resumed block repeats the same trials, and each condition's session differs)."""
    return int(np.random.SeedSequence([subject_seed, zlib.crc32(condition.encode()), number]).generate_state(1)[0])


def make_camera(task: HmiTask) -> A.SceneCamera:
    eye = task.camera.eye_m
    look = task.camera.look_at_m or task.start_m
    return A.SceneCamera((eye[0], eye[1], task.table_z_m + eye[2]), (look[0], look[1], task.z_tool_m),
                         task.camera.focal_px)


#: Largest gravity torque, as a fraction of the torque limit, at the start and the spots / at the workspace corners.
GRAVITY_BUDGET_SPOTS = 0.85
GRAVITY_BUDGET_CORNERS = 0.95


def _check_gravity(spec: HmiBlockSpec, kin: A.HandKinematics, R_ref: np.ndarray, q_start: np.ndarray,
                   q_targets: dict[str, np.ndarray]) -> None:
    """SpecError when the arm could not hold the hand at a spot or a workspace corner (joint torque limits)."""
    from wamctl.model.dynamics import Payload, WamDynamics
    h = spec.hmi
    load = spec.plant.effects.payload or spec.controller.declared_payload
    dyn = WamDynamics(Payload(load.mass_kg, tuple(load.com_m)) if load else None)
    checks = [("hmi.start_m", q_start, GRAVITY_BUDGET_SPOTS)]
    checks += [(f"hmi.targets_m.{k}", q, GRAVITY_BUDGET_SPOTS) for k, q in q_targets.items()]
    for x in h.workspace.x_m:
        for y in h.workspace.y_m:
            q, ep, _ = kin.solve((x, y, h.z_tool_m), R_ref, q_start)
            if ep > 1e-3:
                raise SpecError(f"hmi.workspace: corner ({x}, {y}) m cannot be reached palm down at "
                                f"{h.z_tool_m:.3f} m")
            checks.append((f"hmi.workspace corner ({x}, {y}) m", q, GRAVITY_BUDGET_CORNERS))
    for where, q, budget in checks:
        ratio = np.abs(dyn.gravity(q)) / P.TAU_MAX_NM
        j = int(np.argmax(ratio))
        if ratio[j] > budget:
            raise SpecError(f"{where}: holding the hand there takes {ratio[j] * P.TAU_MAX_NM[j]:.1f} N m on joint "
                            f"{j + 1} against gravity, over {budget:.0%} of its {P.TAU_MAX_NM[j]:g} N m limit; "
                            f"bring it closer to the arm or raise hmi.table_z_m")


def plan(spec: HmiBlockSpec, base_dir: Path | None = None) -> HmiPlan:
    """Solve the start pose and every spot palm down (reachability), check the view; list the trials."""
    h = spec.hmi
    kin = A.HandKinematics(tool_offset_m=h.tool_offset_m)
    R_ref = A.palm_down_rotation(A.PALM_DOWN_YAW_RAD)
    z = h.z_tool_m
    q_start, ep, eo = kin.solve((h.start_m[0], h.start_m[1], z), R_ref, h.start_q_rad)
    if ep > 1e-3 or eo > 1e-2:
        raise SpecError(f"hmi.start_m: ({h.start_m[0]}, {h.start_m[1]}) m at {z:.3f} m cannot be reached palm down "
                        f"(residual {ep * 1e3:.1f} mm, {math.degrees(eo):.1f} deg)")
    camera = make_camera(h)
    q_targets = {}
    locs = h.locations or list(h.targets_m)
    for loc in locs:
        x, y = h.targets_m[loc]
        q, ep, eo = kin.solve((x, y, z), R_ref, q_start)
        if ep > 1e-3 or eo > 1e-2:
            raise SpecError(f"hmi.targets_m.{loc}: ({x}, {y}) m cannot be reached palm down at {z:.3f} m "
                            f"(residual {ep * 1e3:.1f} mm, {math.degrees(eo):.1f} deg)")
        if not camera.in_image((x, y, z)):
            raise SpecError(f"hmi.targets_m.{loc}: ({x}, {y}) m is outside the subject's scene image; move the spot "
                            f"or hmi.camera")
        q_targets[loc] = q
    _check_gravity(spec, kin, R_ref, q_start, q_targets)
    q_home = np.asarray(h.home_q_rad, float) if h.home_q_rad is not None else q_start.copy()
    try:
        check_positions(q_home, "hmi.home_q_rad")
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    trials = make_trials(h, h.subject.seed)
    rows = [np.asarray(spec.q0_rad, float), q_start, *q_targets.values(), q_home]
    labels = ["q0", "start"] + [f"spot {k}" for k in q_targets] + ["home"]
    q = np.array(rows)
    ref = Reference(np.arange(len(q)) / P.CONTROL_RATE_HZ, q, np.zeros_like(q), np.zeros_like(q),
                    [(i, lab) for i, lab in enumerate(labels)])
    mapping = camera.mapping()
    f = h.resolved_filter()
    profile = PROFILES[h.profile.kind](h.profile.speed())
    dist = {loc: math.dist(h.targets_m[loc], h.start_m) for loc in locs}
    summary = [
        f"hmi block: subject {h.subject.id} ({h.source.kind} source"
        + (f", seed {h.subject.seed}, skill {h.subject.skill}, fatigue {h.subject.fatigue_per_min}/min"
           if h.source.kind == "virtual" else "") + ")",
        f"condition {h.condition_label()}: {h.strategy} control, filter {f.label()}, {profile.name} profile "
        f"({', '.join(f'{v:.3f}' for v in profile.speeds_m_s)} m/s)",
        f"{len(trials)} trials ({len(locs)} spots x {h.attempts} attempts, {h.order}), time-out {h.timeout_s:g} s, "
        f"hit radius {h.hit_radius_m * 1e3:.0f} mm, supervisor start: {h.start_mode()}",
        f"start cross ({h.start_m[0]:.3f}, {h.start_m[1]:.3f}) m, grasp centre at z0 = {z:.3f} m "
        f"({h.grasp_height_m:.3f} m above the table), workspace x {h.workspace.x_m}, y {h.workspace.y_m} m",
        f"image right -> table ({mapping.right_xy[0]:+.2f}, {mapping.right_xy[1]:+.2f}), image up -> table "
        f"({mapping.forward_xy[0]:+.2f}, {mapping.forward_xy[1]:+.2f})",
        f"start pose q = [{', '.join(f'{v:.3f}' for v in q_start)}] rad",
    ]
    summary += [f"  {loc}: ({h.targets_m[loc][0]:.3f}, {h.targets_m[loc][1]:.3f}) m, {dist[loc]:.3f} m from the "
                f"start, reachable palm down" for loc in locs]
    return HmiPlan(ref, summary, None, q_start=q_start, q_home=q_home, q_targets=q_targets, R_ref=R_ref,
                   camera=camera, mapping=mapping,
                   workspace=A.Workspace(tuple(h.workspace.x_m), tuple(h.workspace.y_m)), trials=trials,
                   condition=h.condition_label())


# ----------------------------------------------------------------------------------------------- gaze feeds
class VirtualFeed:
    """Samples of the current trial's virtual subject (none between trials), on the arm clock."""

    exhausted = False
    started = True
    offset_s = 0.0

    def __init__(self) -> None:
        self._subject: VirtualSubject | None = None
        self._ahead: GazeSample | None = None

    @property
    def subject(self) -> VirtualSubject | None:
        return self._subject

    @subject.setter
    def subject(self, subject: VirtualSubject | None) -> None:
        self._subject = subject
        self._ahead = None

    def next_due(self, t_s: float) -> GazeSample | None:
        if self._subject is None:
            return None
        if self._ahead is None:
            self._ahead = self._subject.read()
        s = self._ahead
        if s is not None and s.t_s <= t_s:
            self._ahead = None
            return s
        return None

    def close(self) -> None:
        pass


_END = object()


class StreamFeed:
    """A recorded or live gaze stream on the arm clock.

    The first timed sample is due when it is first looked for; later ones at their tracker-time offset from it.
    A live source is read in a thread; when its next sample has not arrived yet, :meth:`next_due` waits for it as
    long as the arm clock is ahead of the last sample's time plus the wall time since it arrived (so the
    simulation follows the tracker and a silent tracker stalls in real time).
    """

    def __init__(self, source, *, live: bool, clock: Callable[[], float] = time.monotonic) -> None:
        self.source = source
        self.live = live
        self.clock = clock
        self._ahead: GazeSample | None = None
        self._offset_s: float | None = None
        self._last_t_s: float | None = None
        self._last_wall_s = clock()
        self._ended = False
        self._queue: queue.Queue | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if live:
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=self._reader, name="gaze-reader", daemon=True)
            self._thread.start()

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                s = self.source.read(0.05)
                if s is not None:
                    self._queue.put(s)
                elif self.source.exhausted:
                    break
        except Exception as exc:  # noqa: BLE001 - reported through the queue's end
            log.error("gaze reader stopped: %s", exc)
        finally:
            self._queue.put(_END)

    @property
    def exhausted(self) -> bool:
        return self._ended and self._ahead is None

    @property
    def started(self) -> bool:
        """True once the first timed sample has been seen (it sets the stream's time offset)."""
        return self._offset_s is not None

    @property
    def offset_s(self) -> float:
        """Tracker time minus arm time, s (0 before the first sample)."""
        return self._offset_s or 0.0

    def _read(self, t_s: float) -> GazeSample | None:
        if self._ended:
            return None
        if not self.live:
            s = self.source.read(0.0)
            if s is None and self.source.exhausted:
                self._ended = True
            return s
        try:
            item = self._queue.get_nowait()
        except queue.Empty:
            if self._last_t_s is None:
                wait = 0.02
            else:
                wait = t_s - (self._last_t_s + self.clock() - self._last_wall_s)
            if wait <= 0.0:
                return None
            try:
                item = self._queue.get(timeout=min(wait, 0.5))
            except queue.Empty:
                return None
        if item is _END:
            self._ended = True
            return None
        return item

    def next_due(self, t_s: float) -> GazeSample | None:
        if self._ahead is None:
            self._ahead = self._read(t_s)
            if self._ahead is None:
                return None
        s = self._ahead
        if not s.has_time:
            self._ahead = None
            return s
        if self._offset_s is None:
            self._offset_s = s.t_s - t_s
        if s.t_s - self._offset_s <= t_s:
            self._ahead = None
            self._last_t_s = s.t_s - self._offset_s
            self._last_wall_s = self.clock()
            return s
        return None

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.source.close()


# ----------------------------------------------------------------------------------------------- supervisor
def _stdin_prompt(message: str) -> None:
    log.warning("%s", message)
    sys.stdin.readline()


#: How a ``prompt`` start asks the supervisor: called in a thread with the message, returns when started. The
#: CLI installs its own (a console prompt) with :func:`set_supervisor_prompt`.
_PROMPT: list[Callable[[str], None]] = [_stdin_prompt]


def set_supervisor_prompt(prompt: Callable[[str], None]) -> None:
    """Install the function a ``start: prompt`` block calls (in a thread) and waits for before each trial."""
    _PROMPT[0] = prompt


class Supervisor:
    """The supervisor's start: immediate (``auto``) or a prompt answered while the arm keeps holding."""

    def __init__(self, mode: str) -> None:
        self.mode = mode
        self._done = threading.Event()

    def request(self, message: str) -> None:
        self._done.clear()
        if self.mode == "auto":
            self._done.set()
            return
        prompt = _PROMPT[0]

        def wait() -> None:
            try:
                prompt(message)
            finally:
                self._done.set()

        threading.Thread(target=wait, name="supervisor", daemon=True).start()

    def ready(self) -> bool:
        return self._done.is_set()


# ----------------------------------------------------------------------------------------------- the block
class _SessionEnded(Exception):
    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


class HmiBlock:
    """Runs (or resumes) the trials of one block in a run directory."""

    def __init__(self, spec: HmiBlockSpec, plan: HmiPlan, run: RunDir, progress=None,
                 base_dir: Path | None = None) -> None:
        self.spec = spec
        self.h = spec.hmi
        self.plan = plan
        self.run = run
        self.progress = progress
        self.base_dir = Path(base_dir) if base_dir is not None else None
        self.trial_rows: list[dict] = []
        self.event_rows: list[dict] = []
        self._trial: Trial | None = None
        self._t0_s = math.nan
        self._traj: list[list[float]] = []
        self._last_key = None
        self._counts = {"blink": 0, "voluntary_blink": 0, "stall": 0}
        self.session_end = ""

    # -- persistence ------------------------------------------------------------------------------

    def load_existing(self) -> set[int]:
        """Trials already in the run directory (resume); events of unfinished trials are dropped."""
        path = self.run.path
        if (path / f"{TRIALS_TABLE}.csv").is_file():
            df = pd.read_csv(path / f"{TRIALS_TABLE}.csv")
            missing = [c for c in TRIAL_TABLE_COLUMNS if c not in df.columns]
            if missing:
                raise DataFormatError(f"{path / (TRIALS_TABLE + '.csv')}: missing column(s) {missing}")
            self.trial_rows = df[TRIAL_TABLE_COLUMNS].to_dict("records")
        done = {int(r["trial"]) for r in self.trial_rows}
        if (path / EVENTS_FILE).is_file():
            ev = pd.read_csv(path / EVENTS_FILE, keep_default_na=False, na_values={"t_trial_s": [""]})
            keep = ev["trial"].isin(list(done) + [0])
            self.event_rows = ev[keep].to_dict("records")
        return done

    def _atomic_csv(self, df: pd.DataFrame, name: str) -> None:
        tmp = self.run.path / f".{name}.tmp"
        df.to_csv(tmp, index=False)
        os.replace(tmp, self.run.path / name)

    def write_tables(self) -> None:
        trials = pd.DataFrame(self.trial_rows, columns=TRIAL_TABLE_COLUMNS).sort_values("trial")
        self._atomic_csv(trials, f"{TRIALS_TABLE}.csv")
        tmp = self.run.path / f".{TRIALS_TABLE}.parquet.tmp"
        trials.to_parquet(tmp, index=False)
        os.replace(tmp, self.run.path / f"{TRIALS_TABLE}.parquet")
        self._atomic_csv(pd.DataFrame(self.event_rows, columns=EVENT_COLUMNS), EVENTS_FILE)

    def _write_trajectory_part(self, number: int) -> None:
        if not self.h.record_trajectory:
            return
        d = self.run.path / TRAJECTORY_TABLE
        d.mkdir(exist_ok=True)
        df = pd.DataFrame(np.array(self._traj, float).reshape(-1, len(TRAJECTORY_COLUMNS)), columns=TRAJECTORY_COLUMNS)
        tmp = d / f".part-{number:05d}.parquet.tmp"
        df.to_parquet(tmp, index=False)
        os.replace(tmp, d / f"part-{number:05d}.parquet")

    def consolidate_trajectory(self) -> None:
        d = self.run.path / TRAJECTORY_TABLE
        parts = sorted(d.glob("part-*.parquet")) if d.is_dir() else []
        if not parts:
            return
        df = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
        df.to_parquet(self.run.path / f"{TRAJECTORY_TABLE}.parquet", index=False)
        df.to_csv(self.run.path / f"{TRAJECTORY_TABLE}.csv", index=False)

    # -- events -----------------------------------------------------------------------------------

    def _event(self, kind: str, detail: str = "", t_s: float | None = None) -> None:
        t = self.arm.t_s if t_s is None else t_s
        tr = self._trial
        self.event_rows.append({"trial": tr.number if tr else 0, "location": tr.location if tr else "",
                                "attempt": tr.attempt if tr else 0, "t_s": round(t, 6),
                                "t_trial_s": round(t - self._t0_s, 6) if tr else math.nan,
                                "kind": kind, "detail": detail})

    def _drain_arm_events(self) -> None:
        for ev in self.arm.drain_events():
            if ev.kind == "stall":
                self._counts["stall"] += 1
            self._event(ev.kind, ev.detail, ev.t_s)

    # -- the loop ---------------------------------------------------------------------------------

    def _on_sample(self, s: GazeSample) -> None:
        cmd = self.gaze.update(s)
        self.arm.apply(cmd, fresh=s.is_valid or s.is_blink)
        for ev in cmd.events:
            kind = ev.kind.value
            if kind in self._counts:
                self._counts[kind] += 1
            self._event(kind, "" if ev.duration_s is None else f"{ev.duration_s:.3f} s", ev.t_s - self._offset())
        key = (cmd.motion, cmd.level, cmd.hold)
        if key != self._last_key:
            self._last_key = key
            text = cmd.motion.value + (f" level {cmd.level}" if cmd.level else "")
            self._event("command", text if cmd.hold is Hold.NONE else f"hold: {cmd.hold.value}")
        if self._trial is not None and self.h.record_trajectory:
            self._record(s, cmd)

    def _offset(self) -> float:
        """Tracker time minus arm time of the stream (0 for the virtual subject)."""
        return self.feed.offset_s

    def _record(self, s: GazeSample, cmd) -> None:
        arm = self.arm
        p, R = arm.hand_pose()
        hold = arm.hold_reason
        self._traj.append([
            self._trial.number, arm.t_s, arm.t_s - self._t0_s, s.t_s, s.x_px, s.y_px,
            int(s.flags), MOTION_CODES.index(cmd.motion.value), cmd.level, cmd.vx_m_s, cmd.vy_m_s,
            HOLD_CODES.index(cmd.hold.value), ARM_HOLD_CODES.index(hold) if hold in ARM_HOLD_CODES else -1,
            p[0], p[1], p[2], math.degrees(A.tilt_rad(R)), arm.p_ref[0], arm.p_ref[1], arm.gripper.closure,
            *arm.q_meas])

    def _step(self) -> None:
        arm, feed = self.arm, self.feed
        arm.tick()
        while (s := feed.next_due(arm.t_s)) is not None:
            self._on_sample(s)
        if arm.events:
            self._drain_arm_events()

    def _tick_until(self, done: Callable[[], bool], limit_s: float, *, pace: bool = False,
                    need_stream: bool = True) -> bool:
        """Step until ``done()`` or ``limit_s`` of arm time (False); raise _SessionEnded when the stream ends
        (if ``need_stream``). ``pace``: keep a simulated arm at the wall clock (waiting for a person)."""
        arm = self.arm
        t_end = arm.t_s + limit_s
        wall0, t0 = time.monotonic(), arm.t_s
        while not done():
            if arm.t_s >= t_end:
                return False
            self._step()
            if pace and self.simulated:
                ahead = (arm.t_s - t0) - (time.monotonic() - wall0)
                if ahead > 0.005:
                    time.sleep(ahead)
            if need_stream and self.feed.exhausted and not done():
                raise _SessionEnded("the gaze stream ended")
        return True

    # -- session ----------------------------------------------------------------------------------

    def execute(self) -> None:
        spec, h, plan = self.spec, self.h, self.plan
        done = self.load_existing()
        todo = [t for t in plan.trials if t.number not in done]
        self.run.update_manifest(hmi={
            "subject": h.subject.id, "condition": plan.condition, "strategy": h.strategy,
            "filter": h.resolved_filter().label(), "profile": h.profile.kind, "source": h.source.kind,
            "trials_planned": len(plan.trials), "trials_done": len(done),
            "base_dir": str(self.base_dir) if self.base_dir else None,
            "codes": {"motion": list(MOTION_CODES), "hold": list(HOLD_CODES), "arm_hold": list(ARM_HOLD_CODES)}})
        if not todo:
            log.info("every trial of %s is done", self.run.path)
            return
        controller_spec = spec.controller
        ff = np.zeros((1, P.N_JOINTS)) if controller_spec.kind == "pd_g_ff" else None
        friction_ff = None
        if ff is not None:
            from wamctl.model.plant import resolve_friction
            friction_ff = resolve_friction(controller_spec.friction_ff, self.base_dir)
        self.feed = self._open_feed()
        try:
            with make_backend(spec, self.base_dir) as backend:
                self.run.update_manifest(backend=backend.describe())
                self.simulated = backend.name == "sim"
                f = h.resolved_filter()
                self.gaze = make_gaze_controller(
                    strategy=h.strategy, profile=h.profile.kind, speed_m_s=h.profile.speed(),
                    point_filter=f.kind if f.kind in ("ma", "wma") else None, window_s=f.window_s,
                    kalman_q=f.q if f.kind == "kalman" else None, stall_timeout_s=h.watchdog_s)
                self.arm = A.HandArm(
                    backend, make_controller(spec, ff), A.HandKinematics(tool_offset_m=h.tool_offset_m),
                    workspace=plan.workspace, mapping=plan.mapping, z_tool_m=h.z_tool_m, R_ref=plan.R_ref,
                    q_rest=plan.q_start, home_q_rad=plan.q_home, ik_rate_hz=h.ik_rate_hz, watchdog_s=h.watchdog_s,
                    accel_m_s2=h.accel_m_s2, joint_speed_rad_s=h.joint_speed_rad_s,
                    gripper=A.BarrettHandSim(close_time_s=h.gripper_close_s, open_time_s=h.gripper_open_s),
                    friction_ff=friction_ff, ff_buffer=ff)
                self.supervisor = Supervisor(h.start_mode())
                self._event("session_start", f"{len(todo)} of {len(plan.trials)} trials to run")
                try:
                    self._wait_for_stream()
                    for k, trial in enumerate(todo):
                        if self.progress is not None:
                            self.progress(len(done) + k, len(plan.trials), f"trial {trial.number} {trial.location}")
                        self._run_trial(trial)
                        if h.subject.end_session_after_trial == trial.number:
                            self._subject_ends_session()
                    self.session_end = "completed"
                    self._go_home()
                except _SessionEnded as exc:
                    self.session_end = exc.why
                    self._trial = None
                    self._event("session_end", exc.why)
                    self._go_home()
                if self.progress is not None:
                    self.progress(len(self.trial_rows), len(plan.trials))
        finally:
            self.feed.close()
            self._trial = None
            self.write_tables()
            self.consolidate_trajectory()
            self.run.update_manifest(hmi={**self.run.manifest().get("hmi", {}), "trials_done": len(self.trial_rows),
                                          "session_end": self.session_end or "interrupted"})
            if self.session_end not in ("", "completed"):
                self.run.event(self.arm.t_s if hasattr(self, "arm") else 0.0, "session_end", None, self.session_end)

    def _open_feed(self):
        src = self.h.source
        if src.kind == "virtual":
            return VirtualFeed()
        if src.kind == "replay":
            from wamctl.hmi.gaze import ReplayGazeSource
            path = Path(src.path)
            if not path.is_absolute() and self.base_dir is not None and not path.exists():
                path = self.base_dir / path
            return StreamFeed(ReplayGazeSource.from_csv(path), live=False)
        from wamctl.hmi.gaze import SerialGazeSource
        return StreamFeed(SerialGazeSource(src.url, baudrate=src.baudrate, eof_idle_s=src.eof_idle_s), live=True)

    def _wait_for_stream(self) -> None:
        """Hold until the gaze stream delivers its first sample (a recorded one at once)."""
        if self.feed.started:
            return
        if not self._tick_until(lambda: self.feed.started, STREAM_START_TIMEOUT_S, pace=True):
            raise BackendError(f"no gaze sample from {self.h.source.kind} source within {STREAM_START_TIMEOUT_S:g} s "
                               f"(is the tracker streaming?)")
        self._event("stream_start", f"first gaze sample at tracker time {self.feed.offset_s:.3f} s")

    def _go_home(self) -> None:
        self._trial = None
        if not self.arm.ended:
            self.arm.go_home()
        self._tick_until(lambda: not self.arm.busy, 120.0, need_stream=False)
        self._drain_arm_events()

    def _subject_ends_session(self) -> None:
        """The virtual subject blinks three times in a row: the session ends (issue 7)."""
        t = self.arm.t_s
        subject = VirtualSubject(lambda _t: (CENTER_X_PX, CENTER_Y_PX), seed=self.h.subject.seed + 999983,
                                 skill=self.h.subject.skill, blink_rate_hz=0.0, t0_s=t)
        for k in range(3):
            subject.request_voluntary_blink(duration_s=1.0, at_s=t + 0.5 + 1.6 * k)
        self.feed.subject = subject
        self._event("end_session_blinks", "three voluntary blinks in a row")
        self._tick_until(lambda: self.arm.ended and not self.arm.busy, 20.0, need_stream=False)
        self.feed.subject = None
        if self.arm.ended:
            raise _SessionEnded("go_home")

    def _run_trial(self, trial: Trial) -> None:
        arm, h = self.arm, self.h
        # 1. hand open, arm to the start pose
        self._trial = None
        arm.stop()
        if not arm.gripper.is_open:
            arm.open_hand()
        self._tick_until(lambda: not arm.gripper.moving, 10.0)
        arm.move_to_joints(self.plan.q_start, f"start for trial {trial.number}")
        self._tick_until(lambda: not arm.busy, 120.0)
        if arm.ended:
            raise _SessionEnded("go_home")
        # 2. supervisor
        x, y = trial.xy_m
        self.supervisor.request(f"trial {trial.number}/{len(self.plan.trials)}: object at {trial.location} "
                                f"({x:.3f}, {y:.3f}) m; press Enter to start")
        self._tick_until(self.supervisor.ready, 1e9, pace=True)
        # 3. the trial
        self._trial = trial
        self._t0_s = t0 = arm.t_s
        self._traj = []
        self._counts = {"blink": 0, "voluntary_blink": 0, "stall": 0}
        self.gaze.gripper_closed = False  # the arm side owns the hand: it is open now
        if h.source.kind == "virtual":  # the subject's tracker starts with the trial: no stall before its first sample
            self.gaze.watchdog.feed(t0)
        seed = trial_seed(h.subject.seed, self.plan.condition, trial.number)
        if h.source.kind == "virtual":
            rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
            f = h.resolved_filter()
            policy = ReachPolicy(lambda: tuple(self.arm.hand_pose()[0][:2]), trial.xy_m, z_m=h.z_tool_m,
                                 camera=self.plan.camera, mapping=self.plan.mapping, strategy=h.strategy,
                                 profile=self.gaze.strategy.profile, skill=h.subject.skill,
                                 lag_s=SUBJECT_LATENCY_S + f.delay_s(), rng=rng, t0_s=t0)
            subject = VirtualSubject(policy, seed=seed, skill=h.subject.skill,
                                     fatigue_per_min=h.subject.fatigue_per_min, blink_rate_hz=h.subject.blink_rate_hz,
                                     t0_s=t0, session_start_s=0.0)
            policy.request_blink = subject.request_voluntary_blink
            self.feed.subject = subject
        self._event("trial_start", f"{trial.location} attempt {trial.attempt}, object at ({x:.3f}, {y:.3f}) m")
        arm.start()
        closing = lambda: arm.gripper.target == 1.0 and not arm.gripper.is_closed  # noqa: E731
        outcome = ""
        while True:
            self._step()
            if arm.ended:
                raise _SessionEnded("go_home")
            if arm.gripper.is_closed:
                outcome = "grasp"
                break
            if arm.t_s - t0 >= h.timeout_s and not closing():
                outcome = "timeout"
                break
            if self.feed.exhausted and not closing():
                raise _SessionEnded("the gaze stream ended")
        t_end = arm.t_s
        p, _ = arm.hand_pose()
        err = math.hypot(p[0] - x, p[1] - y)
        hit = outcome == "grasp" and err <= h.hit_radius_m
        if outcome == "grasp":
            self._event("grasp", f"{'hit' if hit else 'miss'}: grasp centre {err * 1e3:.1f} mm from the object")
        else:
            self._event("timeout", f"no grasp within {h.timeout_s:g} s")
        arm.stop()
        self._drain_arm_events()
        if h.source.kind == "virtual":
            self.feed.subject = None
        traj = np.array(self._traj, float).reshape(-1, len(TRAJECTORY_COLUMNS))
        hx, hy = traj[:, TRAJECTORY_COLUMNS.index("hand_x_m")], traj[:, TRAJECTORY_COLUMNS.index("hand_y_m")]
        path = float(np.sum(np.hypot(np.diff(hx), np.diff(hy)))) if len(traj) > 1 else 0.0
        tilt = float(np.max(traj[:, TRAJECTORY_COLUMNS.index("tilt_deg")])) if len(traj) else math.nan
        f = h.resolved_filter()
        self.trial_rows.append({
            "trial": trial.number, "subject": h.subject.id, "condition": self.plan.condition, "strategy": h.strategy,
            "filter": f.label(), "profile": h.profile.kind, "location": trial.location, "attempt": trial.attempt,
            "hit": int(hit), "time_s": round(t_end - t0, 4) if outcome == "grasp" else math.nan,
            "outcome": ("hit" if hit else "miss") if outcome == "grasp" else "timeout", "error_m": round(err, 5),
            "target_x_m": x, "target_y_m": y, "hand_x_m": round(float(p[0]), 5), "hand_y_m": round(float(p[1]), 5),
            "t_start_s": round(t0, 4), "n_blinks": self._counts["blink"] + self._counts["voluntary_blink"],
            "n_voluntary_blinks": self._counts["voluntary_blink"], "n_stalls": self._counts["stall"],
            "path_m": round(path, 4), "max_tilt_deg": round(tilt, 4),
            "subject_seed": seed if h.source.kind == "virtual" else -1})
        self._write_trajectory_part(trial.number)
        self._trial = None
        self.write_tables()
        self.run.update_manifest(hmi={**self.run.manifest().get("hmi", {}), "trials_done": len(self.trial_rows)})
        log.info("trial %d %s: %s in %.1f s (%.1f mm)", trial.number, trial.location,
                 self.trial_rows[-1]["outcome"], t_end - t0, err * 1e3)


# ----------------------------------------------------------------------------------------------- runner API
def execute(spec: HmiBlockSpec, plan: HmiPlan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    HmiBlock(spec, plan, run, progress, base_dir).execute()


def resume(run_path: str | Path, spec: HmiBlockSpec | None = None, progress=None):
    """Continue an interrupted block in ``run_path`` at its next trial.

    ``spec``, if given, must have the same ``hmi`` section as the run's ``spec.yaml``. Returns a
    :class:`wamctl.experiments.runner.RunOutcome`; raises ``RunInterrupted`` if interrupted again.
    """
    from wamctl.experiments.runner import record_outcome
    from wamctl.specs import parse_spec

    run_path = Path(run_path)
    manifest, stored = open_run(run_path)
    if manifest.get("kind") != "hmi_block":
        raise SpecError(f"{run_path}: --resume needs an hmi_block run directory, not a {manifest.get('kind')!r} run")
    run_spec = parse_spec(stored, str(run_path / "spec.yaml"))
    if spec is not None and spec.hmi.model_dump(mode="json") != run_spec.hmi.model_dump(mode="json"):
        raise SpecError(f"{run_path}: the spec's hmi section differs from the run's spec.yaml; resume with the same "
                        f"spec (or without one)")
    base = (manifest.get("hmi") or {}).get("base_dir")
    base_dir = Path(base) if base else None
    p = plan(run_spec, base_dir)
    p.check_limits()
    run = RunDir(run_path)
    for r in read_events(run_path).itertuples():
        run.event(float(r.t_s), str(r.kind), None if pd.isna(r.joint) else int(r.joint),
                  "" if pd.isna(r.detail) else str(r.detail))
    run.event(0.0, "resumed", None, f"previous status {manifest.get('status')}")
    run.update_manifest(status="running", reason=None, end_utc=None,
                        resumed=list(manifest.get("resumed") or []) + [utc_now()])
    return record_outcome(run, lambda: execute(run_spec, p, run, progress, base_dir), resume_hint=True)
