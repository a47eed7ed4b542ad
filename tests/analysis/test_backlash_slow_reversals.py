"""Issue 28, a motor-side gap crossed at slow reversals: the onset's window reaches the model's link.

At each reversal of a slow back-and-forth motion the motor crosses the gap alone, and the measurement leads the
link by the gap. The model's link (rigid, no gap) starts to move only when the torque has turned round; at the
slow reversals a designed run makes, that is later than the 100 samples kept after the measured stall. The onset
was then given up (its hidden travel NaN): the reversals of such a run were dropped, on a designed run all of
them ("0 reversals measured"), and the run designed to decide the gap named nothing. The window is now extended
(up to ``EXTEND_MAX_S``, never into the next onset) where the model's link has not moved within it.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from wamctl.analysis.diagnosis import onsets as onsets_mod

GAP_RAD = 0.003          # a small gap (the generator's "small" range)
PERIOD_S = 16.0


def _spec(periods: int) -> dict:
    """Joint 7 alone, two harmonics (two reversals and a dwell per period), at a wrist pose; the form of the
    reversal design's next_experiment.yaml."""
    a = 0.25 * 2 * np.pi / PERIOD_S
    return {"kind": "excitation", "name": "slow-reversals", "seed": 0,
            "q0_rad": [-0.67, 0.08, 0.06, 0.77, -0.57, 0.55, -0.03],
            "excitation": {"joints": [7], "period_s": PERIOD_S, "harmonics": 2, "periods": periods,
                           "settle_s": 1.0, "coefficients": {7: {"a_rad_s": [a, -a], "b_rad_s": [0.0, 0.0]}}}}


@pytest.fixture(scope="module")
def slow_run(tmp_path_factory):
    from gen_independent import generate

    case = {"id": "slow-reversals", "seed": 41, "links": "nominal", "rate_hz": 500, "noise": "quiet",
            "jitter": "stamp", "excitation": "designed", "reference": _spec(3),
            "effects": [{"name": "backlash", "joint": 7, "size": "small",
                         "params": {"gap_rad": GAP_RAD, "link_friction_share": 0.3}}]}
    return generate(case, tmp_path_factory.mktemp("slow") / case["id"])


def _diagnose(path):
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    logging.disable(logging.WARNING)
    try:
        return ModelDiagnosis().fit(load_run_data(path))
    finally:
        logging.disable(logging.NOTSET)


def test_slow_reversals_through_a_gap_keep_their_onsets_and_name_it(slow_run):
    diag = _diagnose(slow_run.path)
    ons = diag.onsets_[6]
    rev = ons["reversal"]
    assert rev.sum() >= 5
    # every reversal's hidden travel is measured, and it is a lead (the encoder on the motor side of the gap)
    assert np.isfinite(ons["travel_rad"][rev]).all()
    assert (ons["travel_rad"][rev] < -2 * ons["tol_rad"]).all()
    assert diag.effects_found_[:1] == ["backlash"]
    c = diag.joints_[6].candidates["backlash"]
    assert c["encoder_side"] == "motor"


def test_the_short_window_alone_lost_every_reversal(slow_run, monkeypatch):
    """The same run with the window of 100 samples only (the method before): the reversals of one direction are
    lost (their travel NaN). On this 3-period run the other half still named the gap; the designed run of the
    report split's backlash-009 (6 periods of this motion, a 3 mrad gap) lost all 12 and named nothing."""
    monkeypatch.setattr(onsets_mod, "EXTEND_MAX_S", 0.0)
    diag = _diagnose(slow_run.path)
    ons = diag.onsets_[6]
    assert (~np.isfinite(ons["travel_rad"][ons["reversal"]])).sum() >= 2
