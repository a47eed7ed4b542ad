"""The thesis' RPE figures stand beside ours only for the test the thesis ran (0.5 rad at 0.083 rad/s under
libbarrett's gains); any other test says what differs instead."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from wamctl.analysis.rotation import find_rotations, move_speed_rad_s, thesis_test_differences
from wamctl.model import params as P
from wamctl.report.rotation import rotation_table, thesis_column


def lspb(t, amplitude, speed, tc=1.0):
    """Linear segment with parabolic blends from 0 to ``amplitude`` at ``speed`` (acceleration speed / tc)."""
    a = speed / tc
    tf = abs(amplitude) / speed + tc
    s = np.where(t < tc, 0.5 * a * t**2,
                 np.where(t < tf - tc, 0.5 * a * tc**2 + speed * (t - tc),
                          abs(amplitude) - 0.5 * a * np.clip(tf - t, 0, None)**2))
    return np.sign(amplitude) * np.where(t >= tf, abs(amplitude), s), tf


def rotation_data(amplitude=0.5, speed=0.083, joints=(1, 4), jitter_s=0.0, seed=0):
    rng = np.random.default_rng(seed)
    _, tf = lspb(np.zeros(1), amplitude, speed)
    t = np.arange(0.0, tf + 1.0, 0.002) + rng.uniform(-jitter_s, jitter_s, int(np.ceil((tf + 1.0) / 0.002)))
    df = {"t_s": t}
    for j in range(1, P.N_JOINTS + 1):
        ref = lspb(t, amplitude, speed)[0] if j in joints else np.zeros_like(t)
        df[f"q_ref_{j}_rad"] = ref
        df[f"q_{j}_rad"] = ref - 1e-3 * np.tanh(ref)    # a final error of about 1 mrad
    return pd.DataFrame(df)


def test_the_speed_of_a_move_is_read_from_its_reference_despite_jittered_stamps():
    data = rotation_data(speed=0.083, jitter_s=2e-4)
    for r in find_rotations(data):
        assert move_speed_rad_s(data, r) == pytest.approx(0.083, rel=2e-3)


def test_the_thesis_test_gets_the_thesis_column():
    data = rotation_data()
    assert thesis_test_differences(data, {"kind": "pd_g", "kp": None}) == []
    spec = {"controller": {"kind": "pd_g"}, "rotation": {"mode": "one_at_a_time"}}
    table = rotation_table(data, spec)
    assert table["thesis_rpe_pct"].tolist() == [1.0876, 0.2912]       # joints 1 and 4, thesis ch. 3
    assert thesis_column(data, {**spec, "controller": {"kind": "pd_g", "kp": P.KP.tolist()}})[0] is not None


@pytest.mark.parametrize("data, controller, says", [
    (rotation_data(amplitude=0.3, speed=0.1), {"kind": "pd_g"}, ["amplitude 0.3 rad", "speed 0.1 rad/s"]),
    (rotation_data(amplitude=-0.5, speed=0.2), {"kind": "pd_g"}, ["speed 0.2 rad/s"]),
    (rotation_data(), {"kind": "pd_g", "kp": [100.0] * 7}, ["its own kp"]),
    (rotation_data(), {"kind": "pid"}, ["controller pid, one at a time"]),
], ids=["amplitude-and-speed", "speed", "gains", "controller"])
def test_another_test_says_what_differs_and_shows_no_thesis_column(data, controller, says):
    spec = {"controller": controller, "rotation": {"mode": "one_at_a_time"}}
    figures, caption = thesis_column(data, spec)
    assert figures is None and "thesis_rpe_pct" not in rotation_table(data, spec)
    assert caption.startswith("No thesis column: the thesis rotated each joint 0.5 rad at 0.083 rad/s")
    for s in says:
        assert s in caption


# ------------------------------------------------------------------------------ issue 32, item 5: moves cut off
SPEC = {"controller": {"kind": "pd_g"}, "rotation": {"mode": "one_at_a_time", "amplitude_rad": 0.5, "hold_s": 1.0}}


def test_a_move_cut_off_mid_ramp_is_not_finished_and_has_no_rpe():
    data = rotation_data(joints=(1, 4))                # 0.5 rad at 0.083 rad/s, then a 1 s hold: 8.02 s
    cut = data[data["t_s"] < 1.43]                     # interrupted 1.43 s in: the reference at 0.0774 rad
    assert cut["q_ref_4_rad"].iloc[-1] == pytest.approx(0.0774, abs=1e-3)
    table = rotation_table(cut, SPEC)
    assert table["move"].tolist() == ["not finished", "not finished"]
    assert table["rpe_pct"].isna().all() and table["final_error_rad"].isna().all()
    assert table["amplitude_rad"].tolist() == [0.5, 0.5]      # the rotation asked for, not 0.0774
    # from the data alone (no spec): the reference still moving at the last sample is enough
    assert rotation_table(cut, {"controller": {"kind": "pd_g"}})["rpe_pct"].isna().all()


def test_a_move_cut_off_in_its_hold_is_not_finished_and_a_whole_one_is():
    data = rotation_data(joints=(1,))
    t_end = data["t_s"].iloc[-1]
    cut = data[data["t_s"] < t_end - 0.5]              # at the target, but only half of the 1 s hold
    assert rotation_table(cut, SPEC)["move"].tolist() == ["not finished"]
    whole = rotation_table(data, SPEC)
    assert "move" not in whole                         # every move finished: no column
    assert whole["rpe_pct"].tolist() == pytest.approx([100 * 1e-3 * np.tanh(0.5) / 0.5])


def test_a_plan_without_a_settle_starts_one_step_into_its_move_and_still_finishes():
    # the sweep tests' tiny rotation: 0.05 rad at 0.25 rad/s, t_c 0.1 s, no settle: the first sample of the
    # reference is already 5e-6 rad into the move (a tenth of a thousandth of the amplitude)
    from wamctl.experiments.rotation import plan
    from wamctl.specs import parse_spec
    rot = {"mode": "all_together", "amplitude_rad": 0.05, "velocity_rad_s": 0.25, "tc_s": 0.1, "settle_s": 0.0,
           "hold_s": 0.1}
    spec = parse_spec({"kind": "rotation", "q0_rad": [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0], "rotation": rot})
    ref = plan(spec).reference
    data = pd.DataFrame({"t_s": ref.t_s} | {f"q_ref_{j}_rad": ref.q_rad[:, j - 1] for j in range(1, 8)}
                        | {f"q_{j}_rad": ref.q_rad[:, j - 1] - 1e-3 for j in range(1, 8)})
    table = rotation_table(data, {"controller": {"kind": "pd_g"}, "rotation": rot})
    assert list(table.index) == list(range(1, 8)) and "move" not in table
    assert table["rpe_pct"].tolist() == pytest.approx([2.0] * 7, rel=1e-3)


def test_the_report_of_an_interrupted_run_warns_first_scores_no_cut_move_and_plots_the_whole_run(tmp_path,
                                                                                                 monkeypatch):
    from wamctl.analysis.loop_events import TORQUE_SATURATION, LoopEvent
    from wamctl.report import rotation as rotation_report
    from wamctl.report import write_report
    from wamctl.runs.store import RunDir

    moving = rotation_data(joints=(1, 4))
    still = pd.concat([moving.iloc[:1]] * 250, ignore_index=True).assign(t_s=np.arange(250) * 0.002)
    data = pd.concat([still, moving.assign(t_s=moving["t_s"] + 0.5)], ignore_index=True)   # 0.5 s settle first
    data = data[data["t_s"] < 1.93]                    # interrupted mid-ramp
    spec = {"kind": "rotation", "name": "cut", **SPEC}
    run = RunDir.create(tmp_path, "cut", spec, 0, "rotation")
    run.write_table("data", data)
    stuck = LoopEvent(TORQUE_SATURATION, 2, 0.2, 1.1, -20.0, 20.0)
    run.event(0.0, "segment", None, "move joints 1,4")
    run.event(stuck.start_s, stuck.kind, stuck.joint, stuck.detail)
    run.finish("interrupted", "stopped by SIGINT")
    figures = {}

    def keep(fig, path):
        figures[path.name] = [(ax.get_title(), ax.lines[0].get_xdata()[0], ax.lines[0].get_xdata()[-1])
                              for ax in fig.axes if ax.get_visible()]
        return path
    monkeypatch.setattr(rotation_report, "save", keep)
    doc = write_report(run.path, tmp_path / "report", ("json", "md"))
    assert doc.blocks[0] == ("warn", "joint 2 at torque limit 0.20-1.30 s (1.1 s), peak -20.0 N m")
    assert doc.data["rpe_pct"] == {} and doc.data["not_finished"] == [1, 4]
    md = (tmp_path / "report" / "report.md").read_text()
    assert md.index("joint 2 at torque limit") < md.index("Relative position error")
    assert "Not finished: the move of joints 1, 4" in md
    for name in ("rotation_errors.png", "rotation_positions.png"):     # the whole run, not the move's samples,
        assert figures[name] == [(f"joint {j}", 0.0, pytest.approx(1.928))    # and the joint with a warning too
                                 for j in ("1", "2 (not moved)", "4")]


def test_the_report_of_a_run_interrupted_before_its_first_sample_says_so(tmp_path):
    """A Ctrl-C in the first moments leaves a data table of no rows (issue 32): `wamctl report` on it said
    `IndexError: index 0 is out of bounds` with a traceback; it reports the run as interrupted, nothing scored."""
    from cli_runs import run_cli

    from wamctl.runs.store import RunDir

    spec = {"kind": "rotation", "name": "early", **SPEC}
    run = RunDir.create(tmp_path, "early", spec, 0, "rotation")
    run.write_table("data", rotation_data(joints=(1,)).iloc[:0])
    run.finish("interrupted", "stopped by Ctrl-C")
    r = run_cli("report", run.path, "--out", tmp_path / "report")
    assert r.exc is None, r.tb
    assert r.code == 0 and r.out.splitlines()[0].startswith("interrupted: stopped by Ctrl-C"), (r.out, r.err)
    assert '"rpe_pct": {}' in (tmp_path / "report" / "report.json").read_text()     # nothing scored
