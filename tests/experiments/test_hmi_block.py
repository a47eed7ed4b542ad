"""The arm side of the gaze HMI and the trial blocks (issue 7): IK, safety holds, go-home, blocks, resume, serial.

Everything runs on the simulated arm, in seconds of arm time. Numbers that come from the thesis (8 spots, 30 Hz,
0.7 s voluntary blinks, the 200 ms watchdog of issue 7) are the package's own constants; nothing is read from
../shared.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import wamctl_completed

from wamctl.analysis.hmi_results import TRIAL_COLUMNS
from wamctl.backends import make_backend
from wamctl.backends.gaze.line_format import format_line
from wamctl.backends.gaze.replay import write_gaze_csv
from wamctl.experiments import hmi_block
from wamctl.experiments.common import make_joint_controller
from wamctl.experiments.hmi_block.planning import make_camera, trial_seed
from wamctl.experiments.hmi_block.supervisor import stdin_prompt
from wamctl.experiments.hmi_block.tables import MOTION_CODES, TRAJECTORY_COLUMNS, TRIAL_TABLE_COLUMNS
from wamctl.hmi.arm import HandArm
from wamctl.hmi.gaze import GazeFlag, GazeSample
from wamctl.hmi.kinematics import (
    IK_SEED_Q_RAD,
    PALM_DOWN_YAW_RAD,
    HandKinematics,
    dls_step,
    limit_weights,
    orientation_error,
    palm_down_rotation,
    tilt_rad,
)
from wamctl.hmi.strategy import EventKind, HandCommand, Hold, Motion, make_gaze_controller
from wamctl.model import params as P
from wamctl.runs.store import read_table
from wamctl.specs import parse_spec

ROOT = Path(__file__).resolve().parents[2]
CENTRE = (384.0, 288.0)


def wamctl(*args):
    """``wamctl ARGS`` in this process (tests/cli_runs.py), as ``subprocess.run`` returns it."""
    return wamctl_completed(*args)


@pytest.fixture(scope="module")
def setup():
    spec = parse_spec({"kind": "hmi_block", "name": "t", "seed": 2})
    return spec, hmi_block.plan(spec)


@contextmanager
def arm_session(spec, plan, *, home=None):
    """A started HandArm on the simulated arm, at the start pose, in teleoperation."""
    with make_backend(spec, q0_rad=plan.q_start) as backend:
        arm = HandArm(backend, make_joint_controller(spec), HandKinematics(tool_offset_m=spec.hmi.tool_offset_m),
                        workspace=plan.workspace, mapping=plan.mapping, z_tool_m=spec.hmi.z_tool_m, R_ref=plan.R_ref,
                        q_rest=plan.q_start, home_q_rad=plan.q_home if home is None else home, teleop=True)
        arm.start()
        yield arm


def drive(arm, command, duration_s, rate_hz=30.0, probe=None):
    """Tick for ``duration_s``; ``command(t) -> HandCommand | None`` is applied at ``rate_hz`` (None: nothing
    sent). ``probe(arm)`` is called every 10 ticks."""
    every = round(1.0 / (rate_hz * arm.dt_s))
    for k in range(round(duration_s / arm.dt_s)):
        if k % every == 0:
            c = command(arm.t_s)
            if c is not None:
                arm.apply(c)
        arm.tick()
        if probe is not None and k % 10 == 0:
            probe(arm)


def hand_xy(arm):
    return arm.hand_pose()[0][:2].copy()


# ------------------------------------------------------------------------------------------------ kinematics
def test_camera_mapping_matches_the_seat_and_the_image():
    cam = make_camera(parse_spec({"kind": "hmi_block"}).hmi)
    m = cam.mapping()
    # The subject sits at the arm's left (+y) looking along -y: image right is -x, image up is -y.
    assert np.allclose(m.right_xy, (-1.0, 0.0), atol=1e-12) and np.allclose(m.forward_xy, (0.0, -1.0), atol=1e-12)
    u0, v0 = cam.project((0.35, 0.0, 0.0))
    assert (u0, v0) == pytest.approx(CENTRE, abs=1e-9)  # it looks at the start cross
    u1, _ = cam.project((0.30, 0.0, 0.0))  # towards the base = image right
    _, v1 = cam.project((0.35, -0.10, 0.0))  # away from the subject = higher in the image (smaller v)
    assert u1 > u0 + 20 and v1 < v0 - 20
    assert m.to_table(*m.to_command(0.3, -0.2)) == pytest.approx((0.3, -0.2))


def test_ik_step_is_weighted_damped_least_squares():
    kin = HandKinematics()
    rng = np.random.default_rng(4)
    R_ref = palm_down_rotation(PALM_DOWN_YAW_RAD)
    for _ in range(5):
        q = rng.uniform(P.Q_MIN_RAD + 0.1, P.Q_MAX_RAD - 0.1)
        target = kin.tool_pose(q)[0] + rng.normal(0.0, 0.01, 3)
        J, p, R = kin.tool_jacobian(q)
        e = np.concatenate([target - p, orientation_error(R, R_ref)])
        w = limit_weights(q)
        expected = np.clip(q + dls_step(J, e, kin.damping, w), P.Q_MIN_RAD + 0.05, P.Q_MAX_RAD - 0.05)
        q_next, err = kin.step(q, target, R_ref, dt_s=100.0)  # no speed cap, no null space
        assert np.allclose(err, e, atol=1e-12)
        assert np.allclose(q_next, expected, atol=1e-10)
        # the null-space pull towards a rest posture leaves the task motion (almost) alone
        q_null, _ = kin.step(q, target, R_ref, dt_s=100.0, q_rest=q + rng.normal(0.0, 0.3, 7))
        inside = np.all((q_null > P.Q_MIN_RAD + 0.05) & (q_null < P.Q_MAX_RAD - 0.05))
        if inside and np.all((expected > P.Q_MIN_RAD + 0.05) & (expected < P.Q_MAX_RAD - 0.05)):
            assert np.linalg.norm(J @ (q_null - expected)) < 0.05 * np.linalg.norm(q_null - expected) + 1e-9
    # the speed cap: no joint moves more than qd_max * dt in one step
    q = IK_SEED_Q_RAD.copy()
    q_next, _ = kin.step(q, kin.tool_pose(q)[0] + [0.2, 0.0, 0.0], R_ref, dt_s=0.01)
    assert np.max(np.abs(q_next - q)) <= kin.qd_max_rad_s * 0.01 + 1e-12


def test_ik_holds_palm_down_and_reaches_the_spots(setup):
    spec, plan = setup
    kin = HandKinematics(tool_offset_m=spec.hmi.tool_offset_m)
    z = spec.hmi.z_tool_m
    assert len(plan.q_targets) == 8
    for loc, q in plan.q_targets.items():
        p, R = kin.tool_pose(q)
        assert np.linalg.norm(p - (*spec.hmi.targets_m[loc], z)) < 1e-4, loc
        assert tilt_rad(R) < 1e-3 and np.linalg.norm(orientation_error(R, plan.R_ref)) < 1e-3, loc
        assert np.all(q > P.Q_MIN_RAD) and np.all(q < P.Q_MAX_RAD)
    # closed loop on the simulated arm: a proportional vector command to two far spots, then stop
    with arm_session(spec, plan) as arm:
        worst = {"tilt": 0.0, "dz": 0.0}

        def probe(a):
            p, R = a.hand_pose()
            worst["tilt"] = max(worst["tilt"], tilt_rad(R))
            worst["dz"] = max(worst["dz"], abs(p[2] - z))

        for loc in ("P3", "P5"):
            target = np.array(spec.hmi.targets_m[loc])

            def toward(t, target=target):
                e = target - hand_xy(arm)
                cx, cy = plan.mapping.to_command(*e)
                n = math.hypot(cx, cy)
                if n < 5e-4:
                    return HandCommand(t, Motion.STOP)
                v = min(0.06, 2.0 * n) / n
                return HandCommand(t, Motion.VECTOR, 1, v * cx, v * cy)

            drive(arm, toward, 7.0, probe=probe)
            drive(arm, lambda t: HandCommand(t, Motion.STOP), 0.5, probe=probe)
            assert np.linalg.norm(hand_xy(arm) - target) < 0.004, loc
    assert math.degrees(worst["tilt"]) < 3.0
    assert worst["dz"] < 0.006


# ------------------------------------------------------------------------------------------------ safety
@pytest.mark.parametrize("how", ["blink", "stall", "stop"])
def test_hand_holds_still_during_blinks_stalls_and_in_the_stop_region(setup, how):
    spec, plan = setup
    moving = lambda t: HandCommand(t, Motion.LEFT, 2, -0.05, 0.0)  # noqa: E731  image left = +x on the table
    then = {"blink": lambda t: HandCommand(t, Motion.STOP, hold=Hold.BLINK),
            "stall": lambda t: None,  # the stream went silent: no command at all
            "stop": lambda t: HandCommand(t, Motion.STOP)}[how]
    with arm_session(spec, plan) as arm:
        p0 = hand_xy(arm)
        drive(arm, moving, 1.0)
        p1 = hand_xy(arm)
        assert p1[0] - p0[0] > 0.035 and abs(p1[1] - p0[1]) < 0.003  # it was moving, along +x
        drive(arm, then, 0.3)  # the 200 ms watchdog, the 1 m/s^2 ramp
        p2, q2 = hand_xy(arm), arm.q_meas.copy()
        drive(arm, then, 1.0)
        p3, q3 = hand_xy(arm), arm.q_meas.copy()
        assert arm.hold_reason == how
        assert np.linalg.norm(p2 - p1) < (0.016 if how == "stall" else 0.006)
        assert np.linalg.norm(p3 - p2) < 0.001
        assert np.max(np.abs(q3 - q2)) < 0.002
        kinds = [e.kind for e in arm.drain_events()]
        assert ("stall" in kinds) == (how == "stall")


def test_workspace_bounds_clamp_the_hand(setup):
    spec, plan = setup
    ws = plan.workspace
    with arm_session(spec, plan) as arm:
        inside = []
        diagonal = lambda t: HandCommand(t, Motion.VECTOR, 2, 0.075, 0.075)  # noqa: E731  table (-x, -y)
        drive(arm, diagonal, 4.5, probe=lambda a: inside.append(ws.contains(*hand_xy(a), margin_m=-0.004)))
        assert tuple(arm.p_ref) == (ws.x_m[0], ws.y_m[0])
        assert np.linalg.norm(hand_xy(arm) - (ws.x_m[0], ws.y_m[0])) < 0.006
        assert all(inside)
        assert "bound" in [e.kind for e in arm.drain_events()]
        # away from the corner it moves again
        drive(arm, lambda t: HandCommand(t, Motion.LEFT, 2, -0.075, 0.0), 0.5)
        assert hand_xy(arm)[0] > ws.x_m[0] + 0.02


def test_three_voluntary_blinks_send_the_arm_home(setup):
    spec, plan = setup
    home = plan.q_start + np.array([0.25, 0.0, 0.0, -0.2, 0.0, 0.0, 0.0])
    controller = make_gaze_controller(strategy="four", profile="dual", point_filter="ma", window_s=0.3)
    samples, t = [], 0.0

    def add(n, x, y, flags=GazeFlag(0)):
        nonlocal t
        for _ in range(n):
            samples.append(GazeSample(round(t, 3), x, y, flags))
            t += 1 / 30

    add(30, 150.0, 288.0)  # look left: the hand moves
    for _ in range(3):  # three voluntary blinks (25 samples ~ 0.83 s), 0.5 s apart
        add(25, -2000.0, -2000.0, GazeFlag.BLINK)
        add(15, *CENTRE)
    add(90, 150.0, 288.0)  # looking left again: the session has ended, nothing moves
    kinds = []
    with arm_session(spec, plan, home=home) as arm:
        p_start = hand_xy(arm)
        after_home = []
        for i, s in enumerate(samples):
            if i == 30:
                assert hand_xy(arm)[0] - p_start[0] > 0.01  # looking left moved the hand along +x
            while arm.t_s < s.t_s:
                arm.tick()
            cmd = controller.update(s)
            kinds += [e.kind for e in cmd.events]
            arm.apply(cmd)
            if arm.mode == "ended":
                after_home.append(hand_xy(arm))
        while arm.busy:
            arm.tick()
        arm.run(1.0)
        assert kinds.count(EventKind.GO_HOME) == 1
        assert kinds.index(EventKind.GRIPPER_CLOSE) < kinds.index(EventKind.GRIPPER_OPEN) < kinds.index(
            EventKind.GO_HOME)
        assert arm.ended and arm.mode == "ended"
        assert np.max(np.abs(arm.q_meas - home)) < 0.01
        assert len(after_home) > 30 and np.linalg.norm(after_home[-1] - after_home[0]) < 0.001
        assert "home_reached" in [e.kind for e in arm.drain_events()]


# ------------------------------------------------------------------------------------------------ blocks
def block_spec(tmp_path: Path, name: str, **hmi) -> Path:
    spec = {"kind": "hmi_block", "name": name, "seed": 1,
            "hmi": {"subject": {"id": "S1", "seed": 5, "skill": 0.95}, **hmi}}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def test_virtual_block_end_to_end_through_the_cli(tmp_path):
    spec = block_spec(tmp_path, "e2e", locations=["P4", "P7"], attempts=1)
    r = wamctl("hmi-session", spec, "--out", tmp_path / "runs", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["status"] == "completed"
    run = Path(out["run_dir"])
    trials = pd.read_csv(run / "trials.csv")
    assert list(trials.columns) == TRIAL_TABLE_COLUMNS
    assert set(TRIAL_COLUMNS) <= set(trials.columns)
    assert trials["location"].tolist() == ["P4", "P7"] and trials["attempt"].tolist() == [1, 1]
    assert (trials["condition"] == "four-ma300-dual").all() and (trials["subject"] == "S1").all()
    # a skilled subject hits, in a plausible time (P7 is farther than P4)
    assert trials["hit"].tolist() == [1, 1]
    assert ((trials["time_s"] > 2.0) & (trials["time_s"] < 30.0)).all()
    assert trials.loc[1, "time_s"] > trials.loc[0, "time_s"]
    assert (trials["error_m"] < 0.03).all() and (trials["max_tilt_deg"] < 3.0).all()
    assert (trials["n_voluntary_blinks"] >= 1).all()
    events = pd.read_csv(run / "hmi_events.csv")
    for n in (1, 2):
        kinds = set(events.loc[events["trial"] == n, "kind"])
        assert {"trial_start", "voluntary_blink", "gripper_close", "gripper_closed", "grasp", "command"} <= kinds
    traj = read_table(run, "trajectory")
    assert list(traj.columns) == TRAJECTORY_COLUMNS
    assert set(traj["trial"]) == {1.0, 2.0}
    dt = np.diff(traj.loc[traj["trial"] == 1, "gaze_t_s"])
    assert 0.025 < np.median(dt) < 0.04  # one row per 30 Hz sample
    m = json.loads((run / "manifest.json").read_text())
    assert m["hmi"]["trials_done"] == 2 and m["hmi"]["session_end"] == "completed"
    report = (run / "report.md").read_text()
    assert "Per location" in report and "| P7 |" in report
    assert out["report"]["hmi"]["hits"] == 2


def test_resume_continues_at_the_next_trial(tmp_path):
    # the subject ends the session after trial 1 (three voluntary blinks): the arm goes home, the run stops
    spec = block_spec(tmp_path, "resume", locations=["P4", "P1", "P8"],
                      subject={"id": "S1", "seed": 5, "skill": 0.95, "end_session_after_trial": 1})
    r = wamctl("hmi-session", spec, "--out", tmp_path / "runs", "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    run = Path(json.loads(r.stdout)["run_dir"])
    first = pd.read_csv(run / "trials.csv")
    assert first["trial"].tolist() == [1]
    m = json.loads((run / "manifest.json").read_text())
    assert m["hmi"]["session_end"] == "go_home" and m["hmi"]["trials_done"] == 1
    kinds = pd.read_csv(run / "hmi_events.csv")["kind"].tolist()
    assert "go_home" in kinds and "home_reached" in kinds
    assert len(list((run / "trajectory").glob("part-*.parquet"))) == 1   # trial 1's part, kept for a resume
    r = wamctl("hmi-session", "--resume", run, "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    trials = pd.read_csv(run / "trials.csv")
    assert trials["trial"].tolist() == [1, 2, 3]
    assert trials["location"].tolist() == ["P4", "P1", "P8"]
    pd.testing.assert_frame_equal(trials.iloc[:1], first)
    assert trials.loc[1, "subject_seed"] == trial_seed(5, "four-ma300-dual", 2)
    m = json.loads((run / "manifest.json").read_text())
    assert m["status"] == "completed" and len(m["resumed"]) == 1 and m["hmi"]["trials_done"] == 3
    traj = read_table(run, "trajectory")
    assert set(traj["trial"]) == {1.0, 2.0, 3.0}
    assert not (run / "trajectory").exists()      # complete: the parts removed, trajectory.parquet holds them
    # resuming a finished block runs nothing more
    assert hmi_block.resume(run).status == "completed"
    assert pd.read_csv(run / "trials.csv")["trial"].tolist() == [1, 2, 3]
    pd.testing.assert_frame_equal(read_table(run, "trajectory"), traj)


class Killed(BaseException):
    """The process dying (SIGKILL, a power cut): after it, nothing more reaches the disk."""


def test_a_death_while_a_trial_is_saved_leaves_no_trial_without_its_events(tmp_path, monkeypatch):
    """SIGKILL cannot be held back like Ctrl-C: it falls while trial 2 is saved (its trajectory part written, its
    rows not all). The resumed block has every trial once, each with its events (trials.csv, which resume counts
    as done, was written before the events: trial 2 came back done without one)."""
    from wamctl.experiments.hmi_block import tables
    from wamctl.experiments.runner import run_spec
    from wamctl.runs import store
    spec = parse_spec(yaml.safe_load(block_spec(tmp_path, "killed", locations=["P4", "P1", "P8"]).read_text()))
    real, dead = store.atomic_write, []

    def dying(path, write):
        path = Path(path)
        if dead or (path.name == "hmi_events.csv" and (path.parent / "trajectory" / "part-00002.parquet").is_file()):
            dead.append(path.name)
            raise Killed
        real(path, write)
    monkeypatch.setattr(store, "atomic_write", dying)
    monkeypatch.setattr(tables, "atomic_write", dying)
    with pytest.raises(Killed):
        run_spec(spec, None, tmp_path / "runs", make_report=False)
    monkeypatch.undo()
    [run] = list((tmp_path / "runs").iterdir())
    assert pd.read_csv(run / "trials.csv")["trial"].tolist() in ([1], [1, 2])
    assert hmi_block.resume(run).status == "completed"
    trials = pd.read_csv(run / "trials.csv")
    assert trials["trial"].tolist() == [1, 2, 3]
    events = pd.read_csv(run / "hmi_events.csv")
    for n in (1, 2, 3):
        kinds = events.loc[events["trial"] == n, "kind"].tolist()
        assert kinds.count("trial_start") == 1 and "grasp" in kinds, (n, kinds)
    assert set(read_table(run, "trajectory")["trial"]) == {1.0, 2.0, 3.0}
    assert not (run / "trajectory").exists()      # the block complete: its parts joined, then removed


def _scripted_stream() -> list[GazeSample]:
    """Centre while the arm goes to the start, look left (+x), back to the centre, a grasp blink, centre."""
    samples, t = [], 0.0
    for n, (x, y) in ((135, CENTRE), (45, (200.0, 300.0)), (36, CENTRE), (30, (-2000.0, -2000.0)),
                      (120, CENTRE)):
        for _ in range(n):
            flags = GazeFlag.BLINK if x == -2000.0 else GazeFlag(0)
            samples.append(GazeSample(round(t, 3), x, y, flags))
            t += 1 / 30
    return samples


def test_serial_block_gives_the_same_commands_as_the_replay(tmp_path):
    from wamctl.experiments.runner import run_spec

    samples = _scripted_stream()
    write_gaze_csv(tmp_path / "gaze.csv", samples)
    lines = []
    for i, s in enumerate(samples):
        lines.append(format_line(s.t_s, s.x_px, s.y_px))
        if i % 60 == 30:
            lines.append(b"\xfe\x00garbage,,\n")
    data = b"".join(lines)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve():
        conn, _ = server.accept()
        time.sleep(0.5)  # pyserial flushes its input when it opens: send after that
        with conn:
            conn.sendall(data)
        server.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    base = {"kind": "hmi_block", "seed": 1,
            "hmi": {"subject": {"id": "P01"}, "locations": ["P4"], "start": "auto", "timeout_s": 20}}
    serial = parse_spec({**base, "name": "serial",
                         "hmi": {**base["hmi"], "source": {"kind": "serial", "url": f"socket://127.0.0.1:{port}",
                                                          "format": "ascii-timestamped"}}})
    replay = parse_spec({**base, "name": "replay", "hmi": {**base["hmi"], "source": {"kind": "replay",
                                                                                      "path": "gaze.csv"}}})
    out_r = run_spec(replay, tmp_path, tmp_path / "runs", make_report=False)
    out_s = run_spec(serial, tmp_path, tmp_path / "runs", make_report=False)
    thread.join(5.0)
    assert out_r.status == out_s.status == "completed"
    tr, ts = pd.read_csv(out_r.path / "trials.csv"), pd.read_csv(out_s.path / "trials.csv")
    assert len(tr) == len(ts) == 1
    assert tr.loc[0, "outcome"] == ts.loc[0, "outcome"] != "timeout"
    assert ts.loc[0, "time_s"] == pytest.approx(tr.loc[0, "time_s"], abs=0.05)
    assert ts.loc[0, "error_m"] == pytest.approx(tr.loc[0, "error_m"], abs=0.002)
    assert tr.loc[0, "hand_x_m"] > 0.37  # looking left moved the hand along +x
    cols = ["gaze_t_s", "gaze_x_px", "gaze_y_px", "motion", "level", "vx_cmd_m_s", "vy_cmd_m_s", "hold"]
    a = read_table(out_r.path, "trajectory")[cols].round(6)
    b = read_table(out_s.path, "trajectory")[cols].round(6)
    both = a.merge(b, on="gaze_t_s", suffixes=("_r", "_s"))
    assert len(both) >= 0.95 * len(a) and len(a) > 100
    for c in cols[1:]:
        assert (both[f"{c}_r"] == both[f"{c}_s"]).all(), c
    assert {MOTION_CODES.index("stop"), MOTION_CODES.index("left")} <= set(a["motion"])
    assert json.loads((out_s.path / "manifest.json").read_text())["hmi"]["source"] == "serial"


# ------------------------------------------------------------------------------------------------ specs, study
@pytest.mark.parametrize("hmi, match", [
    ({"strategy": "four", "filter": {"kind": "kalman"}}, "filter.kind: kalman"),
    ({"targets_m": {"PX": [0.9, 0.0]}}, "targets_m.PX: .* outside the workspace"),
    ({"locations": ["P9"]}, "locations: 'P9'"),
    ({"ik_rate_hz": 70}, "ik_rate_hz"),
    ({"workspace": {"x_m": [0.2, 0.7], "y_m": [-0.26, 0.26]}, "targets_m": {"FAR": [0.68, 0.0]}},
     "FAR: holding the hand there takes .* joint 2"),
])
def test_bad_specs_name_the_field(hmi, match):
    from wamctl.errors import SpecError
    with pytest.raises(SpecError, match=match):
        hmi_block.plan(parse_spec({"kind": "hmi_block", "hmi": hmi}))


def test_study_tables_from_several_runs(tmp_path):
    from wamctl.report.hmi import results_from_runs, study_report, trials_from_runs
    from wamctl.runs.store import RunDir

    # hand-made trials: (subject, condition) -> [(location, hit, time_s)]
    blocks = {("S1", "E1"): [("P1", 1, 10.0), ("P2", 0, 20.0)], ("S1", "E2"): [("P1", 1, 8.0), ("P2", 1, 12.0)],
              ("S2", "E1"): [("P1", 0, 30.0), ("P2", 0, None)], ("S2", "E2"): [("P1", 1, 9.0), ("P2", 1, 11.0)]}
    dirs = []
    for (subject, condition), rows in blocks.items():
        run = RunDir.create(tmp_path / "runs", f"{subject}-{condition}", {"kind": "hmi_block"}, 0, "hmi_block")
        pd.DataFrame([{"trial": i + 1, "subject": subject, "condition": condition, "location": loc, "attempt": 1,
                       "hit": hit, "time_s": t} for i, (loc, hit, t) in enumerate(rows)]).to_csv(
            run.path / "trials.csv", index=False)
        run.finish("completed")
        dirs.append(run.path)
    assert len(trials_from_runs(dirs)) == 8
    by_subject = results_from_runs(dirs)  # two subjects: per subject
    assert by_subject.unit_kind == "subject"
    hits = by_subject.wide("hit_pct")
    assert hits.loc["S1", "E1"] == 50.0 and hits.loc["S2", "E1"] == 0.0 and hits.loc["S2", "E2"] == 100.0
    times = by_subject.wide("mean_time_s")
    assert times.loc["S1", "E1"] == 15.0 and times.loc["S2", "E1"] == 30.0  # a time-out has no time
    by_location = results_from_runs(dirs, unit="location")
    assert by_location.wide("hit_pct").loc["P2", "E1"] == 0.0 and by_location.wide("mean_time_s").loc["P1", "E2"] == 8.5
    doc = study_report(dirs, tmp_path / "study")
    names = [obj[0] for kind, obj in doc.blocks if kind == "table"]
    assert {"hmi_by_location", "hmi_by_subject", "hmi_anova_hit_rate", "hmi_anova_mean_time_s"} <= set(names)
    table = {obj[0]: obj[1] for kind, obj in doc.blocks if kind == "table"}["hmi_by_subject"]
    assert table.loc["Mean", "hit_pct E2"] == 100.0 and table.loc["Mean", "hit_pct E1"] == 25.0
    assert (tmp_path / "study" / "hmi_mean.png").stat().st_size > 1000
    assert doc.data["hmi_study"]["trials"] == 8


def test_supervisor_prompt_starts_each_trial(tmp_path):
    from wamctl.experiments.runner import run_spec

    asked = []

    def prompt(message):
        asked.append((time.monotonic(), message))
        time.sleep(0.3)

    spec = parse_spec({"kind": "hmi_block", "name": "prompt", "seed": 1,
                       "hmi": {"subject": {"id": "S1", "seed": 5, "skill": 0.95}, "locations": ["P4"],
                               "start": "prompt"}})
    hmi_block.set_supervisor_prompt(prompt)
    try:
        out = run_spec(spec, tmp_path, tmp_path / "runs", make_report=False)
    finally:
        hmi_block.set_supervisor_prompt(stdin_prompt)
    assert out.status == "completed"
    assert len(asked) == 1 and "P4" in asked[0][1]
    events = pd.read_csv(out.path / "hmi_events.csv")
    t_move_done = events.loc[events["kind"] == "joint_move_done", "t_s"].iloc[0]
    t_start = events.loc[events["kind"] == "trial_start", "t_s"].iloc[0]
    assert t_start > t_move_done  # the arm held at the start pose until the supervisor answered
    assert pd.read_csv(out.path / "trials.csv")["hit"].tolist() == [1]
