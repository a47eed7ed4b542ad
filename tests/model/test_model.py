"""The rigid-body model against numbers computed independently of pinocchio (DH by hand, energy, Newton's law)."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics

RNG = np.random.default_rng(42)


def random_poses(n):
    return RNG.uniform(P.Q_MIN_RAD, P.Q_MAX_RAD, size=(n, P.N_JOINTS))


def dh_frames(q):
    """Frames 0..7 by the standard DH product A_i = Rz(q) Tz(d) Tx(a) Rx(alpha), written here independently."""
    T = np.eye(4)
    frames = [T.copy()]
    for i in range(7):
        ct, st = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(P.DH_ALPHA_RAD[i]), np.sin(P.DH_ALPHA_RAD[i])
        a, d = P.DH_A_M[i], P.DH_D_M[i]
        A = np.array([[ct, -st * ca, st * sa, a * ct],
                      [st, ct * ca, -ct * sa, a * st],
                      [0, sa, ca, d],
                      [0, 0, 0, 1]])
        T = T @ A
        frames.append(T.copy())
    return frames


def potential_energy(q, payload=None):
    frames = dh_frames(q)
    v = 0.0
    for i in range(7):
        com = frames[i + 1] @ np.append(P.LINK_COM_M[i], 1.0)
        v += P.LINK_MASS_KG[i] * P.GRAVITY_M_S2 * com[2]
    if payload is not None:
        com = frames[7] @ np.append(payload.com_m, 1.0)
        v += payload.mass_kg * P.GRAVITY_M_S2 * com[2]
    return v


def gravity_from_energy(q, payload=None, h=1e-6):
    g = np.zeros(7)
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        g[j] = (potential_energy(q + dq, payload) - potential_energy(q - dq, payload)) / (2 * h)
    return g


@pytest.mark.parametrize("payload", [None, Payload(1.1, (0.0, -0.005, 0.038))])
def test_gravity_matches_energy_gradient(payload):
    dyn = WamDynamics(payload)
    for q in random_poses(8):
        np.testing.assert_allclose(dyn.gravity(q), gravity_from_energy(q, payload), atol=2e-6)


def test_gravity_at_zero_pose_only_from_com_offsets():
    # arm straight up: the torques come from the small horizontal COM offsets only, and joint 1 (vertical) has none
    g = WamDynamics().gravity(np.zeros(7))
    assert abs(g[0]) < 1e-12
    np.testing.assert_allclose(g, gravity_from_energy(np.zeros(7)), atol=1e-6)


def test_payload_changes_gravity_by_m_g_lever():
    # J2 at 0, J4 at pi/2: the forearm is horizontal; a point mass at the flange adds m*g*(horizontal lever) on J2
    q = np.array([0.0, 0.0, 0.0, np.pi / 2, 0.0, 0.0, 0.0])
    m = 2.0
    base = WamDynamics().gravity(q)
    loaded = WamDynamics(Payload(m, (0.0, 0.0, 0.0))).gravity(q)
    flange = dh_frames(q)[7][:3, 3]
    shoulder_axis_origin = np.zeros(3)
    # horizontal distance from the J2 axis (through the origin)
    lever = np.linalg.norm((flange - shoulder_axis_origin)[:2])
    assert lever > 0.2
    assert abs(abs(loaded[1] - base[1]) - m * P.GRAVITY_M_S2 * lever) < 1e-6


def test_mass_matrix_symmetric_positive_definite():
    dyn = WamDynamics()
    for q in random_poses(200):
        m = dyn.mass_matrix(q)
        np.testing.assert_allclose(m, m.T, atol=1e-12)
        assert np.linalg.eigvalsh(m).min() > 1e-4
        # armature is on the diagonal: B_ii >= armature_i
        assert (np.diag(m) >= P.ARMATURE_KG_M2 - 1e-12).all()


def test_aba_inverts_rnea():
    dyn = WamDynamics(Payload(0.6, (0.01, 0.0, 0.04)))
    for q in random_poses(50):
        qd = RNG.normal(0, 1, 7)
        qdd = RNG.normal(0, 3, 7)
        tau = dyn.inverse_dynamics(q, qd, qdd)
        np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau), qdd, atol=1e-8)


def test_rnea_is_newtons_law_at_rest():
    # at zero velocity: tau = B(q) qdd + g(q), with B from CRBA
    dyn = WamDynamics()
    for q in random_poses(20):
        qdd = RNG.normal(0, 2, 7)
        np.testing.assert_allclose(dyn.inverse_dynamics(q, np.zeros(7), qdd),
                                   dyn.mass_matrix(q) @ qdd + dyn.gravity(q), atol=1e-9)


def test_armature_is_reflected_rotor_inertia():
    # diag(J2MP^T diag(Jm) J2MP) reproduces the published armature (coupled joints included)
    refl = np.diag(P.J2MP.T @ np.diag(P.ROTOR_INERTIA_KG_M2) @ P.J2MP)
    np.testing.assert_allclose(refl, P.ARMATURE_KG_M2, rtol=2e-3)


def test_forward_kinematics_hand_computable_poses():
    dyn = WamDynamics()
    # straight up: a3 and a4 cancel, the flange is d3 + d5 + d7 above the shoulder
    np.testing.assert_allclose(dyn.link7_pose(np.zeros(7))[:3, 3], [0, 0, 0.55 + 0.30 + 0.0609], atol=1e-12)
    # shoulder pitched forward by pi/2: the upper arm lies along +x0 (d3 along z1 which is x0), a3 then lifts...
    q = np.array([0, np.pi / 2, 0, 0, 0, 0, 0])
    p = dyn.link7_pose(q)[:3, 3]
    np.testing.assert_allclose(p, [0.9109, 0.0, 0.0], atol=1e-12)
    # elbow at pi/2 with the rest at zero: forearm horizontal along +x0, elbow at (0.045, 0, 0.55)
    q = np.array([0, 0, 0, np.pi / 2, 0, 0, 0])
    p = dyn.link7_pose(q)[:3, 3]
    np.testing.assert_allclose(p, [0.045 + 0.3609, 0.0, 0.55 + 0.045], atol=1e-12)
    for q in random_poses(20):
        np.testing.assert_allclose(dyn.link7_pose(q), dh_frames(q)[7], atol=1e-12)


def test_jacobian_matches_finite_difference_of_fk():
    dyn = WamDynamics()
    q = random_poses(1)[0]
    J = dyn.link7_jacobian(q)
    h = 1e-7
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        dp = (dyn.link7_pose(q + dq)[:3, 3] - dyn.link7_pose(q - dq)[:3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:3, j], dp, atol=1e-6)


def test_friction_torque_is_thesis_eq_2_8_at_hand_computed_points():
    """The Stribeck form against values worked out by hand from eq. 2.8, ``F = Fc + (Fs - Fc) exp(-|v/vs|^d)``
    (+ viscous), per direction: an outside reference for the one copy of the shape that the simulator, the
    identification and the diagnosis all share (a wrong exponent there would go unnoticed by comparing them
    with each other)."""
    from wamctl.model.friction import FrictionModel

    n = P.N_JOINTS
    fm = FrictionModel(fc_pos_Nm=np.full(n, 2.0), fc_neg_Nm=np.full(n, 1.0),
                       viscous_pos_Nm_s_rad=np.full(n, 0.5), viscous_neg_Nm_s_rad=np.full(n, 0.25),
                       fs_pos_Nm=np.full(n, 3.0), fs_neg_Nm=np.full(n, 1.5), vs_rad_s=np.full(n, 0.1),
                       stribeck_delta=np.full(n, 2.0))
    v = np.array([[0.1, 0.2, 0.05, -0.1, -0.2, 1.0, 0.0]])
    expected = [2 + 1 * np.exp(-1) + 0.05,          # v = vs: the excess has fallen to 1/e
                2 + 1 * np.exp(-4) + 0.10,          # v = 2 vs, delta 2: exp(-4)
                2 + 1 * np.exp(-0.25) + 0.025,      # v = vs / 2: exp(-1/4)
                -(1 + 0.5 * np.exp(-1)) - 0.025,    # negative direction, its own levels
                -(1 + 0.5 * np.exp(-4)) - 0.05,
                2 + 1 * np.exp(-100) + 0.5,         # far above vs: Coulomb + viscous only
                0.0]                                # at rest: no sliding friction (stiction is the simulator's)
    np.testing.assert_allclose(fm.friction_torque(v)[0], expected, rtol=1e-12, atol=1e-15)
    # another exponent: at v = 2 vs with delta = 1 the excess is exp(-2)
    fm1 = FrictionModel(**{**fm.__dict__, "stribeck_delta": np.full(n, 1.0)})
    assert fm1.friction_torque(np.full((1, n), 0.2))[0, 0] == pytest.approx(2 + np.exp(-2) + 0.1, rel=1e-12)


def test_batch_dynamics_match_the_per_sample_calls():
    """The batch helpers (one pinocchio call per sample, no per-call copies) give the per-sample results."""
    dyn = WamDynamics(Payload(0.4, (0.0, 0.02, 0.05)))
    q = np.array(random_poses(30))
    qd, qdd = RNG.normal(0, 1, q.shape), RNG.normal(0, 3, q.shape)
    np.testing.assert_array_equal(dyn.inverse_dynamics_many(q, qd, qdd),
                                  [dyn.inverse_dynamics(*s) for s in zip(q, qd, qdd)])
    np.testing.assert_array_equal(dyn.gravity_many(q), [dyn.gravity(x) for x in q])
    # column-major input (a table's columns) and a single state
    np.testing.assert_array_equal(dyn.inverse_dynamics_many(np.asfortranarray(q), qd, qdd)[3],
                                  dyn.inverse_dynamics(q[3], qd[3], qdd[3]))
    assert dyn.gravity_many(q[0]).shape == (1, 7)


def test_friction_shapes_fast_paths_are_the_formula():
    """``stribeck_decay``'s exponents 1 and 2 (computed without pow) and the classic columns, against the
    formulas written out here."""
    from wamctl.model.friction import classic_friction_columns, stribeck_decay

    v = np.array([-0.3, -0.05, 0.0, 0.01, 0.05, 0.2, 2.0])
    for delta in (1.0, 1.5, 2.0, 3.0):
        np.testing.assert_allclose(stribeck_decay(v, 0.05, delta), np.exp(-np.abs(v / 0.05) ** delta),
                                   rtol=1e-14, atol=0)
        assert stribeck_decay(0.1, 0.05, delta) == pytest.approx(np.exp(-(2.0 ** delta)), rel=1e-14)
    np.testing.assert_array_equal(classic_friction_columns(v), np.column_stack(
        [(v > 0) * 1.0, (v < 0) * -1.0, v * (v > 0), v * (v < 0)]))
