"""`wamctl identify` on a simulated arm whose links differ from the datasheet: the issue's "done when" claims.

The arm: every link's mass, COM and inertia scaled by a factor drawn once in U(0.8, 1.2) (fixed seed, never
redrawn), armature in U(0.9, 1.1), Table 4.1 friction scaled by U(0.85, 1.15) per joint; sensors as a real WAM
(4096-count encoders, 2e-5 rad position noise, 0.02 N m actuation noise that the log does not see). Identified
from the shipped designed excitation (configs/excitation.yaml, 6 x 10 s) run on the project's simulator, and
validated on the other shipped trajectory (configs/excitation_validation.yaml). Thresholds are the issue's,
fixed before looking: held-out RMS <= 1.5 x the noise floor on every joint, >= 90 % of the identified base
parameters' 95 % intervals contain the truth, every link physically consistent. The noise floor is the
held-out RMS of the true arm's own model through the same processing (the diagnosis' filter).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from wamctl.analysis.identification.base import base_parameters, standard_vector
from wamctl.analysis.identification.data import run_rows
from wamctl.analysis.rotation import rotation_metrics
from wamctl.experiments.identify import identify, identify_to_run_dir
from wamctl.experiments.runner import run_spec
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.runs.measured import load_run_data
from wamctl.runs.store import read_table
from wamctl.specs import PlantSpec, load_model_file, load_spec, parse_spec
from wamctl.specs.common import link_parameters

ROOT = Path(__file__).resolve().parents[2]
SENSORS = {"position_noise_rad": 2.0e-5, "torque_noise_Nm": 0.02}
# 8 physics sub-steps per 2 ms period (0.25 ms): at the default 2, the simulator's own semi-implicit Euler step
# lets the viscous friction act with the velocity half a step late, a bias of 3-4 standard errors on some
# viscous coefficients of this fast excitation (interval coverage 82 % instead of 91 % for this arm, measured
# before the per-joint instruments: reported in docs/claims.md); the held-out torque is unaffected (<= 1.17 x the
# floor either way)
BACKEND = {"kind": "sim", "physics_substeps": 8}


def perturbed_plant(seed: int = 18, share: float = 0.2) -> dict:
    """The plant mapping of an arm whose links differ from the datasheet by up to ``share``."""
    rng = np.random.default_rng(seed)
    d = P.LinkParameters.datasheet()
    k = rng.uniform(1 - share, 1 + share, (P.N_JOINTS, 3))
    links = {j + 1: {"mass_kg": float(d.mass_kg[j] * k[j, 0]), "com_m": (d.com_m[j] * k[j, 1]).tolist(),
                     "inertia_kg_m2": (d.inertia_kg_m2[j] * k[j, 2]).tolist(),
                     "armature_kg_m2": float(d.armature_kg_m2[j] * rng.uniform(0.9, 1.1))}
             for j in range(P.N_JOINTS)}
    friction = FrictionModel.table_4_1().scaled(rng.uniform(0.85, 1.15, P.N_JOINTS))
    return {"friction": {"joints": friction.to_dict()["joints"]}, "links": links, "sensors": SENSORS}


def true_standard(plant: dict) -> np.ndarray:
    return standard_vector(WamDynamics(links=link_parameters(plant["links"])),
                           FrictionModel.from_dict(plant["friction"]))


def run_config(config: str, plant: dict, out: Path, **overrides) -> Path:
    raw = yaml.safe_load((ROOT / "configs" / config).read_text())
    raw.update(plant=plant, backend=BACKEND)
    raw.update(overrides)
    outcome = run_spec(parse_spec(raw), ROOT / "configs", out, make_report=False)
    assert outcome.status == "completed", outcome.reason
    return outcome.path


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    out = tmp_path_factory.mktemp("ident")
    plant = perturbed_plant()
    train = run_config("excitation.yaml", plant, out)
    held = run_config("excitation_validation.yaml", plant, out)
    est, validation, _ = identify([train], [held])
    # the noise floor on the rows the models are judged on: the fit's band (issue H10)
    (band,) = validation["band"]
    rows = run_rows(load_run_data(held), WamDynamics(), window_s=band["window_s"], gauss_s=band["gauss_s"])
    pi_true = true_standard(plant)
    floor = est.rms_by_joint([rows], pi=pi_true)
    return {"out": out, "plant": plant, "train": train, "held": held, "est": est, "validation": validation,
            "floor": floor, "pi_true": pi_true}


def test_held_out_rms_within_one_and_a_half_noise_floors_on_every_joint(arm):
    ident = arm["validation"]["rms"]["identified"]
    nominal = arm["validation"]["rms"]["nominal"]
    ratio = ident / arm["floor"]
    print("floor", arm["floor"].round(4), "identified/floor", ratio.round(3),
          "nominal/floor", (nominal / arm["floor"]).round(2))
    assert np.all(ratio <= 1.5), ratio
    # the nominal arm (datasheet links, friction fitted on the same data) is far off where gravity and inertia
    # matter (joints 2-4): at least three noise floors
    assert np.all(nominal[1:4] / arm["floor"][1:4] >= 3.0), nominal / arm["floor"]


def test_identified_base_parameters_cover_the_truth(arm):
    est = arm["est"]
    base = base_parameters()
    truth = base.of(arm["pi_true"])
    lo, hi = est.intervals()
    numbered = est.status() != "not identified"
    assert numbered.all(), est.identifiability_.undetermined          # every joint moved both ways
    inside = (truth >= lo) & (truth <= hi)
    print("coverage", inside[numbered].mean(), "outside", [base.names[k] for k in np.flatnonzero(~inside)])
    assert inside[numbered].mean() >= 0.90


def test_every_identified_link_is_physically_consistent(arm):
    est = arm["est"]
    assert (est.margin_ > 0).all(), est.margin_
    assert est.links_.inconsistent_links() == {}
    # the truth moved by up to 20 %; the identified arm reproduces its base parameters, not the datasheet's
    base = base_parameters()
    decl = base.of(est.pi_declared_)
    truth = base.of(arm["pi_true"])
    k = base.index("my2")
    assert abs(est.beta_[k] - truth[k]) < 0.2 * abs(decl[k] - truth[k])


def test_model_file_runs_the_identified_arm_and_feeds_the_controller(arm, tmp_path):
    """The run directory's model.yaml is a plant (`plant: model.yaml`) and a declared model
    (`controller.declared_links: model.yaml`): its gravity matches the true arm's far better than the
    datasheet's."""
    run_path, result, doc = identify_to_run_dir([arm["train"]], [arm["held"]], out=tmp_path)
    # the held-out check against the datasheet arm with friction fitted, in the fit's band (issue H10): below it
    # on every joint (0.0057-0.996x measured; 1-4 significantly, p_worse >= 0.98), the wrist joints 5-7 barely
    # (0.96 / 0.88 / 0.996x: links off by 20 % there change less than the estimate's noise): `better`, written as
    # model.yaml without --force. Until H10 the check ran without the fit's second filter: joints 5 and 7 were
    # above the declared arm (1.013x, 1.007x) by less than the held-out run could tell, `no_worse`.
    check = result["held_out_check"]
    print("held-out check", check["verdict"], {j: (round(r, 4), round(check["p_worse"][j], 3))
                                                for j, r in check["ratio"].items()})
    assert check["verdict"] == "better" and check["within_noise_joints"] == [] and check["worse_joints"] == []
    assert all(check["p_worse"][j] >= 0.95 for j in (2, 3, 4))
    assert check["model_written"] and not check["forced"] and (run_path / "model.yaml").is_file()
    # the report says which band its held-out RMS is in, and gives the diagnosis band's beside it
    report = (run_path / "report.md").read_text()
    (band,) = result["validation_band"]
    assert f"then the fit's second filter ({band['window_s']:g} s window)" in report
    assert "diagnosis filter (about 10 Hz, as `wamctl diagnose`)" not in report
    rows = json.loads((run_path / "report.json").read_text())["validation"]
    assert all(r["nominal_rms_diagnosis_band_Nm"] > 0 for r in rows)
    assert check["statement"].startswith("held-out check: the identified model is at least as good")
    assert all(r <= 0.25 for j, r in check["ratio"].items() if j in (2, 3, 4))
    assert max(check["ratio"].values()) < 1.0
    # in the diagnosis' band (the rows the check used before H10) the same model: joints 2-4 still far below
    v = result["validation"]
    diag = np.array(v["identified_diagnosis_band"]) / np.array(v["nominal_diagnosis_band"])
    print("diagnosis band ratios", diag.round(4))
    assert np.all(diag[1:4] <= 0.25) and diag.max() <= 1.10
    # instrumental variables on joints 1-6; joint 7 by least squares, said with its figure (its tracking error
    # is 40 % of its motion under the default gains; the reference is an instrument up to 20 %)
    runs = result["instruments_detail"]["runs"]
    assert runs[0]["instrumented_joints"] == [1, 2, 3, 4, 5, 6] and runs[0]["least_squares_joints"] == [7]
    assert 0.3 <= runs[0]["tracking_share"][7] <= 0.5
    assert "least squares on joint(s) 7" in result["instruments"] and "joint 7: tracking error 40 %" in \
        result["instruments"]
    for f in ("model.yaml", "identification.json", "parameters.csv", "validation.parquet", "report.md",
              "identification_validation.png", "identification_residuals.png", "identification_moved.png"):
        assert (run_path / f).stat().st_size > 0, f
    model = run_path / "model.yaml"
    # the same links as a URDF; the relative held-out torque error below the nominal's, inside its interval
    from wamctl.model.urdf import read_urdf_links
    urdf_links, yaml_links = read_urdf_links(run_path / "model.urdf"), link_parameters(result["links"])
    for k in P.LINK_KEYS:
        np.testing.assert_allclose(getattr(urdf_links, k), getattr(yaml_links, k), rtol=1e-12, atol=1e-15)
    rel = result["relative_error"]["held_out"][0]
    print("relative error held out", rel)
    assert rel["identified_ci95"][0] <= rel["identified"] <= rel["identified_ci95"][1] < rel["nominal"]
    assert check["relative_error_held_out"][0]["identified"] == rel["identified"]
    assert len(result["prior_moves"]) == result["identifiability"]["n_base"]
    plant = PlantSpec.model_validate(load_model_file(model))
    assert plant.links is not None and plant.friction.joints
    mf = yaml.safe_load(model.read_text())
    assert mf["provenance"]["tool"] == "wamctl identify" and mf["provenance"]["data"]
    spec_file = tmp_path / "rot.yaml"
    spec_file.write_text(yaml.safe_dump({"kind": "rotation", "name": "r", "plant": str(model),
                                         "controller": {"declared_links": str(model)}}))
    spec = load_spec(spec_file)
    assert spec.controller.declared_links == mf["links"] or spec.controller.declared_links
    true_dyn = WamDynamics(links=link_parameters(arm["plant"]["links"]))
    ident_dyn = WamDynamics(links=link_parameters(spec.controller.declared_links))
    qs = np.random.default_rng(0).uniform(P.Q_MIN_RAD, P.Q_MAX_RAD, (50, P.N_JOINTS))
    err_ident = np.abs([ident_dyn.gravity(q) - true_dyn.gravity(q) for q in qs]).max(axis=0)
    err_nom = np.abs([WamDynamics().gravity(q) - true_dyn.gravity(q) for q in qs]).max(axis=0)
    print("gravity error identified", err_ident.round(3), "nominal", err_nom.round(3))
    assert np.all(err_ident[1:4] < 0.25 * err_nom[1:4])


def test_gravity_compensation_with_the_identified_model_reduces_the_static_rotation_error(arm, tmp_path):
    """Rotation test (PD + gravity, libbarrett's gains, each joint 0.3 rad, one at a time, 1.5 s hold) on the
    perturbed arm's links, joints 2 and 4 (the ones gravity loads). Friction is switched off in this plant: with
    it, a move ends anywhere in the stick band (friction / kp) and the band, not the gravity compensation, sets
    the final error. The static error left is then the gravity mismatch over kp: smaller with the identified
    model declared (controller.declared_links: model.yaml) than with the datasheet's, on both joints."""
    model = identify_to_run_dir([arm["train"]], [arm["held"]], out=tmp_path, force=True)[0] / "model.yaml"
    plant = dict(arm["plant"], friction="none")
    static = {}
    for name, ctl in (("nominal", {}), ("identified", {"declared_links": str(model)})):
        spec = {"kind": "rotation", "name": f"g-{name}", "seed": 1, "plant": plant, "controller": ctl,
                "q0_rad": [0.0, 0.2, 0.0, 1.2, 0.0, 0.0, 0.0],
                "rotation": {"joints": [2, 4], "mode": "one_at_a_time", "amplitude_rad": 0.3, "hold_s": 1.5,
                             "return_to_start": False}}
        outcome = run_spec(parse_spec(spec), None, tmp_path, make_report=False)
        assert outcome.status == "completed", outcome.reason
        static[name] = rotation_metrics(read_table(outcome.path))["final_error_rad"].abs()
    print({k: v.round(6).to_dict() for k, v in static.items()})
    assert (static["identified"] < 0.25 * static["nominal"]).all()


def test_data_where_only_some_joints_move_name_what_they_cannot_determine(tmp_path):
    """A recording where only joints 2 and 4 move (the others held by the controller), identified without a
    separate validation run (the last quarter is held out): the held joints' parameters are named "not
    identified" and carry no number, the arm written is still physically consistent, and the held-out torque
    of the moving joints is not worse than the nominal model's."""
    coeffs = {2: {"a_rad_s": [0.1, -0.1, 0.0], "b_rad_s": [-0.06, -0.06, 0.06]},
              4: {"a_rad_s": [-0.2, 0.1, 0.1], "b_rad_s": [0.3, -0.3, 0.1]}}
    spec = {"kind": "excitation", "name": "two", "seed": 2, "q0_rad": [0.0, 0.0, 0.0, 2.2, 0.0, 0.0, 0.0],
            "plant": perturbed_plant(), "backend": BACKEND,
            "excitation": {"joints": [2, 4], "period_s": 6.0, "harmonics": 3, "periods": 4, "coefficients": coeffs,
                           "limits": {"torque_margin": 0.2}}}
    outcome = run_spec(parse_spec(spec), None, tmp_path, make_report=False)
    assert outcome.status == "completed", outcome.reason
    run_path, result, _ = identify_to_run_dir([outcome.path], out=tmp_path)
    ident = result["identifiability"]
    assert ident["rank"] < ident["n_base"]
    und = set(ident["undetermined"])
    assert {"fc_pos1", "b_neg3", "Ia5", "fc_neg7", "Izz7"} <= und
    assert not {"fc_pos2", "fc_neg4"} & und
    rows = {r["parameter"]: r for r in result["base"]}
    assert rows["fc_pos1"]["estimate"] is None and rows["fc_pos1"]["status"] == "not identified"
    assert rows["fc_pos2"]["estimate"] is not None
    assert result["consistent"]
    v = result["validation"]
    for j in (1, 3):
        assert v["identified"][j] <= v["nominal"][j] * 1.05
    assert "not identified" in (run_path / "report.md").read_text()


def test_unusable_input_is_one_line_and_exit_code_2(tmp_path):
    from cli_runs import wamctl_completed

    r = wamctl_completed("identify", tmp_path / "nope")
    assert r.returncode == 2 and "Traceback" not in r.stderr and "nope" in r.stderr


def test_a_run_that_does_not_excite_the_arm_is_not_offered_as_a_model(tmp_path):
    """Issue 32: identify on the demo's rotation run offered a model 5800x worse than the datasheet on joints 6-7,
    exit 0, no warning. A rotation run of joints 6 and 7 (0.3 rad at 0.083 rad/s, the demo's settings), identified
    with its last quarter held out: the held-out check fails on joint 7 (2.95x the declared arm's RMS measured),
    joint 6 has no held-out rows and is said unchecked, joints 1-5 did not move and are said not identified, and
    the model is written as model_rejected.yaml, never model.yaml."""
    spec = {"kind": "rotation", "name": "rot67", "seed": 1, "backend": {"kind": "sim"},
            "plant": {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 4096}},
            "controller": {"kind": "pd_g"}, "q0_rad": [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0],
            "rotation": {"joints": [6, 7], "mode": "one_at_a_time", "amplitude_rad": 0.3,
                         "velocity_rad_s": 0.083}}
    outcome = run_spec(parse_spec(spec), None, tmp_path, make_report=False)
    assert outcome.status == "completed", outcome.reason
    run_path, result, _ = identify_to_run_dir([outcome.path], out=tmp_path)
    check = result["held_out_check"]
    print(check["statement"])
    assert check["verdict"] == "worse" and check["worse_joints"] == [7] and check["ratio"][7] > 1.5
    assert check["unchecked_joints"] == [6] and check["not_moving_joints"] == [1, 2, 3, 4, 5]
    assert not (run_path / "model.yaml").exists() and (run_path / "model_rejected.yaml").is_file()
    assert result["model_file"] == "model_rejected.yaml" and check["model_written"] is False
