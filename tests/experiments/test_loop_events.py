"""Issue 32, item 2: a joint held at its torque limit, or off its reference, is an event of the run (one row per
stretch in events.csv: start, duration, peak) on every backend, the simulator and the CAN arm (simulated pucks on
python-can's virtual bus), because the loop and its bookkeeping are shared."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
from conftest import rotation_spec

from wamctl.analysis.loop_events import LoopEvent
from wamctl.backends import make_backend
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.common import closed_loop_stage, make_joint_controller
from wamctl.model import params as P
from wamctl.runs.store import RunDir, read_events, read_table
from wamctl.specs import parse_spec

pytestmark = pytest.mark.timeout(180)

# Joint 2 tilted forward (0.5 rad) with the elbow at 1.57 rad: holding it takes 17.2 N m of its 20 N m; lifting it
# back (negative velocity) adds 3.56 N m of Coulomb friction: more than the limit, so the joint stays put.
Q0_TILTED = [0.0, 0.5, 0.0, 1.57, 0.0, 0.0, 0.0]


def lift_back_reference():
    """0.2 s still, joint 2 back by 0.1 rad at 0.1 rad/s (t_c 0.25 s: 1.25 s), 0.5 s hold: 1.95 s."""
    return (ReferenceBuilder(Q0_TILTED, 1.0 / P.CONTROL_RATE_HZ).hold(0.2, "settle")
            .move({1: -0.1}, 0.1, 0.25, "lift joint 2").hold(0.5, "hold").build())


@pytest.mark.parametrize("backend", ["sim", "can"])
def test_a_joint_held_at_its_torque_limit_is_one_event_on_every_backend(tmp_path, backend):
    extra = {} if backend == "sim" else {
        "backend": {"kind": "can", "interface": "virtual", "channel": f"wamctl-test-{uuid.uuid4().hex[:12]}",
                    "simulate_pucks": True, "watchdog_cycles": 25, "reply_timeout_s": 0.05}}
    spec = parse_spec(rotation_spec(q0_rad=Q0_TILTED, **extra))
    ref = lift_back_reference()
    run = RunDir.create(tmp_path, "t", spec.model_dump(mode="json"), spec.seed, "rotation")
    with make_backend(spec, None) as be:
        closed_loop_stage(be, make_joint_controller(spec), ref, run)
    run.finish("completed")

    data = read_table(run.path)
    tau2 = data["tau_2_Nm"].to_numpy()
    at_limit = np.abs(tau2) >= 20.0 - 1e-9
    assert at_limit.sum() / P.CONTROL_RATE_HZ > 1.0       # the loop did hold joint 2 at its limit for over 1 s

    ev = read_events(run.path)
    sat = ev[ev["kind"] == "torque_saturation"]
    assert sat["joint"].tolist() == [2]                   # one row for the whole stretch, no other joint
    e = LoopEvent.from_row("torque_saturation", 2, sat["detail"].iloc[0])
    first, last = np.flatnonzero(at_limit)[[0, -1]]
    assert e.start_s == pytest.approx(data["t_s"].iloc[first], abs=1e-3)
    assert e.duration_s == pytest.approx(data["t_s"].iloc[last] - data["t_s"].iloc[first], abs=0.25)
    assert e.peak == pytest.approx(-20.0) and e.limit == 20.0
    assert sat["t_s"].iloc[0] == pytest.approx(e.start_s, abs=1e-6)
    track = ev[ev["kind"] == "tracking_error"]
    assert track["joint"].tolist() == [2]                 # it fell 0.1 rad behind: beyond 0.05 rad
    t = LoopEvent.from_row("tracking_error", 2, track["detail"].iloc[0])
    assert t.peak == pytest.approx(-0.1, abs=0.01) and t.limit == 0.05   # q_ref - q: 0.4 - 0.5 rad
