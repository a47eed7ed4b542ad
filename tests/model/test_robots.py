"""The robot registry (wamctl.model.robots) and the model of any registered arm, the 4-DOF WAM in particular."""

import numpy as np
import pytest

from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics, links_from_standard
from wamctl.model.robots import ROBOTS, get_robot

G = 9.81


def _hand_frames(r, q):
    """DH frames 0..n in frame 0, by hand (numpy only): A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)."""
    T = [np.eye(4)]
    for i, qi in enumerate(q):
        ct, st = np.cos(qi), np.sin(qi)
        ca, sa = np.cos(r.dh_alpha_rad[i]), np.sin(r.dh_alpha_rad[i])
        A = np.array([[ct, -st * ca, st * sa, r.dh_a_m[i] * ct],
                      [st, ct * ca, -ct * sa, r.dh_a_m[i] * st],
                      [0, sa, ca, r.dh_d_m[i]],
                      [0, 0, 0, 1.0]])
        T.append(T[-1] @ A)
    return T


def _hand_gravity(r, q, payload=None):
    """tau_i = -sum_k m_k g0 . (z_{i-1} x (p_k - o_{i-1})), g0 = (0, 0, -9.81): the torque holding the arm."""
    T = _hand_frames(r, q)
    masses = list(r.link_mass_kg)
    points = [T[k + 1][:3, :3] @ r.link_com_m[k] + T[k + 1][:3, 3] for k in range(r.n_joints)]
    if payload is not None:
        flange = T[-1] @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, r.flange_d_m], [0, 0, 0, 1.0]])
        masses.append(payload.mass_kg)
        points.append(flange[:3, :3] @ np.asarray(payload.com_m) + flange[:3, 3])
    g0 = np.array([0.0, 0.0, -G])
    tau = np.zeros(r.n_joints)
    for i in range(r.n_joints):
        z, o = T[i][:3, 2], T[i][:3, 3]
        # links i..n (0-based k >= i) and the payload move with joint i
        tau[i] = -sum(m * g0 @ np.cross(z, p - o) for k, (m, p) in enumerate(zip(masses, points)) if k >= i)
    return tau


def test_wam7_entry_is_params_unchanged():
    r = get_robot("wam7")
    assert r.n_joints == P.N_JOINTS == 7
    for a, b in ((r.dh_d_m, P.DH_D_M), (r.link_mass_kg, P.LINK_MASS_KG), (r.link_com_m, P.LINK_COM_M),
                 (r.link_inertia_kg_m2, P.LINK_INERTIA_KG_M2), (r.armature_kg_m2, P.ARMATURE_KG_M2),
                 (r.kp, P.KP), (r.tau_max_Nm, P.TAU_MAX_NM), (r.home_q_rad, P.HOME_Q_RAD), (r.j2mp, P.J2MP)):
        np.testing.assert_array_equal(a, b)
    assert get_robot(None) is r
    assert set(ROBOTS) >= {"wam7", "wam4"}


def test_unknown_robot_one_line():
    with pytest.raises(ValueError, match="robot 'wam5': unknown"):
        get_robot("wam5")


def test_wam4_description_from_libbarrett():
    r = get_robot("wam4")
    assert r.n_joints == 4 and r.puck_ids == (1, 2, 3, 4)
    np.testing.assert_allclose(r.link_mass_kg, [10.7677, 3.8749, 1.8023, 1.0651])
    np.testing.assert_allclose(r.home_q_rad, [0, -2, 0, 3.13])
    # armature = diag(j2mp^T diag(Jm) j2mp) of the four shoulder/elbow motors
    np.testing.assert_allclose(r.armature_kg_m2, np.diag(r.j2mp.T @ np.diag(P.ROTOR_INERTIA_KG_M2[:4]) @ r.j2mp),
                               rtol=2e-4)


@pytest.mark.parametrize("name", ["wam4", "wam7"])
def test_gravity_against_hand_computation(name):
    r = get_robot(name)
    dyn = WamDynamics(robot=name)
    assert dyn.model.nq == r.n_joints
    rng = np.random.default_rng(3)
    for q in [r.home_q_rad, *rng.uniform(r.q_min_rad, r.q_max_rad, (4, r.n_joints))]:
        np.testing.assert_allclose(dyn.gravity(q), _hand_gravity(r, q), atol=1e-10)


def test_wam4_gravity_at_home_pose_figures():
    """libbarrett's home pose (0, -2, 0, 3.13): joints 1 and 3 have no gravity torque (the arm folded in the
    vertical plane through joint 1's axis; the links' small lateral COM offsets give the remainder)."""
    dyn = WamDynamics(robot="wam4")
    g = dyn.gravity(np.array([0.0, -2.0, 0.0, 3.13]))
    expected = _hand_gravity(get_robot("wam4"), np.array([0.0, -2.0, 0.0, 3.13]))
    np.testing.assert_allclose(g, expected, atol=1e-10)
    assert abs(g[0]) < 1e-12                                     # joint 1 vertical
    # the numpy computation above gives, at home: joint 2 10.296 N m (links 2-4 held against gravity), joint 3
    # -0.0002 N m (link 3's 0.03 mm lateral COM), joint 4 -1.176 N m
    np.testing.assert_allclose(g, [0.0, 10.2961, -0.000197, -1.1763], atol=2e-4)


def test_wam4_payload_at_flange():
    pay = Payload(1.0, (0.0, 0.0, 0.06))
    dyn = WamDynamics(payload=pay, robot="wam4")
    r = get_robot("wam4")
    q = np.array([0.3, 0.4, -0.2, 1.1])
    np.testing.assert_allclose(dyn.gravity(q), _hand_gravity(r, q, pay), atol=1e-10)
    # the flange is 0.36 m beyond DH frame 4 along z4 (libbarrett wam4.conf toolplate)
    T = _hand_frames(r, q)[-1]
    np.testing.assert_allclose(dyn.link7_pose(q)[:3, 3], T[:3, 3] + 0.36 * T[:3, 2], atol=1e-12)


def test_wam4_mass_matrix_spd_and_inverse_dynamics():
    dyn = WamDynamics(robot="wam4")
    rng = np.random.default_rng(7)
    r = dyn.robot
    for _ in range(5):
        q = rng.uniform(r.q_min_rad, r.q_max_rad)
        M = dyn.mass_matrix(q)
        assert M.shape == (4, 4)
        np.testing.assert_allclose(M, M.T, atol=0)
        assert np.linalg.eigvalsh(M).min() > 0.9 * r.armature_kg_m2.min()
        qd, qdd = rng.normal(size=4), rng.normal(size=4)
        tau = dyn.inverse_dynamics(q, qd, qdd)
        np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau), qdd, atol=1e-9)
        Y = dyn.regressor_basis(q, qd, qdd)
        assert Y.shape == (4, 40)
        np.testing.assert_allclose(Y @ dyn.standard_parameters() + r.armature_kg_m2 * qdd, tau, atol=1e-9)


def test_wam4_links_round_trip_and_refusals():
    dyn = WamDynamics(robot="wam4")
    links = links_from_standard(dyn.standard_parameters(), dyn.armature_kg_m2, robot="wam4")
    assert links.robot == "wam4"
    np.testing.assert_allclose(links.mass_kg, dyn.links.mass_kg)
    np.testing.assert_allclose(links.com_m, dyn.links.com_m, atol=1e-12)
    assert WamDynamics(links=links).n_joints == 4
    with pytest.raises(ValueError, match="links.5: joint numbers of wam4 are 1..4"):
        links.with_overrides({5: {"mass_kg": 1.0}})
    with pytest.raises(ValueError, match="links of wam7 for a wam4 model"):
        WamDynamics(robot="wam4", links=P.LinkParameters.datasheet())


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_link_parameters_survive_pickling(name):
    """A sweep's workers and the tests' shared values pickle the links: the immutable slots came back (they had
    raised 'LinkParameters is immutable' on unpickling)."""
    import pickle

    links = P.LinkParameters.datasheet(name).with_overrides({2: {"mass_kg": 4.2}})
    back = pickle.loads(pickle.dumps(links))
    assert back.robot == name and back.mass_kg[1] == 4.2
    for key in P.LINK_KEYS:
        np.testing.assert_array_equal(getattr(back, key), getattr(links, key))
    with pytest.raises(AttributeError):
        back.mass_kg = None
