"""The base-parameter core (wamctl.analysis.identification.base) and the link parameters of the model.

Tolerances are set before looking: identities that hold in exact arithmetic are checked to 1e-9 relative to
the torque scale (pinocchio and LAPACK round to ~1e-15); what the data determine is checked by recovering the
truth exactly from noise-free torques (to 1e-6 relative) where the statement says "determined".
"""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.identification.base import (
    N_STANDARD,
    STANDARD_NAMES,
    base_from_regressor,
    base_parameters,
    identifiability,
    random_states,
    split_standard,
    standard_regressor,
    standard_vector,
)
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics, links_from_standard
from wamctl.model.friction import FrictionModel


def perturbed_links(rng, share=0.2) -> P.LinkParameters:
    """Every link's mass, COM and principal inertia scaled by up to +-share (a physical body stays physical:
    the inertia is rescaled as a whole and the COM moved)."""
    d = P.LinkParameters.datasheet()
    k = rng.uniform(1 - share, 1 + share, (7, 3))
    return P.LinkParameters(d.mass_kg * k[:, 0], d.com_m * k[:, 1:2], d.inertia_kg_m2 * k[:, 2:3],
                            d.armature_kg_m2 * rng.uniform(0.9, 1.1, 7))


@pytest.fixture(scope="module")
def base():
    return base_parameters()


def test_standard_regressor_is_the_simulators_dynamics():
    """Y @ pi equals pinocchio's inverse dynamics (armature included) plus the classic friction of the
    FrictionModel, for a perturbed arm with a payload: the regressor and the simulator share one truth."""
    rng = np.random.default_rng(1)
    dyn = WamDynamics(Payload(0.8, (0.01, 0.0, 0.06)), perturbed_links(rng))
    fr = FrictionModel.table_4_1()
    q, qd, qdd = random_states(20, rng)
    Y = standard_regressor(dyn, q, qd, qdd)
    pi = standard_vector(dyn, fr)
    want = np.array([dyn.inverse_dynamics(*x) for x in zip(q, qd, qdd)]) + fr.friction_torque(qd)
    np.testing.assert_allclose(Y @ pi, want, atol=1e-9 * np.abs(want).max())
    inertial, armature, fr2 = split_standard(pi)
    np.testing.assert_allclose(armature, dyn.links.armature_kg_m2)
    np.testing.assert_allclose(fr2.fc_neg_Nm, fr.fc_neg_Nm)


def test_base_reproduces_every_standard_vector_on_fresh_states(base):
    """Y pi == Y_b beta(pi) at states the base was not computed from, for random (not only nominal) pi."""
    rng = np.random.default_rng(7)
    q, qd, qdd = random_states(50, rng)
    Y = standard_regressor(WamDynamics(), q, qd, qdd).reshape(-1, N_STANDARD)
    for _ in range(5):
        pi = rng.normal(0.0, 1.0, N_STANDARD)
        tau = Y @ pi
        np.testing.assert_allclose(base.regressor(Y) @ base.of(pi), tau, atol=1e-9 * np.abs(tau).max())
    np.testing.assert_allclose(base.matrix @ pi, base.of(pi), atol=1e-12)


def test_base_size_is_the_regressor_rank(base):
    """The number of base parameters equals the rank of the stacked regressor found by an SVD (not the QR the
    base comes from), and the base's own columns are independent."""
    rng = np.random.default_rng(3)
    q, qd, qdd = random_states(150, rng)
    W = standard_regressor(WamDynamics(), q, qd, qdd).reshape(-1, N_STANDARD)
    s = np.linalg.svd(W, compute_uv=False)
    assert int(np.sum(s > 1e-9 * s[0])) == base.n_base
    sb = np.linalg.svd(base.regressor(W), compute_uv=False)
    assert sb[-1] / sb[0] > 1e-6
    # structural facts of the WAM: joint 1's axis is vertical (its link's mass and first moments never act),
    # every friction and armature parameter of joints 3..7 is a base parameter of its own
    assert {"m1", "mx1", "my1", "mz1"}.isdisjoint({n.rstrip("'") for n in base.names})
    for j in range(3, 8):
        assert f"Ia{j}" in base.names and f"fc_pos{j}" in base.names and f"b_neg{j}" in base.names
    assert base.expression(base.index("Izz1")).split(" + ")[0] == "Izz1"
    assert "Ia1" in base.expression(base.index("Izz1"))


def test_base_is_deterministic_and_independent_of_the_link_parameters():
    """The base is a property of the kinematics: recomputed from a perturbed arm's regressor, it is the same."""
    rng = np.random.default_rng(11)
    q, qd, qdd = random_states(120, rng)
    W = standard_regressor(WamDynamics(links=perturbed_links(rng)), q, qd, qdd).reshape(-1, N_STANDARD)
    b2 = base_from_regressor(W)
    b1 = base_parameters()
    assert b2.n_base == b1.n_base
    # the chosen columns may differ with the states; the spans must agree: each base of one is a combination
    # of the other's independent columns
    Y = standard_regressor(WamDynamics(), *random_states(30, rng)).reshape(-1, N_STANDARD)
    pi = rng.normal(size=N_STANDARD)
    np.testing.assert_allclose(b2.regressor(Y) @ b2.of(pi), b1.regressor(Y) @ b1.of(pi), atol=1e-8)


def _held_and_moving_data(moving: list[int], n=400, seed=5):
    """States where only ``moving`` (0-based) joints move (the others held at q0), positive and negative
    velocities; returns the stacked rows of the moving joints only (a held joint's rows carry unknown static
    friction and are not used), as an estimator would use them."""
    rng = np.random.default_rng(seed)
    q0 = np.array([0.1, 0.3, -0.2, 1.2, 0.3, -0.4, 0.5])
    t = np.linspace(0, 12, n)
    q, qd, qdd = np.tile(q0, (n, 1)), np.zeros((n, 7)), np.zeros((n, 7))
    for j in moving:
        w, a, ph = rng.uniform(0.8, 2.0), rng.uniform(0.3, 0.6), rng.uniform(0, 2 * np.pi)
        q[:, j] += a * np.sin(w * t + ph)
        qd[:, j] = a * w * np.cos(w * t + ph)
        qdd[:, j] = -a * w ** 2 * np.sin(w * t + ph)
    Y = standard_regressor(WamDynamics(), q, qd, qdd)[:, moving, :].reshape(-1, N_STANDARD)
    return Y


def test_identifiability_names_what_data_with_few_moving_joints_cannot_determine(base):
    """Joints 2 and 4 move, the others are held. Everything on a held joint (its friction, armature) is
    named undetermined; what the statement calls determined is recovered exactly from noise-free torques by
    the minimum-norm least squares (which knows nothing of the truth), what it calls undetermined is not."""
    Y = _held_and_moving_data([1, 3])
    Yb = base.regressor(Y)
    ident = identifiability(Yb, base)
    und = set(ident.undetermined)
    for j in (1, 3, 5, 6, 7):
        assert {f"fc_pos{j}", f"fc_neg{j}", f"b_pos{j}", f"b_neg{j}"} <= und
    assert {"Ia3", "Ia5", "Ia6", "Ia7"} <= und
    assert not {"fc_pos2", "fc_neg2", "b_pos4", "b_neg4"} & und
    assert ident.rank < base.n_base and ident.condition_number == float("inf")
    assert "not determined by these data" in ident.statement()
    rng = np.random.default_rng(9)
    beta = base.of(standard_vector(WamDynamics(links=perturbed_links(rng)), FrictionModel.table_4_1()))
    est = np.linalg.lstsq(Yb, Yb @ beta, rcond=None)[0]
    rel = np.abs(est - beta) / np.maximum(np.abs(beta), 1e-3)
    assert (rel[ident.identified] < 1e-6).all()
    assert (rel[~ident.identified] > 1e-6).sum() >= 0.8 * (~ident.identified).sum()


def test_identifiability_of_rich_data_is_full_rank(base):
    """Random states (every joint moving both ways) determine every base parameter."""
    Y = standard_regressor(WamDynamics(), *random_states(300, np.random.default_rng(2))).reshape(-1, N_STANDARD)
    ident = identifiability(base.regressor(Y), base)
    assert ident.full_rank and not ident.undetermined
    assert np.isfinite(ident.condition_number) and ident.condition_number >= 1.0
    assert ident.to_dict()["rank"] == base.n_base


def test_names_are_the_documented_layout():
    assert len(STANDARD_NAMES) == N_STANDARD == 105
    assert STANDARD_NAMES[:3] == ("m1", "mx1", "my1") and STANDARD_NAMES[70] == "Ia1"
    assert STANDARD_NAMES[77:81] == ("fc_pos1", "fc_neg1", "b_pos1", "b_neg1")


# ----------------------------------------------------------------------------------------------- model
def test_links_round_trip_through_standard_parameters():
    """DH-frame link parameters -> pinocchio standard parameters -> DH-frame link parameters, exactly; and the
    datasheet is the default."""
    rng = np.random.default_rng(4)
    links = perturbed_links(rng)
    dyn = WamDynamics(links=links)
    back = links_from_standard(dyn.standard_parameters(), links.armature_kg_m2)
    for name in P.LINK_KEYS:
        np.testing.assert_allclose(getattr(back, name), getattr(links, name), atol=1e-14)
    assert WamDynamics().links == P.LinkParameters.datasheet()
    np.testing.assert_allclose(WamDynamics().mass_matrix(P.HOME_Q_RAD),
                               WamDynamics(links=P.LinkParameters.datasheet()).mass_matrix(P.HOME_Q_RAD))


def test_link_overrides_change_the_dynamics_and_name_bad_entries():
    d = P.LinkParameters.datasheet()
    heavier = d.with_overrides({3: {"mass_kg": 2.5}, 4: {"armature_kg_m2": 0.04}})
    assert heavier.mass_kg[2] == 2.5 and heavier.armature_kg_m2[3] == 0.04 and heavier.mass_kg[3] == d.mass_kg[3]
    assert heavier.to_mapping(changed_only=True) == {3: {"mass_kg": 2.5}, 4: {"armature_kg_m2": 0.04}}
    q = np.array([0.0, 0.8, 0.0, 1.0, 0.0, 0.0, 0.0])
    assert abs(WamDynamics(links=heavier).gravity(q)[1]) > abs(WamDynamics().gravity(q)[1])
    with pytest.raises(ValueError, match=r"links\.3\.mass: unknown key"):
        d.with_overrides({3: {"mass": 1.0}})
    with pytest.raises(ValueError, match=r"links\.2\.com_m: expected 3"):
        d.with_overrides({2: {"com_m": [0.0, 0.1]}})
    with pytest.raises(ValueError, match=r"links\.5\.mass_kg: must be > 0"):
        d.with_overrides({5: {"mass_kg": 0.0}})
    with pytest.raises(ValueError, match=r"links\.9"):
        d.with_overrides({9: {"mass_kg": 1.0}})
