"""The arm's capsules: segment distances against brute force (and coal, pinocchio's collision library), the
DH frames against a hand-written DH product, a folded elbow detected as self-collision, the sampling bound."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.model import collision as C
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics


def brute_force(p1, q1, p2, q2, n=801):
    s = np.linspace(0, 1, n)
    a = p1 + s[:, None] * (q1 - p1)
    b = p2 + s[:, None] * (q2 - p2)
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min()


def test_segment_distance_matches_brute_force_including_parallel_and_degenerate_segments():
    rng = np.random.default_rng(3)
    cases = [tuple(rng.normal(0, 0.3, (4, 3))) for _ in range(40)]
    p = np.array([0.0, 0.0, 0.0])
    cases += [(p, p + [1, 0, 0], p + [0.2, 0.1, 0], p + [0.8, 0.1, 0]),      # parallel, overlapping
              (p, p + [1, 0, 0], p + [1.5, 0.1, 0], p + [2.5, 0.1, 0]),      # parallel, apart along the axis
              (p, p, p + [0.3, 0.4, 0], p + [0.3, 0.4, 1.0]),                 # a point and a segment
              (p + [1, 2, 3], p + [1, 2, 3], p, p),                           # two points
              (p, p + [1, 0, 0], p + [0.5, -1, 0], p + [0.5, 1, 0])]          # crossing: 0
    got = C.segment_distance(*(np.array([c[k] for c in cases]) for k in range(4)))
    want = np.array([brute_force(*c) for c in cases])
    # brute force on 801 points per segment is above the truth by at most half a step's chord
    step = np.array([max(np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[2])) / 800 for c in cases])
    assert np.all(got <= want + 1e-12) and np.all(want - got <= step + 1e-12)
    assert got[-1] == pytest.approx(0.0, abs=1e-12) and got[-2] == pytest.approx(np.sqrt(14))
    assert got[-3] == pytest.approx(0.5) and got[-4] == pytest.approx(np.hypot(0.5, 0.1))
    assert got[-5] == pytest.approx(0.1)


def test_capsule_distance_matches_coal():
    coal = pytest.importorskip("coal")
    rng = np.random.default_rng(4)
    for _ in range(10):
        p1, q1, p2, q2 = rng.normal(0, 0.4, (4, 3))
        r1, r2 = 0.03, 0.05
        shapes = []
        for p, q, r in ((p1, q1, r1), (p2, q2, r2)):   # coal's capsule lies along its z axis, centred
            axis = q - p
            length = np.linalg.norm(axis)
            z = axis / length
            x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
            x /= np.linalg.norm(x)
            R = np.column_stack([x, np.cross(z, x), z])
            shapes.append((coal.Capsule(r, length), coal.Transform3s(R, 0.5 * (p + q))))
        res = coal.DistanceResult()
        coal.distance(shapes[0][0], shapes[0][1], shapes[1][0], shapes[1][1], coal.DistanceRequest(), res)
        ours = C.segment_distance(p1, q1, p2, q2)[0] - r1 - r2
        if ours > 0:
            assert ours == pytest.approx(res.min_distance, abs=1e-9)


def dh_frames(q):
    """DH frames 0..7 by the product of A_i = Rz(q) Tz(d) Tx(a) Rx(alpha), written out."""
    T = np.eye(4)
    out = [T.copy()]
    for i in range(7):
        ct, st = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(P.DH_ALPHA_RAD[i]), np.sin(P.DH_ALPHA_RAD[i])
        a, d = P.DH_A_M[i], P.DH_D_M[i]
        A = np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
        T = T @ A
        out.append(T.copy())
    return np.array(out)


def test_joint_frames_are_the_dh_product():
    dyn = WamDynamics()
    q = np.random.default_rng(5).uniform(P.Q_MIN_RAD, P.Q_MAX_RAD, (5, 7))
    F = dyn.joint_frames(q)
    assert F.shape == (5, 8, 4, 4)
    for k in range(5):
        assert np.allclose(F[k], dh_frames(q[k]), atol=1e-12)
    assert np.allclose(dyn.joint_frames(q[0])[7], dyn.link7_pose(q[0]), atol=1e-12)


def test_folded_elbow_with_the_hand_bent_back_hits_the_upper_arm_and_the_rest_pose_is_clear():
    dyn, geo = WamDynamics(), C.ArmGeometry.default()
    folded = np.array([0.0, 0.0, 0.0, 3.1, 0.0, 1.6, 0.0])     # elbow folded, wrist bent back onto the upper arm
    d = C.smallest(C.distances(dyn.joint_frames(folded[None]), geo))["self"]
    assert d.between == "link 3 (upper arm) / links 5-7 (wrist and hand)" and d.distance_m == pytest.approx(
        -0.0435, abs=1e-3)
    rest = C.smallest(C.distances(dyn.joint_frames(P.HOME_Q_RAD[None]), geo))["self"]
    assert 0.0 < rest.distance_m < 0.01        # the radii are sized to keep the rest pose just clear
    straight = C.smallest(C.distances(dyn.joint_frames(np.zeros((1, 7))), geo, table_z_m=-0.1))
    # upright: the upper arm starts at the shoulder, 0.1 m above the table, radius 0.045
    assert straight["table"].distance_m == pytest.approx(0.055) and straight["table"].between == "link 3 (upper arm)"


def test_workspace_box_distance_is_negative_outside():
    dyn, geo = WamDynamics(), C.ArmGeometry.default()
    F = dyn.joint_frames(np.zeros((1, 7)))      # upright: the hand's end at z = 0.55 + 0.3 + 0.0609 m
    top = 0.55 + 0.30 + 0.0609
    d = C.distances(F, geo, box_min_m=[-1, -1, -0.5], box_max_m=[1, 1, 0.8], self_collision=False)["box"]
    assert d["links 5-7 (wrist and hand)"][0] == pytest.approx(0.8 - top - 0.04)


def test_sampling_bound_covers_what_a_coarse_sampling_misses():
    """The wrist bent back onto the folded elbow and away again (a kink at t = 0.5 s, between the coarse
    samples) sampled at 20 Hz and at 20 kHz: the fine minimum is never below the coarse minimum minus the bound,
    and the coarse sampling does miss some of it."""
    dyn, geo = WamDynamics(), C.ArmGeometry.default()
    t_fine = np.linspace(0, 1, 20001)

    def traj(t):
        q = np.tile([0.0, 0.0, 0.0, 3.1, 0.0, 0.0, 0.0], (len(t), 1))
        q[:, 5] = 1.0 - 2.0 * np.abs(t - 0.5)
        q[:, 0] = 0.5 * np.sin(2 * np.pi * t)
        return q

    fine = C.smallest(C.distances(dyn.joint_frames(traj(t_fine)), geo))["self"].distance_m
    t_coarse = t_fine[500::1000]                # 0.025, 0.075, ...: 25 ms either side of the kink
    coarse = C.smallest(C.distances(dyn.joint_frames(traj(t_coarse)), geo))["self"].distance_m
    qd_max = np.abs(np.gradient(traj(t_fine), t_fine, axis=0)).max(axis=0)
    bound = C.motion_bound_m(qd_max, geo, t_coarse[1] - t_coarse[0])
    assert coarse > fine + 1e-3           # the coarse sampling misses the deepest point
    assert fine >= coarse - bound
