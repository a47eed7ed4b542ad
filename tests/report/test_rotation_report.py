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
