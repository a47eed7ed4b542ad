"""Backlash with the encoder on the motor side (issue 15): the measurement leads the link at reversals.

The independent generator's backlash is a two-inertia joint whose encoder sits on the rotor: at a reversal the
rotor crosses the gap with only its own inertia and friction before it takes the link along, so the measured
position moves before the rigid model's link could (the opposite of a dead band behind the encoder, which the
first generator simulates). A run of that generator on joint 1 (no gravity: the drive's torque changes sign at
every reversal, so the gap is crossed each time) must come out as ``backlash`` on the motor side, and the same run
without the gap must not name it.

Tolerances, fixed before the runs were looked at: the width within a factor of two of the gap (what the encoder
measures at a reversal is the lost motion, the gap plus the change of the drive's deflection, and a reversal whose
gap is crossed during the deceleration shows part of it); the interval contains the width and is narrower than
the width itself; the held-out torque RMS at the joint drops by a fifth at least.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from gen_independent import generate

from wamctl.analysis.diagnosis.augmented import plant_dict
from wamctl.analysis.diagnosis.backlash import band_width, signed_travel, turning_point
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.runs.measured import load_run_data

GAP_RAD = 0.006
BACKLASH = dict(name="backlash", joint=1, size="medium",
                params=dict(gap_rad=GAP_RAD, resonance_hz=90.0, zeta=0.2, link_friction_share=0.3))
CASE = dict(id="backlash-motor-j1", seed=424242, effects=[BACKLASH], links="nominal", excitation="free",
            joint=1, free_joints=[1, 4], rate_hz=500, noise="quiet", jitter="stamp")


def _diagnose(case: dict, path):
    r = generate(case, path)
    logging.disable(logging.WARNING)
    try:
        return r, ModelDiagnosis().fit(load_run_data(r.path))
    finally:
        logging.disable(logging.NOTSET)


@pytest.fixture(scope="module")
def motor_side(tmp_path_factory):
    root = tmp_path_factory.mktemp("motor_side")
    return (_diagnose(CASE, root / "backlash"),
            _diagnose(dict(CASE, id="clean-motor-j1", effects=[]), root / "clean"))


def test_motor_side_backlash_is_named_with_its_width(motor_side):
    (run, diag), _ = motor_side
    assert run.truth["effects"][0]["observable"]
    out = diag.to_dict()
    assert out["effects_found"][:1] == ["backlash"], out["effects_found"]
    joint = out["joints"]["1"]
    e = next(e for e in joint["effects"] if e["name"] == "backlash")
    p, ci = e["params"], e["params_ci"]["width_rad"]
    assert p["encoder_side"] == "motor"
    assert "gravity_offset_rad" not in p          # a gap on the motor side has no gravity offset column
    assert 0.5 * GAP_RAD <= p["width_rad"] <= 2.0 * GAP_RAD, p
    assert ci[0] <= p["width_rad"] <= ci[1] and ci[1] - ci[0] < p["width_rad"]
    assert joint["torque_rms_after_Nm"] <= 0.8 * joint["torque_rms_before_Nm"]
    assert any("motor side" in w for w in out["warnings"])       # the plant cannot write it: said, and left out
    assert "backlash" not in plant_dict(diag)["effects"]


def test_same_run_without_the_gap_names_no_backlash(motor_side):
    _, (run, diag) = motor_side
    assert "backlash" not in diag.effects_found_
    for res in diag.joints_.values():
        assert not res.candidates.get("backlash", {}).get("kept", False)


def test_signed_travel_lags_and_leads():
    """The model's link (from rest) and the measurement, one moving ``w`` before the other along a ramp."""
    tol, w, n = 1e-4, 3e-3, 200
    ramp = np.maximum(np.arange(n) - 50, 0) * 2e-4                  # starts moving at sample 51
    # a dead band behind the encoder: the measurement moves w later than the link
    q_lag = np.maximum(ramp - w, 0.0)
    stall = int(np.flatnonzero(q_lag > tol)[0])
    assert signed_travel(ramp, q_lag, stall, 0.0, 1.0, tol) == pytest.approx(w, abs=2.5e-4)
    # the encoder on the motor: the measurement crossed w before the link moved (new direction negative)
    q_lead = -(ramp + w * (np.arange(n) >= 20))
    stall = int(np.flatnonzero(-q_lead > tol)[0])
    assert signed_travel(-ramp, q_lead, stall, 0.0, -1.0, tol) == pytest.approx(-w, abs=2.5e-4)
    # the model's link never moves: nothing to compare
    assert np.isnan(signed_travel(np.zeros(n), q_lead, stall, 0.0, -1.0, tol))


def test_band_width_and_turning_point():
    rev = np.array([True] * 8 + [False] * 4)
    lag = np.r_[np.full(8, 5e-3), np.full(4, 1e-4)]
    assert band_width(lag, rev) == pytest.approx(5e-3 - 1e-4)
    # a gap on the motor side crossed at five reversals out of eight (a flank kept at the other three)
    lead = np.r_[np.full(5, -4e-3), np.full(3, -1e-4), np.zeros(4)]
    assert band_width(lead, rev) == pytest.approx(-4e-3)
    # a baseline of the other sign does not widen the band (dev friction_drift-007, joint 7: the measurement led
    # the model by 0.3-0.8 mrad at reversals, the model led it by 0.3-0.55 mrad at same-direction onsets: a
    # "gap" of 1.07 mrad was named beside the drift); a baseline the reversals' way is still taken off
    rev6 = np.array([True] * 6 + [False] * 3)
    light = np.r_[-0.822, -0.308, -0.308, -0.308, -0.822, -0.308, 0.315, 0.402, 0.548] * 1e-3
    assert band_width(light, rev6) == pytest.approx(-np.mean([0.822, 0.822, 0.308]) * 1e-3)
    assert band_width(np.r_[np.full(6, -4e-3), np.full(3, -1e-3)], rev6) == pytest.approx(-3e-3)
    assert band_width(np.r_[np.full(6, 5e-3), np.full(3, -1e-3)], rev6) == pytest.approx(5e-3)
    q = np.r_[np.linspace(0.0, -0.01, 50), np.full(20, -0.0101), np.linspace(-0.0101, 0.0, 51)[1:]]
    assert turning_point(q, 55, 75, 1.0, 20) == 69            # the last sample of the old direction's extreme


def _onsets_reference(t_s, q_raw, qd_s, v_stick, tol, min_len):
    """find_onsets written with numpy slices, one stall at a time (the compiled kernel's reference)."""
    from wamctl.analysis.diagnosis.backlash import sliding_stretches

    st = sliding_stretches(q_raw, qd_s, v_stick, tol, min_len)
    out = []
    for (p0, p1, d_prev), (s0, s1, d_new) in zip(st[:-1], st[1:]):
        lo, hi = max(p1 - min_len, p0), min(s0 + min_len, s1)
        mid_i = lo + int(np.argmin(np.abs(q_raw[lo:hi] - np.median(q_raw[p1:s0 + 1]))))
        q_stall = q_raw[mid_i]
        off = np.abs(q_raw[p0:s1] - q_stall) > tol
        m = mid_i - p0
        before, after = np.flatnonzero(off[:m]), np.flatnonzero(off[m:])
        a = p0 + (before[-1] + 1 if len(before) else 0)
        b = p0 + m + after[0] if len(after) else s1
        if b >= min(s1, len(q_raw)) or b - a < 2 or np.sign(q_raw[b] - q_stall) != d_new:
            continue
        rev = d_new != d_prev
        t0 = max(a - min_len, 0)
        seg = d_new * q_raw[t0:b + 1]          # the turning point: the last sample furthest the old way
        out.append((a, b, rev, d_new, float(t_s[b]), t0 + len(seg) - 1 - int(np.argmin(seg[::-1])) if rev else a))
    return out


def test_find_onsets_is_its_numpy_reference():
    """The compiled stall search gives onset for onset what the numpy one gives, on 150 quantised random motions
    (several hundred onsets, reversals and same-direction stalls)."""
    from wamctl.analysis.diagnosis.backlash import find_onsets

    rng = np.random.default_rng(0)
    total = reversals = 0
    for _ in range(150):
        n = int(rng.integers(200, 4000))
        t = np.arange(n) / 500.0
        v = np.cumsum(rng.normal(size=n)) * 0.002 * rng.uniform(0.2, 3)
        step = float(rng.choice([1e-4, 5e-5, 2e-4]))
        q = np.cumsum(v - v.mean()) / 500.0
        q = np.round((q + rng.normal(scale=0.3 * step, size=n)) / step) * step
        qd = np.convolve(np.gradient(q) * 500, np.ones(9) / 9, mode="same")
        v_stick, tol = rng.uniform(0.002, 0.02), 2 * step
        got = [(o.start, o.end, o.reversal, o.sign_new, o.t_s, o.turn) for o in find_onsets(t, q, qd, v_stick, tol, 10)]
        assert got == _onsets_reference(t, q, qd, v_stick, tol, 10)
        total += len(got)
        reversals += sum(g[2] for g in got)
    assert total > 300 and 0 < reversals < total
