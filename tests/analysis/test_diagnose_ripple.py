"""The position ripple as real ripples are: a fundamental and its harmonics (issue 15).

A run of the independent generator (tests/analysis/gen_independent: its own plant, 4 kHz physics, its ripple
formula ``A sum_h c_h sin(2 pi h q / P + phi_h)``) with a second harmonic STRONGER than the fundamental, so that
the period found must be the fundamental ``P``, not ``P / 2``; and the model files: an old one-sinusoid ripple
still loads and simulates, a ripple with harmonics is applied as written.

Tolerances were stated before the first run: period within 0.5 %; each harmonic's amplitude within a tenth of
the largest one's; held-out torque RMS after / before at most 0.2 (a large ripple: "well below 1/3").
"""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.diagnosis.augmented import plant_dict
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.model.effects import ripple_torque_Nm
from wamctl.model.plant import Plant
from wamctl.runs.measured import load_run_data
from wamctl.specs import PlantSpec

WEIGHTS = [0.4, 0.85, 0.3]          # the second harmonic carries most of the ripple
PHASES = [0.7, 2.1, 4.4]
PERIOD = 2 * np.pi / 36.0           # a shoulder joint's motor turn


@pytest.fixture(scope="module")
def ripple_run(tmp_path_factory):
    from gen_independent import generate

    case = dict(id="ripple-harmonics", seed=1515, links="nominal", excitation="sweep", joint=4, rate_hz=500,
                noise="quiet", jitter="stamp",
                effects=[dict(name="position_ripple", joint=4, size="large",
                              params=dict(period_rad=PERIOD, harmonic_weights=WEIGHTS, phases_rad=PHASES))])
    r = generate(case, tmp_path_factory.mktemp("ripple") / "run")
    diag = ModelDiagnosis().fit(load_run_data(r.path))
    return r.truth, diag


def test_ripple_with_a_strong_harmonic_is_named_at_its_fundamental(ripple_run):
    truth, diag = ripple_run
    amp = truth["effects"][0]["params"]["amplitude_Nm"]
    out = diag.to_dict()
    assert out["effects_found"][0] == "position_ripple"
    e = next(x for x in out["joints"]["4"]["effects"] if x["name"] == "position_ripple")
    p = e["params"]
    assert p["period_rad"] == pytest.approx(PERIOD, rel=0.005)           # P, not P / 2
    assert p["n_harmonics"] >= 3
    true_amps = amp * np.array(WEIGHTS)
    found = [p["amplitude_Nm"], p["amplitude_2_Nm"], p["amplitude_3_Nm"]]
    np.testing.assert_allclose(found, true_amps, atol=0.1 * true_amps.max())
    # every parameter the report gives carries its 95 % interval (the period's from the profile likelihood)
    for k, v in p.items():
        if k != "n_harmonics":
            lo, hi = e["params_ci"][k]
            assert lo <= v <= hi, k
    j = out["joints"]["4"]
    assert j["torque_rms_after_Nm"] <= 0.2 * j["torque_rms_before_Nm"]


def test_model_file_carries_the_harmonics_found(ripple_run):
    """The augmented model (model.yaml's plant) applies the ripple the diagnosis fitted: the plant's torque equals
    the fitted series at any angle."""
    _, diag = ripple_run
    rip = plant_dict(diag)["effects"]["position_ripple"]
    assert len(rip["harmonics"]) >= 2
    p = diag.effect_params(3, "position_ripple")
    plant = Plant(PlantSpec.model_validate(plant_dict(diag)))
    q = np.linspace(-1.0, 1.0, 7)
    series = sum(p["amplitude_Nm" if h == 1 else f"amplitude_{h}_Nm"]
                 * np.sin(2 * np.pi * h * q / p["period_rad"] + p["phase_rad" if h == 1 else f"phase_{h}_rad"])
                 for h in range(1, p["n_harmonics"] + 1))
    qq = np.zeros((len(q), 7))
    qq[:, 3] = q
    np.testing.assert_allclose(plant.ripple_torque_Nm(qq)[:, 3], series, atol=1e-9)


def test_old_one_sinusoid_model_file_loads_and_simulates():
    """A model file written before harmonics existed (no ``harmonics`` key) is still valid, its ripple is the one
    sinusoid it says, and the simulated arm feels it."""
    from wamctl.backends.sim import SimBackend

    old = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0},
           "effects": {"position_ripple": {"joints": [3], "amplitude_Nm": 0.8, "period_rad": 0.1, "phase_rad": 0.3}}}
    plant = Plant(PlantSpec.model_validate(old))
    q = np.zeros((5, 7))
    q[:, 2] = np.linspace(0.0, 0.2, 5)
    np.testing.assert_allclose(plant.ripple_torque_Nm(q)[:, 2], 0.8 * np.sin(2 * np.pi * q[:, 2] / 0.1 + 0.3))
    assert not plant.ripple_torque_Nm(q)[:, [0, 1, 3, 4, 5, 6]].any()
    q0 = np.array([0.0, 0.0, 0.05, 1.5, 0.0, 0.0, 0.0])
    moved = {}
    for name, fx in (("ripple", old["effects"]), ("none", {})):
        spec = dict(old, friction="none", effects=fx)         # no friction: the ripple alone moves joint 3
        with SimBackend(Plant(PlantSpec.model_validate(spec)), q0, np.random.default_rng(0)) as sim:
            for _ in range(50):
                sim.read_positions()
                sim.command_torques(sim.dynamics.gravity(sim.q_true_rad))
                sim.wait_next_cycle()
            moved[name] = sim.q_true_rad[2] - q0[2]
    ripple_at_q0 = 0.8 * np.sin(2 * np.pi * 0.05 / 0.1 + 0.3)
    assert abs(moved["none"]) < 1e-6
    assert np.sign(moved["ripple"]) == np.sign(ripple_at_q0) and abs(moved["ripple"]) > 1e-4


def test_ripple_torque_is_the_sum_of_its_harmonics():
    q = np.linspace(-0.3, 0.3, 11)
    amps, phases = np.array([0.5, 0.2, 0.1]), np.array([0.1, 1.0, 2.0])
    want = sum(a * np.sin((h + 1) * 20.0 * q + ph) for h, (a, ph) in enumerate(zip(amps, phases)))
    np.testing.assert_allclose(ripple_torque_Nm(q, amps, 20.0, phases), want)
    assert ripple_torque_Nm(float(q[7]), amps, 20.0, phases) == pytest.approx(float(want[7]))   # a scalar angle
