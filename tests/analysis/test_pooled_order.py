"""Pooled runs: the order of the effects named, when some were named on another basis than the pooled test.

Seen on the report split (backlash-005, a motor-side gap at joint 5): the designed run named the gap at its
reversals (onset test p 2e-13) and a Stribeck effect at its breakaways (p 2e-5); pooled, the gap (onsets only,
not tested again: p-value None) came after the Stribeck effect, whose pooled sliding-sample test gave p = 1 and
which was kept only because a run named it at the breakaways. A pooled p-value that did not name the effect is no
rank: such findings come after those the pooled test named, ordered by the evidence of the run that named them.
"""

from __future__ import annotations

from wamctl.analysis.diagnosis.pooled import effects_in_order


def _finding(name, p, run_p, basis=None, named=True):
    pooled = {"named": named, "p_value": p}
    if basis:
        pooled["basis"] = basis
    return {"name": name, "joint": 5, "pooled": pooled, "run_p_value": run_p}


def test_a_finding_kept_on_another_basis_is_ranked_by_its_run_evidence():
    findings = [_finding("backlash", None, 2.3e-13),
                _finding("stribeck", 1.0, 2.1e-5, basis="named at the breakaways by next")]
    assert effects_in_order(findings) == ["backlash", "stribeck"]
    # the other way round when the run's evidence for the breakaway effect is the stronger
    findings[1]["run_p_value"] = 1e-20
    assert effects_in_order(findings) == ["stribeck", "backlash"]


def test_findings_the_pooled_test_named_come_first_by_pooled_p():
    findings = [_finding("backlash", None, 1e-30),
                _finding("stribeck", 1.0, 1e-25, basis="named at the breakaways by run"),
                _finding("position_ripple", 1e-4, 1e-9),
                _finding("friction_drift", 1e-12, 1e-3),
                _finding("payload", 1e-40, 1e-40, named=False)]
    assert effects_in_order(findings) == ["friction_drift", "position_ripple", "backlash", "stribeck"]
