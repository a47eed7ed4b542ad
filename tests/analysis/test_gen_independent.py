"""The independent generator (tests/analysis/gen_independent/) checked on its own: its pinocchio model against a plain
DH product and the gradient of the potential energy, its 4 kHz integrator against RK45, a clean run's applied
torque against the true model without any fit, the files it writes (no truth in meta.yaml), the study plan, and a
loop that cannot hold reported rather than redrawn. Tolerances were set before running: numerical agreement for the
model (1e-12 m, 1e-6 N m), 1 % of the swing for the integrator, 2 % of the Coulomb level for the oracle residual.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest
import yaml
from gen_independent import EFFECTS, cases, generate
from gen_independent import arm as A
from gen_independent import physics as PH

MODEL = A.build_model()
DATA = MODEL.createData()


def _potential(q):
    return sum(A.LINK_MASS[i] * A.G0 * (T[:3, :3] @ A.LINK_COM[i] + T[:3, 3])[2]
               for i, T in enumerate(A.dh_fk_numpy(q)))


def test_model_matches_dh_product_and_potential_energy():
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(A.Q_MIN, A.Q_MAX)
        pin.forwardKinematics(MODEL, DATA, q)
        pin.updateFramePlacements(MODEL, DATA)
        for i, T in enumerate(A.dh_fk_numpy(q)):
            assert np.abs(DATA.oMf[MODEL.getFrameId(f"dh{i + 1}")].homogeneous - T).max() < 1e-12
        g_num = np.array([(_potential(q + 1e-6 * e) - _potential(q - 1e-6 * e)) / 2e-6 for e in np.eye(7)])
        assert np.abs(g_num - pin.computeGeneralizedGravity(MODEL, DATA, q)).max() < 1e-6


def test_integrator_against_rk45():
    """A frictionless, torque-free swing of 1 s from a tilted pose: the 4 kHz semi-implicit Euler kernel against
    scipy's RK45 on pinocchio's ABA, within 1 % of the swing."""
    from scipy.integrate import solve_ivp

    q0 = np.array([0.3, 0.8, -0.4, 1.2, 0.5, -0.6, 0.2])
    fr = np.zeros((8, 9))
    fr[:, 6], fr[:, 8] = 1.0, 1.0
    rip = np.zeros(9)
    rip[0] = -1
    dri, bkl = np.array([-1.0, 0, 0, 1, 1]), np.array([-1.0, 0, 0, 0, 1])
    x = np.zeros(16)
    x[:7] = q0
    W, st = np.zeros((8, 40)), np.zeros(8, np.int64)
    for n in range(4000):
        Minv = pin.computeMinverse(MODEL, DATA, x[:7])
        nle = pin.nonLinearEffects(MODEL, DATA, x[:7], x[7:14])
        PH.phys_step(x, np.zeros(7), Minv, nle, n * A.H_PHYS, fr, rip, dri, bkl, A.H_PHYS, 0.0, st, W)
    sol = solve_ivp(lambda t, y: np.r_[y[7:], pin.aba(MODEL, DATA, y[:7], y[7:], np.zeros(7))], (0, 1.0),
                    np.r_[q0, np.zeros(7)], rtol=1e-10, atol=1e-10)
    swing = np.abs(sol.y[:7, -1] - q0).max()
    assert swing > 0.1
    assert np.abs(sol.y[:7, -1] - x[:7]).max() < 0.01 * swing


@pytest.fixture(scope="module")
def clean_sweep(tmp_path_factory):
    case = dict(id="clean-sweep-j3", seed=103, effects=[], links="nominal", excitation="sweep", joint=3,
                rate_hz=500, noise="quiet", jitter="stamp")
    return generate(case, tmp_path_factory.mktemp("gen2") / "run")


def test_run_files_carry_no_truth(clean_sweep):
    d = clean_sweep.path
    meta = yaml.safe_load((d / "meta.yaml").read_text())
    assert meta["format"] == "wamctl-measured/1" and meta["payload"] is None
    text = (d / "meta.yaml").read_text().lower().replace("payload: null", "")
    for word in EFFECTS + ("truth", "ripple"):
        assert word not in text
    df = pd.read_parquet(d / "data.parquet")
    assert list(df.columns) == ["t"] + [f"{c}_{i}" for c in ("q_ref", "q", "tau") for i in range(1, 8)]
    assert not df.isna().any().any() and np.all(np.diff(df["t"]) > 0)
    assert clean_sweep.status == "ok" and clean_sweep.truth["expected_effects"] == []


def test_applied_torque_matches_the_true_model_without_a_fit(clean_sweep):
    """Over each 2 ms interval of the clean run (the joint sliding the whole interval), the torque really applied
    equals M(q) dv/dt + n(q, v) + the true classic friction at the interval's midpoint, within 2 % of Fc."""
    d = clean_sweep.path
    tr = yaml.safe_load((d / "truth.yaml").read_text())
    ts = pd.read_parquet(d / "truth_states.parquet")
    t = ts["t_sample"].to_numpy()
    q = ts[[f"q_true_{i}" for i in range(1, 8)]].to_numpy()
    v = ts[[f"qd_true_{i}" for i in range(1, 8)]].to_numpy()
    tau = ts[[f"tau_applied_{i}" for i in range(1, 8)]].to_numpy()
    st = ts[[f"stuck_{i}" for i in range(1, 8)]].to_numpy()
    fr = {k: np.array(x) for k, x in tr["friction_truth_classic"].items()}
    qm, vm = 0.5 * (q[1:] + q[:-1]), 0.5 * (v[1:] + v[:-1])
    a = np.diff(v, axis=0) / np.diff(t)[:, None]
    pred = np.array([pin.rnea(MODEL, DATA, qm[i], vm[i], a[i]) for i in range(len(a))])
    fric = np.where(vm > 0, fr["Fc_pos"] + fr["B_pos"] * vm, -(fr["Fc_neg"] - fr["B_neg"] * vm))
    res = tau[:-1] - pred - fric
    j = 2
    ok = (v[1:, j] * v[:-1, j] > 0) & (np.abs(vm[:, j]) > 0.01) & (st[1:, j] == 0) & (st[:-1, j] == 0)
    assert ok.sum() > 500
    assert math.sqrt(np.mean(res[ok, j] ** 2)) < 0.02 * max(A.T41_FC_POS[j], A.T41_FC_NEG[j])


def test_study_plan_is_fixed_and_covers_the_factors():
    plan = cases(6, 6, seed=3)
    assert plan == cases(6, 6, seed=3)
    effect_runs = [c for c in plan if c["id"].split("-")[0] in EFFECTS]
    assert len(effect_runs) == 36 and len({c["seed"] for c in plan}) == len(plan)
    for key, values in (("rate_hz", {250, 500}), ("excitation", {"sweep", "free"}), ("noise", {"quiet", "noisy"})):
        assert {c[key] for c in effect_runs} == values
    assert {c["links"] for c in plan if c["id"].startswith("clean")} == {"nominal", "heavier_3_4", "random_10pct"}


def test_a_loop_that_cannot_hold_is_reported_not_redrawn(tmp_path):
    case = dict(id="delay-beyond-margin", seed=5, effects=[dict(name="delay", size="large",
                                                                params=dict(delay_ms=16.0))],
                links="nominal", excitation="free", joint=2, rate_hz=500, noise="quiet", jitter="stamp")
    r = generate(case, tmp_path / "run")
    assert r.status != "ok" and r.truth["trip"] is not None and r.rows > 0
    assert r.truth["effects"][0]["params"]["delay_ms"] == 16.0


@pytest.mark.parametrize("share_of_accuracy, identifiable", [(0.5, False), (4.0, True)])
def test_identifiable_means_beyond_what_the_declared_link_accuracy_can_produce(share_of_accuracy, identifiable):
    """The truth's `identifiable`: what is left of an effect's torque after the best fit the declared model's own
    freedom allows (links within the declared accuracy, friction free). A change of link 4's mass by half its
    declared accuracy is fitted away (nothing left); by four times it, more than twice the floor is left."""
    from gen_independent.truth import ACCURACY_SHARE, _beyond_declared_model

    t = np.linspace(0.0, 8.0, 400)
    q = np.zeros((len(t), A.N))
    q[:, 1] = 0.6 * np.sin(2 * np.pi * 0.25 * t)
    q[:, 3] = 1.2 + 0.8 * np.sin(2 * np.pi * 0.4 * t + 0.3)
    v, a = np.gradient(q, t, axis=0), np.gradient(np.gradient(q, t, axis=0), t, axis=0)
    mass = A.LINK_MASS.copy()
    mass[3] *= 1 + share_of_accuracy * ACCURACY_SHARE
    heavier = A.build_model(mass=mass)
    d1, d0 = heavier.createData(), MODEL.createData()
    effect = np.array([pin.rnea(heavier, d1, q[i], v[i], a[i]) - pin.rnea(MODEL, d0, q[i], v[i], a[i])
                       for i in range(len(t))])
    floor = np.full(A.N, 0.05)
    left = _beyond_declared_model(effect, MODEL, q, v, a, [1, 3], floor)
    if identifiable:
        assert max(left.values()) > 2.0, left
    else:
        assert max(left.values()) < 0.05, left


def test_a_designed_run_follows_the_spec_reference_with_the_same_truth(clean_sweep, tmp_path):
    """A further run of the clean sweep's arm along an excitation spec (as ``wamctl diagnose`` writes
    next_experiment.yaml: Fourier coefficients of joint 3, one 2 s period between holds of 0.25 s): the logged
    reference is the spec's documented series (summed term by term here, 1e-12 rad), the loop tracks it (within
    0.02 rad), the arm's truth (friction, links) is the first run's, the noise is drawn anew, and meta.yaml
    calls the run free motion of joint 3 (a kind diagnose takes)."""
    from gen_independent import follow_up

    q0 = yaml.safe_load((clean_sweep.path / "meta.yaml").read_text())["q0"]
    a = [0.2, -0.05, -0.15]                          # rad/s; sum a_l = 0
    b = [0.1, 0.1, -0.1]                             # sum l b_l = 0
    spec = {"kind": "excitation", "name": "next-run", "q0_rad": q0,
            "excitation": {"joints": [3], "period_s": 2.0, "harmonics": 3, "periods": 1, "settle_s": 0.25,
                           "coefficients": {3: {"a_rad_s": a, "b_rad_s": b}}}}
    (tmp_path / "next_experiment.yaml").write_text(yaml.safe_dump(spec))
    r = follow_up(clean_sweep.path, tmp_path / "next_experiment.yaml", tmp_path / "next")
    assert r.status == "ok" and r.case_id.endswith("-next")
    df = pd.read_parquet(tmp_path / "next" / "data.parquet")
    t = np.arange(len(df)) * A.T_CTRL                # the reference advances by T per tick
    w = 2 * math.pi / 2.0
    u = np.clip(t - 0.25, 0.0, 2.0)
    want = q0[2] + sum(a[k] / (w * (k + 1)) * np.sin(w * (k + 1) * u)
                       - b[k] / (w * (k + 1)) * (np.cos(w * (k + 1) * u) - 1) for k in range(3))
    assert np.abs(df["q_ref_3"].to_numpy() - want).max() < 1e-12
    assert np.ptp(want) > 0.1
    for j in (1, 2, 4, 5, 6, 7):
        assert np.all(df[f"q_ref_{j}"] == q0[j - 1])
    assert np.abs(df["q_3"] - df["q_ref_3"]).max() < 0.02
    first = yaml.safe_load((clean_sweep.path / "truth.yaml").read_text())
    again = yaml.safe_load((tmp_path / "next" / "truth.yaml").read_text())
    assert again["friction_truth_classic"] == first["friction_truth_classic"]
    assert again["link_perturbation"] == first["link_perturbation"]
    assert again["excitation"]["kind"] == "designed" and again["excitation"]["moving_joints"] == [3]
    meta = yaml.safe_load((tmp_path / "next" / "meta.yaml").read_text())
    assert meta["experiment"] == {"kind": "free", "joints": [3]}
    first_df = pd.read_parquet(clean_sweep.path / "data.parquet")
    assert not np.allclose(df["t"].to_numpy()[1:50], first_df["t"].to_numpy()[1:50])   # stamps' jitter anew
