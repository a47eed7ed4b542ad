"""The torque a plan needs is checked against the limits for every kind that plans motion (issue 32 item 2): the
friction sweep's validation rotation and the IFT task, not only the rotation test."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from wamctl.errors import SpecError
from wamctl.experiments.runner import plan_only
from wamctl.specs.load import parse_spec

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _spec(name: str, **changes):
    raw = yaml.safe_load((CONFIGS / name).read_text())
    for path, value in changes.items():
        d = raw
        *head, last = path.split(".")
        for k in head:
            d = d[k]
        d[last] = value
    return parse_spec(raw, name)


def test_the_shipped_specs_pass_the_torque_check():
    for name, prefix in (("friction_sweep.yaml", "validation: torque needed at most"),
                         ("ift.yaml", "torque needed at most")):
        _, checks = plan_only(_spec(name), CONFIGS)
        assert any(prefix in c for c in checks), (name, checks)


def test_a_friction_sweep_whose_validation_rotation_saturates_is_refused():
    # joint 2's return from +0.5 rad at the sweep's start pose needs 20.9 N m against its 20 N m limit
    with pytest.raises(SpecError, match=r"validation: move 4 of 14 \(return joint 2.*would saturate joint 2.*"
                                        r"-20\.9\d N m"):
        plan_only(_spec("friction_sweep.yaml", **{"validation.amplitude_rad": 0.5}), CONFIGS)


def test_an_ift_task_that_saturates_is_refused():
    # a 0.6 rad task on joint 2 from the IFT pose: its return needs more than the 20 N m limit
    with pytest.raises(SpecError, match=r"ift\.task: .*would saturate joint 2"):
        plan_only(_spec("ift.yaml", **{"ift.task.amplitude_rad": 0.6}), CONFIGS)
