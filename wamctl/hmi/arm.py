"""Arm side of the gaze HMI (thesis 6.1.1, issue 7): the hand moves over the table, palm down, on gaze commands.

:class:`HandArm` drives an open backend tick by tick. Its parts: the tool-point kinematics and the IK step
(:mod:`wamctl.hmi.kinematics`: frame 0, tool point, palm down), the table, workspace, scene camera and command
mapping (:mod:`wamctl.hmi.scene`: command frame -> table plane) and the hand (:mod:`wamctl.hmi.gripper`).

Control
-------
Differential inverse kinematics at ``ik_rate_hz`` (100 Hz by default): a Cartesian reference (tool position in
the plane, constant height, orientation ``R_ref``) integrates the commanded velocity (acceleration-limited, clamped
to the workspace box), and one damped-least-squares step per IK period brings a kinematic joint reference
``q_ik`` onto it (closed-loop IK: the pose error of ``q_ik`` itself is fed back, so it never drifts). Joint limits
are respected by a weighting that slows joints near their limits, a null-space pull towards a rest posture, a
joint-speed cap and a final clamp with a margin. The joint reference is interpolated linearly to the 500 Hz
control rate and tracked by the backend's :class:`~wamctl.control.controllers.JointController`.

Safety holds (the reference velocity ramps to zero at ``accel_m_s2``): the session has not been started by the
supervisor; a command holds (eyes closed, no gaze, session ended); the command is the stop region; the last fresh
command is older than ``watchdog_s`` (stall); the hand is closing or opening. Joint-space moves (to the start
pose, home) are LSPB moves (thesis eqs. 3.3-3.5) from the current joint reference.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from wamctl.control.trajectory import ReferenceBuilder
from wamctl.hmi.gripper import BarrettHandSim
from wamctl.hmi.kinematics import HandKinematics
from wamctl.hmi.scene import CommandMapping, Workspace
from wamctl.hmi.strategy import EventKind, HandCommand, Hold, Motion
from wamctl.model import params as P

logger = logging.getLogger(__name__)


@dataclass
class ArmEvent:
    """Something the arm side did (for the events table)."""

    t_s: float
    kind: str
    detail: str = ""


@dataclass
class _JointMove:
    q_rad: np.ndarray  # (n, 7) per tick
    label: str
    then: str  # "teleop" or "ended"
    i: int = 0


class HandArm:
    """Drives the hand from :class:`~wamctl.hmi.strategy.HandCommand` s on an open backend, tick by tick.

    Parameters
    ----------
    backend : ArmBackend
        Open backend (simulated or real); the arm starts holding its measured position.
    controller : JointController
        Joint controllers at the control rate (``backend.control_period_s``).
    kinematics : HandKinematics
        Tool-point kinematics and IK step.
    workspace : Workspace
        Bounds of the tool point on the table.
    mapping : CommandMapping
        Command frame -> table plane.
    z_tool_m : float
        Height of the tool point while reaching, frame 0.
    R_ref : (3, 3)
        Hand orientation held (palm down).
    q_rest : (7,)
        Rest posture for the IK null space (the start pose).
    home_q_rad : (7,)
        Where the arm goes at the end of a session (three voluntary blinks).
    ik_rate_hz : float
        Rate of the IK steps; must divide the control rate.
    watchdog_s : float
        Hold still when the last fresh command is older than this.
    accel_m_s2 : float
        Acceleration limit of the Cartesian reference velocity (stops from 0.075 m/s in 75 ms at 1 m/s^2).
    joint_speed_rad_s, joint_blend_s : float
        Cruise speed and blend time of the LSPB joint moves.
    gripper : BarrettHandSim or None
        The hand (a fresh one if None).
    teleop : bool
        If True the arm is taken to be in its working pose already (palm down at ``z_tool_m``) and gaze commands
        may move it once started; otherwise it holds its joint positions until the first :meth:`move_to_joints`
        has brought it to one (a joint move always ends in the working pose, except the move home).
    friction_ff : FrictionModel or None
        For a ``pd_g_ff`` controller: friction feed-forward of the IK reference velocity, written into
        ``ff_buffer`` (the controller's one-row ``feedforward_Nm``) at each IK step.
    ff_buffer : (1, 7) array or None
        See ``friction_ff``.
    """

    def __init__(self, backend, controller, kinematics: HandKinematics, *, workspace: Workspace,
                 mapping: CommandMapping, z_tool_m: float, R_ref: np.ndarray, q_rest: np.ndarray,
                 home_q_rad: np.ndarray, ik_rate_hz: float = 100.0, watchdog_s: float = 0.2,
                 accel_m_s2: float = 1.0, joint_speed_rad_s: float = 0.5, joint_blend_s: float = 0.5,
                 gripper: BarrettHandSim | None = None, teleop: bool = False, friction_ff=None,
                 ff_buffer: np.ndarray | None = None) -> None:
        self.backend = backend
        self.controller = controller
        self.kin = kinematics
        self.workspace = workspace
        self.mapping = mapping
        self.z_tool_m = float(z_tool_m)
        self.R_ref = np.asarray(R_ref, float).copy()
        self.q_rest = np.asarray(q_rest, float).copy()
        self.home_q_rad = np.asarray(home_q_rad, float).copy()
        self.dt_s = float(backend.control_period_s)
        n_ik = round(1.0 / (ik_rate_hz * self.dt_s))
        if n_ik < 1 or abs(n_ik * ik_rate_hz * self.dt_s - 1.0) > 1e-9:
            raise ValueError(f"ik_rate_hz {ik_rate_hz} must divide the control rate {1.0 / self.dt_s:g} Hz")
        self.n_ik = int(n_ik)
        self.dt_ik_s = self.n_ik * self.dt_s
        self.watchdog_s = float(watchdog_s)
        self.accel_m_s2 = float(accel_m_s2)
        self.joint_speed_rad_s = float(joint_speed_rad_s)
        self.joint_blend_s = float(joint_blend_s)
        self.gripper = gripper if gripper is not None else BarrettHandSim()
        self.friction_ff = friction_ff
        self.ff_buffer = ff_buffer

        q = np.array(backend.read_positions(), float)
        self.q_meas = q
        self.q_ik = q.copy()
        self._q_prev_ik = q.copy()
        self._dq_ik = np.zeros(P.N_JOINTS)
        self.q_ref = q.copy()
        p, _ = self.kin.tool_pose(q)
        self.p_ref = np.array([p[0], p[1]])
        self.v_ref = np.zeros(2)
        self.v_des = np.zeros(2)
        self.t_s = 0.0
        self._k = 0
        self.started = False
        self.ended = False
        self._mode = "teleop" if teleop else "joint_hold"
        self._move: _JointMove | None = None
        self._last_fresh_s: float | None = None
        self._command: HandCommand | None = None
        self.hold_reason = "not_started"
        self._at_bound = False
        self.events: list[ArmEvent] = []
        self.ik_error = np.zeros(6)

    # -- supervisor and commands --------------------------------------------------------------------

    def start(self) -> None:
        """Supervisor start: gaze commands move the hand from now on."""
        if not self.started:
            self.started = True
            self._last_fresh_s = None
            self._event("start")

    def stop(self) -> None:
        """Supervisor stop: the hand holds still until :meth:`start`."""
        if self.started:
            self.started = False
            self._event("stop")

    @property
    def busy(self) -> bool:
        """True during a joint-space move (gaze commands are ignored)."""
        return self._move is not None

    def apply(self, command: HandCommand, *, fresh: bool = True) -> None:
        """Take a gaze command (``fresh``: it answers a new sample and feeds the watchdog).

        Gripper events toggle the hand (ignored during a joint move or before the start); ``GO_HOME`` ends the
        session and sends the arm home.
        """
        if fresh:
            self._last_fresh_s = self.t_s
        self._command = command
        for ev in command.events:
            if ev.kind is EventKind.GO_HOME:
                self.go_home()
            elif ev.kind in (EventKind.GRIPPER_CLOSE, EventKind.GRIPPER_OPEN):
                if self.busy or not self.started or self.ended:
                    self._event("gripper_ignored", ev.kind.value)
                elif ev.kind is EventKind.GRIPPER_CLOSE:
                    self.close_hand()
                else:
                    self.open_hand()

    def close_hand(self) -> None:
        self.gripper.close(self.t_s)
        self._event("gripper_closing")

    def open_hand(self) -> None:
        self.gripper.open(self.t_s)
        self._event("gripper_opening")

    def move_to_joints(self, q_target: Sequence[float], label: str = "move", *, then: str = "teleop",
                       settle_s: float = 0.3) -> float:
        """Start an LSPB joint move from the current joint reference; returns its duration, s."""
        q_target = np.asarray(q_target, float)
        delta = q_target - self.q_ref
        amp = float(np.max(np.abs(delta)))
        b = ReferenceBuilder(self.q_ref, self.dt_s)
        if amp > 1e-9:
            # LSPB needs t_f = t_c + amp / v >= 2 t_c: short moves cruise slower, keeping the blend time.
            tc = self.joint_blend_s
            speed = min(self.joint_speed_rad_s, amp / tc)
            b.move({j: float(delta[j]) for j in range(P.N_JOINTS)}, speed, tc, label)
        b.hold(max(settle_s, 2 * self.dt_s), "settle")
        ref = b.build()
        q = ref.q_rad.copy()
        q[-1] = q_target
        self._move = _JointMove(q, label, then)
        self._mode = "joint"
        self.v_ref[:] = 0.0
        self._event("joint_move", f"{label}: {len(q) * self.dt_s:.2f} s")
        return len(q) * self.dt_s

    def go_home(self) -> None:
        """End the session: LSPB to the home pose; the hand stays as it is."""
        if self.ended:
            return
        self.ended = True
        self._event("going_home")
        self.move_to_joints(self.home_q_rad, "home", then="ended")

    # -- state ------------------------------------------------------------------------------------

    def hand_pose(self, q: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tool point (3,) and orientation of the measured (or given) joint positions."""
        return self.kin.tool_pose(self.q_meas if q is None else q)

    def _event(self, kind: str, detail: str = "") -> None:
        self.events.append(ArmEvent(self.t_s, kind, detail))

    def drain_events(self) -> list[ArmEvent]:
        out, self.events = self.events, []
        return out

    # -- the control period -------------------------------------------------------------------------

    def tick(self) -> None:
        """One control period: reference, joint controllers, torques, wait for the next period."""
        move = self._move
        if move is not None:
            np.copyto(self.q_ref, move.q_rad[move.i])
            move.i += 1
            if self._k % self.n_ik == 0:
                self._update_gripper()
            if move.i >= len(move.q_rad):
                self._end_move(move)
        elif self._mode == "teleop":
            phase = self._k % self.n_ik
            if phase == 0:
                self._ik_update()
            np.multiply(self._dq_ik, (phase + 1) / self.n_ik, out=self.q_ref)
            self.q_ref += self._q_prev_ik
        elif self._k % self.n_ik == 0:  # joint hold, or home reached: the reference stands still
            self._update_gripper()
        q = self.backend.read_positions()
        tau = self.controller.update(self.q_ref, q)
        self.backend.command_torques(tau)
        self.backend.wait_next_cycle()
        self.q_meas = q
        self._k += 1
        self.t_s = self._k * self.dt_s

    def run(self, duration_s: float) -> None:
        """Tick for ``duration_s`` (rounded to whole periods)."""
        for _ in range(int(round(duration_s / self.dt_s))):
            self.tick()

    def _end_move(self, move: _JointMove) -> None:
        self._move = None
        q_end = move.q_rad[-1]
        self.q_ik[:] = q_end
        self._q_prev_ik[:] = q_end
        self._dq_ik[:] = 0.0
        p, _ = self.kin.tool_pose(q_end)
        self.p_ref[:] = p[:2]
        self.v_ref[:] = 0.0
        self._event("joint_move_done", move.label)
        if move.then == "ended":
            self._mode = "ended"
            self._event("home_reached")
        else:
            self._mode = "teleop"

    def _hold(self) -> str:
        """Why the hand must hold still now ('' when the gaze may move it)."""
        if self._mode == "ended" or self.ended:
            return "session_ended"
        if not self.started:
            return "not_started"
        cmd = self._command
        if cmd is None or self._last_fresh_s is None or self.t_s - self._last_fresh_s > self.watchdog_s:
            return "stall"
        if cmd.hold is not Hold.NONE:
            return cmd.hold.value
        if self.gripper.moving:
            return "gripper"
        if cmd.motion is Motion.STOP:
            return "stop"
        return ""

    def _update_gripper(self) -> None:
        was_moving = self.gripper.moving
        self.gripper.update(self.t_s)
        if was_moving and not self.gripper.moving:
            self._event("gripper_closed" if self.gripper.is_closed else "gripper_opened")

    @property
    def mode(self) -> str:
        """``joint_hold`` (before the first move), ``joint`` (LSPB move), ``teleop`` or ``ended``."""
        return self._mode

    def _ik_update(self) -> None:
        self._update_gripper()
        reason = self._hold()
        if reason != self.hold_reason:
            if reason == "stall" and self.hold_reason not in ("not_started", "session_ended"):
                self._event("stall", f"no fresh gaze command for more than {self.watchdog_s:.3f} s")
            self.hold_reason = reason
        if reason:
            self.v_des[:] = 0.0
        else:
            cmd = self._command
            vx, vy = self.mapping.to_table(cmd.vx_m_s, cmd.vy_m_s)
            self.v_des[0], self.v_des[1] = vx, vy
        # acceleration-limited reference velocity
        dv = self.v_des - self.v_ref
        n = math.hypot(dv[0], dv[1])
        step = self.accel_m_s2 * self.dt_ik_s
        if n > step:
            dv *= step / n
        self.v_ref += dv
        x = self.p_ref[0] + self.v_ref[0] * self.dt_ik_s
        y = self.p_ref[1] + self.v_ref[1] * self.dt_ik_s
        x, y, clamped = self.workspace.clamp(x, y)
        if clamped:
            ws = self.workspace
            if x in ws.x_m:
                self.v_ref[0] = 0.0
            if y in ws.y_m:
                self.v_ref[1] = 0.0
            if not self._at_bound:
                self._event("bound", f"hand clamped at the workspace bound ({x:.3f}, {y:.3f}) m")
        self._at_bound = clamped
        self.p_ref[0], self.p_ref[1] = x, y
        target = np.array([x, y, self.z_tool_m])
        self._q_prev_ik[:] = self.q_ik
        q_next, self.ik_error = self.kin.step(self.q_ik, target, self.R_ref, self.dt_ik_s, self.q_rest)
        np.subtract(q_next, self.q_ik, out=self._dq_ik)
        self.q_ik[:] = q_next
        if self.friction_ff is not None and self.ff_buffer is not None:
            self.ff_buffer[0] = self.friction_ff.friction_torque(self._dq_ik / self.dt_ik_s)
