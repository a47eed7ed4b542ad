"""Iterative feedback tuning (issue 6): the IFT maths, the gradient against finite differences of J on the model,
a seven-joint tuning of the simulated arm with an undeclared payload, the safeguards, and --resume."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import Q0
from once import make_once
from scipy.signal import lfilter

from wamctl.analysis import ift as A
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import Reference
from wamctl.errors import SpecError
from wamctl.experiments import ift as E
from wamctl.experiments.ift import experiments as ift_experiments
from wamctl.experiments.ift.state import STATE_FILE, IterationTables
from wamctl.experiments.ift.tuner import IftTuner
from wamctl.experiments.runner import RunInterrupted, run_spec
from wamctl.model import params as P
from wamctl.report import write_report
from wamctl.report.ift import comparison_table, gains_table, read_iterations, table_5_1
from wamctl.runs.store import RunDir, read_events
from wamctl.specs import parse_spec
from wamctl.specs.ift import gain_bounds

pytestmark = pytest.mark.timeout(400)
DT = 1.0 / P.CONTROL_RATE_HZ

# The plant of the tuning tests: Table 4.1 friction, 4096-count encoders, and a 0.3 kg tool at the wrist that the
# gravity compensation and the model do not know (the undeclared effect).
PLANT = {"friction": "table_4_1", "effects": {"payload": {"mass_kg": 0.3, "com_m": [0.0, 0.0, 0.05]}},
         "sensors": {"encoder_counts_per_rev": 4096}}
# BFGS first as in the thesis, then Gauss-Newton; the first Gauss-Newton stage over-relaxes (gamma 2) so that
# Ki, which starts at Kd/10, grows by the needed orders of magnitude in a few iterations; the model check
# backtracks any step that would not lower J on the model.
FAST_SCHEDULE = [{"method": "bfgs", "gamma": 0.5, "iterations": 1}, {"method": "gauss_newton", "gamma": 2.0},
                 {"method": "gauss_newton", "gamma": 1.0}, {"method": "gauss_newton", "gamma": 0.5}]


def ift_spec(**ift) -> dict:
    spec = {"kind": "ift", "name": "ift-test", "seed": 11, "backend": {"kind": "sim"}, "plant": PLANT,
            "controller": {"kind": "pid"}, "q0_rad": Q0.tolist(),
            "ift": {"task": {"settle_s": 0.2, "hold_s": 1.0}, "schedule": FAST_SCHEDULE,
                    "comparison": {"enabled": False}}}
    spec["ift"].update(ift)
    return spec


def only_run(runs_dir):
    (path,) = list(runs_dir.iterdir())
    return path


# ------------------------------------------------------------------------------------------------ maths
def test_ift_filters_invert_the_libbarrett_pid():
    """(1/C) dC/drho applied to the controller's output u = C e gives dC/drho e exactly: the filters are the
    discrete derivatives of the PID that wamctl runs."""
    rng = np.random.default_rng(0)
    e = np.concatenate([[0.0], rng.normal(0, 1e-3, 999)])   # e[-1] = e[0] = 0: the controller starts at rest
    kp, kd, ki = 900.0, 10.0, 250.0
    ctl = JointController([kp] * 7, [kd] * 7, [ki] * 7, DT)
    u = np.array([ctl.update(np.full(7, ek), np.zeros(7))[0] for ek in e])
    b, a = A.pid_filters(kp, kd, ki, DT)
    expected = {0: e, 1: np.diff(e, prepend=0.0) / DT, 2: DT * np.concatenate([[0.0], np.cumsum(e)[:-1]])}
    for i in range(3):
        np.testing.assert_allclose(lfilter(b[i], a, u), expected[i], rtol=1e-6, atol=1e-9 * np.abs(expected[i]).max())
    # and C(z) itself: the numerator over T (1 - z^-1) reproduces u
    np.testing.assert_allclose(lfilter(A.pid_numerator(kp, kd, ki, DT), [DT, -DT], e), u, rtol=1e-9, atol=1e-12)


def test_pid_filters_reject_a_non_minimum_phase_controller():
    with pytest.raises(ValueError, match="unstable"):
        A.pid_filters(1.0, 1e-6, 1e7, DT)    # ki T^2 >> 4 kd + 2 kp T: N(q) has a root outside the unit circle


def test_bfgs_update_secant_positivity_and_skip():
    B = np.diag([2.0, 1.0, 0.5])
    s = np.array([0.1, -0.2, 0.3])
    z = np.array([0.3, -0.1, 0.2])
    B1, updated = A.bfgs_update(B, s, z)
    assert updated
    np.testing.assert_allclose(B1 @ s, z, rtol=1e-12)          # the secant condition of eq. 2.17
    assert np.all(np.linalg.eigvalsh(B1) > 0)
    B2, updated = A.bfgs_update(B, s, -z)                      # z^T s < 0: B kept
    assert not updated and np.array_equal(B2, B)


def test_update_is_gauss_newton_step_and_respects_bounds():
    rng = np.random.default_rng(1)
    psi = rng.normal(size=(500, 3)) * np.array([1e-6, 1e-4, 1e-8])  # very different scales, as kp/kd/ki
    theta = np.array([-50.0, 0.5, 2000.0])
    y = -(psi @ theta) + rng.normal(0, 1e-9, 500)          # the error that the step theta would cancel
    rho = np.array([900.0, 10.0, 1.0])
    g = A.ift_gradient(y, psi)
    R = A.gauss_newton_hessian(psi)
    np.testing.assert_allclose(A.ift_update(rho, g, R, 1.0) - rho, theta, rtol=1e-3)   # GN solves the LS
    np.testing.assert_allclose(A.ift_update(rho, g, R, 0.5) - rho, 0.5 * theta, rtol=1e-3)
    lo, hi = np.array([450.0, 5.0, 0.0]), np.array([3600.0, 40.0, 1500.0])
    new_b = A.ift_update(rho, g, R, 1.0, lo, hi)
    assert np.all(new_b >= lo) and np.all(new_b <= hi) and new_b[2] == 1500.0
    at_bound = np.array([900.0, 10.0, 1500.0])              # ki held at its bound: kp, kd solved without it
    assert list(A.free_parameters(at_bound, g, lo, hi)) == [True, True, False]
    new_c = A.ift_update(at_bound, g, R, 1.0, lo, hi)
    assert new_c[2] == 1500.0
    np.testing.assert_allclose(new_c[:2] - at_bound[:2], theta[:2], rtol=0.05)
    assert A.decreased(1.233e-5, 1.234e-5) and not A.decreased(1.23441e-5, 1.23449e-5)  # 4 digits
    assert A.decreased(1.23441e-5, 1.23449e-5, digits=6)


# ------------------------------------------------------------------------------------------------ (a) gradient
def test_ift_gradient_matches_finite_differences_of_J_on_the_model(tmp_path):
    """Plant = the model (rigid body + Table 4.1 friction, ideal sensors): the IFT gradient (first experiment,
    incremental second experiment, PID filters) against central differences of J, at the initial gains."""
    spec = parse_spec(ift_spec(joints=[1, 4, 6, 7]) | {"plant": {"friction": "table_4_1",
                                                                  "sensors": {"encoder_counts_per_rev": 0}}})
    run = RunDir.create(tmp_path, "grad", {}, 0, "ift")
    tuner = IftTuner(spec, run)
    results = {}
    for joint in (1, 4, 6, 7):
        rho = tuner.g0[joint - 1].copy()
        tables = IterationTables()
        r, y1, qref, _ = tuner.first_experiment(0, joint, rho, tuner.g0, tables)
        est = tuner.estimate(0, joint, rho, tuner.g0, r, y1, qref, tables)

        def J(p, joint=joint, qref=qref):
            g = tuner.g0.copy()
            g[joint - 1] = p
            rows, reason = tuner._run_model(g, qref, 0)
            assert reason is None
            return A.objective(rows[:, 8 + joint - 1] - rows[:, 1 + joint - 1])
        fd = np.zeros(3)
        for i in range(3):
            h = 0.02 * rho[i]
            up, dn = rho.copy(), rho.copy()
            up[i] += h
            dn[i] -= h
            fd[i] = (J(up) - J(dn)) / (2 * h)
        assert est.J == pytest.approx(J(rho), rel=1e-9)      # the model's own first experiment
        # compare d J / d log(rho) (gradient times gains), so that kp, kd and ki weigh alike
        g_ift, g_fd = est.gradient * rho, fd * rho
        results[joint] = (np.linalg.norm(g_ift - g_fd) / np.linalg.norm(g_fd), g_ift, g_fd)
    print({j: round(v[0], 5) for j, v in results.items()})
    for joint, (rel, g_ift, g_fd) in results.items():
        # README: "within 1 %" (measured 2026-11: 0.25-0.50 % on joints 1, 4, 6, 7)
        assert rel < 0.01, (joint, g_ift, g_fd)
        assert np.sign(g_ift[0]) == np.sign(g_fd[0]) == -1       # larger kp lowers J (friction error ~ Fc / kp)
        assert g_ift[2] == pytest.approx(g_fd[2], rel=0.10)      # and the integral gain, separately


def test_ift_gradient_against_finite_differences_of_J_on_the_plant(tmp_path):
    """Where it matters: the plant is not the model. It carries the undeclared 0.3 kg tool, 4096-count encoders
    and position noise; the second experiment runs on the model (rigid body + Table 4.1 friction, ideal sensors).
    The IFT gradient is compared with central differences of J measured on the plant itself (same noise draws
    for every evaluation: common random numbers, as the first experiment's seed is fixed per iteration).

    Compared in d J / d log(rho): the kp and the ki components each within 10 % of the plant's finite
    differences (measured 2026-11: kp 0.05-0.3 %, ki 1.7-4 % on joints 1, 4, 7). The kd component is three
    orders of magnitude below kp's and within the noise of J on the plant, so only its size is checked."""
    plant = {"friction": "table_4_1", "effects": {"payload": {"mass_kg": 0.3, "com_m": [0.0, 0.0, 0.05]}},
             "sensors": {"encoder_counts_per_rev": 4096, "position_noise_rad": 2e-5}}
    spec = parse_spec(ift_spec(joints=[1, 4, 7]) | {"plant": plant})
    run = RunDir.create(tmp_path, "grad-plant", {}, 0, "ift")
    tuner = IftTuner(spec, run)
    for joint in (1, 4, 7):
        rho = tuner.g0[joint - 1].copy()
        tables = IterationTables()
        r, y1, qref, _ = tuner.first_experiment(0, joint, rho, tuner.g0, tables)
        est = tuner.estimate(0, joint, rho, tuner.g0, r, y1, qref, tables)
        ref, n_task = E.planning.task_reference(spec, joint, tuner.with_return)
        seed = tuner._plant_seed(0, joint)

        def J_plant(p, joint=joint, ref=ref, n_task=n_task, seed=seed):
            rows, _, reason = tuner._run_backend(joint, E.experiments.with_joint_gains(tuner.g0, joint, p), ref,
                                                 seed)
            assert reason is None
            j0 = joint - 1
            return A.objective(rows[:n_task, E.experiments.Q_MEAS + j0] - rows[:n_task, E.experiments.Q_REF + j0])
        assert est.J == pytest.approx(J_plant(rho), rel=1e-12)        # the same experiment
        fd = np.zeros(3)
        for i in range(3):
            h = 0.05 * rho[i]
            up, dn = rho.copy(), rho.copy()
            up[i] += h
            dn[i] -= h
            fd[i] = (J_plant(up) - J_plant(dn)) / (2 * h)
        g_ift, g_fd = est.gradient * rho, fd * rho
        print(joint, g_ift, g_fd)
        assert g_ift[0] == pytest.approx(g_fd[0], rel=0.10), (joint, g_ift, g_fd)
        assert g_ift[2] == pytest.approx(g_fd[2], rel=0.10), (joint, g_ift, g_fd)
        assert abs(g_ift[1]) < 1e-2 * abs(g_ift[0]) and abs(g_fd[1]) < 1e-2 * abs(g_fd[0])


# ------------------------------------------------------------------------------------------------ (b) tuning
def _tune_all_joints(runs: Path) -> Path:
    spec = parse_spec(ift_spec(max_iterations=7, comparison={"enabled": True}))
    outcome = run_spec(spec, None, runs, make_report=False)
    assert outcome.status == "completed", outcome.reason
    return outcome.path


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    """All seven joints tuned on the plant with the undeclared payload; then the strategy comparison. Made once
    per session for every xdist worker (tests/once.py): the tests read the run, never change it."""
    return make_once(tmp_path_factory, "ift_tuned", _tune_all_joints)


def test_tuning_lowers_J_by_two_orders_of_magnitude_on_a_plant_the_model_does_not_describe(tuned):
    """The plant carries a 0.3 kg tool that neither the gravity compensation nor the model knows. Accepted steps
    lower J by construction (a step is kept only if J fell); what can fail is how far J falls from the initial
    gains after the seven iterations: README "at least two orders of magnitude on every joint" (measured
    2026-11: 2.5 orders on joint 2 to 4.2 on joint 7)."""
    it = read_iterations(tuned)
    assert sorted(it["joint"].unique()) == list(range(1, 8))
    t51 = table_5_1(it)
    print(t51.to_string())
    for joint, g in it.groupby("joint"):
        acc = g[g["status"].isin(["initial", "accepted"])].sort_values("iteration")
        J = acc["J"].to_numpy()
        assert len(J) >= 3, joint                          # at least two accepted iterations per joint
        assert J[-1] <= 1e-2 * J[0], (joint, J)
    gt = gains_table(it)
    assert (gt["ki_tuned"] > 100 * gt["ki_initial"]).all()   # the integral action grew from Ki = Kd / 10
    lo, hi = gain_bounds(parse_spec(yaml.safe_load((tuned / "spec.yaml").read_text())))
    for j, r in gt.iterrows():
        g = np.array([r.kp_tuned, r.kd_tuned, r.ki_tuned])
        assert np.all(g >= lo[j - 1] - 1e-9) and np.all(g <= hi[j - 1] + 1e-9)


def test_tuned_pid_final_position_rpe_and_strategy_comparison(tuned):
    ct, differs = comparison_table(tuned)
    print(ct.to_string())
    assert differs == []            # the thesis' task (0.5 rad at 0.083 rad/s): its figures are comparable
    assert list(ct.index) == list(range(1, 8))
    assert (ct["rpe_pid_pct"] < 0.05).all(), ct["rpe_pid_pct"]    # README: below 0.05 % (measured <= 0.033 %)
    # PD + gravity leaves the friction error Fc / Kp (thesis ch. 3: about 0.2-5 %); the tuned PID removes it
    assert (ct["rpe_pd_g_pct"] > ct["rpe_pid_pct"]).all()
    assert ct["rpe_pd_g_pct"].median() > 0.3 and ct["rpe_pid_pct"].median() < 0.02
    # the thesis' figures sit beside ours, joint by joint: typed here from the thesis text (section 4.4 and
    # section 5.4), not from the constants the report uses, so a transcription or ordering error would show
    assert ct["thesis_rpe_pd_g_pct"].tolist() == [1.0876, 0.2342, 0.8666, 0.2912, 1.3592, 3.2848, 5.4132]
    assert ct["thesis_rpe_pd_g_ff_pct"].tolist() == [1.1198, 0.2244, 0.8988, 0.4398, 1.2426, 1.7974, 7.2360]
    assert ct["thesis_rpe_pid_pct"].tolist() == [0.0003, 0.0, 0.0004, 0.0003, 0.0003, 0.0003, 0.0007]


def test_ift_report_tables_and_figures(tuned, tmp_path):
    doc = write_report(tuned, tmp_path)
    names = [b[1][0] for b in doc.blocks if b[0] == "table"]
    assert {"ift_J", "ift_methods", "thesis_table_5_1", "ift_gains", "comparison_rpe"} <= set(names)
    for f in ("ift_convergence.png", "ift_gains.png", "ift_errors.png", "ift_comparison_errors.png", "report.md"):
        assert (tmp_path / f).is_file(), f
    data = json.loads((tmp_path / "report.json").read_text())
    assert set(data["rpe_pct"]) == {"pd_g", "pd_g_ff", "pid"}
    tuned_yaml = yaml.safe_load((tuned / "tuned_gains.yaml").read_text())
    assert tuned_yaml["controller"]["kind"] == "pid" and len(tuned_yaml["controller"]["ki"]) == 7
    exp1 = pd.read_parquet(tuned / "iter-003-exp1.parquet")
    assert set(exp1["joint"]) <= set(range(1, 8)) and "q_true_1_rad" in exp1
    exp2 = pd.read_parquet(tuned / "iter-003-exp2.parquet")
    assert {"r2_rad", "y2_rad", "psi_kp", "psi_kd", "psi_ki"} <= set(exp2.columns)
    # issue 32, item 12: the gains had no units. Each gain row carries its unit: kp N m/rad, kd N m s/rad, ki
    # N m/(rad s) (the PID's torque per error, per its rate, per its integral)
    tables = doc.tables()
    gains = tables["ift_gains"].reset_index()
    assert len(gains) == 21                                     # 7 joints x 3 gains
    units = gains.groupby("gain")["unit"].unique()
    assert {g: list(u) for g, u in units.items()} == {"kp": ["N m/rad"], "kd": ["N m s/rad"], "ki": ["N m/(rad s)"]}
    gt = gains_table(read_iterations(tuned))
    np.testing.assert_array_equal(gains.set_index(["joint", "gain"]).loc[(1, "ki"), "tuned"], gt.loc[1, "ki_tuned"])
    assert json.loads((tmp_path / "report.json").read_text())["gain_units"]["kd"] == "N m s/rad"
    bt = tables["ift_gains_at_bounds"]
    kp = bt[bt["gain"] == "kp"]
    assert sorted(kp.index) == list(range(1, 8)) and (kp["J_falls_beyond"] == True).all()  # noqa: E712
    assert (bt["unit"] == bt["gain"].map({"kp": "N m/rad", "kd": "N m s/rad", "ki": "N m/(rad s)"})).all()


def warning_lines(doc, width=80) -> list[list[str]]:
    """Each warning of a report as the terminal prints it: 'warning: ' and the text wrapped at ``width``."""
    import textwrap
    return [textwrap.wrap("warning: " + w, width) for w in doc.data.get("warnings", [])]


@pytest.fixture(scope="module")
def example_interrupted(tmp_path_factory):
    """The README's example (configs/ift.yaml) on joints 1 and 7, Ctrl-C after iteration 2 was saved; then the
    same run resumed to max_iterations 4. Returns (spec dict, run path, report of the interrupted run,
    report of the completed one). Made once per session for every xdist worker (tests/once.py)."""
    return make_once(tmp_path_factory, "ift_example_interrupted", _interrupt_and_resume_the_example)


def _interrupt_and_resume_the_example(runs: Path):
    d = yaml.safe_load((Path(__file__).parents[2] / "configs" / "ift.yaml").read_text())
    d["ift"].update(joints=[1, 7], max_iterations=3, comparison={"enabled": False})
    spec = parse_spec(d)
    orig = IftTuner._after_iteration

    def stop(self, k):
        if k == 2:
            raise KeyboardInterrupt("Ctrl-C")
    IftTuner._after_iteration = stop
    try:
        with pytest.raises(RunInterrupted):
            run_spec(spec, None, runs / "runs", make_report=False)
    finally:
        IftTuner._after_iteration = orig
    path = only_run(runs / "runs")
    interrupted = write_report(path, runs / "report-interrupted")
    assert E.resume(path, spec).status == "completed"
    completed = write_report(path, runs / "report-completed")
    return d, path, interrupted, completed


def test_an_interrupted_tuning_reports_after_which_iteration_not_a_bound(example_interrupted):
    """Issue 32, item 9: after Ctrl-C the report said the tuning "stopped at the bound". It says where it was
    interrupted, in one warning of at most two lines at 80 columns, and how to continue."""
    _, path, doc, _ = example_interrupted
    md = (path.parent.parent / "report-interrupted" / "report.md").read_text()
    assert "stopped at the bound" not in md and "chose these gains" not in md
    (lines,) = warning_lines(doc)
    assert len(lines) <= 2, lines
    assert " ".join(lines).startswith("warning: interrupted after iteration 2:")
    assert "--resume" in " ".join(lines)


def test_the_example_names_the_gains_j_would_push_beyond_their_bound_in_two_lines(example_interrupted):
    """Issue 32, item 9: the README's example ended with a ten-line warning that every gain was at its bound. J
    (thesis eq. 2.13) is the output error alone, and on the simulated arm it keeps falling as kp rises: at kp's
    bound (4x the start) J's gradient still points up, and a plant experiment beyond the bound confirms that J
    falls further. The report says so in one warning of at most two lines at 80 columns, naming the gains."""
    d, path, _, doc = example_interrupted
    (lines,) = warning_lines(doc)
    text = " ".join(lines)
    assert len(lines) <= 2, lines
    assert text.startswith("warning: J still fell at the upper bound of kp (joints 1, 7)"), text
    assert "the bound, not J, chose these gains" in text
    bt = doc.tables()["ift_gains_at_bounds"].reset_index()
    kp = bt[bt["gain"] == "kp"].set_index("joint")
    assert list(kp.index) == [1, 7] and kp["J_falls_beyond"].tolist() == [True, True]
    np.testing.assert_allclose(kp["tuned"], [3600.0, 32.0])    # 4 x libbarrett's 900 and 8
    # J truly still falls beyond kp's bound: joint 7's first experiment at the tuned gains and with kp 25 % above
    spec = parse_spec(d)
    st = json.loads((path / STATE_FILE).read_text())["joints"]["7"]
    tuner = IftTuner(spec, RunDir.create(path.parent, "probe", {}, 0, "ift"))
    ref, n = E.planning.task_reference(spec, 7, tuner.with_return)

    def J(rho):
        rows, _, reason = tuner._run_backend(7, E.experiments.with_joint_gains(tuner.g0, 7, rho), ref, 1)
        assert reason is None
        return A.objective(rows[:n, E.experiments.Q_MEAS + 6] - rows[:n, E.experiments.Q_REF + 6])
    rho = np.array(st["rho"])
    J_at, J_beyond = J(rho), J(rho * [1.25, 1.0, 1.0])
    print(rho, J_at, J_beyond)
    assert J_beyond < 0.9 * J_at


def test_J_rewards_higher_gains_while_the_pid_torque_stays_the_same(tmp_path):
    """Issue 32, item 9, the cause: J (thesis eq. 2.13, as in the thesis: output error only) falls as the gains
    rise on the simulated arm, so an unbounded tuning ends at the bounds. An effort term lambda u^2
    (Hjalmarsson's criterion) would not bound the gains: the PID's torque u is the friction and tool torque the
    move needs whatever the gains. What grows is the torque's change from sample to sample (the encoder's counts
    through kd / T), which the bounds limit. Joint 1 of the README's example, initial gains and kp, kd at their
    default bound (4x): README "J falls 16x, the PID's torque RMS changes by 1 %, its sample-to-sample change
    grows 4x" (measured 2026-11: 15.7x, 0.9 %, 4.1x)."""
    d = yaml.safe_load((Path(__file__).parents[2] / "configs" / "ift.yaml").read_text())
    d["ift"].update(joints=[1], comparison={"enabled": False})
    spec = parse_spec(d)
    tuner = IftTuner(spec, RunDir.create(tmp_path, "probe", {}, 0, "ift"))
    ref, n = E.planning.task_reference(spec, 1, tuner.with_return)
    out = {}
    for label, f in (("initial", 1.0), ("bound", 4.0)):
        rho = tuner.g0[0] * [f, f, 1.0]
        rows, _, reason = tuner._run_backend(1, E.experiments.with_joint_gains(tuner.g0, 1, rho), ref,
                                             tuner._plant_seed(0, 1))
        assert reason is None
        e = rows[:n, E.experiments.Q_REF] - rows[:n, E.experiments.Q_MEAS]
        u = lfilter(A.pid_numerator(*rho, DT), [DT, -DT], e)          # the PID's torque (gravity aside), N m
        out[label] = (A.objective(e), np.sqrt(np.mean(u ** 2)), np.sqrt(np.mean(np.diff(u) ** 2)))
    print(out)
    (J0, u0, du0), (J4, u4, du4) = out["initial"], out["bound"]
    assert J0 / J4 > 10
    assert abs(u4 / u0 - 1) < 0.02
    assert du4 / du0 > 3


# ------------------------------------------------------------------------------------------------ (c) safeguards
@pytest.fixture
def count_plant(monkeypatch):
    """Record the gains of the tuned joint in every experiment that reaches the plant (the backend)."""
    seen = []
    orig = IftTuner._run_backend

    def wrapped(self, joint, gains, ref, seed, ff=None):
        seen.append((joint, np.asarray(gains[joint - 1], float).copy()))
        return orig(self, joint, gains, ref, seed, ff)
    monkeypatch.setattr(IftTuner, "_run_backend", wrapped)
    return seen


def test_unstable_proposal_is_caught_on_the_model_and_never_reaches_the_plant(runs_dir, count_plant):
    spec = parse_spec(ift_spec(
        joints=[1], max_iterations=1, schedule=[{"method": "gauss_newton", "gamma": 1.0e4}],
        safeguards={"backtracking": 0},
        bounds={"kp_max": [1e7] * 7, "kd_max": [1e5] * 7, "ki_max": [1e9] * 7}))
    outcome = run_spec(spec, None, runs_dir, make_report=False)
    assert outcome.status == "completed"
    it = read_iterations(outcome.path)
    rej = it[it["status"] == "model_rejected"]
    assert len(rej) == 1
    big = rej.iloc[0]
    assert big.kp > 100 * 900.0                              # the huge step really was huge
    ev = read_events(outcome.path)
    detail = ev[ev["kind"] == "ift_rejected"]["detail"].tolist()
    assert len(detail) == 1 and any(w in detail[0] for w in ("unstable", "torque limit", "diverging")), detail
    assert len(count_plant) == 1                             # the initial experiment only
    assert np.allclose(count_plant[0][1], [900.0, 10.0, 1.0])
    state = json.loads((outcome.path / STATE_FILE).read_text())
    assert state["plant_experiments"] == 1
    assert state["joints"]["1"]["done"] and state["joints"]["1"]["rho"] == [900.0, 10.0, 1.0]   # the fallback


def test_backtracking_shrinks_gamma_until_the_model_accepts(runs_dir, count_plant):
    spec = parse_spec(ift_spec(
        joints=[1], max_iterations=1, schedule=[{"method": "gauss_newton", "gamma": 1.0e4}],
        safeguards={"backtracking": 20, "backtrack_factor": 0.25},
        bounds={"kp_max": [1e7] * 7, "kd_max": [1e5] * 7, "ki_max": [1e9] * 7}))
    outcome = run_spec(spec, None, runs_dir, make_report=False)
    it = read_iterations(outcome.path)
    rejected = it[it["status"] == "model_rejected"]
    ran = it[it["status"].isin(["accepted", "plant_rejected"])]
    assert len(rejected) >= 1 and len(ran) == 1
    assert ran.iloc[0].gamma < rejected["gamma"].min()
    plant_gains = [g for _, g in count_plant]
    assert len(plant_gains) == 2                             # initial + the one accepted proposal
    for r in rejected.itertuples():
        assert not any(np.allclose(g, [r.kp, r.kd, r.ki]) for g in plant_gains)
    assert ran.iloc[0].status == "accepted" and ran.iloc[0].J < it[it["status"] == "initial"].iloc[0].J


def test_spec_rejects_initial_gains_outside_the_bounds():
    with pytest.raises(SpecError, match="outside its bounds"):
        parse_spec(ift_spec(initial={"ki": [1e9] * 7}))
    with pytest.raises(SpecError, match="pd_g_ff"):
        parse_spec(ift_spec() | {"controller": {"kind": "pd_g_ff", "friction_ff": "table_4_1"}})


# ------------------------------------------------------------------------------------------------ (d) resume
RESUME_SPEC = ift_spec(joints=[5, 7], max_iterations=3)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The state of RESUME_SPEC's tuning run without a stop; made once per session for every xdist worker."""
    def tune(folder: Path) -> dict:
        out = run_spec(parse_spec(RESUME_SPEC), None, folder, make_report=False)
        return json.loads((out.path / STATE_FILE).read_text())
    return make_once(tmp_path_factory, "ift_uninterrupted", tune)


@pytest.mark.parametrize("where", ["between_iterations", "mid_experiment"])
def test_resume_continues_from_the_last_completed_iteration(tmp_path, monkeypatch, uninterrupted, where):
    from typer.testing import CliRunner

    from wamctl.cli import _register, app
    spec = parse_spec(RESUME_SPEC)
    calls = []
    monkeypatch.setattr(IftTuner, "_after_iteration", lambda self, k: calls.append(k))
    if where == "between_iterations":          # Ctrl-C right after iteration 1 was saved
        def stop(self, k):
            calls.append(k)
            if k == 1:
                raise KeyboardInterrupt("SIGTERM")
        monkeypatch.setattr(IftTuner, "_after_iteration", stop)
    else:                                       # SIGTERM 2 s into joint 7's first experiment of iteration 2
        real_loop = ift_experiments.run_loop
        plant_calls = []

        def loop(backend, controller, reference, recorder, progress=None):
            if backend.plant.payload is not None:     # the plant (the model has no payload)
                plant_calls.append(1)
                if len(plant_calls) == 6:             # iteration 0: 2, iteration 1: 2, iteration 2: joint 5, 7
                    cut = Reference(reference.t_s[:1000], reference.q_rad[:1000], reference.qd_rad_s[:1000],
                                    reference.qdd_rad_s2[:1000], [])
                    real_loop(backend, controller, cut, recorder)
                    raise KeyboardInterrupt("SIGTERM")
            return real_loop(backend, controller, reference, recorder, progress)
        monkeypatch.setattr(ift_experiments, "run_loop", loop)
    with pytest.raises(RunInterrupted):
        run_spec(spec, None, tmp_path / "runs", make_report=False)
    path = only_run(tmp_path / "runs")
    assert json.loads((path / "manifest.json").read_text())["status"] == "interrupted"
    st = json.loads((path / STATE_FILE).read_text())
    assert st["last_completed_iteration"] == 1 and calls == [0, 1]
    plant_before = st["plant_experiments"]
    if where == "mid_experiment":               # the interrupted iteration's samples reached its table
        part = pd.read_parquet(path / "iter-002-exp1.parquet")
        assert (part["joint"] == 7).sum() == 1000 and (part["joint"] == 5).sum() > 4000
    monkeypatch.undo()
    monkeypatch.setattr(IftTuner, "_after_iteration", lambda self, k: calls.append(k))
    spec_file = tmp_path / "ift.yaml"
    spec_file.write_text(yaml.safe_dump(RESUME_SPEC))
    _register()
    res = CliRunner().invoke(app, ["tune-ift", str(spec_file), "--resume", str(path), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["status"] == "completed" and out["run_dir"] == str(path)
    assert calls == [0, 1, 2, 3]                             # continued with iteration 2, not from scratch
    st = json.loads((path / STATE_FILE).read_text())
    assert st["last_completed_iteration"] == 3 and st["phase"] == "done"
    assert st["plant_experiments"] == uninterrupted["plant_experiments"] > plant_before
    for j in ("5", "7"):                                     # the same tuning as without the interruption
        np.testing.assert_allclose(st["joints"][j]["rho"], uninterrupted["joints"][j]["rho"], rtol=1e-12)
        assert st["joints"][j]["J"] == uninterrupted["joints"][j]["J"]
    it = read_iterations(path)
    assert not it.duplicated(["iteration", "joint", "status", "gamma", "kp"]).any()
    assert sorted(it["iteration"].unique()) == [0, 1, 2, 3]
    assert (pd.read_parquet(path / "iter-002-exp1.parquet")["joint"] == 7).sum() > 4000
    assert "ift_resumed" in set(read_events(path)["kind"])
    # a different spec is refused
    spec_file.write_text(yaml.safe_dump(dict(RESUME_SPEC, seed=99)))
    res = CliRunner().invoke(app, ["tune-ift", str(spec_file), "--resume", str(path)])
    assert isinstance(res.exception, SpecError) and "seed" in str(res.exception)


class Killed(BaseException):
    """The process dying (SIGKILL, a power cut) between two writes: nothing after it runs."""


@pytest.mark.parametrize("table", ["iterations.parquet", "iterations.csv"])
def test_a_death_while_an_iteration_is_saved_loses_none_of_its_rows(tmp_path, monkeypatch, uninterrupted, table):
    """SIGKILL cannot be held back like Ctrl-C: wherever it falls among the writes that save iteration 1, the
    resumed run has every iteration's rows and the tuning of an uninterrupted run (CI saw iteration 1's row lost
    when the state file was written before the table)."""
    from wamctl.experiments.ift import state as state_module
    from wamctl.experiments.ift import tuner as tuner_module
    from wamctl.runs import store

    def dying(path, write):
        if Path(path).name == table and json.loads((Path(path).parent / "manifest.json").read_text()).get(
                "ift", {}).get("last_completed_iteration") == 0:
            raise Killed
        real(path, write)
    real = store.atomic_write
    monkeypatch.setattr(store, "atomic_write", dying)
    for module in (tuner_module, state_module):
        monkeypatch.setattr(module, "atomic_write", dying, raising=False)   # (the old tuner wrote its CSV directly)
    with pytest.raises(Killed):
        run_spec(parse_spec(RESUME_SPEC), None, tmp_path / "runs", make_report=False)
    monkeypatch.undo()
    path = only_run(tmp_path / "runs")
    assert E.resume(path, parse_spec(RESUME_SPEC)).status == "completed"
    it = read_iterations(path)
    assert sorted(it["iteration"].unique()) == [0, 1, 2, 3]
    assert not it.duplicated(["iteration", "joint", "status", "gamma", "kp"]).any()
    st = json.loads((path / STATE_FILE).read_text())
    for j in ("5", "7"):
        np.testing.assert_allclose(st["joints"][j]["rho"], uninterrupted["joints"][j]["rho"], rtol=1e-12)


# ------------------------------------------------------------------------------------------------ variants
def test_direct_second_experiment_underestimates_the_gradient_under_friction(tmp_path):
    """The thesis' literal second experiment (the model at rest driven by r - y1) mostly sticks in Coulomb
    friction; the incremental form (about the task trajectory) is the one that matches J's gradient."""
    base = ift_spec(joints=[1]) | {"plant": {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}}
    grads = {}
    for form in ("incremental", "direct"):
        d = yaml.safe_load(yaml.safe_dump(base))
        d["ift"]["second_experiment"] = form
        spec = parse_spec(d)
        tuner = IftTuner(spec, RunDir.create(tmp_path, form, {}, 0, "ift"))
        rho = tuner.g0[0].copy()
        t = IterationTables()
        r, y1, qref, _ = tuner.first_experiment(0, 1, rho, tuner.g0, t)
        grads[form] = tuner.estimate(0, 1, rho, tuner.g0, r, y1, qref, t).gradient * rho
    assert grads["direct"][0] < 0 and grads["incremental"][0] < 0
    assert abs(grads["direct"][0]) < 0.5 * abs(grads["incremental"][0])


def test_measured_first_experiments_propose_then_resume_with_the_next_run(tmp_path):
    """First experiments from recorded runs (here rotation runs of the simulated arm): the tuning proposes gains,
    waits for the next recording, and evaluates it on --resume."""
    def record(gains, name):
        d = {"kind": "rotation", "name": name, "seed": 2, "backend": {"kind": "sim"}, "plant": PLANT,
             "controller": {"kind": "pid", "kp": gains[:, 0].tolist(), "kd": gains[:, 1].tolist(),
                            "ki": gains[:, 2].tolist()},
             "q0_rad": Q0.tolist(), "rotation": {"joints": [1, 7], "mode": "one_at_a_time", "settle_s": 0.5,
                                                 "hold_s": 1.0}}
        return run_spec(parse_spec(d), None, tmp_path / "recorded", make_report=False).path
    g0 = np.stack([P.KP, P.KD, P.KD / 10], axis=1)
    first = record(g0, "rec0")
    d = ift_spec(joints=[1, 7], max_iterations=3, plant={"source": "measured", "runs": [str(first)]})
    out = run_spec(parse_spec(d), None, tmp_path / "runs", make_report=False)
    assert out.status == "completed"
    it = read_iterations(out.path)
    assert list(it[it["status"] == "initial"]["joint"]) == [1, 7]
    J0 = it[it["status"] == "initial"].set_index("joint")["J"]
    assert 1e-6 < J0[1] < 1e-4 and 1e-5 < J0[7] < 1e-3       # Fc / Kp friction errors of a few mrad
    assert "ift_awaiting_measured_run" in set(read_events(out.path)["kind"])
    nxt = yaml.safe_load((out.path / "tuned_gains.yaml").read_text())["next"]["joints"]
    g1 = g0.copy()
    for j, v in nxt.items():
        g1[int(j) - 1] = [v["kp"], v["kd"], v["ki"]]
    second = record(g1, "rec1")
    d["ift"]["plant"]["runs"].append(str(second))
    res = E.resume(out.path, parse_spec(d))
    assert res.status == "completed"
    it = read_iterations(out.path)
    one = it[it["iteration"] == 1].set_index("joint")
    assert set(one.index) == {1, 7} and (one["status"] == "accepted").all()
    assert (one["J"] < 0.7 * J0).all()
    assert "ift_measured_gains" not in set(read_events(out.path)["kind"])   # the recordings ran the proposals
