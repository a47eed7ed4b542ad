"""Runs pooled: a name one run kept gives way when the runs' onsets prefer the other of a delay and a gap behind a
motor-side encoder (issue 28, D8; :meth:`PooledDiagnosis._gap_or_delay`, :meth:`PooledDiagnosis._delay_kept_or_gap`).
The onsets' head to head is replaced by its record (its own tests: test_delay_backlash.py)."""

from types import SimpleNamespace

import pytest

from wamctl.analysis.diagnosis import delay_backlash as DB
from wamctl.analysis.diagnosis.pooled import PooledDiagnosis


def _pooled(diags):
    p = PooledDiagnosis(diags, [f"run{k}" for k in range(len(diags))], [None] * len(diags))
    p.delay_term_ = {"name": "delay", "h_all": 0.006}
    return p


def _gap_run():
    kept = [{"name": "backlash", "encoder_side": "motor"}]
    return SimpleNamespace(conclusive_=True, joints_={6: SimpleNamespace(kept=kept, ambiguous=[])})


def _h2h(log_ratio):
    def fake(diags, labels, j, delay_s):
        out = ("backlash" if log_ratio >= DB.DECIDED_LOG_RATIO else "delay" if log_ratio <= -DB.DECIDED_LOG_RATIO
               else "ambiguous")
        return {"outcome": out, "log_ratio": log_ratio, "delay_s": delay_s, "joint": j + 1, "per_run": {}}
    return fake


@pytest.mark.parametrize("lr, named", [(-11.0, False), (-7.0, True), (1.0, True), (7.0, True)])
def test_an_onset_only_gap_gives_way_to_the_pooled_delay(monkeypatch, lr, named):
    """Named by one run; the runs' onsets stacked with the pooled delay: -11 prefers the delay very strongly (not
    named, with why); -7 (strong, not very strong: a run's name stays), +1 or +7 does not."""
    monkeypatch.setattr(DB, "pooled_head_to_head", _h2h(lr))
    p = _pooled([_gap_run(), _gap_run()])
    finding = {"name": "backlash", "joint": 7, "pooled": {"named": True, "p_value": None}}
    p._gap_or_delay(finding, 6, [0, 1])
    assert finding["pooled"]["named"] is named
    assert finding["delay_vs_gap"]["log_ratio"] == pytest.approx(lr)
    if not named:
        assert "6.0 ms delay" in finding["pooled"]["basis"]


@pytest.mark.parametrize("lr, outcome", [(11.0, "ambiguous"), (7.0, "delay"), (1.0, "delay")])
def test_a_delay_kept_by_one_run_gives_way_to_a_gap_the_onsets_prefer(monkeypatch, lr, outcome):
    """A delay no run decided (kept because a run named it) against a gap some run kept: the runs' onsets with
    the pooled delay prefer the gap very strongly (+11): ambiguous, with what it gave way to; +7 (dev
    pair-delay+stribeck-009: a designed run's Stribeck breakaways read as leads at joint 7) or +1: the delay
    stays."""
    monkeypatch.setattr(DB, "pooled_head_to_head", _h2h(lr))
    p = _pooled([_gap_run(), _gap_run()])
    dec = {"fitted_delay_s": 0.006, "decided_by": ["run0"]}
    assert p._delay_kept_or_gap(dec, [0, 1]) == outcome
    if outcome == "ambiguous":
        assert dec["gave_way_to"]["name"] == "backlash" and dec["decided_by"] == []
