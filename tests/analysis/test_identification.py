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
from wamctl.runs.store import read_table
from wamctl.specs import PlantSpec, load_model_file, load_spec, parse_spec
from wamctl.specs.common import link_parameters

ROOT = Path(__file__).resolve().parents[2]
SENSORS = {"position_noise_rad": 2.0e-5, "torque_noise_Nm": 0.02}


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
    raw.update(plant=plant, **overrides)
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
    rows = run_rows(__import__("wamctl.runs.measured", fromlist=["x"]).load_run_data(held), WamDynamics(),
                    window_s=None)
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
    for f in ("model.yaml", "identification.json", "parameters.csv", "validation.parquet", "report.md",
              "identification_validation.png", "identification_moved.png"):
        assert (run_path / f).stat().st_size > 0, f
    model = run_path / "model.yaml"
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
    """Thesis rotation test (PD + gravity, each joint 0.5 rad, one at a time) on the perturbed arm: the final
    (static) errors of the gravity-loaded joints 2 and 4 are smaller with the identified model declared."""
    model = identify_to_run_dir([arm["train"]], [arm["held"]], out=tmp_path)[0] / "model.yaml"
    links = yaml.safe_load(model.read_text())["links"]
    base = {"kind": "rotation", "name": "g", "seed": 1, "plant": arm["plant"],
            "q0_rad": [0.0, 0.6, 0.0, 1.2, 0.0, 0.0, 0.0],
            "rotation": {"joints": [2, 4], "mode": "one_at_a_time", "hold_s": 2.0}}
    errors = {}
    for name, ctl in (("nominal", {}), ("identified", {"declared_links": links})):
        outcome = run_spec(parse_spec(dict(base, controller=ctl)), None, tmp_path, make_report=False)
        errors[name] = rotation_metrics(read_table(outcome.path))["final_error_rad"].abs()
    print(errors)
    assert (errors["identified"] < errors["nominal"]).all()
    assert errors["identified"].sum() < 0.5 * errors["nominal"].sum()
