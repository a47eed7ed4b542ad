"""A 4-DOF WAM (robot wam4) end to end: a friction sweep logged as libbarrett's exportCSV writes it, imported with
``wamctl import --robot wam4``, then ``wamctl friction-id --data``: the robot comes from the run (four joints, the
wam4's own links), the friction found is the one put in."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from cli_runs import run_cli

from wamctl.model.dynamics import WamDynamics

RATE_HZ = 500.0
Q0 = np.array([0.0, 0.4, 0.0, 1.2])
FC_NM = np.array([3.0, 2.0, 1.5, 1.0])              # Coulomb level, both directions
VISCOUS_NM_S_RAD = np.array([1.0, 2.0, 0.5, 0.8])
SPEEDS_RAD_S = (0.1, 0.2, 0.35, 0.6)
AMPLITUDE_RAD = 0.4
BLEND_S = 0.15


def _lspb(travel: float, v: float, dt: float):
    """Trapezoidal profile of ``travel`` at cruise speed ``v`` with ``BLEND_S`` blends: (x, xd, xdd) samples."""
    a = v / BLEND_S
    T = abs(travel) / v + BLEND_S
    t = np.arange(0.0, T + dt / 2, dt)
    s = np.sign(travel)
    x = np.where(t < BLEND_S, 0.5 * a * t ** 2,
                 np.where(t < T - BLEND_S, 0.5 * a * BLEND_S ** 2 + v * (t - BLEND_S),
                          abs(travel) - 0.5 * a * (T - t) ** 2))
    xd = np.where(t < BLEND_S, a * t, np.where(t < T - BLEND_S, v, a * (T - t)))
    xdd = np.where(t < BLEND_S, a, np.where(t < T - BLEND_S, 0.0, -a))
    return s * x, s * xd, s * xdd


def sweep(seed: int = 0):
    """Each joint in turn out and back at each speed, the others held, 0.5 s holds; the wam4's inverse dynamics
    plus the friction above plus 0.05 N m noise as the total torque; 20 urad encoder noise on q."""
    dt = 1.0 / RATE_HZ
    q, qd, qdd = [np.tile(Q0, (int(0.5 * RATE_HZ), 1))], [np.zeros((int(0.5 * RATE_HZ), 4))], \
        [np.zeros((int(0.5 * RATE_HZ), 4))]
    hold = int(0.5 * RATE_HZ)
    for j in range(4):
        for v in SPEEDS_RAD_S:
            for travel in (AMPLITUDE_RAD, -AMPLITUDE_RAD):
                x, xd, xdd = _lspb(travel, v, dt)
                base = q[-1][-1].copy()
                blk = np.tile(base, (len(x), 1))
                blk[:, j] += x
                d1, d2 = np.zeros_like(blk), np.zeros_like(blk)
                d1[:, j], d2[:, j] = xd, xdd
                q.append(blk)
                qd.append(d1)
                qdd.append(d2)
                q.append(np.tile(blk[-1], (hold, 1)))
                qd.append(np.zeros((hold, 4)))
                qdd.append(np.zeros((hold, 4)))
    q, qd, qdd = (np.concatenate(x) for x in (q, qd, qdd))
    rng = np.random.default_rng(seed)
    tau = WamDynamics(robot="wam4").inverse_dynamics_many(q, qd, qdd)
    tau += FC_NM * np.sign(np.round(qd, 9)) + VISCOUS_NM_S_RAD * qd + rng.normal(0, 0.05, tau.shape)
    q_meas = q + rng.normal(0, 2e-5, q.shape)
    t = np.arange(len(q)) / RATE_HZ
    return t, q, q_meas, tau


@pytest.fixture(scope="module")
def wam4_sweep_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wam4")
    t, q_ref, q, tau = sweep()
    src = tmp / "wam4_sweep.csv"
    # log::Reader::exportCSV: ostream defaults (%g, 6 significant digits), no header
    src.write_text("".join(",".join(f"{v:g}" for v in (t[k], *q_ref[k], *q[k], *tau[k])) + "\n"
                           for k in range(len(t))))
    r = run_cli("import", src, "--format", "libbarrett-csv", "--layout", "t,q_ref[4],q[4],tau[4]", "--robot",
                "wam4", "--rate-hz", 500, "--torque", "total", "--out", tmp / "runs", "--json")
    assert r.code == 0, r.err
    return tmp, json.loads(r.out)["run_dir"]


def test_friction_id_on_an_imported_wam4_sweep(wam4_sweep_run):
    tmp, run = wam4_sweep_run
    r = run_cli("friction-id", "--data", run, "--out", tmp / "fid")
    assert r.code == 0, r.err
    model = yaml.safe_load(next((tmp / "fid").glob("*/friction_model.yaml")).read_text())
    joints = model["joints"]
    assert sorted(int(j) for j in joints) == [1, 2, 3, 4]            # the wam4's four joints, no 5..7
    assert "not_identified" not in model
    for j in range(1, 5):
        p = joints[j]
        assert p["fc_pos_Nm"] == pytest.approx(FC_NM[j - 1], abs=0.03), (j, p)
        assert p["fc_neg_Nm"] == pytest.approx(FC_NM[j - 1], abs=0.03), (j, p)
        assert p["viscous_pos_Nm_s_rad"] == pytest.approx(VISCOUS_NM_S_RAD[j - 1], abs=0.05), (j, p)
        assert p["viscous_neg_Nm_s_rad"] == pytest.approx(VISCOUS_NM_S_RAD[j - 1], abs=0.05), (j, p)


def test_the_wam7_datasheet_would_not_explain_the_wam4(wam4_sweep_run):
    """The robot matters: the wam7's links in place of the wam4's move joint 2's friction by newton metres (so the
    test above checks that the run's robot is used)."""
    t, q_ref, q, tau = sweep()
    dyn4 = WamDynamics(robot="wam4")
    q7 = np.column_stack([q_ref, np.zeros((len(q_ref), 3))])
    g4 = dyn4.gravity_many(q_ref[::500])
    g7 = WamDynamics().gravity_many(q7[::500])[:, :4]
    assert np.abs(g4 - g7)[:, 1].max() > 1.0


def test_controller_torque_uses_only_the_joints_without_gravity(tmp_path):
    """``--torque controller`` (gravity compensation added downstream, not logged): joint 1's axis is vertical,
    so its logged torque is its whole torque and it is identified; joints 2-4 are refused with the reason and
    listed as not identified in friction_model.yaml."""
    t, q_ref, q, tau = sweep(seed=1)
    tau_ctrl = tau - WamDynamics(robot="wam4").gravity_many(q_ref)
    src = tmp_path / "wam4_ctrl.csv"
    src.write_text("".join(",".join(f"{v:g}" for v in (t[k], *q_ref[k], *q[k], *tau_ctrl[k])) + "\n"
                           for k in range(len(t))))
    r = run_cli("import", src, "--format", "libbarrett-csv", "--layout", "t,q_ref[4],q[4],tau[4]", "--robot",
                "wam4", "--rate-hz", 500, "--torque", "controller", "--out", tmp_path / "runs", "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    r = run_cli("friction-id", "--data", run, "--out", tmp_path / "fid")
    assert r.code == 0, r.err
    model = yaml.safe_load(next((tmp_path / "fid").glob("*/friction_model.yaml")).read_text())
    assert sorted(int(j) for j in model["joints"]) == [1]
    assert model["joints"][1]["fc_pos_Nm"] == pytest.approx(FC_NM[0], abs=0.03)
    assert model["joints"][1]["viscous_neg_Nm_s_rad"] == pytest.approx(VISCOUS_NM_S_RAD[0], abs=0.05)
    assert sorted(int(j) for j in model["not_identified"]) == [2, 3, 4]
    assert "gravity compensation not logged" in model["not_identified"][2]
