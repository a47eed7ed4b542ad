"""The driver of a block: the arm and the gaze controller on one clock, the session (stream start, trials, the
subject's go-home), and each trial from the start pose to its row in ``trials``."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from wamctl.backends import make_backend
from wamctl.backends.gaze.virtual import VirtualSubject
from wamctl.errors import BackendError
from wamctl.experiments.common import make_joint_controller
from wamctl.experiments.hmi_block.feeds import open_feed
from wamctl.experiments.hmi_block.planning import HmiPlan, Trial, trial_seed
from wamctl.experiments.hmi_block.supervisor import Supervisor
from wamctl.experiments.hmi_block.tables import (
    ARM_HOLD_CODES,
    HOLD_CODES,
    MOTION_CODES,
    TRAJECTORY_COLUMNS,
    consolidate_trajectory,
    read_done,
    write_tables,
    write_trajectory_part,
)
from wamctl.hmi.arm import HandArm
from wamctl.hmi.gaze import CENTER_X_PX, CENTER_Y_PX, GazeSample
from wamctl.hmi.gripper import BarrettHandSim
from wamctl.hmi.kinematics import HandKinematics, tilt_rad
from wamctl.hmi.policy import ReachPolicy
from wamctl.hmi.strategy import Hold, make_gaze_controller
from wamctl.model import params as P
from wamctl.runs.store import RunDir
from wamctl.specs.hmi_block import HmiBlockSpec

log = logging.getLogger(__name__)

#: Saccade latency and perception before the filters: part of the policy's stopping lead, s.
SUBJECT_LATENCY_S = 0.3


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
        self.trial_rows, self.event_rows = read_done(self.run.path)
        return {int(r["trial"]) for r in self.trial_rows}

    def write_tables(self) -> None:
        write_tables(self.run.path, self.trial_rows, self.event_rows)

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
            p[0], p[1], p[2], math.degrees(tilt_rad(R)), arm.p_ref[0], arm.p_ref[1], arm.gripper.closure,
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
        h, plan = self.h, self.plan
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
        ff, friction_ff = self._friction_feedforward()
        self.feed = open_feed(h, self.base_dir, self.run.path)
        try:
            self.gaze = self._make_gaze()
            controller = make_joint_controller(self.spec, ff)  # built before the arm is live (no heartbeat gap)
            with make_backend(self.spec, self.base_dir) as backend:
                try:
                    self.simulated = backend.name == "sim"
                    self.feed.hold_arm_clock = self.simulated  # a simulated arm waits for samples still in transit
                    self.arm = self._make_arm(backend, controller, ff, friction_ff)
                    self.supervisor = Supervisor(h.start_mode())
                    self._event("session_start", f"{len(todo)} of {len(plan.trials)} trials to run")
                    self._session(todo, len(done))
                finally:  # after the session: the CAN backend's loop statistics are final then
                    self.run.update_manifest(backend=backend.describe())
        finally:
            self.feed.close()
            self._trial = None
            self.write_tables()
            consolidate_trajectory(self.run.path, complete=len(self.trial_rows) == len(self.plan.trials))
            self.run.update_manifest(hmi={**self.run.manifest().get("hmi", {}), "trials_done": len(self.trial_rows),
                                          "session_end": self.session_end or "interrupted"})
            if self.session_end not in ("", "completed"):
                self.run.event(self.arm.t_s if hasattr(self, "arm") else 0.0, "session_end", None, self.session_end)

    def _session(self, todo: list[Trial], n_done: int) -> None:
        """The trials still to run, then home; a session the subject or the stream ended goes home too."""
        h, plan = self.h, self.plan
        try:
            self._wait_for_stream()
            for k, trial in enumerate(todo):
                if self.progress is not None:
                    self.progress(n_done + k, len(plan.trials), f"trial {trial.number} {trial.location}")
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

    def _friction_feedforward(self):
        """(feed-forward buffer, friction model) for a ``pd_g_ff`` controller, else (None, None): the arm writes
        the friction of its IK reference velocity into the controller's one-row buffer at each IK step."""
        controller_spec = self.spec.controller
        if controller_spec.kind != "pd_g_ff":
            return None, None
        from wamctl.model.plant import resolve_friction
        return np.zeros((1, P.N_JOINTS)), resolve_friction(controller_spec.friction_ff, self.base_dir)

    def _make_gaze(self):
        h = self.h
        f = h.resolved_filter()
        return make_gaze_controller(
            strategy=h.strategy, profile=h.profile.kind, speed_m_s=h.profile.speed(),
            point_filter=f.kind if f.kind in ("ma", "wma") else None, window_s=f.window_s,
            kalman_q=f.q if f.kind == "kalman" else None, stall_timeout_s=h.watchdog_s)

    def _make_arm(self, backend, controller, ff, friction_ff) -> HandArm:
        h, plan = self.h, self.plan
        return HandArm(
            backend, controller, HandKinematics(tool_offset_m=h.tool_offset_m),
            workspace=plan.workspace, mapping=plan.mapping, z_tool_m=h.z_tool_m, R_ref=plan.R_ref,
            q_rest=plan.q_start, home_q_rad=plan.q_home, ik_rate_hz=h.ik_rate_hz, watchdog_s=h.watchdog_s,
            accel_m_s2=h.accel_m_s2, joint_speed_rad_s=h.joint_speed_rad_s,
            gripper=BarrettHandSim(close_time_s=h.gripper_close_s, open_time_s=h.gripper_open_s),
            friction_ff=friction_ff, ff_buffer=ff)

    def _wait_for_stream(self) -> None:
        """Hold until the gaze stream has started (:attr:`StreamFeed.started`: its third timed sample taken)."""
        if self.feed.started:
            return
        t0 = self.arm.t_s
        try:
            started = self._tick_until(lambda: self.feed.started, self.feed.start_timeout_s, pace=True)
        except _SessionEnded:  # the stream ended before it delivered anything usable
            started = False
        if not started:
            raise BackendError(self.feed.no_sample_message(self.arm.t_s - t0, ended=self.feed.exhausted))
        first, offset = self.feed.first_t_s, self.feed.offset_s  # (offset_s is tracker minus arm time)
        self._event("stream_start", f"first gaze sample at tracker time {first:.3f} s, arm time {first - offset:.3f} s")

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

    # -- a trial ----------------------------------------------------------------------------------

    def _run_trial(self, trial: Trial) -> None:
        self._to_start(trial)
        x, y = trial.xy_m
        self.supervisor.request(f"trial {trial.number}/{len(self.plan.trials)}: object at {trial.location} "
                                f"({x:.3f}, {y:.3f}) m; press Enter to start")
        self._tick_until(self.supervisor.ready, 1e9, pace=True)
        seed = self._begin(trial)
        outcome = self._drive()
        self._finish(trial, outcome, seed)

    def _to_start(self, trial: Trial) -> None:
        """Hand open, arm to the start pose (the subject's go-home on the way ends the session)."""
        arm = self.arm
        self._trial = None
        arm.stop()
        if not arm.gripper.is_open:
            arm.open_hand()
        self._tick_until(lambda: not arm.gripper.moving, 10.0)
        arm.move_to_joints(self.plan.q_start, f"start for trial {trial.number}")
        self._tick_until(lambda: not arm.busy, 120.0)
        if arm.ended:
            raise _SessionEnded("go_home")

    def _begin(self, trial: Trial) -> int:
        """Start the trial's clock, counts and (virtual source) subject; returns the subject's seed."""
        h = self.h
        self._trial = trial
        self._t0_s = t0 = self.arm.t_s
        self._traj = []
        self._counts = {"blink": 0, "voluntary_blink": 0, "stall": 0}
        self.gaze.gripper_closed = False  # the arm side owns the hand: it is open now
        if h.source.kind == "virtual":  # the subject's tracker starts with the trial: no stall before its first sample
            self.gaze.watchdog.feed(t0)
        seed = trial_seed(h.subject.seed, self.plan.condition, trial.number)
        if h.source.kind == "virtual":
            self.feed.subject = self._virtual_subject(trial, seed, t0)
        x, y = trial.xy_m
        self._event("trial_start", f"{trial.location} attempt {trial.attempt}, object at ({x:.3f}, {y:.3f}) m")
        self.arm.start()
        return seed

    def _virtual_subject(self, trial: Trial, seed: int, t0_s: float) -> VirtualSubject:
        """The subject of one trial: a reach policy looking at the hand through the scene camera."""
        h = self.h
        rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
        f = h.resolved_filter()
        policy = ReachPolicy(lambda: tuple(self.arm.hand_pose()[0][:2]), trial.xy_m, z_m=h.z_tool_m,
                             camera=self.plan.camera, mapping=self.plan.mapping, strategy=h.strategy,
                             profile=self.gaze.strategy.profile, skill=h.subject.skill,
                             lag_s=SUBJECT_LATENCY_S + f.delay_s(), rng=rng, t0_s=t0_s)
        subject = VirtualSubject(policy, seed=seed, skill=h.subject.skill,
                                 fatigue_per_min=h.subject.fatigue_per_min, blink_rate_hz=h.subject.blink_rate_hz,
                                 t0_s=t0_s, session_start_s=0.0)
        policy.request_blink = subject.request_voluntary_blink
        return subject

    def _drive(self) -> str:
        """The gaze drives the hand until it has closed (``grasp``) or the time-out (``timeout``); a closing hand
        is let finish."""
        arm = self.arm
        closing = lambda: arm.gripper.target == 1.0 and not arm.gripper.is_closed  # noqa: E731
        while True:
            self._step()
            if arm.ended:
                raise _SessionEnded("go_home")
            if arm.gripper.is_closed:
                return "grasp"
            if arm.t_s - self._t0_s >= self.h.timeout_s and not closing():
                return "timeout"
            if self.feed.exhausted and not closing():
                raise _SessionEnded("the gaze stream ended")

    def _finish(self, trial: Trial, outcome: str, seed: int) -> None:
        """Judge the trial (hit: grasp centre within the hit radius), record its row, trajectory and tables."""
        arm, h = self.arm, self.h
        t0, t_end = self._t0_s, arm.t_s
        x, y = trial.xy_m
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
        path, tilt = self._path_and_tilt()
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
        if h.record_trajectory:
            write_trajectory_part(self.run.path, trial.number, self._traj)
        self._trial = None
        self.write_tables()
        self.run.update_manifest(hmi={**self.run.manifest().get("hmi", {}), "trials_done": len(self.trial_rows)})
        log.info("trial %d %s: %s in %.1f s (%.1f mm)", trial.number, trial.location,
                 self.trial_rows[-1]["outcome"], t_end - t0, err * 1e3)

    def _path_and_tilt(self) -> tuple[float, float]:
        """The hand's path length on the table (m) and its largest tilt (deg) during the trial."""
        traj = np.array(self._traj, float).reshape(-1, len(TRAJECTORY_COLUMNS))
        hx, hy = traj[:, TRAJECTORY_COLUMNS.index("hand_x_m")], traj[:, TRAJECTORY_COLUMNS.index("hand_y_m")]
        path = float(np.sum(np.hypot(np.diff(hx), np.diff(hy)))) if len(traj) > 1 else 0.0
        tilt = float(np.max(traj[:, TRAJECTORY_COLUMNS.index("tilt_deg")])) if len(traj) else math.nan
        return path, tilt
