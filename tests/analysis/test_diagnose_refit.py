"""One ``ModelDiagnosis`` fitted on a second run diagnoses it as a new one would: nothing the first run left
(the friction map of its joints, say) is read for the second."""

from __future__ import annotations

import json

from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.runs.measured import load_run_data


def _run(case_id: str, tmp_path):
    from gen_independent import cases, generate

    case = next(c for c in cases(1, 0, 0, 0) if c["id"] == case_id)
    d = tmp_path / case_id
    generate(case, d)
    return d, load_run_data(d)


def test_a_second_fit_reads_nothing_of_the_first_run(tmp_path):
    (_, first), (path, second) = _run("position_ripple-000", tmp_path), _run("stribeck-000", tmp_path)
    reused = ModelDiagnosis(jobs=1)
    reused.fit(first)
    reused.fit(second)
    fresh = ModelDiagnosis(jobs=1).fit(second)
    assert fresh.map_tests_, "the second run was chosen for its friction-map tests"
    # the friction map of the second run's joint 7 alone (12 rows), not the first run's five joints (84 rows)
    assert len(reused.friction_map_) == len(fresh.friction_map_)
    assert repr(reused.map_tests_) == repr(fresh.map_tests_)
    as_json = [json.dumps(d.to_dict(str(path)), sort_keys=True, default=repr) for d in (reused, fresh)]
    assert as_json[0] == as_json[1]
