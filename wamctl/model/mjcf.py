"""The WAM as a MuJoCo model (MJCF), generated in code from :mod:`wamctl.model.params`: for the peer benchmark
and for cross-checking the pinocchio model against an independent implementation.

Construction (mirrors :func:`wamctl.model.dynamics.build_wam7_model`)
-------------------------------------------------------------------
* Body ``link{i}`` carries hinge joint ``joint{i}`` about its local z axis; it sits in its parent body at the
  fixed part of the previous DH transform, ``Tz(d_{i-1}) Tx(a_{i-1}) Rx(alpha_{i-1})`` (identity for link 1),
  so the body frame is DH frame ``i-1`` rotated by ``q_i``.
* Link ``i``'s COM and inertia (given about the COM, in DH frame ``i``) are mapped into the body frame through
  the fixed part of ``A_i``: ``c_body = R c + t``, ``I_body = R I R^T`` (written as ``fullinertia``).
* The reflected rotor inertia is the joint ``armature``; gravity is -9.81 m/s^2 along z0; no geometry, no
  contacts, no joint limits (safety limits belong to the controller side, as in wamctl's simulator).
* A site ``link7`` marks DH frame 7 (the wrist flange).

Friction (optional). MuJoCo has a symmetric Coulomb ``frictionloss`` (a soft constraint solved with the
dynamics) and a symmetric viscous ``damping`` (integrated implicitly by the Euler integrator). wamctl's
friction models have one level per direction, so the MJCF uses the **mean of the two directions** for both;
the Stribeck term has no MuJoCo counterpart and is left out.
"""

from __future__ import annotations

import logging
from xml.sax.saxutils import quoteattr

import numpy as np

from wamctl.model import params as P
from wamctl.model.dynamics import Payload
from wamctl.model.friction import FrictionModel

log = logging.getLogger(__name__)


def dh_fixed(i: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) of ``Tz(d_i) Tx(a_i) Rx(alpha_i)`` for 0-based joint ``i``."""
    ca, sa = np.cos(P.DH_ALPHA_RAD[i]), np.sin(P.DH_ALPHA_RAD[i])
    rot = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    return rot, np.array([P.DH_A_M[i], 0.0, P.DH_D_M[i]])


def link_inertial_in_body(i: int) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, COM (3,) m, inertia about the COM (3, 3) kg m^2) of link ``i`` (0-based) in its body frame."""
    ixx, iyy, izz, ixy, ixz, iyz = P.LINK_INERTIA_KG_M2[i]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    rot, trans = dh_fixed(i)
    return float(P.LINK_MASS_KG[i]), rot @ P.LINK_COM_M[i] + trans, rot @ inertia @ rot.T


def mujoco_friction(friction: FrictionModel) -> tuple[np.ndarray, np.ndarray]:
    """(frictionloss N m, damping N m s/rad), each (7,): the mean of the positive and negative direction of
    the Coulomb level and of the viscous coefficient (absolute values). Stribeck terms are dropped."""
    if np.any(friction.has_stribeck):
        log.warning("MuJoCo has no Stribeck friction: the Stribeck terms are left out of the MJCF model")
    fc = (np.abs(friction.fc_pos_Nm) + np.abs(friction.fc_neg_Nm)) / 2
    visc = (np.abs(friction.viscous_pos_Nm_s_rad) + np.abs(friction.viscous_neg_Nm_s_rad)) / 2
    return fc, visc


def _vec(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def _quat_x(alpha: float) -> str:
    """MuJoCo quaternion (w x y z) of a rotation by ``alpha`` about x."""
    return _vec([np.cos(alpha / 2), np.sin(alpha / 2), 0.0, 0.0])


def wam_mjcf(friction: FrictionModel | None = None, payload: Payload | None = None,
             timestep_s: float = 1.0 / P.CONTROL_RATE_HZ / 2, integrator: str = "Euler",
             friction_timeconst_s: float | None = None, model_name: str = "wam7") -> str:
    """The 7-DOF WAM as an MJCF document (a string; no MuJoCo needed to build it).

    Parameters
    ----------
    friction : joint friction (mean of both directions, see the module docstring); None = frictionless.
    payload : point mass on link 7 (a child body with a negligible 1e-9 kg m^2 inertia, which MuJoCo needs).
    timestep_s : physics step (default 1 ms: two steps per 2 ms control period, as wamctl's simulator).
    integrator : MuJoCo integrator; ``Euler`` is semi-implicit Euler (velocity first, then position with the
        new velocity), the scheme of wamctl's simulator, with implicit joint damping.
    friction_timeconst_s : time constant of the soft Coulomb friction constraint (``solreffriction``);
        None keeps MuJoCo's default (0.02 s, a creeping friction); MuJoCo advises at least 2 timesteps.

    Returns
    -------
    str, the MJCF XML.
    """
    fl, damp = mujoco_friction(friction) if friction is not None else (np.zeros(P.N_JOINTS),) * 2
    solref = f'solreffriction="{friction_timeconst_s:.17g} 1" ' if friction_timeconst_s else ""
    lines = [f"<mujoco model={quoteattr(model_name)}>",
             '  <compiler angle="radian" inertiafromgeom="false" boundmass="0" boundinertia="0" '
             'balanceinertia="false"/>',
             f'  <option timestep="{timestep_s:.17g}" gravity="0 0 {-P.GRAVITY_M_S2:.17g}" '
             f'integrator="{integrator}">',
             '    <flag contact="disable"/>',
             "  </option>",
             "  <worldbody>"]
    indent = "    "
    for i in range(P.N_JOINTS):
        if i == 0:
            pos, quat = _vec(np.zeros(3)), _vec([1.0, 0.0, 0.0, 0.0])
        else:
            _, t = dh_fixed(i - 1)
            pos, quat = _vec(t), _quat_x(P.DH_ALPHA_RAD[i - 1])
        mass, com, inertia = link_inertial_in_body(i)
        full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
        lines += [f'{indent}<body name="link{i + 1}" pos="{pos}" quat="{quat}">',
                  f'{indent}  <inertial pos="{_vec(com)}" mass="{mass:.17g}" fullinertia="{_vec(full)}"/>',
                  f'{indent}  <joint name="joint{i + 1}" type="hinge" axis="0 0 1" limited="false" '
                  f'armature="{P.ARMATURE_KG_M2[i]:.17g}" damping="{damp[i]:.17g}" '
                  f'{solref}frictionloss="{fl[i]:.17g}"/>']
        indent += "  "
    _, t7 = dh_fixed(P.N_JOINTS - 1)
    lines.append(f'{indent}<site name="link7" pos="{_vec(t7)}" quat="{_quat_x(P.DH_ALPHA_RAD[-1])}"/>')
    if payload is not None and payload.mass_kg > 0:
        rot, trans = dh_fixed(P.N_JOINTS - 1)
        com = rot @ np.asarray(payload.com_m, float) + trans
        lines += [f'{indent}<body name="payload" pos="{_vec(com)}">',
                  f'{indent}  <inertial pos="0 0 0" mass="{payload.mass_kg:.17g}" diaginertia="1e-9 1e-9 1e-9"/>',
                  f"{indent}</body>"]
    for _ in range(P.N_JOINTS):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


def load_mujoco_model(**kwargs):
    """``mujoco.MjModel`` of :func:`wam_mjcf` (``kwargs`` passed on). Needs the ``mujoco`` package."""
    try:
        import mujoco
    except ImportError:
        from wamctl.errors import BackendError
        raise BackendError("the MuJoCo model needs the mujoco package: pip install mujoco") from None
    return mujoco.MjModel.from_xml_string(wam_mjcf(**kwargs))


def full_mass_matrix(model, data):
    """The dense joint-space inertia matrix (nv, nv) of a MuJoCo model after ``mj_forward``; works with the
    MuJoCo 4 signature ``mj_fullM(m, d, dst)`` and the MuJoCo 3 one ``mj_fullM(m, dst, d.qM)``."""
    import mujoco
    out = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, out)
    except TypeError:
        mujoco.mj_fullM(model, out, data.qM)
    return out
