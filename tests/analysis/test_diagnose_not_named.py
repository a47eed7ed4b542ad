"""Issue 28, the silent drop: what the diagnosis sees and does not name is said.

* an arm-level finding no joint kept (the payload-or-links decision said ``link_parameters``, the arm's link refit
  explains most of the residual, and link_parameters was not named) is in ``not_named`` with the share it explains
  and why, and in the one-line summary;
* on a run of the independent generator moving joints 2 and 4 with a large payload and a large position ripple at
  joint 4: the payload is named, and the ripple is named at joint 4 or its residual is said there as a structured
  unexplained residual (following the position), in ``diagnosis.json`` and in the summary line.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest

from wamctl.analysis.diagnosis.unexplained import arm_unnamed
from wamctl.report.diagnosis import found_line, not_named_lines


def _diag(outcome: str, found: list[str], candidates=("payload", "link_parameters"), reason=None):
    cands = {} if reason is None else {"link_parameters": {"kept": False, "reason": reason}}
    return SimpleNamespace(
        payload_vs_links_={"outcome": outcome, "joints": [2, 4],
                           "ssr_ratio": {"links": 0.2, "payload+links": 0.19, "wide_links": 0.1,
                                         "payload+wide_links": 0.1}},
        effects_found_=found, ambiguous_=[], candidates=candidates, payload_dropped_=None,
        joints_={1: SimpleNamespace(candidates=cands), 3: SimpleNamespace(candidates=cands)})


def test_link_errors_found_at_the_arm_and_not_named_are_said():
    """Outcome link_parameters, its refit leaving 20 % of the held-out residual, link_parameters not kept: one
    entry naming it, joints 2 and 4, the share explained (80 %) and the joints' own reason; the summary line says
    it was seen and not named (the old code said 'effects found: none' and nothing else)."""
    why = "a refit of the arm's link parameters does not add to the model of the joints (p = 0.02)"
    out = arm_unnamed(_diag("link_parameters", [], reason=why))
    assert len(out) == 1
    u = out[0]
    assert u["name"] == "link_parameters" and u["joints"] == [2, 4]
    assert u["held_out_ssr_ratio"] == pytest.approx(0.2)
    assert "80%" in u["why"] and why in u["why"]
    result = {"conclusive": True, "effects_found": [], "ambiguous": [], "not_named": out, "joints": {}}
    assert found_line(result) == "effects found: none; seen, not named: link_parameters"
    assert not_named_lines(result)[0].startswith("not named: link_parameters (joints 2, 4): ")


def test_nothing_left_out_when_the_arm_finding_is_named():
    """Named (link_parameters kept, or the payload kept on a payload outcome), or not a candidate: the entry is
    absent in the first two cases and says 'not among the candidates tested' in the third."""
    assert arm_unnamed(_diag("link_parameters", ["link_parameters"])) == []
    assert arm_unnamed(_diag("payload", ["payload"])) == []
    u = arm_unnamed(_diag("link_parameters", [], candidates=("payload",)))
    assert "not among the candidates tested" in u[0]["why"]


def test_payload_at_joint_2_and_ripple_at_joint_4_both_said(tmp_path):
    """Joints 2 and 4 move (free excitation), a large wrist payload and a large position ripple at joint 4
    (seed fixed before the run was looked at): payload is named; the ripple is named at joint 4, or joint 4's
    residual is said unexplained and following the position; either way the summary line carries it."""
    from gen_independent import generate

    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    case = {"id": "payload-ripple", "seed": 9301, "links": "nominal", "rate_hz": 500, "noise": "quiet",
            "jitter": "stamp", "excitation": "free", "joint": 2, "free_joints": [2, 4],
            "effects": [{"name": "payload", "size": "large"},
                        {"name": "position_ripple", "joint": 4, "size": "large"}]}
    r = generate(case, tmp_path / case["id"])
    assert r.truth["expected_effects"] == ["payload", "position_ripple"]
    logging.disable(logging.WARNING)
    try:
        out = ModelDiagnosis().fit(load_run_data(r.path)).to_dict()
    finally:
        logging.disable(logging.NOTSET)
    assert "payload" in out["effects_found"], out["effects_found"]
    j4 = out["joints"]["4"]
    named = any(e["name"] == "position_ripple" for e in j4["effects"])
    said = j4.get("unexplained") is not None and "position" in j4["unexplained"]["correlates_with"]
    assert named or said, (j4["effects"], j4.get("unexplained"))
    line = found_line(out)
    assert "payload" in line
    assert "position_ripple" in line or "unexplained residual at joint" in line and "4" in line.split("joint")[-1]
    if not named:
        assert any(s.startswith("unexplained residual at joint 4:") and "follows position" in s
                   for s in not_named_lines(out))
