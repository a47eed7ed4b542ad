"""Issue 28: the runs pooled do not lose a name the first run made unless the added run's evidence contradicts it.

The independent generator's dev case ``pair-delay+stribeck-009``'s sibling ``pair-delay+stribeck-002``
(``cases(10, 0, seed=0, 20)``: a 2-4 ms delay and a medium Stribeck effect at joint 7, a free run of joints 5-7 at
500 Hz, noisy): alone, the diagnosis names delay and stribeck (Stribeck seen at the breakaways); its delay-or-inertia
check leaves the two ambiguous and the designed run predicts a separation below its target (under 2 noise floors,
said: ``decisive`` false). Pooled with that run, before: ``ambiguous`` delay or inertia and nothing named (the
delay lost: neither run's excess reached a noise floor; the Stribeck effect lost: the sliding samples do not show
it and the breakaways that did, added from the onsets, were not recognised). Now both are kept, each with why.
"""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow


def _diagnose(path):
    from diagnosis_gen import diagnose_quietly

    return diagnose_quietly(path)


def test_a_below_target_designed_run_does_not_lose_the_first_runs_names(tmp_path):
    from gen_independent import cases, follow_up, generate

    from wamctl.analysis.diagnosis.pooled import PooledDiagnosis
    from wamctl.experiments.diagnose_next import next_experiment_delay

    case = next(c for c in cases(10, 0, 0, 20) if c["id"] == "pair-delay+stribeck-002")
    first = generate(case, tmp_path / "run").path
    diag, data = _diagnose(first)
    assert diag.effects_found_[:2] == ["delay", "stribeck"]
    out = next_experiment_delay(diag, data, first, tmp_path)
    assert out["spec"] and out["decision"]["outcome"] == "ambiguous"
    assert out["separation_noise_floors"] < 2 and out["decisive"] is False
    assert "still below 2" in out["why"]
    nxt = follow_up(first, tmp_path / "next_experiment.yaml", tmp_path / "next")
    diag2, data2 = _diagnose(nxt.path)
    p = PooledDiagnosis([diag, diag2], ["run", "next"], [data, data2]).fit()
    assert "delay" in p.effects_found_ and "stribeck" in p.effects_found_ and p.ambiguous_ == []
    d = next(f for f in p.findings_ if f["name"] == "delay")["delay_or_inertia"]
    assert "run" in d["named_by"] and not d["contradicted_by"]     # (the designed run names it alone too)
    assert all(r["excess_noise_floors"] < 1 for r in d["per_run"])     # no run decided it on its evidence alone
    s = next(f for f in p.findings_ if f["name"] == "stribeck")
    assert "named at the breakaways by run" in s["pooled"]["basis"]
