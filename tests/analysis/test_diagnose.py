"""wamctl diagnose (issue 5): effects named on generated runs, clean runs left alone, errors before and after on
held-out data, the model file closing the loop, the statistics underneath, and garbage in.

The generated runs come from tests/diagnosis_gen.py (the real simulator with one undeclared effect); the
acceptance study over many runs is benchmarks/bench_diagnose.py (docs/diagnosis-validation.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from diagnosis_gen import EFFECTS, generate_run, make_reference, simulate, write_measured
from once import make_once

from wamctl.analysis.diagnosis.backlash import breakaway_ratio, hidden_travel
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.analysis.diagnosis.signals import savgol_gain
from wamctl.analysis.diagnosis.stats import integrated_autocorr_time, nested_test, whiteness_p
from wamctl.errors import DataFormatError
from wamctl.experiments.diagnose import simulate_positions
from wamctl.model import params as P
from wamctl.runs.measured import load_run_data

# one generated run per effect (seeds chosen once, before looking at any result) and two clean runs
SEEDS = {"stribeck": 11, "position_ripple": 12, "payload": 13, "delay": 14, "friction_drift": 15, "backlash": 16}
CLEAN_SEEDS = (21, 22)


class Generated:
    """{name: (GeneratedRun, ModelDiagnosis)} for one run per effect and the clean runs ("clean21"), each generated
    and diagnosed once per session when a test first asks for it, whichever xdist worker that is (tests/once.py):
    the tests of one run need not wait for the other seven, nor two workers make the same one."""

    def __init__(self, tmp_path_factory):
        self.tmp_path_factory, self.made = tmp_path_factory, {}

    def __getitem__(self, name: str):
        effect, seed = (None, int(name[5:])) if name.startswith("clean") else (name, SEEDS[name])
        if effect is None and seed not in CLEAN_SEEDS:
            raise KeyError(name)

        def make(root: Path):
            g = generate_run(root, effect, seed)
            return g, ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(g.path))
        if name not in self.made:       # held while this module runs (50-150 MB each), as the module fixture did
            self.made[name] = make_once(self.tmp_path_factory, f"diagnose_{name}", make, keep=False)
        return self.made[name]


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    return Generated(tmp_path_factory)


def _ratio(diag, joint, key):
    """after / before at the effect's joint (1-based), or pooled over the joints (payload, delay)."""
    js = [joint - 1] if joint else list(diag.joints_)
    b = np.array([getattr(diag.joints_[j], f"{key}_before_{'Nm' if key == 'torque_rms' else 'rad'}") for j in js])
    a = np.array([getattr(diag.joints_[j], f"{key}_after_{'Nm' if key == 'torque_rms' else 'rad'}") for j in js])
    return float(np.sqrt(np.sum(a ** 2) / np.sum(b ** 2)))


# ------------------------------------------------------------------------------------- generated runs
@pytest.mark.slow
@pytest.mark.parametrize("effect", EFFECTS)
def test_injected_effect_is_named_first(generated, effect):
    g, diag = generated[effect]
    assert diag.conclusive_
    assert diag.effects_found_, f"{effect} at joint {g.joint} ({g.effect_spec}) not found"
    assert diag.effects_found_[0] == effect, diag.effects_found_
    if g.joint is not None:
        names = [e["name"] for e in diag.joints_[g.joint - 1].effects]
        assert effect in names, f"{effect} named at the wrong joint: {diag.to_dict()['effects_found']}"


@pytest.mark.slow
@pytest.mark.parametrize("seed", CLEAN_SEEDS)
def test_clean_runs_report_nothing(generated, seed):
    g, diag = generated[f"clean{seed}"]
    assert diag.conclusive_
    assert diag.effects_found_ == []
    for res in diag.joints_.values():
        assert res.torque_rms_after_Nm == pytest.approx(res.torque_rms_before_Nm)


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["position_ripple", "payload", "friction_drift", "backlash"])
def test_held_out_torque_rms_drops_threefold(generated, effect):
    g, diag = generated[effect]
    assert _ratio(diag, g.joint, "torque_rms") <= 1 / 3


# Stribeck is left out here: a joint that sticks and slips is chaotic in closed loop, so a re-simulation with the
# right model can still be out of phase with the measurement (the benchmark measures how often positions drop)
@pytest.mark.slow
@pytest.mark.parametrize("effect", [e for e in EFFECTS if e != "stribeck"])
def test_held_out_position_rms_drops(generated, effect):
    g, diag = generated[effect]
    assert _ratio(diag, g.joint, "position_rms") < 1.0


@pytest.mark.slow
def test_effect_parameters_are_recovered(generated):
    g, diag = generated["position_ripple"]
    p = diag.effect_params(g.joint - 1, "position_ripple")
    assert p["period_rad"] == pytest.approx(g.effect_spec["period_rad"], rel=0.02)
    assert p["amplitude_Nm"] == pytest.approx(g.effect_spec["amplitude_Nm"], rel=0.15)
    g, diag = generated["payload"]
    assert diag.payload_["mass_kg"] == pytest.approx(g.effect_spec["mass_kg"], rel=0.1)
    g, diag = generated["delay"]
    found = [diag.effect_params(j, "delay")["delay_s"] for j, r in diag.joints_.items()
             if any(t["name"] == "delay" for t in r.kept)]
    assert np.median(found) == pytest.approx(g.effect_spec["delay_s"], abs=1.5e-3)
    g, diag = generated["backlash"]
    p = diag.effect_params(g.joint - 1, "backlash")
    assert p["width_rad"] == pytest.approx(g.effect_spec["width_rad"], rel=0.25)
    assert p["encoder_side"] == "link"             # the plant's dead band: the measurement lags the link


@pytest.mark.slow
def test_diagnosis_json_has_the_documented_keys(generated):
    g, diag = generated["friction_drift"]
    d = json.loads(json.dumps(diag.to_dict(str(g.path))))
    assert d["format"] == "wamctl-diagnosis/1"
    assert d["effects_found"][0] == "friction_drift"
    for key in ("data", "declared_model", "joints"):
        assert key in d
    jd = d["joints"][str(g.joint)]
    for key in ("effects", "candidates", "torque_rms_before_Nm", "torque_rms_after_Nm", "position_rms_before_rad",
                "position_rms_after_rad", "residual_whiteness_p_before", "residual_whiteness_p_after"):
        assert key in jd
    e = jd["effects"][0]
    assert e["name"] == "friction_drift" and {"test", "p_value", "delta_bic"} <= set(e["evidence"])
    assert e["evidence"]["p_value"] < d["method"]["test_threshold_p"] and e["evidence"]["delta_bic"] < 0
    assert e["params"]["fraction"] == pytest.approx(g.effect_spec["fraction"], abs=0.1)
    names = {c["name"] for c in jd["candidates"]}
    assert names - set(EFFECTS) <= {"link_parameters"} and set(EFFECTS) <= names  # docs: the seventh candidate
    assert all({"name", "p_value", "delta_bic", "kept"} <= set(c) for c in jd["candidates"])


# ------------------------------------------------------------------------------------- CLI and model file
@pytest.fixture(scope="module")
def ripple_cli(generated, tmp_path_factory):
    """``wamctl diagnose RUN --json`` on the position-ripple run, once for the two tests that read it (each had
    diagnosed the run again): the command's result, its run directory, and every (done, total, label) that
    ``diagnose_to_run_dir`` reported to its progress callback on the way."""
    import wamctl.experiments.diagnose as pipeline

    g, _ = generated["position_ripple"]
    out, seen, real = tmp_path_factory.mktemp("ripple_cli"), [], pipeline.diagnose_to_run_dir

    def recording(*args, progress=None, **kw):
        def tee(done, total, label=None):
            seen.append((done, total, label))
            if progress is not None:
                progress(done, total, label)
        return real(*args, progress=tee, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pipeline, "diagnose_to_run_dir", recording)
        res = run_cli("diagnose", g.path, "--out", out / "runs", "--json")
    assert res.exc is None, res.tb
    return res, out / "runs", seen


@pytest.mark.slow
def test_cli_writes_run_directory_and_model_file_closes_the_loop(generated, ripple_cli, tmp_path):
    from typer.testing import CliRunner

    from wamctl.cli import _register, app
    from wamctl.specs import load_spec

    _register()
    g, _ = generated["position_ripple"]
    res, runs, _ = ripple_cli
    assert res.code == 0, res.out + res.err
    out = json.loads(res.out)
    assert out["effects_found"][0] == "position_ripple"
    run = next(runs.iterdir())
    for f in ("diagnosis.json", "model.yaml", "report.md", "report.html", "diagnosis_residuals.png",
              "diagnosis_evidence.png", "diagnosis_positions.png", "residuals.parquet", "positions.parquet"):
        assert (run / f).is_file(), f
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["kind"] == "diagnosis" and manifest["status"] == "completed"
    model = yaml.safe_load((run / "model.yaml").read_text())
    assert model["format"] == "wamctl-model/1"
    rip = model["effects"]["position_ripple"]
    assert rip["joints"] == [g.joint]
    assert rip["period_rad"] == pytest.approx(g.effect_spec["period_rad"], rel=0.02)
    # `wamctl run` takes it as `plant: model.yaml`
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(yaml.safe_dump({
        "kind": "rotation", "name": "replay", "plant": str(run / "model.yaml"), "controller": {"kind": "pd_g"},
        "rotation": {"joints": [g.joint], "amplitude_rad": 0.1, "velocity_rad_s": 0.2, "tc_s": 0.2,
                     "settle_s": 0.0, "hold_s": 0.1}}))
    spec = load_spec(spec_path)
    assert spec.plant.effects.position_ripple.period_rad == pytest.approx(rip["period_rad"])
    res = CliRunner().invoke(app, ["run", str(spec_path), "--out", str(tmp_path / "replay"), "--json", "-q"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["status"] == "completed"


@pytest.mark.slow
def test_declared_friction_file_is_used(tmp_path):
    """--model with the true friction: a clean run stays clean; the before model is not refitted."""
    from wamctl.experiments.diagnose import declared_model
    from wamctl.model.friction import FrictionModel

    g = generate_run(tmp_path, None, 31, duration_s=15.0)
    f = tmp_path / "friction_model.yaml"
    FrictionModel.table_4_1().save(f)
    decl = declared_model(f)
    diag = ModelDiagnosis(declared=decl).fit(load_run_data(g.path))
    assert diag.effects_found_ == []
    assert "friction_model.yaml" in diag.to_dict()["declared_model"]
    for j, res in diag.joints_.items():
        np.testing.assert_array_equal(res.e_before, diag.jd_[j].y_Nm)     # "before" is the file's model as given
        # the levels: the file's, plus a small correction fitted on top (for the tests of the candidates)
        assert diag.friction_before(j)["fc_pos_Nm"] == pytest.approx(P.TABLE_4_1_FC_POS_NM[j], abs=0.15)


@pytest.mark.slow
def test_clean_stalls_leave_no_torque_residual(generated):
    """A clean run: at the stalls the declared model and the measurement leave rest together (within the
    encoder's resolution), so the stall residual is a small part of the torque RMS; it is not made of one-sample
    disagreements on when the joint moved, each worth the whole torque beyond the Coulomb level."""
    for seed in CLEAN_SEEDS:
        _, diag = generated[f"clean{seed}"]
        for res in diag.joints_.values():
            st = res.stall_before
            if st is None or not len(st):
                continue
            e = res.e_before[np.isfinite(res.e_before)]
            assert np.sqrt(np.mean(st ** 2)) <= 0.5 * np.sqrt(np.mean(e ** 2)) + 1e-3


@pytest.mark.slow
def test_declared_delay_applies_at_the_stalls_too(generated):
    """A model file that declares the run's delay: nothing is left to name, and the declared model's residual is
    the one the diagnosis reached by finding the delay itself (the stalls shifted like the sliding samples)."""
    from wamctl.analysis.diagnosis.estimator import DeclaredModel

    g, diag = generated["delay"]
    found = np.median([diag.effect_params(j, "delay")["delay_s"] for j, r in diag.joints_.items()
                       if any(t["name"] == "delay" for t in r.kept)])
    decl = DeclaredModel(effects={"delay": {"delay_s": float(found)}})
    again = ModelDiagnosis(declared=decl).fit(load_run_data(g.path))
    assert "delay" not in again.effects_found_
    b = np.sqrt(sum(r.torque_rms_before_Nm ** 2 for r in again.joints_.values()))
    a = np.sqrt(sum(r.torque_rms_after_Nm ** 2 for r in diag.joints_.values()))
    assert b <= 1.25 * a


@pytest.mark.slow
def test_stribeck_breakaway_levels_per_direction(generated):
    """Stribeck: the breakaway level of each direction, measured at the onsets, within 20 % of the truth
    (seed 11: +9 % and +13 %; the breakaway is seen a sample or two late, once the encoder has moved)."""
    g, diag = generated["stribeck"]
    p = diag.effect_params(g.joint - 1, "stribeck")
    rho = g.effect_spec["breakaway_ratio"]
    j = g.joint - 1
    assert p["Fs_pos_Nm"] == pytest.approx(rho * P.TABLE_4_1_FC_POS_NM[j], rel=0.2)
    assert p["Fs_neg_Nm"] == pytest.approx(rho * P.TABLE_4_1_FC_NEG_NM[j], rel=0.2)


# ------------------------------------------------------------------------------------- statistics
def test_savgol_gain_is_one_at_dc_and_small_at_nyquist():
    assert savgol_gain(21, np.array([0.0]))[0] == pytest.approx(1.0)
    assert abs(savgol_gain(21, np.array([0.45]))[0]) < 0.1


def test_integrated_autocorrelation_time():
    rng = np.random.default_rng(0)
    white = rng.normal(size=20000)
    assert integrated_autocorr_time(white) == pytest.approx(1.0, abs=0.2)
    ar = np.zeros(20000)
    for i in range(1, len(ar)):
        ar[i] = 0.9 * ar[i - 1] + white[i]
    assert integrated_autocorr_time(ar) == pytest.approx((1 + 0.9) / (1 - 0.9), rel=0.25)


def test_nested_test_false_alarm_rate_on_noise():
    """Held-out residuals of a useless extra column: p-values are not small more often than they should."""
    rng = np.random.default_rng(1)
    small = 0
    for _ in range(200):
        e0 = rng.normal(size=500)
        e1 = e0 - 0.02 * rng.normal(size=500)
        t = nested_test(e0, e1, 1, 5, min_effect=0.0)
        small += t["p_value"] < 0.01
    assert small <= 6


def test_minimum_effect_test_ignores_tiny_structure_but_not_real_effects():
    rng = np.random.default_rng(2)
    e1 = rng.normal(size=50000)
    tiny = e1 + 0.1 * np.sin(np.arange(50000) / 50)        # 0.5 % of the variance, "significant" at this n
    big = e1 + 0.6 * np.sin(np.arange(50000) / 50)          # 15 %
    assert nested_test(tiny, e1, 2, 6, min_effect=0.0)["p_value"] < 1e-6
    assert nested_test(tiny, e1, 2, 6)["p_value"] > 0.5
    assert nested_test(big, e1, 2, 6)["p_value"] < 1e-10


def test_whiteness_of_white_and_of_correlated_noise():
    rng = np.random.default_rng(3)
    assert whiteness_p(rng.normal(size=3000), 1) > 0.01
    assert whiteness_p(np.cumsum(rng.normal(size=3000)), 1) < 1e-6


def test_hidden_travel_and_breakaway_ratio():
    dt, inertia = 0.002, 0.01
    assert np.all(hidden_travel(np.full(100, 0.5), dt, inertia, 1.0, 1.0, 0.1, 0.1) == 0.0)
    ramp = np.linspace(0.0, 3.0, 300)                  # torque ramping through the Coulomb level
    x = hidden_travel(ramp, dt, inertia, 1.0, 1.0, 0.1, 0.1)
    assert x[-1] > 0.1 and x[np.searchsorted(ramp, 0.99)] == 0.0
    # a joint that held until 1.6 N m (the ramp stops there, then the data say it moved): ratio ~1.6
    u = np.concatenate([np.linspace(0.0, 1.6, 200), np.full(5, 1.6)])
    assert breakaway_ratio(u, dt, inertia, 1.0, 1.0, 0.1, 0.1, tol=1e-4) == pytest.approx(1.6, rel=0.03)


# ------------------------------------------------------------------------------------- garbage in
@pytest.fixture(scope="module")
def short_clean(tmp_path_factory):
    """A short clean run (10 s), its data as a DataFrame."""
    root = tmp_path_factory.mktemp("short")
    g = generate_run(root, None, 41, duration_s=10.0)
    return g.path, pd.read_parquet(g.path / "data.parquet"), yaml.safe_load((g.path / "meta.yaml").read_text())


def _write(tmp_path, df, meta, name="bad"):
    d = tmp_path / name
    d.mkdir()
    df.to_parquet(d / "data.parquet", index=False)
    (d / "meta.yaml").write_text(yaml.safe_dump(meta))
    return d


def test_many_nan_rows_are_a_clear_error(tmp_path, short_clean):
    from wamctl.experiments.diagnose import diagnose_to_run_dir
    _, df, meta = short_clean
    df = df.copy()
    df.loc[df.index[100:400], "q_3"] = np.nan
    with pytest.raises(DataFormatError, match="NaN"):
        diagnose_to_run_dir(_write(tmp_path, df, meta), out=tmp_path / "runs")


def test_isolated_nan_rows_are_dropped_and_nothing_is_made_up(tmp_path, short_clean):
    _, df, meta = short_clean
    df = df.copy()
    df.loc[df.index[[500, 1700, 3100]], "tau_2"] = np.nan
    diag = ModelDiagnosis().fit(load_run_data(_write(tmp_path, df, meta)))
    assert diag.conclusive_ and diag.effects_found_ == []
    assert diag.signals_.resampled


def test_missing_joint_column_is_a_clear_error(tmp_path, short_clean):
    _, df, meta = short_clean
    with pytest.raises(DataFormatError, match="tau_4"):
        load_run_data(_write(tmp_path, df.drop(columns=["tau_4"]), meta))


def test_wrong_sample_rate_is_a_clear_error(tmp_path, short_clean):
    _, df, meta = short_clean
    with pytest.raises(DataFormatError, match="sample_rate_hz"):
        load_run_data(_write(tmp_path, df, dict(meta, sample_rate_hz=1000)))
    slow = df.iloc[::25].reset_index(drop=True)             # 20 Hz, and the metadata says so
    with pytest.raises(DataFormatError, match="50 Hz"):
        slow_run = _write(tmp_path, slow, dict(meta, sample_rate_hz=20), "slow")
        ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(slow_run))


def _with_gaps(src: Path, dst: Path, n_gaps: int = 8, seed: int = 3) -> Path:
    """A copy of the run ``src`` whose log lost ``n_gaps`` stretches of 25-250 samples (a bus that dropped
    frames, a logger that paused): about 8 % of a 30 s run."""
    df = pd.read_parquet(src / "data.parquet")
    rng = np.random.default_rng(seed)
    drop = np.zeros(len(df), bool)
    for c in rng.choice(np.arange(len(df) // 20, len(df) - len(df) // 20), n_gaps, replace=False):
        drop[c:c + int(rng.integers(25, 250))] = True
    dst.mkdir()
    df[~drop].reset_index(drop=True).to_parquet(dst / "data.parquet", index=False)
    (dst / "meta.yaml").write_text((src / "meta.yaml").read_text())
    return dst


@pytest.mark.slow
@pytest.mark.parametrize("name", ["payload", "position_ripple", "clean21"])
def test_gaps_in_time_are_left_out_and_change_nothing(generated, tmp_path, name):
    """A log with gaps in t is diagnosed as without them: the samples around each gap are left out (interpolated
    across, the filters would make up accelerations and torques there: the payload and the ripple were missed)."""
    g, diag = generated[name]
    gapped = ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(_with_gaps(g.path, tmp_path / "gaps")))
    assert gapped.effects_found_ == diag.effects_found_ and gapped.ambiguous_ == diag.ambiguous_
    assert gapped.conclusive_
    sig = gapped.signals_
    assert len(sig.gaps_s) >= 6 and not sig.moving[~sig.valid].any()
    assert any(w.startswith("t: ") and "gap(s)" in w for w in gapped.warnings_)


def test_the_encoder_step_is_read_from_measured_samples_only():
    """A slow quantised joint with five gaps of 200 samples: the interpolated stretches move by a fraction of a
    count per sample; the encoder step (and so the onsets' detection tolerance) must not come from them (it read
    6e-6 rad for a 3.7e-5 rad step)."""
    from wamctl.analysis.diagnosis.onsets import detection_tolerance
    from wamctl.analysis.diagnosis.signals import prepare_signals

    rate, n = 500.0, 30000
    t = np.arange(n) / rate
    step = 2 * np.pi / 4096 * np.abs(np.linalg.inv(P.J2MP))[0][np.abs(np.linalg.inv(P.J2MP))[0] > 1e-12].min()
    q_true = np.zeros((n, 7))
    q_true[:, 0] = 0.03 * (2 * np.abs((t / 20.0) % 1 - 0.5) - 0.5)       # +-15 mrad over 20 s: 3 mrad/s
    q = np.round(q_true / step) * step
    tau = 0.5 * np.sign(np.gradient(q_true, axis=0)) + 0.01 * np.random.default_rng(0).standard_normal((n, 7))
    keep = np.ones(n, bool)
    for c in (3000, 9000, 15000, 21000, 27000):
        keep[c:c + 200] = False
    tols = [detection_tolerance(prepare_signals(t[k], q[k], q_true[k], tau[k], rate, [0]), 0)
            for k in (np.ones(n, bool), keep)]
    assert tols[0][0] == pytest.approx(step, rel=1e-6)
    assert tols[1][0] == pytest.approx(tols[0][0], rel=1e-6) and tols[1][1] == pytest.approx(tols[0][1], rel=1e-6)


def test_a_log_that_is_mostly_gaps_is_a_clear_error(tmp_path, short_clean):
    _, df, meta = short_clean
    holey = df.iloc[np.arange(len(df)) % 40 < 8].reset_index(drop=True)     # 8 samples out of every 40
    with pytest.raises(DataFormatError, match="away from the gaps in t"):
        ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(_write(tmp_path, holey, meta)))


def test_no_motion_reports_why_nothing_was_concluded(tmp_path):
    from wamctl.control.trajectory import ReferenceBuilder
    from wamctl.experiments.diagnose import diagnose_to_run_dir

    q0 = np.array([0.0, 0.3, 0.0, 1.57, 0.0, 0.0, 0.0])
    ref = ReferenceBuilder(q0, 1.0 / P.CONTROL_RATE_HZ).hold(4.0).build()
    rows = simulate({"friction": "table_4_1"}, ref, q0)
    path = write_measured(tmp_path / "still", rows, q0)
    run, result, doc = diagnose_to_run_dir(path, out=tmp_path / "runs")
    assert result["conclusive"] is False and result["effects_found"] == [] and result["joints"] == {}
    assert "no joint moved" in result["reason"]
    assert "Nothing could be concluded" in (run / "report.md").read_text()


def test_torque_that_is_not_this_arm_names_nothing(tmp_path, short_clean):
    """Torque in the wrong unit (mN m) or shuffled joints: no effect is made up to explain it."""
    _, df, meta = short_clean
    bad = df.copy()
    for j in range(1, 8):
        bad[f"tau_{j}"] = df[f"tau_{(j % 7) + 1}"]
    diag = ModelDiagnosis().fit(load_run_data(_write(tmp_path, bad, meta)))
    assert diag.effects_found_ == []
    assert not diag.conclusive_ and "declared model explains only" in diag.reason_


def test_reference_generator_reverses_every_joint():
    rng = np.random.default_rng(5)
    q0 = np.array([0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])
    ref = make_reference(rng, q0, 30.0)
    for j in range(P.N_JOINTS):
        signs = np.sign(ref.qd_rad_s[:, j][np.abs(ref.qd_rad_s[:, j]) > 1e-6])
        assert np.count_nonzero(np.diff(signs)) >= 3
    assert np.all(ref.q_rad >= P.Q_MIN_RAD) and np.all(ref.q_rad <= P.Q_MAX_RAD)


def test_progress_moves_through_the_joints_and_ends_at_the_whole(ripple_cli):
    """The progress bar advances joint by joint (it sat at 0 % through the whole fit, then jumped): what
    `wamctl diagnose` on the position-ripple run reported to its progress callback."""
    _, _, seen = ripple_cli
    done = [d for d, _, _ in seen]
    assert done == sorted(done) and done[0] == 0 and seen[-1][:2] == (100, 100)
    joints = [label for _, _, label in seen if "joint" in label and "torque residual" in label]
    assert len(joints) >= 1 and len(set(done)) >= 5, seen
