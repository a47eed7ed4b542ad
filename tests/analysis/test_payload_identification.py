"""`wamctl identify --payload` on the simulated arm (issue 29 item 1).

One designed trajectory (the shipped excitation, 4 periods of 8 s) is run loaded and bare; between runs the
friction drifts (every joint's Table 4.1 friction scaled by 1.0, 0.9, 0.8, 0.7 at schedule positions 0-3: a
warming-up arm). In the ABBA order (positions: loaded 0 and 3, bare 1 and 2) the drift cancels: mass within 3 %
and centre of mass within 3 mm of the truth, and inside their 95 % intervals; in the order loaded-loaded-bare-bare
(loaded 0 and 1, bare 2 and 3) the drift leaks into the estimate (more than three times the ABBA's error).
The static variant: held poses (the excitation's holds at q0, three q0) for mass (5 %) and centre of mass (2.5 cm,
within its intervals).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

from wamctl.analysis.identification.payload import identify_payload, identify_payload_static
from wamctl.experiments.runner import run_spec
from wamctl.model.friction import FrictionModel
from wamctl.runs.measured import load_run_data
from wamctl.specs import load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[2]
TRUTH = {"mass_kg": 1.2, "com_m": [0.01, -0.02, 0.06]}
DRIFT = (1.0, 0.9, 0.8, 0.7)        # friction scale at schedule positions 0..3


def _run(out: Path, loaded: bool, position: int, seed: int, noise: bool = True, **excitation) -> Path:
    raw = yaml.safe_load((ROOT / "configs" / "excitation.yaml").read_text())
    raw["excitation"].update(**{"periods": 4, **excitation})
    raw["seed"] = seed
    friction = FrictionModel.table_4_1().scaled(DRIFT[position])
    sensors = {"position_noise_rad": 2e-5, "torque_noise_Nm": 0.02} if noise else {"position_noise_rad": 0.0,
                                                                                   "torque_noise_Nm": 0.0}
    raw.update(plant={"friction": {"joints": friction.to_dict()["joints"]},
                      "effects": {"payload": TRUTH} if loaded else {}, "sensors": sensors}, backend={"kind": "sim"})
    outcome = run_spec(parse_spec(raw), ROOT / "configs", out, make_report=False)
    assert outcome.status == "completed", outcome.reason
    return outcome.path


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("payload")
    return {key: _run(out, role == "L", pos, seed) for seed, (key, role, pos) in enumerate(
        [("L0", "L", 0), ("B1", "B", 1), ("B2", "B", 2), ("L3", "L", 3), ("L1", "L", 1), ("B3", "B", 3)])}


@pytest.fixture(scope="module")
def estimates(runs):
    d = {k: load_run_data(p) for k, p in runs.items()}
    cache: dict = {}
    abba = identify_payload([d["L0"], d["L3"]], [d["B1"], d["B2"]], rows_cache=cache)
    llbb = identify_payload([d["L0"], d["L1"]], [d["B2"], d["B3"]], rows_cache=cache)
    return abba, llbb


def _com_error_m(est) -> float:
    return float(np.linalg.norm(np.array(est.com_m) - TRUTH["com_m"]))


def _starts(loaded, bare) -> list[tuple[str, str]]:
    """[(role, start time)], loaded runs first, from the runs' manifests (as `wamctl identify --payload` passes
    them)."""
    return [(role, json.loads((Path(d.source) / "manifest.json").read_text())["start_utc"])
            for role, ds in (("loaded", loaded), ("bare", bare)) for d in ds]


def test_abba_recovers_mass_and_com_within_their_intervals(estimates):
    est, _ = estimates
    m = TRUTH["mass_kg"]
    assert abs(est.mass_kg - m) / m < 0.03
    assert est.mass_ci_kg[0] <= m <= est.mass_ci_kg[1]
    assert _com_error_m(est) < 0.003
    # these runs are seed 0 of benchmarks/bench_payload_coverage.py; with the zero-order hold's timing assumed
    # (before the torque's timing was estimated) its COM z was 2.17 standard errors off and the I_xy and I_xz
    # intervals missed zero. With the rows' and the friction drift's biases removed (issue 29 item 1: COM x had
    # been +0.66 standard errors off on average) this seed's COM x is -2.05 standard errors off (-5.8e-5 m), just
    # outside its interval (by 1.4e-7 m), COM y -1.60, COM z +1.90: whether 95 % intervals hold the truth is a share
    # over seeds (the benchmark: report seeds 30-89), not a property of one; each coordinate within 2.5 here
    for c, ci, truth, axis in zip(est.com_m, est.com_ci_m, TRUTH["com_m"], "xyz"):
        se = (ci[1] - ci[0]) / 2 / stats.t.ppf(0.975, est.dof[f"com_{axis}"])
        assert abs(c - truth) < 2.5 * se, (c, ci, truth)
    # a point mass: no inertia about its COM; I_xy's interval holds zero (+2.76e-4 +- 3.17e-4 kg m^2; it was
    # +4.53e-4 +- 2.89e-4 with the timing assumed)
    lo, hi = est.inertia_ci_kg_m2["I_xy"]
    assert lo <= 0.0 <= hi, (lo, hi)
    assert all(hi - lo < 5e-3 for lo, hi in est.inertia_ci_kg_m2.values())
    assert est.not_identified == []


def test_without_abba_the_friction_drift_biases_the_payload(estimates):
    abba, llbb = estimates
    m = TRUTH["mass_kg"]
    assert abs(llbb.mass_kg - m) > 3 * abs(abba.mass_kg - m)
    assert _com_error_m(llbb) > 3 * _com_error_m(abba)
    assert "NOT balanced" not in abba.order
    assert "LLBB" not in llbb.order or "NOT balanced" in llbb.order


@pytest.fixture(scope="module")
def clean_abba(tmp_path_factory):
    """One period of the excitation, ABBA under the drift, without sensor or actuation noise: what is left of the
    estimate's error is bias."""
    out = tmp_path_factory.mktemp("payload_clean")
    return [load_run_data(_run(out, role == "L", pos, pos, noise=False, periods=1))
            for role, pos in (("L", 0), ("B", 1), ("B", 2), ("L", 3))]


def test_bare_fitted_friction_removes_the_drift_bias(clean_abba):
    """The coverage that was missed (12/16 mass, 7/16 COM x): the loaded arm tracks a little differently, so the
    friction the declared arm predicts differs between the loaded and bare motions, and the declared friction is
    not the arm's (the schedule's mean is 0.85 of it): that remainder follows the payload and leaked into it (noise-
    free: mass +0.15 g, COM x +0.06 mm, 1.3 and 1.7 standard errors of the noisy case on average). Fitted on the
    bare runs, the arm's friction is the schedule's mean and the bias is gone (benchmarks/bench_payload_coverage.py:
    intervals holding the truth 48 -> 58 of 60 seeds for the mass, 33 -> 55 for COM x)."""
    L0, B1, B2, L3 = clean_abba
    cache: dict = {}
    est = identify_payload([L0, L3], [B1, B2], rows_cache=cache)
    declared = identify_payload([L0, L3], [B1, B2], rows_cache=cache, fit_friction=False)
    m = TRUTH["mass_kg"]
    assert declared.mass_kg - m > 1.0e-4                # measured +1.59e-4 kg (+1.48e-4 with the ZOH timing)
    assert declared.com_m[0] - TRUTH["com_m"][0] > 4e-5      # measured +6.6e-5 m
    assert abs(est.mass_kg - m) < 7e-5                  # measured -6.6e-6 kg (-4.4e-5 with the ZOH timing)
    assert abs(est.com_m[0] - TRUTH["com_m"][0]) < 2e-5     # measured +1.5e-5 m
    assert _com_error_m(est) < 3e-5 < _com_error_m(declared)    # measured 1.6e-5 and 7.3e-5 m
    # the fitted friction is the bare runs' (positions 1 and 2: 0.9 and 0.8 of Table 4.1), every joint
    table = FrictionModel.table_4_1().to_dict()["joints"]
    assert est.arm_friction["source"].startswith("fitted") and declared.arm_friction == {"source": "declared"}
    assert sorted(est.arm_friction["joints"]) == [str(j) for j in range(1, 8)]
    for j, fitted in est.arm_friction["joints"].items():
        declared_j = table[int(j)]
        for name, key in (("fc_pos", "fc_pos_Nm"), ("fc_neg", "fc_neg_Nm"), ("b_pos", "viscous_pos_Nm_s_rad"),
                          ("b_neg", "viscous_neg_Nm_s_rad")):
            assert fitted[name] == pytest.approx(0.85 * declared_j[key], rel=0.02), (j, name)


def test_torque_timing_is_estimated_and_removes_the_I_xy_bias(clean_abba):
    """I_xy's interval held the truth in 36/60 seeds (+1.7 standard errors on average): the simulated arm's
    positions lead the torque by half a physics step (semi-implicit Euler: each step moves the position with the
    step's new velocity; 2 steps of 1 ms per 2 ms control period, so 0.5 ms) beyond the zero-order hold's half
    control period, which the rows' alignment assumes; the residual then holds -0.5 ms times the torque's time
    derivative, and in the loaded-minus-bare difference that is the payload's torque's derivative (mostly joint 2's
    gravity term), which leaked into I_xy. The offset is now a column of the fit (estimated, as a real arm's
    bus latency would be): on these noise-free runs it is the simulator's 0.5 ms, and I_xy's error is a third of
    what it was (over many seeds: benchmarks/bench_payload_coverage.py, docs/payload.md)."""
    L0, B1, B2, L3 = clean_abba
    cache: dict = {}
    starts = _starts([L0, L3], [B1, B2])        # the friction's drift modelled (figures before it: in brackets)
    est = identify_payload([L0, L3], [B1, B2], rows_cache=cache, starts=starts)
    zoh = identify_payload([L0, L3], [B1, B2], rows_cache=cache, fit_timing=False, starts=starts)
    lo, hi = est.timing["offset_ci95_s"]
    assert abs(est.timing["offset_s"] - 0.5e-3) < 0.05e-3 and lo < 0.5e-3 < hi    # measured 0.496 ms (0.470-0.521)
    assert "offset_s" not in zoh.timing and zoh.timing["source"].startswith("assumed")
    # measured +8.1e-5 kg m^2 (noisy runs' standard error 1.5e-4); +1.14e-4 before the rows' and the drift's fixes
    assert zoh.inertia_kg_m2["I_xy"] > 6e-5
    assert abs(est.inertia_kg_m2["I_xy"]) < 3e-5          # measured +1.8e-5 kg m^2 (+3.4e-5)
    m = TRUTH["mass_kg"]
    # measured -2.5e-5 and -1.7e-6 kg (-4.4e-5, -6.6e-6)
    assert zoh.mass_kg - m < -2e-5 and abs(est.mass_kg - m) < 5e-6
    assert est.to_dict()["torque_timing"]["offset_s"] == est.timing["offset_s"]


def test_consistent_rows_and_the_drifting_friction_remove_the_inertia_bias(clean_abba):
    """Issue 29 item 1: I_yy +1.06 and COM x +0.66 standard errors of bias over 60 seeds (I_yy's interval held the
    truth in 51/60). Noise-free (these runs) the bias was +1.14e-4 kg m^2 (I_yy), +8.2e-5 (I_xx) and +1.47e-5 m (COM
    x), two causes: (1) the rows' acceleration is the Savitzky-Golay second-derivative kernel's, which attenuates
    the motion more than the smoothing kernel the torque went through (run_rows(derivatives="smoothed") builds the
    regressor from the smoothed position's own derivatives); (2) the loaded runs (friction 1.0 and 0.7 of Table
    4.1) were given the bare runs' mean friction (0.85), and what each run's friction predicts differently for its
    slightly different motion leaked (payload.bare_friction now fits the drift over the schedule from the bare
    runs, each run's friction at its position: the start times)."""
    L0, B1, B2, L3 = clean_abba
    cache: dict = {}
    starts = _starts([L0, L3], [B1, B2])
    est = identify_payload([L0, L3], [B1, B2], rows_cache=cache, starts=starts)
    assert abs(est.inertia_kg_m2["I_yy"]) < 4e-5                 # measured +2.3e-5 kg m^2 (was +1.14e-4)
    assert abs(est.inertia_kg_m2["I_xx"]) < 7e-5                 # measured -4.7e-5 (was +8.2e-5)
    assert abs(est.inertia_kg_m2["I_xy"]) < 3e-5                 # measured +1.8e-5 (was +3.4e-5)
    assert abs(est.com_m[0] - TRUTH["com_m"][0]) < 3e-6          # measured +4.3e-7 m (was +1.47e-5)
    assert _com_error_m(est) < 4e-6                              # measured 1.3e-6 m (was 1.6e-5)
    # each interval's Student's t: the effective number of independent stretches less one (measured 4.7-6.6 on
    # these 8 s runs; 20-30 on the benchmark's 32 s)
    assert sorted(est.dof) == sorted(["mass", "com_x", "com_y", "com_z", "I_xx", "I_yy", "I_zz", "I_xy", "I_xz",
                                      "I_yz"]) and all(3 < v < 12 for v in est.dof.values())
    # each cause alone: the rows' kernel derivatives (the drift modelled) and the bare runs' mean friction (the rows
    # consistent)
    kernel = identify_payload([L0, L3], [B1, B2], rows_cache=cache, starts=starts, consistent=False)
    mean = identify_payload([L0, L3], [B1, B2], rows_cache=cache)
    assert kernel.inertia_kg_m2["I_yy"] > 1.2e-4 and kernel.inertia_kg_m2["I_xx"] > 6e-5    # +1.57e-4, +9.1e-5
    assert mean.inertia_kg_m2["I_xx"] < -1e-4 and mean.inertia_kg_m2["I_xy"] > 4.5e-5      # -1.25e-4, +6.1e-5
    assert "drifting linearly" in est.arm_friction["source"] and "unknown" in mean.arm_friction["source"]
    # the drift recovered: -0.1 of Table 4.1 per schedule position (measured within 0.3 %), 0.85 at the centre
    table = FrictionModel.table_4_1().to_dict()["joints"]
    for j, fitted in est.arm_friction["joints"].items():
        for name, key in (("fc_pos", "fc_pos_Nm"), ("fc_neg", "fc_neg_Nm"), ("b_pos", "viscous_pos_Nm_s_rad"),
                          ("b_neg", "viscous_neg_Nm_s_rad")):
            assert fitted[f"{name}_per_run"] == pytest.approx(-0.1 * table[int(j)][key], rel=0.02), (j, name)
            assert fitted[name] == pytest.approx(0.85 * table[int(j)][key], rel=0.02), (j, name)


def test_order_statement_from_start_times():
    from wamctl.analysis.identification.payload import order_statement

    abba = [("loaded", "t0"), ("bare", "t1"), ("bare", "t2"), ("loaded", "t3")]
    assert "balanced" in order_statement(abba) and "NOT" not in order_statement(abba)
    llbb = [("loaded", "t0"), ("loaded", "t1"), ("bare", "t2"), ("bare", "t3")]
    assert "NOT balanced" in order_statement(llbb)


def test_payload_file_feeds_plant_controller_and_model(runs, tmp_path):
    from wamctl.experiments.identify import identify_payload_to_run_dir
    from wamctl.specs.load import load_model_file

    path, result, _ = identify_payload_to_run_dir([runs["L0"]], [runs["B1"]],
                                                  out=tmp_path, formats=("md",))
    pf = path / "payload.yaml"
    f = yaml.safe_load(pf.read_text())
    assert f["format"] == "wamctl-payload/1" and abs(f["mass_kg"] - result["mass_kg"]) < 1e-12
    assert (path / "report.md").exists() and "mass" in (path / "report.md").read_text()
    # one loaded run at friction 1.0, one bare at 0.9: the unbalanced drift follows the torque's derivative too
    # (estimated 67 ms), which is not the arm's timing: the zero-order hold's is kept and that is said
    assert "offset_s" not in result["torque_timing"] and "beyond one control period" in result["torque_timing"][
        "source"]
    raw = yaml.safe_load((ROOT / "configs" / "excitation.yaml").read_text())
    raw.update(plant={"effects": {"payload": str(pf)}}, controller={"declared_payload": "payload.yaml"})
    spec_path = path / "spec_with_payload.yaml"
    spec_path.write_text(yaml.safe_dump(raw))
    spec = load_spec(spec_path)
    assert spec.plant.effects.payload.mass_kg == pytest.approx(f["mass_kg"])
    assert spec.controller.declared_payload.com_m == pytest.approx(f["com_m"])
    assert load_model_file(pf)["effects"]["payload"]["mass_kg"] == pytest.approx(f["mass_kg"])


def test_static_variant_from_held_poses(tmp_path):
    poses = ([0.0, 0.0, 0.0, 2.0, 0.0, 0.5, 0.0], [0.5, 0.0, 0.6, 2.0, -0.7, -0.6, 0.9],
             [-0.4, 0.0, -0.7, 2.0, 0.7, 0.8, -1.2])
    loaded, bare = [], []
    for i, q0 in enumerate(poses):
        for role, lst in (("L", loaded), ("B", bare)):
            raw = yaml.safe_load((ROOT / "configs" / "excitation.yaml").read_text())
            raw["excitation"].update(periods=1, settle_s=3.0)
            for c in raw["excitation"]["coefficients"].values():     # a small motion between the holds
                c.update({k: [0.2 * v for v in c[k]] for k in ("a_rad_s", "b_rad_s")})
            raw.update(q0_rad=q0, seed=i, plant={"effects": {"payload": TRUTH} if role == "L" else {}},
                       backend={"kind": "sim"})
            outcome = run_spec(parse_spec(raw), ROOT / "configs", tmp_path, make_report=False)
            assert outcome.status == "completed", outcome.reason
            lst.append(load_run_data(outcome.path))
    est = identify_payload_static(loaded, bare)
    m = TRUTH["mass_kg"]
    assert abs(est.mass_kg - m) / m < 0.05 and est.mass_ci_kg[0] <= m <= est.mass_ci_kg[1]
    # held torque carries each joint's stick friction and steady-state error: coarser than the dynamic variant
    # (measured: mass 1.22 kg, COM 17 mm off), but inside its intervals
    assert _com_error_m(est) < 0.025
    for ci, truth in zip(est.com_ci_m, TRUTH["com_m"]):
        assert ci[0] <= truth <= ci[1]
    assert set(est.not_identified) == {"I_xx", "I_yy", "I_zz", "I_xy", "I_xz", "I_yz"}


def test_runs_of_different_trajectories_are_one_line_and_exit_code_2(runs, tmp_path):
    raw = yaml.safe_load((ROOT / "configs" / "excitation_validation.yaml").read_text())
    raw["excitation"]["periods"] = 1
    raw.update(backend={"kind": "sim"})
    other = run_spec(parse_spec(raw), ROOT / "configs", tmp_path, make_report=False).path
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "wamctl", "identify", "--payload", "--loaded", str(runs["L0"]),
                        "--bare", str(other), "--out", str(tmp_path)], capture_output=True, text=True, timeout=300,
                       env=env, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "different trajectories" in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1


def test_payload_schedule_is_abba_of_one_trajectory(tmp_path):
    from wamctl.errors import SpecError
    from wamctl.experiments.identify import payload_schedule

    raw = yaml.safe_load((ROOT / "configs" / "excitation.yaml").read_text())
    raw.update(plant={"effects": {"payload": TRUTH}})
    spec = tmp_path / "pl.yaml"
    spec.write_text(yaml.safe_dump(raw))
    folder, paths = payload_schedule(spec, tmp_path)
    assert [p.name for p in paths] == ["1-loaded.yaml", "2-bare.yaml", "3-bare.yaml", "4-loaded.yaml"]
    specs = [load_spec(p) for p in paths]
    assert [s.plant.effects.payload is not None for s in specs] == [True, False, False, True]
    assert all(s.excitation.coefficients == specs[0].excitation.coefficients for s in specs)
    assert specs[0].excitation.coefficients is not None and (folder / "schedule.md").exists()
    raw.update(plant={})
    spec.write_text(yaml.safe_dump(raw))
    with pytest.raises(SpecError, match="plant.effects.payload"):
        payload_schedule(spec, tmp_path)
