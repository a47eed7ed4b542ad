"""The MJCF model generated from the same parameters (benchmarks/bench_peer.py's MuJoCo peer) agrees with the
pinocchio model: mass matrix with armature, gravity, link-7 pose, masses and friction."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.model import params as P


def test_mjcf_model_matches_pinocchio():
    mujoco = pytest.importorskip("mujoco")
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel
    from wamctl.model.mjcf import full_mass_matrix, load_mujoco_model, mujoco_friction

    m = load_mujoco_model()
    d = mujoco.MjData(m)
    dyn = WamDynamics()
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "link7")
    rng = np.random.default_rng(7)
    for _ in range(50):
        q = rng.uniform(P.Q_MIN_RAD, P.Q_MAX_RAD)
        d.qpos[:] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        mm = full_mass_matrix(m, d)
        assert np.allclose(mm, dyn.mass_matrix(q), rtol=0, atol=1e-10)          # incl. armature
        assert np.allclose(d.qfrc_bias, dyn.gravity(q), rtol=0, atol=1e-9)      # zero velocity: gravity only
        pose = dyn.link7_pose(q)
        assert np.allclose(d.site_xpos[site], pose[:3, 3], atol=1e-12)
        assert np.allclose(d.site_xmat[site].reshape(3, 3), pose[:3, :3], atol=1e-12)
    # the armature is where both engines put it: MuJoCo's mass matrix without it differs from pinocchio's by
    # exactly diag(armature) (the reflected rotor inertias of wamctl.model.params)
    assert np.allclose(m.dof_armature, P.ARMATURE_KG_M2)
    m.dof_armature[:] = 0.0
    mujoco.mj_forward(m, d)
    assert np.allclose(dyn.mass_matrix(q) - full_mass_matrix(m, d), np.diag(P.ARMATURE_KG_M2), rtol=0, atol=1e-10)
    # a mismatched parameter would show: the MJCF really carries the link masses
    assert m.body_mass[1:].sum() == pytest.approx(P.LINK_MASS_KG.sum())
    fl, damp = mujoco_friction(FrictionModel.table_4_1())
    mf = load_mujoco_model(friction=FrictionModel.table_4_1())
    assert np.allclose(mf.dof_frictionloss, (P.TABLE_4_1_FC_POS_NM + P.TABLE_4_1_FC_NEG_NM) / 2)
    assert np.allclose(mf.dof_damping, (np.abs(P.TABLE_4_1_VISCOUS_POS) + np.abs(P.TABLE_4_1_VISCOUS_NEG)) / 2)
    assert np.allclose(fl, mf.dof_frictionloss) and np.allclose(damp, mf.dof_damping)
